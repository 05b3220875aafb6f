"""The shared finite-volume engine: nested grids, Richardson extrapolation, the one result builder.

Every finite-volume backend goes through :func:`solve_fv`, contributing only its operator (``assemble``
returning the tridiagonal bands of :mod:`.operator`).  :mod:`.domain` prepares
the problem, :mod:`.stages` integrates one grid; this module owns the three nested grids ``N, 2N, 4N``, the
Richardson extrapolation with the error estimate ``||R(2N,4N) - R(N,2N)||_1 / 7`` of the reported ``R(2N,4N)``,
refined until it meets ``rtol``, the non-contact weight (absorbed at ``p = 0``, else the mass below
``p_floor = FLOOR * p0``) and the one result builder (:func:`build_result`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Optional, Sequence

import numpy as np

from ..result import PressureDistribution
from .domain import FLOOR, Prepared, _compiled, _exit_wall, _trimmed_depth, density_knots, prepare
from .expm import ERROR_BOUND as CRAM_ERROR_BOUND
from .grading import _depth_fraction, _regradable, _regraded
from .grid import GridSpec, edges_for, knot_indices, same_grid
from .operator import centres
from .stages import Assemble, _coefficients, _integrator, native_assemble

__all__ = ["FLOOR", "MAX_CELLS", "RICHARDSON_DIVISOR", "solve_fv", "solve_fv_full", "FVSolution", "GridFamily",
           "build_result", "DIAGNOSTIC_KEYS"]

#: default cap on the cells of the finest grid
MAX_CELLS = 65536
#: ||R(2N,4N) - R(N,2N)|| / RICHARDSON_DIVISOR estimates the error of R(2N,4N): 2^3 - 1 (order 3-4)
RICHARDSON_DIVISOR = 7.0
#: the same, 2^2 - 1, for an exit wall (``f ~ p^k``, ``0 < k < 2``) on an ungraded grid family: second order there
EXIT_RICHARDSON_DIVISOR = 3.0
#: the grids (0: N, 1: 2N, 2: 4N) a solve with ``plain=`` integrates alone, by mode
PLAIN_GRIDS = {"only": (0, 1), "finest": (2,), "coarsest": (0,), "answer": (1,)}


@dataclass(frozen=True)
class GridFamily:
    """The nested grids of a solve's last level (``grid=`` of :func:`solve_fv_full`): the family ``spec``, the
    coarsest grid's knot indices ``knots`` (``knots[-1]`` its cells) and the finest grid's ``edges``."""

    spec: GridSpec
    knots: tuple
    edges: np.ndarray = field(compare=False, repr=False)

    @property
    def n_cells(self) -> int:
        """Cells of the coarsest grid."""
        return int(self.knots[-1])


@dataclass(frozen=True)
class FVSolution:
    """What :func:`solve_fv_full` returns: the ``result``, the last level's ``grid``, with ``plain=`` the plain cell
    masses ``[z, m...]`` of the N, 2N and 4N grids lumped below the floor (None where not integrated) and
    ``plain_failure`` why they are no result; ``prep`` the problem as prepared on ``grid`` (results on the same grid
    are built from it)."""

    result: PressureDistribution
    grid: Optional[GridFamily] = None
    plain: Optional[tuple] = None
    plain_failure: Optional[str] = None
    prep: Optional[Prepared] = field(default=None, repr=False, compare=False)

#: refinement stops when the estimate is below SAFETY * rtol (margin for the estimate's own error)
SAFETY = 0.5
#: cells of the first level's coarsest grid at rtol 1e-4 (times (1e-4/rtol)^(1/4), at least 16)
START_CELLS = 25.0
#: ... for staged problems without a balance
START_CELLS_STAGED = 18.0
#: the next level's cells: NEED_MARGIN times those the N^-4 law predicts for SAFETY * rtol
NEED_MARGIN = 1.25
#: ... but at least MIN_GROWTH times the current level's
MIN_GROWTH = 1.5
#: the largest growth of the cells from one level to the next
MAX_GROWTH = 8.0
#: a refinement whose estimate grew at two levels in a row to more than this factor above its smallest diverges
DIVERGENCE_FACTOR = 10.0
#: a level whose balance fails is repeated with twice the cells, at most this many times per solve
BALANCE_RETRIES = 2
#: the error estimate carries the time integration's bound, CRAM_AMPLIFICATION * applications * uniform error
CRAM_AMPLIFICATION = 10.0
#: keys every finite-volume result's diagnostics carry (same for every backend)
DIAGNOSTIC_KEYS = ("backend", "rtol", "n_cells", "levels", "zero_power", "wall", "p_floor", "p_min", "p_max",
                   "mass_error", "mean_error", "negative_mass", "min_density", "tail_mass",
                   "time_integration", "n_stages", "substeps", "timings")


def _lump(y: np.ndarray, j: int) -> np.ndarray:
    """``[z + m_0 + .. + m_{j-1}, m_j, ...]``: the first ``j`` cells (below the floor) lumped into ``z``."""
    if j <= 0:
        return y
    return np.concatenate(((y[: j + 1].sum(),), y[j + 1:]))


#: cells just below the floor whose cumulative masses a result keeps for its cdf's spline (:func:`_floor_ghosts`)
FLOOR_GHOSTS = 3


def _floor_ghosts(edges: np.ndarray, y: np.ndarray, j: int) -> Optional[tuple]:
    """``(edges, cumulative from the floor)`` of the last :data:`FLOOR_GHOSTS` cells below the floor ``edges[j]``,
    so the cdf's spline runs on across it; None where fewer cells lie below."""
    if j < FLOOR_GHOSTS:
        return None
    below = y[1 + j - FLOOR_GHOSTS:1 + j]
    cum = -np.cumsum(below[::-1])[::-1]
    return tuple(float(e) for e in edges[j - FLOOR_GHOSTS:j]), tuple(float(c) for c in cum)


def _aggregate(y_fine: np.ndarray) -> np.ndarray:
    """Sum the fine cells' masses (each coarse cell split in two) onto the coarse cells."""
    out = np.empty(y_fine.size // 2 + 1)
    out[0] = y_fine[0]
    np.add(y_fine[1::2], y_fine[2::2], out=out[1:])
    return out


def _extrapolate(fine: np.ndarray, coarse: np.ndarray, ratio: float) -> np.ndarray:
    """Richardson on a coarse grid, ``(ratio fine - coarse)/(ratio - 1)``, ``fine`` summed onto the coarse cells."""
    return (ratio * fine - coarse) / (ratio - 1.0)


def _pairs(x: np.ndarray) -> np.ndarray:
    """Per-cell quantities without a zero-weight entry (moments) summed over each coarse cell's two halves."""
    return x[0::2] + x[1::2]


def solve_fv(problem, **options) -> PressureDistribution:
    """Solve ``problem`` to ``rtol`` on nested grids: the result of :func:`solve_fv_full` (same options)."""
    return solve_fv_full(problem, **options).result


def solve_fv_full(problem, *, rtol: float, backend: str, assemble: Assemble = native_assemble,
                  n_cells: Optional[int] = None, max_cells: int = MAX_CELLS, p_floor: Optional[float] = None,
                  extra: Optional[dict] = None, grid: Optional[GridFamily] = None,
                  plain: Optional[str] = None) -> FVSolution:
    """Solve ``problem`` to ``rtol`` on nested grids (the engine's entry point).

    Repeated once on the conservative domain where the Lamperti-bounded one proves too short
    (``diagnostics["domain"]``), once on the first level's grid family where the regraded one diverges
    (``diagnostics["regrade"]``).

    Parameters
    ----------
    problem : FokkerPlanckProblem or StagedProblem
    rtol : float
        Target L1 error (validated by the caller, in [1e-14, 1)).
    backend : str
        Name stored in the result.
    assemble : callable
        ``assemble(edges, f_centres, a_faces, a_centres) -> (lower, diag, upper)``: the backend's operator on
        the state ``[z, m_0..m_{n-1}]``.
    n_cells : int, optional
        Cells of the coarsest grid, fixed (no refinement); default chosen from ``rtol`` and refined.
    max_cells : int
        Cap on the cells of the finest grid.
    p_floor : float, optional
        Floor (pressure) where the wall is not reached; default ``FLOOR * p0``.
    extra : dict, optional
        Backend-specific diagnostics.
    grid : GridFamily, optional
        Solve on a previous solution's grids, edge for edge, without refinement.
    plain : {"keep", "only", "finest", "coarsest", "answer"}, optional
        ``"keep"``: also return the last level's plain cell masses (``FVSolution.plain``); the others (with
        ``grid``) integrate only the grids :data:`PLAIN_GRIDS` names, and the result is failed by construction.

    Returns
    -------
    FVSolution
    """
    t_start = time.perf_counter()
    if n_cells is not None:
        if isinstance(n_cells, bool) or not isinstance(n_cells, (int, np.integer)) or n_cells < 8:
            raise ValueError(f"n_cells must be an integer >= 8; got n_cells={n_cells!r}")
    if isinstance(max_cells, bool) or not isinstance(max_cells, (int, np.integer)) or max_cells < 32:
        raise ValueError(f"max_cells must be an integer >= 32; got max_cells={max_cells!r}")
    if plain is not None and plain != "keep" and plain not in PLAIN_GRIDS:
        raise ValueError(f"plain must be None, 'keep' or one of {sorted(PLAIN_GRIDS)}; got plain={plain!r}")
    if plain in PLAIN_GRIDS and grid is None:
        raise ValueError(f"plain={plain!r} needs grid= (the grids whose plain masses to integrate)")
    if grid is not None and n_cells is not None and int(n_cells) != grid.n_cells:
        raise ValueError(f"n_cells={n_cells!r} differs from the given grid's coarsest grid ({grid.n_cells} cells)")
    options = dict(rtol=rtol, backend=backend, assemble=assemble, n_cells=n_cells, max_cells=int(max_cells),
                   p_floor=p_floor, extra=extra, grid=grid,
                   plain=plain, t_start=t_start)
    retried: dict = {}  # diagnostics key -> why the solve was repeated
    lamperti = regrade = True
    while True:
        out = _solve_levels(problem, lamperti=lamperti, regrade=regrade, **options)
        if isinstance(out, FVSolution):
            break
        key, why = out
        retried.setdefault(key, why)
        if key == "domain":
            lamperti = False  # the conservative domain (a second "domain" retry cannot arise there)
        else:
            regrade = False  # the first level's grid family
    if retried:
        d = out.result.diagnostics
        timings = {**d["timings"], "total": time.perf_counter() - t_start}
        out = replace(out, result=replace(out.result, diagnostics={**d, **retried, "timings": timings}))
    return out


def _solve_levels(problem, *, rtol: float, backend: str, assemble: Assemble, n_cells: Optional[int],
                  max_cells: int, p_floor: Optional[float], extra: Optional[dict], grid: Optional[GridFamily], plain: Optional[str],
                  lamperti: bool, regrade: bool, t_start: float):
    """One attempt of :func:`solve_fv_full`: an :class:`FVSolution`, or ``(key, why)`` where the solve is to be
    repeated with ``lamperti`` (key ``"domain"``) or ``regrade`` (key ``"regrade"``) off."""
    plain_only = plain in PLAIN_GRIDS
    fixed = n_cells is not None or grid is not None  # the three nested grids only, no refinement
    prep = prepare(problem, rtol=rtol, p_floor=p_floor, lamperti=lamperti, on_grid=grid.spec if plain_only else None)
    if grid is not None:  # another problem's grids; its domain, grading and depth as they were
        prep = replace(prep, spec=grid.spec)
    # coefficients constant within each stage: a grid's integration does not depend on its level (reusable)
    stage_constant = (assemble is native_assemble and not prep.time_dependent
                      and (prep.balance_per_stage or not prep.has_balance))
    t_prep = time.perf_counter() - t_start
    integrate = _integrator(assemble, rtol)
    cap = max_cells // 4  # the most cells of a coarsest grid (its finest grid has 4x as many)
    if grid is not None:
        n = grid.n_cells
    elif n_cells is not None:
        n = int(n_cells)
    else:
        n = int(min(max((START_CELLS_STAGED if _compiled(prep) and not prep.has_balance else START_CELLS)
                        * (1e-4 / rtol) ** 0.25, 16), 4096))
    history = []

    failure = None
    balance_broke = False  # the failure is a balance's (not the domain's business)
    balance_retries = 0
    # a level that doubles the previous one reuses its two finer grids (native operator only)
    reusable = stage_constant
    reuse = None
    remap_factor = 1.0  # the cell factor of a remapped monitor (:func:`_remapped`)
    moved = False  # the first level's grid family was regraded or remapped for the next levels
    grids_integrated = 0
    centre_drift = assemble is not native_assemble
    while True:
        if reuse is not None:
            idx = 2 * reuse[0]
        elif grid is not None and not history and n == grid.n_cells:
            idx = np.array(grid.knots)  # the knots where the other solve's last level had them
        else:
            idx = knot_indices(prep.spec, n)
        n_base = int(idx[-1])
        if 4 * n_base > max_cells and history:
            failure = f"refinement stopped at max_cells={max_cells} (the next grid needs {4 * n_base} cells)"
            break
        # the coarser grids are every 2nd / 4th edge of it
        finest = grid.edges.copy() if grid is not None else edges_for(
            prep.spec, idx, 4, known=reuse[2] if reuse is not None else None)
        es = [finest[::4 >> k] for k in range(3)]  # coarsest first
        ks = [0, 1, 2]  # each grid's refinement exponent (its cells are n_base << k)
        if plain_only:  # the N and 2N grids alone, or one grid alone
            ks = list(PLAIN_GRIDS[plain])
            es = [es[k] for k in ks]
        if reuse is not None and not (same_grid(es[0], reuse[1]) and same_grid(es[1], reuse[2])):
            reuse = None  # not the same grids (never seen): integrate all three grids
        if reuse is not None:
            coef3 = _coefficients(prep.pieces, [es[-1]], centre_drift=centre_drift, plans=prep.row_plans)[0]
            ys = [reuse[3], reuse[4], integrate(prep, es[-1], n_base, 4, coef3)]
        elif not prep.time_dependent:  # each coefficient evaluated once for all the grids
            coefs = _coefficients(prep.pieces, es, centre_drift=centre_drift, plans=prep.row_plans)
            ys = [integrate(prep, e, n_base, 1 << k, coefs[g]) for g, (k, e) in enumerate(zip(ks, es))]
        else:
            ys = [integrate(prep, e, n_base, 1 << k) for k, e in zip(ks, es)]
        grids_integrated += 1 if reuse is not None else len(es)
        reuse = None
        if plain_only:
            return _plain_solution(prep, es, ys, idx, ks, finest, backend=backend, rtol=rtol, t_start=t_start,
                                   t_prep=t_prep)
        (y1, c1), (y2, c2), (y3, cnt) = ys
        e1, e2, e3 = es
        broken = [cc["balance_failure"] for _, cc in ys if "balance_failure" in cc]
        if broken:
            failure = broken[0]
            balance_broke = True
            if not fixed and balance_retries < BALANCE_RETRIES and 8 * n_base <= max_cells:
                # the grids do not resolve a balance: the same level with twice the cells
                balance_retries += 1
                failure, balance_broke = None, False
                n = 2 * n_base
                continue
            if not history:  # nothing to report: the coarsest level failed
                raise RuntimeError(failure)
            break
        unstable = _unstable_grid(es, ys)
        if unstable is not None:
            # a first level too coarse for its drift is refined; a later unstable level is no result
            if not history and not fixed and 4 * n_base * MAX_GROWTH <= max_cells:
                n = int(math.ceil(n_base * MAX_GROWTH))
                continue
            failure = unstable
            if not history:  # nothing to report: the coarsest level failed
                raise RuntimeError(failure)
            break
        r12 = _extrapolate(_aggregate(y2), y1, 4.0)
        fine = _aggregate(y3)
        r23 = _extrapolate(fine, y2, 4.0)
        # first moments per cell, extrapolated the same way: the cells' barycentres
        mom2 = centres(e2) * y2[1:]
        mom3 = centres(e3) * y3[1:]
        r_mom = _extrapolate(_pairs(mom3), mom2, 4.0)
        mean_full = float(r_mom.sum() + e2[0] * r23[0])
        # the quantity reported: cells below the floor lumped into zero_weight (before any other step)
        j1 = _cells_below_floor(prep, e1)
        j2 = 2 * j1
        diff = _lump(_aggregate(r23), j1) - _lump(r12, j1)  # the Richardson differences on the N grid
        exit_wall = _exit_wall(prep)
        est = float(np.abs(diff).sum()) / (EXIT_RICHARDSON_DIVISOR if exit_wall else RICHARDSON_DIVISOR)
        out_edges, out_y, out_mom, fine_l = e2[j2:], _lump(r23, j2), r_mom[j2:], _lump(fine, j2)
        order = 2 if exit_wall else 4
        # where extrapolation overshoots below 0 (far tails, 1e-17-level), keep the finest grid's own
        # value (>= 0 up to CRAM round-off, which is then cut to 0); the change is added to the estimate
        neg = out_y < 0.0
        if neg.any():
            repl = np.maximum(fine_l[neg], 0.0)
            est += float(np.abs(out_y[neg] - repl).sum())
            out_y = out_y.copy()
            out_y[neg] = repl
        # where the exact mean is p0, the L1 error is at least |mean - p0| / p_max: a level missing it is refined
        mean_miss = abs(mean_full - prep.p0) if prep.mean_conserved else 0.0
        if (prep.lamperti_bounded and assemble is native_assemble and mean_miss > SAFETY * rtol * prep.p0):
            # the native operator conserves the mean to round-off: a miss is the domain's top cut
            return "domain", (f"conservative: on the Lamperti-bounded domain (p_max = {out_edges[-1]:.4g}) the mean "
                              f"missed p0 by {mean_miss / prep.p0:.2e} p0")
        est = max(est, mean_miss / float(out_edges[-1]))
        # the time integration's own error (not removed by Richardson): its uniform bound per application
        est += CRAM_AMPLIFICATION * max(cc.get("cram_applications", 0) * CRAM_ERROR_BOUND
                                        for _, cc in ys)
        history.append((n_base, est))
        # the estimate falls like N^-order: the factor on this level's cells that meets rtol
        need = NEED_MARGIN * max((est / (SAFETY * rtol)) ** (1.0 / order),
                                 (mean_miss / (SAFETY * rtol * prep.p0)) ** (1.0 / order))
        best = (out_edges, out_y, out_mom, est, cnt, [n_base << k for k in range(3)], mean_full)
        best_grid = GridFamily(prep.spec, tuple(idx.tolist()), finest)
        best_ghosts = _floor_ghosts(e2, r23, j2)
        best_plain = (_lump(y1, j1), _lump(y2, j2), _lump(y3, 2 * j2)) if plain == "keep" else None
        trimmed = _trimmed_depth(prep, float(out_y[0]) + est, rtol) if len(history) == 1 else None
        if (est <= SAFETY * rtol and mean_miss <= SAFETY * rtol * prep.p0) or fixed:
            break
        if len(history) > 12:
            failure = "refinement did not converge in 12 levels"
            break
        smallest = min(e for _, e in history)
        if len(history) >= 3 and est > history[-2][1] > history[-3][1] and est > DIVERGENCE_FACTOR * smallest:
            failure = (f"refinement diverges: the error estimate grew at two levels in a row, "
                       f"{history[-3][1]:.2e} -> {history[-2][1]:.2e} -> {est:.2e} on {history[-3][0]}, "
                       f"{history[-2][0]}, {n_base} coarsest cells (smallest {smallest:.2e}): the finer grids lose "
                       f"accuracy (e.g. a drift far stronger than the diffusion in the cells below the floor); "
                       f"a looser rtol may be met")
            break
        grow = float(min(max(need, MIN_GROWTH), MAX_GROWTH))  # x MIN_GROWTH ... x MAX_GROWTH per level
        if 4 * n_base >= max_cells or 4 * n_base * need > 8 * max_cells:
            failure = (f"error estimate {est:.2e} misses rtol={rtol:.1e}: it would need about "
                       f"{int(4 * n_base * need)} cells, max_cells={max_cells}")
            break
        if trimmed is not None:  # a shallower domain below the floor for the next levels (a new grid family)
            # the cells per unit of Phi predicted for the old domain (growth capped at MAX_GROWTH, as below)
            ratio = float(np.sum(trimmed.spec.segment_weights()) / np.sum(prep.spec.segment_weights()))
            prep = trimmed
            n = int(min(max(math.ceil(n_base * min(need, MAX_GROWTH) * ratio), 16), cap))
            continue
        # the remap only under the native operator (py-pde's on a remapped grid can underestimate its error)
        regraded = _regraded(prep, e1, diff, j1, remap=assemble is native_assemble) if (
            regrade and len(history) == 1 and _regradable(prep)) else None
        if regraded is not None:  # the same domain, its cells moved to where the first level's error was
            spec_new, factor = regraded
            moved = True
            if spec_new.remap is not None:
                remap_factor = factor
            prep = replace(prep, spec=spec_new)
            n = int(min(max(math.ceil(n_base * min(need * factor, MAX_GROWTH)), 16), cap))
            continue
        if reusable and grow <= 2.0 and 8 * n_base <= max_cells:  # cheaper to double: one new grid (8 n_base cells) instead of three
            reuse = (idx, e2, e3, (y2, c2), (y3, cnt))
        n = min(int(math.ceil(n_base * grow)), cap)
    if failure is not None and moved and failure.startswith("refinement diverges"):
        # the grid family the first level's errors favoured diverged where the first level's family may
        # converge: once more without (a divergence only: other failures are reported as they are)
        return "regrade", f"the first level's grid family (the regraded one failed: {failure})"
    edges, y, moments, est, cnt, cells, mean_full = best
    # under a balance the top cell's mass counts with its weight p_max / p0 in the mean
    top_weight = max(1.0, float(edges[-1]) / prep.p0) if prep.has_balance else 1.0
    if prep.lamperti_bounded and failure is None and abs(float(y[-1])) * top_weight > rtol:
        # the Lamperti bound was too short (a balance's drift, which it does not see, carried the tail further)
        return "domain", (f"conservative: on the Lamperti-bounded domain (p_max = {edges[-1]:.4g}) the top cell held "
                          f"{abs(float(y[-1])):.2e}" + (f" (x p_max/p0 = {top_weight:.3g} in the mean)"
                                                         if top_weight > 1.0 else "") + " > rtol")
    if prep.lamperti_bounded and failure is not None and not balance_broke:
        # a refinement that failed on the shorter domain is tried once on the conservative one
        return "domain", (f"conservative: on the Lamperti-bounded domain (p_max = {edges[-1]:.4g}) the solve "
                          f"failed: {failure}")
    timings = {"setup": t_prep, "solve": time.perf_counter() - t_start - t_prep,
               "total": time.perf_counter() - t_start}
    result = build_result(prep, backend=backend, edges=edges, y=y, moments=moments, estimate=est, rtol=rtol,
                          timings=timings, mean_full=mean_full,
                          extra={"levels": cells, "history": history,
                                 "cram_applications": cnt["cram_applications"], "substeps": cnt["substeps"],
                                 "grids_integrated": grids_integrated,
                                 "remap_factor": remap_factor,
                                 "newton_steps": cnt.get("newton_steps", 0),
                                 "domain": "Lamperti-bounded" if prep.lamperti_bounded else "from the spread",
                                 "wall_grading": float(prep.spec.c_wall), "wall_depth": _depth_fraction(prep.spec),
                                 # (the family of the result's grid: its cdf interpolates in the family's coordinate)
                                 "grid": (best_grid.spec, best_grid.knots),
                                 **({"floor_ghosts": best_ghosts} if best_ghosts is not None else {}),
                                 **(extra or {})},
                          failure=failure)
    return FVSolution(result=result, grid=best_grid, plain=best_plain, prep=prep)


#: a grid whose states sum in absolute value to more than this is unstable (probability is at most 1)
UNSTABLE_L1 = 2.0


def _unstable_grid(es: Sequence[np.ndarray], ys: Sequence[tuple]) -> Optional[str]:
    """Why a level's integration is no result, or None: a grid's state not finite or its absolute sum above
    :data:`UNSTABLE_L1` (a central-flux drift dominating the diffusion gives complex eigenvalues, which the
    rational approximation can amplify)."""
    for edges, (y, _) in zip(es, ys):
        total = float(np.abs(y).sum())
        if not math.isfinite(total) or total > UNSTABLE_L1:
            return (f"the exponential integration is unstable on the {edges.size - 1}-cell grid (sum |Pr| = "
                    f"{total:.3g} instead of 1): a drift dominating the diffusion gives the operator eigenvalues "
                    "off the negative real axis, where the rational approximation does not hold")
    return None


def _cells_below_floor(prep: Prepared, edges: np.ndarray) -> int:
    """How many cells of the grid ``edges`` lie below the floor (lumped into the zero weight of an answer)."""
    return int(edges.searchsorted(prep.lump_below)) if prep.lump_below > 0 else 0


def _plain_solution(prep: Prepared, es: Sequence[np.ndarray], ys: Sequence[tuple], idx: np.ndarray,
                    ks: Sequence[int], finest: np.ndarray, *, backend: str, rtol: float, t_start: float,
                    t_prep: float) -> FVSolution:
    """The :class:`FVSolution` of a plain solve: the grids' own masses lumped below the floor (``ks`` their
    refinement exponents); the result is the finest integrated grid's, failed by construction."""
    j1 = _cells_below_floor(prep, es[0][::1 << ks[0]])  # the N grid's (every 2^k-th edge) cells below the floor
    broken = [cc["balance_failure"] for _, cc in ys if "balance_failure" in cc]
    unstable = _unstable_grid(es, ys)
    if unstable is not None:
        broken.append(unstable)
    timings = {"setup": t_prep, "solve": time.perf_counter() - t_start - t_prep,
               "total": time.perf_counter() - t_start}
    plain = [None, None, None]
    for k, (y, _) in zip(ks, ys):
        plain[k] = _lump(y, j1 << k)
    last = ks[-1]
    result = build_result(prep, backend=backend, edges=es[-1][j1 << last:], y=plain[last], estimate=float("inf"),
                          rtol=rtol, timings=timings, failure="plain masses only (no extrapolation, no estimate)",
                          extra={"levels": [int(idx[-1]) << k for k in ks], "grid": (prep.spec, tuple(idx.tolist()))})
    return FVSolution(result=result, grid=GridFamily(prep.spec, tuple(idx.tolist()), finest), plain=tuple(plain),
                      plain_failure=broken[0] if broken else None, prep=prep)


#: a breakpoint within this fraction of the domain above its bottom is not resolved (:func:`build_result`)
UNRESOLVED = 1e-15


def build_result(prep: Prepared, *, backend: str, edges: np.ndarray, y: np.ndarray, estimate: float, rtol: float,
                 timings: dict, extra: dict, moments: Optional[np.ndarray] = None,
                 mean_full: Optional[float] = None, failure: Optional[str] = None) -> PressureDistribution:
    """The one place a finite-volume result is made (one meaning of ``success``).

    ``p`` holds each cell's barycentre ``moments / masses`` (clipped into the cell), so ``sum(weights * p *
    density)`` is the solver's first moment; the cells under a breakpoint within :data:`UNRESOLVED` of the bottom
    (densities of 1e5 and more below 1e-21 where a jump at ``p = 0`` was found) give their mass and moment to the
    first cell above it (keeping their edges: grids stay nested).  ``success`` requires: the estimate <= rtol, total
    probability within rtol of 1, the mean within ``rtol p0`` of ``p0`` (where conserved), negative probability (never
    clipped), the top cell's probability and what left through a truncated bottom all below rtol.
    """
    knots = density_knots(prep)
    tiny = [k for k in knots if edges[0] < k <= edges[0] + UNRESOLVED * (edges[-1] - edges[0])]
    low = int(np.argmin(np.abs(edges - max(tiny)))) if tiny else 0
    if low:
        y = np.r_[y[0], np.zeros(low), np.sum(y[1:low + 2]), y[low + 2:]]
        moments = None if moments is None else np.r_[np.zeros(low), np.sum(moments[:low + 1]), moments[low + 1:]]
    h = edges[1:] - edges[:-1]
    m = np.asarray(y[1:], dtype=float)
    c = centres(edges)
    if moments is not None:
        ok = m > 1e-300
        bary = np.where(ok, moments / np.where(ok, m, 1.0), c)
        c = np.minimum(np.maximum(bary, edges[:-1]), edges[1:])  # (np.clip's values, without its overhead)
    z = float(y[0])
    density = m / h
    mass = float(m.sum() + z)
    # the mean checked is the solver's full first moment (the lumped mass below the floor included)
    mean = float(c @ m + edges[0] * z) if mean_full is None else float(mean_full)
    neg = m < 0.0
    negative_mass = float(-m[neg].sum())
    tail = float(abs(m[-1]))
    problems = []
    if failure:
        problems.append(failure)
    if not estimate <= rtol:
        problems.append(f"error estimate {estimate:.2e} misses rtol={rtol:.1e} on {c.size} cells")
    if not abs(mass - 1.0) <= rtol:
        problems.append(f"mass {mass:.12g} not conserved to rtol")
    if prep.mean_conserved and not abs(mean - prep.p0) <= rtol * prep.p0:
        problems.append(f"mean {mean:.10g} differs from p0={prep.p0:.10g} by more than rtol")
    if negative_mass > rtol:
        problems.append(f"negative probability {negative_mass:.2e} > rtol")
    if tail > rtol:
        problems.append(f"probability {tail:.2e} in the top cell: the domain is too short")
    if edges[0] > prep.p_floor and z > rtol:  # a bottom above the wall (and the floor): what left was a tail
        problems.append(f"probability {z:.2e} left through the domain's bottom at p = {edges[0]:.6g} (above the "
                        "wall, where less than the tail tolerance was to arrive): the domain is too short")
    success = not problems
    wall = "absorbing at p = 0" if prep.reached else f"not reached (k >= 2); floor at p_floor = {prep.p_floor:.6g}"
    absorbed = "; zero_weight = probability absorbed at p = 0"
    if prep.reached and z == 0.0 and any(pc.b is not None for pc in prep.pieces):
        # the wall's net flux was clipped to 0 on every stage (operator.wall_drift): Feller's entrance boundary
        wall = "p = 0 never reached: the drift away from it outweighs diffusion there (an entrance boundary)"
        absorbed = "; zero_weight = 0: p = 0 is an entrance boundary (the drift holds probability off it)"
    if success:
        message = (f"converged: L1 error estimate {estimate:.2e} <= rtol {rtol:.1e} on {c.size} cells"
                   + (absorbed if prep.reached else f"; zero_weight = probability below p_floor = {prep.p_floor:.3g}"))
    else:
        message = "; ".join(problems)
    diagnostics = {
        "backend": backend, "rtol": float(rtol), "n_cells": int(c.size), "levels": extra.get("levels"),
        "zero_power": float(prep.zero_power), "wall": wall, "p_floor": float(prep.p_floor),
        "p_min": float(edges[0]), "p_max": float(edges[-1]), "mass_error": mass - 1.0, "mean_error": mean - prep.p0,
        "negative_mass": negative_mass, "min_density": float(density.min()), "tail_mass": tail,
        "time_integration": extra.get("time_integration", "cram16"), "n_stages": len(prep.pieces),
        "substeps": int(extra.get("substeps", 0)), "timings": dict(timings),
    }
    diagnostics["knots"] = knots
    diagnostics["domain_bottom"] = float(prep.spec.p_wall)  # the absorbing lower end of the grids (pressure)
    diagnostics.update({k: v for k, v in extra.items() if k not in diagnostics})
    if prep.label:
        diagnostics["label"] = prep.label
    return PressureDistribution(p=c, density=density, weights=h, zero_weight=z, mean_pressure=prep.p0,
                                variance=2.0 * prep.tau_end, backend=backend, success=bool(success), message=message,
                                error_estimate=float(estimate), wall_time=float(timings["total"]),
                                diagnostics=diagnostics, edges=edges, contact_threshold=0.0 if prep.reached else None)
