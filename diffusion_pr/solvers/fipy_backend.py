"""FiPy backend for the Fokker-Planck problem (backend name ``"fipy"``).

The Ito equation of :mod:`diffusion_pr.problem` is expanded the way FiPy can
express it,

    dP/dtau = d^2(f P)/dp^2 - d(a P)/dp
            = d/dp( f dP/dp ) + d/dp( f' P ) - d/dp( a P ),

and written term by term on a (non-uniform) :class:`fipy.Grid1D` from
:func:`diffusion_pr.solvers._common.domain_edges`::

    TransientTerm() == DiffusionTerm(coeff=f_face)
                       + CentralDifferenceConvectionTerm(coeff=[f'_face])
                       - CentralDifferenceConvectionTerm(coeff=[a_face])

with the face values chosen so that the discrete flux is *exactly* the
conservative Ito flux of the other backends, ``J = -(f_{i+1} P_{i+1} - f_i
P_i) / d_i`` (``d_i`` the distance between cell centres):
``f_face = (f_i + f_{i+1}) / 2`` and ``f'_face = (f_{i+1} - f_i) / d_i`` with
``f`` sampled at the cell centres (FiPy's central-difference face value is the
arithmetic mean ``(P_i + P_{i+1})/2`` on any grid).  Because ``f'`` is a
difference quotient of cell values, a jump of ``f`` (the literal seed cutoff
at ``p_c``, which ``_common`` puts on a cell edge) is handled exactly like in
the ``Q = f P`` form: ``f P`` stays continuous, ``P`` jumps by ``f_-/f_+``; no
``delta`` in ``f'`` is ever needed.  Unlike the ``Q``-form
``TransientTerm(1/f, var=Q)`` this also works where ``f = 0`` in a cell.

Boundaries: ``P`` is constrained to 0 on the left face (``p = 0``) with the
face diffusivity set to the first cell's ``f_0``, giving the absorbing Ito
flux ``f_0 P_0 / (h_0 / 2)`` out of the domain; the right face has FiPy's
default zero flux (and zero convection coefficient).

Time stepping: Crank-Nicolson by hand as a backward-Euler half step followed
by extrapolation, ``P* = (1 - dt/2 L)^-1 P^n``, ``P^{n+1} = 2 P* - P^n``
(algebraically identical to CN).  For autonomous problems FiPy assembles the
operator once and the steps are banded solves (``assemble_once=True``, the
default); otherwise, and with ``assemble_once=False``, every half step is
``eq.solve`` with FiPy's sparse LU (about 6 ms each, mostly FiPy rebuilding
its matrix; the two paths agree to 1e-14).  The steps
are uniform in ``sqrt(tau)`` from the short-time start ``tau0`` (dense early,
where the peak is narrow); the first ``max(4, sqrt(steps))`` steps are each
replaced by two backward-Euler half steps (Rannacher start,
:func:`rannacher_steps`) to damp CN's undamped stiff modes.

The absorbed mass is the time-integrated boundary flux,
``zero_weight = zero_weight0 + sum_n dt f_0 P*_0 / (h_0/2)`` (``P*`` the
half-step value, i.e. the trapezoidal average of ``P^n`` and ``P^{n+1}``);
``1 - mass - zero_weight`` is reported as ``diagnostics["mass_defect"]``
(round-off: the interior fluxes telescope).

The error estimate solves nested pairs like the native backend (a fresh
``domain_edges(2n)`` grid with ``2K`` steps and its every-other-edge
coarsening with ``K`` steps), doubling ``n`` and ``K`` until the estimate
meets ``rtol``; the L1 metric and Richardson rule are those of the py-pde
backend (:func:`diffusion_pr.solvers.pypde_backend.level_difference`,
``_richardson``: observed order from successive pairs, at most 2, at most 1
for wall-avoiding cutoffs).
"""
from __future__ import annotations

import math
import time
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from ..problem import FokkerPlanckProblem
from ..result import PressureDistribution
from ._results import finite_volume_result
from . import BackendUnavailableError, timed_import  # noqa: F401 (documented raise)
from .pypde_backend import _richardson, error_metric_name, level_difference, lump_pressure

Array = NDArray[np.float64]

__all__ = ["solve", "steps_for", "initial_cells", "rannacher_steps"]

#: refinement stops before more cells / steps than this: (assembled once, FiPy loop)
DEFAULT_MAX_CELLS = (2**15, 8192)
DEFAULT_MAX_STEPS = (2**15, 1600)  # the FiPy loop costs ~6 ms per step regardless of size

_STATE: dict[str, Any] = {"warm": False}


def _import_fipy() -> tuple[Any, float]:
    """Import FiPy (lazily, about 1 s); return ``(module, seconds or 0 if cached)``."""
    return timed_import("fipy", "fipy", "FiPy")


def steps_for(rtol: float, n_cells: int) -> int:
    """Default number of CN steps for a first level (dimensionless).

    The CN error in steps uniform in ``sqrt(tau)`` is second order like the
    spatial one; ``n_cells / 2`` steps (at least 16) balances the two on the
    stretched grids of ``_common`` (mirror Gaussian, measured: with
    ``n_cells / 4`` the time error dominates and the observed order drops to
    1.5 on coarse grids; with ``n_cells / 2`` it is 2.0 from 48 cells on).
    """
    return int(max(16, math.ceil(n_cells / 2)))


def initial_cells(rtol: float) -> int:
    """Cells of the first level for a requested ``rtol`` (even, 32 ... 4096).

    On ``_common``'s stretched grid with ``n/2`` CN steps the measured L1 error
    is ``K / n^2`` with ``K`` about 1 (mirror Gaussian), 3.4 (Fig. 1 scene,
    seed cutoff) and 5 (Feller, ``p1 = p0``); ``n0 = 1.5 / sqrt(rtol)`` makes
    the second level (``2 n0``, the one returned) meet ``rtol`` for
    ``K <= 9`` without a third level, independently of ``p_max`` (which is
    large for diffusivities growing with ``p``).
    """
    n0 = int(math.ceil(1.5 / math.sqrt(rtol)))
    return int(np.clip(n0 + n0 % 2, 32, 4096))


def _face_coefficients(f: Array, x: Array, a_face: Optional[Array]) -> tuple[Array, Array]:
    """Face diffusivity and convection velocity reproducing the Ito flux.

    Returns ``(gamma, velocity)`` on the ``n + 1`` faces: ``gamma`` = mean of
    the neighbouring ``f`` (left wall: ``f_0``; right wall: ``f_{n-1}``, unused
    under zero flux) and ``velocity = f'_face - a_face`` (0 on both walls).
    """
    n = f.size
    gamma = np.empty(n + 1)
    gamma[1:-1] = 0.5 * (f[:-1] + f[1:])
    gamma[0] = f[0]
    gamma[-1] = f[-1]
    vel = np.zeros(n + 1)
    vel[1:-1] = np.diff(f) / np.diff(x)
    if a_face is not None:
        vel[1:-1] -= a_face[1:-1]
    return gamma, vel


def _assembled_bands(eq: Any, var: Any, h: Array) -> tuple[Array, Array]:
    """The operator ``L`` (``dP/dtau = L P + s``) as FiPy assembles it, in banded form.

    FiPy builds ``M P_new = b`` with ``M = diag(h/dt) - h L`` and
    ``b = (h/dt) P_old + h s`` for ``TransientTerm() == (terms)``; one sweep
    with ``dt = 1`` (the variable is restored afterwards) gives ``L`` and the
    boundary source ``s`` (0 for the homogeneous constraint used here).
    Returns ``(ab, s)`` with ``ab`` the 3 x n banded matrix of ``L``
    (scipy ``solve_banded`` layout: upper, main, lower diagonal).
    """
    saved = np.array(var.value, dtype=float)
    eq.cacheMatrix()
    eq.cacheRHSvector()
    eq.sweep(var=var, dt=1.0)
    mat = eq.matrix.matrix.tocsr()
    rhs = np.asarray(eq.RHSvector, dtype=float)
    var.setValue(saved)
    n = h.size
    ab = np.zeros((3, n))
    ab[0, 1:] = -mat.diagonal(1) / h[:-1]
    ab[1, :] = (h - mat.diagonal(0)) / h
    ab[2, :-1] = -mat.diagonal(-1) / h[1:]
    source = (rhs - h * saved) / h
    coo = mat.tocoo()
    if np.any((np.abs(coo.row - coo.col) > 1) & (coo.data != 0.0)):
        raise RuntimeError("FiPy assembled a non-tridiagonal operator; use assemble_once=False")
    return ab, source


def rannacher_steps(n_steps: int) -> int:
    """CN steps replaced by two backward-Euler half steps each at the start: ``max(4, ceil(sqrt(n_steps)))``.

    CN does not damp stiff modes.  When ``p0`` is tiny compared with
    ``sqrt(V)`` (the delta starts next to the absorbing wall, on cells of
    ``1e-5 sqrt(V)``) the usual single Rannacher step leaves oscillations
    that end as negative densities of order 1 (measured at ``p0/sqrt(V) =
    1e-3``: min density -8, L1 error 1e-2).  ``sqrt(n_steps)`` damped steps
    cover ``tau < tau_end / n_steps`` of the ``sqrt(tau)``-uniform schedule, so
    their first-order error stays below the second-order CN error: measured
    orders 1.8-2.2 for ``p0/sqrt(V)`` = 1e-3, 0.1 and 1, all densities positive.
    """
    return int(max(4, math.ceil(math.sqrt(max(int(n_steps), 1)))))


def _solve_on_edges(fipy: Any, problem: FokkerPlanckProblem, edges: Array, n_steps: int,
                    assemble_once: bool = True, n_rannacher: Optional[int] = None) -> dict[str, Any]:
    """One FiPy Crank-Nicolson run on ``edges`` with ``n_steps`` steps; no refinement.

    ``assemble_once`` (autonomous problems only): FiPy assembles the operator
    once (:func:`_assembled_bands`) and the same Crank-Nicolson / Rannacher
    steps are done with ``scipy.linalg.solve_banded``, avoiding FiPy's
    per-solve matrix rebuild (~6 ms per step).  Otherwise every half step is
    ``eq.solve(var, dt, solver=LinearLUSolver())``.
    """
    from fipy import CellVariable, CentralDifferenceConvectionTerm, DiffusionTerm, FaceVariable, Grid1D, TransientTerm
    from fipy.solvers.scipy import LinearLUSolver

    from ._common import short_time_start

    h = np.diff(edges)
    x = 0.5 * (edges[:-1] + edges[1:])
    tau0, dens0, zw0 = short_time_start(problem, edges)
    dens0 = np.asarray(dens0, dtype=float)
    mesh = Grid1D(dx=h)
    var = CellVariable(mesh=mesh, value=dens0.copy(), name="P")
    var.constrain(0.0, mesh.facesLeft)
    has_drift = problem.drift is not None
    faces = np.asarray(mesh.faceCenters.value[0], dtype=float)

    def coefficients(tau: float) -> tuple[Array, Array]:
        f = problem.f(x, tau)
        a_face = problem.a(faces, tau) if has_drift else None
        return _face_coefficients(f, x, a_face)

    gamma, vel = coefficients(tau0)
    gamma_var = FaceVariable(mesh=mesh, value=gamma)
    vel_var = FaceVariable(mesh=mesh, rank=1, value=vel[None, :])
    # d/dtau P = d/dp(f dP/dp) + d/dp((f' - a) P)   (= d^2(fP)/dp^2 - d(aP)/dp)
    eq = TransientTerm() == DiffusionTerm(coeff=gamma_var) + CentralDifferenceConvectionTerm(coeff=vel_var)
    solver = LinearLUSolver()
    static = problem.autonomous

    use_bands = bool(assemble_once) and static
    if n_rannacher is None:
        n_rannacher = rannacher_steps(n_steps)
    if use_bands:
        bands, source = _assembled_bands(eq, var, h)
    s = np.linspace(math.sqrt(tau0), math.sqrt(problem.tau_end), int(n_steps) + 1)
    taus = s * s
    taus[0], taus[-1] = tau0, problem.tau_end
    absorbed = 0.0
    t0 = time.perf_counter()
    error = None
    solves = 0
    try:
        if tau0 < problem.tau_end and use_bands:
            from scipy.linalg import solve_banded

            wall = float(gamma[0]) / (0.5 * h[0])
            dens = np.array(var.value, dtype=float)
            for k in range(int(n_steps)):
                dt = float(taus[k + 1] - taus[k])
                system = -0.5 * dt * bands
                system[1] += 1.0  # I - (dt/2) L
                if k < n_rannacher:  # Rannacher start: two backward-Euler half steps per step
                    for _sub in range(2):
                        dens = solve_banded((1, 1), system, dens + 0.5 * dt * source, check_finite=False)
                        absorbed += 0.5 * dt * wall * dens[0]
                        solves += 1
                    continue
                half = solve_banded((1, 1), system, dens + 0.5 * dt * source, check_finite=False)
                solves += 1
                absorbed += dt * wall * half[0]
                dens = 2.0 * half - dens
            var.setValue(dens)
        elif tau0 < problem.tau_end:
            for k in range(int(n_steps)):
                t_a, t_b = float(taus[k]), float(taus[k + 1])
                dt = t_b - t_a
                if k < n_rannacher:  # Rannacher start: two backward-Euler half steps per step
                    for sub in range(2):
                        if not static:
                            g, v = coefficients(t_a + (sub + 0.5) * 0.5 * dt)
                            gamma_var.setValue(g)
                            vel_var.setValue(v[None, :])
                        eq.solve(var=var, dt=0.5 * dt, solver=solver)
                        solves += 1
                        absorbed += 0.5 * dt * float(gamma_var.value[0]) * float(var.value[0]) / (0.5 * h[0])
                    continue
                if not static:  # implicit midpoint: coefficients at the step's centre
                    g, v = coefficients(0.5 * (t_a + t_b))
                    gamma_var.setValue(g)
                    vel_var.setValue(v[None, :])
                old = np.array(var.value, dtype=float)
                eq.solve(var=var, dt=0.5 * dt, solver=solver)  # P* = P^{n+1/2}
                solves += 1
                half = np.array(var.value, dtype=float)
                absorbed += dt * float(gamma_var.value[0]) * half[0] / (0.5 * h[0])
                var.setValue(2.0 * half - old)
    except Exception as exc:  # reported, not raised
        error = f"{type(exc).__name__}: {exc}"
    elapsed = time.perf_counter() - t0
    dens = np.array(var.value, dtype=float)
    if not np.all(np.isfinite(dens)):
        error = error or "non-finite density"
    mass = float(np.sum(h * dens))
    return {
        "edges": edges,
        "density": dens,
        "zero_weight": float(zw0) + absorbed,
        "zero_weight0": float(zw0),
        "mass_defect": 1.0 - mass - float(zw0) - absorbed,
        "tau0": float(tau0),
        "steps": int(n_steps),
        "rannacher_steps": int(n_rannacher),
        "linear_solves": solves,
        "stepping": "FiPy-assembled operator, banded CN solves" if use_bands else "FiPy eq.solve per half step",
        "time": elapsed,
        "error": error,
    }


def _warm_up(fipy: Any) -> float:
    """One tiny run so FiPy's lazy imports / solver set-up are not billed to ``wall_time``."""
    if _STATE["warm"]:
        return 0.0
    t0 = time.perf_counter()
    _solve_on_edges(fipy, FokkerPlanckProblem(1.0, 0.1), np.linspace(0.0, 3.0, 17), 3, False)
    _solve_on_edges(fipy, FokkerPlanckProblem(1.0, 0.1), np.linspace(0.0, 3.0, 17), 3, True)
    _STATE["warm"] = True
    return time.perf_counter() - t0


def solve(
    problem: FokkerPlanckProblem,
    *,
    rtol: float = 1e-4,
    n_cells: Optional[int] = None,
    n_steps: Optional[int] = None,
    max_cells: Optional[int] = None,
    max_steps: Optional[int] = None,
    refine: bool = True,
    uniform: bool = False,
    assemble_once: bool = True,
    **options: Any,
) -> PressureDistribution:
    """Solve the Fokker-Planck problem with FiPy (Crank-Nicolson, sparse LU).

    Parameters
    ----------
    problem : FokkerPlanckProblem
        The problem in diffusion time ``tau`` (pressure squared), from
        ``delta(p - p0)`` to ``tau_end = V/2``.
    rtol : float
        Target L1 error of the density plus that of ``zero_weight``
        (dimensionless); also the tolerance for mass and mean conservation.
    n_cells, n_steps : int, optional
        First (coarsest) grid size and number of CN steps; from ``rtol`` if
        omitted (:func:`initial_cells`, :func:`steps_for`).
    max_cells, max_steps : int, optional
        Refinement stops (``success=False``) before exceeding these; default
        32768 / 32768 with ``assemble_once`` on an autonomous problem, else
        8192 / 1600 (the FiPy loop's ~6 ms per step).
    refine : bool
        If False, one run on ``(n_cells, n_steps)`` without an error estimate.
    uniform : bool
        Uniform cells instead of ``_common``'s stretched grid.
    assemble_once : bool
        For autonomous problems (no drift, ``f`` independent of ``tau``): let
        FiPy assemble the operator once and do the identical CN steps with a
        banded solve (about 100x faster than FiPy's own per-step rebuild;
        same numbers to round-off).  False: every step through
        ``eq.solve`` (the pure-FiPy loop).  Ignored for non-autonomous
        problems (always the FiPy loop).
    **options
        ``edges_kwargs``: extra keywords for ``_common.domain_edges``.

    Returns
    -------
    PressureDistribution
        On the finest level run (cell centres, cell averages, cell widths),
        ``zero_weight`` = the time-integrated absorbing-boundary flux.

    Raises
    ------
    BackendUnavailableError
        FiPy is not installed.
    """
    if not isinstance(problem, FokkerPlanckProblem):
        raise ValueError(f"problem must be a FokkerPlanckProblem; got {type(problem).__name__}")
    rtol = float(rtol)
    if not (np.isfinite(rtol) and 0.0 < rtol < 1.0):
        raise ValueError(f"rtol must be a number in (0, 1); got rtol={rtol!r}")
    unknown = set(options) - {"edges_kwargs"}
    if unknown:
        raise TypeError(f"unknown option(s) for the fipy backend: {sorted(unknown)}")
    fipy, import_time = _import_fipy()
    warm_time = _warm_up(fipy)
    from ._common import domain_edges

    t_start = time.perf_counter()
    edges_kwargs = dict(options.get("edges_kwargs", {}))
    if n_cells is None:
        n0 = initial_cells(rtol)
    else:
        n0 = int(n_cells)
    s0 = int(n_steps) if n_steps is not None else steps_for(rtol, n0)
    mode = 0 if (assemble_once and problem.autonomous) else 1
    max_cells = int(max_cells) if max_cells is not None else DEFAULT_MAX_CELLS[mode]
    max_steps = int(max_steps) if max_steps is not None else DEFAULT_MAX_STEPS[mode]
    p_lump = lump_pressure(problem)

    def grid(n: int) -> Array:
        return np.asarray(domain_edges(problem, n, rtol=rtol, uniform=uniform, align=2, **edges_kwargs), dtype=float)

    estimate = float("nan")
    diffs: list[float] = []
    orders: list[float] = []
    history: list[tuple[int, int, float]] = []
    levels: list[dict[str, Any]] = []
    if not refine:
        best = _solve_on_edges(fipy, problem, grid(n0), s0, assemble_once)
        levels.append(best)
    else:
        # nested pairs as in the native backend: the fine grid is built fresh
        # (so its cells next to p = 0 are graded like any grid of that size)
        # and the coarse one is every other edge of it
        n_fine, k_fine = 2 * (n0 + n0 % 2), 2 * s0
        while True:
            fine_edges = grid(n_fine)
            coarse = _solve_on_edges(fipy, problem, fine_edges[::2], k_fine // 2, assemble_once)
            fine = _solve_on_edges(fipy, problem, fine_edges, k_fine, assemble_once)
            levels += [coarse, fine]
            best = fine
            if coarse["error"] is not None or fine["error"] is not None:
                best = fine if fine["error"] is not None else coarse
                break
            diff = level_difference(coarse, fine, p_lump)
            estimate, order = _richardson(diff, diffs[-1] if diffs else None, 2.0 if p_lump == 0.0 else 1.0)
            diffs.append(diff)
            orders.append(order)
            history.append((n_fine, k_fine, estimate))
            if estimate <= rtol or 2 * n_fine > max_cells or 2 * k_fine > max_steps:
                break
            n_fine, k_fine = 2 * n_fine, 2 * k_fine
    wall = time.perf_counter() - t_start
    return _result(problem, best, rtol=rtol, estimate=estimate, refine=refine, wall=wall, levels=levels,
                   history=history, orders=orders, import_time=import_time, warm_time=warm_time,
                   p_lump=p_lump, limits=(max_cells, max_steps))


def _result(problem: FokkerPlanckProblem, best: dict[str, Any], *, rtol: float, estimate: float, refine: bool,
            wall: float, levels: list, history: list, orders: list, import_time: float, warm_time: float,
            p_lump: float, limits: tuple[int, int]) -> PressureDistribution:
    edges = best["edges"]
    diagnostics = {
        "cells": int(edges.size - 1),
        "steps": int(best["steps"]),
        "linear_solves": int(best["linear_solves"]),
        "levels": [(int(lv["edges"].size - 1), int(lv["steps"])) for lv in levels],
        "level_times": [float(lv["time"]) for lv in levels],
        "estimate_history": history,
        "observed_orders": orders,
        "error_metric": error_metric_name(p_lump),
        "tau0": best["tau0"],
        "zero_weight0": best["zero_weight0"],
        "zero_weight_accounting": "short-time start's weight + time-integrated absorbing-boundary flux",
        "mass_defect": best["mass_defect"],
        "import_time": import_time,
        "first_call_time": warm_time,
        "time_stepping": "Crank-Nicolson (BE half step + extrapolation), Rannacher start, steps uniform in sqrt(tau)",
        "rannacher_steps": best.get("rannacher_steps"),
        "stepping": best.get("stepping"),
    }
    return finite_volume_result(
        problem, backend="fipy", edges=edges, density=best["density"], zero_weight=best["zero_weight"], rtol=rtol,
        estimate=estimate, refine=refine, wall_time=wall, work=f"{edges.size - 1} cells, {best['steps']} CN steps",
        failure=best["error"], budget=f"max_cells={limits[0]}, max_steps={limits[1]}", diagnostics=diagnostics)
