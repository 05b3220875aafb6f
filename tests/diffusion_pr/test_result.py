"""The result object's integrals (mass, mean, moments, CDF) against exact values."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from diffusion_pr.closed_forms import mirror_gaussian_density, persson_zero_weight
from diffusion_pr.result import PressureDistribution


def exact_mirror_cdf(p, p0, var):
    s = np.sqrt(var)
    cont = (norm.cdf((p - p0) / s) - norm.cdf(-p0 / s)) - (norm.cdf((p + p0) / s) - norm.cdf(p0 / s))
    return persson_zero_weight(p0, var) + cont


def gauss_legendre_result(p0, var, panels=40, nodes=16):
    """Mirror Gaussian on Gauss-Legendre panels: sparse nodes, exact weights."""
    top = p0 + 12 * np.sqrt(var)
    x, w = np.polynomial.legendre.leggauss(nodes)
    edges = np.linspace(0, top, panels + 1)
    a, b = edges[:-1, None], edges[1:, None]
    p = (0.5 * (b - a) * x + 0.5 * (a + b)).ravel()
    wt = (0.5 * (b - a) * w).ravel()
    return PressureDistribution(p, mirror_gaussian_density(p, p0, var), wt, persson_zero_weight(p0, var),
                                p0, var, "test")


def test_pointwise_cdf_integrates_between_nodes():
    p0, var = 0.004, 0.0413**2
    r = gauss_legendre_result(p0, var)
    q = np.linspace(0, 0.3, 3001)  # far finer than the node spacing
    # PCHIP antiderivative on 640 nodes: 3rd-order accurate, error ~1e-7 here;
    # the old cumulative-sum rule was off by ~1e-3 (10 % of a narrow bin).
    assert np.max(np.abs(r.cdf(q) - exact_mirror_cdf(q, p0, var))) < 1e-6
    assert r.cdf(-1.0) == 0.0
    assert r.cdf(1.0) == pytest.approx(1.0, abs=1e-10)


def test_mass_mean_and_moments_of_mirror_gaussian():
    p0, var = 1.0, 1.0
    r = gauss_legendre_result(p0, var, panels=60)
    # Gauss-Legendre with 16 nodes per panel integrates the smooth density to round-off
    assert r.mass == pytest.approx(1.0, abs=1e-12)
    assert r.mean == pytest.approx(p0, abs=1e-12)
    # <p^2> of the mirror Gaussian including the delta: (p0^2 + V) erf(s/sqrt2) + 2 p0 sqrt(V) phi(s)
    s = p0 / np.sqrt(var)
    from scipy.special import erf

    second = (p0**2 + var) * erf(s / np.sqrt(2)) + 2 * p0 * np.sqrt(var) * norm.pdf(s)
    assert r.moment(2) == pytest.approx(second, rel=1e-12)
    assert r.moment(2, central=True) == pytest.approx(second - p0**2, rel=1e-12)
    assert r.contact_fraction == pytest.approx(1 - persson_zero_weight(p0, var), abs=1e-15)


def test_finite_volume_cdf_is_exact_on_edges():
    edges = np.array([0.0, 1.0, 3.0, 4.0])
    dens = np.array([0.1, 0.2, 0.1])
    r = PressureDistribution(0.5 * (edges[1:] + edges[:-1]), dens, np.diff(edges), 0.4, 1.5, 1.0, "fv",
                             edges=edges)
    assert r.cdf(edges) == pytest.approx([0.4, 0.5, 0.9, 1.0])
    assert r.cdf(2.0) == pytest.approx(0.7)
