"""Histogram metrics against exactly known distributions."""
from __future__ import annotations

import numpy as np
import pytest

from diffusion_pr.closed_forms import mirror_gaussian_density, persson_zero_weight
from diffusion_pr.comparison import (
    SimulatedHistogram,
    bin_averaged_density,
    compare,
    log_density_curvature,
)
from diffusion_pr.result import PressureDistribution


def mirror_theory(p0: float, variance: float, n: int = 20001) -> PressureDistribution:
    """Mirror Gaussian on a fine grid, with Simpson weights (error ~1e-12)."""
    p_max = p0 + 12.0 * np.sqrt(variance)
    p = np.linspace(0.0, p_max, n)
    h = p[1] - p[0]
    w = np.full(n, 2.0)
    w[1::2] = 4.0
    w[0] = w[-1] = 1.0
    w *= h / 3.0
    return PressureDistribution(p, mirror_gaussian_density(p, p0, variance), w,
                                persson_zero_weight(p0, variance), p0, variance, "closed_form")


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
    from diffusion_pr.comparison import kolmogorov_between

    # two-sample Kolmogorov at 99.9 %: 1.95 sqrt(2/N) = 6.2e-3, plus one quantile step 4.9e-4
    assert kolmogorov_between(a, b) < 1.95 * np.sqrt(2 / 2e5) + 1.0 / 2048
    # the exact distance of the two mirror Gaussians is > 0.1 (zero weights 0.317 vs 0.134)
    assert kolmogorov_between(a, c) > 0.1
