"""Graded, nested finite-volume grids on ``[p_wall, p_max]``.

The cell density is the derivative of a smooth monotone monitor function ::

    Phi(p) = p / s  +  c_wall ln(p - p_wall + delta)  +  c_0 asinh((p - p0) / w0)

(``s``: the width of the final distribution; the logarithm grades the cells
geometrically towards the wall where the wall is not reached, ``f ~ p^k`` with
``k >= 2``, so that the density creeping towards 0 is resolved down to the
floor; the ``asinh`` grades towards the start ``p0`` where the local spread is
small).  Knots -- the wall, every breakpoint of the coefficients, ``p0`` and
``p_max`` -- are cell edges; between knots the edges are ``Phi^-1`` of equally
spaced values, so the grid with ``2 n`` cells per segment nests in the one with
``n`` (each cell split in two) and the grid spacing is smooth inside every
segment: the conditions under which Richardson extrapolation on nested grids
is valid.  Pressures in the units of ``p0``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GridSpec", "edges_for"]


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
        ``delta``, the inner scale of the logarithmic grading (pressure above ``p_wall``): the cells grow
        geometrically from ``p_wall + delta`` up and are about uniform below it.  0 (default): ``p_wall`` itself
        where ``p_wall > 0`` (the grading reaches the floor), else ``1e-12 p_max``.
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

    @property
    def all_knots(self) -> np.ndarray:
        """Wall, interior knots and ``p_max``, increasing (pressure)."""
        return np.array([self.p_wall, *self.knots, self.p_max], dtype=float)

    def phi(self, p: np.ndarray) -> np.ndarray:
        """The monitor function ``Phi`` (dimensionless)."""
        p = np.asarray(p, dtype=float)
        out = (p - self.p_wall) / self.scale
        if self.c_wall > 0.0:
            out = out + self.c_wall * np.log((p - self.p_wall + self._delta) / self._delta)
        if self.c_0 > 0.0:
            out = out + self.c_0 * np.arcsinh((p - self.p0) / self.w0)
        return out

    def dphi(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=float)
        out = np.full_like(p, 1.0 / self.scale)
        if self.c_wall > 0.0:
            out = out + self.c_wall / (p - self.p_wall + self._delta)
        if self.c_0 > 0.0:
            out = out + self.c_0 / np.sqrt((p - self.p0) ** 2 + self.w0**2)
        return out

    @property
    def _delta(self) -> float:
        # the logarithmic grading reaches down to p_wall itself when p_wall > 0 (the floor)
        if self.wall_depth > 0.0:
            return self.wall_depth
        return self.p_wall if self.p_wall > 0.0 else 1e-12 * self.p_max

    def segment_weights(self) -> np.ndarray:
        """``Phi`` increments of the segments between knots (dimensionless)."""
        return np.diff(self.phi(self.all_knots))


def _invert(spec: GridSpec, targets: np.ndarray, a: float, b: float) -> np.ndarray:
    """``Phi^-1(targets)`` on ``[a, b]``: a tabulated start, then Newton (to round-off).

    Newton steps from the table's start (``Phi`` is smooth and increasing:
    from the table's interpolation error, 1e-4 relative or less, it converges in
    two to four steps); if a step leaves ``[a, b]`` or 8 steps do not converge,
    the safeguarded bisection-Newton of :func:`_invert_safe` takes over from the start.
    """
    table, phi_table = _table(spec, a, b)
    x0 = np.interp(targets, phi_table, table)
    tol = 1e-14 * np.maximum(np.abs(targets), 1.0)
    x = x0
    for _ in range(8):
        r = spec.phi(x) - targets
        done = np.abs(r) <= tol
        if np.all(done):
            return x
        # converged points stay: each edge's value depends on its own target only (nested grids agree bit for bit)
        x = np.where(done, x, x - r / spec.dphi(x))
        if not (np.all(x >= a) and np.all(x <= b)):
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
    """Safeguarded Newton: bisection on the bracket ``[lo, hi]`` where a Newton step would leave it."""
    lo = np.full_like(targets, a)
    hi = np.full_like(targets, b)
    for _ in range(60):
        r = spec.phi(x) - targets
        done = np.abs(r) <= tol
        if np.all(done):
            break
        lo = np.where(r < 0, x, lo)
        hi = np.where(r > 0, x, hi)
        step = x - r / spec.dphi(x)
        bad = (step <= lo) | (step >= hi)
        x = np.where(done, x, np.where(bad, 0.5 * (lo + hi), step))  # converged points stay
    return x


class _NaturalSpline:
    """Natural cubic spline through a few points (numpy only: no scipy.interpolate import on the solve path)."""

    def __init__(self, x: np.ndarray, y: np.ndarray) -> None:
        n = x.size
        h = np.diff(x)
        a = np.zeros((n, n))
        b = np.zeros(n)
        a[0, 0] = a[-1, -1] = 1.0
        for i in range(1, n - 1):
            a[i, i - 1], a[i, i], a[i, i + 1] = h[i - 1], 2.0 * (h[i - 1] + h[i]), h[i]
            b[i] = 6.0 * ((y[i + 1] - y[i]) / h[i] - (y[i] - y[i - 1]) / h[i - 1])
        self.x, self.y, self.h, self.m = x, y, h, np.linalg.solve(a, b)  # m: second derivatives

    def __call__(self, t: np.ndarray, nu: int = 0) -> np.ndarray:
        x, y, h, m = self.x, self.y, self.h, self.m
        i = np.clip(np.searchsorted(x, t, side="right") - 1, 0, x.size - 2)
        a, b = x[i + 1] - t, t - x[i]
        hi = h[i]
        if nu == 1:
            return (-m[i] * a * a / (2 * hi) + m[i + 1] * b * b / (2 * hi)
                    + (y[i + 1] - y[i]) / hi - (m[i + 1] - m[i]) * hi / 6.0)
        return (m[i] * a**3 / (6 * hi) + m[i + 1] * b**3 / (6 * hi)
                + (y[i] / hi - m[i] * hi / 6.0) * a + (y[i + 1] / hi - m[i + 1] * hi / 6.0) * b)


def knot_indices(spec: GridSpec, n_cells: int) -> np.ndarray:
    """Edge index of every knot (wall, interior knots, ``p_max``) on the grid of about ``n_cells`` cells.

    ``round(n Phi(knot)/Phi_total)``, pushed apart to at least :data:`MIN_GAP`
    cells between neighbouring knots.
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


def edges_for(spec: GridSpec, idx: np.ndarray, factor: int = 1) -> np.ndarray:
    """Edges of the grid whose knots sit at edge indices ``factor * idx`` (pressure).

    The edge with index ``i`` is ``Phi^-1(T(i / (factor n)))`` with ``n = idx[-1]`` and
    ``T(x) = Phi_0 + Phi_total x + r(x)``, ``r`` the natural cubic spline through
    the knots' rounding residuals: ``T`` is smooth (C2) across the knots, so every
    grid of the family is a smooth map of a uniform one (the condition for
    Richardson extrapolation and for py-pde's uniform-grid operators), the grid
    with ``factor = 2`` nests exactly in the one with ``factor = 1``, and every
    knot is an edge.

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
    targets = ph[0] + tot * x
    if k.size > 2:
        r = _NaturalSpline(xk, resid)
        # T' = tot + r' must stay positive: r' is quadratic on each segment between knots, so 33 samples per
        # segment find its minimum far inside the 0.2 tot margin
        probe = np.concatenate([np.linspace(a, b, 33) for a, b in zip(xk[:-1], xk[1:])])
        if np.all(tot + r(probe, 1) > 0.2 * tot):
            targets = targets + r(x)
        else:  # knots crowded: equal Phi steps per segment (nested, piecewise smooth)
            targets = np.concatenate([ph[j] + (ph[j + 1] - ph[j]) * np.arange(factor * (idx[j + 1] - idx[j])) /
                                      (factor * (idx[j + 1] - idx[j])) for j in range(k.size - 1)] + [ph[-1:]])
    edges = _invert(spec, targets, k[0], k[-1])
    edges[factor * idx] = k  # knots exactly
    return edges
