"""Closures beyond the paper's second order (docs/closures.md).

The paper (M. H. Müser, Phys. Rev. Lett. 100, 055504 (2008), doi:10.1103/PhysRevLett.100.055504) broadens a
Gaussian with the second-order variance ``V = sum_q (q E*/2)^2 G1(q)^2 |h~(q)|^2`` and needs a fitted cutoff
pressure ``p_c``.  The closures here need no fitted number, but for the two fitted corrections at the end:

``"second_order"``
    The paper: ``dPr/dtau = d^2/dp^2 [f(p) Pr]`` to ``tau = V/2`` (solved by
    :func:`diffusion_pr.pressure_distribution` itself).
``"lognormal_gap"``
    The gap fluctuation ``-(1 - G1(q)) h~(q)`` is Gaussian; the wall law ``p = p_w exp(-gap/zeta)`` makes the
    pressure log-normal with ``Var(ln p) = V / p0^2`` and mean ``p0``
    (:func:`diffusion_pr.closed_forms.lognormal_gap_distribution`; ``zeta > 0`` only).
``"local_g1"``
    Shell by shell in ``q`` (``tau`` advancing by ``dV0_k/2`` across shell ``k``):
    ``dPr/dtau = d^2/dp^2 [g(q_k; p)^2 Pr]`` with ``g(q; p) = 1/(1 + zeta q E*/(2p))`` at the local pressure.
``"local_g1_balanced"``
    As ``local_g1`` plus the drift ``b = (1 - g(q_min; p)) (g(q_k; p)^2/p - A p)``, ``A`` one number per
    shell (by default) that brings ``<p>`` back to ``p0`` at the shell's end.
``"local_g1_shell_balanced"``
    As ``local_g1_balanced`` with ``g(q_k; p)`` in the partition; the best on the Fig. 1 scene's GFMD
    ensemble, not off it (docs/closures.md, docs/fig1.md).
``"sum_rule"``
    The hard wall: Persson's mirror Gaussian re-timed so that ``Var(p) = a_r V`` (elasticity's
    ``Var(p) = (E*/2)^2 <|grad u|^2>`` with the slopes in contact those of the surface;
    :func:`diffusion_pr.closed_forms.sum_rule_variance`; ``zeta = 0`` only).
``"yang_persson"``, ``"wang_muser"``
    Not parameter free: Persson's hard-wall diffusion slowed by ``gamma + (1 - gamma) a_r^2`` with a constant
    fitted to simulations by Yang & Persson 2008 (``gamma = 0.45``) and Wang & Müser 2017 (``5/9``), for
    comparison (:func:`diffusion_pr.closed_forms.persson_corrected_variance`; ``zeta = 0`` only).

Submodules: :mod:`~diffusion_pr.closures.shells`, :mod:`~diffusion_pr.closures.models`,
:mod:`~diffusion_pr.closures.continuum`.  Pressures in the unit of ``E_star``; lengths in the unit of the
spectrum; ``tau`` in pressure^2."""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Optional

import numpy as np

from .._validation import check_nonnegative, check_positive
from ..spectra import DiscreteSpectrum, Spectrum
from .continuum import (GRID_RETRY_FRACTION, MAX_CONTINUUM_SHELLS, SHELL_SHARE, shell_extrapolated, shell_problem,
                        solve_shells)
from .models import (BALANCED_FLOOR, LoadExcessDrift, LocalResponseDiffusivity, RigidApproachBalance,
                     closure_problem)
from .shells import (BALANCED, DEFAULT_CONTINUUM_SHELLS, EXTRAPOLATION_SHELLS, Shells, cached_shells, local_response,
                     shell_grading, spectrum_shells)

__all__ = ["CLOSURES", "Shells", "spectrum_shells", "shell_grading", "local_response", "closure_problem",
           "LocalResponseDiffusivity", "LoadExcessDrift", "RigidApproachBalance", "DEFAULT_CONTINUUM_SHELLS",
           "PERSSON_CORRECTIONS"]

#: the closures by name; "second_order" is the paper's theory
CLOSURES: tuple[str, ...] = ("second_order", "lognormal_gap", "local_g1", "local_g1_balanced",
                             "local_g1_shell_balanced", "yang_persson", "wang_muser", "sum_rule")
#: the hard-wall corrections of Persson's theory and their fitted ``gamma`` (docs/closures.md)
PERSSON_CORRECTIONS: dict[str, float] = {"yang_persson": 0.45, "wang_muser": 5.0 / 9.0}

#: (the names tests/oracles/closure_reference.py imports)
_BALANCED, _cached_shells = BALANCED, cached_shells

def check_closure(closure: object) -> str:
    """Return ``closure`` if it names a closure, else raise ``ValueError`` listing the names."""
    if not isinstance(closure, str) or closure not in CLOSURES:
        raise ValueError(f"closure must be one of {list(CLOSURES)}; got closure={closure!r}")
    return closure


def _check_fv_options(backend: str, options: dict) -> str:
    """The finite-volume backend ``backend`` names (``"auto"``: ``"native"``), after checking that it is one and
    that it takes ``options``."""
    import sys

    from ..fokker_planck.backends import backend_names, get_backend, keyword_options

    chosen = "native" if backend == "auto" else backend
    if chosen not in backend_names():
        raise ValueError(f"backend must be one of {sorted(set(backend_names()) | {'auto'})}; got backend={backend!r}")
    solver = get_backend(chosen)
    full = getattr(sys.modules[solver.__module__], "solve_full", None)
    if full is None:
        raise ValueError(f"the shell closures are staged problems for a finite-volume backend; backend {chosen!r} "
                         "is not one (use 'auto', 'native', 'pypde' or 'fipy')")
    accepted = keyword_options(solver)
    unknown = set(options) - accepted
    if unknown:
        raise ValueError(f"unknown option(s) {sorted(unknown)} for backend {chosen!r}; it accepts {sorted(accepted)}")
    return chosen


def closure_distribution(spectrum: Spectrum, *, E_star: float, mean_pressure: float, zeta: float = 0.0,
                         closure: str, backend: str = "auto", rtol: float = 1e-6, n_shells: Optional[int] = None,
                         shell_extrapolation: Optional[bool] = None, **options: Any) -> Any:
    r"""The pressure distribution of a closure beyond the paper's second order: the layer's entry, which
    :func:`diffusion_pr.pressure_distribution` calls with ``closure=`` (the parameters are described there).

    ``"lognormal_gap"`` is a closed form (:func:`diffusion_pr.closed_forms.lognormal_gap_distribution`).  The
    shell closures are a :class:`~diffusion_pr.problem.StagedProblem` (:func:`closure_problem`) on the shells of
    the spectrum (:func:`spectrum_shells`: a :class:`~diffusion_pr.spectra.DiscreteSpectrum`'s own, or
    ``n_shells`` of a continuum), solved by the finite-volume ``backend`` (``"auto"``: ``"native"``); with
    ``shell_extrapolation`` (the default on a continuum spectrum without ``n_shells``) the continuum closure,
    extrapolated in the number of shells (:mod:`~diffusion_pr.closures.continuum`; the first solve on
    :data:`~diffusion_pr.closures.shells.EXTRAPOLATION_SHELLS` shells graded by :func:`shell_grading`).

    Returns
    -------
    PressureDistribution
        ``diagnostics["closure"]`` names the closure.
    """
    check_closure(closure)
    if closure in ("second_order", "sum_rule", *PERSSON_CORRECTIONS):
        raise ValueError(f"closure={closure!r} is a mirror Gaussian or the paper's theory: "
                         "diffusion_pr.pressure_distribution solves it")
    for name, value in (("E_star", E_star), ("mean_pressure", mean_pressure), ("zeta", zeta)):
        if np.ndim(value) != 0:
            raise ValueError(f"{name} must be a scalar (loop for several distributions); got an array of shape "
                             f"{np.shape(value)}")
    E = float(check_positive("E_star", E_star))
    p0 = float(check_positive("mean_pressure", mean_pressure))
    z = float(check_nonnegative("zeta", zeta))
    if shell_extrapolation is not None and not isinstance(shell_extrapolation, (bool, np.bool_)):
        raise ValueError(f"shell_extrapolation must be None, True or False; got "
                         f"shell_extrapolation={shell_extrapolation!r}")
    if closure == "lognormal_gap":
        if shell_extrapolation:
            raise ValueError("shell_extrapolation applies to the shell closures ('local_g1', 'local_g1_balanced', "
                             f"'local_g1_shell_balanced') on the finite-volume backends; got closure={closure!r}, "
                             f"backend={backend!r}")
        if n_shells is not None:
            raise ValueError("shell options (n_shells) do not apply to closure='lognormal_gap' (closed form)")
        from ..closed_forms import lognormal_gap_distribution

        return lognormal_gap_distribution(spectrum, E_star=E, mean_pressure=p0, zeta=z, rtol=rtol)
    if shell_extrapolation is None:  # the default: the continuum closure where the shells are a quadrature
        shell_extrapolation = bool(not isinstance(spectrum, DiscreteSpectrum) and n_shells is None)
    chosen = _check_fv_options(backend, options)
    grading, kappa, lam = shell_grading(spectrum, E_star=E, zeta=z, mean_pressure=p0, closure=closure) \
        if shell_extrapolation else ("uniform", None, None)
    shells = cached_shells(spectrum, E, EXTRAPOLATION_SHELLS if shell_extrapolation and n_shells is None
                           else n_shells, grading)
    problem = closure_problem(shells, zeta=z, E_star=E, mean_pressure=p0, closure=closure)
    if closure in BALANCED and z > 0:
        # part of the closure's definition, not an accuracy knob: its drift cancels the Ito drift of
        # ln p below p* = zeta q_min E*/2, so mass returns from deep below p*; resolve down to
        # BALANCED_FLOOR p* (docs/closures.md), as the reference solver does
        options.setdefault("p_floor", BALANCED_FLOOR * 0.5 * z * E * shells.q_min)
    if shell_extrapolation:
        if shells.exact:
            raise ValueError("shell_extrapolation applies to continuum spectra; a DiscreteSpectrum's shells are its "
                             "own modes (exact)")
        if shells.q.size % 4:
            raise ValueError(f"shell_extrapolation needs n_shells divisible by 4 (n, n/2, n/4 shells); got "
                             f"n_shells={shells.q.size}")
    scene = (spectrum, E, p0, z, closure, grading)
    note = {"backend_requested": backend}
    sol = solve_shells(problem, shells, closure, chosen, rtol, options, keep=shell_extrapolation,
                       note=note)
    if not shell_extrapolation:
        return sol.result
    first = int(shells.q.size)
    tightened = False  # the first solve was repeated on tighter grids (once at most)
    spent = 0.0  # the discarded attempts' time (a retry on tighter grids, a restart from twice the shells)
    while True:
        out = shell_extrapolated(sol, scene, rtol, options)
        n = int(sol.result.diagnostics["n_shells"])
        if (not out.success and not tightened and out.diagnostics.get("shell_extrapolation")
                and out.diagnostics.get("grid_estimate", 0.0) >= SHELL_SHARE * rtol):
            # the grids' share left no room for the shells' residual: once more on the finer grids of a tighter
            # first solve
            tightened = True
            spent += out.wall_time
            sol = solve_shells(problem, shells, closure, chosen, GRID_RETRY_FRACTION * rtol, options, keep=True,
                               note={**note, "grids_tightened": f"the grids' estimate "
                                     f"{out.diagnostics['grid_estimate']:.2e} left no room for the shells' residual "
                                     f"at rtol {rtol:.1e}"})
            continue
        if "shell_extrapolation_failed" not in out.diagnostics or 2 * n > MAX_CONTINUUM_SHELLS:
            out = replace(out, diagnostics={**out.diagnostics, "shell_grading": grading, "wall_layer_ratio": kappa,
                                            "start_layer_ratio": lam})
            return out if spent == 0.0 else replace(out, wall_time=out.wall_time + spent)
        # a coarser-shell problem did not solve on these grids (wide shells on a steep spectrum at a small load):
        # all three with twice the shells, on the grids of the finer first solve
        spent += out.wall_time
        problem, shells = shell_problem(scene, 2 * n)
        sol = solve_shells(problem, shells, closure, chosen, rtol, options, keep=True,
                           note={**note, "shells_first_tried": first})
