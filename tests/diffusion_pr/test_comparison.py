"""Histogram metrics against exactly known distributions."""
from __future__ import annotations

import numpy as np
import pytest

from diffusion_pr.closed_forms import mirror_gaussian_density, persson_zero_weight
from diffusion_pr.compare import (
    SimulatedHistogram,
    bin_averaged_density,
    compare,
    log_density_curvature,
)
from diffusion_pr.fokker_planck.backends.closed_form import ExactSolution
from diffusion_pr.result import PressureDistribution


def mirror_theory(p0: float, variance: float, n: int = 20001) -> PressureDistribution:
    """Mirror Gaussian on a fine grid, with Simpson weights (error ~1e-12); pdf and cdf the exact ones."""
    p_max = p0 + 12.0 * np.sqrt(variance)
    p = np.linspace(0.0, p_max, n)
    h = p[1] - p[0]
    w = np.full(n, 2.0)
    w[1::2] = 4.0
    w[0] = w[-1] = 1.0
    w *= h / 3.0
    return PressureDistribution(p, mirror_gaussian_density(p, p0, variance), w,
                                persson_zero_weight(p0, variance), p0, variance, "closed_form", contact_threshold=0.0,
                                analytic=ExactSolution("mirror", p0, 0.5 * variance, 1.0))


def sample_mirror(rng: np.random.Generator, p0: float, variance: float, size: int) -> np.ndarray:
    """Absorbed Brownian endpoints: the mirror Gaussian by the reflection principle.

    A Gaussian sample x ~ N(p0, V) with its negative part set to 0 is *not* the
    mirror Gaussian; the reflection principle says the density of survivors is
    phi(p0) - phi(-p0); sampling: draw x, and a path that ends at x > 0 was
    absorbed with probability exp(-2 p0 x / V) (Brownian-bridge crossing).
    """
    x = rng.normal(p0, np.sqrt(variance), size)
    crossed = (x <= 0) | (rng.random(size) < np.exp(-2.0 * p0 * np.maximum(x, 0.0) / variance))
    return np.where(crossed, 0.0, x)


def test_theory_sample_matches_its_own_distribution(rng):
    p0, var = 1.0, 1.0
    pressures = sample_mirror(rng, p0, var, 400_000)
    hist = SimulatedHistogram.from_pressures(pressures, bins=np.linspace(0, 7, 141))
    theory = mirror_theory(p0, var)
    cmp = compare(theory, hist)
    # Sampling noise: the zero weight has std sqrt(w(1-w)/N) ~ 7e-4; the binned
    # L1 distance of a 140-bin histogram with N = 4e5 is dominated by Poisson
    # noise, sum_i sqrt(2 n_i/pi)/N ~ 0.01; the Kolmogorov statistic stays below
    # 1.95/sqrt(N) = 3.1e-3 with 99.9 % probability, plus one quantile-level step
    # (1/2048 = 4.9e-4) of resolution.
    assert abs(cmp.contact_fraction_theory - cmp.contact_fraction_sim) < 4e-3
    assert cmp.l1 < 0.02
    assert cmp.kolmogorov < 1.95 / np.sqrt(4e5) + 1.0 / 2048
    assert cmp.moments_theory["mean"] == pytest.approx(p0, abs=1e-9)
    assert cmp.moments_sim["mean"] == pytest.approx(p0, abs=4 * np.sqrt(var / 4e5) * 2)


def test_wrong_theory_is_detected(rng):
    pressures = sample_mirror(rng, 1.0, 1.0, 200_000)
    hist = SimulatedHistogram.from_pressures(pressures, bins=np.linspace(0, 7, 141))
    good = compare(mirror_theory(1.0, 1.0), hist)
    bad = compare(mirror_theory(1.0, 1.3), hist)
    # a 30 % wrong variance moves the zero weight by ~0.06 and the CDF by > 0.03
    assert bad.kolmogorov > 10 * good.kolmogorov
    assert bad.l1 > 3 * good.l1


def test_bin_average_integrates_exactly():
    theory = mirror_theory(0.5, 2.0)
    edges = np.linspace(0, 10, 11)
    avg = bin_averaged_density(theory, edges)
    # bin masses sum to the continuous mass (tail beyond 10 is ~1e-12)
    assert np.sum(avg * np.diff(edges)) == pytest.approx(1.0 - theory.zero_weight, abs=1e-9)


def test_log_density_curvature_of_gaussian_is_minus_inverse_variance():
    p = np.linspace(0.0, 4.0, 200)
    var = 0.7
    dens = np.exp(-((p - 1.0) ** 2) / (2 * var))
    # ln of a Gaussian is exactly quadratic: the fit returns -1/V to round-off
    assert log_density_curvature(p, dens, p_lo=1.0, p_hi=3.5) == pytest.approx(-1.0 / var, rel=1e-10)


def test_histogram_normalization_and_zero_weight():
    pressures = np.array([0.0, 0.0, 1.0, 2.0, 2.5, 3.0])
    hist = SimulatedHistogram.from_pressures(pressures, bins=np.linspace(0, 4, 5))
    assert hist.zero_weight == pytest.approx(2 / 6)
    assert np.sum(hist.density * hist.widths) + hist.zero_weight == pytest.approx(1.0)
    merged = hist.rebinned(2)
    assert np.sum(merged.density * merged.widths) == pytest.approx(4 / 6)


def test_histogram_rejects_bad_input():
    with pytest.raises(ValueError, match="pressure"):
        SimulatedHistogram.from_pressures(np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match=">= 0"):
        SimulatedHistogram.from_pressures(np.array([1.0, -1.0]))
    with pytest.raises(ValueError, match="factor"):
        SimulatedHistogram.from_pressures(np.array([1.0, 2.0])).rebinned(0)


def test_tiny_positive_pressures_count_as_the_zero_peak(rng):
    """A soft wall reports 1e-300 where a hard wall reports 0: same distances."""
    pressures = sample_mirror(rng, 1.0, 1.0, 100_000)
    soft = np.where(pressures == 0.0, 1e-300, pressures)
    edges = np.linspace(0, 7, 141)
    theory = mirror_theory(1.0, 1.0)
    hard_cmp = compare(theory, SimulatedHistogram.from_pressures(pressures, bins=edges))
    soft_cmp = compare(theory, SimulatedHistogram.from_pressures(soft, bins=edges))
    # identical bin masses once the delta is counted in the first bin (exact),
    # identical CDFs above the first edge (exact up to float round-off)
    assert soft_cmp.l1 == pytest.approx(hard_cmp.l1, abs=1e-12)
    assert soft_cmp.kolmogorov == pytest.approx(hard_cmp.kolmogorov, abs=1e-12)
    assert soft_cmp.kolmogorov < 0.01


def test_kolmogorov_between_two_samples(rng):
    """Two independent samples of one law: distance ~ 1/sqrt(N); a shifted law: the shift."""
    a = SimulatedHistogram.from_pressures(sample_mirror(rng, 1.0, 1.0, 200_000), bins=np.linspace(0, 7, 141))
    b = SimulatedHistogram.from_pressures(sample_mirror(rng, 1.0, 1.0, 200_000), bins=np.linspace(0, 7, 141))
    c = SimulatedHistogram.from_pressures(sample_mirror(rng, 1.5, 1.0, 200_000), bins=np.linspace(0, 7, 141))
    from diffusion_pr.compare import kolmogorov_between

    # two-sample Kolmogorov at 99.9 %: 1.95 sqrt(2/N) = 6.2e-3, plus one quantile step 4.9e-4
    assert kolmogorov_between(a, b) < 1.95 * np.sqrt(2 / 2e5) + 1.0 / 2048
    # the exact distance of the two mirror Gaussians is > 0.1 (zero weights 0.317 vs 0.134)
    assert kolmogorov_between(a, c) > 0.1


def test_uniform_bins_cover_the_field_exactly(rng):
    """bins=int: that many equal bins from 0 to the largest pressure (or p_max), every pressure counted."""
    field = np.concatenate([np.zeros(100), rng.exponential(1.0, 5000)])
    for bins in (1, 7, 40):
        hist = SimulatedHistogram.from_pressures(field, bins=bins)
        assert hist.density.size == bins and hist.edges.size == bins + 1
        assert hist.edges[0] == 0.0 and hist.edges[-1] == field.max()
        np.testing.assert_allclose(np.diff(hist.edges), field.max() / bins, rtol=1e-12)
        counts, _ = np.histogram(field[field > 0], bins=np.linspace(0, field.max(), bins + 1))
        np.testing.assert_allclose(hist.density * hist.widths, counts / field.size, rtol=1e-12)
        assert hist.moments["outside_bins"] == 0.0
        assert np.sum(hist.density * hist.widths) + hist.zero_weight == pytest.approx(1.0, abs=1e-12)
    capped = SimulatedHistogram.from_pressures(field, bins=10, p_max=2.0)
    assert capped.edges[-1] == 2.0 and capped.density.size == 10
    assert capped.moments["outside_bins"] == pytest.approx(np.count_nonzero(field > 2.0) / field.size)
    for bad in (0, -3, 2.5, True, "10"):
        with pytest.raises(ValueError, match="bins"):
            SimulatedHistogram.from_pressures(field, bins=bad)
    with pytest.raises(ValueError, match="bins"):
        SimulatedHistogram.from_pressures(field, bins=[0.0, 2.0, 1.0])


def ks_oracle(theory, field: np.ndarray, p_floor: float) -> float:
    """Textbook one-sample Kolmogorov statistic sup |F_theory - F_n| over x >= p_floor."""
    x = np.sort(field)
    n = x.size
    xs = x[x >= p_floor]
    f = np.asarray(theory.cdf(xs))
    # just below x_i the theory's CDF lacks the delta peak when x_i == 0 (x_i >= p_floor > 0 here)
    after = np.searchsorted(x, xs, side="right") / n  # F_n just after x_i
    before = np.searchsorted(x, xs, side="left") / n  # F_n just before x_i
    d = max(np.max(np.abs(f - after)), np.max(np.abs(f - before)))
    d_floor = abs(float(theory.cdf(p_floor)) - np.searchsorted(x, p_floor, side="right") / n)
    return float(max(d, d_floor))


@pytest.mark.parametrize("p0_theory", [0.7, 1.4])
def test_kolmogorov_is_the_absolute_sup_distance(rng, p0_theory):
    """Theory below and above the sample's law: the same absolute statistic as the textbook formula."""
    field = sample_mirror(rng, 1.0, 1.0, 50_000)
    hist = SimulatedHistogram.from_pressures(field, bins=np.linspace(0, 7, 141))
    theory = mirror_theory(p0_theory, 1.0)
    expected = ks_oracle(theory, field, hist.edges[1])
    assert expected > 0.05  # a real, one-signed difference (the test could fail)
    # resolution of the stored quantile function: one level step 1/2048 (plus interpolation)
    assert compare(theory, hist).kolmogorov == pytest.approx(expected, abs=2.0 / 2048)
    # without quantiles: CDF at the bin edges, never above the full statistic
    coarse = SimulatedHistogram(hist.edges, hist.density, hist.zero_weight, dict(hist.moments))
    ks_edges = compare(theory, coarse).kolmogorov
    assert 0.8 * expected < ks_edges <= expected + 1e-12


def test_kolmogorov_between_is_symmetric_and_absolute(rng):
    from diffusion_pr.compare import kolmogorov_between

    x = sample_mirror(rng, 1.0, 1.0, 40_000)
    y = sample_mirror(rng, 1.5, 1.0, 40_000)
    edges = np.linspace(0, 7, 141)
    a, b = (SimulatedHistogram.from_pressures(v, bins=edges) for v in (x, y))
    # textbook two-sample statistic over p >= edges[1]
    grid = np.union1d(x, y)
    grid = grid[grid >= edges[1]]
    fx = np.searchsorted(np.sort(x), grid, side="right") / x.size
    fy = np.searchsorted(np.sort(y), grid, side="right") / y.size
    expected = float(np.max(np.abs(fx - fy)))
    assert expected > 0.05
    assert kolmogorov_between(a, b) == pytest.approx(expected, abs=2.0 / 2048)
    assert kolmogorov_between(b, a) == pytest.approx(expected, abs=2.0 / 2048)


def test_contact_fraction_at_a_threshold_on_both_sides(rng):
    """compare(..., contact_threshold=t): theory 1 - cdf(t), field fraction above t (counted exactly)."""
    field = sample_mirror(rng, 1.0, 1.0, 20_000)
    t = 0.3
    hist = SimulatedHistogram.from_pressures(field, bins=np.linspace(0, 7, 141), contact_threshold=t)
    theory = mirror_theory(1.0, 1.0)
    cmp = compare(theory, hist, contact_threshold=t)
    assert cmp.contact_threshold == t
    assert cmp.contact_fraction_sim == np.count_nonzero(field > t) / field.size
    # theory: 1 - zero_weight - integral_0^t density, Simpson on a fine grid of the closed form
    q = np.linspace(0.0, t, 2001)
    w = np.full(q.size, 2.0)
    w[1::2], w[0], w[-1] = 4.0, 1.0, 1.0
    inner = float(np.sum(w * mirror_gaussian_density(q, 1.0, 1.0)) * (q[1] - q[0]) / 3)
    assert cmp.contact_fraction_theory == pytest.approx(1.0 - persson_zero_weight(1.0, 1.0) - inner, abs=1e-8)
    # default threshold 0: the hard-wall fractions, 1 - zero_weight on both sides
    cmp0 = compare(theory, hist)
    assert cmp0.contact_fraction_sim == 1.0 - hist.zero_weight
    assert cmp0.contact_fraction_theory == pytest.approx(theory.contact_fraction, abs=1e-15)
    # a histogram without the counted threshold falls back to its quantiles (one level step)
    plain = SimulatedHistogram.from_pressures(field, bins=np.linspace(0, 7, 141))
    assert plain.fraction_above(t) == pytest.approx(cmp.contact_fraction_sim, abs=1.0 / 2048)
    with pytest.raises(ValueError, match="contact_threshold"):
        compare(theory, hist, contact_threshold=-1.0)


def test_compare_takes_a_gfmd_result_a_field_a_histogram_or_an_ensemble():
    """One bridge: a ContactResult, its pressure field and its histogram give the same comparison (the field counted
    at the theory's threshold, as the result's histogram is); an ensemble group is compare_ensemble's comparison."""
    import gfmd_ref as g

    import diffusion_pr as dp
    from diffusion_pr.compare import EnsembleComparison, compare, compare_ensemble

    h, L = g.fig1_surface(64, seed=1)
    res = g.solve_contact(h, length=L, E_star=8 / 3, mean_pressure=0.004, interaction=g.HardWall())
    theory = dp.pressure_distribution(dp.DiscreteSpectrum.from_heights(h, L), E_star=8 / 3, mean_pressure=0.004,
                                      rtol=1e-5)
    field_hist = g.PressureHistogram.from_pressures(res.pressure, contact_threshold=theory.contact_threshold)
    for other, same in ((compare(theory, res), compare(theory, g.pressure_histogram(res))),
                        (compare(theory, res.pressure), compare(theory, field_hist))):
        assert other.contact_fraction_sim == pytest.approx(res.contact_area(), abs=1e-12)
        assert other.kolmogorov == same.kolmogorov and other.l1 == same.l1  # the same field, bins and quantiles
    group = g.bundled_ensemble("fig1_n1024").group(None)
    pooled = compare(theory, group)
    assert isinstance(pooled, EnsembleComparison)
    assert pooled.kolmogorov == pytest.approx(compare_ensemble(theory, group).kolmogorov, abs=1e-12)
    with pytest.raises(TypeError, match="PressureHistogram"):
        compare(theory, "field.npy")
