"""The problem's preparation: stages, the wall, the floor and the domain (:func:`prepare`).

* the stages the engine integrates (:class:`_Piece`: coefficients constant in ``tau``; a ``tau``-dependent
  problem in midpoint segments),
* the wall by Feller's criterion (``f ~ p^k`` reaches ``p = 0`` iff ``k < 2``;
  :func:`diffusion_pr.models.wall_reached`) and the floor ``p_floor = FLOOR * p0`` where it is not reached,
* the domain: its upper end from a Gaussian bound on the spread, an affine (Chernoff) bound where the drift grows
  with ``p``, and the Lamperti bound on staged problems; its lower end at the wall, below the floor, or where the
  lower tail ends,
* the grid family (:class:`~.grid.GridSpec`) graded towards ``p0`` and the wall.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from typing import Callable, Optional, Sequence

import numpy as np

from ..models import breakpoints_of, evaluate_vectorized, wall_reached, zero_power_of
from ..problem import FokkerPlanckProblem, StagedProblem
from .grid import GridSpec

__all__ = ["FLOOR", "MAX_RATIO", "Prepared", "prepare", "row_plans", "density_knots"]

#: the domain ends where a diffusion of the problem's largest spread leaves it with probability at most
#: TAIL_FRACTION * rtol (Gaussian bound, :func:`_tail_quantile`): z = 6.1 spreads at rtol 1e-6
TAIL_FRACTION = 1e-3
#: floor of the grid where the wall is not reached, relative to p0 (dimensionless)
FLOOR = 1e-6
#: largest p0 / spread whose distribution double precision can resolve
MAX_RATIO = 1e12
#: the weight of the logarithmic grading towards an exit wall (``f ~ p^k``, ``0 < k < 2``): its wall face is first
#: order, so cells shrinking geometrically towards ``p = 0`` make that error negligible (a fall of
#: 16x per doubling of the cells, as at every other wall)
C_EXIT_WALL = 1.0
#: the inner scale of that grading, ``delta = EXIT_WALL_DEPTH rtol s`` (``s`` the spread); the wall error left is
#: about ``1e-4 delta / s``
EXIT_WALL_DEPTH = 1.0
#: e-folds of p resolved below the floor where the wall is not reached: ln(10/rtol), at least this many;
#: mass that goes further down returns above the floor with probability below exp(-e-folds) = rtol/10
#: for f ~ p^2 (ln p drifts down at the rate it diffuses)
BOTTOM_EFOLDS_MIN = 8.0
#: e-folds resolved below the floor where a drift is present, whatever rtol: a drift can cancel the Ito drift of
#: ln p there, so the answer depends on the depth (docs/closures.md), which therefore may not follow rtol
BOTTOM_EFOLDS_DRIFT = math.log(1e7)
#: fewest e-folds below the floor after the first level's trim (:func:`_trimmed_depth`)
BOTTOM_EFOLDS_TRIMMED = 3.0
#: weight of the logarithmic grading towards the floor (Phi units per e-fold of p)
C_WALL = 0.6
#: a problem with at least this many pieces or a balance is integrated by the compiled kernels (:mod:`._kernels`)
COMPILED_MIN_PIECES = 4
#: fixed-point steps of the Lamperti bound on the tail's share of the mean (mass times p_max / p0) under a balance
LAMPERTI_MEAN_ITERATIONS = 2
#: points of the probe that bounds the spread in :func:`prepare` (grown on the coarse one, confirmed on the full)
PROBE_POINTS = 1024
PROBE_POINTS_COARSE = 128


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
    #: the depth below the floor may be shortened after the first level (:func:`_trimmed_depth`)
    depth_adaptive: bool = False
    #: the upper end was shortened by the Lamperti bound (:func:`prepare`)
    lamperti_bounded: bool = False
    #: the drift takes its upwinding weight (``operator.fitted_weight``): a FokkerPlanckProblem's drift, not a
    #: closure's
    fitted_drift: bool = False
    #: the coefficients' breakpoints, where the density may jump or kink (None: unknown; :func:`density_knots`)
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
    #: ``plan(p, out=None)``: the rows of ``funcs`` in one compiled call, where their type offers ``row_plan``;
    #: else None
    plan: Optional[Callable]


def row_plans(pieces: Sequence) -> dict:
    """``{"f": StageRows, "b": StageRows, "w": StageRows}`` of ``pieces``, gathered once per problem."""
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
    """The knots where the final density may jump or kink: the coefficients' breakpoints (``p0`` and the floor
    only where they are breakpoints too)."""
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
    """``[g(p) for g in funcs]`` as rows, checked like :func:`_check_f`; ``plan`` (:func:`row_plans`, one compiled
    pass, None where a value is not finite) first."""
    if plan is not None:
        block = plan(p, out)
        if block is not None:
            return block
    if out is None:
        out = np.empty((len(funcs), p.size))
    for k, g in enumerate(funcs):
        out[k] = _check_f(g, p, f"{name} of stage {k}")
    return out


def _tau_independent(problem: FokkerPlanckProblem) -> bool:
    """Whether the drift ``a(p, tau)`` returns identical values at nine probe times (then one stage)."""
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
                # consecutive stages with the same diffusivity and nothing else commute: one exponential, exactly
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
    """Whether the wall is reached by a vanishing diffusivity, ``f ~ p^k`` with ``0 < k < 2`` (Feller's exit)."""
    return bool(reached and 0.0 < zero_power < 2.0)


def _exit_wall(prep: Prepared) -> bool:
    """Whether an exit wall (:func:`_is_exit`) meets an ungraded grid family (second order there)."""
    return _is_exit(prep.reached, prep.zero_power) and prep.spec.c_wall == 0.0


@functools.lru_cache(maxsize=64)
def _tail_quantile(mass: float) -> float:
    """``z`` with ``erfc(z / sqrt 2) = mass``: a diffusion whose quadratic variation is at most ``s^2`` leaves
    ``p0 + z s`` with probability at most ``mass`` (time change to Brownian motion, reflection principle)."""
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
    and ``M + z sqrt(V)`` bounds the tail (``g = 0`` gives ``p0 + shift + z s``).  None where ``g dtau > 350``.
    Where this bound is below ``bounded``, :func:`_affine_chernoff_bound` may tighten it.
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
    # a diffusivity growing with p, bounded by F0 + F1 p: the affine diffusion's exponential moments bound tighter
    chernoff = _affine_chernoff_bound(pieces, _slopes_of(with_b, rates, intercepts), f_rows, probe, p0, spread,
                                      z) if bound < bounded else None
    if chernoff is not None and chernoff < bound:
        bound = chernoff
    return bound, mean - p0, spread


def _affine_moments(pieces: Sequence, with_b: Sequence, rates: np.ndarray, intercepts: np.ndarray,
                    f_max: np.ndarray, p0: float) -> Optional[tuple]:
    """``(mean, var)`` of :func:`_affine_envelope_bound`'s affine diffusion after every stage, or None where a
    stage's ``g dtau`` exceeds 350."""
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
    is ``c + g p`` and whose diffusivity is ``F0 + F1 p`` (affine envelopes on the probe), started at ``p0``;
    ``mass`` is the one-sided Gaussian tail of ``z``.  None where ``f`` does not grow with ``p`` or no ``theta``
    has a finite moment.

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



def prepare(problem, *, rtol: float, p_floor: Optional[float] = None, lamperti: bool = True,
            on_grid: Optional[GridSpec] = None) -> Prepared:
    """Classify the wall, bound the domain and fix the grid family of ``problem``.

    Raises
    ------
    ValueError
        ``f = 0`` everywhere (the start never moves), ``p0/spread`` beyond
        double precision (``> 1e12``), or a coefficient that is not a
        vectorized finite callable.

    ``lamperti=False``: the upper end from the spread alone, never the shorter Lamperti bound.
    ``on_grid``: the grid family is given: no domain probe, no grading.
    """
    p0, pieces, time_dependent, segment_fn = _pieces_of(problem)
    tau_end = float(sum(pc.duration for pc in pieces))
    plans = None if time_dependent else row_plans(pieces)
    if on_grid is not None:
        return _prepared_on(problem, p0, pieces, time_dependent, segment_fn, tau_end, on_grid, p_floor, plans)
    return _prepare_probed(problem, rtol, p_floor, lamperti, p0, pieces, time_dependent, segment_fn, tau_end, plans)


def _prepare_probed(problem, rtol: float, p_floor: Optional[float], lamperti: bool, p0: float, pieces: Sequence,
                    time_dependent: bool, segment_fn: Optional[Callable], tau_end: float,
                    plans: Optional[dict]) -> Prepared:
    """:func:`prepare` with the domain probe, the Lamperti bound and the grid family."""
    # spread: sqrt(2 sum dtau max f) on an expanding probe, plus the drift displacement
    p_hi = p0 * 4.0
    points = PROBE_POINTS_COARSE
    with_b = [pc for pc in pieces if pc.b is not None]
    durations = np.array([pc.duration for pc in pieces], dtype=float)
    durations_b = np.array([pc.duration for pc in with_b], dtype=float)
    z = _tail_quantile(TAIL_FRACTION * max(rtol, 1e-15))
    for _ in range(60):
        probe = np.linspace(0.0, p_hi, points + 1)[1:]
        f_rows = _rows([pc.f for pc in pieces], probe, "the diffusivity", plan=_plan(plans, "f"))
        f_max = f_rows.max(axis=1)
        # only a drift away from the wall moves the upper tail up (comparison with the drift max(a, 0))
        var = _ordered_sum(2.0 * durations * f_max)
        shift = 0.0
        if with_b:
            b_rows = _rows([pc.b for pc in with_b], probe, "the drift", plan=_plan(plans, "b"))
            shift = _ordered_sum(durations_b * np.maximum(b_rows, 0.0).max(axis=1))
        s = math.sqrt(var)
        new = p0 + shift + z * s
        # where that bound does not close on this probe, a drift growing with p may: its affine envelope
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
    # a drift towards the wall moves the lower tail down (comparison with the drift -max(-a, 0) below p0)
    shift_down = 0.0
    if with_b:
        below = b_rows[:, :int(np.searchsorted(probe, p0, side="right"))]  # (the probe increases: probe <= p0)
        towards = np.negative(below)
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
        _rows(with_w, probe, "the balance", plan=_plan(plans, "w"))
    p_max = new
    lamperti_bounded = False
    if lamperti and not growing and not time_dependent and len(pieces) >= COMPILED_MIN_PIECES:
        # the Lamperti coordinate Y = int dp / sqrt(2 F), F = sum dtau_k f_k: Y - Y(p0) is a unit-variance
        # diffusion whose Ito drift -F'/(2 sqrt(2F)) points down where F grows, so z units of Y bound the tail
        nodes = np.linspace(p0, p_max, 2049)
        weighted = np.maximum(_rows([pc.f for pc in pieces], nodes, "the diffusivity", plan=_plan(plans, "f")), 0.0)
        weighted *= durations[:, None]
        F = np.add.reduce(weighted, axis=0)
        if np.all(np.diff(F) >= 0.0) and F[0] > 0.0:
            rho = 1.0 / np.sqrt(2.0 * F)
            y_l = np.concatenate(([0.0], np.cumsum(0.5 * np.diff(nodes) * (rho[1:] + rho[:-1]))))
            z_tail = z
            for _ in range(LAMPERTI_MEAN_ITERATIONS if with_w else 0):
                # under a balance the tail's share of the mean (mass times p_max / p0) must meet the tolerance
                if y_l[-1] <= z_tail:
                    break
                p_cut = float(np.interp(z_tail, y_l, nodes)) + shift
                z_tail = _tail_quantile(TAIL_FRACTION * max(rtol, 1e-15) * min(1.0, p0 / p_cut))
            if y_l[-1] > z_tail:
                p_max = min(p_max, float(np.interp(z_tail, y_l, nodes)) + shift)
                lamperti_bounded = p_max < new
    bps, k_min, reached, floor = _wall_of(pieces, time_dependent, p0, p_max, p_floor)
    has_balance = any(pc.w is not None for pc in pieces)
    has_drift = any(pc.b is not None for pc in pieces)
    # far from the wall less than the tail tolerance gets below p0 - z s: the domain starts there
    p_lo = p0 - (z * s + shift + shift_down)
    truncated = p_lo > floor
    if truncated:
        floor_domain = p_lo
    elif reached:
        floor_domain = 0.0
    else:  # the wall is not reached: resolve BOTTOM_EFOLDS e-folds below the floor (the floor is an edge)
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
    """``terms[0] + terms[1] + ...`` added left to right, 0 where empty."""
    return float(np.cumsum(terms)[-1]) if terms.size else 0.0


def _wall_of(pieces: Sequence, time_dependent: bool, p0: float, p_max: float, p_floor: Optional[float]) -> tuple:
    """``(breakpoints, zero power, reached, floor)``: Feller's criterion on every stage (the wall absorbs if one of
    them reaches it) and the floor of a wall that is not reached."""
    bps: list[float] = []
    k_min = math.inf
    scale = p0
    seen = set()  # a model shared by several stages is asked once
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
    """The :class:`Prepared` record of a classified problem on its grid family (cells below the floor lumped
    where the wall is not reached and the domain not truncated)."""
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

def _trimmed_depth(prep: Prepared, below_floor: float, rtol: float) -> Optional[Prepared]:
    """``prep`` with a shallower domain below the floor, or None (keep it).

    From ``d`` e-folds below the floor ``ln p`` returns with probability ``exp(-d)`` (``f ~ p^2``); at most
    ``below_floor`` goes below at all, so ``d = ln(10 below_floor / rtol)`` (at least
    :data:`BOTTOM_EFOLDS_TRIMMED`) keeps the returning probability below ``rtol/10``.  Trimmed when that saves at
    least two e-folds.
    """
    if not prep.depth_adaptive:
        return None
    depth = math.log(prep.p_floor / prep.spec.p_wall)
    new = max(BOTTOM_EFOLDS_TRIMMED, math.log(10.0 * max(below_floor, 1e-300) / rtol))
    if new > depth - 2.0:
        return None
    return replace(prep, spec=replace(prep.spec, p_wall=prep.p_floor * math.exp(-new)), depth_adaptive=False)


def _compiled(prep: Prepared) -> bool:
    """Whether ``prep`` is integrated by the compiled kernels (else LAPACK): a balance, or at least
    COMPILED_MIN_PIECES pieces; a time-dependent problem has at least 4 segments (``max(4, n_base // 8)``)."""
    return prep.has_balance or prep.time_dependent or len(prep.pieces) >= COMPILED_MIN_PIECES

