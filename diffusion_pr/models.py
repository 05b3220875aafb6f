"""Pressure dependence of the diffusivity ``D(p, eta) = D(eta) c(p) t(p)`` (docs/theory.md).

Cutoffs ``c(p)`` switch ``D`` off at and below ``p = 0``: :class:`SharpCutoff` (Persson's mirror Gaussian),
:class:`MuserCutoff` (the seed paper's printed factor; Müser, PRL 100, 055504 (2008),
doi:10.1103/PhysRevLett.100.055504), :class:`RaisedCosineCutoff` (C1), :class:`SmoothstepCutoff` (C2, the paper's
"D, D' and D'' continuous").  Tails ``t(p)`` for large pressures: :class:`GaussianTail` (``t = 1``), and
:class:`LinearTail`, :class:`MaxLinearTail`, whose ``D ∝ p`` gives exponential tails.  All are frozen dataclasses,
vectorized callables of a pressure array (the unit of ``mean_pressure``); any vectorized callable of ``p`` is accepted
wherever a cutoff or tail is.

The model protocol: a coefficient may declare ``zero_power``, the ``k`` of
``f(p) ~ C p^k`` as ``p -> 0+`` (Feller, Ann. Math. 55, 468 (1952), doi:10.2307/1969644: mass reaches the absorbing
wall in finite time iff ``k < 2``; for ``k >= 2`` the solvers resolve it on a logarithmic grid down to a floor), and
``breakpoints()``, the pressures where ``f``, ``f'`` or ``f''`` jump (cell edges go there).  Every class here
declares both; for a plain callable :func:`zero_power_of` and :func:`breakpoints_of` probe them."""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Callable, ClassVar, Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import check_positive

PressureFunction = Callable[[NDArray[np.float64]], NDArray[np.float64]]

#: Feller's threshold: the wall p = 0 is reached in finite tau iff f ~ p^k with k < WALL_POWER
WALL_POWER = 2.0


def wall_reached(k: float) -> bool:
    """Feller's criterion: ``f ~ p^k`` reaches ``p = 0`` in finite tau iff ``k < 2``."""
    return bool(k < WALL_POWER)


def evaluate_vectorized(f: Callable, p: np.ndarray, name: str | None = None) -> np.ndarray:
    """``f(p)``, one value per pressure: a scalar result is broadcast (a constant ``f``); any other shape, or an
    exception inside ``f``, is a ``ValueError`` naming ``name`` (default: the callable's repr) and the shapes."""
    who = f"the callable {f!r}" if name is None else name
    try:
        out = np.asarray(f(p), dtype=float)
    except Exception as exc:  # the user's callable: say what went wrong, where
        raise ValueError(f"{who} failed on a pressure array of shape {p.shape}: "
                         f"{type(exc).__name__}: {exc}") from exc
    if out.shape != p.shape:
        if out.ndim == 0:
            out = np.full(p.shape, float(out))
        else:
            raise ValueError(f"{who} returned shape {out.shape} for pressures of shape {p.shape}; "
                             "it must be vectorized (same shape out as in)")
    return out


def zero_power_of(f: Callable, scale: float) -> float:
    """``k`` of ``f ~ p^k`` at ``p -> 0+`` for a vectorized ``f``: its declared ``zero_power``, else a probe.

    The probe takes the median slope of ``log f`` against ``log p`` between consecutive ``p = scale 10^-j``
    (``j = 2..8``; ``scale`` the problem's pressure scale, e.g. ``min(p0, p_c)``) with ``f > 0``, snapped to the
    nearest integer within 0.02; ``f = 0`` at every probe gives ``inf``."""
    declared = getattr(f, "zero_power", None)
    if declared is not None:
        return float(declared)
    probes = float(scale) * 10.0 ** -np.arange(2.0, 9.0)
    vals = evaluate_vectorized(f, probes)
    pos = np.flatnonzero(vals > 0.0)
    if pos.size == 0:
        return math.inf
    if pos.size == 1:
        return 0.0 if pos[0] == probes.size - 1 else math.inf
    lv, lp = np.log(vals[pos]), np.log(probes[pos])
    k = float(np.median(np.diff(lv) / np.diff(lp)))  # median: robust to round-off (1 - cos near 0)
    if abs(k - round(k)) < 0.02:
        k = float(round(k))
    return max(k, 0.0)


def breakpoints_of(f: Callable, p_lo: float, p_hi: float) -> tuple[float, ...]:
    """Non-smooth points of ``f`` in ``(p_lo, p_hi)`` (units of pressure): ``f.breakpoints()`` where declared, else
    the jumps of ``f`` found on a 4096-point probe and bisected to 1e-13 relative."""
    method = getattr(f, "breakpoints", None)
    declared = getattr(f, "declared", None)
    if callable(method) and (not callable(declared) or declared()):
        return tuple(sorted(float(b) for b in method() if p_lo < float(b) < p_hi))
    x = np.linspace(p_lo, p_hi, 4097)
    y = evaluate_vectorized(f, x)
    d = np.abs(np.diff(y))
    if d.size < 3:
        return ()
    smooth = np.maximum(np.maximum(np.r_[d[1:], 0.0], np.r_[0.0, d[:-1]]), 1e-14 * max(np.max(np.abs(y)), 1e-300))
    jumps = np.flatnonzero(d > 8.0 * smooth)
    out = []
    for i in jumps:
        a, b = x[i], x[i + 1]
        ya = evaluate_vectorized(f, np.array([a]))[0]
        for _ in range(60):
            m = 0.5 * (a + b)
            if m <= a or m >= b or (b - a) <= 1e-13 * abs(b):
                break
            ym = evaluate_vectorized(f, np.array([m]))[0]
            if abs(ym - ya) < 0.5 * abs(y[i + 1] - y[i]):
                a, ya = m, ym
            else:
                b = m
        out.append(float(b))
    return tuple(out)


class _Model:
    """Base of the pressure factors below: every dataclass field is a pressure (checked finite and > 0), and
    no breakpoint unless a subclass names one."""

    def __post_init__(self) -> None:
        for f in fields(self):  # type: ignore[arg-type]
            object.__setattr__(self, f.name, check_positive(f.name, getattr(self, f.name)))

    def breakpoints(self) -> tuple[float, ...]:
        """Pressures (units of pressure) inside ``p > 0`` where ``f``, ``f'`` or ``f''`` jump: none."""
        return ()


@dataclass(frozen=True)
class SharpCutoff(_Model):
    """Sharp cutoff ``c(p) = theta(p)`` (1 for ``p > 0``, 0 otherwise), discontinuous at ``p = 0``
    (``continuity = -1``): mass that diffuses to ``p = 0`` is absorbed there, the non-contact weight."""

    continuity: ClassVar[int] = -1  # -1: the function itself jumps somewhere
    zero_power: ClassVar[float] = 0.0  # f(0+) = 1: the wall is reached (Feller)

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        return np.where(np.asarray(p, dtype=float) > 0.0, 1.0, 0.0)


@dataclass(frozen=True)
class _Cutoff(_Model):
    """A switch from 0 at ``p <= 0`` to its plateau, ending at the cutoff pressure ``p_c`` (> 0, units of pressure);
    subclasses set ``continuity`` (the highest continuous derivative, -1 for a jump), ``zero_power``, ``__call__``."""

    p_c: float

    def breakpoints(self) -> tuple[float, ...]:
        """``p_c`` (units of pressure), where the switch ends."""
        return (self.p_c,)


@dataclass(frozen=True)
class MuserCutoff(_Cutoff):
    """The seed paper's cutoff, exactly as printed, for a cutoff pressure ``p_c`` > 0 (units of pressure).

    ``c(p) = 1 - theta(p_c - p) cos(pi p / p_c)`` for ``p >= 0`` and 0 for ``p < 0`` (Müser 2008, text below Eq. 10).
    Below ``p_c`` it rises from 0 to 2; above ``p_c`` it is 1.  It is continuous with zero slope at ``p = 0`` but jumps
    from 2 to 1 at ``p = p_c`` (``continuity = -1``).  ``c ~ (pi p/p_c)^2/2`` near 0, so no mass reaches ``p = 0``: the
    non-contact peak broadens instead."""

    continuity: ClassVar[int] = -1
    zero_power: ClassVar[float] = 2.0  # f ~ p^2 at 0: the wall is not reached

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        p = np.asarray(p, dtype=float)
        # 1 - cos(x) = 2 sin^2(x/2): no cancellation for small x (1 - cos underflows to 0 below x ~ 1e-8)
        below = 2.0 * np.sin(0.5 * np.pi * p / self.p_c) ** 2
        return np.where(p < 0.0, 0.0, np.where(p < self.p_c, below, 1.0))


@dataclass(frozen=True)
class RaisedCosineCutoff(_Cutoff):
    """C1 raised-cosine switch ``(1 - cos(pi p/p_c)) / 2`` on ``[0, p_c]`` (``p_c`` > 0, units of pressure), 0 for
    ``p <= 0``, 1 for ``p >= p_c``; the second derivative jumps at 0 and ``p_c`` (``continuity = 1``)."""

    continuity: ClassVar[int] = 1
    zero_power: ClassVar[float] = 2.0  # f ~ p^2 at 0: the wall is not reached

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        x = np.clip(np.asarray(p, dtype=float) / self.p_c, 0.0, 1.0)
        return np.sin(0.5 * np.pi * x) ** 2  # = (1 - cos(pi x))/2 without cancellation near 0


@dataclass(frozen=True)
class SmoothstepCutoff(_Cutoff):
    """C2 quintic smoothstep ``6x^5 - 15x^4 + 10x^3``, ``x = p / p_c`` (``p_c`` > 0, units of pressure), 0 for
    ``p <= 0``, 1 for ``p >= p_c`` (``continuity = 2``: the switch the paper's text describes); ``c ~ 10 (p/p_c)^3``
    near 0, so no mass reaches ``p = 0``."""

    continuity: ClassVar[int] = 2
    zero_power: ClassVar[float] = 3.0  # f ~ p^3 at 0: the wall is not reached

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        x = np.clip(np.asarray(p, dtype=float) / self.p_c, 0.0, 1.0)
        return x * x * x * (10.0 + x * (-15.0 + 6.0 * x))


@dataclass(frozen=True)
class GaussianTail(_Model):
    """Tail factor ``t(p) = 1``: pressure-independent diffusivity, Gaussian tails."""

    zero_power: ClassVar[float] = 0.0

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        return np.ones_like(np.asarray(p, dtype=float))


@dataclass(frozen=True)
class LinearTail(_Model):
    """Tail factor ``t(p) = 1 + p / p_t`` (exponential tail of ``Pr``); ``p_t`` > 0 (units of pressure)."""

    p_t: float
    zero_power: ClassVar[float] = 0.0

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        return 1.0 + np.maximum(np.asarray(p, dtype=float), 0.0) / self.p_t


@dataclass(frozen=True)
class MaxLinearTail(_Model):
    """Tail factor ``t(p) = max(1, p / p_t)`` (exponential tail above ``p_t`` > 0, units of pressure)."""

    p_t: float
    zero_power: ClassVar[float] = 0.0

    def breakpoints(self) -> tuple[float, ...]:
        """The kink at ``p_t`` (units of pressure)."""
        return (self.p_t,)

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        return np.maximum(1.0, np.asarray(p, dtype=float) / self.p_t)


_CUTOFFS = {"sharp": SharpCutoff, "muser": MuserCutoff, "seed": MuserCutoff, "raised_cosine": RaisedCosineCutoff,
            "smoothstep": SmoothstepCutoff}
_TAILS = {"gaussian": GaussianTail, "linear": LinearTail, "max_linear": MaxLinearTail}


def _make(kind: str, spec: object, pname: str, value: float | None, table: dict) -> PressureFunction:
    """The factor named ``spec`` in ``table`` (None: the first entry), given ``pname=value`` exactly where it takes
    one, or the callable ``spec`` itself (without ``pname``)."""
    if spec is None:
        spec = next(iter(table))
    if isinstance(spec, str):
        cls = table.get(spec.lower())
        if cls is None:
            raise ValueError(f"{kind} must be one of {sorted(table)} or a callable; got {kind}={spec!r}")
        takes = bool(fields(cls))
    elif callable(spec):
        cls, takes = None, False
    else:
        raise ValueError(f"{kind} must be a name or a vectorized callable of p; got {type(spec).__name__}")
    if takes and value is None:
        raise ValueError(f"{kind}={spec!r} needs a pressure {pname} > 0; got {pname}=None")
    if not takes and value is not None:
        raise ValueError(f"{pname} applies to the {kind}s {[k for k, c in table.items() if fields(c)]} only; "
                         f"{kind}={spec!r} would ignore {pname}={value!r}")
    return spec if cls is None else (cls(value) if takes else cls())  # type: ignore[return-value]


def make_cutoff(cutoff: object, p_c: float | None = None) -> PressureFunction:
    """Turn a cutoff specification into a callable ``c(p)``.

    Parameters
    ----------
    cutoff : str, callable or None
        ``None`` or ``"sharp"`` (the domain is ``p >= 0`` in any case, so ``c = 1`` on it *is* the sharp cutoff); a
        name from ``"muser"`` (alias ``"seed"``), ``"raised_cosine"``, ``"smoothstep"``; or any vectorized callable.
    p_c : float, optional
        Cutoff pressure (units of pressure) of the named smooth cutoffs, > 0; given for any other, an error.

    Raises
    ------
    ValueError
        Unknown name, ``p_c`` missing or non-positive for a smooth cutoff or given for another, a non-callable.
    """
    return _make("cutoff", cutoff, "p_c", p_c, _CUTOFFS)


def make_tail(tail: object, p_t: float | None = None) -> PressureFunction:
    """Turn a tail specification into a callable ``t(p)``.

    Parameters
    ----------
    tail : str, callable or None
        ``None`` or ``"gaussian"`` (``t = 1``), ``"linear"`` (``1 + p/p_t``), ``"max_linear"`` (``max(1, p/p_t)``), or
        any vectorized callable.
    p_t : float, optional
        Crossover pressure (units of pressure) of the linear tails, > 0; given for any other, an error.
    """
    return _make("tail", tail, "p_t", p_t, _TAILS)


@dataclass(frozen=True)
class PressureFactor:
    """Product ``f(p) = c(p) * t(p)`` (dimensionless): the pressure factor of ``D(p, eta)``, the ``diffusivity``
    :func:`diffusion_pr.propagate` takes; ``tail=None`` is the Gaussian tail ``t = 1``."""

    cutoff: PressureFunction
    tail: Optional[PressureFunction] = None

    def __post_init__(self) -> None:
        if self.tail is None:
            object.__setattr__(self, "tail", GaussianTail())
        for name in ("cutoff", "tail"):
            part = getattr(self, name)
            if not callable(part):
                raise ValueError(f"PressureFactor.{name} must be a vectorized callable of the pressure "
                                 f"(make_cutoff / make_tail turn names into one); got {name}={part!r}")

    @property
    def zero_power(self) -> Optional[float]:  # type: ignore[override]
        """``k`` of ``c t ~ p^k`` at 0: the sum of the parts' declared powers (None if one is undeclared)."""
        kc, kt = getattr(self.cutoff, "zero_power", None), getattr(self.tail, "zero_power", None)
        return None if kc is None or kt is None else float(kc) + float(kt)

    def breakpoints(self) -> tuple[float, ...]:
        """Union of the parts' breakpoints (parts without ``breakpoints()`` are probed by the solver)."""
        return tuple(sorted({float(b) for part in (self.cutoff, self.tail)
                             if callable(getattr(part, "breakpoints", None)) for b in part.breakpoints()}))

    def declared(self) -> bool:
        """Whether both parts declare the protocol (else the solver probes the product)."""
        return all(callable(getattr(part, "breakpoints", None)) and getattr(part, "zero_power", None) is not None
                   for part in (self.cutoff, self.tail))

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        p = np.asarray(p, dtype=float)
        return np.asarray(self.cutoff(p), dtype=float) * np.asarray(self.tail(p), dtype=float)


@dataclass(frozen=True)
class ProportionalDiffusivity(_Model):
    """Pure linear pressure factor ``f(p) = p / p_1`` (0 for ``p <= 0``), ``p_1`` > 0 (units of pressure).

    The diffusivity ``D ∝ p`` of the paper's exponential-tail argument taken literally down to ``p = 0``.  From
    ``delta(p - p0)`` the exact solution is Feller's (W. Feller, Ann. Math. 54, 173 (1951)): see
    :func:`diffusion_pr.closed_forms.feller_density` with ``slope = 1/p_1``. ``p = 0`` is an exit boundary: mass
    ``exp(-p0 p_1 / tau)`` is absorbed."""

    p_1: float
    continuity: ClassVar[int] = 0  # continuous, kink at p = 0
    zero_power: ClassVar[float] = 1.0  # f ∝ p: Feller's exit boundary, the wall is reached

    @property
    def slope(self) -> float:
        """``1 / p_1`` (1 / pressure)."""
        return 1.0 / self.p_1

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        return np.maximum(np.asarray(p, dtype=float), 0.0) / self.p_1
