"""The graded nested grids (diffusion_pr/solvers/fv/grid.py): Phi^-1 and nesting."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from diffusion_pr.fokker_planck import grid
from diffusion_pr.fokker_planck.grid import GridSpec, Remap, edges_for, knot_indices

SPECS = [
    # a floor 16 decades down with a cutoff knot (Fig. 1 scene), a wall at 0 with a p0 grading, no grading
    GridSpec(p_wall=4e-16, p_max=0.104, knots=(4e-9, 0.0027, 0.004), scale=0.009, c_wall=0.6, c_0=0.0, w0=0.009,
             p0=0.004),
    GridSpec(p_wall=0.0, p_max=6.0, knots=(1.0,), scale=0.05, c_wall=0.0, c_0=1.0, w0=1e-3, p0=1.0),
    GridSpec(p_wall=0.0, p_max=8.0, knots=(1.0,), scale=1.0, c_wall=0.0, c_0=0.0, w0=1.0, p0=1.0),
]


def _remapped(spec: GridSpec, values: tuple) -> GridSpec:
    """``spec`` with a Remap whose density takes ``values`` at equidistant knots over its whole Phi."""
    total = float(spec.phi(spec.p_max) - spec.phi(spec.p_wall))
    return replace(spec, remap=Remap(tuple(np.linspace(0.0, total, len(values))), values))


# the Fig. 1 family remapped: cells 0.7x ... 8x as dense as Phi's (the inverse and the nesting hold for it too)
SPECS.append(_remapped(SPECS[0], (1.0, 3.0, 8.0, 2.0, 0.7, 1.0)))


@pytest.mark.parametrize("spec", SPECS)
def test_inverse_of_the_monitor_function_to_round_off(spec):
    """Phi(Phi^-1(t)) = t to 1e-13 (Newton path), and the safeguarded fallback lands on the same points."""
    a, b = spec.p_wall, spec.p_max
    ph = spec.phi(np.array([a, b]))
    targets = np.linspace(ph[0], ph[1], 2001)
    x = grid._invert(spec, targets, a, b)
    assert np.all(np.diff(x) > 0) and x[0] >= a and x[-1] <= b
    assert np.max(np.abs(spec.phi(x) - targets) / np.maximum(np.abs(targets), 1.0)) < 1e-13
    tol = 1e-14 * np.maximum(np.abs(targets), 1.0)
    start = np.interp(targets, *grid._table(spec, a, b)[::-1])
    safe = grid._invert_safe(spec, targets, start, a, b, tol)
    assert np.max(np.abs(safe - x) / np.maximum(x, 1e-300)) < 1e-12


@pytest.mark.parametrize("spec", SPECS)
def test_doubled_grid_nests_bit_for_bit(spec):
    """The grid of 2 idx (factor 4) has the grid of idx (factor 4) as every other edge, to the last bit:
    the engine's doubling levels reuse the solutions on those grids."""
    idx = knot_indices(spec, 97)
    fine = edges_for(spec, idx, 4)
    finer = edges_for(spec, 2 * idx, 4)
    assert np.array_equal(finer[::2], fine)
    assert np.array_equal(edges_for(spec, idx, 2), fine[::2])
    # the doubling level inverts only its new edges (known=): the same grid, bit for bit
    assert np.array_equal(edges_for(spec, 2 * idx, 4, known=fine), finer)


def test_crowded_knots_nest_and_take_known_edges_bit_for_bit():
    """Knots 0.02 apart on a scale of 1 (the residual spline would not be monotone: equal Phi steps per segment
    instead): the doubled grid still nests, and inverting only its new edges gives it bit for bit."""
    spec = GridSpec(p_wall=0.0, p_max=8.0, knots=(1.0, 1.02, 1.05), scale=1.0, c_wall=0.0, c_0=0.0, w0=1.0, p0=1.0)
    for n in (20, 97):
        idx = knot_indices(spec, n)
        fine, finer = edges_for(spec, idx, 4), edges_for(spec, 2 * idx, 4)
        assert np.array_equal(finer[::2], fine)
        assert np.array_equal(edges_for(spec, 2 * idx, 4, known=fine), finer)
        assert np.all(np.diff(finer) > 0)


def test_remap_density_is_the_derivative_of_its_closed_form_integral():
    """F is the spline's integral in closed form: F' = D (central differences, h = 1e-5: error ~1e-10), F(0) = 0,
    F(last knot) = total, linear beyond it; F^-1(F(v)) = v to round-off; a constant density gives F = c v."""
    remap = Remap((0.0, 0.7, 2.0, 2.5, 4.0), (1.0, 4.0, 0.5, 2.0, 1.5))
    v = np.linspace(0.0, 4.0, 801)[1:-1]
    h = 1e-5
    fd = (remap.forward(v + h) - remap.forward(v - h)) / (2 * h)
    np.testing.assert_allclose(fd, remap.density(v), rtol=1e-8)
    assert remap.forward(np.array(0.0)) == 0.0 and np.isclose(remap.forward(np.array(4.0)), remap.total, rtol=1e-15)
    assert np.isclose(remap.forward(np.array(5.0)) - remap.total, 1.5, rtol=1e-14)
    t = np.linspace(0.0, remap.total, 997)
    assert np.max(np.abs(remap.forward(remap.inverse(t)) - t)) <= 1e-14 * remap.total
    flat = Remap((0.0, 1.0, 3.0), (2.0, 2.0, 2.0))
    np.testing.assert_allclose(flat.forward(v), 2.0 * v, rtol=1e-14)


def test_remapped_cells_follow_its_density():
    """The grid's steps in F(v) are the edge map's (smooth, about equal: the knots' rounding residual moves them),
    and its cells are D times denser in v than that: (v-spacing) x D(midpoint) / (F-spacing) = 1 up to the O(h^2)
    of the midpoint rule (measured 4.4e-4 over 800 cells; F-steps within 1.65x), whereas the v-spacing itself
    varies 8x."""
    spec = SPECS[-1]
    idx = knot_indices(spec, 200)
    edges = edges_for(spec, idx, 4)
    v = spec.base.phi(edges) - spec.base.phi(spec.p_wall)
    dv, df = np.diff(v), np.diff(spec.phi(edges))
    assert dv.max() / dv.min() > 5.0 and df.max() / df.min() < 2.0
    assert np.max(np.abs(dv * spec.remap.density(0.5 * (v[1:] + v[:-1])) / df - 1.0)) < 2e-3


def test_remap_rejects_a_density_that_is_not_safely_positive():
    """A spike of 30x between two knots makes the natural spline dip below zero beside it: refused, as are knots
    that do not start at 0 and a non-positive value."""
    with pytest.raises(ValueError, match="not safely positive"):
        Remap((0.0, 1.0, 2.0, 3.0, 4.0), (1.0, 1.0, 30.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="increasing knots from 0"):
        Remap((0.5, 1.0, 2.0), (1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="positive values"):
        Remap((0.0, 1.0, 2.0), (1.0, 0.0, 1.0))


def _random_splines(seed: int, count: int):
    """Natural splines through 3-8 random knots on [0, 1] (the shape of edges_for's rounding residuals, scaled up
    so that their slopes matter)."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        n = int(rng.integers(3, 9))
        x = np.r_[0.0, np.sort(rng.uniform(0.02, 0.98, n - 2)), 1.0]
        if np.min(np.diff(x)) < 0.01:
            continue
        yield grid._NaturalSpline(x, rng.normal(scale=0.05, size=n))


def _oracle(r):
    """SciPy's natural cubic spline through the same points: an independent evaluation of ``r``."""
    from scipy.interpolate import CubicSpline

    return CubicSpline(r.x, r.y, bc_type="natural")


def test_spline_min_slope_is_the_exact_minimum_of_its_derivative():
    """edges_for's monotonicity check: the closed-form minimum of r' (an end of a piece, or inside where r''
    changes sign from - to +) against SciPy's natural spline's derivative on 2e5 points.  It is never above the
    sampled minimum (round-off apart) and within the sampling's error below it ((h/2)^2 |r'''| / 2 at a 5e-6
    spacing), and a spline whose minimum is inside a piece occurs among the 300 (the interior branch is exercised)."""
    t = np.linspace(0.0, 1.0, 200_001)
    interior = 0
    for r in _random_splines(3, 300):
        slope = _oracle(r).derivative()
        exact, dense = r.min_slope(), float(slope(t).min())
        assert exact <= dense + 1e-12
        assert dense - exact <= 1e-8 * (1.0 + np.max(np.abs(r.m)))
        interior += exact < float(slope(r.x).min()) - 1e-12
    assert interior > 10


def test_spline_on_pieces_is_the_natural_cubic_spline():
    """edges_for evaluates the residual spline piece by piece (the knots are edges, so each point's piece is known):
    SciPy's natural spline's values at 97 x 4 + 1 points, the knots and the last point included, to round-off
    (1e-14 of the values' scale: two solves of the spline's system and a dozen operations per point; measured
    2.4e-15)."""
    for r in _random_splines(4, 100):
        n = 97 * 4
        idx = np.round(r.x * n).astype(int)
        if np.min(np.diff(idx)) < 1:
            continue
        r = grid._NaturalSpline(idx / n, r.y)  # knots at grid points, as edges_for puts them
        x = np.arange(n + 1) / n
        counts = np.diff(idx)
        counts[-1] += 1
        assert np.max(np.abs(r.on_pieces(x, counts) - _oracle(r)(x))) <= 1e-14 * (1.0 + np.max(np.abs(r.y)))


def test_three_knot_spline_is_lapacks_solve_bit_for_bit(rng):
    """A spline through three knots (the wall, p0 and p_max: the mirror, Feller) takes its one second derivative in
    closed form instead of np.linalg.solve: the same bits as LAPACK's solve of the 3x3 system, over 2000 random
    knots and values of 16 decades."""
    for _ in range(2000):
        x = np.r_[0.0, rng.uniform(0.001, 0.999), 1.0]
        y = rng.normal(size=3) * 10.0 ** rng.uniform(-16, 0)
        h = np.diff(x)
        a = np.array([[1.0, 0.0, 0.0], [h[0], 2.0 * (h[0] + h[1]), h[1]], [0.0, 0.0, 1.0]])
        b = np.array([0.0, 6.0 * ((y[2] - y[1]) / h[1] - (y[1] - y[0]) / h[0]), 0.0])
        assert np.array_equal(grid._NaturalSpline(x, y).m, np.linalg.solve(a, b))


def _random_remap(spec: GridSpec, rng: np.random.Generator) -> GridSpec:
    """``spec`` with a random Remap as the engine makes them: 12 knots, a density over a range of up to 16."""
    for _ in range(100):
        try:
            return _remapped(spec, tuple(np.exp(rng.uniform(0.0, np.log(16.0), 12))))
        except ValueError:  # (a spline that is not safely positive: drawn again)
            continue
    raise AssertionError("no positive remap drawn")


def test_remap_inverse_bisects_from_a_poor_start(rng):
    """The remap's safeguarded Newton from a poor start (a start table of its two ends: Newton steps leave their
    brackets and bisection takes over) converges to round-off at 2000 random targets of five random remaps."""
    for _ in range(5):
        remap = _random_remap(SPECS[0], rng).remap
        ends = np.array([0.0, remap._x[-1]])
        object.__setattr__(remap, "_start", (remap.forward(ends), ends))  # (a private field: the poor start)
        t = rng.uniform(0.0, remap.total, 2000)
        plain = remap.inverse(t)
        assert np.max(np.abs(remap.forward(plain) - t)) <= 1e-15 * max(remap.total, 1.0)  # converged
