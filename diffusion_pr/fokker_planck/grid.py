"""Graded, nested finite-volume grids on ``[p_wall, p_max]``.

The cell density is the derivative of a smooth monotone monitor function ::

    Phi(p) = p / s  +  c_wall ln(p - p_wall + delta)  +  c_0 asinh((p - p0) / w0)

(``s``: the width of the final distribution; the logarithm grades the cells geometrically towards the wall
down to ``delta``; the ``asinh`` towards the start ``p0``).  A :class:`Remap` ``F`` may replace ``Phi`` by
``F(Phi)``, moving cells to where the first level's errors were.  Knots (the wall, the coefficients'
breakpoints, ``p0``, ``p_max``) are cell edges; between knots the edges are ``Phi^-1`` of equally spaced
values, so the grid with ``2 n`` cells nests in the one with ``n`` and the spacing is smooth inside every
segment: the conditions for Richardson extrapolation on nested grids.  Pressures in the units of ``p0``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import functools
import math
from typing import Optional

import numpy as np

__all__ = ["GridSpec", "Remap", "edges_for", "same_grid", "SAME_GRID_RTOL"]


@dataclass(frozen=True)
class Remap:
    """A smooth increasing map ``F`` of the monitor's values ``v = Phi(p) - Phi(p_wall)`` (dimensionless).

    ``F(v) = integral_0^v D``, ``D > 0`` the natural cubic spline through ``values`` at ``knots`` (``knots[0] = 0``),
    constant beyond the last knot: ``F`` is a C3 piecewise quartic, so nested grids and Richardson stay valid.

    Raises
    ------
    ValueError
        Where the spline is not positive (its minimum below a fifth of the smallest value).
    """

    knots: tuple
    values: tuple
    _x: np.ndarray = field(init=False, repr=False, compare=False, hash=False)
    _y: np.ndarray = field(init=False, repr=False, compare=False, hash=False)
    _m: np.ndarray = field(init=False, repr=False, compare=False, hash=False)
    _cum: np.ndarray = field(init=False, repr=False, compare=False, hash=False)
    _pieces: np.ndarray = field(init=False, repr=False, compare=False, hash=False)
    _start: tuple = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        x = np.asarray(self.knots, dtype=float)
        y = np.asarray(self.values, dtype=float)
        if x.size < 2 or x[0] != 0.0 or np.any(np.diff(x) <= 0.0) or np.any(y <= 0.0):
            raise ValueError("Remap needs increasing knots from 0 and positive values")
        m = _NaturalSpline(x, y).m
        for name, value in (("_x", x), ("_y", y), ("_m", m)):
            object.__setattr__(self, name, value)
        h = np.diff(x)
        inc = 0.5 * h * (y[:-1] + y[1:]) - h**3 * (m[:-1] + m[1:]) / 24.0  # integral of the spline per interval
        cum = np.concatenate(([0.0], np.cumsum(inc)))
        object.__setattr__(self, "_cum", cum)
        # each piece's coefficients once (the operations :meth:`_both` would apply per point: the same bits)
        c_l, c_r = y[:-1] / h - m[:-1] * h / 6, y[1:] / h - m[1:] * h / 6
        object.__setattr__(self, "_pieces", np.array([x[:-1], x[1:], h, m[:-1], m[1:], 6 * h, c_l, c_r, cum[:-1],
                                                      h**4, 24 * h, 0.5 * c_l, h * h, 0.5 * c_r]))
        probe = np.linspace(0.0, x[-1], 64 * (x.size - 1) + 1)
        f_probe, d_probe = self._both(probe)
        if np.min(d_probe) < 0.2 * np.min(y):
            raise ValueError("Remap: the density's spline is not safely positive")
        object.__setattr__(self, "_start", (f_probe, probe))

    @property
    def total(self) -> float:
        """``F`` at the last knot."""
        return float(self._cum[-1])

    def _both(self, v: np.ndarray, forward: bool = True, density: bool = True) -> tuple:
        """``(F(v), D(v))`` (None for the one not asked), one search and one gather of the piece table:
        ``D = (m_i a^3 + m_{i+1} b^3)/(6 h) + (y_i/h - m_i h/6) a + (y_{i+1}/h - m_{i+1} h/6) b`` and its integral,
        ``a = x_{i+1} - w``, ``b = w - x_i``, ``w = min(v, x_-1)``; beyond the last knot ``D = y_-1``."""
        v = np.asarray(v, dtype=float)
        x = self._x
        i = np.clip(np.searchsorted(x, v, side="right") - 1, 0, x.size - 2)
        xl, xr, h, ml, mr, h6, c_l, c_r, cum, h4, h24, c_l2, hh, c_r2 = self._pieces[:, i]
        w = np.minimum(v, x[-1])
        b = w - xl
        f_out = d_out = None
        if forward:
            a = h - b
            f_out = cum + (ml * (h4 - a**4) + mr * b**4) / h24 + c_l2 * (hh - a * a) + c_r2 * b * b
            f_out += self._y[-1] * np.maximum(v - x[-1], 0.0)
        if density:
            a = xr - w
            d_out = np.where(v > x[-1], self._y[-1], (ml * a**3 + mr * b**3) / h6 + c_l * a + c_r * b)
        return f_out, d_out

    def density(self, v: np.ndarray) -> np.ndarray:
        """``D(v) = F'(v)``."""
        return self._both(v, forward=False)[1]

    def forward(self, v: np.ndarray) -> np.ndarray:
        """``F(v)``."""
        return self._both(v, density=False)[0]

    def inverse(self, t: np.ndarray) -> np.ndarray:
        """``F^-1(t)`` on ``[0, total]`` by safeguarded Newton to round-off; each value depends on its own ``t`` only
        (nested grids agree bit for bit)."""
        t = np.asarray(t, dtype=float)
        f_tab, v_tab = self._start
        k = np.clip(np.searchsorted(f_tab, t, side="right") - 1, 0, f_tab.size - 2)
        x0, lo, hi, tol = np.interp(t, f_tab, v_tab), v_tab[k], v_tab[k + 1], 1e-15 * max(self.total, 1.0)
        return _safeguarded_newton(self._both, t, x0, lo, hi, tol, 40)


@dataclass(frozen=True)
class GridSpec:
    """Everything that fixes a family of nested grids (pressures in units of ``p0``).

    Attributes
    ----------
    p_wall : float
        Lower end: 0 where the wall is reached, the floor ``p_floor`` otherwise (pressure).
    p_max : float
        Upper end (pressure); the mass beyond it is below the tail tolerance.
    knots : tuple of float
        Interior edges every grid keeps: breakpoints and ``p0`` (pressure).
    scale : float
        ``s``, the spread of the final distribution (pressure).
    c_wall : float
        Weight of the logarithmic grading towards the wall (0 for none).
    c_0, w0 : float
        Weight and width (pressure) of the grading towards ``p0``.
    p0 : float
        The start (pressure), one of the knots.
    wall_depth : float
        ``delta``, the inner scale of the logarithmic grading (pressure above ``p_wall``).  0 (default):
        ``p_wall`` where ``p_wall > 0``, else ``1e-12 p_max``.
    """

    p_wall: float
    p_max: float
    knots: tuple
    scale: float
    c_wall: float
    c_0: float
    w0: float
    p0: float
    wall_depth: float = 0.0
    remap: Optional[Remap] = None

    @property
    def all_knots(self) -> np.ndarray:
        """Wall, interior knots and ``p_max``, increasing (pressure)."""
        return np.array([self.p_wall, *self.knots, self.p_max], dtype=float)

    def phi(self, p: np.ndarray) -> np.ndarray:
        """The monitor function ``Phi`` (dimensionless; ``F(Phi - Phi(p_wall))`` with a :class:`Remap`)."""
        if self.remap is not None:
            return self.remap.forward(self._base_value(p))
        p = np.asarray(p, dtype=float)
        out = (p - self.p_wall) / self.scale
        if self.c_wall > 0.0:
            out = out + np.log((p - self.p_wall + self._delta) / self._delta) * self.c_wall
        if self.c_0 > 0.0:
            out = out + np.arcsinh((p - self.p0) / self.w0) * self.c_0
        return out

    def dphi(self, p: np.ndarray) -> np.ndarray:
        """``dPhi/dp`` (1/pressure)."""
        if self.remap is not None:
            return self.remap.density(self._base_value(p)) * self.base.dphi(p)
        p = np.asarray(p, dtype=float)
        out = np.full(p.shape, 1.0 / self.scale)
        if self.c_wall > 0.0:
            out += self.c_wall / (p - self.p_wall + self._delta)
        if self.c_0 > 0.0:
            out += self.c_0 / np.sqrt((p - self.p0) ** 2 + self.w0**2)
        return out

    @functools.cached_property
    def base(self) -> "GridSpec":
        """The family without its :class:`Remap` (itself where it has none; made once per family)."""
        return self if self.remap is None else replace(self, remap=None)

    @functools.cached_property
    def _base_wall(self) -> np.ndarray:
        """``Phi(p_wall)`` of the base family (a 0-d array, computed once)."""
        return self.base.phi(self.p_wall)

    def _base_value(self, p: np.ndarray) -> np.ndarray:
        """``v = Phi(p) - Phi(p_wall)`` of the base family: the argument of the :class:`Remap`."""
        return self.base.phi(p) - self._base_wall

    @property
    def _delta(self) -> float:
        # the logarithmic grading reaches down to p_wall itself when p_wall > 0 (the floor)
        if self.wall_depth > 0.0:
            return self.wall_depth
        return self.p_wall if self.p_wall > 0.0 else 1e-12 * self.p_max

    def segment_weights(self) -> np.ndarray:
        """``Phi`` increments of the segments between knots (dimensionless)."""
        return np.diff(self.phi(self.all_knots))


#: two edge arrays within this relative difference of each other are the same grid (:func:`same_grid`)
SAME_GRID_RTOL = 1e-12


def same_grid(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two edge arrays are the same grid: the same size, every edge within :data:`SAME_GRID_RTOL` of the
    other's (masses on the two then combine cell by cell)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= SAME_GRID_RTOL * np.abs(b)))


def _invert(spec: GridSpec, targets: np.ndarray, a: float, b: float) -> np.ndarray:
    """``Phi^-1(targets)`` on ``[a, b]``: Newton from a tabulated start, to round-off; :func:`_invert_safe` where a
    step leaves ``[a, b]`` or 8 steps do not converge.  With a :class:`Remap` ``F``: ``F^-1`` first."""
    if spec.remap is not None:
        return _invert(spec.base, spec.remap.inverse(targets) + float(spec._base_wall), a, b)
    table, phi_table = _table(spec, a, b)
    x0 = np.interp(targets, phi_table, table)
    tol = 1e-14 * np.maximum(np.abs(targets), 1.0)
    x = x0
    for _ in range(8):
        r = spec.phi(x) - targets
        done = np.abs(r) <= tol
        if done.all():
            return x
        # converged points stay: each edge's value depends on its own target only (nested grids agree bit for bit)
        step = x - r / spec.dphi(x)
        x = np.where(done, x, step) if done.any() else step
        if not (a <= x.min() and x.max() <= b):
            break
    return _invert_safe(spec, targets, x0, a, b, tol)


def _table(spec: GridSpec, a: float, b: float) -> tuple:
    """Points of ``[a, b]`` (geometric towards ``a``, uniform) and ``Phi`` there: the start of :func:`_invert`."""
    key = (spec, a, b)
    hit = _TABLES.get(key)
    if hit is None:
        lo_t = a - spec.p_wall + spec._delta
        table = np.unique(np.concatenate((spec.p_wall + np.geomspace(lo_t, b - spec.p_wall + spec._delta, 400)
                                               - spec._delta, np.linspace(a, b, 400))))
        table = table[(table >= a) & (table <= b)]
        hit = (table, spec.phi(table))
        if len(_TABLES) >= 64:
            _TABLES.pop(next(iter(_TABLES)))
        _TABLES[key] = hit
    return hit


#: start tables of :func:`_invert` per grid family (the levels of one solve share them)
_TABLES: dict = {}


def _invert_safe(spec: GridSpec, targets: np.ndarray, x: np.ndarray, a: float, b: float,
                 tol: np.ndarray) -> np.ndarray:
    """Safeguarded Newton on ``Phi``: bisection on the bracket ``[a, b]`` where a Newton step would leave it."""
    return _safeguarded_newton(lambda p: (spec.phi(p), spec.dphi(p)), targets, x, np.full_like(targets, a),
                               np.full_like(targets, b), tol, 60)


def _safeguarded_newton(f_df, targets: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray, tol,
                        iterations: int) -> np.ndarray:
    """``f^-1(targets)`` for an increasing ``f`` from ``x`` in the brackets ``[lo, hi]`` (``f_df(x) = (f(x), f'(x))``):
    Newton steps, bisection where a step would leave the bracket; converged points stay, so each value depends on
    its own target only."""
    for _ in range(iterations):
        f, df = f_df(x)
        r = f - targets
        done = np.abs(r) <= tol
        if np.all(done):
            break
        lo = np.where(r < 0, x, lo)
        hi = np.where(r > 0, x, hi)
        step = x - r / df
        bad = (step <= lo) | (step >= hi)
        x = np.where(done, x, np.where(bad, 0.5 * (lo + hi), step))
    return x


class _NaturalSpline:
    """Natural cubic spline through a few points (numpy only: no scipy.interpolate import on the solve path)."""

    def __init__(self, x: np.ndarray, y: np.ndarray) -> None:
        n = x.size
        h = x[1:] - x[:-1]
        a = np.zeros((n, n))
        b = np.zeros(n)
        a[0, 0] = a[-1, -1] = 1.0
        for i in range(1, n - 1):
            a[i, i - 1], a[i, i], a[i, i + 1] = h[i - 1], 2.0 * (h[i - 1] + h[i]), h[i]
            b[i] = 6.0 * ((y[i + 1] - y[i]) / h[i] - (y[i] - y[i - 1]) / h[i - 1])
        self.x, self.y, self.h, self.m = x, y, h, np.linalg.solve(a, b)  # m: second derivatives

    def min_slope(self) -> float:
        """The smallest first derivative on ``[x_0, x_-1]``, exact: ``r'`` is quadratic on each piece, so its minimum
        is at an end or where ``r''`` changes sign from - to +."""
        lowest = math.inf
        for h, yl, yr, ml, mr in zip(self.h.tolist(), self.y[:-1].tolist(), self.y[1:].tolist(),
                                     self.m[:-1].tolist(), self.m[1:].tolist()):
            mid = (yr - yl) / h - (mr - ml) * h / 6.0  # r' without its quadratic terms
            lowest = min(lowest, mid - ml * h / 2.0, mid + mr * h / 2.0)  # r' at the left and right ends
            if ml < 0.0 < mr:  # r'' = 0 at b = t - x_i = -m_i h / (m_{i+1} - m_i)
                b = -ml * h / (mr - ml)
                a = h - b
                lowest = min(lowest, mid + (mr * b * b - ml * a * a) / (2.0 * h))
        return lowest

    def on_pieces(self, t: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """The spline at ``t``, whose first ``counts[0]`` points lie on the first piece, the next ``counts[1]`` on the
        second, ... (no search)."""
        x, y, h, m = self.x, self.y, self.h, self.m
        pieces = np.array([x[1:], x[:-1], 6 * h, m[:-1], m[1:], y[:-1] / h - m[:-1] * h / 6.0,
                           y[1:] / h - m[1:] * h / 6.0])
        xr, xl, hi6, ml, mr, cl, cr = np.repeat(pieces, counts, axis=1)
        a, b = xr - t, t - xl
        return ml * a**3 / hi6 + mr * b**3 / hi6 + cl * a + cr * b


def knot_indices(spec: GridSpec, n_cells: int) -> np.ndarray:
    """Edge index of every knot (wall, interior knots, ``p_max``) on the grid of about ``n_cells`` cells.

    ``round(n Phi(knot)/Phi_total)``, at least :data:`MIN_GAP` cells apart.
    """
    k = spec.all_knots
    ph = spec.phi(k)
    frac = (ph - ph[0]) / (ph[-1] - ph[0])
    idx = np.round(n_cells * frac).astype(int)
    idx[0] = 0
    for j in range(1, idx.size):
        idx[j] = max(idx[j], idx[j - 1] + MIN_GAP)
    return idx


#: fewest cells between two knots
MIN_GAP = 3


def edges_for(spec: GridSpec, idx: np.ndarray, factor: int = 1,
              known: Optional[np.ndarray] = None) -> np.ndarray:
    """Edges of the grid whose knots sit at edge indices ``factor * idx`` (pressure).

    The edge with index ``i`` is ``Phi^-1(T(i / (factor n)))`` with ``n = idx[-1]`` and
    ``T(x) = Phi_0 + Phi_total x + r(x)``, ``r`` the natural cubic spline through the knots' rounding residuals:
    ``T`` is C2, so every grid is a smooth map of a uniform one, ``factor = 2`` nests exactly in ``factor = 1``
    and every knot is an edge.  ``known``: the edges of the grid this one doubles (every second edge, bit for
    bit); only the new edges are inverted.

    Raises
    ------
    ValueError
        When the knots are too crowded for a monotone map (increase the cells).
    """
    k = spec.all_knots
    ph = spec.phi(k)
    n = int(idx[-1])
    xk = idx / n
    tot = ph[-1] - ph[0]
    resid = ph - (ph[0] + tot * xk)
    x = np.arange(n * factor + 1) / (n * factor)
    # the new edges only (odd indices; the knots, at factor * idx, are even): their targets alone
    new_only = known is not None and factor % 2 == 0 and known.size == n * factor // 2 + 1
    if new_only:
        x = x[1::2]
    targets = ph[0] + tot * x
    if k.size > 2:
        r = _NaturalSpline(xk, resid)
        # T' = tot + r' must stay well positive: r' is quadratic on each segment between knots (its minimum exact)
        if tot + r.min_slope() > 0.2 * tot:
            counts = factor * (idx[1:] - idx[:-1])
            if new_only:
                counts //= 2  # each piece's odd points
            else:
                counts[-1] += 1  # the last edge (x = 1) on the last piece
            targets = targets + r.on_pieces(x, counts)
        else:  # knots crowded: equal Phi steps per segment (nested, piecewise smooth)
            targets = np.concatenate([ph[j] + (ph[j + 1] - ph[j]) * np.arange(factor * (idx[j + 1] - idx[j])) /
                                      (factor * (idx[j + 1] - idx[j])) for j in range(k.size - 1)] + [ph[-1:]])
            if new_only:
                targets = targets[1::2]
    if new_only:
        edges = np.empty(n * factor + 1)
        edges[::2] = known
        edges[1::2] = _invert(spec, targets, k[0], k[-1])
    else:
        edges = _invert(spec, targets, k[0], k[-1])
    edges[factor * idx] = k  # knots exactly
    return edges
