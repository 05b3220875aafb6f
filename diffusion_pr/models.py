"""Pressure dependence of the diffusivity: cutoffs ``c(p)`` and tails ``t(p)``.

The magnification-dependent diffusivity of the Fokker-Planck equation
(SPEC section 4) is ``D(p, eta) = D(eta) * c(p) * t(p)``.  This module holds the
pressure factors as small frozen dataclasses that are vectorized callables of a
pressure array (same units as ``mean_pressure`` and ``E_star``):

Cutoffs ``c(p)`` (switch ``D`` off at and below ``p = 0``)
    * :class:`SharpCutoff` -- ``theta(p)``; with ``t = 1`` the exact solution is
      Persson's mirror Gaussian plus a ``delta(p)`` non-contact peak.
    * :class:`MuserCutoff` -- the seed paper's printed factor
      ``1 - theta(p_c - p) cos(pi p / p_c)`` (Müser, PRL 100, 055504 (2008),
      doi:10.1103/PhysRevLett.100.055504).  Read literally it rises from 0 to 2
      just below ``p_c`` and drops to 1 above: it is *discontinuous* at ``p_c``.
    * :class:`RaisedCosineCutoff` -- ``(1 - cos(pi p / p_c)) / 2`` below ``p_c``:
      C1 everywhere (second derivative jumps at 0 and ``p_c``).
    * :class:`SmoothstepCutoff` -- ``6x^5 - 15x^4 + 10x^3`` with ``x = p / p_c``:
      C2 everywhere, what the paper's text asks for ("D, D' and D''
      continuous").

Tails ``t(p)`` (large-pressure behaviour)
    * :class:`GaussianTail` -- ``t = 1`` (Gaussian tails, the default).
    * :class:`LinearTail` -- ``t = 1 + p / p_t``.
    * :class:`MaxLinearTail` -- ``t = max(1, p / p_t)``.

    Both linear variants make ``D`` grow proportionally to ``p`` at large ``p``,
    which gives exponential tails (the paper's "D proportional to sigma").

Any vectorized callable of ``p`` is accepted wherever a cutoff or tail is.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import check_positive

PressureFunction = Callable[[NDArray[np.float64]], NDArray[np.float64]]


@dataclass(frozen=True)
class SharpCutoff:
    """Sharp cutoff ``c(p) = theta(p)`` (1 for ``p > 0``, 0 otherwise).

    Continuity: discontinuous at ``p = 0`` (``continuity = -1``).  Mass that
    diffuses to ``p = 0`` is absorbed there and becomes the non-contact weight.
    """

    continuity: int = -1  # -1 = the function itself jumps somewhere
    absorbing: bool = True  # mass reaches p = 0 in finite magnification

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        p = np.asarray(p, dtype=float)
        return np.where(p > 0.0, 1.0, 0.0)


@dataclass(frozen=True)
class MuserCutoff:
    """The seed paper's cutoff, exactly as printed.

    ``c(p) = 1 - theta(p_c - p) cos(pi p / p_c)`` for ``p >= 0`` and 0 for
    ``p < 0`` (Müser 2008, text below Eq. 10).  Below ``p_c`` it rises from 0 to
    2; above ``p_c`` it is 1.  It is continuous with zero slope at ``p = 0`` but
    jumps from 2 to 1 at ``p = p_c`` (``continuity = -1``).  ``c ~ (pi p/p_c)^2/2``
    near 0, so no mass reaches ``p = 0``: the non-contact peak broadens instead.

    Parameters
    ----------
    p_c : float
        Cutoff pressure (units of pressure), > 0.
    """

    p_c: float
    continuity: int = -1
    absorbing: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "p_c", check_positive("p_c", self.p_c))

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        p = np.asarray(p, dtype=float)
        # 1 - cos(x) = 2 sin^2(x/2): no cancellation for small x (1 - cos underflows to 0 below x ~ 1e-8)
        below = 2.0 * np.sin(0.5 * np.pi * p / self.p_c) ** 2
        return np.where(p < 0.0, 0.0, np.where(p < self.p_c, below, 1.0))


@dataclass(frozen=True)
class RaisedCosineCutoff:
    """C1 raised-cosine switch: ``(1 - cos(pi p/p_c)) / 2`` on ``[0, p_c]``.

    0 for ``p <= 0``, 1 for ``p >= p_c``.  Value and first derivative are
    continuous; the second derivative jumps at 0 and ``p_c`` (``continuity = 1``).

    Parameters
    ----------
    p_c : float
        Cutoff pressure (units of pressure), > 0.
    """

    p_c: float
    continuity: int = 1
    absorbing: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "p_c", check_positive("p_c", self.p_c))

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        x = np.clip(np.asarray(p, dtype=float) / self.p_c, 0.0, 1.0)
        return np.sin(0.5 * np.pi * x) ** 2  # = (1 - cos(pi x))/2 without cancellation near 0


@dataclass(frozen=True)
class SmoothstepCutoff:
    """C2 quintic smoothstep ``6x^5 - 15x^4 + 10x^3`` with ``x = p / p_c``.

    0 for ``p <= 0``, 1 for ``p >= p_c``; value, first and second derivatives
    are continuous everywhere (``continuity = 2``): the switch the paper's text
    describes.  ``c ~ 10 (p/p_c)^3`` near 0, so no mass reaches ``p = 0``.

    Parameters
    ----------
    p_c : float
        Cutoff pressure (units of pressure), > 0.
    """

    p_c: float
    continuity: int = 2
    absorbing: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "p_c", check_positive("p_c", self.p_c))

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        x = np.clip(np.asarray(p, dtype=float) / self.p_c, 0.0, 1.0)
        return x * x * x * (10.0 + x * (-15.0 + 6.0 * x))


@dataclass(frozen=True)
class GaussianTail:
    """Tail factor ``t(p) = 1``: pressure-independent diffusivity, Gaussian tails."""

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        return np.ones_like(np.asarray(p, dtype=float))


@dataclass(frozen=True)
class LinearTail:
    """Tail factor ``t(p) = 1 + p / p_t`` (exponential tail of ``Pr``).

    Parameters
    ----------
    p_t : float
        Crossover pressure (units of pressure), > 0.
    """

    p_t: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "p_t", check_positive("p_t", self.p_t))

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        return 1.0 + np.maximum(np.asarray(p, dtype=float), 0.0) / self.p_t


@dataclass(frozen=True)
class MaxLinearTail:
    """Tail factor ``t(p) = max(1, p / p_t)`` (exponential tail above ``p_t``).

    Parameters
    ----------
    p_t : float
        Crossover pressure (units of pressure), > 0.
    """

    p_t: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "p_t", check_positive("p_t", self.p_t))

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        return np.maximum(1.0, np.asarray(p, dtype=float) / self.p_t)


Cutoff = Union[SharpCutoff, MuserCutoff, RaisedCosineCutoff, SmoothstepCutoff, PressureFunction]
Tail = Union[GaussianTail, LinearTail, MaxLinearTail, PressureFunction]

_CUTOFFS = {
    "sharp": SharpCutoff,
    "muser": MuserCutoff,
    "seed": MuserCutoff,
    "raised_cosine": RaisedCosineCutoff,
    "smoothstep": SmoothstepCutoff,
}


def make_cutoff(cutoff: object, p_c: float | None = None) -> PressureFunction:
    """Turn a cutoff specification into a callable ``c(p)``.

    Parameters
    ----------
    cutoff : str, callable or None
        ``None`` means the sharp cutoff (the domain is ``p >= 0`` in any
        case, so ``c = 1`` on it *is* the sharp cutoff); a name from ``"sharp"``, ``"muser"`` (alias ``"seed"``),
        ``"raised_cosine"``, ``"smoothstep"``; or any vectorized callable.
    p_c : float, optional
        Cutoff pressure (units of pressure) for the named smooth cutoffs.

    Raises
    ------
    ValueError
        Unknown name, missing or non-positive ``p_c``, or a non-callable object.
    """
    if cutoff is None:
        return SharpCutoff()
    if isinstance(cutoff, str):
        key = cutoff.lower()
        if key not in _CUTOFFS:
            raise ValueError(f"cutoff must be one of {sorted(_CUTOFFS)} or a callable; got cutoff={cutoff!r}")
        cls = _CUTOFFS[key]
        if cls is SharpCutoff:
            return SharpCutoff()
        if p_c is None:
            raise ValueError(f"cutoff={cutoff!r} needs a cutoff pressure p_c > 0; got p_c=None")
        return cls(p_c)
    if not callable(cutoff):
        raise ValueError(f"cutoff must be a name or a vectorized callable c(p); got {type(cutoff).__name__}")
    return cutoff  # type: ignore[return-value]


def make_tail(tail: object, p_t: float | None = None) -> PressureFunction:
    """Turn a tail specification into a callable ``t(p)``.

    Parameters
    ----------
    tail : str, callable or None
        ``None`` or ``"gaussian"`` (``t = 1``), ``"linear"`` (``1 + p/p_t``),
        ``"max_linear"`` (``max(1, p/p_t)``), or any vectorized callable.
    p_t : float, optional
        Crossover pressure (units of pressure) for the linear tails.
    """
    if tail is None or (isinstance(tail, str) and tail.lower() == "gaussian"):
        return GaussianTail()
    if isinstance(tail, str):
        key = tail.lower()
        cls = {"linear": LinearTail, "max_linear": MaxLinearTail}.get(key)
        if cls is None:
            raise ValueError(f"tail must be 'gaussian', 'linear', 'max_linear' or a callable; got tail={tail!r}")
        if p_t is None:
            raise ValueError(f"tail={tail!r} needs a crossover pressure p_t > 0; got p_t=None")
        return cls(p_t)
    if not callable(tail):
        raise ValueError(f"tail must be a name or a vectorized callable t(p); got {type(tail).__name__}")
    return tail  # type: ignore[return-value]


@dataclass(frozen=True)
class PressureFactor:
    """Product ``f(p) = c(p) * t(p)``: the pressure factor of ``D(p, eta)``.

    This is the ``diffusivity`` that :func:`diffusion_pr.propagate` takes.
    Dimensionless.
    """

    cutoff: PressureFunction
    tail: PressureFunction

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        p = np.asarray(p, dtype=float)
        return np.asarray(self.cutoff(p), dtype=float) * np.asarray(self.tail(p), dtype=float)


@dataclass(frozen=True)
class ProportionalDiffusivity:
    """Pure linear pressure factor ``f(p) = p / p_1`` (0 for ``p <= 0``).

    The diffusivity ``D ∝ p`` of the paper's exponential-tail argument taken
    literally down to ``p = 0``.  From ``delta(p - p0)`` the exact solution is
    Feller's (W. Feller, Ann. Math. 54, 173 (1951)): see
    :func:`diffusion_pr.closed_forms.feller_density` with ``slope = 1/p_1``.
    ``p = 0`` is an exit boundary: mass ``exp(-p0 p_1 / tau)`` is absorbed.

    Parameters
    ----------
    p_1 : float
        Pressure (units of pressure), > 0, at which ``f = 1``.
    """

    p_1: float
    continuity: int = 0  # continuous, kink at p = 0
    absorbing: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "p_1", check_positive("p_1", self.p_1))

    @property
    def slope(self) -> float:
        """``1 / p_1`` (1 / pressure)."""
        return 1.0 / self.p_1

    def __call__(self, p: ArrayLike) -> NDArray[np.float64]:
        return np.maximum(np.asarray(p, dtype=float), 0.0) / self.p_1
