"""One grid's integration from the start to ``tau_end`` (:func:`solve_on_grid`).

Per stage ``exp(dtau L)`` by CRAM-16 (:mod:`.expm`); a balance multiplier ``A`` is held constant over a substep
(one per stage for ``balance_per_stage`` problems such as the closures, else substeps refined with the grids) and
found by Newton steps with the exact derivative of the CRAM map so that the mean is ``p0`` at every substep end.
A problem with a balance or at least :data:`~.domain.COMPILED_MIN_PIECES` pieces runs all its stages in one
compiled call (:mod:`._kernels`, CRAM-16 in partial fractions); a few plain stages go through LAPACK (the IPF form).
A ``tau``-dependent coefficient is sampled at segment midpoints (exponential midpoint rule).
"""
from __future__ import annotations

import functools
import math
from typing import Callable, Optional, Sequence

import numpy as np

from .domain import Prepared, _compiled, _Piece, _rows, row_plans
from .expm import ALPHA as CRAM_ALPHA
from .expm import ALPHA0 as CRAM_ALPHA0
from .expm import PFD_RESIDUES, expm_tridiagonal
from .expm import THETA as CRAM_THETA
from .operator import bands as fv_bands
from .operator import centres

__all__ = ["Assemble", "native_assemble", "solve_on_grid"]

#: a drift stage is split so that each exponential moves the distribution by at most this many spreads
DRIFT_SPLIT = 2.0
#: at most this many exponential steps per drift stage
MAX_DRIFT_SPLIT = 256
#: a balance substep keeps the mean within MEAN_TOL_FRACTION * rtol * p0 of p0 (else Newton steps on A)
MEAN_TOL_FRACTION = 1e-2
#: Newton steps on the balance multiplier of one substep before the solve reports failure
MAX_BALANCE_ITERATIONS = 30
#: the last Newton step on A is taken to first order on the state (no further exponential) once the mean misses
#: p0 by less than sqrt(LINEAR_FRACTION * rtol) p0: its O(miss^2) state error is then about LINEAR_FRACTION * rtol
LINEAR_FRACTION = 1e-2
#: the compiled stages use CRAM in partial fractions down to this rtol, below it the IPF form (round-off 1e-15
#: of max|y| per application against 1e-13)
PFD_MIN_RTOL = 1e-10
#: cells per balance substep (the substeps double with the cells, so Richardson removes their O(dtau^2) error)
SUBSTEP_CELLS = 16

#: ``assemble(edges, f_centres, a_faces, a_centres) -> (lower, diag, upper)`` on ``[z, m_0..m_{n-1}]``
Assemble = Callable[[np.ndarray, np.ndarray, Optional[np.ndarray], Optional[np.ndarray]], tuple]


def native_assemble(edges: np.ndarray, f_c: np.ndarray, a_faces: Optional[np.ndarray],
                    a_centres: Optional[np.ndarray] = None) -> tuple:
    """The engine's own operator (:func:`.operator.bands`; drift taken at the faces)."""
    return fv_bands(edges, f_c, a_faces)


def _substeps(prep: Prepared, piece: _Piece, n_base: int, refine: int) -> int:
    """Balance substeps of ``piece``: ``refine`` times those of the coarsest grid (``n_base`` cells).

    Doubling with the cells keeps the O(dtau^2) error of the frozen ``A`` in step with the O(h^2) error, so one
    Richardson step removes both; ``balance_per_stage`` problems have one substep per stage.
    """
    if prep.balance_per_stage:
        return 1
    return refine * max(1, int(round(n_base / SUBSTEP_CELLS * piece.duration / prep.tau_end)))


def _coefficients(pieces: Sequence, grids: Sequence[np.ndarray], centre_drift: bool,
                  plans: Optional[dict] = None) -> list:
    """Every stage's ``f`` (centres), drift and balance (faces; centres too if ``centre_drift``) as rows, per grid.

    Each callable is evaluated once, on the points of all ``grids`` together.
    """
    cs = [centres(e) for e in grids]
    faces = [e[:-1] for e in grids]
    cut = np.cumsum([0] + [c.size for c in cs])
    c_all, f_all = np.concatenate(cs), np.concatenate(faces)
    k_stages = len(pieces)
    layout = row_plans(pieces) if plans is None else plans
    shape = (k_stages, c_all.size)
    keys = ("f", "b", "w", "b_c", "w_c") if centre_drift else ("f", "b", "w")
    rows = {key: np.empty(shape) for key in keys}
    for key in keys[1:]:  # stages without a drift or a balance have rows of zeros
        if not layout[key[0]].every:
            rows[key].fill(0.0)
    has = {"b": np.zeros(k_stages, dtype=bool), "w": np.zeros(k_stages, dtype=bool)}
    np.maximum(_rows(layout["f"].funcs, c_all, "the diffusivity", out=rows["f"], plan=layout["f"].plan), 0.0,
               out=rows["f"])
    for key, name in (("b", "the drift"), ("w", "the balance")):
        sr = layout[key]
        if not sr.stages:
            continue
        idx = list(sr.stages)
        has[key][idx] = True
        for suffix, pts in (("", f_all), ("_c", c_all)) if centre_drift else (("", f_all),):
            if sr.every:  # all stages: write in place
                _rows(sr.funcs, pts, name, out=rows[key + suffix], plan=sr.plan)
            else:
                rows[key + suffix][idx] = _rows(sr.funcs, pts, name, plan=sr.plan)
    return [{**{key: v[:, cut[g]:cut[g + 1]] for key, v in rows.items()},  # views: no copies
             "has_b": has["b"], "has_w": has["w"], "c": cs[g]} for g in range(len(grids))]


def _fitted_stages(prep: Prepared, coef: dict) -> np.ndarray:
    """Which stages' drift takes its upwinding weight: plain drift stages where :attr:`Prepared.fitted_drift`."""
    return coef["has_b"] & ~coef["has_w"] & bool(prep.fitted_drift)


def _stage_bands(edges: np.ndarray, coef: dict, assemble: Assemble, fitted: bool | np.ndarray = False) -> tuple:
    """Rows of the stages' bands ``L_k`` and of their balance operators (0 where a stage has none).

    Without a balance the balance rows are one row of zeros.  ``fitted``: :func:`_fitted_stages`.
    """
    n_stages, n = coef["f"].shape
    any_w = bool(coef["has_w"].any())
    if assemble is native_assemble:  # all stages at once (the compiled path makes them in its kernel)
        any_b = bool(coef["has_b"].any())
        base = fv_bands(edges, coef["f"], coef["b"] if any_b else None, fitted=fitted, c=coef.get("c"))
        if not any_w:
            return base, (np.zeros((1, n)), np.zeros((1, n + 1)), np.zeros((1, n)))
        return base, fv_bands(edges, np.zeros((n_stages, n)), coef["w"], fitted=False)
    rows = []
    wrows = []
    zero = np.zeros(n)
    for k in range(n_stages):
        has_b, has_w = coef["has_b"][k], coef["has_w"][k]
        rows.append(assemble(edges, coef["f"][k], coef["b"][k] if has_b else None,
                             coef["b_c"][k] if has_b else None))
        if has_w or (k == 0 and not any_w):
            wrows.append(assemble(edges, zero, coef["w"][k], coef["w_c"][k]) if has_w
                         else (np.zeros(n), np.zeros(n + 1), np.zeros(n)))
        elif any_w:
            wrows.append((np.zeros(n), np.zeros(n + 1), np.zeros(n)))
    stack = lambda rs: tuple(np.array([r[i] for r in rs], dtype=float) for i in range(3))  # noqa: E731
    return stack(rows), stack(wrows)


def _drift_splits(pieces: Sequence, coef: dict) -> np.ndarray:
    """Exponential steps per plain drift stage: the drift moves Pr by at most DRIFT_SPLIT spreads per step.

    CRAM is accurate near the negative real axis; a drift adds imaginary parts ~ a k.
    """
    splits = np.ones(len(pieces), dtype=np.int64)
    for k, pc in enumerate(pieces):
        if coef["has_b"][k] and not coef["has_w"][k]:
            peclet = pc.duration * float(np.abs(coef["b"][k]).max()) / math.sqrt(
                2.0 * pc.duration * max(float(coef["f"][k].max()), 1e-300))
            splits[k] = max(1, math.ceil((peclet / DRIFT_SPLIT) ** 2))
            if splits[k] > MAX_DRIFT_SPLIT:
                raise ValueError(f"drift-dominated stage: Peclet number {peclet:.3g} (drift shift over diffusive "
                                 f"spread) needs {splits[k]} exponential steps, more than {MAX_DRIFT_SPLIT}; "
                                 "split the problem into shorter stages or reduce the drift")
    return splits


def _start(prep: Prepared, edges: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The start ``[z, m...]`` on a grid (cell centres ``c``): delta(p - p0) split between the two cells at ``p0``
    (an edge) so that the mean is ``p0``."""
    y = np.zeros(c.size + 1)
    j = int(edges.searchsorted(prep.p0))  # p0 == edges[j]
    cl, cr = c[j - 1], c[j]
    y[j] = (cr - prep.p0) / (cr - cl)
    y[j + 1] = (prep.p0 - cl) / (cr - cl)
    return y


def solve_on_grid(prep: Prepared, edges: np.ndarray, *, assemble: Assemble = native_assemble,
                  n_base: int = 64, refine: int = 1, mean_tol: float = 1e-13,
                  lin_tol: float = 0.0, coef: Optional[dict] = None,
                  partial_fractions: bool = True) -> tuple[np.ndarray, dict]:
    """Integrate from the start to ``tau_end`` on one grid; return ``y = [z, m...]`` and counters.

    ``n_base``: cells of the coarsest grid; ``refine`` (1, 2, 4): this grid's factor on its time segments and
    balance substeps.  A balance substep takes Newton steps on ``A`` until the mean is within ``mean_tol p0`` of
    ``p0`` (the last to first order once the miss is below ``lin_tol p0``); after MAX_BALANCE_ITERATIONS the
    counters carry ``"balance_failure"``.  ``partial_fractions``: CRAM in partial fractions in the kernels and
    the flux form on LAPACK (see PFD_MIN_RTOL); ``coef``: the coefficients on this grid, if evaluated.
    """
    pieces = prep.segment_fn(refine * max(4, n_base // 8)) if prep.time_dependent else prep.pieces
    if coef is None:
        coef = _coefficients(pieces, [edges], centre_drift=assemble is not native_assemble,
                             plans=prep.row_plans if pieces is prep.pieces else None)[0]
    c = coef["c"]
    n = c.size
    y = _start(prep, edges, c)
    compiled = _compiled(prep)
    rows_in_kernel = compiled and assemble is native_assemble  # the kernel makes each stage's bands itself
    if not rows_in_kernel:
        (lower, diag, upper), (wl, wd, wu) = _stage_bands(edges, coef, assemble, _fitted_stages(prep, coef))
    balanced = coef["has_w"]
    reps = _drift_splits(pieces, coef)
    for k in np.flatnonzero(balanced):
        reps[k] = _substeps(prep, pieces[k], n_base, refine)
    dt = np.array([pc.duration for pc in pieces]) / reps
    counters = {"cram_applications": 0, "substeps": int(reps[balanced].sum()), "newton_steps": 0}
    # a balance always runs in the kernel (its substep loop is compiled); a few plain stages stay on LAPACK
    if compiled:
        common = (balanced, dt, reps, np.concatenate(((edges[0],), c)), y, prep.p0, mean_tol, max(mean_tol, lin_tol),
                  bool(partial_fractions))
        if rows_in_kernel:
            y, n_cram, n_newton, info, stage, residual = _staged_kernels().run_rows(
                edges, coef["f"], coef["b"], coef["w"], bool(coef["has_b"].any()), *common,
                fitted=_fitted_stages(prep, coef))
        else:
            y, n_cram, n_newton, info, stage, residual = _staged_kernels().run(lower, diag, upper, wl, wd, wu,
                                                                              *common)
        counters["cram_applications"] = n_cram
        counters["newton_steps"] = n_newton
        if info > 0:
            raise FloatingPointError(f"CRAM: singular shifted tridiagonal system (zero pivot at row {info}, "
                                     f"stage {stage})")
        if info < 0:
            counters["balance_failure"] = (f"the balance multiplier A of stage {stage} did not converge: the mean "
                                           f"still missed p0 by {residual:.2e} p0 after {MAX_BALANCE_ITERATIONS} "
                                           f"Newton steps (tolerance {mean_tol:.1e} p0) on {n} cells")
        return y, counters
    for k in range(len(pieces)):
        for _ in range(reps[k]):
            y = expm_tridiagonal(lower[k], diag[k], upper[k], dt[k], y, flux_form=bool(partial_fractions))
        counters["cram_applications"] += int(reps[k])
    return y, counters


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float)


class _Kernels:
    """The compiled staged integration (:mod:`._kernels`, imported on first use)."""

    def __init__(self) -> None:
        from . import _kernels

        self._k = _kernels
        self._coef = (np.ascontiguousarray(CRAM_ALPHA), np.ascontiguousarray(CRAM_THETA), float(CRAM_ALPHA0),
                      np.ascontiguousarray(PFD_RESIDUES))

    def run_rows(self, edges, f_rows, b_rows, w_rows, any_b, balanced, dt, reps, cvec, y, p0, mean_tol, lin_tol,
                 pfd, fitted=None):
        """:meth:`run` with the native operator's bands made in the kernel; ``fitted`` as :func:`_fitted_stages`."""
        f = _f64
        fitted = np.zeros(len(balanced), dtype=np.bool_) if fitted is None else fitted
        out = self._k.staged_run_rows(
            f(edges), f(f_rows), f(b_rows), f(w_rows), bool(any_b), np.ascontiguousarray(balanced, dtype=np.bool_),
            np.ascontiguousarray(fitted, dtype=np.bool_), f(dt), np.ascontiguousarray(reps, dtype=np.int64), f(cvec),
            f(y), float(p0), float(mean_tol), float(lin_tol), int(MAX_BALANCE_ITERATIONS), bool(pfd), *self._coef)
        return _as_python(*out)

    def run(self, lower, diag, upper, wl, wd, wu, balanced, dt, reps, cvec, y, p0, mean_tol, lin_tol, pfd):
        """Every stage on one grid: ``(y, n_cram, n_newton, info, stage, residual)``; ``pfd``: partial fractions."""
        f = _f64
        out = self._k.staged_run(
            f(lower), f(diag), f(upper), f(wl), f(wd), f(wu), np.ascontiguousarray(balanced, dtype=np.bool_), f(dt),
            np.ascontiguousarray(reps, dtype=np.int64), f(cvec), f(y), float(p0), float(mean_tol), float(lin_tol),
            int(MAX_BALANCE_ITERATIONS), bool(pfd), *self._coef)
        return _as_python(*out)


def _as_python(y, n_cram, n_newton, info, stage, res) -> tuple:
    """A kernel's results with its counters as Python numbers."""
    return y, int(n_cram), int(n_newton), int(info), int(stage), float(res)


@functools.cache
def _staged_kernels() -> _Kernels:
    return _Kernels()


def _integrator(assemble: Assemble, rtol: float) -> Callable:
    """``integrate(prep, edges, n_base, refine, coef=None) -> (y, counters)``: :func:`solve_on_grid` at ``rtol``."""
    return lambda pr, e, nb, rf, cf=None: solve_on_grid(pr, e, assemble=assemble, n_base=nb, refine=rf, coef=cf,
                                                        mean_tol=max(1e-13, MEAN_TOL_FRACTION * rtol),
                                                        lin_tol=math.sqrt(LINEAR_FRACTION * rtol),
                                                        partial_fractions=rtol >= PFD_MIN_RTOL)
