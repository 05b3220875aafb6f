r"""Closed-form pressure distributions of the cumulant / diffusion theory.

Units throughout: pressures ``p`` and ``mean_pressure`` (``p0``, > 0 unless said otherwise) in one unit; the
variance ``V`` of the unrestricted Gaussian and ``tau`` (the integrated diffusivity ``\int D deta``, ``V = 2 tau``)
in pressure^2, both > 0; ``slope`` ``a`` (of ``f(p) = a p``) in 1/pressure, > 0; densities in 1/pressure with the
shape of ``p`` (any shape; 0 for ``p < 0`` where the wall absorbs).  Every ``*_density`` is the continuous part; the
``delta(p)`` weight is the matching ``*_zero_weight``.

* Gaussian, the soft wall at leading order (Müser, Phys. Rev. Lett. 100, 055504 (2008),
  doi:10.1103/PhysRevLett.100.055504): :func:`gaussian_density`.
* Persson's mirror Gaussian for a hard wall (B. N. J. Persson, J. Chem. Phys. 115, 3840 (2001),
  doi:10.1063/1.1388626): :func:`mirror_gaussian_density`, :func:`persson_zero_weight`.
* Feller's solution for ``f(p) = a p`` (W. Feller, Ann. Math. 54, 173 (1951), doi:10.2307/1969318):
  :func:`feller_density`, :func:`feller_zero_weight`.
* The same with an affine drift, the Cox-Ingersoll-Ross process absorbed at 0 (Econometrica 53, 385 (1985),
  doi:10.2307/1911242; A. Goeing-Jaeschke and M. Yor, Bernoulli 9, 313 (2003), doi:10.3150/bj/1068128980):
  :func:`cir_density`, :func:`cir_zero_weight`.
* The mirror Gaussian with a constant drift (method of images with the Girsanov weight; A. N. Borodin and
  P. Salminen, *Handbook of Brownian Motion*, 2nd ed., 2002, doi:10.1007/978-3-0348-8163-0, part II, 2.1.15.6):
  :func:`drifted_mirror_gaussian_density`, :func:`drifted_mirror_gaussian_zero_weight`.
* Persson's diffusion re-timed at the hard wall: by the stress-variance sum rule (the ``"sum_rule"`` closure,
  :func:`sum_rule_variance`) or by a fitted factor of the contact area (``"yang_persson"``, ``"wang_muser"``,
  :func:`persson_corrected_variance`)."""
from __future__ import annotations

import math
import time
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy import special

from ._validation import check_finite, check_finite_array, check_int, check_nonnegative, check_positive

__all__ = ["Moments", "gaussian_density", "gaussian_moments", "mirror_gaussian_density", "mirror_gaussian_moments",
           "persson_zero_weight", "persson_contact_fraction", "feller_density", "feller_zero_weight",
           "feller_moments", "cir_density", "cir_zero_weight", "drifted_mirror_gaussian_density",
           "drifted_mirror_gaussian_zero_weight", "lognormal_gap_distribution", "persson_corrected_variance",
           "sum_rule_variance"]

_SQRT2PI = math.sqrt(2.0 * math.pi)


class Moments(NamedTuple):
    """Moments of a full distribution (continuous part plus the ``delta(p)`` peak): ``mean`` ``<p>`` [pressure],
    ``variance`` ``<p^2> - <p>^2`` [pressure^2], ``zero_weight`` the probability of the peak."""

    mean: float
    variance: float
    zero_weight: float


def _out(x: np.ndarray) -> np.ndarray | float:
    return float(x) if np.ndim(x) == 0 else x


def _positive(**values: float) -> tuple[float, ...]:
    """The keyword values as floats, each checked finite and > 0 (the error names it)."""
    return tuple(float(check_positive(name, v)) for name, v in values.items())


def _pressures(p: ArrayLike) -> np.ndarray:
    return check_finite_array("p", p, min_size=0)


def _phi(p: np.ndarray, m: float, var: float) -> np.ndarray:
    return np.exp(-((p - m) ** 2) / (2.0 * var)) / (_SQRT2PI * math.sqrt(var))


def _mirrored(p: np.ndarray, p0: float, var: float, centre: float) -> np.ndarray:
    """``phi(p; centre, V) (1 - exp(-2 p p0 / V))`` for ``p > 0``, 0 for ``p <= 0``: the image at ``-p0`` taken off
    (``-expm1``, accurate for small ``p p0 / V``); ``centre = p0`` is the mirror Gaussian, ``p0 + S`` the drifted one."""
    pp = np.maximum(p, 0.0)
    return np.where(p > 0, _phi(pp, centre, var) * (-np.expm1(-2.0 * pp * p0 / var)), 0.0)


def gaussian_density(p: ArrayLike, mean_pressure: float, variance: float) -> np.ndarray | float:
    """Normal density ``phi(p; p0, V)`` [1/pressure] (Müser 2008, Eq. 2); ``p`` and ``p0`` of any sign."""
    pa = _pressures(p)
    m = float(check_finite_array("mean_pressure", mean_pressure))
    return _out(_phi(pa, m, *_positive(variance=variance)))


def gaussian_moments(mean_pressure: float, variance: float) -> Moments:
    """Mean ``p0``, variance ``V`` and zero weight 0 of the Gaussian."""
    return Moments(float(check_finite_array("mean_pressure", mean_pressure)), *_positive(variance=variance), 0.0)


def mirror_gaussian_density(p: ArrayLike, mean_pressure: float, variance: float) -> np.ndarray | float:
    """Persson's mirror Gaussian ``phi(p; p0, V) - phi(p; -p0, V)`` for ``p > 0``, 0 for ``p <= 0``.

    The continuous part of the solution of ``dPr/dtau = d^2 Pr/dp^2`` absorbed at ``p = 0`` (``V = 2 tau``); the
    ``delta(p)`` weight is :func:`persson_zero_weight`.  Computed as ``phi(p; p0, V) (1 - exp(-2 p p0 / V))``
    (``-expm1``), accurate for small ``p p0 / V``."""
    pa = _pressures(p)
    p0, v = _positive(mean_pressure=mean_pressure, variance=variance)
    return _out(_mirrored(pa, p0, v, p0))


def persson_zero_weight(mean_pressure: float, variance: float) -> float:
    """Non-contact weight ``1 - a_r = erfc(p0 / sqrt(2 V))`` (Persson 2001); ``erfc`` keeps small weights
    (``p0 >> sqrt(V)``) to full relative accuracy."""
    p0, v = _positive(mean_pressure=mean_pressure, variance=variance)
    return float(special.erfc(p0 / math.sqrt(2.0 * v)))


def persson_contact_fraction(mean_pressure: float, variance: float) -> float:
    """Relative contact area ``a_r = erf(p0 / sqrt(2 V))`` (Persson 2001)."""
    p0, v = _positive(mean_pressure=mean_pressure, variance=variance)
    return float(special.erf(p0 / math.sqrt(2.0 * v)))


def persson_corrected_variance(mean_pressure: float, variance: float, gamma: float) -> float:
    r"""The variance ``V_eff`` of the mirror Gaussian when Persson's diffusion is slowed by the factor
    ``S = gamma + (1 - gamma) a_r^2`` of the current contact area (Yang & Persson, J. Phys.: Condens. Matter 20,
    215214 (2008), doi:10.1088/0953-8984/20/21/215214; ``gamma`` was fitted to simulations there).

    ``S`` does not depend on ``p``, so it only re-times the diffusion: ``d tau_eff / d tau = S(a_r(tau_eff))`` with
    ``a_r(t) = erf(p0 / (2 sqrt(t)))`` up to ``tau = V/2``; the result is the mirror Gaussian of variance
    ``V_eff = 2 tau_eff`` (between ``gamma V`` and ``V``; ``V`` for ``gamma = 1``).  Solved as
    ``int_0^{tau_eff} dt / S = V/2`` (quadrature in ``ln t``, root by Brent, relative error about 1e-12).
    Units: ``p0`` [pressure], ``V``, ``V_eff`` [pressure^2]; ``gamma`` in (0, 1]."""
    from scipy import integrate, optimize

    p0, v = _positive(mean_pressure=mean_pressure, variance=variance)
    g = float(check_positive("gamma", gamma))
    if g > 1.0:
        raise ValueError(f"gamma must be in (0, 1]; got gamma={gamma!r}")
    if g == 1.0:
        return v
    lo = 1e-12 * min(p0 * p0, v)  # below it S = 1 to within 1e-300

    def rate(x: float) -> float:  # d tau / d ln(tau_eff) at tau_eff = e^x
        return math.exp(x) / (g + (1.0 - g) * math.erf(p0 / (2.0 * math.exp(0.5 * x))) ** 2)

    def elapsed(t: float) -> float:  # tau at tau_eff = t, the quadrature split where a_r starts to fall
        mid = min(2.0 * math.log(p0), math.log(t))
        return lo + sum(integrate.quad(rate, a, b, epsabs=0.0, epsrel=1e-13, limit=200)[0]
                        for a, b in ((math.log(lo), mid), (mid, math.log(t))))

    return 2.0 * optimize.brentq(lambda t: elapsed(t) - 0.5 * v, 0.5 * g * v, 0.5 * v, rtol=1e-13)


def sum_rule_variance(mean_pressure: float, variance: float) -> float:
    r"""The variance ``T`` of the ``"sum_rule"`` closure's mirror Gaussian: the one whose pressure variance is
    ``a_r V`` (docs/closures.md).

    Linear elasticity gives ``Var(p) = (E*/2)^2 <|grad u|^2>`` exactly; at a hard wall ``grad u = grad h`` on the
    contact, so with the free surface's slopes neglected and the slopes in contact those of the whole surface,
    ``Var(p) = a_r V`` at every magnification (``V`` the Persson variance resolved so far).  Persson's diffusion
    on the clock ``T`` has ``Var = int_0^T a_r(t) dt``, ``a_r(t) = erf(p0/sqrt(2t))``, so ``T`` solves
    (``c = p0/sqrt 2``)

        V = T + [2 c sqrt(T/pi) exp(-c^2/T) - 2 c^2 erfc(c/sqrt T)] / erf(c/sqrt T),

    between ``V/2`` (small loads: ``a_r = 4/sqrt(pi) p0/(E* gbar)``) and ``V`` (full contact); Brent's root,
    relative error about 1e-14.  Units: ``p0`` [pressure], ``V``, ``T`` [pressure^2]."""
    from scipy import optimize

    p0, v = _positive(mean_pressure=mean_pressure, variance=variance)
    c = p0 / math.sqrt(2.0)

    def excess(t: float) -> float:
        z = c / math.sqrt(t)
        return t - v + 2.0 * c * (math.sqrt(t / math.pi) * math.exp(-z * z) - c * math.erfc(z)) / math.erf(z)

    return float(optimize.brentq(excess, 0.25 * v, v, xtol=1e-300, rtol=1e-14))


def mirror_gaussian_moments(mean_pressure: float, variance: float) -> Moments:
    r"""Moments of the mirror Gaussian including its ``delta(p)`` peak. With ``s = p0/sqrt(V)``: mean ``p0`` exactly
    (force balance); ``<p^2> = (p0^2 + V) erf(s/sqrt 2) + 2 p0 sqrt(V) phi(s)`` with ``phi`` the standard normal
    density; zero weight ``erfc(s/sqrt 2)``."""
    p0, v = _positive(mean_pressure=mean_pressure, variance=variance)
    sd = math.sqrt(v)
    s = p0 / sd
    m2 = (p0 * p0 + v) * math.erf(s / math.sqrt(2.0)) + 2.0 * p0 * sd * math.exp(-0.5 * s * s) / _SQRT2PI
    return Moments(p0, m2 - p0 * p0, float(special.erfc(s / math.sqrt(2.0))))


def feller_density(p: ArrayLike, mean_pressure: float, tau: float, slope: float) -> np.ndarray | float:
    r"""Feller's density for ``dPr/dtau = d^2(a p Pr)/dp^2`` from ``delta(p - p0)``.

    ``Pr = (1/(a tau)) sqrt(p0/p) exp(-(p+p0)/(a tau)) I1(2 sqrt(p p0)/(a tau))`` for ``p > 0``; at ``p = 0`` the
    finite limit ``p -> 0+``, ``p0 exp(-p0/(a tau)) / (a tau)^2``, and 0 for ``p < 0``.  Evaluated overflow-free as
    ``(2 p0/(a tau)^2) exp(-(sqrt p - sqrt p0)^2/(a tau)) ive(1, x)/x`` with ``x = 2 sqrt(p p0)/(a tau)``."""
    pa = _pressures(p)
    p0, t, a = _positive(mean_pressure=mean_pressure, tau=tau, slope=slope)
    at = a * t
    pp = np.maximum(pa, 0.0)
    x = 2.0 * np.sqrt(pp * p0) / at
    xs = np.where(x > 0, x, 1.0)
    ratio = np.where(x > 0, special.ive(1, xs) / xs, 0.5)  # I1(x) e^-x / x -> 1/2 as x -> 0
    dens = (2.0 * p0 / (at * at)) * np.exp(-((np.sqrt(pp) - math.sqrt(p0)) ** 2) / at) * ratio
    return _out(np.where(pa >= 0, dens, 0.0))


def feller_zero_weight(mean_pressure: float, tau: float, slope: float) -> float:
    """Mass absorbed at ``p = 0`` by the Feller diffusion: ``exp(-p0/(a tau))``."""
    p0, t, a = _positive(mean_pressure=mean_pressure, tau=tau, slope=slope)
    return math.exp(-p0 / (a * t))


def feller_moments(mean_pressure: float, tau: float, slope: float) -> Moments:
    """Moments of the Feller solution including its ``delta(p)`` peak. ``p`` is the martingale ``dp = sqrt(2 a p) dW``
    stopped at 0: ``<p> = p0``, variance ``2 a p0 tau`` [pressure^2], zero weight ``exp(-p0/(a tau))``."""
    p0, t, a = _positive(mean_pressure=mean_pressure, tau=tau, slope=slope)
    return Moments(p0, 2.0 * a * p0 * t, math.exp(-p0 / (a * t)))


def _cir_clock(tau: float, slope: float, drift_at_wall: float, restoring_rate: float) -> tuple:
    """``(delta, s, scale)``: the squared Bessel process's dimension, its clock ``s`` [in units of ``Z``] and the
    factor ``exp(beta tau)`` by which ``Z`` is stretched (``Y_s = exp(beta tau) Z_tau``)."""
    beta_tau = restoring_rate * tau
    return 2.0 * drift_at_wall / slope, tau * float(special.exprel(beta_tau)), math.exp(beta_tau)


def _cir_args(mean_pressure, tau, slope, drift_at_wall, restoring_rate) -> tuple:
    p0, t, a = _positive(mean_pressure=mean_pressure, tau=tau, slope=slope)
    alpha = float(check_finite("drift_at_wall", drift_at_wall))
    beta = float(check_finite("restoring_rate", restoring_rate))
    if abs(beta * t) > 700.0:
        raise ValueError(f"restoring_rate * tau must lie in [-700, 700] (exp overflows beyond); got "
                         f"restoring_rate={beta!r}, tau={t!r}")
    return p0, t, a, alpha, beta


def cir_density(p: ArrayLike, mean_pressure: float, tau: float, slope: float, drift_at_wall: float = 0.0,
                restoring_rate: float = 0.0) -> np.ndarray | float:
    r"""Density of ``dPr/dtau = -d/dp[(alpha - beta p) Pr] + d^2(a p Pr)/dp^2`` from ``delta(p - p0)``, absorbed at 0.

    The Ito process ``dp = (alpha - beta p) dtau + sqrt(2 a p) dW`` killed at ``p = 0``.  With ``Z = 2 p/a``,
    ``z0 = 2 p0/a``, ``delta = 2 alpha/a``, ``nu = delta/2 - 1``, ``s = (exp(beta tau) - 1)/beta`` and
    ``y = exp(beta tau) Z``:

        Pr(p) = (2/a) exp(beta tau) (1/2s) (y/z0)^(nu/2) exp(-(y + z0)/2s) I_|nu|(sqrt(y z0)/s),

    the squared Bessel process's transition density on the clock ``s``; ``I_|nu|`` (not ``I_nu``) is the process killed
    at 0 where ``delta < 2``, and the same function where ``delta >= 2`` (0 is never reached: then ``2 k p`` is
    noncentral chi-square with ``delta`` degrees of freedom and noncentrality ``2 k p0 exp(-beta tau)``,
    ``k = beta/(a (1 - exp(-beta tau)))``; Cox, Ingersoll and Ross 1985, doi:10.2307/1911242).  ``alpha = beta = 0`` is
    :func:`feller_density`.  Evaluated overflow-free with ``ive`` and in logarithms; at ``p = 0`` the limit ``p -> 0+``.

    ``drift_at_wall`` ``alpha`` [pressure per unit ``tau``] is the drift at ``p = 0``, any sign (``alpha >= a``
    makes ``p = 0`` an entrance boundary, never reached); ``restoring_rate`` ``beta`` [1/pressure^2], any sign,
    ``|beta tau| <= 700``."""
    pa = _pressures(p)
    p0, t, a, alpha, beta = _cir_args(mean_pressure, tau, slope, drift_at_wall, restoring_rate)
    delta, s, scale = _cir_clock(t, a, alpha, beta)
    nu = delta / 2.0 - 1.0
    z0 = 2.0 * p0 / a
    y = 2.0 * np.maximum(pa, 0.0) / a * scale
    pos = y > 0.0
    ys = np.where(pos, y, 1.0)
    x = np.sqrt(ys * z0) / s
    with np.errstate(divide="ignore", under="ignore"):
        log_bessel = np.log(special.ive(abs(nu), x))  # I e^-x: exp(-(y + z0)/2s) I = exp(-(sqrt y - sqrt z0)^2/2s) ive
        log_dens = (math.log(2.0 / a * scale / (2.0 * s)) + 0.5 * nu * np.log(ys / z0)
                    - (np.sqrt(ys) - math.sqrt(z0)) ** 2 / (2.0 * s) + log_bessel)
    dens = np.where(pos, np.exp(log_dens), 0.0)
    # p -> 0+: (y/z0)^(nu/2) I_|nu|(x) -> (z0/2s)^|nu| / Gamma(1 + |nu|) y^((nu + |nu|)/2): finite where nu <= 0
    at_zero = 0.0 if nu > 0.0 else (2.0 / a * scale / (2.0 * s) * math.exp(-z0 / (2.0 * s))
                                    * math.exp(abs(nu) * math.log(z0 / (2.0 * s)) - math.lgamma(1.0 + abs(nu))))
    dens = np.where((pa >= 0) & ~pos, at_zero, dens)
    return _out(np.where(pa >= 0, dens, 0.0))


def cir_zero_weight(mean_pressure: float, tau: float, slope: float, drift_at_wall: float = 0.0,
                    restoring_rate: float = 0.0) -> float:
    """Mass absorbed at ``p = 0`` by the process of :func:`cir_density`. ``Q(1 - delta/2, z0/2s)`` for
    ``delta = 2 alpha/a < 2`` (the time a squared Bessel process of dimension ``delta < 2`` takes from ``z0`` to 0 is
    ``z0/(2 G)``, ``G ~ Gamma(1 - delta/2)``; Goeing-Jaeschke and Yor 2003, doi:10.3150/bj/1068128980), 0 for
    ``delta >= 2`` (entrance boundary).  ``alpha = beta = 0``: ``exp(-p0/(a tau))``, :func:`feller_zero_weight`."""
    p0, t, a, alpha, beta = _cir_args(mean_pressure, tau, slope, drift_at_wall, restoring_rate)
    delta, s, _ = _cir_clock(t, a, alpha, beta)
    if delta >= 2.0:
        return 0.0
    return float(special.gammaincc(1.0 - delta / 2.0, 2.0 * p0 / a / (2.0 * s)))


def drifted_mirror_gaussian_density(p: ArrayLike, mean_pressure: float, variance: float,
                                    drift_shift: float) -> np.ndarray | float:
    """The mirror Gaussian carried by a constant drift: ``phi(p; p0 + S, V) (1 - exp(-2 p p0 / V))`` for ``p > 0``.

    The continuous part of the solution of ``dPr/dtau = d^2 Pr/dp^2 - a dPr/dp`` from ``delta(p - p0)``, absorbed
    at ``p = 0``, with ``V = 2 tau`` and ``drift_shift`` ``S = a tau`` [pressure] the displacement the drift alone
    makes (any sign, finite).  ``S = 0`` is :func:`mirror_gaussian_density`."""
    pa = _pressures(p)
    p0, v = _positive(mean_pressure=mean_pressure, variance=variance)
    return _out(_mirrored(pa, p0, v, p0 + check_finite("drift_shift", drift_shift)))


def drifted_mirror_gaussian_zero_weight(mean_pressure: float, variance: float, drift_shift: float) -> float:
    """Non-contact weight of :func:`drifted_mirror_gaussian_density`.

    ``Phi(-(p0 + S)/sqrt V) + exp(-2 S p0 / V) Phi((S - p0)/sqrt V)``, the probability that Brownian motion with
    drift has hit 0 (the second term in logarithms: ``log_ndtr``, no overflow for a strong drift towards the wall).
    ``S = 0`` is :func:`persson_zero_weight`."""
    p0, v = _positive(mean_pressure=mean_pressure, variance=variance)
    shift = check_finite("drift_shift", drift_shift)
    sd = math.sqrt(v)
    first = float(special.log_ndtr(-(p0 + shift) / sd))
    second = -2.0 * shift * p0 / v + float(special.log_ndtr((shift - p0) / sd))
    hi = max(first, second)
    return float(min(1.0, math.exp(hi) * (math.exp(first - hi) + math.exp(second - hi))))


def lognormal_gap_distribution(spectrum: Any, *, E_star: float, mean_pressure: float, zeta: float,
                               n_cells: int = 4000, rtol: float = 1e-6) -> Any:
    """The ``"lognormal_gap"`` closure: a log-normal pressure, closed form.

    The gap fluctuation ``delta g~(q) = -(1 - G1(q)) h~(q)`` of the second-order response (Müser 2008, Eq. 10) is
    Gaussian with variance ``zeta^2 V / p0^2`` (since ``1 - G1 = (zeta q E*/(2 p0)) G1``); the wall law
    ``p = p_w exp(-g/zeta)`` makes ``ln p`` Gaussian with variance ``s^2 = V/p0^2``
    (``V``: :func:`~diffusion_pr.cumulants.stress_variance`), and force balance fixes the mean to ``p0``:
    ``<ln p> = ln p0 - s^2/2``.

    ``pdf`` and ``cdf`` are the exact log-normal's (``analytic``); ``p``, ``density`` and ``weights`` are
    ``n_cells`` cells uniform in ``ln p`` over ``[<ln p> - 9.5 s, <ln p> + s^2 + 9.5 s]`` (plus
    ``[0, p_lo]``) with the exact cell masses and, as each cell's point, the exact conditional mean of ``p`` in
    the cell: mass and mean are exact to round-off (the mass dropped beyond ``9.5 s`` is below 1e-20).

    Parameters
    ----------
    spectrum : Spectrum
        Height spectrum (lengths in the unit of ``zeta``).
    E_star, mean_pressure : float
        ``E*`` and ``p0`` [pressure], > 0.
    zeta : float
        Wall range [length], > 0 (``zeta = 0``, the hard wall, raises: it has no exponential wall law).
    n_cells : int
        Cells in ``ln p`` (>= 100).
    rtol : float
        Accepted for the closures' common signature (kept in the diagnostics); the result is exact to round-off.

    Returns
    -------
    PressureDistribution
        As the ``"closed_form"`` backend's results (``success`` True, ``error_estimate`` the cells' mass defect,
        the same diagnostics keys), plus ``diagnostics["closure"] = "lognormal_gap"`` and
        ``diagnostics["ln_variance"] = s^2``.
    """
    from scipy import stats

    from .cumulants import stress_variance
    from .paper import contact_threshold
    from .result import PressureDistribution

    z = float(check_nonnegative("zeta", zeta))
    if z == 0.0:
        raise ValueError("closure='lognormal_gap' needs an exponential wall (zeta > 0); got zeta=0 (hard wall), "
                         "where no wall law maps gaps to pressures. Use 'second_order' (Persson) or 'local_g1_balanced'.")
    E = float(check_positive("E_star", E_star))
    p0 = float(check_positive("mean_pressure", mean_pressure))
    check_int("n_cells", n_cells, minimum=100)
    t0 = time.perf_counter()
    V = float(stress_variance(spectrum, E_star=E, mean_pressure=p0, zeta=z))
    s2 = V / (p0 * p0)
    s = math.sqrt(s2)
    mu = math.log(p0) - 0.5 * s2
    # the mass lies within mu +- 9.5 s; the mean's integrand p Pr(p) is the same Gaussian in ln p
    # shifted by s^2, so the grid reaches mu + s^2 + 9.5 s
    top = mu + s2 + 9.5 * s
    if top - math.log(p0) > 690.0:
        raise ValueError(f"closure='lognormal_gap' is not defined here: its ln-variance s^2 = V/p0^2 = {s2:.4g} "
                         f"(zeta={z!r}, p0={p0!r}) puts the mean-carrying pressures exp({s2:.3g}/2) times above p0, "
                         "beyond floating point; the log-normal picture of the gap does not apply at such small "
                         "zeta / load (use 'local_g1_balanced')")
    x = np.linspace(mu - 9.5 * s, top, int(n_cells))
    edges = np.concatenate(([0.0], np.exp(x)))
    u = (x - mu) / s
    # cell masses from the CDF below the median and from the survival function above it
    # (differences of numbers near 1 would lose the far tail that carries the mean when s is large)
    lo_c, hi_c = special.ndtr(u[:-1]), special.ndtr(u[1:])
    lo_s, hi_s = special.ndtr(-u[:-1]), special.ndtr(-u[1:])
    upper = 0.5 * (u[:-1] + u[1:]) > 0
    mass = np.concatenate(([special.ndtr(u[0])], np.where(upper, lo_s - hi_s, hi_c - lo_c)))
    # partial expectations E[p; p < e] = exp(mu + s^2/2) Phi((ln e - mu - s^2)/s)
    pe = np.concatenate(([0.0], np.exp(mu + 0.5 * s2 + special.log_ndtr(u - s))))
    pm = np.diff(pe)
    widths = np.diff(edges)
    ok = mass > 0
    points = np.where(ok, pm / np.where(ok, mass, 1.0), 0.5 * (edges[1:] + edges[:-1]))
    points = np.clip(points, edges[:-1], edges[1:])
    density = mass / widths
    total = float(mass.sum())
    mean = float(points @ mass)
    wall = time.perf_counter() - t0
    diag = {"backend": "closed_form", "rtol": float(rtol), "n_cells": int(points.size), "levels": None,
            "zero_power": 0.0, "wall": "not reached: p = p_w exp(-gap/zeta) > 0", "p_floor": 0.0,
            "p_min": float(edges[0]), "p_max": float(edges[-1]), "mass_error": total - 1.0, "mean_error": mean - p0,
            "negative_mass": 0.0, "min_density": float(density.min()), "tail_mass": float(mass[-1]),
            "time_integration": "exact", "n_stages": 1, "substeps": 0,
            "timings": {"setup": 0.0, "solve": wall, "total": wall},
            "closure": "lognormal_gap", "stress_variance": V, "ln_variance": s2, "ln_mean": mu, "zeta": z,
            "E_star": E}
    return PressureDistribution(p=points, density=density, weights=widths, zero_weight=0.0, mean_pressure=p0,
                                variance=V, backend="closed_form", success=True,
                                message=f"exact: log-normal gap closure on {points.size} cells uniform in ln p",
                                error_estimate=abs(total - 1.0), wall_time=wall, diagnostics=diag, edges=edges,
                                contact_threshold=contact_threshold(z, p0),
                                analytic=stats.lognorm(s, scale=math.exp(mu)))
