"""The native backend: the shared finite-volume engine with its own operator.

Autonomous problems (``D(p, eta) = D(eta) f(p)``) are one matrix exponential
of the tridiagonal finite-volume operator applied to the start, computed by
CRAM-16 (:mod:`diffusion_pr.solvers.fv.cram`: eight complex tridiagonal
solves); staged and ``tau``-dependent problems by one exponential per stage
or midpoint segment (a balance multiplier by substeps with a Newton step on
``A``).  Three nested grids give a Richardson-extrapolated answer and an
error estimate of it (:mod:`diffusion_pr.solvers.fv.engine`).  No JIT: scipy's
LAPACK tridiagonal solver, so the first solve in a fresh process costs no
compilation.
"""
from __future__ import annotations

from typing import Optional

from ..result import PressureDistribution
from .fv.engine import MAX_CELLS, native_assemble, solve_fv

__all__ = ["solve", "warm_up"]


def warm_up() -> float:
    """Nothing to compile (LAPACK through scipy); returns 0.0 seconds.

    Kept so every backend has the same visible ``warm_up()``.
    """
    return 0.0


def solve(problem, *, rtol: float = 1e-6, n_cells: Optional[int] = None, max_cells: int = MAX_CELLS,
          p_floor: Optional[float] = None) -> PressureDistribution:
    """Solve a :class:`~diffusion_pr.problem.FokkerPlanckProblem` or :class:`~diffusion_pr.problem.StagedProblem`.

    Parameters
    ----------
    problem : FokkerPlanckProblem or StagedProblem
    rtol : float
        Target L1 error of ``Pr`` (density integral plus zero weight); the
        caller (:func:`diffusion_pr.solve_problem`) validates it.
    n_cells : int, optional
        Cells of the coarsest of the three nested grids (no refinement loop);
        integer >= 8.
    max_cells : int
        Cap on the cells of the finest grid.
    p_floor : float, optional
        Floor (pressure) where the wall is not reached (default ``1e-6 p0``).
    """
    return solve_fv(problem, rtol=rtol, backend="native", assemble=native_assemble, n_cells=n_cells,
                    max_cells=max_cells, p_floor=p_floor, time_integration="cram16")
