"""py-pde backend (name ``"pypde"``): the operator written with py-pde's own Laplacian and gradient.

On the cell index of the engine's grid, with ``v = f m / h`` and ``K = 1/h`` (docs/backends.md)::

    dm/dtau = (laplace(K v) - v laplace(K) + K laplace(v)) / 2  -  gradient(a m / h)

``method="cram"`` (default) reads the tridiagonal matrix off with three probes and integrates it by CRAM-16;
``method="loop"`` uses py-pde's ``PDEBase.solve`` (``solve_ivp`` BDF at 1e-3 rtol; slow; no balance).
"""
from __future__ import annotations

import time
from typing import Optional

import numpy as np

from ...result import PressureDistribution
from . import timed_import
from ..domain import Prepared
from ..engine import MAX_CELLS, FVSolution, solve_fv_full
from ..operator import centres, probe_bands, state_bands, wall_drift, wall_drift_rate

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


def _wall_rate(ops: _Operators, f_c: np.ndarray, h: np.ndarray, a_wall: float, p_wall: float) -> float:
    """The wall's drift term of cell 0's rate per unit of ``m_0`` (``wall_drift_rate`` on py-pde's diffusive
    outflow, read off with one probe)."""
    e0 = np.zeros(h.size)
    e0[0] = 1.0
    return float(wall_drift_rate(-float(np.sum(ops.rate(e0, f_c, h, None))), a_wall, h[0], p_wall))


def _loop(prep: Prepared, edges: np.ndarray, n_base: int, refine: int, tol: float) -> tuple[np.ndarray, dict]:
    """py-pde's own time integration (``PDEBase.solve``, scipy solver) on one grid."""
    import pde

    if prep.has_balance:
        raise ValueError("method='loop' cannot hold the mean with a balance multiplier; use method='cram'")
    c = centres(edges)
    h = np.diff(edges)
    n = c.size
    ops = _ops(n)
    m = np.zeros(n)
    j = int(np.searchsorted(edges, prep.p0))
    m[j - 1] = (c[j] - prep.p0) / (c[j] - c[j - 1])
    m[j] = (prep.p0 - c[j - 1]) / (c[j] - c[j - 1])
    pieces = prep.segment_fn(refine * max(4, n_base // 8)) if prep.time_dependent else prep.pieces
    calls = 0
    for pc in pieces:
        f_c = np.maximum(np.asarray(pc.f(c), dtype=float), 0.0)
        a_c = None if pc.b is None else np.asarray(pc.b(c), dtype=float)
        k_wall = 0.0 if pc.b is None else _wall_rate(ops, f_c, h, float(np.asarray(pc.b(edges[:1]))[0]), edges[0])

        class _Piece(pde.PDEBase):  # the piece's equation for py-pde's solver
            def evolution_rate(self, state, t=0.0):
                out = state.copy()
                out.data[...] = ops.rate(state.data, f_c, h, a_c)
                out.data[0] += k_wall * state.data[0]
                return out

        field = pde.ScalarField(ops.grid, m)
        eq = _Piece()
        res = eq.solve(field, t_range=pc.duration, dt=pc.duration / 64, solver="scipy", tracker=None,
                       method="BDF", rtol=tol, atol=tol * 1e-3)
        m = np.array(res.data, dtype=float)
        calls += 1
    return np.r_[1.0 - m.sum(), m], {"cram_applications": 0, "substeps": calls}


def warm_up() -> float:
    """Import py-pde and build one operator set; return the seconds spent."""
    t0 = time.perf_counter()
    timed_import("pde", "pypde", "py-pde")
    assemble(np.linspace(0.0, 1.0, 9), np.ones(8), None)
    return time.perf_counter() - t0


def solve(problem, *, rtol: float = 1e-6, method: str = "cram", n_cells: Optional[int] = None,
          max_cells: int = MAX_CELLS, p_floor: Optional[float] = None) -> PressureDistribution:
    """Solve with py-pde's operators (see the module docstring).

    Parameters
    ----------
    problem : FokkerPlanckProblem or StagedProblem
    method : {"cram", "loop"}
        CRAM-16 on py-pde's operator, or py-pde's own solver loop.
    rtol, n_cells, max_cells, p_floor
        As for :func:`~diffusion_pr.fokker_planck.backends.native.solve`.

    Raises
    ------
    BackendUnavailableError
        py-pde is not installed.
    ValueError
        Unknown ``method``.
    """
    return solve_full(problem, rtol=rtol, method=method, n_cells=n_cells, max_cells=max_cells,
                      p_floor=p_floor).result


def solve_full(problem, *, rtol: float = 1e-6, method: str = "cram", n_cells: Optional[int] = None,
               max_cells: int = MAX_CELLS, p_floor: Optional[float] = None, **engine) -> FVSolution:
    """:func:`solve` with the engine's :class:`~diffusion_pr.fokker_planck.engine.FVSolution` (``engine``: ``grid``, ``plain``,
    ``warm_start`` of :func:`~diffusion_pr.fokker_planck.engine.solve_fv_full`)."""
    _, import_time = timed_import("pde", "pypde", "py-pde")
    if method not in ("cram", "loop"):
        raise ValueError(f"method must be 'cram' or 'loop'; got method={method!r}")
    loop = None
    if method == "loop":
        loop = (lambda prep, e, nb, rf: _loop(prep, e, nb, rf, tol=max(1e-3 * rtol, 1e-12)))
    return solve_fv_full(problem, rtol=rtol, backend="pypde", assemble=assemble, n_cells=n_cells,
                         max_cells=max_cells, p_floor=p_floor,
                         time_integration="cram16" if method == "cram" else "pypde-scipy-loop", loop=loop,
                         extra={"import_time": import_time}, **engine)
