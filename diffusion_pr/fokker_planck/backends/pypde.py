"""py-pde backend (name ``"pypde"``): the operator written with py-pde's own Laplacian and gradient.

On the cell index of the engine's grid, with ``v = f m / h`` and ``K = 1/h`` (docs/backends.md)::

    dm/dtau = (laplace(K v) - v laplace(K) + K laplace(v)) / 2  -  gradient(a m / h)

The tridiagonal matrix is read off with three probes and integrated by CRAM-16 on the engine's nested grids.
"""
from __future__ import annotations

import time
from typing import Optional

import numpy as np

from ...result import PressureDistribution
from . import timed_import
from ..engine import MAX_CELLS, FVSolution, solve_fv_full
from ..operator import probe_bands, state_bands, wall_drift

__all__ = ["solve", "warm_up", "assemble"]

_WALL = {"x-": {"value": 0.0}, "x+": {"derivative": 0.0}}
_NEUMANN = {"x-": {"derivative": 0.0}, "x+": {"derivative": 0.0}}
_ZERO = {"x-": {"value": 0.0}, "x+": {"value": 0.0}}


class _Operators:
    """py-pde's Laplacian and gradient on the index grid of ``n`` cells (built per grid size)."""

    def __init__(self, n: int) -> None:
        import pde

        self.grid = pde.CartesianGrid([[0.0, float(n)]], n)
        self.lap_wall = self.grid.make_operator("laplace", bc=_WALL, backend="scipy")
        self.lap_neumann = self.grid.make_operator("laplace", bc=_NEUMANN, backend="scipy")
        self.grad_zero = self.grid.make_operator("gradient", bc=_ZERO, backend="scipy")

    def rate(self, m: np.ndarray, f_c: np.ndarray, h: np.ndarray, a_c: Optional[np.ndarray]) -> np.ndarray:
        """``dm/dtau`` of py-pde's operator (see the module docstring)."""
        k = 1.0 / h
        v = f_c * m / h
        out = 0.5 * (self.lap_wall(k * v) - v * self.lap_neumann(k) + k * self.lap_wall(v))
        if a_c is not None:
            out = out - np.asarray(self.grad_zero(a_c * m / h)).reshape(out.shape)
        return np.asarray(out, dtype=float)


_OPS: dict = {}


def _ops(n: int) -> _Operators:
    # a cache of immutable operator objects keyed by grid size (not results): bounded
    if n not in _OPS:
        if len(_OPS) > 64:
            _OPS.clear()
        _OPS[n] = _Operators(n)
    return _OPS[n]


def assemble(edges: np.ndarray, f_c: np.ndarray, a_faces: Optional[np.ndarray],
             a_centres: Optional[np.ndarray] = None) -> tuple:
    """py-pde's operator on the engine's state ``[z, m_0..m_{n-1}]`` (tridiagonal, read by 3 probes)."""
    h = np.diff(edges)
    ops = _ops(h.size)
    lo, dg, up = state_bands(*probe_bands(lambda m: ops.rate(m, f_c, h, a_centres), h.size))
    if a_faces is not None:  # py-pde's drift carries nothing through the wall: the wall's drift flux (its physics)
        wall_drift(dg, up, up[0], a_faces[0], h[0], edges[0])
    return lo, dg, up


def warm_up() -> float:
    """Import py-pde and build one operator set; return the seconds spent."""
    t0 = time.perf_counter()
    timed_import("pde", "pypde", "py-pde")
    assemble(np.linspace(0.0, 1.0, 9), np.ones(8), None)
    return time.perf_counter() - t0


def solve(problem, *, rtol: float = 1e-6, n_cells: Optional[int] = None, max_cells: int = MAX_CELLS,
          p_floor: Optional[float] = None) -> PressureDistribution:
    """Solve with py-pde's operators (see the module docstring); the options as for
    :func:`~diffusion_pr.fokker_planck.backends.native.solve`.  ``BackendUnavailableError`` without py-pde."""
    return solve_full(problem, rtol=rtol, n_cells=n_cells, max_cells=max_cells, p_floor=p_floor).result


def solve_full(problem, *, rtol: float = 1e-6, n_cells: Optional[int] = None, max_cells: int = MAX_CELLS,
               p_floor: Optional[float] = None, **engine) -> FVSolution:
    """:func:`solve` with the engine's :class:`~diffusion_pr.fokker_planck.engine.FVSolution` (``engine``: ``grid``,
    ``plain`` of :func:`~diffusion_pr.fokker_planck.engine.solve_fv_full`)."""
    _, import_time = timed_import("pde", "pypde", "py-pde")
    return solve_fv_full(problem, rtol=rtol, backend="pypde", assemble=assemble, n_cells=n_cells,
                         max_cells=max_cells, p_floor=p_floor, extra={"import_time": import_time}, **engine)
