"""FiPy backend (name ``"fipy"``): the equation written in FiPy's terms, on the engine's grid.

The Ito equation ``dP/dtau = d^2(f P)/dp^2 - d(a P)/dp`` expanded the way FiPy
expresses it, ``d/dp(f dP/dp) + d/dp((f' - a) P)``::

    TransientTerm() == DiffusionTerm(coeff=f_face) + CentralDifferenceConvectionTerm(coeff=[f'_face - a_face])

on a non-uniform :class:`fipy.Grid1D` with the engine's cells, ``P = 0`` on the wall face (docs/backends.md):
the native operator to round-off, except where that leans a user's drift upwind.

One ``sweep`` with ``dt = 1`` gives the matrix, integrated by CRAM-16 on the engine's nested grids.
"""
from __future__ import annotations

import time
from typing import Optional

import numpy as np

from ...result import PressureDistribution
from . import timed_import
from ..engine import MAX_CELLS, FVSolution, solve_fv_full
from ..operator import centres, state_bands, wall_drift_rate

__all__ = ["solve", "warm_up", "assemble"]

def _terms(edges: np.ndarray, f_c: np.ndarray, a_faces: Optional[np.ndarray]):
    """FiPy's equation, its variable and the cell widths."""
    from fipy import CellVariable, CentralDifferenceConvectionTerm, DiffusionTerm, FaceVariable, Grid1D, TransientTerm

    h = np.diff(edges)
    c = centres(edges)
    n = h.size
    mesh = Grid1D(dx=h)
    var = CellVariable(mesh=mesh, value=np.zeros(n), name="P")
    var.constrain(0.0, mesh.facesLeft)
    gamma = np.empty(n + 1)
    gamma[1:-1] = 0.5 * (f_c[:-1] + f_c[1:])
    gamma[0], gamma[-1] = f_c[0], f_c[-1]
    vel = np.zeros(n + 1)
    vel[1:-1] = np.diff(f_c) / np.diff(c)
    if a_faces is not None:
        vel[1:-1] -= a_faces[1:]
        # the constrained wall face carries no convection: its net outflow rides on the transfer gamma_0 P_0 / (h_0/2)
        out = gamma[0] / (0.5 * h[0] * h[0])
        net = out - float(wall_drift_rate(out, a_faces[0], h[0], edges[0]))
        gamma[0] = max(net, 0.0) * 0.5 * h[0] * h[0]
    eq = (TransientTerm() == DiffusionTerm(coeff=FaceVariable(mesh=mesh, value=gamma))
          + CentralDifferenceConvectionTerm(coeff=FaceVariable(mesh=mesh, rank=1, value=vel[None, :])))
    return eq, var, h


def assemble(edges: np.ndarray, f_c: np.ndarray, a_faces: Optional[np.ndarray],
             a_centres: Optional[np.ndarray] = None) -> tuple:
    """The operator as FiPy assembles it, on the engine's state ``[z, m_0..m_{n-1}]``.

    FiPy builds ``M P_new = b`` with ``M = diag(h/dt) - h L``; one sweep with
    ``dt = 1`` gives ``L`` (on densities), converted to masses ``H L H^-1``.
    """
    eq, var, h = _terms(edges, f_c, a_faces)
    eq.cacheMatrix()
    eq.sweep(var=var, dt=1.0)
    mat = eq.matrix.matrix.tocsr()
    coo = mat.tocoo()
    if np.any((np.abs(coo.row - coo.col) > 1) & (coo.data != 0.0)):
        raise RuntimeError("FiPy assembled a non-tridiagonal operator")
    up_u = -mat.diagonal(1) / h[:-1]
    dg_u = (h - mat.diagonal(0)) / h
    lo_u = -mat.diagonal(-1) / h[1:]
    # masses: L_m = H L_u H^-1
    return state_bands(lo_u * h[1:] / h[:-1], dg_u, up_u * h[:-1] / h[1:])


def warm_up() -> float:
    """Import FiPy and assemble one tiny operator; return the seconds spent."""
    t0 = time.perf_counter()
    timed_import("fipy", "fipy", "FiPy")
    e = np.linspace(0.0, 1.0, 9)
    assemble(e, np.ones(8), None)
    return time.perf_counter() - t0


def solve(problem, *, rtol: float = 1e-6, n_cells: Optional[int] = None, max_cells: int = MAX_CELLS,
          p_floor: Optional[float] = None) -> PressureDistribution:
    """Solve with the operator written in FiPy's terms (see the module docstring); the options as for
    :func:`~diffusion_pr.fokker_planck.backends.native.solve`.  ``BackendUnavailableError`` without FiPy."""
    return solve_full(problem, rtol=rtol, n_cells=n_cells, max_cells=max_cells, p_floor=p_floor).result


def solve_full(problem, *, rtol: float = 1e-6, n_cells: Optional[int] = None, max_cells: int = MAX_CELLS,
               p_floor: Optional[float] = None, **engine) -> FVSolution:
    """:func:`solve` with the engine's :class:`~diffusion_pr.fokker_planck.engine.FVSolution` (``engine``: ``grid``,
    ``plain`` of :func:`~diffusion_pr.fokker_planck.engine.solve_fv_full`)."""
    _, import_time = timed_import("fipy", "fipy", "FiPy")
    return solve_fv_full(problem, rtol=rtol, backend="fipy", assemble=assemble, n_cells=n_cells,
                         max_cells=max_cells, p_floor=p_floor, extra={"import_time": import_time}, **engine)
