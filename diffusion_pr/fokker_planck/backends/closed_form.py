"""Closed-form backend: the exact solutions, on a Gauss-Legendre grid.

Two factorized problems have exact solutions (Müser 2008, Eq. 2 and docs/theory.md):

* ``f = c`` constant (with the sharp cutoff, i.e. absorbing ``p = 0``):
  Persson's mirror Gaussian of variance ``c V`` plus the non-contact weight
  ``erfc(p0 / sqrt(2 c V))`` (Persson, J. Chem. Phys. 115, 3840 (2001);
  Müser, PRL 100, 055504 (2008), doi:10.1103/PhysRevLett.100.055504).
* ``f = slope * p``: Feller's solution (W. Feller, Ann. Math. 54, 173
  (1951)) with ``tau = V/2`` and zero weight ``exp(-p0 / (slope tau))``.

The density is evaluated on Gauss-Legendre panels (16 nodes each) following the solution's scales, so that
``sum(weights * density) + zero_weight = 1`` to about 1e-13 (``error_estimate``: that defect); smooth moments
integrate to the same accuracy.  :func:`exact_kind` recognizes these problems (used by ``backend="auto"``).
"""
from __future__ import annotations

import time
from typing import Optional, Tuple

import numpy as np
from numpy.typing import NDArray

from ...models import GaussianTail, PressureFactor, ProportionalDiffusivity, SharpCutoff
from ...problem import FokkerPlanckProblem, _unit
from ...result import PressureDistribution

Array = NDArray[np.float64]

NODES_PER_PANEL = 16


def _probe_points(problem: FokkerPlanckProblem) -> Array:
    """Pressures (units of pressure) at which a generic callable ``f`` is probed."""
    p0 = problem.mean_pressure
    top = p0 + 12.0 * np.sqrt(problem.variance) * 4.0
    return np.unique(np.concatenate((np.geomspace(1e-12 * p0, top, 1500), np.linspace(0.0, top, 1501)[1:])))


def exact_kind(problem: FokkerPlanckProblem) -> Optional[Tuple[str, float]]:
    """Which closed form solves ``problem`` exactly, if any.

    Returns
    -------
    ("mirror", c) or ("feller", slope) or None
        ``("mirror", c)`` for ``f = c > 0``, ``("feller", slope)`` for ``f = slope * p``; ``None`` otherwise
        (also with a drift or a ``tau``-dependent ``f``).

    Notes
    -----
    Recognized by model type and, for any other callable, by probing it at 3000 pressures from ``1e-12 p0``
    to ``p0 + 48 sqrt(V)``: ``f`` or ``f(p)/p`` constant to 1e-14 relative.
    """
    if not problem.autonomous:
        return None
    f = problem.diffusivity
    if f is _unit or isinstance(f, SharpCutoff):
        return ("mirror", 1.0)
    if isinstance(f, ProportionalDiffusivity):
        return ("feller", f.slope)
    if isinstance(f, PressureFactor) and isinstance(f.tail, GaussianTail):
        if isinstance(f.cutoff, SharpCutoff):
            return ("mirror", 1.0)
        if isinstance(f.cutoff, ProportionalDiffusivity):
            return ("feller", f.cutoff.slope)
    declared = getattr(f, "zero_power", None)
    if declared is not None and (float(declared) not in (0.0, 1.0) or tuple(getattr(f, "breakpoints", tuple)())):
        return None  # the model protocol says: neither constant nor linear (no probing needed)
    p = _probe_points(problem)
    try:
        v = problem.f(p, 0.0)
    except ValueError:
        return None
    if v[0] > 0.0 and np.all(np.abs(v - v[0]) <= 1e-14 * v[0]):
        return ("mirror", float(v[0]))
    ratio = v / p
    if ratio[0] > 0.0 and np.all(np.abs(ratio - ratio[0]) <= 1e-14 * ratio[0]):
        return ("feller", float(ratio[0]))
    return None


def _panel_edges(p0: float, width: float, far: float, p_max: float, p_lo: float = 0.0) -> Array:
    """Panel edges on ``[p_lo, p_max]`` of width ``clip(|p - p0| / 4, width / 4, far)`` (pressure)."""
    edges = [float(p_lo)]
    p = float(p_lo)
    lo_w = width / 4.0
    while p < p_max:
        w = float(np.clip(abs(p - p0) / 4.0, lo_w, far))
        # never step over p0: put an edge on it
        if p < p0 < p + w:
            w = p0 - p
        p = min(p + w, p_max)
        edges.append(p)
    # guard against a sliver at the end
    if len(edges) > 2 and edges[-1] - edges[-2] < 1e-3 * lo_w:
        edges.pop(-2)
    return np.asarray(edges)


def gauss_legendre_grid(panel_edges: Array, n: int = NODES_PER_PANEL) -> Tuple[Array, Array]:
    """Nodes and weights of ``n``-point Gauss-Legendre on each panel (units of pressure)."""
    x, w = np.polynomial.legendre.leggauss(n)
    a, b = panel_edges[:-1], panel_edges[1:]
    half = 0.5 * (b - a)
    nodes = (half[:, None] * x[None, :] + 0.5 * (a + b)[:, None]).ravel()
    weights = (half[:, None] * w[None, :]).ravel()
    return nodes, weights


def solve(problem: FokkerPlanckProblem, *, rtol: float = 1e-6, tail_mass: float = 1e-16) -> PressureDistribution:
    """Evaluate the exact solution of ``problem`` on a Gauss-Legendre grid.

    Parameters
    ----------
    problem : FokkerPlanckProblem
        Must be one of the kinds :func:`exact_kind` recognizes.
    rtol : float
        Accepted for the common signature; the result is exact to about 1e-13 regardless.
    tail_mass : float
        Probability allowed beyond the last panel (default 1e-16).

    Raises
    ------
    ValueError
        If the problem has no closed form here, or ``p0/sqrt(V) > 1e12`` (narrower than double precision
        resolves at ``p0``).
    """
    # imported here, not by exact_kind, which every "auto" solve asks
    from ... import closed_forms as cf
    from ..domain import MAX_RATIO

    t0 = time.perf_counter()
    kind = exact_kind(problem)
    if kind is None:
        raise ValueError("backend 'closed_form' solves only f = const (sharp cutoff) and f = slope * p "
                         "without drift; use backend='native' (or 'auto') for this problem")
    name, coef = kind
    p0, tau = problem.mean_pressure, problem.tau_end
    spread = np.sqrt(2.0 * coef * tau * (1.0 if name == "mirror" else p0))
    if not p0 / spread <= MAX_RATIO:
        raise ValueError(f"mean_pressure/sqrt(variance) = {p0 / spread:.3g} exceeds {MAX_RATIO:.0e}: the distribution "
                         "is narrower than double precision resolves at p0 (it is the Gaussian limit, zero_weight 0)")
    if name == "mirror":
        var = 2.0 * coef * tau
        sd = np.sqrt(var)
        p_max = p0 + 10.0 * sd  # Gaussian tail beyond 10 sd: 7.6e-24
        panels = _panel_edges(p0, sd, sd / 2.0, p_max, p_lo=max(0.0, p0 - 12.0 * sd))
        p, w = gauss_legendre_grid(panels)
        dens = np.asarray(cf.mirror_gaussian_density(p, p0, var), dtype=float)
        zero = cf.persson_zero_weight(p0, var)
        label = f"mirror Gaussian (f = {coef:g})"
    else:
        scale = coef * tau  # exponential tail scale of the Feller solution
        sd = np.sqrt(2.0 * coef * p0 * tau)
        # density ~ exp(-(sqrt p - sqrt p0)^2 / scale): beyond p_max < tail_mass
        z = np.sqrt(-np.log(max(tail_mass, 1e-300)))
        p_max = (np.sqrt(p0) + z * np.sqrt(scale)) ** 2 + 4.0 * scale
        p_lo = max(0.0, np.sqrt(p0) - z * np.sqrt(scale)) ** 2
        panels = _panel_edges(p0, min(sd, scale) if p0 < scale else sd, max(sd, scale) / 2.0, p_max, p_lo=p_lo)
        p, w = gauss_legendre_grid(panels)
        dens = np.asarray(cf.feller_density(p, p0, tau, coef), dtype=float)
        zero = cf.feller_zero_weight(p0, tau, coef)
        label = f"Feller (f = {coef:g} p)"
    mass = float(np.sum(w * dens) + zero)
    mean = float(np.sum(w * p * dens))
    defect = abs(mass - 1.0)
    wall = time.perf_counter() - t0
    return PressureDistribution(
        p=p, density=dens, weights=w, zero_weight=float(zero), mean_pressure=p0,
        variance=problem.variance, backend="closed_form", success=True,
        message=f"exact: {label} on {panels.size - 1} Gauss-Legendre panels x {NODES_PER_PANEL} nodes",
        error_estimate=float(defect), wall_time=wall,
        diagnostics={"backend": "closed_form", "rtol": float(rtol), "n_cells": int(p.size), "levels": None,
                     "zero_power": 0.0 if name == "mirror" else 1.0, "wall": "absorbing at p = 0", "p_floor": 0.0, "p_min": float(panels[0]),
                     "p_max": float(p_max), "mass_error": mass - 1.0, "mean_error": mean - p0,
                     "negative_mass": 0.0, "min_density": float(dens.min()), "tail_mass": float(tail_mass),
                     "time_integration": "exact", "n_stages": 1, "substeps": 0,
                     "timings": {"setup": 0.0, "solve": wall, "total": wall},
                     "kind": name, "coefficient": coef, "panels": panels, "quadrature_mass_defect": mass - 1.0},
        edges=None, contact_threshold=0.0,
    )
