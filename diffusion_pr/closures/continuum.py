r"""The continuum closure: the shell closures extrapolated in the number of shells (docs/closures.md).

The shell sum is the exponential midpoint rule in the diffusion time with exact ``tau``-midpoints: symmetric, its
error even in the shell width.  The ``n``-shell problem is solved to ``rtol`` on nested grids; the ``n/2``-,
``n/4``- and ``n/8``-shell problems are integrated on the same grids (``grid=`` of
:func:`~diffusion_pr.fokker_planck.engine.solve_fv_full`), so their masses combine cell by cell
(:func:`_shell_table`: Richardson or Romberg in the shells, with a residual).  The answer is built by the engine's
one result builder (:func:`~diffusion_pr.fokker_planck.engine.build_result`).

Units: masses and L1 distances dimensionless; pressures in the unit of ``E_star``.
"""
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
#: the later rungs of the ladder (where it doubles past its first table) are solved on the answer's N grid alone
#: where the shells are graded (:func:`_shell_corrected`); their refinement's spatial error is counted as this
#: multiple of its size times four times the first table's correction's relative second-order error
REFINEMENT_MARGIN = 3.0
#: ... where that counted error, predicted from the first table's residual, takes at most this share of the room the
#: grids' estimate leaves in rtol (else the later rungs get both grids from the start)
COARSE_ROOM = 0.5
#: the shells grow only while the grids' estimate leaves the extrapolation's residual this share of rtol at least
SHELL_SHARE = 0.9
#: where the grids' estimate alone takes SHELL_SHARE of rtol, the first solve is repeated at this fraction of rtol
GRID_RETRY_FRACTION = 0.25
#: the observed ratio of successive shell differences above which the midpoint rule's second order is taken as
#: asymptotic (4 at second order; 3.0 is an order of 1.58)
SHELL_ORDER_RATIO = 3.0
#: ... and the ratio below which that second order is not yet clear (an order of 1.81): the shells' table then
#: divides the last ``R(n/2, n)`` difference by at most that ratio minus 1 (:func:`_uniform_table`)
SECOND_ORDER_CLEAR = 3.5
#: the observed ratio of successive ``R(n/2, n)`` differences above which their fourth order is taken as asymptotic
#: and Romberg's sixth-order column is used (16 at fourth order; 12 is an order of 3.58)
ROMBERG_RATIO = 12.0
#: the largest such ratio Romberg trusts (16 x 1.0625): above it the ladder is taken as not yet asymptotic
#: (docs/closures.md "Pre-asymptotic shell ladders and thin starts")
ROMBERG_MAX_RATIO = 17.0
#: where the wall's layer is thin (graded shells), the largest ratio of successive ``R(n/2, n)`` differences the
#: shells' table trusts: ``2^2.5``, the order the frozen layer leaves after one Richardson step (docs/closures.md
#: "The thin layer's table")
THIN_LAYER_RATIO = 2.0 ** 2.5
#: the plain grids' correction extrapolated in space from the N and 2N grids (:func:`_correction_in_space`): its
#: own error is the second-order estimate times this multiple of the same extrapolation's observed error on the
#: n-shell problem's own three grids, relative to their second-order estimate (docs/closures.md "The correction
#: extrapolated in space"); the extrapolation is used where the factor is below 1
SPLIT_MARGIN = 4.0
#: ... and never less than this fraction of the second-order estimate
SPLIT_FLOOR = 0.1
#: the fewest shells a coarser plain solve of the table has (the n/8 of 48)
MIN_ROMBERG_SHELLS = 6


def solve_full(problem: Any, backend: str, rtol: float, options: dict, **engine: Any) -> Any:
    """The :class:`~diffusion_pr.fokker_planck.engine.FVSolution` of a closure's staged problem by the
    finite-volume backend ``backend`` (a registered name; its options ``options`` checked by the caller;
    ``engine``: the ``grid``, ``plain`` and ``warm_start`` arguments of its ``solve_full``, None ones left out)."""
    from ..fokker_planck.backends import get_backend

    solver = get_backend(backend)
    full = sys.modules[solver.__module__].solve_full
    return full(problem, rtol=rtol, **options, **{k: v for k, v in engine.items() if v is not None})


def _shell_residual(m_n: np.ndarray, m_h: np.ndarray, m_q: np.ndarray) -> tuple:
    """``(estimate, rho, difference)``: the L1 error of ``R(n/2, n) = (4 m(n) - m(n/2))/3`` from the masses of
    ``n``, ``n/2`` and ``n/4`` shells, the observed ratio ``rho = |m(n/2) - m(n/4)| / |m(n) - m(n/2)|`` (L1; 4 for
    the midpoint rule's second order) and ``|R(n/2, n) - R(n/4, n/2)|`` in L1.

    With an error ``a n^-p`` the extrapolation leaves ``a n^-p (4 - 2^p)/3`` and
    ``R(n/2, n) - R(n/4, n/2) = a n^-p (4 - 2^p)(1 - 2^p)/3``: the error is that difference over ``rho - 1``
    (``rho = 2^p``).  Where ``rho`` >= :data:`SHELL_ORDER_RATIO` the second order is taken as asymptotic and
    the difference is the fourth-order term, over 15; below it (the last shells freeze a thin wall layer,
    :func:`~diffusion_pr.closures.shells.shell_grading`) over ``max(rho - 1, 1)``."""
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
                  keep: bool, warm_start: Any = None, note: Optional[dict] = None) -> Any:
    """The closure's :class:`~diffusion_pr.fokker_planck.engine.FVSolution` with the closure and the shell count in
    the result's diagnostics (and ``note``); with ``keep`` the last level's plain masses too (the shell
    extrapolation's corrections are taken from them)."""
    sol = solve_full(problem, backend, rtol, options, plain="keep" if keep else None, warm_start=warm_start)
    res = sol.result
    return replace(sol, result=replace(res, diagnostics={**res.diagnostics, "closure": closure,
                                                         "n_shells": int(shells.q.size), **(note or {})}))


def _coarser_on_grid(sol: Any, m: int, scene: tuple, rtol: float, options: dict, *, plain: Optional[str]) -> Any:
    """The ``m``-shell problem of ``scene = (spectrum, E, p0, z, closure, grading)`` solved on the
    grids of ``sol`` (the ``n``-shell solution), in full (``plain=None``) or for the plain masses of some of its
    grids alone (``plain`` a mode of :data:`~diffusion_pr.fokker_planck.engine.PLAIN_GRIDS`); a balance with no root
    there is a failed solution that says so."""
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
    """The continuum closure from the ``n``-shell solution ``sol`` (:func:`_shell_corrected` where its plain masses
    were kept, else :func:`_shell_combined`)."""
    z = scene[3]
    res = sol.result
    if z == 0.0 or not res.success or res.edges is None or sol.grid is None:
        diag = {**res.diagnostics, "shell_error": 0.0 if z == 0.0 else None, "shell_extrapolation": False}
        return replace(res, diagnostics=diag)
    if sol.plain is not None:
        out = _shell_corrected(sol, scene, rtol, options)
        if out.success:
            return out
        # the plain grids' correction misses rtol (on steep spectra at small loads its spatial error dominates):
        # the n/2 and n/4-shell problems are solved in full instead
        combined = _shell_combined(sol, scene, rtol, options)
        tried = out.diagnostics["timings"].get("shells", 0.0)
        timings = dict(combined.diagnostics["timings"])
        timings["shells"] = timings.get("shells", 0.0) + tried
        return replace(combined, wall_time=combined.wall_time + tried,
                       diagnostics={**combined.diagnostics, "timings": timings,
                                    "shell_correction_missed": out.message})
    return _shell_combined(sol, scene, rtol, options)


def _shell_corrected(sol: Any, scene: tuple, rtol: float, options: dict) -> Any:
    """The continuum closure as ``res = sol.result`` plus a correction from plain grids.

    ``res`` (``n`` shells) is extrapolated in space; the difference between it and the continuum is a
    difference between problems on the same grid, whose spatial errors are correlated: it is taken from the
    plain masses ``P`` of the last level's grids alone (``plain=`` of :func:`~diffusion_pr.fokker_planck.engine.solve_fv_full`),
    solved for ``n/2``, ``n/4`` and ``n/8`` shells on ``res``'s grids.  With ``top`` the most shells solved, the
    shells' table (:func:`_shell_table`) gives the continuum ``X`` on each grid (Richardson ``R(top/2, top)``, or
    Romberg's sixth order where the observed order allows it) and its residual; the correction is
    ``c = X(top) - P(n)`` per grid, and the answer ``m(res) + c``.

    First from the ``N`` and ``2N`` grids alone: ``c`` on the ``2N`` grid extrapolated in space
    (:func:`_correction_in_space`; ``c_2N`` itself where the problem's own grids do not trust that).  Its error is
    counted as the extrapolation's own estimate on uniform shells, and at the second-order size
    ``|agg(c_2N) - c_N|/3`` (the error of ``c_2N``) where the wall's layer is thin (docs/closures.md "The
    correction's own error counted").  Where the counted error leaves the sum above ``rtol``, the ``4N``
    grids are integrated too and the correction is extrapolated in space as the answer is,
    ``(4 agg(c_4N) - c_2N)/3`` on the ``2N`` grid, its error the engine's estimate of that extrapolation (the full
    solves' price, nothing integrated twice).  Where the sum still misses ``rtol`` the ``2 top``-shell problem is
    solved on the same grids (per doubling, the grids the correction uses)."""
    from ..fokker_planck.engine import RICHARDSON_DIVISOR
    from ..fokker_planck.grid import same_grid

    res = sol.result
    n = int(res.diagnostics["n_shells"])
    plain = {n: list(sol.plain)}
    timing = {"shells": 0.0}
    finest = False  # the correction from the 4N grids too, extrapolated in space
    evaluated: dict = {}  # ("base", n) -> the first table's evaluation (the later rungs' tables add to it)
    thin = scene[5] != "uniform"  # graded shells: the wall's layer is thin (shell_grading)
    # the later rungs on the N grid alone (graded shells only): their refinement of the first table's continuum is
    # added to that table's correction; "coarse" off once the 2N grids are wanted after all (the margin misses, or
    # the 4N grids)
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
        """Grid ``g`` (the plain mode ``mode`` integrates it alone) of the shell counts ``ms`` that lack it."""
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
        """The correction and its errors from the table of ``top`` shells (``masses`` the plain masses by shell
        count, every rung of ``_ladder_below(top)`` in it)."""
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
        # counted: on uniform shells the extrapolated correction's own error; where the wall's layer is thin the
        # second-order size, a margin the thin layer's table needs (docs/closures.md "The correction's own error
        # counted")
        ev["counted"] = ev["split_error"] if ev["split"] and not finest and not thin else ev["corr_error"]
        ev["grids"] = res.error_estimate + ev["counted"]
        # the N grid's continuum, and that grid's relative error of the correction (4 s / |c_2N|: the later rungs'
        # refinement, a difference of the same kind, is counted with it)
        size = l1(c[1])
        ev["x_coarse"], ev["n_relative"] = c[0] + masses[n][0], 4.0 * ev["corr_error"] / size if size > 0.0 else 0.0
        return ev

    def evaluate_coarse(top: int, masses: dict) -> dict:
        """:func:`evaluate` where the rungs above the first table's (``state["base"]``) are on the N grid alone: the
        first table's correction (extrapolated in space as there) plus the refinement of the N grid's continuum
        from the first table's to this one's, split onto the 2N grid; that refinement's spatial error is counted as
        :data:`REFINEMENT_MARGIN` times its size times the N grid's relative error of the first correction
        (``4 s / |c_2N|``, ``s`` that correction's second-order estimate on the 2N grid)."""
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
        """What the ladder does after the table of ``top`` shells: "done", "finest" (the correction's spatial
        error misses: the 4N grids), "full" (the later rungs' 2N grids: their refinement's counted error is what
        misses), "stop" (no room or no more shells) or "double"."""
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
            # the later rungs on the N grid alone where their refinement's counted error, predicted from this
            # table's residual (the refinement's expected size), leaves room for theirs
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
    """The L1 norm of masses ``[zero weight, cells]``."""
    return float(np.sum(np.abs(x)))


def _aggregated(x: np.ndarray) -> np.ndarray:
    """Masses ``[zero weight, cells]`` of a grid aggregated to the grid half as fine (the inverse of
    :func:`_split_to_finer`)."""
    return np.concatenate(((x[0],), x[1::2] + x[2::2]))


def _split_to_finer(x: np.ndarray) -> np.ndarray:
    """Masses ``[zero weight, cells]`` of a grid onto the grid twice as fine (its cells halved in the monitor
    coordinate): each cell's mass shared by its two halves as a density linear across the cell would share it, the
    slope from the neighbours (one-sided at the ends); the zero weight as it is.  ``agg`` of the result is ``x``."""
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
    """``(correction, its L1 error estimate, the second-order estimate, extrapolated)``: the shells' correction
    ``c`` of the ``N`` and ``2N`` grids (``[zero weight, cells]`` each) extrapolated in space onto the ``2N`` grid.

    ``c`` converges at second order in the cell width, so ``R = (4 agg(c_2N) - c_N)/3`` is the fourth-order
    correction on the ``N`` grid.  On the ``2N`` grid: ``c_2N + split(agg(c_2N) - c_N)/3``
    (:func:`_split_to_finer`), which aggregates to ``R``.  Its error is not observed (that needs the ``4N``
    grids); it is taken as the second-order estimate ``s = |agg(c_2N) - c_N|/3`` times
    ``max(SPLIT_MARGIN rho, SPLIT_FLOOR)``, with ``rho`` the same extrapolation's observed error on the
    ``n``-shell problem's own masses ``own = [P_N, P_2N, P_4N]`` (against ``(4 agg(P_4N) - P_2N)/3``) over its
    ``s``.  Where that factor is not below 1, or ``P_4N`` is missing, ``c_2N`` with ``s`` (second order).  The
    caller counts ``s`` in the answer's estimate either way (docs/closures.md "The correction extrapolated in
    space")."""
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

    The exponential midpoint rule with exact ``tau``-midpoints is symmetric: its error is even in the shell width,
    ``a h^2 + b h^4 + c h^6 + ...`` where the coefficients are smooth (``R(n/2, n) = (4 P(n) - P(n/2))/3`` then
    falls about 16x per doubling).  Near ``p* = zeta q E*/2`` at small ``zeta`` the order is lower.  The observed ratio of ``R``'s successive differences decides, with ``P(n/8)``:

    * above :data:`ROMBERG_MAX_RATIO`: the order is not observed (the coarse end of the ladder is pre-asymptotic and
      a finer ``R`` may lie near the continuum by a crossing of its terms, docs/closures.md "Pre-asymptotic shell
      ladders and thin starts"): ``R(n/2, n)`` with its last difference, undivided, as the residual;
    * at least :data:`ROMBERG_RATIO` (fourth order asymptotic): Romberg's next column,
      ``(16 R(n/2, n) - R(n/4, n/2))/15``, with its difference from the same at half the shells over 15 as the
      residual (that assumes a fourth order only; the sixth it has gives /63, so the estimate is about 4x safe);
    * below: ``R(n/2, n)`` with its difference from ``R(n/4, n/2)`` over ``rho - 1`` (``rho`` that ratio,
      ``rho - 1`` at most 15), never less than :func:`_shell_residual` says from the ``P`` alone; where the ``P``
      differences fall slower than :data:`SECOND_ORDER_CLEAR` (no clear second order), ``rho`` is at most their
      ratio: a term below second order remains in ``R`` and need not fall faster than they do.

    Without ``P(n/8)`` (a balance with no root on 6 shells, or ``n`` not divisible by 8), ``R(n/2, n)`` with
    :func:`_shell_residual`.  ``diagnostics["shell_weights"]``: the continuum as weights of ``P(n) ... P(n/8)``
    (for the first moments and the spatial errors of full solves, :func:`_shell_combined`).

    With ``P(n/8)``, these rules decide on the zero weight (the probability below the
    floor) and on the cells apart (:func:`_uniform_table` on each): each part takes its own branch, continuum and
    residual, and the residuals add (the zero weight converges on its own, and in the L1 sums the cells' larger
    differences would hide it).  The diagnostics keep the whole ladder's ratios; ``shell_extrapolation_order`` and
    ``shell_weights`` are the cells', ``zero_weight_extrapolation_order`` and ``zero_weight_order_ratios`` the zero
    weight's, ``grid_weights`` the larger of the two parts' weights.

    With ``thin`` (graded shells: the wall's layer is thin, :func:`shell_grading`) :func:`_thin_layer_table`;
    ``start``: the shells are graded at both ends ("ends")."""
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
    # where the P differences fall clearly slower than second order, a term below second order is in the ladder: R
    # keeps part of it, and its remainder need not fall faster than the P differences do
    rho = rho_r if rho_p >= SECOND_ORDER_CLEAR else min(rho_r, rho_p)
    return r_n, max(residual, d_top / min(15.0, max(rho - 1.0, 1.0))), info


def _thin_layer_table(ladder: list, start: bool = False) -> tuple:
    """``(continuum, residual, diagnostics)`` of :func:`_shell_table` where the wall's layer is thin.

    There the shells' error after one Richardson step is not of fourth order: the ratios of successive
    ``R(n/2, n)`` differences run 5-9 per doubling (the frozen layer), with single ratios of 13-16 between them
    that the next doubling does not follow; and the zero weight, the probability below the floor, converges on
    its own, at first order on the coarse shells of some scenes, hidden in the L1 sums by the cells' larger
    differences.  So ``R(n/2, n)`` is the continuum (never Romberg), and its residual is summed over the zero weight
    and the cells, each ``|R(n/2, n) - R(n/4, n/2)|`` over ``min(rho_R, THIN_LAYER_RATIO) - 1`` (``rho_R`` its own
    observed ratio), or over ``max(rho_P - 1, 1)`` where its ``P`` differences fall slower than
    :data:`SHELL_ORDER_RATIO` (not yet second order); docs/closures.md "The thin layer's table".

    ``start`` (shells graded at both ends, "ends"): an ``R`` ratio above :data:`ROMBERG_MAX_RATIO` is taken for a
    crossing of terms on a pre-asymptotic ladder, and that entry's last ``R`` difference counts undivided, as the
    uniform table counts it (docs/closures.md "A ladder below second order on uniform shells")."""
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
    """A result on the grid of ``sol`` (the ``n``-shell solution) made by the engine's one builder
    (:func:`~diffusion_pr.fokker_planck.engine.build_result`, with its one meaning of ``success``): the masses
    ``[zero weight, cells]``, the cells' first ``moments``, the L1 ``estimate``, ``failure`` (a reason it is no
    answer, or None) and ``extra`` diagnostics over the ``n``-shell solve's."""
    from ..fokker_planck.domain import prepare
    from ..fokker_planck.engine import build_result

    res = sol.result
    problem, _ = shell_problem(scene, int(res.diagnostics["n_shells"]))
    prep = prepare(problem, rtol=rtol, p_floor=options.get("p_floor"), on_grid=sol.grid.spec)
    timings = {**res.diagnostics["timings"], "shells": extra_time}
    timings["total"] = res.wall_time + extra_time
    kept = {k: v for k, v in res.diagnostics.items() if k != "floor_ghosts"}  # (the n-shell solve's floor masses)
    # the mean checked: every problem of the shells' table conserves p0 where the closure does (a balance, or no
    # drift), and so does their combination; the n-shell solve's full first moment is the one computed
    mean_full = prep.p0 + float(res.diagnostics["mean_error"])
    return build_result(prep, backend=res.backend, edges=res.edges, y=masses, moments=moments, estimate=estimate,
                        rtol=rtol, timings=timings, extra={**kept, **extra}, mean_full=mean_full, failure=failure)


def _continuum(sol: Any, scene: tuple, rtol: float, options: dict, masses: np.ndarray, moments: np.ndarray, *,
               grids: float, residual: float, shell_error: float, n: int, extra_time: float, extra: dict) -> Any:
    """The continuum closure's result: the extrapolated ``masses`` and first ``moments`` on the grid of ``sol``, its
    estimate the grids' ``grids`` plus the shells' ``residual`` (:func:`_rebuilt`)."""
    return _rebuilt(sol, scene, rtol, options, masses=masses, moments=moments, estimate=grids + residual,
                    extra_time=extra_time,
                    extra={"shell_extrapolation": True, "shell_error": shell_error,
                           "shell_extrapolation_residual": residual, "grid_estimate": grids,
                           "n_shells": (n, n // 2, n // 4), **extra})


def _shell_combined(sol: Any, scene: tuple, rtol: float, options: dict) -> Any:
    """The continuum closure from the ``n``-shell result ``res`` and full solves of fewer shells on its grids.

    The ``n/2``-, ``n/4``- and (where ``n/8 >= MIN_ROMBERG_SHELLS`` shells solve there) ``n/8``-shell problems
    are solved on ``res``'s grids (``grid=`` of :func:`~diffusion_pr.fokker_planck.engine.solve_fv_full`),
    so the cell masses combine cell by cell as :func:`_shell_table` says (Richardson, or Romberg where the
    observed order allows it), its residual added to the grids' estimate: the solves' own estimates with the
    table's weights in absolute value (``(4 e(n) + e(n/2))/3`` for Richardson; the spatial errors of the solves
    are not assumed to cancel).  Where the sum misses ``rtol``, the ``2n``-shell problem is solved on the same
    grids and the table is made again from the top (one solve per doubling, up to :data:`MAX_CONTINUUM_SHELLS`).
    Used where the plain grids' correction misses (:func:`shell_extrapolated`) or no plain masses were kept."""
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
