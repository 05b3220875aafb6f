"""The native backend: the shared finite-volume engine with its own operator.

Autonomous problems (``D(p, eta) = D(eta) f(p)``) are one CRAM-16 exponential of the tridiagonal operator
(:mod:`~diffusion_pr.fokker_planck.expm`, SciPy's LAPACK, no compilation).  Staged problems apply one
exponential per stage, a balance by Newton steps; from four stages on (or with a balance) they run in the numba
kernels of :mod:`~diffusion_pr.fokker_planck._kernels` (compiled on first use and cached on disk;
:func:`warm_up`).  Nested grids and Richardson extrapolation: :mod:`~diffusion_pr.fokker_planck.engine`.
"""
from __future__ import annotations

import time
from typing import Optional

from ...result import PressureDistribution
from ..engine import MAX_CELLS, FVSolution, solve_fv, solve_fv_full
from ..stages import native_assemble

__all__ = ["solve", "solve_full", "warm_up"]


def warm_up() -> float:
    """Compile or load from numba's cache the staged kernels; return the seconds spent.

    Single-stage problems (the paper's theory) need no warm-up.
    """
    from ...problem import Stage, StagedProblem

    t0 = time.perf_counter()
    stages = []
    for q in (1.0, 2.0, 4.0, 8.0):
        stages.append(Stage(1e-4, lambda p, c=0.002 * q: (p / (p + c)) ** 2,
                            drift=lambda p, c=0.002 * q: p / (p + c) ** 2,
                            balance=lambda p: p * 0.002 / (p + 0.002)))
    solve_fv(StagedProblem(0.004, tuple(stages), balance_per_stage=True), rtol=1e-3, backend="native",
             assemble=native_assemble, n_cells=48)  # on 16 cells its drift is unstable, which the engine refuses
    return time.perf_counter() - t0


def solve(problem, *, rtol: float = 1e-6, n_cells: Optional[int] = None, max_cells: int = MAX_CELLS,
          p_floor: Optional[float] = None) -> PressureDistribution:
    """Solve a :class:`~diffusion_pr.problem.FokkerPlanckProblem` or :class:`~diffusion_pr.problem.StagedProblem`.

    Parameters
    ----------
    problem : FokkerPlanckProblem or StagedProblem
    rtol : float
        Target L1 error of ``Pr`` (density integral plus zero weight).
    n_cells : int, optional
        Cells of the coarsest of the three nested grids (no refinement); >= 8.
    max_cells : int
        Cap on the cells of the finest grid.
    p_floor : float, optional
        Floor (pressure) where the wall is not reached (default ``1e-6 p0``).
    """
    return solve_full(problem, rtol=rtol, n_cells=n_cells, max_cells=max_cells, p_floor=p_floor).result


def solve_full(problem, *, rtol: float = 1e-6, n_cells: Optional[int] = None, max_cells: int = MAX_CELLS,
               p_floor: Optional[float] = None, **engine) -> FVSolution:
    """:func:`solve` with the engine's :class:`~diffusion_pr.fokker_planck.engine.FVSolution` (``engine``: ``grid`` and ``plain``
    of :func:`~diffusion_pr.fokker_planck.engine.solve_fv_full`)."""
    return solve_fv_full(problem, rtol=rtol, backend="native", assemble=native_assemble, n_cells=n_cells,
                         max_cells=max_cells, p_floor=p_floor, **engine)
