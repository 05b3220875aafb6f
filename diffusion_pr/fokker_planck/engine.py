"""The shared finite-volume engine: problem -> nested grids -> exponential integration -> result.

Every finite-volume backend (``native``, ``pypde``, ``fipy``) goes through
:func:`solve_fv`; a backend contributes only its way of writing the operator
(an ``assemble(edges, f_c, a_faces)`` returning the tridiagonal bands of
:mod:`.operator`) and, optionally, its own time loop.  The engine owns

* the classification of the wall by Feller's criterion (``f ~ p^k`` reaches
  ``p = 0`` iff ``k < 2``; :func:`diffusion_pr.models.wall_reached`),
* the non-contact weight: the absorbed mass at ``p = 0`` where the wall is
  reached, else the mass that reached the floor ``p_floor = FLOOR * p0`` (fixed
  by the problem, not by the grid; reported in the diagnostics),
* the nested grids (:mod:`.grid`), the start (two cells around ``p0``
  carrying mass 1 and mean ``p0`` exactly),
* the time integration: per stage ``exp(dtau L)`` by CRAM-16
  (:mod:`.cram`); a balance multiplier ``A`` is held constant over a substep
  (one per stage for ``balance_per_stage`` problems such as the closures, else
  substeps refined with the grids) and found by Newton steps with the exact
  derivative of the CRAM map so that the mean is ``p0`` at every substep end;
  all stages of a grid run in one compiled call (:mod:`._kernels`); a
  ``tau``-dependent coefficient is sampled at segment midpoints (exponential
  midpoint rule),
* the error control: three nested grids ``N, 2N, 4N`` (time substeps doubled
  with the cells), Richardson extrapolation of order 2 on each pair, and the
  estimate ``||R(2N,4N) - R(N,2N)||_1 / 7`` of the reported ``R(2N, 4N)``,
  refined until it meets ``rtol``,
* the one result builder and diagnostics schema (:func:`build_result`).
"""
from __future__ import annotations

import contextlib
import functools
import math
import threading
import time
from dataclasses import dataclass, field, replace
from typing import Callable, Optional, Sequence

import numpy as np

from ..models import breakpoints_of, evaluate_vectorized, wall_reached, zero_power_of
from ..problem import FokkerPlanckProblem, StagedProblem
from ..result import PressureDistribution
from .expm import ALPHA as CRAM_ALPHA
from .expm import ALPHA0 as CRAM_ALPHA0
from .expm import CANCELLED, PFD_RESIDUES, expm_tridiagonal
from .expm import ERROR_BOUND as CRAM_ERROR_BOUND
from .expm import THETA as CRAM_THETA
from .grid import GridSpec, Remap, edges_for, knot_indices, same_grid
from .operator import bands as fv_bands
from .operator import centres

__all__ = ["FLOOR", "MAX_CELLS", "Prepared", "prepare", "solve_fv", "solve_fv_full", "FVSolution", "GridFamily",
           "WarmStart", "build_result", "DIAGNOSTIC_KEYS"]

#: the domain ends where a diffusion of the problem's largest spread leaves it with probability at most
#: TAIL_FRACTION * rtol (Gaussian bound, :func:`_tail_quantile`): z = 6.1 spreads at rtol 1e-6
TAIL_FRACTION = 1e-3
#: floor of the grid where the wall is not reached, relative to p0 (dimensionless)
FLOOR = 1e-6
#: default cap on the cells of the finest grid
MAX_CELLS = 65536
#: largest p0 / spread whose distribution double precision can resolve
MAX_RATIO = 1e12
#: ||R(2N,4N) - R(N,2N)|| / RICHARDSON_DIVISOR estimates the error of R(2N,4N): 2^p - 1 for order p;
#: 7 assumes third order (the extrapolated values converge at order 3-4: wall cells, knots), conservative by
#: up to 2 where they converge at order 4
RICHARDSON_DIVISOR = 7.0
#: the same where a vanishing diffusivity reaches the wall (``f ~ p^k``, ``0 < k < 2``: Feller's exit boundary):
#: there the extrapolated values converge at second order only, so 2^2 - 1.  Measured on Feller's solution
#: (``f = p/p_1``, against the closed form; ``benchmarks/fp_random_truth.py``): with 7 the true L1 error was
#: 2.05-3.32x the estimate (2.33 on most) on 61 of 65 random problems (3 above rtol 1e-6), and successive levels'
#: errors fell as ``N^-1.9``; with 3 it is 0.88-1.34x.  Since the exit walls' grading (:data:`C_EXIT_WALL`) only an
#: exit wall on another problem's ungraded grid family uses it (:func:`_exit_wall`)
EXIT_RICHARDSON_DIVISOR = 3.0
#: the weight of the logarithmic grading towards an exit wall (``f ~ p^k``, ``0 < k < 2``, the wall reached): its
#: wall face is first order (the density at ``p = 0`` and ``d(f Pr)/dp`` there from the wall cell alone), so cells
#: that shrink geometrically towards ``p = 0`` down to :data:`EXIT_WALL_DEPTH` make that error negligible, and the
#: extrapolated masses converge at fourth order as elsewhere (:data:`RICHARDSON_DIVISOR`).  Measured (twenty-seventh
#: session, rtol 1e-6, against Feller's solution and the absorbed squared Bessel / CIR closed forms): 4184-65536
#: cells and 7-1456 ms ungraded (one case failed at 65536 cells), 272-512 cells and 1.2-12 ms graded, the errors
#: falling 16x per doubling instead of 4x (docs/backends.md "Exit walls graded")
C_EXIT_WALL = 1.0
#: the inner scale of that grading, ``delta = EXIT_WALL_DEPTH rtol s`` (``s`` the spread): cells are about uniform
#: below it.  The first-order wall error left is about ``1e-4 delta / s`` (measured at delta = 1e-4 s: the
#: refinement's errors stop falling near 1e-8), so ``rtol s`` keeps it 1e4 below rtol
EXIT_WALL_DEPTH = 1.0
#: candidate factors on ``c_wall`` (the weight of the logarithmic grading); down to 0.04 since the eighth session
#: (balanced closures, Fig. 1: zeta = 4 on 95 cells instead of 138 at 0.2x, zeta = 2 on 122 instead of 168; a sweep's
#: second regrading had found 0.024 = 0.04 x 0.6 there; nothing changed at zeta <= 1)
REGRADE_FACTORS = (0.04, 0.07, 0.1, 0.15, 0.2, 0.3, 0.45, 0.7, 1.5, 2.0)
#: candidate inner scales of the logarithmic grading (``GridSpec.wall_depth``), as fractions of the way from the
#: floor to ``p0`` in ``ln p``
REGRADE_DEPTHS = (0.2, 0.35, 0.5, 0.65, 0.8)
#: after the first level, the monitor may also be remapped by the first level's errors (:func:`_remapped`, a
#: :class:`~.grid.Remap`): knots of its density's spline, the largest ratio of its densities, and the share of the
#: cells it must save beyond the logarithmic grading's best candidate to be taken
REMAP_KNOTS = 12
REMAP_MAX_RATIO = 16.0
REMAP_PREFERENCE = 0.9
#: the grids a solve with ``plain=`` integrates alone, by mode (refinement exponents: 0 the N grid, 1 the 2N grid,
#: 2 the 4N grid); ``plain="keep"`` integrates the three grids as usual and returns their plain masses too
PLAIN_GRIDS = {"only": (0, 1), "finest": (2,), "coarsest": (0,), "answer": (1,)}


@dataclass(frozen=True)
class GridFamily:
    """The nested grids of a solve's last level: the family ``spec``, the knot indices ``knots`` of the coarsest
    grid (``knots[-1]`` its cells) and the ``edges`` of the finest (``4 knots[-1]`` cells; the coarser grids are
    every second and fourth of them).  Passed as ``grid=`` to :func:`solve_fv_full`, another problem is solved on
    the same grids, edge for edge (the closures' extrapolation in the number of shells combines two problems cell
    by cell)."""

    spec: GridSpec
    knots: tuple
    edges: np.ndarray = field(compare=False, repr=False)

    @property
    def n_cells(self) -> int:
        """Cells of the coarsest grid."""
        return int(self.knots[-1])


@dataclass(frozen=True)
class WarmStart:
    """Where a solve of a neighbouring problem starts (a sweep over the wall range).

    ``n_start``: cells of the first level's coarsest grid (refined from there as usual).  ``wall_grading``: the
    weight of the logarithmic grading towards the wall (``c_wall``, in (0, :data:`WALL_GRADING_MAX`]; None:
    :data:`C_WALL`) and ``wall_depth`` where it ends, as the fraction in [0, 1) of the way from the floor to ``p0``
    in ``ln p`` (0: it reaches the floor); both only where the grading may change (:func:`_regradable`)."""

    n_start: int
    wall_grading: Optional[float] = None
    wall_depth: float = 0.0


@dataclass(frozen=True)
class FVSolution:
    """What :func:`solve_fv_full` returns: the ``result`` and what a caller needs to solve related problems.

    ``grid``: the grids of the last level (:class:`GridFamily`).  ``plain``: with ``plain=`` the plain (not
    extrapolated) cell masses ``[z, m...]`` of the level's N, 2N and 4N grids, each lumped below the floor as the
    answer is (None where a grid was not integrated), and ``plain_failure`` why they are no result (a balance
    without a root, an unstable grid) or None.  ``cells_needed``: the coarsest cells the last level's estimate
    predicts for ``rtol``; ``next_start``: the :class:`WarmStart` for a neighbouring problem (None where the solve
    failed or integrated plain grids only)."""

    result: PressureDistribution
    grid: Optional[GridFamily] = None
    plain: Optional[tuple] = None
    plain_failure: Optional[str] = None
    cells_needed: Optional[int] = None
    next_start: Optional[WarmStart] = None

#: the largest weight of the logarithmic grading towards the wall (the ``wall_grading`` option's range, and the
#: regrading's candidates)
WALL_GRADING_MAX = 10.0
#: regrade only where the predicted cells fall by at least this fraction
REGRADE_GAIN = 0.15
#: refinement stops when the estimate is below SAFETY * rtol (margin for the estimate's own error)
SAFETY = 0.5
#: cells of the first level's coarsest grid at rtol 1e-4 (times (1e-4/rtol)^(1/4), at least 16)
START_CELLS = 25.0
#: ... for staged problems without a balance (``local_g1``: the first level is 1/4-1/3 of the work of a solve and
#: its prediction holds from fewer cells; measured on the Fig. 1 walls: 7.4-12.2 ms instead of 9.0-13.1, always two
#: levels)
START_CELLS_STAGED = 18.0
#: the next level's cells: NEED_MARGIN times those the N^-4 law predicts for SAFETY * rtol
NEED_MARGIN = 1.25
#: ... but at least MIN_GROWTH times the current level's
MIN_GROWTH = 1.5
#: the largest growth of the cells from one level to the next
MAX_GROWTH = 8.0
#: a refinement whose error estimate grew at two levels in a row to more than this factor above the smallest it
#: had reached diverges and stops (the operator loses accuracy on the finer grids; measured: a restoring drift with
#: the Muser cutoff at p_c = 0.0025 sqrt(V), whose cells below the floor hold most of the probability at face Peclet
#: numbers up to ~1e5, grew 8.6e-9 -> 2.6e-7 -> 2.7e-6 -> 9.2e-5 at rtol 1e-8 and ran 69 s to max_cells; in the 847
#: tests of the suite, slow ones included, no estimate rose twice in a row)
DIVERGENCE_FACTOR = 10.0
#: a drift stage is split so that each exponential moves the distribution by at most this many spreads
DRIFT_SPLIT = 2.0
#: at most this many exponential steps per drift stage
MAX_DRIFT_SPLIT = 256
#: a balance substep keeps the mean within MEAN_TOL_FRACTION * rtol * p0 of p0 (else Newton steps on A); the
#: distribution then moves by about that much in L1, far below the error estimate (1e-2: answers moved by <= 6e-9
#: against 1e-3 and 1e-4 on the balanced closures at rtol 1e-6)
MEAN_TOL_FRACTION = 1e-2
#: a level whose balance fails is repeated with twice the cells, at most this many times per solve
BALANCE_RETRIES = 2
#: Newton steps on the balance multiplier of one substep before the solve reports failure
MAX_BALANCE_ITERATIONS = 30
#: the last Newton step on A is taken to first order on the state (no further exponential) once the mean misses
#: p0 by less than sqrt(LINEAR_FRACTION * rtol) p0: its O(miss^2) state error is then about LINEAR_FRACTION * rtol
#: (measured on the closures: 96 stages at a miss of 5e-5 moved the answer by 2e-9)
LINEAR_FRACTION = 1e-2
#: the compiled stages use CRAM in partial fractions (all poles eliminated together, 2-3x faster than the
#: IPF form) down to this rtol; its round-off, about 1e-13 of max|y| per application against 1e-15, would
#: matter below (docs/backends.md)
PFD_MIN_RTOL = 1e-10
#: the error estimate carries the time integration's bound, CRAM_AMPLIFICATION * applications * uniform error
CRAM_AMPLIFICATION = 10.0
#: cells per balance substep (the substeps double with the cells, so Richardson removes their O(dtau^2) error)
SUBSTEP_CELLS = 16
#: e-folds of p resolved below the floor where the wall is not reached: ln(10/rtol), at least this many;
#: mass that goes further down returns above the floor with probability below exp(-e-folds) = rtol/10
#: for f ~ p^2 (ln p drifts down at the rate it diffuses)
BOTTOM_EFOLDS_MIN = 8.0
#: e-folds resolved below the floor where a drift is present, whatever rtol (ln 1e7: the depth of rtol = 1e-6):
#: a drift can cancel the Ito drift of ln p below the floor (the balanced closures), probability then returns
#: from below and the answer depends on the depth (docs/closures.md), which therefore may not follow rtol
BOTTOM_EFOLDS_DRIFT = math.log(1e7)
#: fewest e-folds below the floor after the first level's trim (:func:`_trimmed_depth`)
BOTTOM_EFOLDS_TRIMMED = 3.0
#: weight of the logarithmic grading towards the floor (Phi units per e-fold of p)
C_WALL = 0.6
#: a problem with at least this many pieces (stages, time segments) or a balance is integrated by the
#: compiled kernels of :mod:`._kernels` (numba); fewer pieces go through LAPACK (no numba import)
COMPILED_MIN_PIECES = 4
#: where a balance holds the mean, the Lamperti bound is taken where the tail's share of the mean (its mass times
#: p_max / p0), not its mass, is the tail tolerance: this many fixed-point steps from the mass-based bound (0: the
#: mass-based bound, as before the nineteenth session)
LAMPERTI_MEAN_ITERATIONS = 2
#: points of the probe that bounds the spread in :func:`prepare`; the domain grows (x1.5) on a coarse probe
#: and is confirmed on the full one: 0.2-1.3 ms of 1.8-4.5 ms saved per closure solve (Fig. 1).  Where the
#: coefficients peak at the probe's end (``local_g1``) the domain and the answer are the same bit for bit; where
#: a drift peaks inside (the balanced closures) the domain moved by up to 8 % and the cdf by up to 4e-9 (rtol 1e-6)
PROBE_POINTS = 1024
PROBE_POINTS_COARSE = 128
#: keys every finite-volume result's diagnostics carry (same for every backend)
DIAGNOSTIC_KEYS = ("backend", "rtol", "n_cells", "levels", "zero_power", "wall", "p_floor", "p_min", "p_max",
                   "mass_error", "mean_error", "negative_mass", "min_density", "tail_mass",
                   "time_integration", "n_stages", "substeps", "timings")

#: ``assemble(edges, f_centres, a_faces, a_centres) -> (lower, diag, upper)`` on ``[z, m_0..m_{n-1}]``
Assemble = Callable[[np.ndarray, np.ndarray, Optional[np.ndarray], Optional[np.ndarray]], tuple]


@dataclass(frozen=True)
class _Piece:
    """A stage as the engine integrates it: coefficients constant in tau (pressure units)."""

    duration: float
    f: Callable
    b: Optional[Callable]
    w: Optional[Callable]


@dataclass(frozen=True)
class Prepared:
    """A problem classified and gridded, ready for the nested solves (see :func:`prepare`)."""

    p0: float
    tau_end: float
    pieces: tuple  # of _Piece, or a function of the number of segments for tau-dependent problems
    time_dependent: bool
    spec: GridSpec
    zero_power: float
    reached: bool
    p_floor: float
    has_balance: bool
    mean_conserved: bool
    lump_below: float = 0.0
    label: str = ""
    balance_per_stage: bool = False
    segment_fn: Optional[Callable] = field(default=None, compare=False)
    #: the depth below the floor is an accuracy knob (ln(10/rtol) e-folds: no drift, no balance), which the first
    #: level may shorten to what its probability below the floor needs (:func:`_trimmed_depth`)
    depth_adaptive: bool = False
    #: the upper end was shortened by the Lamperti bound (:func:`prepare`); a solve whose top cell then holds
    #: more than rtol is repeated on the conservative domain (:func:`solve_fv`)
    lamperti_bounded: bool = False
    #: the drift takes its upwinding weight (``operator.fitted_weight``) on plain stages: the user's drift of a
    #: FokkerPlanckProblem; a closure's drift (a StagedProblem) keeps the central value its balance search and its
    #: validation against the reference solver are built on
    fitted_drift: bool = False
    #: the coefficients' breakpoints, where the density may jump or kink (None: unknown, every knot counts); ``p0``
    #: and the floor are knots of the grids only, across which the final density is smooth (:func:`density_knots`)
    breakpoints: Optional[tuple] = None
    #: the pieces' coefficients gathered once (:func:`row_plans`; None for a time-dependent problem)
    row_plans: Optional[dict] = field(default=None, compare=False)


@dataclass(frozen=True)
class StageRows:
    """One coefficient (``f``, ``b`` or ``w``) of a problem's pieces, gathered once (:func:`row_plans`)."""

    #: the pieces that have it, in their order
    stages: tuple
    #: their callables
    funcs: tuple
    #: whether every piece has it
    every: bool
    #: ``plan(p, out=None)``: the rows of ``funcs`` in one compiled call, where their type offers
    #: ``row_plan(items)`` (the closures' shell models: the wall products gathered once per problem instead of on
    #: every grid); the same bits as the type's ``rows`` (:func:`_rows` tries it first); else None
    plan: Optional[Callable]


def row_plans(pieces: Sequence) -> dict:
    """``{"f": StageRows, "b": StageRows, "w": StageRows}`` of ``pieces``: which have each coefficient, its
    callables and their compiled plan (:class:`StageRows`), gathered once per problem instead of on every probe
    and grid (a pass of Python over the stages each time)."""
    out = {}
    for key in ("f", "b", "w"):
        stages = tuple(k for k, pc in enumerate(pieces) if getattr(pc, key) is not None)
        funcs = tuple(getattr(pieces[k], key) for k in stages)
        kinds = {type(g) for g in funcs}
        maker = getattr(next(iter(kinds)), "row_plan", None) if len(kinds) == 1 else None
        out[key] = StageRows(stages, funcs, len(stages) == len(pieces), maker(funcs) if callable(maker) else None)
    return out


def _plan(plans: Optional[dict], key: str) -> Optional[Callable]:
    """The compiled plan of ``key`` in a :func:`row_plans` dict (None where there is none)."""
    return None if plans is None else plans[key].plan


def density_knots(prep: Prepared) -> tuple:
    """The knots where the final density may jump or kink: the coefficients' breakpoints.  ``p0`` and the floor
    only where one of them is one too: the start's delta has diffused into a smooth density, and the floor cuts
    the report, not the problem (a cubic spline of the cdf broken at ``p0`` missed by 2e-7 next to it where one
    across it missed by 3e-8; at the floor see ``diagnostics["floor_ghosts"]``; docs/backends.md)."""
    if prep.breakpoints is None:
        return tuple(float(k) for k in prep.spec.knots)
    return tuple(float(k) for k in prep.spec.knots if any(abs(k - b) <= 1e-9 * k for b in prep.breakpoints))


def _check_f(f: Callable, p: np.ndarray, name: str) -> np.ndarray:
    """``f(p)`` checked vectorized (:func:`~diffusion_pr.models.evaluate_vectorized`) and finite."""
    out = evaluate_vectorized(f, p, name)
    if not np.isfinite(out).all():
        bad = p[~np.isfinite(out)][0]
        raise ValueError(f"{name} returned a non-finite value at p={bad!r}")
    return out


def _rows(funcs: Sequence, p: np.ndarray, name: str, out: Optional[np.ndarray] = None,
          plan: Optional[Callable] = None) -> np.ndarray:
    """``[g(p) for g in funcs]`` as rows, checked like :func:`_check_f`.

    ``plan``: the rows' compiled evaluator made once for ``funcs`` (:func:`row_plans`), tried first.
    Callables of one type that offers ``rows(items, p)`` (the closures' models)
    are evaluated in one vectorized pass; the values are the same.
    """
    if plan is not None:
        block = plan(p, out)
        if block is not None:
            return block
    kinds = {type(g) for g in funcs}
    if len(kinds) == 1 and callable(getattr(next(iter(kinds)), "rows", None)):
        # one call for all rows (the closures' models evaluate them in a compiled pass, no temporaries)
        block = np.asarray(next(iter(kinds)).rows(tuple(funcs), p), dtype=float)
        if block.shape == (len(funcs), p.size) and np.isfinite(block).all():
            if out is None:
                return block
            out[...] = block
            return out
    if out is None:
        out = np.empty((len(funcs), p.size))
    for k, g in enumerate(funcs):  # (each row written where it goes: no list, no stacked copy)
        out[k] = _check_f(g, p, f"{name} of stage {k}")
    return out


def _tau_independent(problem: FokkerPlanckProblem) -> bool:
    """Whether the drift ``a(p, tau)`` returns identical values at nine probe times (then one stage).

    A documented shortcut: a drift written as a function of ``(p, tau)`` that
    ignores ``tau`` is integrated by one exponential instead of midpoint segments.
    """
    p = np.linspace(0.0, problem.mean_pressure * 4.0, 257)[1:]
    ref = np.asarray(problem.drift(p, 0.0), dtype=float)
    for t in np.linspace(0.0, problem.tau_end, 9)[1:]:
        if not np.array_equal(np.broadcast_to(np.asarray(problem.drift(p, float(t)), dtype=float), p.shape),
                              np.broadcast_to(ref, p.shape)):
            return False
    return True


def _pieces_of(problem) -> tuple[float, list, bool, Optional[Callable]]:
    """(p0, pieces, time_dependent, segment_fn) of a StagedProblem or FokkerPlanckProblem."""
    if isinstance(problem, StagedProblem):
        pieces: list = []
        for s in problem.stages:
            if s.duration <= 0:
                continue
            if (pieces and s.drift is None and s.balance is None and pieces[-1].b is None and pieces[-1].w is None
                    and s.diffusivity is pieces[-1].f):
                # consecutive stages with the same diffusivity object and nothing else commute: one exponential
                # of the summed duration is their product, exactly (the shell closures at the hard wall)
                pieces[-1] = _Piece(pieces[-1].duration + s.duration, s.diffusivity, None, None)
                continue
            pieces.append(_Piece(s.duration, s.diffusivity, s.drift, s.balance))
        return problem.mean_pressure, pieces, False, None
    if isinstance(problem, FokkerPlanckProblem):
        if problem.autonomous:
            return problem.mean_pressure, [_Piece(problem.tau_end, problem.diffusivity, None, None)], False, None
        if not problem.time_dependent and _tau_independent(problem):
            drift0 = (lambda p: problem.drift(p, 0.0))
            return problem.mean_pressure, [_Piece(problem.tau_end, problem.diffusivity, drift0, None)], False, None

        prefetch = getattr(problem.drift, "prefetch_times", None)  # a magnification map solves all midpoints at once

        def segments(m: int) -> list:
            nodes = np.linspace(0.0, problem.tau_end, m + 1)
            if prefetch is not None:
                prefetch(0.5 * (nodes[:-1] + nodes[1:]))
            out = []
            for t0, t1 in zip(nodes[:-1], nodes[1:]):
                tm = 0.5 * (t0 + t1)
                f = (lambda p, tm=tm: problem.diffusivity(p, tm)) if problem.time_dependent else problem.diffusivity
                b = None if problem.drift is None else (lambda p, tm=tm: problem.drift(p, tm))
                out.append(_Piece(t1 - t0, f, b, None))
            return out

        return problem.mean_pressure, segments(4), True, segments
    raise ValueError(f"problem must be a FokkerPlanckProblem or StagedProblem; got {type(problem).__name__}")


def _is_exit(reached: bool, zero_power: float) -> bool:
    """Whether the wall is reached by a vanishing diffusivity, ``f ~ p^k`` with ``0 < k < 2`` (Feller's exit
    boundary, with or without a drift away from it that does not make it an entrance)."""
    return bool(reached and 0.0 < zero_power < 2.0)


def _exit_wall(prep: Prepared) -> bool:
    """Whether an exit wall (:func:`_is_exit`) meets cells not graded towards it (another problem's grid family):
    the extrapolated values converge at second order there (:data:`EXIT_RICHARDSON_DIVISOR`); the exit walls'
    own grids are graded (:data:`C_EXIT_WALL`) and converge at fourth order."""
    return _is_exit(prep.reached, prep.zero_power) and prep.spec.c_wall == 0.0


@functools.lru_cache(maxsize=64)
def _tail_quantile(mass: float) -> float:
    """``z`` with ``erfc(z / sqrt 2) = mass``: a diffusion whose quadratic variation is at most ``s^2`` leaves
    ``p0 + z s`` with probability at most ``mass`` (time change to Brownian motion, reflection principle).  A pure
    function of one number, remembered: every solve at the same rtol asks for the same one."""
    z = math.sqrt(max(2.0 * math.log(1.0 / mass), 1.0))
    for _ in range(50):  # Newton on ln erfc (erfc is log-concave: monotone convergence from above)
        g = math.log(math.erfc(z / math.sqrt(2.0))) - math.log(mass)
        dg = -math.sqrt(2.0 / math.pi) * math.exp(-0.5 * z * z) / math.erfc(z / math.sqrt(2.0))
        step = g / dg
        z -= step
        if abs(step) < 1e-12:
            break
    return z


def _affine_envelope(rows: np.ndarray, probe: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(slopes, intercepts)``, each row's affine envelope on the probe: ``g`` its largest slope between probe
    points (at least 0), ``c >= 0`` the smallest intercept with ``c + g p`` above the row at every probe point."""
    slopes = np.maximum((np.diff(rows, axis=1) / np.diff(probe)).max(axis=1), 0.0)
    return slopes, np.maximum((rows - slopes[:, None] * probe).max(axis=1), 0.0)


def _affine_envelope_bound(pieces: Sequence, with_b: Sequence, b_rows: np.ndarray, f_rows: np.ndarray,
                           probe: np.ndarray, p0: float, z: float, bounded: float) -> Optional[tuple]:
    """``(p0 + shift + z s, shift, s)``, the upper tail's bound by an affine envelope of the drift, or None where no
    drift grows with ``p`` on the probe.

    Each stage's drift away from the wall is bounded by ``c + g p`` (``g`` its largest slope on the probe, ``c`` the
    smallest intercept that covers it), its diffusivity by ``F`` (its largest value).  The diffusion with that drift
    stays above (comparison theorem), and is linear: ``Y = exp(-g tau) (X + c/g)`` is a martingale whose quadratic
    variation is at most ``2 F (1 - exp(-2 g dtau))/(2 g)`` per stage.  So the mean bound and the variance propagate
    through the stages as ``M <- exp(g dtau) M + c expm1(g dtau)/g``, ``V <- exp(2 g dtau) V + F expm1(2 g dtau)/g``,
    and ``M + z sqrt(V)`` bounds the tail as ``p0 + shift + z s`` does for a bounded drift (``g = 0`` is that bound).
    A drift that grows with ``p`` (the CIR drift ``alpha - beta p`` with ``beta < 0``) outruns the bounded one once
    ``|beta| tau`` nears 1: only this one closes there.  A growth beyond double precision (``g dtau > 350``): None.
    Where this bound is below ``bounded`` (the bounded drift's), a diffusivity that grows with ``p`` tightens it
    further (:func:`_affine_chernoff_bound`); elsewhere the caller keeps ``bounded`` and nothing more is computed.
    """
    rates, intercepts = _affine_envelope(np.maximum(b_rows, 0.0), probe)
    if not np.any(rates > 0.0):
        return None
    moments = _affine_moments(pieces, with_b, rates, intercepts, f_rows.max(axis=1), p0)
    if moments is None:  # exp(2 g dtau) beyond double precision (a drift that rises steeply near the wall)
        return None
    mean, var = moments
    spread = math.sqrt(var)
    bound = mean + z * spread
    if not (math.isfinite(bound) and spread > 0.0):
        return None
    # a diffusivity that grows with p too (the CIR diffusivity p/p_1): with it bounded by F0 + F1 p as well, the
    # dominating diffusion is affine, and its exponential moments bound the tail tighter than F = max f does
    chernoff = _affine_chernoff_bound(pieces, _slopes_of(with_b, rates, intercepts), f_rows, probe, p0, spread,
                                      z) if bound < bounded else None
    if chernoff is not None and chernoff < bound:
        bound = chernoff
    return bound, mean - p0, spread


def _affine_moments(pieces: Sequence, with_b: Sequence, rates: np.ndarray, intercepts: np.ndarray,
                    f_max: np.ndarray, p0: float) -> Optional[tuple]:
    """``(mean, var)`` of :func:`_affine_envelope_bound`'s affine diffusion after every stage (the drifting stages'
    envelopes ``rates``, ``intercepts``, in the order of ``with_b``; ``f_max`` each stage's largest diffusivity), or
    None where a stage's ``g dtau`` exceeds 350."""
    slopes = _slopes_of(with_b, rates, intercepts)
    mean, var = p0, 0.0
    for pc, fm in zip(pieces, f_max):
        g, c = slopes.get(id(pc), (0.0, 0.0))
        d = pc.duration
        if g * d > 350.0:
            return None
        if g > 0.0:
            grow = math.exp(g * d)
            mean = grow * mean + c * math.expm1(g * d) / g
            var = grow * grow * var + float(fm) * math.expm1(2.0 * g * d) / g
        else:
            mean += c * d
            var += 2.0 * d * float(fm)
    return mean, var


def _slopes_of(with_b: Sequence, rates: np.ndarray, intercepts: np.ndarray) -> dict:
    """``{id(piece): (g, c)}``: each drifting stage's affine envelope (:func:`_affine_envelope_bound`)."""
    return {id(pc): (float(g), float(c)) for pc, g, c in zip(with_b, rates, intercepts)}


def _affine_chernoff_bound(pieces: Sequence, slopes: dict, f_rows: np.ndarray, probe: np.ndarray, p0: float,
                           spread: float, z: float) -> Optional[float]:
    """The Chernoff bound ``min_theta (log E exp(theta X) + ln(1/mass))/theta`` of the affine diffusion whose drift
    is ``c + g p`` (``slopes``, :func:`_affine_envelope_bound`) and whose diffusivity is ``F0 + F1 p`` (each stage's
    affine envelope of its row of ``f`` on the probe, ``f_rows``: :func:`_affine_envelope`),
    started at ``p0``; ``mass`` is the one-sided Gaussian tail of ``z``.  None where ``f`` does not grow with ``p``
    (the bound with ``F = max f`` is then as tight) or no ``theta`` has a finite moment.

    The generator ``(c + g x) d/dx + (F0 + F1 x) d^2/dx^2`` maps ``exp(A + B x)`` to itself with the Riccati
    equations ``B' = g B + F1 B^2``, ``A' = c B + F0 B^2`` in the time left; per stage of length ``d``, with
    ``psi = expm1(g d)/g`` and ``w = F1 B psi`` (finite while ``w < 1``): ``B <- B exp(g d)/(1 - w)``,
    ``A += c B psi L(w) + F0 B^2 psi (1/(1 - w) + g psi H(w))``, ``L(w) = -log1p(-w)/w``,
    ``H(w) = (w/(1 - w) + log1p(-w))/w^2`` (both 1 and 1/2 at ``w = 0``, series below 1e-3), applied from the last
    stage back to the first.  (Affine processes: Duffie, Filipovic and Schachermayer, Ann. Appl. Probab. 13 (2003)
    984, doi:10.1214/aoap/1060202833.)"""
    f_slopes, f_intercepts = _affine_envelope(f_rows, probe)
    if not np.any(f_slopes > 0.0):
        return None
    mass = 0.5 * math.erfc(z / math.sqrt(2.0))
    theta = np.geomspace(1e-3, 1e3, 241) / spread
    a, b, ok = _chernoff_moments(pieces, slopes, f_slopes, f_intercepts, theta)
    if not np.any(ok):
        return None
    x = (a[ok] + b[ok] * p0 + math.log(1.0 / mass)) / theta[ok]
    best = float(x.min())
    return best if math.isfinite(best) and best > p0 else None


def _chernoff_moments(pieces: Sequence, slopes: dict, f_slopes: np.ndarray, f_intercepts: np.ndarray,
                      theta: np.ndarray) -> tuple:
    """``(A, B, ok)`` of :func:`_affine_chernoff_bound` at every ``theta``: the Riccati recursion from the last stage
    to the first, ``ok`` where the moment stayed finite (``w < 1`` and ``A``, ``B`` finite at every stage)."""
    b = theta.copy()
    a = np.zeros_like(theta)
    ok = np.ones(theta.size, dtype=bool)
    for pc, f1, f0 in zip(reversed(pieces), f_slopes[::-1], f_intercepts[::-1]):
        g, c = slopes.get(id(pc), (0.0, 0.0))
        d = pc.duration
        psi = math.expm1(g * d) / g if g > 0.0 else d
        w = float(f1) * b * psi
        ok &= w < 1.0
        w = np.where(ok, w, 0.0)
        small = np.abs(w) < 1e-3
        w_safe = np.where(small, 0.5, w)
        ell = np.where(small, 1.0 + w / 2.0 + w * w / 3.0 + w ** 3 / 4.0,
                       -np.log1p(-w_safe) / w_safe)
        h = np.where(small, 0.5 + 2.0 * w / 3.0 + 0.75 * w * w + 0.8 * w ** 3,
                     (w_safe / (1.0 - w_safe) + np.log1p(-w_safe)) / (w_safe * w_safe))
        a = a + c * b * psi * ell + float(f0) * b * b * psi * (1.0 / (1.0 - w) + g * psi * h)
        b = b * math.exp(g * d) / (1.0 - w)
        ok &= np.isfinite(a) & np.isfinite(b)
    return a, b, ok


#: the largest work array :func:`_thread_work` keeps for a thread [bytes]; a larger one is allocated per call.  4 MB
#: covers the Fig. 1 closures (at most 1.9 MB: 96 shells on 2528 cells) and bounds what a thread keeps to about
#: 15 keys x 4 MB (prepare, a level and a plain solve, five each at most)
WORK_MAX_BYTES = 1 << 22

_WORK = threading.local()


def _thread_work(prefix: str) -> Callable:
    """``get(name, shape)``: an uninitialized float array of ``shape`` that this thread keeps between calls under
    ``prefix + name`` (one buffer per key; one above :data:`WORK_MAX_BYTES` is allocated afresh).

    Why: large temporaries made afresh in the main thread (:func:`prepare`'s probe rows, stages x 1024 and x 2049
    points; the grids' coefficient rows, stages x cells) are mapped and returned to the system by glibc's allocator
    on every call, because freeing them leaves the main heap's top above its trim threshold.  Measured on this
    machine: 450 page faults and about 1.5 ms of a 12 ms closure call in ``prepare`` alone, while the worker
    thread waits; 1390 faults and 4 ms of the main thread's 8.4 ms of coefficient rows at ``zeta = 0.01`` (the
    worker's own arena did not fault).  The contract: a key's array is dead before the same thread asks for that
    key again (each user below says why), and nothing that outlives its user is a view of one.
    """
    store = getattr(_WORK, "store", None)
    if store is None:
        store = _WORK.store = {}

    def get(name: str, shape: tuple) -> np.ndarray:
        n = math.prod(shape)
        if 8 * n > WORK_MAX_BYTES:
            return np.empty(shape)
        key = prefix + name
        buf = store.get(key)
        if buf is None or buf.size < n:
            buf = store[key] = np.empty(n)
        return buf[:n].reshape(shape)

    return get


@contextlib.contextmanager
def _work_arrays(prefix: str):
    """:func:`_thread_work` of ``prefix`` for the duration of a ``with`` block that does not hand its arrays out;
    a nested block of the same prefix in the same thread (a user's coefficient that solves a problem itself) gets
    fresh arrays."""
    busy = getattr(_WORK, "busy", None)
    if busy is None:
        busy = _WORK.busy = set()
    if prefix in busy:
        yield lambda name, shape: np.empty(shape)
        return
    busy.add(prefix)
    try:
        yield _thread_work(prefix)
    finally:
        busy.discard(prefix)


def prepare(problem, *, rtol: float, p_floor: Optional[float] = None, lamperti: bool = True,
            on_grid: Optional[GridSpec] = None) -> Prepared:
    """Classify the wall, bound the domain and fix the grid family of ``problem``.

    Raises
    ------
    ValueError
        ``f = 0`` everywhere (the start never moves), ``p0/spread`` beyond
        double precision (``> 1e12``), or a coefficient that is not a
        vectorized finite callable.

    ``lamperti=False``: the upper end from the spread alone, never the shorter
    Lamperti bound (the fallback of :func:`solve_fv_full` where that bound was too short).
    ``on_grid``: the grid family is given (another problem's, :class:`GridFamily`): no domain probe, no
    grading; the wall, the floor and the lumping are classified for it (the plain-mass solves of
    ``plain=`` of :func:`solve_fv_full`, 0.3-1 ms each saved).
    """
    p0, pieces, time_dependent, segment_fn = _pieces_of(problem)
    tau_end = float(sum(pc.duration for pc in pieces))
    plans = None if time_dependent else row_plans(pieces)
    if on_grid is not None:
        return _prepared_on(problem, p0, pieces, time_dependent, segment_fn, tau_end, on_grid, p_floor, plans)
    with _work_arrays("prepare:") as work:
        return _prepare_probed(problem, rtol, p_floor, lamperti, p0, pieces, time_dependent, segment_fn, tau_end,
                               plans, work)


def _prepare_probed(problem, rtol: float, p_floor: Optional[float], lamperti: bool, p0: float, pieces: Sequence,
                    time_dependent: bool, segment_fn: Optional[Callable], tau_end: float, plans: Optional[dict],
                    work: Callable) -> Prepared:
    """:func:`prepare` with the domain probe, the Lamperti bound and the grid family, its large rows in the
    thread's work arrays ``work`` (:func:`_work_arrays`: none of them outlives the call)."""
    # spread: sqrt(2 sum dtau max f) on an expanding probe, plus the drift displacement
    p_hi = p0 * 4.0
    points = PROBE_POINTS_COARSE
    with_b = [pc for pc in pieces if pc.b is not None]
    durations = np.array([pc.duration for pc in pieces], dtype=float)
    durations_b = np.array([pc.duration for pc in with_b], dtype=float)
    z = _tail_quantile(TAIL_FRACTION * max(rtol, 1e-15))
    for _ in range(60):
        probe = _probe_points(p_hi, points)
        f_rows = _rows([pc.f for pc in pieces], probe, "the diffusivity", plan=_plan(plans, "f"),
                       out=work("f", (len(pieces), probe.size)))
        f_max = f_rows.max(axis=1)
        # only a drift away from the wall moves the upper tail up (comparison: the diffusion with the drift
        # max(a, 0) stays above); a restoring drift may outgrow p (the CIR drift alpha - beta p)
        # sum_k 2 dtau_k max f_k and sum_k dtau_k max b_k, added in stage order (cumsum is sequential)
        var = _ordered_sum(2.0 * durations * f_max)
        shift = 0.0  # (what the empty sum gives, without its arrays)
        if with_b:
            b_rows = _rows([pc.b for pc in with_b], probe, "the drift", plan=_plan(plans, "b"),
                           out=work("b", (len(with_b), probe.size)))
            shift = _ordered_sum(durations_b * np.maximum(b_rows, 0.0, out=work("b+", b_rows.shape)).max(axis=1))
        s = math.sqrt(var)
        new = p0 + shift + z * s
        # where that bound does not close on this probe, a drift that grows with p may: its affine envelope (tried
        # only there, so that every problem the bounded drift closes keeps its domain, and no time is spent on it)
        grown = _affine_envelope_bound(pieces, with_b, b_rows, f_rows, probe, p0, z, new) if with_b and new > p_hi \
            else None
        if grown is not None and grown[0] < new:
            new, shift, s = grown
        growing = grown is not None and new == grown[0]
        if new <= p_hi:
            if points == PROBE_POINTS:
                break
            points = PROBE_POINTS  # the growth found on the coarse probe: confirmed on the full one
            continue
        p_hi = 1.5 * new
    else:
        raise ValueError("could not bound the pressure domain: the diffusivity grows faster than linearly in p, or "
                         "the drift faster than exponentially in the diffusion time (the spread estimate exceeded "
                         f"{p_hi:.3g} after 60 iterations)")
    # a drift towards the wall moves the lower tail down (comparison: below p0 the process is above the one with
    # the drift -max(-a, 0) there, and every excursion below p0 starts at p0): the domain's bottom takes it
    shift_down = 0.0
    if with_b:
        below = b_rows[:, :int(np.searchsorted(probe, p0, side="right"))]  # (the probe increases: probe <= p0)
        towards = np.negative(below, out=work("b+", below.shape))
        shift_down = _ordered_sum(durations_b * np.maximum(towards, 0.0, out=towards).max(axis=1, initial=0.0))
    if s <= 0.0 or not np.isfinite(s):
        raise ValueError("the diffusivity is 0 on the whole domain (0, "
                         f"{p_hi:.3g}]: Pr stays delta(p - p0) and has no density to resolve")
    if p0 / s > MAX_RATIO:
        raise ValueError(f"mean_pressure/spread = {p0 / s:.3g} exceeds {MAX_RATIO:.0e}: the distribution is narrower "
                         "than double precision resolves at p0 (use the Gaussian limit)")
    if p0 / s < 1.0 / MAX_RATIO:
        raise ValueError(f"mean_pressure/spread = {p0 / s:.3g} is below {1 / MAX_RATIO:.0e}: the start sits at the wall "
                         "to double precision (the contact is lost)")
    with_w = [pc.w for pc in pieces if pc.w is not None]  # the balance does not set the spread: checked once
    if with_w:
        _rows(with_w, probe, "the balance", plan=_plan(plans, "w"), out=work("w", (len(with_w), probe.size)))
    p_max = new
    lamperti_bounded = False
    if lamperti and not growing and not time_dependent and len(pieces) >= COMPILED_MIN_PIECES:
        # the upper tail in the Lamperti coordinate Y = int dp / sqrt(2 F), F = sum dtau_k f_k: Y - Y(p0) is
        # a unit-variance diffusion whose Ito drift -F'/(2 sqrt(2F)) points down where F grows, so z units of
        # Y bound the tail like z spreads do for constant f (checked after the solve: the top cell's mass)
        nodes = np.linspace(p0, p_max, 2049)
        # sum_k dtau_k max(f_k, 0), reduced over the stages in their order (as a loop of += adds them); a work
        # block of its own, weighted in place (a model's own rows are never written to)
        weighted = np.maximum(_rows([pc.f for pc in pieces], nodes, "the diffusivity", plan=_plan(plans, "f"),
                                    out=work("f", (len(pieces), nodes.size))), 0.0,
                              out=work("weighted", (len(pieces), nodes.size)))
        weighted *= durations[:, None]
        F = np.add.reduce(weighted, axis=0)
        if np.all(np.diff(F) >= 0.0) and F[0] > 0.0:
            rho = 1.0 / np.sqrt(2.0 * F)
            y_l = np.concatenate(([0.0], np.cumsum(0.5 * np.diff(nodes) * (rho[1:] + rho[:-1]))))
            z_tail = z
            for _ in range(LAMPERTI_MEAN_ITERATIONS if with_w else 0):
                # a balance holds the mean: the tail beyond the bound takes its share of the mean, about its mass
                # times p_max / p0, and the balance moves the whole distribution to make up for it, so that share
                # is what must stay below the tail tolerance (H 0.36, rms slope 0.024, q 2pi/8192..2pi/4,
                # zeta 0.0035, p0 1.1e-3, local_g1_balanced: 1.6e-7 of the mean beyond the mass-based bound
                # 164 p0 moved 5e-7 of probability into the non-contact weight, the answer 1.0e-6 off against an
                # estimate of 3.1e-7; its top cell, 3.5e-10 x 164, passed the check after the solve)
                if y_l[-1] <= z_tail:
                    break
                p_cut = float(np.interp(z_tail, y_l, nodes)) + shift
                z_tail = _tail_quantile(TAIL_FRACTION * max(rtol, 1e-15) * min(1.0, p0 / p_cut))
            if y_l[-1] > z_tail:
                p_max = min(p_max, float(np.interp(z_tail, y_l, nodes)) + shift)
                lamperti_bounded = p_max < new
    bps, k_min, reached, floor = _wall_of(pieces, time_dependent, p0, p_max, p_floor)
    has_balance = any(pc.w is not None for pc in pieces)
    has_drift = any(pc.b is not None for pc in pieces)  # (the domain's depth below the floor depends on both)
    # far from the wall (p0 - z s above the floor) less than the tail tolerance gets below p0 - z s:
    # the domain starts there (what arrives is booked into zero_weight, below the tail tolerance)
    p_lo = p0 - (z * s + shift + shift_down)
    truncated = p_lo > floor
    if truncated:
        floor_domain = p_lo
    elif reached:
        floor_domain = 0.0
    else:  # the wall is not reached: resolve BOTTOM_EFOLDS e-folds below the floor (the floor is an edge)
        # with a drift the depth is part of the problem (fixed): a drift may cancel the downward Ito drift of
        # ln p (the balanced closures), so what returns from below depends on the depth and must not on rtol
        depth = BOTTOM_EFOLDS_DRIFT if (has_drift or has_balance) else max(BOTTOM_EFOLDS_MIN, math.log(10.0 / rtol))
        floor_domain = floor * math.exp(-depth)
    extra_knots = {floor} if (not reached and not truncated) else set()
    knots = sorted({float(b) for b in bps if floor_domain < b < p_max} | {p0} | extra_knots)
    pruned: list[float] = []
    for x in knots:
        if x in extra_knots:
            pruned.append(x)
            continue  # knots closer than 1e-9 of the domain would make degenerate cells
        if not pruned or x - pruned[-1] > 1e-9 * x:
            pruned.append(x)
    pruned = sorted(set(pruned))
    if p0 not in pruned:
        pruned = sorted([x for x in pruned if abs(x - p0) > 1e-9 * p0 or x in extra_knots] + [p0])
    # grading towards p0 where the local spread is small compared with the global one
    f_p0 = [max(float(v), 0.0) for v in _rows([pc.f for pc in pieces], np.array([p0]), "the diffusivity",
                                              plan=_plan(plans, "f"))[:, 0]]
    if time_dependent:
        w_loc = math.sqrt(2.0 * tau_end * max(f_p0))
    else:  # stages: the variance a start at p0 accumulates, sum_k 2 dtau_k f_k(p0) (not 2 tau_end max_k f_k)
        w_loc = math.sqrt(2.0 * sum(pc.duration * fk for pc, fk in zip(pieces, f_p0)))
    c_0, w0 = (1.0, max(w_loc, 1e-3 * s)) if w_loc < 0.25 * s else (0.0, s)
    exit_graded = _is_exit(reached, k_min) and not truncated
    c_wall = C_EXIT_WALL if exit_graded else 0.0 if (reached or truncated) else C_WALL
    spec = GridSpec(p_wall=floor_domain, p_max=p_max, knots=tuple(pruned), scale=s, c_wall=c_wall, c_0=c_0, w0=w0, p0=p0,
                    wall_depth=EXIT_WALL_DEPTH * max(rtol, 1e-15) * s if exit_graded else 0.0)
    return _prepared(problem, p0, pieces, time_dependent, segment_fn, tau_end, spec, k_min, reached, floor,
                     truncated, lamperti_bounded, bps, plans)


def _ordered_sum(terms: np.ndarray) -> float:
    """``terms[0] + terms[1] + ...`` added left to right (``cumsum`` is sequential; ``sum`` is pairwise), 0 where
    empty: the same bits as a Python loop of ``+=`` from 0."""
    if terms.size == 1:
        return float(terms[0])
    return float(np.cumsum(terms)[-1]) if terms.size else 0.0


def _probe_points(p_hi: float, points: int) -> np.ndarray:
    """``np.linspace(0, p_hi, points + 1)[1:]``, its values (``k (p_hi / points)``, the last ``p_hi`` exactly)
    without its overhead (the domain probe asks for several)."""
    probe = np.arange(1, points + 1, dtype=float)
    probe *= p_hi / points
    probe[-1] = p_hi
    return probe


def _wall_of(pieces: Sequence, time_dependent: bool, p0: float, p_max: float, p_floor: Optional[float]) -> tuple:
    """``(breakpoints, zero power, reached, floor)``: Feller's criterion on every stage (the wall absorbs if one of
    them reaches it) and the floor of a wall that is not reached."""
    bps: list[float] = []
    k_min = math.inf
    scale = p0
    seen = set()  # (a model shared by several stages is asked once: its breakpoints are the same)
    for pc in pieces[:1] if time_dependent else pieces:
        for g in (pc.f, pc.b, pc.w):
            if g is not None and id(g) not in seen:
                seen.add(id(g))
                bps.extend(breakpoints_of(g, 0.0, p_max))
    if bps:
        scale = min(p0, min(bps))
    for pc in pieces[:1] if time_dependent else pieces:
        k_min = min(k_min, zero_power_of(pc.f, scale))
    reached = wall_reached(k_min)
    floor = 0.0 if reached else (FLOOR * p0 if p_floor is None else float(p_floor))
    if not reached and not (0.0 < floor < p0):
        raise ValueError(f"p_floor must be in (0, mean_pressure); got p_floor={p_floor!r}")
    return bps, k_min, reached, floor


def _prepared_on(problem, p0: float, pieces: Sequence, time_dependent: bool, segment_fn: Optional[Callable],
                 tau_end: float, spec: GridSpec, p_floor: Optional[float], plans: Optional[dict] = None) -> Prepared:
    """:func:`prepare` on a given grid family (``on_grid``): the classification without the domain probe."""
    bps, k_min, reached, floor = _wall_of(pieces, time_dependent, p0, spec.p_max, p_floor)
    truncated = not reached and spec.p_wall > floor  # the domain starts above the floor (prepare's p_lo)
    return _prepared(problem, p0, pieces, time_dependent, segment_fn, tau_end, spec, k_min, reached, floor,
                     truncated, False, bps, plans)


def _prepared(problem, p0: float, pieces: Sequence, time_dependent: bool, segment_fn: Optional[Callable],
              tau_end: float, spec: GridSpec, k_min: float, reached: bool, floor: float, truncated: bool,
              lamperti_bounded: bool, breakpoints: Sequence[float] = (), plans: Optional[dict] = None) -> Prepared:
    """The :class:`Prepared` record of a classified problem on its grid family (:func:`prepare`,
    :func:`_prepared_on`): the floor is an edge whose cells below are lumped where the wall is not reached and the
    domain is not truncated above it."""
    has_balance = any(pc.w is not None for pc in pieces)
    has_drift = any(pc.b is not None for pc in pieces)
    return Prepared(mean_conserved=has_balance or not has_drift, p0=p0, tau_end=tau_end, pieces=tuple(pieces),
                    time_dependent=time_dependent, spec=spec, zero_power=k_min, reached=reached, p_floor=floor,
                    has_balance=has_balance, lump_below=floor if not (reached or truncated) else 0.0,
                    label=getattr(problem, "label", ""), segment_fn=segment_fn,
                    balance_per_stage=bool(getattr(problem, "balance_per_stage", False)),
                    depth_adaptive=not (reached or truncated or has_drift or has_balance),
                    lamperti_bounded=lamperti_bounded,
                    fitted_drift=has_drift and isinstance(problem, FokkerPlanckProblem),
                    breakpoints=tuple(float(b) for b in breakpoints), row_plans=plans)


def native_assemble(edges: np.ndarray, f_c: np.ndarray, a_faces: Optional[np.ndarray],
                    a_centres: Optional[np.ndarray] = None) -> tuple:
    """The engine's own operator (:func:`.operator.bands`; drift taken at the faces)."""
    return fv_bands(edges, f_c, a_faces)


def _substeps(prep: Prepared, piece: _Piece, n_base: int, refine: int) -> int:
    """Balance substeps of ``piece``: ``refine`` times those of the coarsest grid (``n_base`` cells).

    Doubling exactly with the cells keeps the O(dtau^2) error of the frozen ``A``
    in step with the O(h^2) spatial error, so one Richardson step removes both.
    A problem whose ``A`` is one number per stage (``balance_per_stage``) has one
    substep per stage on every grid: there the frozen ``A`` is the definition.
    """
    if prep.balance_per_stage:
        return 1
    return refine * max(1, int(round(n_base / SUBSTEP_CELLS * piece.duration / prep.tau_end)))


def _coefficients(pieces: Sequence, grids: Sequence[np.ndarray], centre_drift: bool,
                  plans: Optional[dict] = None, work: Optional[Callable] = None) -> list:
    """Every stage's ``f`` (centres), drift and balance (faces; centres too if ``centre_drift``) as rows, per grid.

    Each callable is evaluated once, on the points of all ``grids`` (edge arrays) together; ``plans``: the
    pieces' :func:`row_plans`; ``work``: the rows in these work arrays (:func:`_thread_work`; the caller keeps
    its contract), else new ones.
    """
    cs = [centres(e) for e in grids]
    faces = [e[:-1] for e in grids]
    cut = np.cumsum([0] + [c.size for c in cs])
    c_all, f_all = np.concatenate(cs), np.concatenate(faces)
    k_stages = len(pieces)
    layout = row_plans(pieces) if plans is None else plans
    shape = (k_stages, c_all.size)
    keys = ("f", "b", "w", "b_c", "w_c") if centre_drift else ("f", "b", "w")
    rows = {key: np.empty(shape) if work is None else work(key, shape) for key in keys}
    for key in keys[1:]:  # (the stages without a drift or a balance have rows of zeros)
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


def _coefficients_lazy(pieces: Sequence, grids: Sequence[np.ndarray], groups: Sequence[tuple],
                       centre_drift: bool, plans: Optional[dict] = None) -> Callable:
    """``coef(g)``: :func:`_coefficients` of ``grids[g]``, evaluated for its whole group (a tuple of grid
    indices) when the first grid of the group is asked for; each group is asked for from one thread.

    The rows are that thread's work arrays (:func:`_thread_work`, key ``"level:"``): they are read only by the
    group's integrations, which that thread runs before it asks for another level's group (the levels of a solve
    follow one another; no other user takes that key)."""
    cache: dict = {}

    def coef(g: int) -> dict:
        if g not in cache:
            grp = next(grp for grp in groups if g in grp)
            cache.update(zip(grp, _coefficients(pieces, [grids[k] for k in grp], centre_drift, plans,
                                                work=_thread_work("level:"))))
        return cache[g]

    return coef


def _fitted_stages(prep: Prepared, coef: dict) -> np.ndarray:
    """Which stages' drift takes its upwinding weight (the native operator): plain drift stages of a problem whose
    drift is fitted (:attr:`Prepared.fitted_drift`)."""
    return coef["has_b"] & ~coef["has_w"] & bool(prep.fitted_drift)


def _stage_bands(edges: np.ndarray, coef: dict, assemble: Assemble, fitted: bool | np.ndarray = False) -> tuple:
    """Rows of the stages' bands ``L_k`` and of their balance operators (0 where a stage has none).

    Without a balance the balance rows are a single row of zeros (never read).  ``fitted``: per stage, the native
    operator's drift takes its upwinding weight (:func:`_fitted_stages`; False: nowhere).
    """
    n_stages, n = coef["f"].shape
    any_w = bool(coef["has_w"].any())
    if assemble is native_assemble:  # all stages at once (the compiled path makes them in its kernel)
        any_b = bool(coef["has_b"].any())
        base = fv_bands(edges, coef["f"], coef["b"] if any_b else None, fitted=fitted, c=coef.get("c"))
        if not any_w:  # (assembling the zero row cost as much as the stages' own bands on a one-stage problem)
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
                  partial_fractions: bool = True, order: int = 16) -> tuple[np.ndarray, dict]:
    """Integrate from the start to ``tau_end`` on one grid; return ``y = [z, m...]`` and counters.

    ``n_base`` is the cell count of the coarsest grid of the nested triple and
    ``refine`` (1, 2, 4) this grid's refinement factor: time segments and
    balance substeps are ``refine`` times those of the coarsest grid (one
    substep per stage for a ``balance_per_stage`` problem).  A balance substep
    takes Newton steps on ``A`` (one exponential each) until the mean is within
    ``mean_tol p0`` of ``p0``, the last one to first order on the state once the
    miss is below ``lin_tol p0``; after MAX_BALANCE_ITERATIONS the counters carry
    ``"balance_failure"`` and ``y`` is not a result.  ``partial_fractions``: the
    compiled stages use CRAM in partial fractions (else the IPF form, in flux form on LAPACK's stages too; see
    PFD_MIN_RTOL); ``order``: the rational approximation's (16); ``coef``: the stage coefficients
    on this grid, if already evaluated.
    """
    pieces = prep.segment_fn(refine * max(4, n_base // 8)) if prep.time_dependent else prep.pieces
    if coef is None:
        coef = _coefficients(pieces, [edges], centre_drift=assemble is not native_assemble,
                             plans=prep.row_plans if pieces is prep.pieces else None)[0]
    c = coef["c"]  # (the centres the coefficients were evaluated at)
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
    order = int(order) if partial_fractions else 16  # the IPF form is CRAM-16's
    counters = {"cram_applications": 0, "substeps": int(reps[balanced].sum()), "newton_steps": 0,
                "cram_order": order}
    # a balance always runs in the kernel (its substep loop is compiled); a few plain stages stay on LAPACK
    if compiled:
        common = (balanced, dt, reps, np.concatenate(((edges[0],), c)), y, prep.p0, mean_tol, max(mean_tol, lin_tol),
                  bool(partial_fractions), order)
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


def _trimmed_depth(prep: Prepared, below_floor: float, rtol: float) -> Optional[Prepared]:
    """``prep`` with a shallower domain below the floor, or None (keep it).

    Where the depth is an accuracy knob (:attr:`Prepared.depth_adaptive`), it is
    there so that what sinks below the floor does not come back: from ``d``
    e-folds down, ``ln p`` returns with probability ``exp(-d)`` (it drifts down
    at the rate it diffuses for ``f ~ p^2``).  The probability that goes below the
    floor at all is at most ``below_floor`` (the first level's lumped weight plus
    its error estimate), so ``d = ln(10 below_floor / rtol)`` keeps the returning
    probability below ``rtol/10``, as ``ln(10/rtol)`` does for a weight of 1
    (at least :data:`BOTTOM_EFOLDS_TRIMMED`).  Trimmed when that saves at least two e-folds.
    """
    if not prep.depth_adaptive:
        return None
    depth = math.log(prep.p_floor / prep.spec.p_wall)
    new = max(BOTTOM_EFOLDS_TRIMMED, math.log(10.0 * max(below_floor, 1e-300) / rtol))
    if new > depth - 2.0:
        return None
    return replace(prep, spec=replace(prep.spec, p_wall=prep.p_floor * math.exp(-new)), depth_adaptive=False)


def cram_order(rtol: float) -> int:
    """The order of the stages' rational approximation: 16 (CRAM-16) at every ``rtol``."""
    return 16


def _regradable(prep: Prepared) -> bool:
    """Whether the grading towards the wall may change (:func:`_regraded`, the ``wall_grading`` option): a
    graded wall (``c_wall > 0``) whose depth below the floor is fixed (a drift or a balance); not an exit wall's
    grading (:data:`C_EXIT_WALL`: there is no floor)."""
    return prep.spec.c_wall > 0.0 and not prep.depth_adaptive and not prep.reached


def _delta_of(spec: GridSpec, wall_depth: float) -> float:
    """``replace(spec, wall_depth=wall_depth)._delta`` without making the family (the same number)."""
    if wall_depth > 0.0:
        return wall_depth
    return spec.p_wall if spec.p_wall > 0.0 else 1e-12 * spec.p_max


def _wall_depth(spec: GridSpec, fraction: float) -> float:
    """``GridSpec.wall_depth`` for ``fraction`` of the way from the floor to ``p0`` in ``ln p`` (0: the default)."""
    if fraction <= 0.0 or spec.p_wall <= 0.0:
        return 0.0
    return spec.p_wall * (spec.p0 / spec.p_wall) ** fraction


def _depth_fraction(spec: GridSpec) -> float:
    """The inverse of :func:`_wall_depth`: where the logarithmic grading of ``spec`` ends, as that fraction."""
    if spec.wall_depth <= 0.0 or spec.p_wall <= 0.0:
        return 0.0
    return math.log(spec.wall_depth / spec.p_wall) / math.log(spec.p0 / spec.p_wall)


def _cell_errors(diff: np.ndarray, j: int) -> np.ndarray:
    """The first level's Richardson differences per cell of the N grid (magnitudes), the lumped entry spread evenly
    over the ``j`` cells below the floor."""
    d = np.abs(np.asarray(diff, dtype=float))
    return np.concatenate((np.full(j, d[0] / j) if j > 0 else np.empty(0), d[1:]))


def _remapped(spec: GridSpec, edges: np.ndarray, diff: np.ndarray, j: int) -> Optional[tuple]:
    """``(spec, cell factor)``: ``spec`` remapped (:class:`~.grid.Remap`) so that the first level's errors are
    about equidistributed, and the ratio of the cells it needs for that error to those ``spec`` needs.

    A cell's error falls like its width to the fourth power, so for a given total the fewest cells have widths
    ``~ e_i^(-1/5)`` (``e_i`` the error of cell ``i`` on the N grid; Lagrange): the density of the new monitor in
    ``v = Phi - Phi(p_wall)`` is ``D ~ e^(1/5)``.  ``ln D`` is smoothed (Gaussian weights of one knot spacing at
    :data:`REMAP_KNOTS` equidistant knots; a sign change of a cell's difference is bridged by half its
    neighbours'), its range capped at :data:`REMAP_MAX_RATIO`, and ``D`` is the natural cubic spline through it.  The
    factor is ``(sum e_i rho_i^4 / sum e_i)^(1/4)``, ``rho_i`` the new width over the old at the same cells.
    None where the density's spline is not safely positive or the errors are not finite.
    """
    e = _cell_errors(diff, j)
    if not np.isfinite(e).all() or e.sum() <= 0.0 or e.size + 1 != edges.size:
        return None
    base0 = float(spec.phi(spec.p_wall))
    v_edges = spec.phi(edges) - base0
    v_c = 0.5 * (v_edges[:-1] + v_edges[1:])
    smooth = np.maximum(e, 0.5 * np.maximum(np.concatenate((e[1:], (0.0,))), np.concatenate(((0.0,), e[:-1]))))
    log_d = 0.2 * np.log(np.maximum(smooth, 1e-12 * smooth.max()))
    total = float(v_edges[-1])
    knots = np.linspace(0.0, total, REMAP_KNOTS)
    weights = np.exp(-0.5 * ((v_c[None, :] - knots[:, None]) / (knots[1] - knots[0])) ** 2)
    log_k = (weights @ log_d) / weights.sum(axis=1)
    log_k = np.maximum(log_k - log_k.max(), -math.log(REMAP_MAX_RATIO))
    try:
        remap = Remap(tuple(knots), tuple(np.exp(log_k - 0.5 * log_k.min())))
    except ValueError:
        return None
    rho = remap.total / (total * remap.density(v_c))
    return replace(spec, remap=remap), float((np.sum(e * rho**4) / np.sum(e)) ** 0.25)


def _regraded(prep: Prepared, edges: np.ndarray, diff: np.ndarray, j: int, remap: bool = False) -> Optional[tuple]:
    """``(spec, cell factor)``: the grid family whose logarithmic grading towards the wall (its weight ``c_wall``
    and its inner scale ``wall_depth``) needs the fewest cells for the first level's error, and the ratio of the
    cells it needs to those the old family needs; or None where no candidate saves :data:`REGRADE_GAIN`.

    ``diff`` are the first level's Richardson differences ``[zero weight, cells from j on]`` on ``edges`` (the N
    grid, cells below the floor lumped into the first entry).  A cell's error scales with its width to the
    fourth power, and a width with the inverse density ``dPhi/dp`` of the monitor times the total ``Phi`` per
    cell; so under a candidate monitor ``Phi'`` the error becomes ``sum_i d_i rho_i^4`` with
    ``rho_i = (Phi'_tot / Phi_tot) (dPhi/dp / dPhi'/dp)(p_i)``, and the cells for the same error scale with its
    fourth root.  The lumped entry's error was made below the floor: it is charged with the largest ``rho`` of
    the cells there (a candidate that widens them, where the balanced closures keep half their probability at
    ``zeta <= 0.1``, is charged for it).  Where the depth below the floor is part of the problem (a drift or a
    balance: the closures), this is what adapts: at large ``zeta`` the balanced closures' probability never gets
    near the floor, and the cells the default grading puts there (half of them) are moved up.  The candidates
    (:data:`REGRADE_FACTORS` on ``c_wall`` times :data:`REGRADE_DEPTHS`) are costed together in one array
    expression: the monitor is ``rest(p) + c_wall / (p - p_wall + delta)`` and only the last term changes.
    """
    spec = prep.spec
    d = np.abs(diff)
    if not np.isfinite(d).all() or d.sum() <= 0.0 or spec.remap is not None:
        return None
    centres_ = 0.5 * (edges[j:-1] + edges[j + 1:])
    below = 0.5 * (edges[:j] + edges[1:j + 1])  # the cells below the floor, lumped into the first entry
    pts = np.concatenate(([centres_[0]], centres_, below))  # the lumped entry at the first cell above the floor
    n_pts = centres_.size + 1
    knots = spec.all_knots
    rest = replace(spec, c_wall=0.0)  # the monitor without its logarithmic grading
    rest_tot = float(rest.phi(knots[-1]) - rest.phi(knots[0]))
    phi_tot = float(spec.phi(knots[-1]) - spec.phi(knots[0]))
    dphi = spec.dphi(pts)
    fractions = (0.0,) + (REGRADE_DEPTHS if spec.p_wall > 0.0 else ())
    deltas = np.array([_delta_of(spec, _wall_depth(spec, k)) for k in fractions])
    weights = spec.c_wall * np.array((1.0,) + REGRADE_FACTORS)
    x = pts - spec.p_wall
    span = knots[-1] - spec.p_wall
    tot = rest_tot + weights[:, None] * np.log((span + deltas) / deltas)[None, :]  # (weights, depths)
    cand_dphi = rest.dphi(pts)[None, None, :] + weights[:, None, None] / (x[None, None, :] + deltas[None, :, None])
    rho = (tot / phi_tot)[:, :, None] * dphi[None, None, :] / cand_dphi
    if below.size:
        rho[:, :, 0] = np.maximum(rho[:, :, 0], np.max(rho[:, :, n_pts:], axis=2))
    cost = (np.sum(d * rho[:, :, :n_pts] ** 4, axis=2) / float(np.sum(d))) ** 0.25
    same = (weights == spec.c_wall)[:, None] & (deltas == spec._delta)[None, :]
    cost[same] = np.inf  # the present grading is no candidate
    # within the range the wall_grading option accepts (a sweep passes the choice on: 2x per entry grew past it)
    cost[weights > WALL_GRADING_MAX, :] = np.inf
    iw, idp = np.unravel_index(int(np.argmin(cost)), cost.shape)
    best_cost = float(cost[iw, idp])
    if remap:
        remapped = _remapped(spec, edges, diff, j)
        if remapped is not None and remapped[1] < 1.0 - REGRADE_GAIN and remapped[1] < REMAP_PREFERENCE * best_cost:
            return remapped
    if not best_cost < 1.0 - REGRADE_GAIN:
        return None
    return replace(spec, c_wall=float(weights[iw]), wall_depth=_wall_depth(spec, fractions[idp])), best_cost


def _compiled(prep: Prepared) -> bool:
    """Whether ``prep`` is integrated by the compiled kernels (else LAPACK): a balance, or at least
    COMPILED_MIN_PIECES pieces; a time-dependent problem has at least 4 segments (``max(4, n_base // 8)``)."""
    return prep.has_balance or prep.time_dependent or len(prep.pieces) >= COMPILED_MIN_PIECES




def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float)


class _Kernels:
    """The compiled staged integration (:mod:`._kernels`, imported on first use: a single-stage problem never
    loads numba)."""

    def __init__(self) -> None:
        from . import _kernels

        self._k = _kernels
        self._coef = (np.ascontiguousarray(CRAM_ALPHA), np.ascontiguousarray(CRAM_THETA), float(CRAM_ALPHA0),
                      np.ascontiguousarray(PFD_RESIDUES))

    def run_rows(self, edges, f_rows, b_rows, w_rows, any_b, balanced, dt, reps, cvec, y, p0, mean_tol, lin_tol,
                 pfd, order=16, fitted=None):
        """:meth:`run` with the native operator's bands made in the kernel (:func:`._kernels.staged_run_rows`);
        ``fitted``: per stage, the drift takes its upwinding weight (None: nowhere)."""
        f = _f64
        fitted = np.zeros(len(balanced), dtype=np.bool_) if fitted is None else fitted
        y, n_cram, n_newton, info, stage, res = self._k.staged_run_rows(
            f(edges), f(f_rows), f(b_rows), f(w_rows), bool(any_b), np.ascontiguousarray(balanced, dtype=np.bool_),
            np.ascontiguousarray(fitted, dtype=np.bool_), f(dt), np.ascontiguousarray(reps, dtype=np.int64), f(cvec),
            f(y), float(p0), float(mean_tol), float(lin_tol), int(MAX_BALANCE_ITERATIONS), bool(pfd), *self._coef,
            _cancel_flag())
        return self._unless_cancelled(y, n_cram, n_newton, info, stage, res)

    def run(self, lower, diag, upper, wl, wd, wu, balanced, dt, reps, cvec, y, p0, mean_tol, lin_tol, pfd, order=16):
        """Every stage on one grid: ``(y, n_cram, n_newton, info, stage, residual)`` (:func:`._kernels.staged_run`);
        ``pfd``: CRAM-16 in partial fractions, else in the IPF form."""
        f = _f64
        y, n_cram, n_newton, info, stage, res = self._k.staged_run(
            f(lower), f(diag), f(upper), f(wl), f(wd), f(wu), np.ascontiguousarray(balanced, dtype=np.bool_), f(dt),
            np.ascontiguousarray(reps, dtype=np.int64), f(cvec), f(y), float(p0), float(mean_tol), float(lin_tol),
            int(MAX_BALANCE_ITERATIONS), bool(pfd), *self._coef, _cancel_flag())
        return self._unless_cancelled(y, n_cram, n_newton, info, stage, res)

    def _unless_cancelled(self, y, n_cram, n_newton, info, stage, res) -> tuple:
        """The kernel's results as Python numbers; :class:`_Cancelled` where this thread's cancel flag stopped it."""
        if info == CANCELLED:
            raise _Cancelled(f"cancelled before stage {int(stage)}")
        return y, int(n_cram), int(n_newton), int(info), int(stage), float(res)


class _Cancelled(Exception):
    """An integration stopped by a raised cancel flag (never raised: :func:`_cancel_flag` is never set)."""


#: the cancel flag the compiled stage loops read before each stage: never set (the kernels take a writeable int64
#: array)
_NEVER_CANCELLED = np.zeros(1, dtype=np.int64)


def _cancel_flag() -> np.ndarray:
    return _NEVER_CANCELLED


_KERNELS: Optional[_Kernels] = None


def _staged_kernels() -> _Kernels:
    global _KERNELS
    if _KERNELS is None:
        _KERNELS = _Kernels()
    return _KERNELS


def _lump(y: np.ndarray, j: int) -> np.ndarray:
    """``[z + m_0 + .. + m_{j-1}, m_j, ...]``: the first ``j`` cells (below the floor) lumped into ``z``."""
    if j <= 0:
        return y
    return np.concatenate(((y[: j + 1].sum(),), y[j + 1:]))


#: cells just below the floor whose cumulative masses a result keeps for its cdf's spline (:func:`_floor_ghosts`)
FLOOR_GHOSTS = 3


def _floor_ghosts(edges: np.ndarray, y: np.ndarray, j: int) -> Optional[tuple]:
    """``(edges, cumulative)`` of the last :data:`FLOOR_GHOSTS` cells below the floor (``edges[j]``; ``y = [z, m...]``
    unlumped), the cumulative taken from the floor (negative): the density is smooth across the floor, which is
    a cut of the report, not of the problem, so the cdf's spline runs on below it instead of ending there
    (``diagnostics["floor_ghosts"]``; None where fewer cells lie below)."""
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
    """Richardson on a coarse grid: ``(ratio fine - coarse)/(ratio - 1)``, ``fine`` already summed onto the
    coarse cells; ``ratio`` 4 removes the ``h^2`` term, 16 then the ``h^4`` term."""
    return (ratio * fine - coarse) / (ratio - 1.0)


def _pairs(x: np.ndarray) -> np.ndarray:
    """Sum per-cell quantities without a zero-weight entry (moments) over each coarse cell's two halves."""
    return x[0::2] + x[1::2]


def _integrator(assemble: Assemble, rtol: float) -> Callable:
    """``integrate(prep, edges, n_base, refine, coef=None) -> (y, counters)``: :func:`solve_on_grid` with the
    tolerances of ``rtol`` (the balance's mean, its last linear step, the partial fractions)."""
    return lambda pr, e, nb, rf, cf=None: solve_on_grid(pr, e, assemble=assemble, n_base=nb, refine=rf, coef=cf,
                                                        mean_tol=max(1e-13, MEAN_TOL_FRACTION * rtol),
                                                        lin_tol=math.sqrt(LINEAR_FRACTION * rtol),
                                                        partial_fractions=rtol >= PFD_MIN_RTOL)


def solve_fv(problem, *, rtol: float, backend: str, assemble: Assemble = native_assemble, n_cells: Optional[int] = None,
             max_cells: int = MAX_CELLS, p_floor: Optional[float] = None,
             time_integration: str = "cram16", loop: Optional[Callable] = None,
             extra: Optional[dict] = None) -> PressureDistribution:
    """Solve ``problem`` to ``rtol`` on nested grids: the result of :func:`solve_fv_full`."""
    return solve_fv_full(problem, rtol=rtol, backend=backend, assemble=assemble, n_cells=n_cells,
                         max_cells=max_cells, p_floor=p_floor, time_integration=time_integration, loop=loop,
                         extra=extra).result


def solve_fv_full(problem, *, rtol: float, backend: str, assemble: Assemble = native_assemble,
                  n_cells: Optional[int] = None, max_cells: int = MAX_CELLS, p_floor: Optional[float] = None,
                  time_integration: str = "cram16", loop: Optional[Callable] = None, extra: Optional[dict] = None,
                  grid: Optional[GridFamily] = None, plain: Optional[str] = None,
                  warm_start: Optional[WarmStart] = None) -> FVSolution:
    """Solve ``problem`` to ``rtol`` on nested grids (the engine's entry point).

    The upper end of a staged problem's domain comes from the Lamperti bound,
    which sees the diffusivity and the drift but not a balance's drift (its
    multiplier is found during the solve), and it bounds the tail's probability,
    not its share of the mean.  Where the solve then leaves more than ``rtol`` in
    the top cell, or (native operator, which conserves the mean to round-off)
    misses the mean by more than ``rtol p0 / 2``, or fails to refine for another
    reason than the balance, it is repeated once on the conservative domain (the
    spread alone), and ``diagnostics["domain"]`` says so.  Where the grid family
    that the first level's errors favoured (:func:`_regraded`) diverges, the solve
    is repeated on the first level's family, and ``diagnostics["regrade"]`` says so.

    Parameters
    ----------
    problem : FokkerPlanckProblem or StagedProblem
    rtol : float
        Target L1 error (already validated by the caller, in [1e-14, 1)).
    backend : str
        Name stored in the result.
    assemble : callable
        ``assemble(edges, f_centres, a_faces, a_centres) -> (lower, diag, upper)``: the
        backend's operator on the state ``[z, m_0..m_{n-1}]``.
    n_cells : int, optional
        Cells of the coarsest grid (fixed: no adaptive refinement beyond the
        three nested grids).  Default: chosen from ``rtol`` and refined.
    max_cells : int
        Cap on the cells of the finest grid.
    p_floor : float, optional
        Floor (pressure) where the wall is not reached; default ``FLOOR * p0``.
    time_integration : str
        Label of the integrator stored in the diagnostics.
    loop : callable, optional
        ``loop(prep, edges, n_base, refine) -> (y, counters)`` replacing the CRAM
        integration (a library's own time loop).
    extra : dict, optional
        Backend-specific diagnostics added to the common ones.
    grid : GridFamily, optional
        Solve on these grids (a previous solution's ``grid``: its family, domain, grading and depth), edge for
        edge, without refinement (its coarsest grid's cells are ``n_cells``).
    plain : {"keep", "only", "finest", "coarsest", "answer"}, optional
        ``"keep"``: also return the plain cell masses of the last level's three grids (``FVSolution.plain``).
        The others (with ``grid``) integrate only the N and 2N grids (``"only"``), only the 4N grid
        (``"finest"``), only the N grid (``"coarsest"``) or only the 2N grid (``"answer"``) and return those
        (:data:`PLAIN_GRIDS`): no Richardson, no estimate; the result is the finest integrated grid's, failed by
        construction, and ``FVSolution.plain_failure`` says whether a balance failed or a grid was unstable.
    warm_start : WarmStart, optional
        Where the refinement starts (a neighbouring problem's ``next_start``).

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
    if warm_start is not None and (n_cells is not None or grid is not None):
        raise ValueError("warm_start and n_cells or grid exclude each other (n_cells and grid fix the grids)")
    options = dict(rtol=rtol, backend=backend, assemble=assemble, n_cells=n_cells, max_cells=int(max_cells),
                   p_floor=p_floor, time_integration=time_integration, loop=loop, extra=extra, grid=grid,
                   plain=plain, warm_start=warm_start, t_start=t_start)
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
                  max_cells: int, p_floor: Optional[float], time_integration: str, loop: Optional[Callable],
                  extra: Optional[dict], grid: Optional[GridFamily], plain: Optional[str],
                  warm_start: Optional[WarmStart], lamperti: bool, regrade: bool, t_start: float):
    """One attempt of :func:`solve_fv_full` on the Lamperti-bounded domain (``lamperti``) or the conservative one,
    regrading after the first level or not (``regrade``): an :class:`FVSolution`, or ``(diagnostics key, why)``
    where the solve is to be repeated with ``lamperti`` (key ``"domain"``) or ``regrade`` (key ``"regrade"``)
    off."""
    plain_only = plain in PLAIN_GRIDS
    fixed = n_cells is not None or grid is not None  # the three nested grids only, no refinement
    prep = prepare(problem, rtol=rtol, p_floor=p_floor, lamperti=lamperti, on_grid=grid.spec if plain_only else None)
    if grid is not None:  # another problem's grids; its domain, grading and depth as they were
        prep = replace(prep, spec=grid.spec)
    if warm_start is not None and _regradable(prep):
        if warm_start.wall_grading is not None:
            prep = replace(prep, spec=replace(prep.spec, c_wall=float(warm_start.wall_grading)))
        prep = replace(prep, spec=replace(prep.spec, wall_depth=_wall_depth(prep.spec, float(warm_start.wall_depth))))
    # the native operator on coefficients constant within each stage: a grid's integration does not depend on
    # the level it belongs to (levels can reuse grids)
    stage_constant = (loop is None and assemble is native_assemble and not prep.time_dependent
                      and (prep.balance_per_stage or not prep.has_balance))
    t_prep = time.perf_counter() - t_start
    integrate = loop if loop is not None else _integrator(assemble, rtol)
    cap = max_cells // 4  # the most cells of a coarsest grid (its finest grid has 4x as many)
    if grid is not None:
        n = grid.n_cells
    elif n_cells is not None:
        n = int(n_cells)
    elif warm_start is not None:
        n = min(max(int(warm_start.n_start), 8), cap)
    else:
        n = int(min(max((START_CELLS_STAGED if _compiled(prep) and not prep.has_balance else START_CELLS)
                        * (1e-4 / rtol) ** 0.25, 16), 4096))
    history = []

    failure = None
    balance_broke = False  # the failure is a balance's (not the domain's business)
    balance_retries = 0
    # a grid's integration does not depend on which level it belongs to (no substeps tied to the cells): a
    # level that doubles the previous one reuses its two finer grids and integrates only its new finest grid.
    # Native operator only: py-pde's index-space operator on a doubled coarse level failed the engine's mean
    # check where a fresh level passes (p0 = 1, V = 4, Muser cutoff at 0.75: mean off by 3e-3 at 102 cells,
    # estimate 4.6e-4), so the peers keep fresh levels
    reusable = stage_constant
    reuse = None
    remap_factor = 1.0  # the cell factor of a remapped monitor (:func:`_remapped`)
    grading_next = None  # (c_wall, depth fraction, cell factor) the converged level's errors favour (:func:`_regraded`)
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
        # the coarser grids are every 2nd / 4th edge of it; 
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
        elif loop is None and not prep.time_dependent:  # each coefficient evaluated once for all the grids
            coefs = _coefficients_lazy(prep.pieces, es, (tuple(range(len(es))),), centre_drift=centre_drift,
                                       plans=prep.row_plans)
            ys = [integrate(prep, e, n_base, 1 << k, coefs(g)) for g, (k, e) in enumerate(zip(ks, es))]
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
                # the level's grids do not resolve a balance (a first shell far wider than p0): the same level
                # with twice the cells (py-pde, H = 0.8, slope 0.1, zeta = p0 = 1e-5: stage 5 failed on its first
                # level's 158 cells, native solved it on 126; native, H = 0.8, slope 0.031, zeta = 1e-3,
                # p0 = 1e-5: stage 0 failed on the second level's 327 cells)
                balance_retries += 1
                failure, balance_broke = None, False
                n = 2 * n_base
                continue
            if not history:  # nothing to report: the coarsest level failed
                raise RuntimeError(failure)
            break
        unstable = _unstable_grid(es, ys)
        if unstable is not None:
            # a first level too coarse for its drift is refined (random drift problem #196 of seed 6: 112 cells
            # unstable, 448 converged); a level that refinement made unstable is no result (#122 of seed 7: stable
            # on 1440-2880 cells, unstable on 5760 and beyond), and finer grids only cost more
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
        # where the exact mean is p0 (no drift, or a balance), the computed mean's miss is a known error: the L1
        # error is at least |mean - p0| / p_max, and a level whose mean misses by more than its share of rtol p0
        # is refined further (the native operator conserves the mean to round-off; py-pde's index-space
        # operator does not, and its Richardson estimate can miss it on coarse graded grids)
        mean_miss = abs(mean_full - prep.p0) if prep.mean_conserved else 0.0
        if (prep.lamperti_bounded and assemble is native_assemble and loop is None
                and mean_miss > SAFETY * rtol * prep.p0):
            # the native operator conserves the mean to round-off on any grid: a miss is the domain's top cut (the
            # tail beyond the Lamperti bound carries mean, not only mass: local_g1, zeta = 0.3, p0 = 1e-4 missed
            # by 4.4e-6 p0 with 1e-10 in the top cell, and refined to 65536 cells in vain)
            return "domain", (f"conservative: on the Lamperti-bounded domain (p_max = {out_edges[-1]:.4g}) the mean "
                              f"missed p0 by {mean_miss / prep.p0:.2e} p0")
        est = max(est, mean_miss / float(out_edges[-1]))
        # the time integration's own error (not removed by Richardson): its uniform bound per application
        est += CRAM_AMPLIFICATION * max(cc.get("cram_applications", 0) * CRAM_ERROR_BOUND
                                        for _, cc in ys)
        history.append((n_base, est))
        # the estimate falls like N^-4: the cells that meet rtol, as a factor on this level's (the next level's
        # growth where it misses; a sweep's next start where it meets rtol)
        need = NEED_MARGIN * max((est / (SAFETY * rtol)) ** (1.0 / order),
                                 (mean_miss / (SAFETY * rtol * prep.p0)) ** (1.0 / order))
        best = (out_edges, out_y, out_mom, est, cnt, [n_base << k for k in range(3)], mean_full, need)
        best_grid = GridFamily(prep.spec, tuple(idx.tolist()), finest)
        best_ghosts = _floor_ghosts(e2, r23, j2)
        best_plain = (_lump(y1, j1), _lump(y2, j2), _lump(y3, 2 * j2)) if plain == "keep" else None
        trimmed = _trimmed_depth(prep, float(out_y[0]) + est, rtol) if len(history) == 1 else None
        if (est <= SAFETY * rtol and mean_miss <= SAFETY * rtol * prep.p0) or fixed:
            if warm_start is not None and _regradable(prep):
                # the grading this level's errors favour, for the next problem of a sweep (not used here; only
                # where a start was given, as a sweep gives it: it costs 0.3 ms)
                suggested = _regraded(prep, e1, diff, j1)
                if suggested is not None:
                    grading_next = (float(suggested[0].c_wall), _depth_fraction(suggested[0]), float(suggested[1]))
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
        # the remap only under the native operator: py-pde's index-space operator on a remapped grid moved its answer
        # by 2.1e-6 from native's while claiming 4.1e-7 (H 0.8, slope 0.031, zeta 1e-5, p0 1e-4, shell partition)
        remap = assemble is native_assemble and loop is None
        regraded = _regraded(prep, e1, diff, j1, remap=remap) if (
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
        # the grid family the first level's errors favoured failed (H 0.744, rms slope 0.080, zeta 1.6e-4,
        # p0 2.3e-3, shell partition: regraded from 79 to 67 cells, the estimates then grew 1.4e-6 -> 2.4e-6 ->
        # 3.9e-5, "refinement diverges"; on the first level's family it converges on 158 cells): once more without
        # (a divergence only: other failures, e.g. an unstable grid, are reported as they are)
        return "regrade", f"the first level's grid family (the regraded one failed: {failure})"
    edges, y, moments, est, cnt, cells, mean_full, need_last = best
    # the coarsest grid this problem needs for rtol, predicted from the last level as the refinement predicts it
    # (a sweep starts the next problem there: its previous cells over-resolve where the need falls)
    grading_needed, depth_needed = float(prep.spec.c_wall), _depth_fraction(prep.spec)
    if grading_next is not None:  # the cells are then those of the favoured grading
        grading_needed, depth_needed, factor = grading_next
        need_last *= factor
    need_last /= remap_factor  # a sweep starts on the family without the remap (its grading passes on)
    cells_needed = int(min(max(math.ceil(cells[0] * need_last), 16), max(16, cap)))
    # a balance fixes the mean: the tail cut at p_max takes its share of the mean with it, and the balance moves the
    # whole distribution to make up for it (H = 0.8, rms slope 0.1, zeta = 3, p0 = 1e-5, local_g1_balanced: 5.3e-7
    # in the top cell at p_max = 5087 p0, 6.2e-6 beyond it carrying 4.3 % of the mean, and the cdf 3.4e-3 off
    # while the estimate claimed 5.5e-7): the top cell counts with its weight in the mean, p_max / p0
    top_weight = max(1.0, float(edges[-1]) / prep.p0) if prep.has_balance else 1.0
    if prep.lamperti_bounded and failure is None and abs(float(y[-1])) * top_weight > rtol:
        # the Lamperti bound was too short (a balance's drift, which it does not see, carried the tail further)
        return "domain", (f"conservative: on the Lamperti-bounded domain (p_max = {edges[-1]:.4g}) the top cell held "
                          f"{abs(float(y[-1])):.2e}" + (f" (x p_max/p0 = {top_weight:.3g} in the mean)"
                                                         if top_weight > 1.0 else "") + " > rtol")
    if prep.lamperti_bounded and failure is not None and not balance_broke:
        # the peers' operators do not conserve the mean to round-off (no early sign, above): a refinement that
        # failed on the shorter domain is tried once on the conservative one (py-pde, local_g1, zeta = 0.3,
        # p0 = 1e-4: the mean's miss was chased to 65536 cells)
        return "domain", (f"conservative: on the Lamperti-bounded domain (p_max = {edges[-1]:.4g}) the solve "
                          f"failed: {failure}")
    timings = {"setup": t_prep, "solve": time.perf_counter() - t_start - t_prep,
               "total": time.perf_counter() - t_start}
    result = build_result(prep, backend=backend, edges=edges, y=y, moments=moments, estimate=est, rtol=rtol,
                          timings=timings, mean_full=mean_full,
                          extra={"levels": cells, "history": history, "time_integration": time_integration,
                                 "cram_applications": cnt["cram_applications"], "substeps": cnt["substeps"],
                                 "cram_order": cnt.get("cram_order", 16),
                                 "grids_integrated": grids_integrated,
                                 "cells_needed": cells_needed, "remap_factor": remap_factor,
                                 "wall_grading_needed": grading_needed,
                                 "newton_steps": cnt.get("newton_steps", 0),
                                 "domain": "Lamperti-bounded" if prep.lamperti_bounded else "from the spread",
                                 "wall_grading": float(prep.spec.c_wall), "wall_depth": _depth_fraction(prep.spec),
                                 # (the family of the result's grid: its cdf interpolates in the family's coordinate)
                                 "grid": (best_grid.spec, best_grid.knots),
                                 **({"floor_ghosts": best_ghosts} if best_ghosts is not None else {}),
                                 "wall_depth_needed": depth_needed,
                                 **(extra or {})},
                          failure=failure)
    # where a sweep's next problem starts: at most this problem's first grid (starting at its own cells
    # over-resolves where the need falls), on the family without a remap (its cells are the remap's over its
    # factor), with the grading its last level's errors favour
    next_start = None
    if result.success:
        start = int(min(math.ceil(min(cells[0] / remap_factor, cells_needed)), cap))
        next_start = WarmStart(n_start=start, wall_grading=grading_needed if grading_needed > 0.0 else None,
                               wall_depth=depth_needed if grading_needed > 0.0 and depth_needed > 0.0 else 0.0)
    return FVSolution(result=result, grid=best_grid, plain=best_plain, cells_needed=cells_needed,
                      next_start=next_start)


#: a grid whose states sum in absolute value to more than this is not a probability distribution any more: the
#: rational approximation amplified some mode (docs/backends.md "An unstable grid")
UNSTABLE_L1 = 2.0


def _unstable_grid(es: Sequence[np.ndarray], ys: Sequence[tuple]) -> Optional[str]:
    """Why a level's integration is no result, or None: a grid's state not finite, or its absolute sum above
    :data:`UNSTABLE_L1` (probabilities sum to 1; a few round-off negatives do not move that).

    The rational approximations hold near the negative real axis.  A drift that dominates the diffusion (cell Peclet
    numbers ``|a| h / f`` above 2, where the central flux's off-diagonals change sign) gives the operator complex
    eigenvalues, and one near a pole is amplified at every application: on random drift problem #122 of seed 7
    (``fp_random_truth.py``, the smoothstep cutoff at ``p_c/sqrt(V)`` 0.009 with ``p0/sqrt(V)`` 0.005) the
    10168-cell grid reached ``1e237`` at rtol 1e-7, and the refinement then raised on a NaN estimate.  A user's drift
    now leans upwind on such faces (:func:`.operator.fitted_weight`); the check stays for the drifts that keep the
    central flux (closures, balances, py-pde's and FiPy's operators).  ``es[i]`` is the grid of ``ys[i]``."""
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
    """The solution of a plain solve (``plain`` "only", "finest", "coarsest" or "answer"): the grids' own masses
    (``ks`` their refinement exponents; ``finest`` the level's 4N grid), lumped below the floor as an answer is, in the N, 2N and 4N grid's places
    of ``plain`` (None where not integrated); the result is the finest integrated grid's (not extrapolated, no
    estimate: ``success`` is False by construction); ``plain_failure`` is a balance's failure, an unstable grid's
    (:func:`_unstable_grid`) or None."""
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
                      plain_failure=broken[0] if broken else None)


def build_result(prep: Prepared, *, backend: str, edges: np.ndarray, y: np.ndarray, estimate: float, rtol: float,
                 timings: dict, extra: dict, moments: Optional[np.ndarray] = None,
                 mean_full: Optional[float] = None, failure: Optional[str] = None) -> PressureDistribution:
    """The one place a finite-volume result is made (one meaning of ``success``).

    ``p`` of the result holds each cell's barycentre ``moments / masses``
    (clipped into the cell; the midpoint where the mass is not positive), so
    that ``sum(weights * p * density)`` is the first moment the solver computed
    (to the same order as the masses), not a midpoint-rule approximation.

    ``success`` requires all of: the error estimate <= rtol, total probability
    within rtol of 1, the mean (with the floor's mass counted at the floor)
    within ``rtol p0`` of ``p0``, negative probability (kept, never clipped)
    below rtol, the probability in the top cell below rtol, and, where the domain
    starts above the wall and the floor (a truncated bottom), the probability that
    left through it below rtol.
    """
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
    diagnostics["knots"] = density_knots(prep)
    diagnostics["domain_bottom"] = float(prep.spec.p_wall)  # the absorbing lower end of the grids (pressure)
    diagnostics.update({k: v for k, v in extra.items() if k not in diagnostics})
    if prep.label:
        diagnostics["label"] = prep.label
    return PressureDistribution(p=c, density=density, weights=h, zero_weight=z, mean_pressure=prep.p0,
                                variance=2.0 * prep.tau_end, backend=backend, success=bool(success), message=message,
                                error_estimate=float(estimate), wall_time=float(timings["total"]),
                                diagnostics=diagnostics, edges=edges)
