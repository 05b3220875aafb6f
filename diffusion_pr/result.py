"""Result object shared by every backend (scipy-style contract)."""
from __future__ import annotations

import math

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


#: degree of the cumulative's spline (:func:`cumulative_interpolant`): its derivative, the density, errs O(h^5);
#: the cubic's O(h^3) missed 10 rtol on the mirror Gaussian (2.3e-6 on its 152 cells at rtol 1e-6; quintic 1.9e-8)
DEGREE = 5


def cumulative_interpolant(u: Array, cum: Array, breaks: Any = ()) -> Any:
    """One :class:`scipy.interpolate.PPoly` in ``u`` through ``(u, cum)``, a piece per interval, monotone where ``cum``
    is. Between the indices ``breaks`` of ``u`` (where the density may jump or kink) the interpolating spline of degree
    :data:`DEGREE` (3, then 1, on segments of fewer than 6, 4 points); in every interval where its derivative dips below
    0, the segment's PCHIP cubic (monotone, exact at the points as well)."""
    from math import factorial

    from scipy.interpolate import PchipInterpolator, PPoly, make_interp_spline

    u, cum = np.asarray(u, dtype=float), np.asarray(cum, dtype=float)
    n = u.size - 1
    coef = np.zeros((DEGREE + 1, n))
    cuts = [0, *sorted({int(b) for b in breaks if 0 < int(b) < n}), n]
    for a, b in zip(cuts[:-1], cuts[1:]):
        x, y = u[a:b + 1], cum[a:b + 1]
        k = 5 if b - a >= 5 else 3 if b - a >= 3 else 1
        # nodes a round-off apart (micro-cells under a breakpoint, floor ghosts) make the collocation matrix singular
        # or ill-conditioned: the spline runs through the others (the segment's ends kept)
        kept, tiny = [0], 1e-9 * (x[-1] - x[0])
        kept += [i for i in range(1, x.size - 1) if x[i] - x[kept[-1]] > tiny and x[-1] - x[i] > tiny]
        kept.append(x.size - 1)
        spline = make_interp_spline(x[kept], y[kept], k=min(k, len(kept) - 1))
        for m in range(spline.k + 1):  # each interval's Taylor coefficients at its left end
            coef[DEGREE - m, a:b] = spline(x[:-1], nu=m) / factorial(m)
        slope = PPoly(coef[:, a:b], x).derivative()
        crit = slope.derivative().roots(discontinuity=False, extrapolate=False)
        at = np.concatenate((x[:-1], np.nextafter(x[1:], -np.inf), crit[np.isfinite(crit)]))
        dips = np.unique(np.clip(np.searchsorted(x, at[slope(at) < 0.0], side="right") - 1, 0, b - a - 1))
        if dips.size and b - a >= 2:
            coef[:, a + dips] = 0.0
            with np.errstate(divide="ignore", over="ignore"):  # (PCHIP's harmonic mean of zero slopes)
                coef[DEGREE - 3:, a + dips] = PchipInterpolator(x, y).c[:, dips]
    return PPoly(coef, u)


@dataclass(frozen=True)
class PressureDistribution:
    """A pressure distribution ``Pr(p) = pdf(p) + zero_weight * delta(p)`` with its diagnostics.

    Finite-volume results are their ``edges``, cell masses ``density * weights``, first moments
    ``p * density * weights`` and ``zero_weight``; :meth:`cdf` is one monotone piecewise polynomial of the cumulative
    masses, exact at the edges (:func:`cumulative_interpolant`, in the grid's monitor coordinate ``Phi`` where the
    result records its grid, else in ``p``), :meth:`pdf` its derivative, :meth:`moment` the masses and first moments.
    Cells under a breakpoint found within :data:`~diffusion_pr.fokker_planck.engine.UNRESOLVED` of the bottom (a
    jump at ``p = 0``, found at 1e-21) have given their mass to the first cell above it.  Closed forms carry the
    exact solution (``analytic``) that :meth:`pdf` and :meth:`cdf` evaluate.

    Attributes
    ----------
    p : ndarray
        Pressure (units of pressure): each cell's barycentre (finite volumes: ``sum(weights * p * density)`` is the
        solver's first moment), the quadrature nodes of closed forms.
    density : ndarray
        Finite volumes: each cell's average density, its mass over its width (1 / pressure); closed forms: the exact
        density at ``p``.  The density at any pressure is :meth:`pdf`.
    weights : ndarray
        Cell widths, or the closed form's quadrature weights (units of pressure): ``sum(weights * g(p) * density)``
        integrates ``g`` against the continuous part.
    zero_weight : float
        The non-contact weight: the probability absorbed at ``p = 0`` where the diffusivity reaches the wall
        (``f ~ p^k``, ``k < 2``), else the probability below the floor ``diagnostics["p_floor"]`` (``1e-6 p0`` by
        default; then not a contact area, see :meth:`contact_area`).
    mean_pressure, variance : float
        The problem's ``p0`` and ``V`` (the inputs).
    backend : str
        Which backend produced it (``"closed_form"``, ``"native"``, ``"pypde"``, ``"fipy"``).
    success : bool
        True only when the solver reached the requested tolerance.
    message : str
        Human-readable status.
    error_estimate : float
        Estimated L1 error of :meth:`pdf` plus the error of ``zero_weight`` (closed forms: their quadrature's mass
        defect).
    wall_time : float
        Seconds spent in the solve (excluding imports and compilation).
    diagnostics : dict
        The same keys from every backend (``backend, rtol, n_cells, levels, zero_power, wall, p_floor, p_max,
        mass_error, mean_error, negative_mass, min_density, tail_mass, time_integration, n_stages, substeps,
        timings``) plus backend-specific extras.  Never mutated after the result is returned.
    edges : ndarray, optional
        Cell edges (length ``len(p) + 1``) for finite-volume results.
    contact_threshold : float, optional
        The default threshold of :meth:`contact_area` (pressure), set by whoever built the result so that it
        means what GFMD means: 0 where the wall is reached (the hard wall), ``0.01 p0`` for an exponential wall
        (``zeta > 0``, ``gfmd_ref``'s threshold); None where neither applies (a floor, no wall law given).
    analytic : object, optional
        Closed forms: the exact continuous part, with ``pdf(p)`` and ``cdf(p)`` (from 0, without ``zero_weight``).
    """

    p: Array
    density: Array
    weights: Array
    zero_weight: float
    mean_pressure: float
    variance: float
    backend: str
    success: bool = True
    message: str = ""
    error_estimate: float = 0.0
    wall_time: float = 0.0
    diagnostics: dict = field(default_factory=dict)
    edges: Optional[Array] = None
    contact_threshold: Optional[float] = None
    analytic: Any = None

    @property
    def mass(self) -> float:
        """Total probability: continuous part plus ``zero_weight`` (should be 1)."""
        return float(np.sum(self.weights * self.density) + self.zero_weight)

    @property
    def mean(self) -> float:
        """Mean pressure ``integral p Pr(p) dp`` (the delta at 0 adds nothing)."""
        return float(np.sum(self.p * (self.weights * self.density)))  # masses first: no overflow in the far tail

    @property
    def second_moment(self) -> float:
        """``integral p^2 Pr(p) dp`` (pressure squared); see :meth:`moment`."""
        return self.moment(2)

    def moment(self, order: int, central: bool = False) -> float:
        """Moment ``<p^k>`` (or ``<(p - mean)^k>`` if ``central``) of the full ``Pr``, including the ``delta(p)`` peak.

        Finite volumes: in every cell the linear density with the cell's mass and barycentre (3-point
        Gauss-Legendre, exact); closed forms: their quadrature of the exact density; the log-normal closure: its
        exact ``<p^j> = exp(j ln(scale) + j^2 s^2/2)`` (its cells do not reach the heavy tail of ``p^k Pr``),
        ``inf`` where that is beyond floating point."""
        if getattr(getattr(self.analytic, "dist", None), "name", "") == "lognorm":
            (s,), log_scale = self.analytic.args, math.log(self.analytic.kwds["scale"])
            logs = [j * log_scale + 0.5 * j * j * s * s for j in range(order + 1)]
            if logs[-1] > 709.0:  # beyond floating point (the central moment too: the top raw one dominates)
                return math.inf
            raw = [math.exp(x) for x in logs]
            mu = raw[1] if central else 0.0
            return float(sum(math.comb(order, j) * raw[j] * (-mu) ** (order - j) for j in range(order + 1)))
        shift = self.mean if central else 0.0
        if self.edges is None:
            value = float(np.sum(self.weights * (self.p - shift) ** order * self.density))
        else:
            e = np.asarray(self.edges, dtype=float)
            h, c, m = np.diff(e), 0.5 * (e[:-1] + e[1:]), self.weights * self.density
            slope = 12.0 * (self.p - c) / np.where(h > 0, h * h, 1.0)
            x, w = np.polynomial.legendre.leggauss(3)
            value = sum(float(np.sum(0.5 * wi * m * (1.0 + slope * 0.5 * h * xi) * (c + 0.5 * h * xi - shift) ** order))
                        for xi, wi in zip(x, w))
        return value + float(self.zero_weight) * (0.0 - shift) ** order

    def contact_area(self, threshold: Optional[float] = None) -> float:
        """Relative contact area: the probability that ``p > threshold`` (pressure; default
        :attr:`contact_threshold`: ``1 - zero_weight`` on a hard wall, ``P(p > 0.01 p0)`` on an exponential wall).

        Raises
        ------
        ValueError
            If ``threshold`` is not a number >= 0; if it is None and the result has no default; or if it lies
            below the floor ``diagnostics["p_floor"]`` of a result whose wall is never reached (there
            ``zero_weight`` is the probability below a numerical floor, not a non-contact area).
        """
        t, floor = self.contact_threshold if threshold is None else threshold, self.diagnostics.get("p_floor", 0.0)
        if t is None:
            raise ValueError("this result has no default contact threshold (its wall is never reached and no wall "
                             "law was given): pass threshold= (pressure units; GFMD counts p > 0.01 p0)")
        if not (np.ndim(t) == 0 and np.isreal(t) and float(t) >= 0.0):
            raise ValueError(f"threshold must be a number >= 0 (pressure units); got threshold={threshold!r}")
        if float(t) < floor:
            raise ValueError(f"threshold={float(t):.3g} lies below this result's floor p_floor={floor:.3g}, under "
                             "which zero_weight is a numerical choice, not a contact area: pass threshold >= p_floor")
        return 1.0 - float(self.zero_weight) if float(t) == 0.0 else 1.0 - float(self.cdf(float(t)))

    @property
    def contact_fraction(self) -> float:
        """:meth:`contact_area` at its default threshold (an alias)."""
        return self.contact_area()

    def pdf(self, p: Any) -> Array:
        """The continuous part's density at ``p`` (1 / pressure): the derivative of :meth:`cdf` (finite volumes;
        0 outside the edges), the exact density (closed forms)."""
        p = np.asarray(p, dtype=float)
        if self.analytic is not None:
            return np.where(p > 0.0, self.analytic.pdf(np.maximum(p, 0.0)), 0.0)
        poly, phi, dphi = self._interpolant
        slope = poly.derivative()
        q = np.clip(p, self.edges[0], self.edges[-1])
        inside = (p >= self.edges[0]) & (p <= self.edges[-1])
        return np.where(inside, slope(phi(q)) * dphi(q), np.where(np.isnan(p), np.nan, 0.0))

    def cdf(self, p: Any) -> Array:
        """Cumulative probability ``P(pressure <= p)`` including the delta at 0. Finite volumes: the cumulative masses
        at the edges exactly, between them :func:`cumulative_interpolant` (fifth-order accurate for a piecewise smooth
        density; docs/backends.md, "What the result exposes"); 0 below the edges (a floor's mass is
        ``zero_weight``).  Closed forms: exact."""
        p = np.asarray(p, dtype=float)
        if self.analytic is not None:
            out = self.analytic.cdf(np.maximum(p, 0.0))
        else:
            poly, phi, _ = self._interpolant
            q = np.clip(p, self.edges[0], self.edges[-1])
            out = np.where(p < self.edges[0], 0.0, poly(phi(q)))
        return np.where(p >= 0.0, out + self.zero_weight, np.where(np.isnan(p), np.nan, 0.0))

    @cached_property
    def _interpolant(self) -> tuple:
        """``(F, Phi, dPhi/dp)``: the cumulative interpolant ``F(Phi(p))`` (:func:`cumulative_interpolant`) in the
        grid's monitor coordinate (``p`` itself where no grid is recorded), made once per result."""
        if self.edges is None:
            raise ValueError("a point-wise result needs its exact solution (analytic=) or cell edges for pdf and cdf")
        spec = (self.diagnostics.get("grid") or (None,))[0]
        phi, dphi = (spec.phi, spec.dphi) if callable(getattr(spec, "dphi", None)) else (np.asarray, np.ones_like)
        edges = np.asarray(self.edges, dtype=float)
        cum = np.concatenate(([0.0], np.cumsum(self.weights * self.density)))
        ghosts = self.diagnostics.get("floor_ghosts")  # cells below the floor: the spline runs on through it
        g = 0 if ghosts is None else len(ghosts[0])
        if g:
            edges, cum = np.r_[ghosts[0], edges], np.r_[ghosts[1], cum]
        knots = [k for k in self.diagnostics.get("knots", ()) if edges[0] < k < edges[-1]]
        breaks = [int(np.argmin(np.abs(edges - k))) for k in knots]  # (the knots are edges)
        u = np.asarray(phi(edges), dtype=float)
        poly = cumulative_interpolant(u, cum, breaks)
        if g:
            from scipy.interpolate import PPoly

            poly = PPoly(poly.c[:, g:], poly.x[g:])
        return poly, phi, dphi

    def plot(self, ax: Any = None, *, log: bool = True, **kwargs: Any) -> Any:
        """Plot the continuous density against ``p``; see :func:`diffusion_pr.plotting.plot_distribution`."""
        from .plotting import plot_distribution

        return plot_distribution(self, ax=ax, log=log, **kwargs)

    def __repr__(self) -> str:  # a short, useful summary instead of the arrays
        return (f"PressureDistribution(backend={self.backend!r}, success={self.success}, cells={self.p.size}, "
                f"mass={self.mass:.10g}, mean={self.mean:.6g} (p0={self.mean_pressure:.6g}), "
                f"zero_weight={self.zero_weight:.6g}, error_estimate={self.error_estimate:.2e}, "
                f"wall_time={self.wall_time:.3g} s, message={self.message!r})")
