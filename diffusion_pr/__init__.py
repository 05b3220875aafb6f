"""diffusion_pr: pressure distributions in rough elastic contacts.

Müser's field theory of rough contact (Phys. Rev. Lett. 100, 055504 (2008),
doi:10.1103/PhysRevLett.100.055504): Persson's mirror Gaussian as the leading
order, the second-order cumulant ``G1(q)`` for exponentially repulsive walls, and
the magnification-dependent drift-diffusion (Fokker-Planck) equation for
``Pr(p, eta)``.

Main entry points::

    from diffusion_pr import SelfAffineSpectrum, pressure_distribution, propagate
    s = SelfAffineSpectrum(0.3, 2*np.pi/1024, 2*np.pi/32, rms_slope=0.031)
    r = pressure_distribution(s, E_star=8/3, mean_pressure=0.004, zeta=0.25)
    paper = pressure_distribution(s, E_star=8/3, mean_pressure=0.004, zeta=0.25,
                                  closure="second_order", cutoff="smoothstep", p_c=0.0027)
    r.plot()

Every public name is imported lazily on first access, so ``import
diffusion_pr`` is fast and never imports py-pde or FiPy (those load only when
their backend is asked for).
"""
from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

# submodule -> the public names it defines
_MODULES = {
    "spectra": ["Spectrum", "SelfAffineSpectrum", "DiscreteSpectrum"],
    "cumulants": ["G1", "stress_variance", "variance_vs_magnification", "diffusivity_vs_magnification"],
    "topography": ["TabulatedSpectrum", "spectrum_from_map", "spectrum_from_psd", "spectrum_from_topography"],
    "closed_forms": ["gaussian_density", "mirror_gaussian_density", "persson_zero_weight", "persson_contact_fraction",
                     "feller_density", "feller_zero_weight", "gaussian_moments", "mirror_gaussian_moments",
                     "feller_moments"],
    "models": ["SharpCutoff", "MuserCutoff", "RaisedCosineCutoff", "SmoothstepCutoff", "GaussianTail", "LinearTail",
               "MaxLinearTail", "PressureFactor", "ProportionalDiffusivity", "make_cutoff", "make_tail"],
    "problem": ["FokkerPlanckProblem", "Stage", "StagedProblem"],
    "result": ["PressureDistribution"],
    "api": ["propagate", "pressure_distribution", "pressure_distributions", "solve_problem", "choose_backend",
            "warm_up", "ConvergenceWarning", "DEFAULT_CLOSURE", "HARD_WALL_DEFAULT"],
    "load_curve": ["load_curve", "LoadCurve"],
    "fokker_planck.backends": ["BackendUnavailableError", "backend_names", "is_available"],
    "_validation": ["InputTypeError"],
}
#: public name -> submodule that defines it
_LAZY = {name: module for module, names in _MODULES.items() for name in names}

__all__ = sorted(_LAZY) + ["__version__"]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'diffusion_pr' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # cache: later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
