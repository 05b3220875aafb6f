"""Hard cases: stable, conservative, non-negative over the ranges issue 3 names.

Every case asserts: success with the estimate below rtol, total probability
(continuous part + zero weight) 1 to within the error estimate (the outflow at
the wall is booked exactly; extrapolation may move tail mass), mean pressure p0 to rtol when there is no drift (force
balance), no negative density.  Where a closed form exists (sharp cutoff) the
zero weight is also compared with it.  rtol = 1e-4 keeps the file fast.
"""
from __future__ import annotations

import numpy as np
import pytest

import diffusion_pr as dp
from diffusion_pr import closed_forms as cf

RTOL = 1e-4


def check_sound(r, p0: float, *, drift: bool = False) -> None:
    assert r.success, r.message
    assert r.error_estimate <= RTOL
    # the exponential conserves mass to round-off; the Richardson step may move the tails' mass by
    # at most what it adds to the estimate
    assert abs(r.mass - 1.0) < 1e-10 + r.error_estimate
    assert np.all(r.density >= 0.0) and np.all(np.isfinite(r.density))
    assert 0.0 <= r.zero_weight <= 1.0
    if not drift:
        assert abs(r.mean - p0) <= RTOL * p0


@pytest.mark.parametrize("ratio", [1e-3, 1e-2, 0.1, 1.0, 10.0])
def test_p0_over_sqrtV_sharp_native(ratio):
    # native on the mirror-Gaussian problem, from nearly-all-absorbed to no absorption
    r = dp.propagate(ratio, 1.0, backend="native", rtol=RTOL)
    check_sound(r, ratio)
    assert abs(r.zero_weight - cf.persson_zero_weight(ratio, 1.0)) <= RTOL


@pytest.mark.parametrize("ratio", [1e-3, 1e-2, 0.1, 1.0, 10.0])
@pytest.mark.parametrize("cutoff", ["muser", "smoothstep"])
def test_p0_over_sqrtV_smooth_cutoffs(ratio, cutoff):
    f = dp.PressureFactor(dp.make_cutoff(cutoff, 0.5), dp.GaussianTail())
    check_sound(dp.propagate(ratio, 1.0, diffusivity=f, rtol=RTOL), ratio)


@pytest.mark.parametrize("p_c", [1e-4, 1e-2, 1.0])
@pytest.mark.parametrize("cutoff", ["muser", "raised_cosine", "smoothstep"])
def test_cutoff_pressure_range(p_c, cutoff):
    f = dp.PressureFactor(dp.make_cutoff(cutoff, p_c), dp.GaussianTail())
    r = dp.propagate(1.0, 1.0, diffusivity=f, rtol=RTOL)
    check_sound(r, 1.0)
    if cutoff != "smoothstep" and p_c <= 1e-2:
        # f ~ p^2 near 0: the creeping peak falls below the wall floor, so a tiny p_c
        # reproduces Persson's non-contact weight (the sharp-cutoff limit)
        assert r.zero_weight == pytest.approx(cf.persson_zero_weight(1.0, 1.0), abs=5e-3)


@pytest.mark.parametrize("tail", [("linear", 0.5), ("max_linear", 2.0)])
def test_exponential_tails(tail):
    f = dp.PressureFactor(dp.SharpCutoff(), dp.make_tail(*tail))
    check_sound(dp.propagate(1.0, 1.0, diffusivity=f, rtol=RTOL), 1.0)


@pytest.mark.parametrize("hurst", [0.1, 0.9])
@pytest.mark.parametrize("zeta", [1e-4, 10.0])
def test_wide_magnification_range_with_drift(hurst, zeta):
    # q_max/q_min = 1e4 and a restoring drift A = -D(eta) (p - p0)/(2 sqrt(V)): exercises the eta path
    s = dp.SelfAffineSpectrum(hurst, 1.0, 1e4, rms_slope=0.1)
    p0 = 0.02
    V = dp.stress_variance(s, E_star=1.0, mean_pressure=p0, zeta=zeta)

    def drift(p, eta):
        D = dp.diffusivity_vs_magnification(s, eta, E_star=1.0, mean_pressure=p0, zeta=zeta)
        return -0.5 * D * (p - p0) / np.sqrt(V)

    r = dp.pressure_distribution(s, E_star=1.0, mean_pressure=p0, zeta=zeta, cutoff="smoothstep",
                                 p_c=0.3 * np.sqrt(V), drift=drift, rtol=RTOL)
    check_sound(r, p0, drift=True)
    # a drift towards p0 cannot move the mean away from it by more than the error
    assert abs(r.mean - p0) <= RTOL * p0 + 1e-3 * np.sqrt(V)


@pytest.mark.parametrize("zeta", [1e-4, 1e-2, 1.0, 10.0])
@pytest.mark.parametrize("hurst", [0.1, 0.5, 0.9])
def test_zeta_and_hurst_ranges(zeta, hurst):
    s = dp.SelfAffineSpectrum(hurst, 1.0, 1e4, rms_slope=0.1)
    p0 = 0.02
    V = dp.stress_variance(s, E_star=1.0, mean_pressure=p0, zeta=zeta)
    r = dp.pressure_distribution(s, E_star=1.0, mean_pressure=p0, zeta=zeta, cutoff="muser",
                                 p_c=0.5 * np.sqrt(V), rtol=RTOL)
    assert r.backend == "native"
    check_sound(r, p0)
    assert r.diagnostics["stress_variance"] == V


def test_seed_figure1_cutoffs_all_converge():
    # the paper's fitted p_c values for the Fig. 1 surface (SPEC section 6)
    s = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    for zeta, p_c in ((0.001, 0.0068), (0.01, 0.0082), (0.25, 0.0027), (4.0, 0.0027)):
        r = dp.pressure_distribution(s, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, cutoff="muser",
                                     p_c=p_c, rtol=RTOL)
        check_sound(r, 0.004)
