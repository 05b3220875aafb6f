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

# public name -> submodule that defines it
_LAZY = {
    # spectra and cumulants
    "Spectrum": "spectra",
    "SelfAffineSpectrum": "spectra",
    "DiscreteSpectrum": "spectra",
    "G1": "cumulants",
    "stress_variance": "cumulants",
    "variance_vs_magnification": "cumulants",
    "diffusivity_vs_magnification": "cumulants",
    "TabulatedSpectrum": "topography",
    "spectrum_from_map": "topography",
    "spectrum_from_psd": "topography",
    "spectrum_from_topography": "topography",
    # closed forms
    "gaussian_density": "closed_forms",
    "mirror_gaussian_density": "closed_forms",
    "persson_zero_weight": "closed_forms",
    "persson_contact_fraction": "closed_forms",
    "feller_density": "closed_forms",
    "feller_zero_weight": "closed_forms",
    "gaussian_moments": "closed_forms",
    "mirror_gaussian_moments": "closed_forms",
    "feller_moments": "closed_forms",
    # models
    "SharpCutoff": "models",
    "MuserCutoff": "models",
    "RaisedCosineCutoff": "models",
    "SmoothstepCutoff": "models",
    "GaussianTail": "models",
    "LinearTail": "models",
    "MaxLinearTail": "models",
    "PressureFactor": "models",
    "ProportionalDiffusivity": "models",
    "make_cutoff": "models",
    "make_tail": "models",
    # problem, result, solving
    "FokkerPlanckProblem": "problem",
    "Stage": "problem",
    "StagedProblem": "problem",
    "PressureDistribution": "result",
    "propagate": "api",
    "pressure_distribution": "api",
    "pressure_distributions": "api",
    "load_curve": "load_curve",
    "LoadCurve": "load_curve",
    "solve_problem": "api",
    "choose_backend": "api",
    "BackendUnavailableError": "fokker_planck.backends",
    "backend_names": "fokker_planck.backends",
    "is_available": "fokker_planck.backends",
    "warm_up": "api",
    "ConvergenceWarning": "api",
    "DEFAULT_CLOSURE": "api",
    "HARD_WALL_DEFAULT": "api",
    "InputTypeError": "_validation",
}

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
