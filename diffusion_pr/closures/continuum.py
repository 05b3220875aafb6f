"""The continuum closure: the shell closures extrapolated in the number of shells (docs/closures.md).

The shell sum is the exponential midpoint rule in ``tau``: its error is even in the shell width.  Fewer-shell
problems are integrated on the ``n``-shell grids, so their masses combine cell by cell (:func:`_shell_table`).
Masses and L1 distances are dimensionless; pressures in the unit of ``E_star``."""
from __future__ import annotations

import math
import sys
from dataclasses import replace
from typing import Any, Optional

import numpy as np

from .models import closure_problem
from .shells import Shells, cached_shells

__all__ = ["MAX_CONTINUUM_SHELLS", "solve_full", "shell_extrapolated"]

#: the most shells the extrapolation grows to where its residual misses rtol
MAX_CONTINUUM_SHELLS = 1536
#: the counted spatial error of the later rungs solved on the N grid alone, as a multiple of their refinement's
#: size times four times the first correction's relative second-order error
REFINEMENT_MARGIN = 3.0
#: ... where that counted error takes at most this share of the room left in rtol (else both grids throughout)
COARSE_ROOM = 0.5
#: the shells grow only while the grids' estimate leaves the shells' residual this share of rtol at least
SHELL_SHARE = 0.9
#: where the grids' estimate alone takes SHELL_SHARE of rtol, the first solve is repeated at this fraction of rtol
GRID_RETRY_FRACTION = 0.25
#: the ratio of successive shell differences above which second order is taken as asymptotic (4 at second order)
SHELL_ORDER_RATIO = 3.0
#: ... and below which second order is not yet clear (:func:`_uniform_table`)
SECOND_ORDER_CLEAR = 3.5
#: the ratio of successive ``R(n/2, n)`` differences above which Romberg's next column is used (16 at fourth order)
ROMBERG_RATIO = 12.0
#: the largest such ratio Romberg trusts: above it the ladder is pre-asymptotic
ROMBERG_MAX_RATIO = 17.0
#: on graded shells, the largest ratio of ``R(n/2, n)`` differences trusted (the frozen layer's order 2.5)
THIN_LAYER_RATIO = 2.0 ** 2.5
#: the space-extrapolated correction's error: the second-order estimate times this multiple of the same
#: extrapolation's observed relative error on the n-shell problem's own grids (used where the factor is below 1)
SPLIT_MARGIN = 4.0
#: ... and never less than this fraction of the second-order estimate
SPLIT_FLOOR = 0.1
#: the fewest shells a coarser plain solve of the table has (the n/8 of 48)
MIN_ROMBERG_SHELLS = 6


def solve_full(problem: Any, backend: str, rtol: float, options: dict, **engine: Any) -> Any:
    """The :class:`~diffusion_pr.fokker_planck.engine.FVSolution` of a closure's staged problem by the
    finite-volume backend ``backend``; ``engine``: the ``grid`` and ``plain`` arguments (None dropped)."""
    from ..fokker_planck.backends import get_backend

    solver = get_backend(backend)
    full = sys.modules[solver.__module__].solve_full
    return full(problem, rtol=rtol, **options, **{k: v for k, v in engine.items() if v is not None})


def _shell_residual(m_n: np.ndarray, m_h: np.ndarray, m_q: np.ndarray) -> tuple:
    """``(estimate, rho, difference)`` from the masses of ``n``, ``n/2``, ``n/4`` shells: the L1 error of ``R(n/2, n)
    = (4 m(n) - m(n/2))/3``, the ratio ``rho = |m(n/2) - m(n/4)| / |m(n) - m(n/2)|`` and ``|R(n/2, n) - R(n/4,
    n/2)|``; the estimate is that difference over ``rho - 1``, over 15 where ``rho >= SHELL_ORDER_RATIO``."""
    d_top = float(np.sum(np.abs(m_n - m_h)))
    d_half = float(np.sum(np.abs(m_h - m_q)))
    rho = d_half / d_top if d_top > 0.0 else math.inf
    difference = float(np.sum(np.abs((4.0 * m_n - m_h) / 3.0 - (4.0 * m_h - m_q) / 3.0)))
    return difference / (15.0 if rho >= SHELL_ORDER_RATIO else max(rho - 1.0, 1.0)), rho, difference


def shell_problem(scene: tuple, m: int) -> tuple:
    """``(problem, shells)``: the closure of ``scene = (spectrum, E, p0, z, closure, grading)`` on
    ``m`` shells of its continuum spectrum."""
    spectrum, E, p0, z, closure, grading = scene
    shells = cached_shells(spectrum, E, m, grading)
    return closure_problem(shells, zeta=z, E_star=E, mean_pressure=p0, closure=closure), shells


def _ladder_below(top: int) -> list:
    """The shell counts :func:`_shell_corrected` solves first below ``top``: ``top/2``, ``top/4`` and, where it
    divides and is at least :data:`MIN_ROMBERG_SHELLS`, ``top/8``."""
    return [top // 2, top // 4] + ([top // 8] if top % 8 == 0 and top // 8 >= MIN_ROMBERG_SHELLS else [])


def solve_shells(problem: Any, shells: Shells, closure: str, backend: str, rtol: float, options: dict, *,
                  keep: bool, note: Optional[dict] = None) -> Any:
    """The closure's FVSolution with the closure and shell count in its diagnostics (and ``note``); with ``keep``
    the last level's plain masses too."""
    sol = solve_full(problem, backend, rtol, options, plain="keep" if keep else None)
    res = sol.result
    return replace(sol, result=replace(res, diagnostics={**res.diagnostics, "closure": closure,
                                                         "n_shells": int(shells.q.size), **(note or {})}))


def _coarser_on_grid(sol: Any, m: int, scene: tuple, rtol: float, options: dict, *, plain: Optional[str]) -> Any:
    """The ``m``-shell problem of ``scene`` solved on the grids of ``sol``, in full (``plain=None``) or for the
    plain masses of some grids (a mode of :data:`~diffusion_pr.fokker_planck.engine.PLAIN_GRIDS`); a balance with no
    root is a failed solution that says so."""
    from ..fokker_planck.engine import FVSolution

    res = sol.result
    sub = {k: v for k, v in options.items() if k != "n_cells"}  # (the grid fixes the cells)
    problem, _ = shell_problem(scene, m)
    try:
        return solve_full(problem, res.backend, rtol, sub, grid=sol.grid, plain=plain)
    except RuntimeError as exc:
        why = f"{type(exc).__name__}: {exc}"
        return FVSolution(result=replace(res, success=False, message=why, wall_time=0.0,
                                         diagnostics={"n_stages": len(problem.stages)}),
                          plain_failure=str(exc))


def _failed_extrapolation(sol: Any, scene: tuple, rtol: float, options: dict, why: str) -> Any:
    """The ``n``-shell answer of ``sol`` marked as a failed shell extrapolation, saying why."""
    res = sol.result
    n = int(res.diagnostics["n_shells"])
    return _rebuilt(sol, scene, rtol, options, masses=_masses(res), moments=res.p * res.density * res.weights,
                    estimate=res.error_estimate,
                    extra={"shell_error": None, "shell_extrapolation": False, "shell_extrapolation_failed": why},
                    failure=f"shell extrapolation failed: {why}; the {n}-shell answer is returned")


def shell_extrapolated(sol: Any, scene: tuple, rtol: float, options: dict) -> Any:
    """The continuum closure from the ``n``-shell solution ``sol``: :func:`_shell_corrected` where its plain masses
    were kept and it meets ``rtol``, else :func:`_shell_combined`."""
    z = scene[3]
    res = sol.result
    if z == 0.0 or not res.success or res.edges is None or sol.grid is None:
        diag = {**res.diagnostics, "shell_error": 0.0 if z == 0.0 else None, "shell_extrapolation": False}
        return replace(res, diagnostics=diag)
    if sol.plain is not None:
        out = _shell_corrected(sol, scene, rtol, options)
        if out.success:
            return out
        # the plain grids' correction misses rtol: solve the coarser-shell problems in full
        combined = _shell_combined(sol, scene, rtol, options)
        tried = out.diagnostics["timings"].get("shells", 0.0)
        timings = dict(combined.diagnostics["timings"])
        timings["shells"] = timings.get("shells", 0.0) + tried
        return replace(combined, wall_time=combined.wall_time + tried,
                       diagnostics={**combined.diagnostics, "timings": timings,
                                    "shell_correction_missed": out.message})
    return _shell_combined(sol, scene, rtol, options)


def _shell_corrected(sol: Any, scene: tuple, rtol: float, options: dict) -> Any:
    """The continuum closure as ``res = sol.result`` plus a correction from plain grids (docs/closures.md,
    "How the shell closures are solved").

    The shells' difference is taken from the plain masses ``P`` of the last level's grids, solved for ``n/2``,
    ``n/4``, ``n/8`` shells on ``res``'s grids: ``c = X(top) - P(n)`` per grid, ``X`` the continuum of
    :func:`_shell_table`, and the answer ``m(res) + c``.  ``c`` is extrapolated in space from the ``N`` and ``2N``
    grids (:func:`_correction_in_space`), or from the ``4N`` grids too where its counted error misses ``rtol``;
    where the sum still misses, the ``2 top``-shell problem is solved on the same grids."""
    from ..fokker_planck.engine import RICHARDSON_DIVISOR
    from ..fokker_planck.grid import same_grid

    res = sol.result
    n = int(res.diagnostics["n_shells"])
    plain = {n: list(sol.plain)}
    timing = {"shells": 0.0}
    finest = False  # the correction from the 4N grids too, extrapolated in space
    evaluated: dict = {}  # ("base", n) -> the first table's evaluation (the later rungs' tables add to it)
    thin = scene[5] != "uniform"  # graded shells: the wall's layer is thin (shell_grading)
    # graded shells: the later rungs on the N grid alone ("coarse"), until the 2N grids are wanted after all
    state = {"coarse": thin, "base": n}

    def masses_of(s: Any, mode: str) -> Optional[list]:
        # (the answer's grid is the 2N grid: the N grid is its every second edge, the 4N grid's every second edge it)
        own = s.result.edges[::2] if mode == "finest" else s.result.edges
        theirs = res.edges[::2] if mode == "coarsest" else res.edges
        ok = not (s.plain_failure or s.plain is None or not same_grid(own, theirs))
        return list(s.plain) if ok else None

    def solve_plain(ms: list, mode: str) -> dict:
        out = {}
        for m in ms:
            s = _coarser_on_grid(sol, m, scene, rtol, options, plain=mode)
            timing["shells"] += s.result.wall_time
            out[m] = masses_of(s, mode)
        return out

    def on_the_grids(ms: list) -> None:
        mode = "coarsest" if state["coarse"] and ms and min(ms) > state["base"] else "only"
        for m, got in solve_plain([m for m in ms if m not in plain], mode).items():
            plain[m] = got
        if finest:
            add_grid(2, "finest", ms)

    def add_grid(g: int, mode: str, ms: list) -> None:
        """Grid ``g`` (integrated alone by plain mode ``mode``) for the shell counts ``ms`` that lack it."""
        for m, got in solve_plain([m for m in ms if plain[m] is not None and plain[m][g] is None], mode).items():
            if got is None:
                plain[m] = None
            else:
                plain[m][g] = got[g]

    def fill_answer_grids() -> None:
        """The 2N grids of the rungs solved on the N grid alone: every table on both grids again."""
        state["coarse"] = False
        add_grid(1, "answer", list(plain))

    l1, agg = _l1, _aggregated

    def table(top: int, masses: dict, g: int) -> tuple:
        eighth = top % 8 == 0 and masses.get(top // 8) is not None
        used = [top >> k for k in range(4 if eighth else 3)]
        return _shell_table([masses[m][g] for m in used], thin=thin, start=scene[5] == "ends")

    def evaluate(top: int, masses: dict, finest: bool) -> dict:
        """The correction and its errors from the table of ``top`` shells."""
        if state["coarse"] and top > state["base"]:
            return evaluate_coarse(top, masses)
        c = [None, None, None]
        ev: dict = {"split": False, "split_error": None, "refinement_error": None}  # split: from the N and 2N grids
        for g in ((0, 1, 2) if finest else (0, 1)):
            x, res_g, table_g = table(top, masses, g)
            c[g] = x - masses[n][g]
            if g == 1:  # the answer's grid: its residual and orders
                ev["residual"], ev["table"] = res_g, table_g
        if finest:
            ev["corr"] = (4.0 * agg(c[2]) - c[1]) / 3.0
            ev["corr_error"] = l1(agg(ev["corr"]) - (4.0 * agg(c[1]) - c[0]) / 3.0) / RICHARDSON_DIVISOR
        else:
            ev["corr"], ev["split_error"], ev["corr_error"], ev["split"] = _correction_in_space(c[0], c[1],
                                                                                             masses[n])
        # counted: the extrapolated correction's own error; the second-order size where the layer is thin
        ev["counted"] = ev["split_error"] if ev["split"] and not finest and not thin else ev["corr_error"]
        ev["grids"] = res.error_estimate + ev["counted"]
        # the N grid's continuum and its relative error of the correction (4 s / |c_2N|), for the later rungs
        size = l1(c[1])
        ev["x_coarse"], ev["n_relative"] = c[0] + masses[n][0], 4.0 * ev["corr_error"] / size if size > 0.0 else 0.0
        return ev

    def evaluate_coarse(top: int, masses: dict) -> dict:
        """:func:`evaluate` for rungs on the N grid alone: the first table's correction plus the refinement of the N
        grid's continuum, split onto the 2N grid; its error counted as :data:`REFINEMENT_MARGIN` times its size times
        the N grid's relative error of the first correction."""
        base = state["base"]
        ev0 = evaluated["base", base]  # (kept by the loop where it doubled from the first table)
        x_n, residual, table_n = table(top, masses, 0)
        refinement = x_n - ev0["x_coarse"]
        ev = dict(ev0)
        ev["corr"] = ev0["corr"] + _split_to_finer(refinement)
        ev["refinement_error"] = REFINEMENT_MARGIN * ev0["n_relative"] * l1(refinement)
        ev["counted"] = ev0["counted"] + ev["refinement_error"]
        ev["grids"] = res.error_estimate + ev["counted"]
        ev["residual"], ev["table"] = residual, table_n
        return ev

    def next_step(top: int, ev: dict, finest: bool) -> str:
        """"done", "finest" (the 4N grids), "full" (the later rungs' 2N grids), "stop" or "double"."""
        if ev["grids"] + ev["residual"] <= rtol:
            return "done"
        coarse = ev["refinement_error"] is not None
        if coarse and ev["grids"] - ev["refinement_error"] + ev["residual"] <= rtol:
            return "full"
        if not finest and plain[n][2] is not None and ev["counted"] > ev["residual"]:
            return "full" if coarse else "finest"
        if 2 * top > MAX_CONTINUUM_SHELLS or ev["grids"] >= SHELL_SHARE * rtol:
            return "full" if coarse else "stop"
        return "double"

    top = n
    while True:
        wanted = _ladder_below(top)
        on_the_grids(wanted)
        if plain[top] is None or plain[top // 2] is None or plain[top // 4] is None:
            return _failed_extrapolation(sol, scene, rtol, options, f"a coarser-shell problem did not solve on the {n}-shell grids")
        ev = evaluate(top, plain, finest)
        step = next_step(top, ev, finest)
        if step == "full":  # the later rungs' 2N grids after all: the table of this top on both grids
            fill_answer_grids()
            continue
        if step == "finest":
            finest = True  # the correction's spatial error is what misses: extrapolate it in space
            on_the_grids(list(plain))
            continue
        if step != "double":
            break
        if top == state["base"]:
            evaluated["base", top] = ev  # the first table, on both grids (the later rungs' tables add to it)
            # the later rungs on the N grid alone only if their predicted counted error leaves room
            if REFINEMENT_MARGIN * ev["n_relative"] * ev["residual"] > COARSE_ROOM * (rtol - ev["grids"]):
                state["coarse"] = False
        top *= 2
        on_the_grids([top])
        if plain[top] is None:
            top //= 2
            break
    corr, corr_error, split_error, split = ev["corr"], ev["corr_error"], ev["split_error"], ev["split"]
    counted, grids, residual, table_diag = ev["counted"], ev["grids"], ev["residual"], ev["table"]
    coarse_rungs = tuple(sorted(m for m in plain if plain[m] is not None and plain[m][1] is None))
    # the first moments per cell: the answer's, corrected with the plain cells' (at their centres)
    mom = res.p * (res.density * res.weights) + 0.5 * (res.edges[:-1] + res.edges[1:]) * corr[1:]
    return _continuum(sol, scene, rtol, options, _masses(res) + corr, mom, grids=grids, residual=residual,
                      shell_error=l1(plain[n][1] - plain[n // 2][1]) / 3.0, n=top, extra_time=timing["shells"],
                      extra={"shell_correction_error": corr_error, "shell_correction_counted": counted,
                                    "shell_correction_extrapolated_error": split_error if split and not finest
                                    else None, **table_diag,
                                    "shells_solved": tuple(sorted(m for m in plain if plain[m] is not None)),
                                    "shells_on_the_coarse_grid": coarse_rungs,
                                    "shell_refinement_error": ev["refinement_error"],
                                    "shell_scheme": "correction from plain grids" + (
                                        ", extrapolated in space (4N grids)" if finest else
                                        ", extrapolated in space (N and 2N grids)" if split else "") + (
                                        f", refined by the N grid's rungs {coarse_rungs}" if coarse_rungs else "")})


def _l1(x: np.ndarray) -> float:
    return float(np.sum(np.abs(x)))


def _aggregated(x: np.ndarray) -> np.ndarray:
    """Masses ``[zero weight, cells]`` of a grid aggregated to the grid half as fine (the inverse of
    :func:`_split_to_finer`)."""
    return np.concatenate(((x[0],), x[1::2] + x[2::2]))


def _split_to_finer(x: np.ndarray) -> np.ndarray:
    """Masses ``[zero weight, cells]`` onto the grid twice as fine: each cell shared by its halves as a density linear
    across the cell (slope from the neighbours); ``_aggregated`` of the result is ``x``."""
    cells = x[1:]
    slope = np.zeros_like(cells)  # the left half's deficit = the right half's excess
    if cells.size >= 2:
        slope[1:-1] = (cells[2:] - cells[:-2]) / 16.0
        slope[0] = (cells[1] - cells[0]) / 8.0
        slope[-1] = (cells[-1] - cells[-2]) / 8.0
    out = np.empty(1 + 2 * cells.size)
    out[0] = x[0]
    out[1::2] = 0.5 * cells - slope
    out[2::2] = 0.5 * cells + slope
    return out


def _correction_in_space(c_coarse: np.ndarray, c_fine: np.ndarray, own: list) -> tuple:
    """``(correction, its L1 error estimate, the second-order estimate, extrapolated)``: the shells' correction of
    the ``N`` and ``2N`` grids extrapolated in space onto the ``2N`` grid.

    ``c_2N + split(agg(c_2N) - c_N)/3`` aggregates to the fourth-order ``(4 agg(c_2N) - c_N)/3``.  Its error is the
    second-order estimate ``s = |agg(c_2N) - c_N|/3`` times ``max(SPLIT_MARGIN rho, SPLIT_FLOOR)``, ``rho`` the same
    extrapolation's observed relative error on ``own = [P_N, P_2N, P_4N]``; where that factor is >= 1 or ``P_4N`` is
    missing, ``c_2N`` with ``s`` (the extrapolation trusted only as far as the problem's own grids bear it out)."""
    l1, agg = _l1, _aggregated
    second = l1(agg(c_fine) - c_coarse) / 3.0
    p_n, p_2n, p_4n = own
    if p_4n is None or second == 0.0:
        return c_fine, second, second, False
    own_second = l1(agg(p_2n) - p_n) / 3.0
    if own_second == 0.0:
        return c_fine, second, second, False
    own_error = l1(p_2n + _split_to_finer(agg(p_2n) - p_n) / 3.0 - (4.0 * agg(p_4n) - p_2n) / 3.0)
    factor = max(SPLIT_MARGIN * own_error / own_second, SPLIT_FLOOR)
    if factor >= 1.0:
        return c_fine, second, second, False
    return c_fine + _split_to_finer(agg(c_fine) - c_coarse) / 3.0, factor * second, second, True


def _shell_table(ladder: list, thin: bool = False, start: bool = False) -> tuple:
    """``(continuum, residual, diagnostics)`` from the masses ``[P(n), P(n/2), P(n/4)(, P(n/8))]`` of one grid.

    The midpoint rule's error is ``a h^2 + b h^4 + ...``, so ``R(n/2, n) = (4 P(n) - P(n/2))/3``.  With ``P(n/8)``
    the observed ratio of ``R``'s successive differences decides:

    * above :data:`ROMBERG_MAX_RATIO` (pre-asymptotic): ``R(n/2, n)``, its last difference undivided as residual;
    * at least :data:`ROMBERG_RATIO`: Romberg's ``(16 R(n/2, n) - R(n/4, n/2))/15``, residual its difference over 15;
    * below: ``R(n/2, n)``, residual its difference over ``min(rho - 1, 15)``, at least :func:`_shell_residual`'s;
      ``rho`` is capped by the ``P`` ratio where that is below :data:`SECOND_ORDER_CLEAR`.

    Without ``P(n/8)``: ``R(n/2, n)`` with :func:`_shell_residual`.  The zero weight and the cells take their
    branches apart and the residuals add.  ``thin`` (graded shells): :func:`_thin_layer_table`."""
    if thin:
        return _thin_layer_table(ladder, start)
    if len(ladder) < 4:
        x, residual, info = _uniform_table(ladder)
        info.pop("l1", None)
        return x, residual, info
    # (the zero weight as numpy scalars: the same arithmetic as on a one-element array, without its overhead)
    (x0, r0, i0), (x1, r1, i1) = (_uniform_table([m[part] for m in ladder]) for part in (0, slice(1, None)))
    p_top, p_half, r_top, r_half = (a + b for a, b in zip(i0.pop("l1"), i1.pop("l1")))  # the whole ladder's
    info = dict(i1, shell_order_ratio=p_half / p_top if p_top > 0.0 else math.inf,
                richardson_order_ratio=r_half / r_top if r_top > 0.0 else math.inf,
                zero_weight_extrapolation_order=i0["shell_extrapolation_order"],
                zero_weight_order_ratios=(i0["shell_order_ratio"], i0["richardson_order_ratio"]))
    # the solves' spatial errors weighted by the larger of the two parts' weights (:func:`_shell_combined`)
    info["grid_weights"] = max(i0["shell_weights"], i1["shell_weights"], key=lambda w: sum(abs(c) for c in w))
    return np.concatenate(((x0,), x1)), r0 + r1, info


def _uniform_table(ladder: list) -> tuple:
    """:func:`_shell_table`'s rules on uniform shells for one vector of masses (the whole ladder, or one part)."""
    p_n, p_h, p_q = ladder[:3]
    r_n, r_h = (4.0 * p_n - p_h) / 3.0, (4.0 * p_h - p_q) / 3.0
    residual, rho_p, d_top = _shell_residual(p_n, p_h, p_q)
    info = {"shell_order_ratio": rho_p, "shell_extrapolation_order": 4, "shell_weights": (4 / 3, -1 / 3, 0.0, 0.0)}
    if len(ladder) < 4:
        return r_n, residual, info
    r_q = (4.0 * p_q - ladder[3]) / 3.0
    d_half = float(np.sum(np.abs(r_h - r_q)))
    rho_r = d_half / d_top if d_top > 0.0 else math.inf
    info["richardson_order_ratio"] = rho_r
    # the L1 differences of the P and of the R, which add over parts (:func:`_shell_table`'s whole-ladder ratios)
    info["l1"] = (float(np.sum(np.abs(p_n - p_h))), float(np.sum(np.abs(p_h - p_q))), d_top, d_half)
    if rho_r > ROMBERG_MAX_RATIO:
        return r_n, max(residual, d_top), info
    if rho_p >= SHELL_ORDER_RATIO and rho_r >= ROMBERG_RATIO:
        x_n, x_h = (16.0 * r_n - r_h) / 15.0, (16.0 * r_h - r_q) / 15.0
        info["shell_extrapolation_order"] = 6
        info["shell_weights"] = (64 / 45, -20 / 45, 1 / 45, 0.0)  # x_n in the P's
        return x_n, float(np.sum(np.abs(x_n - x_h))) / 15.0, info
    # below second order in P, R keeps part of that term, which need not fall faster than the P differences
    rho = rho_r if rho_p >= SECOND_ORDER_CLEAR else min(rho_r, rho_p)
    return r_n, max(residual, d_top / min(15.0, max(rho - 1.0, 1.0))), info


def _thin_layer_table(ladder: list, start: bool = False) -> tuple:
    """:func:`_shell_table` where the wall's layer is thin (graded shells, whose ladder converges at the
    frozen layer's order 2.5 rather than 4).

    ``R(n/2, n)`` is the continuum (never Romberg); the residual sums, over the zero weight and the cells,
    ``|R(n/2, n) - R(n/4, n/2)|`` over ``min(rho_R, THIN_LAYER_RATIO) - 1``, or :func:`_shell_residual`'s estimate
    where ``rho_P < SHELL_ORDER_RATIO``.  ``start`` (both ends graded): a ratio above :data:`ROMBERG_MAX_RATIO`
    counts the last difference undivided."""
    p_n, p_h, p_q = ladder[:3]
    r_n, r_h = (4.0 * p_n - p_h) / 3.0, (4.0 * p_h - p_q) / 3.0
    r_q = (4.0 * p_q - ladder[3]) / 3.0 if len(ladder) > 3 else None

    def r_ratio(part: slice, d_r: float) -> float:  # of the R differences, from P(n/8)
        if r_q is None:
            return THIN_LAYER_RATIO
        d_half = float(np.sum(np.abs(r_h[part] - r_q[part])))
        return d_half / d_r if d_r > 0.0 else math.inf

    residual = 0.0
    ratios = []
    for part in (slice(0, 1), slice(1, None)):  # the zero weight, the cells
        below_second, rho_p, d_r = _shell_residual(p_n[part], p_h[part], p_q[part])
        rho_r = r_ratio(part, d_r)
        if rho_p < SHELL_ORDER_RATIO:
            residual += below_second
        elif start and rho_r > ROMBERG_MAX_RATIO:  # both ends graded, a crossing of terms: the last difference
            residual += d_r
        else:
            residual += d_r / max(min(rho_r, THIN_LAYER_RATIO) - 1.0, 1.0)
        ratios.append((rho_p, rho_r))
    _, rho_all, d_all = _shell_residual(p_n, p_h, p_q)
    info = {"shell_order_ratio": rho_all, "shell_extrapolation_order": 4,
            "shell_weights": (4 / 3, -1 / 3, 0.0, 0.0), "zero_weight_order_ratios": ratios[0]}
    if r_q is not None:
        info["richardson_order_ratio"] = r_ratio(slice(None), d_all)
    return r_n, residual, info


def _masses(r: Any) -> np.ndarray:
    """``[zero weight, cell masses]`` of a finite-volume result."""
    return np.concatenate(([r.zero_weight], r.density * r.weights))


def _rebuilt(sol: Any, scene: tuple, rtol: float, options: dict, *, masses: np.ndarray,
             moments: Optional[np.ndarray], estimate: float, extra: dict, extra_time: float = 0.0,
             failure: Optional[str] = None) -> Any:
    """A result on the grid of ``sol`` from the engine's builder
    (:func:`~diffusion_pr.fokker_planck.engine.build_result`): masses ``[zero weight, cells]``, first ``moments``,
    L1 ``estimate``, ``failure`` reason or None, ``extra`` diagnostics."""
    from ..fokker_planck.engine import build_result

    res, prep = sol.result, sol.prep
    timings = {**res.diagnostics["timings"], "shells": extra_time}
    timings["total"] = res.wall_time + extra_time
    kept = {k: v for k, v in res.diagnostics.items() if k != "floor_ghosts"}  # (the n-shell solve's floor masses)
    # every problem of the table conserves p0 where the closure does, so does their combination
    mean_full = prep.p0 + float(res.diagnostics["mean_error"])
    return build_result(prep, backend=res.backend, edges=res.edges, y=masses, moments=moments, estimate=estimate,
                        rtol=rtol, timings=timings, extra={**kept, **extra}, mean_full=mean_full, failure=failure)


def _continuum(sol: Any, scene: tuple, rtol: float, options: dict, masses: np.ndarray, moments: np.ndarray, *,
               grids: float, residual: float, shell_error: float, n: int, extra_time: float, extra: dict) -> Any:
    """The continuum closure's result: the extrapolated ``masses`` and first ``moments`` on the grid of ``sol``, its
    estimate the grids' ``grids`` plus the shells' ``residual`` (:func:`_rebuilt`).

    Where the extrapolation in the number of shells turns a mass negative (a tail cell or the zero weight far from
    the asymptotic regime, where the table's differences are round-off of masses near 0) the cell keeps the
    ``n``-shell solve's own mass (>= 0), and the change is added to the residual: the same rule as the engine's
    Richardson extrapolation in space."""
    neg = masses < 0.0
    if neg.any():
        own = _masses(sol.result)
        residual += float(np.abs(masses[neg] - own[neg]).sum())
        masses, moments = masses.copy(), moments.copy()
        masses[neg] = own[neg]
        moments[neg[1:]] = (sol.result.p * own[1:])[neg[1:]]
    return _rebuilt(sol, scene, rtol, options, masses=masses, moments=moments, estimate=grids + residual,
                    extra_time=extra_time,
                    extra={"shell_extrapolation": True, "shell_error": shell_error,
                           "shell_extrapolation_residual": residual, "grid_estimate": grids,
                           "n_shells": (n, n // 2, n // 4), **extra})


def _shell_combined(sol: Any, scene: tuple, rtol: float, options: dict) -> Any:
    """The continuum closure from full solves of ``n/2``, ``n/4`` (and ``n/8``) shells on ``sol``'s grids.

    Masses combine by :func:`_shell_table`; the grids' estimate is the solves' estimates with the table's weights in
    absolute value.  Where the sum misses ``rtol``, ``2n`` shells are solved (up to :data:`MAX_CONTINUUM_SHELLS`)."""
    from ..fokker_planck.grid import same_grid

    res = sol.result
    n = int(res.diagnostics["n_shells"])
    solved = {n: res}

    def on_the_grid(m: int) -> Any:
        return _coarser_on_grid(sol, m, scene, rtol, options, plain=None).result

    def usable(r: Any) -> bool:
        return bool(r.success and r.edges is not None and same_grid(r.edges, res.edges))

    while True:
        for m in (n // 2, n // 4) + ((n // 8,) if n % 8 == 0 and n // 8 >= MIN_ROMBERG_SHELLS else ()):
            if m not in solved:
                solved[m] = on_the_grid(m)
        three = [solved[n >> k] for k in range(3)]
        if not all(usable(r) for r in three):
            why = "; ".join(f"{int(r.diagnostics.get('n_stages', 0))} stages: {r.message}" for r in three
                            if not r.success)
            return _failed_extrapolation(sol, scene, rtol, options, why or "a solve's grids differ from the first one's")
        used = three + ([solved[n // 8]] if n % 8 == 0 and n // 8 in solved and usable(solved[n // 8]) else [])
        masses = [_masses(r) for r in used]
        x, residual, table = _shell_table(masses, thin=scene[5] != "uniform", start=scene[5] == "ends")
        weights = table["shell_weights"][:len(used)]
        grids = sum(abs(c) * r.error_estimate for c, r in zip(table.get("grid_weights", weights), used))
        if grids + residual <= rtol or 2 * n > MAX_CONTINUUM_SHELLS or grids >= SHELL_SHARE * rtol:
            break
        n *= 2  # the residual falls 16x per doubling: one more solve on the same grids
        solved[n] = on_the_grid(n)
    # the first moments per cell, extrapolated alike
    w = res.weights
    mom = sum(c * r.p * r.density * w for c, r in zip(weights, used))
    return _continuum(sol, scene, rtol, options, x, mom, grids=grids, residual=residual,
                      shell_error=float(np.sum(np.abs(masses[0] - masses[1]))) / 3.0, n=n,
                      extra_time=sum(r.wall_time for r in solved.values() if r is not res),
                      extra={"shells_solved": tuple(sorted(m for m, r in solved.items() if usable(r))),
                             "shell_scheme": "combined solves", **table})
