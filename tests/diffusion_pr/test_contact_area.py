"""One contact area: ``PressureDistribution.contact_area`` means what GFMD's ``contact_fraction`` means
(hard wall ``p > 0``, exponential wall ``p > 0.01 p0``); oracles: the closed forms' zero weight and the
log-normal gap closure's analytic cdf."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtr

import diffusion_pr as dp
from diffusion_pr.closed_forms import persson_zero_weight
from diffusion_pr.compare import SimulatedHistogram, compare

E, P0 = 8.0 / 3.0, 0.004


@pytest.fixture(scope="module")
def fig1():
    return dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)


def test_hard_wall_contact_area_is_one_minus_the_zero_weight(fig1):
    r = dp.pressure_distribution(fig1, E_star=E, mean_pressure=P0, zeta=0.0, closure="second_order")
    V = r.diagnostics["stress_variance"]
    assert r.contact_threshold == 0.0
    assert r.contact_area() == r.contact_fraction == pytest.approx(1 - persson_zero_weight(P0, V), abs=1e-14)


def test_exponential_wall_counts_gfmds_threshold(fig1):
    """zeta > 0: P(p > 0.01 p0), the log-normal closure's exact 1 - Phi((ln 0.01 + s^2/2) / s) to 1e-9 (its cells
    are exact; the cdf between them is interpolated); 1 - zero_weight (= 1 here) would be a different number."""
    r = dp.pressure_distribution(fig1, E_star=E, mean_pressure=P0, zeta=0.25, closure="lognormal_gap")
    s2 = r.diagnostics["ln_variance"]
    expect = 1.0 - ndtr((math.log(0.01) + 0.5 * s2) / math.sqrt(s2))
    assert r.contact_threshold == pytest.approx(0.01 * P0, rel=1e-15)
    assert r.contact_area() == pytest.approx(expect, abs=1e-9)
    assert abs(r.contact_area() - (1 - r.zero_weight)) > 0.01
    # compare() takes the theory's threshold by default, on both sides
    field = np.full(1000, 2 * P0)
    field[:300] = 0.005 * P0
    hist = SimulatedHistogram.from_pressures(field, bins=np.linspace(0, 3 * P0, 31), contact_threshold=0.01 * P0)
    cmp = compare(r, hist)
    assert cmp.contact_threshold == r.contact_threshold and cmp.contact_fraction_sim == 0.7
    assert cmp.contact_fraction_theory == r.contact_area()


def test_a_floor_is_not_a_contact_area():
    """f ~ p^2 at 0 never reaches the wall: zero_weight is the mass below a numerical floor. No default; a threshold
    below the floor is an error; one above it is answered."""
    r = dp.propagate(1.0, 0.5, diffusivity=lambda p: p * p / (0.01 + p * p), backend="native", rtol=1e-4)
    floor = r.diagnostics["p_floor"]
    assert floor > 0 and r.contact_threshold is None
    with pytest.raises(ValueError, match="no default contact threshold"):
        r.contact_area()
    with pytest.raises(ValueError, match="below this result.s floor"):
        r.contact_area(0.0)
    assert r.contact_area(0.01) == pytest.approx(1.0 - float(r.cdf(0.01)), abs=1e-15)
    with pytest.raises(ValueError, match="threshold"):
        r.contact_area(-1.0)
