"""Result object shared by every backend (scipy-style contract)."""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


class EdgeCdf:
    """The cumulative ``cum`` given at the cell ``edges``, as a function of pressure (pressure units).

    Exact at the edges; between them a cubic spline of ``cum`` against a coordinate (one per segment between the
    ``knots``, where the density may jump or kink), clipped to the cell's two edge values; 0 below the first edge,
    ``cum[-1]`` above the last.  ``coordinate``: an increasing map of pressure, or a sequence of them (None: ``p``
    itself); with several, each cell takes the spline that interpolates best there (:func:`_halving_miss`).  The
    finite-volume results use the grid's monitor function ``Phi`` (logarithmic towards a floor, where a
    non-contact peak's density goes like ``1/p``) and ``p`` (docs/backends.md)."""

    def __init__(self, edges: Array, cum: Array, knots: Any, coordinate: Any = None) -> None:
        from scipy.interpolate import CubicSpline

        self.edges = np.asarray(edges, dtype=float)
        self.cum = np.asarray(cum, dtype=float)
        self.coords = tuple(coordinate) if isinstance(coordinate, (tuple, list)) else (coordinate,)
        edges, cum = self.edges, self.cum
        inner = [float(k) for k in knots if edges[0] < k < edges[-1]]
        self.cuts = [0, *sorted(set(int(j) for j in np.searchsorted(edges, inner))), edges.size - 1]
        # per segment: the splines (one per coordinate; None where it has fewer than 2 cells: linear in p) and
        # which coordinate each of its cells takes
        self.segments: list = []
        for a, b in zip(self.cuts[:-1], self.cuts[1:]):
            if b - a < 2:
                self.segments.append((a, b, None, None))
                continue
            splines, misses = [], []
            for u in self.coords:
                u_edges = edges[a:b + 1] if u is None else np.asarray(u(edges[a:b + 1]), dtype=float)
                splines.append(CubicSpline(u_edges, cum[a:b + 1]))
                if len(self.coords) > 1:
                    misses.append(_halving_miss(u_edges, cum[a:b + 1]))
            choice = np.argmin(np.stack(misses), axis=0) if misses else np.zeros(b - a, dtype=int)
            self.segments.append((a, b, splines, choice))

    def __call__(self, p: Any) -> Array:
        edges, cum = self.edges, self.cum
        p = np.asarray(p, dtype=float)
        q = np.clip(p, edges[0], edges[-1])
        i = np.clip(np.searchsorted(edges, q, side="right") - 1, 0, edges.size - 2)
        spl = np.empty_like(q)
        for a, b, splines, choice in self.segments:
            if b - a < 1:
                continue
            sel = (q >= edges[a]) & (q <= edges[b])
            if splines is None:
                spl[sel] = np.interp(q[sel], edges[a:b + 1], cum[a:b + 1])
                continue
            q_sel = q[sel]
            taken = choice[np.clip(i[sel] - a, 0, b - a - 1)]
            value = np.empty_like(q_sel)
            for k, (u, spline) in enumerate(zip(self.coords, splines)):
                mine = taken == k
                if np.any(mine):
                    value[mine] = spline(q_sel[mine] if u is None else np.asarray(u(q_sel[mine]), dtype=float))
            spl[sel] = value
        inside = np.clip(spl, np.minimum(cum[i], cum[i + 1]), np.maximum(cum[i], cum[i + 1]))
        return np.where(p <= edges[0], 0.0, np.where(p >= edges[-1], cum[-1], inside))


def edge_cdf(edges: Array, cum: Array, knots: Any, p: Any, coordinate: Any = None) -> Array:
    """:class:`EdgeCdf` of ``edges``, ``cum``, ``knots`` and ``coordinate``, at the pressures ``p``."""
    return EdgeCdf(edges, cum, knots, coordinate)(p)


def _halving_miss(u: Array, values: Array) -> Array:
    """Per cell of the nodes ``u``, how badly a cubic spline of ``values`` in ``u`` interpolates there: the spline
    through every other node at the nodes it left out (about 16x the full spline's error on smooth data), the
    largest within two nodes of the cell.  Zeros on fewer than 6 cells (the first coordinate is taken)."""
    from scipy.interpolate import CubicSpline

    n = u.size - 1
    if n < 6:
        return np.zeros(n)
    keep = np.r_[np.arange(0, n, 2), n]
    left_out = np.arange(1, n, 2)
    miss = np.zeros(n + 3)  # edge e at miss[e + 1]; cell c has edges c, c+1: look at edges c-1 .. c+2
    miss[left_out + 1] = np.abs(CubicSpline(u[keep], values[keep])(u[left_out]) - values[left_out])
    return np.maximum(np.maximum(miss[:n], miss[1:n + 1]), np.maximum(miss[2:n + 2], miss[3:n + 3]))


@dataclass(frozen=True)
class PressureDistribution:
    """A pressure distribution ``Pr(p) = density(p) + zero_weight * delta(p)`` with its diagnostics.

    Attributes
    ----------
    p : ndarray
        Pressure grid (units of pressure): each cell's barycentre for finite-volume backends (so that
        ``sum(weights * p * density)`` is the solver's first moment), the quadrature nodes for closed forms.
    density : ndarray
        Continuous part of ``Pr`` on ``p`` (1 / pressure), non-negative.
    weights : ndarray
        Quadrature weights on ``p`` (units of pressure): ``sum(weights * g(p) * density)`` integrates ``g``
        against the continuous part (cell widths for finite volumes).
    zero_weight : float
        The non-contact weight, one definition for every backend: the probability absorbed at ``p = 0`` where the
        diffusivity reaches the wall (``f ~ p^k``, ``k < 2``), else the probability below the floor
        ``diagnostics["p_floor"]`` (``1e-6 p0`` by default).  ``1 - zero_weight`` is the relative contact area.
    mean_pressure, variance : float
        The problem's ``p0`` and ``V`` (the inputs).
    backend : str
        Which backend produced it (``"closed_form"``, ``"native"``, ``"pypde"``, ``"fipy"``).
    success : bool
        True only when the solver reached the requested tolerance.
    message : str
        Human-readable status.
    error_estimate : float
        Estimated L1 error of the density plus the error of ``zero_weight``; 0 for closed forms.
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

    @property
    def mass(self) -> float:
        """Total probability: continuous part plus ``zero_weight`` (should be 1)."""
        return float(np.sum(self.weights * self.density) + self.zero_weight)

    @property
    def mean(self) -> float:
        """Mean pressure ``integral p Pr(p) dp`` (the delta at 0 adds nothing)."""
        return float(np.sum(self.weights * self.p * self.density))

    @property
    def second_moment(self) -> float:
        """``integral p^2 Pr(p) dp`` (pressure squared); see :meth:`moment`."""
        return self.moment(2)

    def _cell_moment(self, order: int, shift: float) -> float:
        """``sum_i integral_cell (x - shift)^order rho_i(x) dx`` with ``rho_i`` the linear density
        of mass ``m_i`` and barycentre ``p_i`` on cell ``i`` (3-point Gauss-Legendre: exact to order 4)."""
        e = np.asarray(self.edges, dtype=float)
        h = np.diff(e)
        c = 0.5 * (e[:-1] + e[1:])
        m = self.weights * self.density
        slope = 12.0 * (self.p - c) / np.where(h > 0, h * h, 1.0)
        x, w = np.polynomial.legendre.leggauss(3)
        total = 0.0
        for xi, wi in zip(x, w):
            q = c + 0.5 * h * xi
            total += float(np.sum(0.5 * wi * m * (1.0 + slope * (q - c)) * (q - shift) ** order))
        return total

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
        t = self.contact_threshold if threshold is None else threshold
        if t is None:
            raise ValueError("this result has no default contact threshold (its wall is never reached and no wall "
                             "law was given): pass threshold= (pressure units; GFMD counts p > 0.01 p0)")
        if not (np.ndim(t) == 0 and np.isreal(t) and float(t) >= 0.0):
            raise ValueError(f"threshold must be a number >= 0 (pressure units); got threshold={threshold!r}")
        floor = float(self.diagnostics.get("p_floor", 0.0))
        if float(t) < floor:
            raise ValueError(f"threshold={float(t):.3g} lies below this result's floor p_floor={floor:.3g}: the "
                             "probability below the floor (zero_weight) depends on where the floor sits, it is not "
                             "a contact area; pass threshold >= p_floor (GFMD counts p > 0.01 p0)")
        return 1.0 - float(self.zero_weight) if float(t) == 0.0 else 1.0 - float(self.cdf(float(t)))

    @property
    def contact_fraction(self) -> float:
        """:meth:`contact_area` at its default threshold (an alias)."""
        return self.contact_area()

    def moment(self, order: int, central: bool = False) -> float:
        """Moment ``<p^k>`` (or ``<(p - mean)^k>`` if ``central``) of the full ``Pr``, including the ``delta(p)`` peak.

        Finite-volume results integrate in every cell the linear density with the cell's mass and barycentre (the
        within-cell spread is kept); closed forms use their quadrature."""
        shift = self.mean if central else 0.0
        if self.edges is not None:
            value = self._cell_moment(order, shift)
        else:
            value = float(np.sum(self.weights * (self.p - shift) ** order * self.density))
        return value + float(self.zero_weight) * (0.0 - shift) ** order

    def pdf(self, p: Any) -> Array:
        """Continuous part interpolated (linearly) at ``p``; 0 outside the grid."""
        return np.interp(np.asarray(p, dtype=float), self.p, self.density, left=0.0, right=0.0)

    def cdf(self, p: Any) -> Array:
        """Cumulative probability ``P(pressure <= p)`` including the delta at 0.

        Finite-volume results: exact at the cell edges, between them :class:`EdgeCdf` (a spline per segment between
        ``diagnostics["knots"]``, in the grid's monitor function or in ``p``, whichever interpolates better, clipped to
        the cell's probability; fourth-order accurate for a piecewise smooth density; docs/backends.md).  Results on
        Gauss-Legendre panels (``diagnostics["panels"]``) integrate each panel's interpolating polynomial: exact to
        about 1e-13.  Other point-wise results integrate a PCHIP interpolant (the density linear from 0 at
        ``p = 0`` on ``[0, p[0]]``), scaled to the quadrature's mass."""
        p = np.asarray(p, dtype=float)
        if self.edges is not None:
            out = np.where(p < self.edges[0], 0.0, self._edge_interpolant(p))
        elif (panels := self._panels()) is not None:
            out = self._panel_cdf(p, panels)
        else:
            out = self._pointwise_cdf(p)
        return np.where(p >= 0.0, out + self.zero_weight, 0.0)

    @cached_property
    def _edge_interpolant(self) -> EdgeCdf:
        """The continuous part's cumulative between the edges (:class:`EdgeCdf`), made once per result."""
        edges = self.edges
        cum = np.concatenate(([0.0], np.cumsum(self.weights * self.density)))
        ghosts = self.diagnostics.get("floor_ghosts")
        if ghosts is not None:  # the density runs on smoothly below the floor: so does the spline
            edges, cum = np.r_[ghosts[0], edges], np.r_[ghosts[1], cum]
        return EdgeCdf(edges, cum, self.diagnostics.get("knots", ()), self._edge_coordinate())

    def _edge_coordinate(self) -> Any:
        """The coordinates of the cdf's spline: the monitor function ``Phi`` of the grid family the edges come
        from and ``p`` (None: ``p`` only, where no family is recorded)."""
        grid = self.diagnostics.get("grid")
        spec = grid[0] if isinstance(grid, tuple) and grid else None
        phi = getattr(spec, "phi", None)
        return (phi, None) if callable(phi) else None

    def _panels(self) -> Optional[Array]:
        """The Gauss-Legendre panel edges of a point-wise result, if its nodes are theirs."""
        panels = self.diagnostics.get("panels") if self.edges is None else None
        if panels is None:
            return None
        panels = np.asarray(panels, dtype=float)
        n_panels = panels.size - 1
        return panels if n_panels >= 1 and self.p.size % n_panels == 0 and self.p.size >= 2 * n_panels else None

    def _panel_cdf(self, p: Array, panels: Array) -> Array:
        """Cumulative of the continuous part on Gauss-Legendre panels: each panel's Legendre interpolant through its
        ``m`` nodes, integrated from the panel's left edge; 0 below the first panel, the total mass above the last."""
        from numpy.polynomial import legendre as leg

        n_panels = panels.size - 1
        m = self.p.size // n_panels
        a, b = panels[:-1], panels[1:]
        half = 0.5 * (b - a)
        t_nodes = (self.p.reshape(n_panels, m) - 0.5 * (a + b)[:, None]) / half[:, None]
        dens = self.density.reshape(n_panels, m)
        coef = np.stack([leg.legfit(t_nodes[k], dens[k], m - 1) for k in range(n_panels)], axis=1)
        anti = leg.legint(coef, lbnd=-1.0) * half[None, :]  # (m + 1, n_panels): integral from the left edge
        before = np.concatenate(([0.0], np.cumsum(leg.legval(1.0, anti))))
        q = np.atleast_1d(np.clip(p, panels[0], panels[-1])).ravel()
        j = np.clip(np.searchsorted(panels, q, side="right") - 1, 0, n_panels - 1)
        t = (q - 0.5 * (a[j] + b[j])) / half[j]
        inside = before[j] + np.sum(leg.legvander(t, m) * anti[:, j].T, axis=1)
        inside = inside.reshape(np.shape(p))
        return np.where(p < panels[0], 0.0, np.where(p >= panels[-1], before[-1], inside))

    def _pointwise_cdf(self, p: Array) -> Array:
        from scipy.interpolate import PchipInterpolator

        nodes, dens = self.p, self.density
        if nodes.size < 2:
            return np.zeros_like(p)
        anti = PchipInterpolator(nodes, dens, extrapolate=False).antiderivative()
        head = 0.5 * dens[0] * nodes[0]  # mass on [0, p[0]] (linear ramp from 0)
        total = head + float(anti(nodes[-1]))
        inside = head + np.nan_to_num(anti(np.clip(p, nodes[0], nodes[-1])))
        ramp = 0.5 * dens[0] * np.clip(p, 0.0, nodes[0]) ** 2 / max(nodes[0], 1e-300)
        out = np.where(p < nodes[0], ramp, inside)
        # renormalize to the quadrature's own mass so cdf(inf) + zero_weight == mass
        quad_mass = float(np.sum(self.weights * self.density))
        return out * (quad_mass / total if total > 0 else 1.0)

    def plot(self, ax: Any = None, *, log: bool = True, **kwargs: Any) -> Any:
        """Plot the continuous density against ``p``; see :func:`diffusion_pr.plotting.plot_distribution`."""
        from .plotting import plot_distribution

        return plot_distribution(self, ax=ax, log=log, **kwargs)

    def __repr__(self) -> str:  # a short, useful summary instead of the arrays
        return (
            f"PressureDistribution(backend={self.backend!r}, success={self.success}, cells={self.p.size}, "
            f"mass={self.mass:.10g}, mean={self.mean:.6g} (p0={self.mean_pressure:.6g}), "
            f"zero_weight={self.zero_weight:.6g}, error_estimate={self.error_estimate:.2e}, "
            f"wall_time={self.wall_time:.3g} s, message={self.message!r})"
        )
