r"""Closed-form pressure distributions of the cumulant / diffusion theory.

All pressures share one unit (that of ``mean_pressure``); variances are in
pressure^2, densities in 1/pressure, ``tau`` in pressure^2 (it is the
integrated diffusivity ``\int D deta``) and ``slope`` in 1/pressure.

* Gaussian (soft wall, leading cumulant order; Müser, Phys. Rev. Lett. 100,
  055504 (2008), Eq. 2, doi:10.1103/PhysRevLett.100.055504):
  ``phi(p; p0, V)``.
* Persson's mirror Gaussian for a hard wall (B. N. J. Persson, J. Chem. Phys.
  115, 3840 (2001), doi:10.1063/1.1388626): the solution of
  ``dPr/dtau = d^2 Pr/dp^2`` absorbed at ``p = 0``,
  ``Pr(p) = phi(p; p0, V) - phi(p; -p0, V)`` on ``p > 0`` plus the weight
  ``1 - a_r = erfc(p0/sqrt(2V))`` in ``delta(p)``, ``V = 2 tau``.
* Feller's solution for a diffusivity linear in pressure,
  ``dPr/dtau = d^2 (f Pr)/dp^2`` with ``f(p) = a p`` (``a = 1/p1 = slope``),
  from ``delta(p - p0)`` (W. Feller, Ann. Math. 54, 173 (1951),
  doi:10.2307/1969318)::

      Pr(p, tau) = (1/(a tau)) sqrt(p0/p) exp(-(p + p0)/(a tau)) I1(2 sqrt(p p0)/(a tau)),

  with mass ``exp(-p0/(a tau))`` absorbed in ``delta(p)``. It is the law of the
  Ito process ``dp = sqrt(2 a p) dW`` killed at 0, so the full mean stays
  ``p0`` (martingale) and the variance is ``2 a p0 tau``.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy import special

from ._validation import check_finite_array, check_positive

__all__ = [
    "Moments",
    "gaussian_density",
    "gaussian_moments",
    "mirror_gaussian_density",
    "mirror_gaussian_moments",
    "persson_zero_weight",
    "persson_contact_fraction",
    "feller_density",
    "feller_zero_weight",
    "feller_moments",
]

_SQRT2PI = math.sqrt(2.0 * math.pi)


class Moments(NamedTuple):
    """Moments of a full distribution (continuous part plus the ``delta(p)`` peak).

    Attributes
    ----------
    mean : float
        ``<p>`` [pressure].
    variance : float
        ``<p^2> - <p>^2`` [pressure^2].
    zero_weight : float
        Probability in the ``delta(p)`` non-contact peak [dimensionless].
    """

    mean: float
    variance: float
    zero_weight: float


def _out(x: np.ndarray) -> np.ndarray | float:
    return float(x) if np.ndim(x) == 0 else x


def _phi(p: np.ndarray, m: float, var: float) -> np.ndarray:
    return np.exp(-((p - m) ** 2) / (2.0 * var)) / (_SQRT2PI * math.sqrt(var))


def gaussian_density(p: ArrayLike, mean_pressure: float, variance: float) -> np.ndarray | float:
    """Normal density ``phi(p; p0, V)`` [1/pressure] (Müser 2008, Eq. 2).

    Parameters
    ----------
    p : float or array_like
        Pressure(s), any sign, any shape.
    mean_pressure : float
        Mean ``p0`` [pressure] (finite; any sign allowed here).
    variance : float
        ``V`` [pressure^2], > 0.

    Returns
    -------
    float or numpy.ndarray
        Density, shape of ``p``.
    """
    pa = check_finite_array("p", p, min_size=0)
    m = float(check_finite_array("mean_pressure", mean_pressure))
    v = check_positive("variance", variance)
    return _out(_phi(pa, m, v))


def gaussian_moments(mean_pressure: float, variance: float) -> Moments:
    """Mean ``p0``, variance ``V`` and zero weight 0 of the Gaussian."""
    m = float(check_finite_array("mean_pressure", mean_pressure))
    v = check_positive("variance", variance)
    return Moments(m, v, 0.0)


def mirror_gaussian_density(p: ArrayLike, mean_pressure: float, variance: float) -> np.ndarray | float:
    """Persson's mirror Gaussian ``phi(p; p0, V) - phi(p; -p0, V)`` for ``p > 0``, 0 for ``p <= 0``.

    The continuous part only; the ``delta(p)`` weight is
    :func:`persson_zero_weight`. Computed as
    ``phi(p; p0, V) (1 - exp(-2 p p0 / V))`` (``-expm1``), accurate for small
    ``p p0 / V``.

    Parameters
    ----------
    p : float or array_like
        Pressure(s) [pressure], any shape.
    mean_pressure : float
        ``p0`` [pressure], > 0.
    variance : float
        ``V`` [pressure^2] of the unrestricted Gaussian, > 0.

    Returns
    -------
    float or numpy.ndarray
        Density [1/pressure], shape of ``p``.
    """
    pa = check_finite_array("p", p, min_size=0)
    p0 = check_positive("mean_pressure", mean_pressure)
    v = check_positive("variance", variance)
    pp = np.maximum(pa, 0.0)
    dens = _phi(pp, p0, v) * (-np.expm1(-2.0 * pp * p0 / v))
    return _out(np.where(pa > 0, dens, 0.0))


def persson_zero_weight(mean_pressure: float, variance: float) -> float:
    """Non-contact weight ``1 - a_r = erfc(p0 / sqrt(2 V))`` [dimensionless] (Persson 2001).

    Uses ``erfc`` so that small weights (``p0 >> sqrt(V)``) keep full
    relative accuracy.

    Parameters
    ----------
    mean_pressure : float
        ``p0`` [pressure], > 0.
    variance : float
        ``V`` [pressure^2], > 0.
    """
    p0 = check_positive("mean_pressure", mean_pressure)
    v = check_positive("variance", variance)
    return float(special.erfc(p0 / math.sqrt(2.0 * v)))


def persson_contact_fraction(mean_pressure: float, variance: float) -> float:
    """Relative contact area ``a_r = erf(p0 / sqrt(2 V))`` [dimensionless] (Persson 2001).

    Parameters
    ----------
    mean_pressure : float
        ``p0`` [pressure], > 0.
    variance : float
        ``V`` [pressure^2], > 0.
    """
    p0 = check_positive("mean_pressure", mean_pressure)
    v = check_positive("variance", variance)
    return float(special.erf(p0 / math.sqrt(2.0 * v)))


def mirror_gaussian_moments(mean_pressure: float, variance: float) -> Moments:
    r"""Moments of the mirror Gaussian including its ``delta(p)`` peak.

    With ``s = p0/sqrt(V)``: mean ``p0`` exactly (force balance);
    ``<p^2> = (p0^2 + V) erf(s/sqrt 2) + 2 p0 sqrt(V) phi(s)`` with
    ``phi`` the standard normal density, so the variance is
    ``<p^2> - p0^2``; zero weight ``erfc(s/sqrt 2)``.

    Parameters
    ----------
    mean_pressure : float
        ``p0`` [pressure], > 0.
    variance : float
        ``V`` [pressure^2], > 0.

    Returns
    -------
    Moments
        ``(mean [pressure], variance [pressure^2], zero_weight)``.
    """
    p0 = check_positive("mean_pressure", mean_pressure)
    v = check_positive("variance", variance)
    sd = math.sqrt(v)
    s = p0 / sd
    m2 = (p0 * p0 + v) * math.erf(s / math.sqrt(2.0)) + 2.0 * p0 * sd * math.exp(-0.5 * s * s) / _SQRT2PI
    return Moments(p0, m2 - p0 * p0, float(special.erfc(s / math.sqrt(2.0))))


def feller_density(p: ArrayLike, mean_pressure: float, tau: float, slope: float) -> np.ndarray | float:
    r"""Feller's density for ``dPr/dtau = d^2(a p Pr)/dp^2`` from ``delta(p - p0)``.

    ``Pr = (1/(a tau)) sqrt(p0/p) exp(-(p+p0)/(a tau)) I1(2 sqrt(p p0)/(a tau))``
    for ``p > 0``; at ``p = 0`` the finite limit ``p -> 0+``,
    ``p0 exp(-p0/(a tau)) / (a tau)^2``, and 0 for ``p < 0``. Evaluated overflow-free as
    ``(2 p0/(a tau)^2) exp(-(sqrt p - sqrt p0)^2/(a tau)) ive(1, x)/x`` with
    ``x = 2 sqrt(p p0)/(a tau)``. The ``delta(p)`` weight is
    :func:`feller_zero_weight`.

    Parameters
    ----------
    p : float or array_like
        Pressure(s) [pressure], any shape.
    mean_pressure : float
        ``p0`` [pressure], > 0.
    tau : float
        Integrated diffusivity ``\int D deta`` [pressure^2], > 0 (a Gaussian
        would have variance ``2 tau``).
    slope : float
        ``a = 1/p1`` in ``f(p) = a p`` [1/pressure], > 0.

    Returns
    -------
    float or numpy.ndarray
        Density [1/pressure], shape of ``p``.
    """
    pa = check_finite_array("p", p, min_size=0)
    p0 = check_positive("mean_pressure", mean_pressure)
    t = check_positive("tau", tau)
    a = check_positive("slope", slope)
    at = a * t
    pp = np.maximum(pa, 0.0)
    x = 2.0 * np.sqrt(pp * p0) / at
    xs = np.where(x > 0, x, 1.0)
    ratio = np.where(x > 0, special.ive(1, xs) / xs, 0.5)  # I1(x) e^-x / x -> 1/2 as x -> 0
    dens = (2.0 * p0 / (at * at)) * np.exp(-((np.sqrt(pp) - math.sqrt(p0)) ** 2) / at) * ratio
    return _out(np.where(pa >= 0, dens, 0.0))


def feller_zero_weight(mean_pressure: float, tau: float, slope: float) -> float:
    """Mass absorbed at ``p = 0`` by the Feller diffusion: ``exp(-p0/(a tau))`` [dimensionless].

    Parameters
    ----------
    mean_pressure : float
        ``p0`` [pressure], > 0.
    tau : float
        Integrated diffusivity [pressure^2], > 0.
    slope : float
        ``a`` [1/pressure], > 0.
    """
    p0 = check_positive("mean_pressure", mean_pressure)
    t = check_positive("tau", tau)
    a = check_positive("slope", slope)
    return math.exp(-p0 / (a * t))


def feller_moments(mean_pressure: float, tau: float, slope: float) -> Moments:
    """Moments of the Feller solution including its ``delta(p)`` peak.

    ``p`` is the martingale ``dp = sqrt(2 a p) dW`` stopped at 0, so
    ``<p> = p0`` and ``d<p^2>/dtau = <2 a p> = 2 a p0``: variance
    ``2 a p0 tau`` [pressure^2]; zero weight ``exp(-p0/(a tau))``.
    """
    p0 = check_positive("mean_pressure", mean_pressure)
    t = check_positive("tau", tau)
    a = check_positive("slope", slope)
    return Moments(p0, 2.0 * a * p0 * t, math.exp(-p0 / (a * t)))
