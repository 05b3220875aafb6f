"""Tests of diffusion_pr.closed_forms against independent oracles.

Oracles: quadrature (normalization, moments), finite-difference residuals of
the Fokker-Planck equations, Monte Carlo of the underlying Ito processes
(seeded; tolerances from the MC standard error), high-precision mpmath
evaluation of the naive Feller formula, and the SPEC's printed numbers.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from diffusion_pr.closed_forms import (
    Moments,
    cir_density,
    cir_zero_weight,
    drifted_mirror_gaussian_density,
    drifted_mirror_gaussian_zero_weight,
    feller_density,
    feller_moments,
    feller_zero_weight,
    gaussian_density,
    gaussian_moments,
    mirror_gaussian_density,
    mirror_gaussian_moments,
    persson_contact_fraction,
    persson_zero_weight,
)


def _quad0inf(f, scale: float, centre: float) -> float:
    """int_0^inf f dp, split at the bulk of the mass so quad resolves narrow peaks."""
    pts = sorted({max(centre - 10 * scale, 0.0), centre, centre + 10 * scale})
    pts = [x for x in pts if x > 0]
    edges = [0.0] + pts
    total = sum(quad(f, a, b, epsabs=0.0, epsrel=1e-12, limit=400)[0] for a, b in zip(edges[:-1], edges[1:]))
    return total + quad(f, edges[-1], np.inf, epsabs=1e-15, epsrel=1e-12, limit=400)[0]


# --------------------------------------------------------------------------- Gaussian / Persson
def test_gaussian_normalized_and_moments():
    m, v = 0.3, 0.04
    f = lambda p: gaussian_density(p, m, v)
    assert quad(f, -np.inf, np.inf, epsrel=1e-12)[0] == pytest.approx(1.0, abs=1e-10)
    assert quad(lambda p: p * f(p), -np.inf, np.inf, epsrel=1e-12)[0] == pytest.approx(m, rel=1e-10)
    assert gaussian_moments(m, v) == Moments(m, v, 0.0)
    assert gaussian_density(m, m, v) == pytest.approx(1 / math.sqrt(2 * math.pi * v), rel=1e-15)


def test_spec_persson_number():
    # SPEC section 3: sqrt(V0) = 0.041333 (i.e. (E*/2) rms_slope = 4/3 * 0.031) -> a_r = 0.07709
    V0 = (4.0 / 3.0 * 0.031) ** 2
    assert persson_contact_fraction(0.004, V0) == pytest.approx(0.07709, abs=5e-6)
    assert persson_contact_fraction(0.004, V0) + persson_zero_weight(0.004, V0) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("ratio", [1e-3, 0.1, 1.0, 3.0, 10.0])
def test_mirror_gaussian_normalization_mean_variance(ratio):
    # hard cases p0/sqrt(V) from 1e-3 to 10; quadrature at epsrel 1e-12 -> 1e-9 tolerances
    V = 2.0
    p0 = ratio * math.sqrt(V)
    f = lambda p: mirror_gaussian_density(p, p0, V)
    zw = persson_zero_weight(p0, V)
    sd = math.sqrt(V)
    assert _quad0inf(f, sd, p0) + zw == pytest.approx(1.0, abs=1e-10)
    mean = _quad0inf(lambda p: p * f(p), sd, p0)
    assert mean == pytest.approx(p0, rel=1e-9)  # the delta at p = 0 carries no pressure
    m2 = _quad0inf(lambda p: p * p * f(p), sd, p0)
    mom = mirror_gaussian_moments(p0, V)
    assert mom.mean == p0
    assert mom.variance == pytest.approx(m2 - p0**2, rel=1e-8)
    assert mom.zero_weight == pytest.approx(zw, rel=1e-14)


def test_persson_zero_weight_tail_accuracy():
    # erfc keeps relative accuracy deep in the tail: p0/sqrt(2V) = 8 -> erfc(8) = 1.1224297172982928e-29
    # (reference value: mpmath.erfc(8) to 17 digits); 1 - erf would give 0.
    assert persson_zero_weight(8.0 * math.sqrt(2.0), 1.0) == pytest.approx(1.1224297172982928e-29, rel=1e-13)


def test_mirror_gaussian_small_p_and_support():
    # near p = 0 the density is linear: 2 p p0/V * phi(0; p0, V) (expm1 keeps it accurate)
    p0, V = 1.0, 0.5
    p = 1e-12
    slope = 2 * p0 / V * math.exp(-p0**2 / (2 * V)) / math.sqrt(2 * math.pi * V)
    assert mirror_gaussian_density(p, p0, V) == pytest.approx(slope * p, rel=1e-9)
    assert mirror_gaussian_density([-1.0, 0.0], p0, V).tolist() == [0.0, 0.0]


def test_mirror_gaussian_pde_residual():
    # Pr(p, tau) with V = 2 tau solves dPr/dtau = d^2 Pr/dp^2 on p > 0 with Pr(0) = 0.
    # Central differences, h = 1e-3, dtau = 1e-4: truncation ~1e-6 relative to |dPr/dtau|.
    p0, tau = 1.0, 0.3
    p = np.linspace(0.01, 4.0, 400)
    h, dt = 1e-3, 1e-4
    P = lambda pp, t: mirror_gaussian_density(pp, p0, 2 * t)
    lhs = (P(p, tau + dt) - P(p, tau - dt)) / (2 * dt)
    rhs = (P(p + h, tau) - 2 * P(p, tau) + P(p - h, tau)) / h**2
    assert np.max(np.abs(lhs - rhs)) < 1e-5 * np.max(np.abs(lhs))


def test_mirror_gaussian_vs_absorbed_brownian_motion():
    # Monte Carlo: p_{k+1} = p_k + sqrt(V/n) Z, killed at 0. Between steps the path is a Brownian
    # bridge, which crosses 0 with probability exp(-2 p_k p_{k+1} / (V/n)) (reflection principle):
    # with that test the discrete simulation is exact, so only statistical error remains.
    rng = np.random.default_rng(7)
    npath, nstep = 200_000, 50
    p0, V = 1.0, 1.5
    dv = V / nstep
    p = np.full(npath, p0)
    alive = np.ones(npath, bool)
    for _ in range(nstep):
        new = p + math.sqrt(dv) * rng.standard_normal(npath)
        cross = (new <= 0) | (rng.random(npath) < np.exp(-2 * np.maximum(p, 0) * np.maximum(new, 0) / dv))
        alive &= ~cross
        p = np.where(alive, new, 0.0)
    zw_mc = 1 - alive.mean()
    se = math.sqrt(zw_mc * (1 - zw_mc) / npath)
    assert zw_mc == pytest.approx(persson_zero_weight(p0, V), abs=5 * se)
    # empirical CDF at several pressures vs quadrature of the closed form (5 standard errors)
    zw = persson_zero_weight(p0, V)
    for x in (0.25, 0.5, 1.0, 2.0, 3.5):
        exact = zw + quad(lambda q: mirror_gaussian_density(q, p0, V), 0, x, epsrel=1e-12)[0]
        emp = np.mean(p <= x)
        assert emp == pytest.approx(exact, abs=5 * math.sqrt(exact * (1 - exact) / npath))
    # mean conserved (martingale): standard error sqrt(var/npath)
    assert p.mean() == pytest.approx(p0, abs=5 * p.std() / math.sqrt(npath))


# --------------------------------------------------------------------------- Feller
@pytest.mark.parametrize("p0,tau,a", [(1.0, 0.5, 1.0), (0.004, 1e-4, 2.0), (2.0, 1e-3, 0.1), (1.0, 50.0, 1.0)])
def test_feller_normalization_and_moments(p0, tau, a):
    # int density + zero weight = 1, mean p0, variance 2 a p0 tau; quadrature tolerances 1e-9
    f = lambda p: feller_density(p, p0, tau, a)
    zw = feller_zero_weight(p0, tau, a)
    scale = math.sqrt(2 * a * p0 * tau) + a * tau
    assert _quad0inf(f, scale, p0) + zw == pytest.approx(1.0, abs=1e-9)
    mean = _quad0inf(lambda p: p * f(p), scale, p0)
    assert mean == pytest.approx(p0, rel=1e-9)
    m2 = _quad0inf(lambda p: p * p * f(p), scale, p0)
    mom = feller_moments(p0, tau, a)
    assert mom.variance == pytest.approx(2 * a * p0 * tau, rel=1e-15)
    assert m2 - p0**2 == pytest.approx(mom.variance, rel=1e-8)
    assert mom.zero_weight == zw and mom.mean == p0


def test_feller_against_mpmath_naive_formula():
    # The overflow-free ive form vs the printed formula (SPEC section 4) in 50-digit arithmetic,
    # including x = 2 sqrt(p p0)/(a tau) ~ 1e4, where I1(x) overflows double precision.
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 50
    for p0, tau, a in ((1.0, 0.5, 1.0), (1.0, 1e-4, 1.0), (0.004, 2e-5, 3.0)):
        at = a * tau
        for p in (1e-9, 0.3 * p0, 0.97 * p0, p0, 1.05 * p0, 3 * p0):
            P = mpmath.mpf(p)
            naive = (1 / mpmath.mpf(at)) * mpmath.sqrt(p0 / P) * mpmath.exp(-(P + p0) / at) * mpmath.besseli(
                1, 2 * mpmath.sqrt(P * p0) / at
            )
            got = feller_density(p, p0, tau, a)
            if float(naive) > 1e-250:
                assert got == pytest.approx(float(naive), rel=1e-11)
            else:
                assert got < 1e-200
    # p -> 0+ limit: p0 exp(-p0/(a tau)) / (a tau)^2
    assert feller_density(0.0, 1.0, 0.5, 1.0) == pytest.approx(math.exp(-2.0) / 0.25, rel=1e-15)
    assert feller_density(-1.0, 1.0, 0.5, 1.0) == 0.0


def test_feller_pde_residual_and_boundary_flux():
    # Pr solves dPr/dtau = d^2(a p Pr)/dp^2; central differences (h = 1e-3, dtau = 1e-5) leave
    # ~1e-6 relative truncation error -> tolerance 1e-5 of max |dPr/dtau|.
    p0, tau, a = 1.0, 0.5, 1.0
    p = np.linspace(0.02, 5.0, 500)
    h, dt = 1e-3, 1e-5
    P = lambda pp, t: feller_density(pp, p0, t, a)
    lhs = (P(p, tau + dt) - P(p, tau - dt)) / (2 * dt)
    fP = lambda pp: a * pp * P(pp, tau)
    rhs = (fP(p + h) - 2 * fP(p) + fP(p - h)) / h**2
    assert np.max(np.abs(lhs - rhs)) < 1e-5 * np.max(np.abs(lhs))
    # mass leaving through p = 0 (flux d(a p Pr)/dp at 0+ = a Pr(0+)) fills the delta peak:
    # d/dtau exp(-p0/(a tau)) = a Pr(0+, tau)  (central difference in tau, rel 1e-8)
    dzw = (feller_zero_weight(p0, tau + dt, a) - feller_zero_weight(p0, tau - dt, a)) / (2 * dt)
    assert dzw == pytest.approx(a * feller_density(0.0, p0, tau, a), rel=1e-8)


def test_feller_vs_monte_carlo_sde():
    # Ito SDE dp = sqrt(2 a p) dW absorbed at 0 (the process whose law is the Feller solution),
    # 2e5 seeded paths, Milstein step p -> (sqrt p + sqrt(a/2) dW)^2 - a dt/2 (strong order 1;
    # Euler gives the same within noise), 200 steps. Measured time-step bias (100 vs 1600 steps)
    # < 1e-3, below the standard error; tolerance 5 standard errors + 1e-3.
    rng = np.random.default_rng(11)
    p0, tau, a = 1.0, 0.5, 1.0
    npath, nstep = 200_000, 200
    dt = tau / nstep
    p = np.full(npath, p0)
    idx = np.arange(npath)
    for _ in range(nstep):
        pa = p[idx]
        new = (np.sqrt(pa) + math.sqrt(a / 2) * math.sqrt(dt) * rng.standard_normal(idx.size)) ** 2 - a * dt / 2
        dead = new <= 0
        new[dead] = 0.0
        p[idx] = new
        idx = idx[~dead]
    zw = feller_zero_weight(p0, tau, a)
    zw_mc = np.mean(p == 0)
    assert zw_mc == pytest.approx(zw, abs=5 * math.sqrt(zw * (1 - zw) / npath) + 1e-3)
    for x in (0.1, 0.25, 0.5, 1.0, 2.0, 4.0):
        exact = zw + quad(lambda q: feller_density(q, p0, tau, a), 0, x, epsrel=1e-12)[0]
        emp = np.mean(p <= x)
        assert emp == pytest.approx(exact, abs=5 * math.sqrt(exact * (1 - exact) / npath) + 1e-3)
    assert p.mean() == pytest.approx(p0, abs=5 * p.std() / math.sqrt(npath) + 1e-3)
    assert p.var() == pytest.approx(2 * a * p0 * tau, rel=0.02)  # SE of a variance ~ sqrt(kurtosis/N) < 0.5 %


def test_feller_small_tau_is_gaussian():
    # for a tau << p0 the diffusivity is ~ a p0 over the peak: Pr -> Gaussian of variance 2 a p0 tau.
    # The leading correction is odd in (p - p0), of relative size ~ sqrt(a tau/p0) = 1e-3 one
    # standard deviation out (tolerance 5e-3) and vanishing at the mean, where the next order
    # is ~ a tau/p0 = 1e-6 (tolerance 1e-5). x = 2 sqrt(p p0)/(a tau) = 2e6: tests the ive form.
    p0, tau, a = 1.0, 1e-6, 1.0
    V = 2 * a * p0 * tau
    assert feller_density(p0, p0, tau, a) == pytest.approx(gaussian_density(p0, p0, V), rel=1e-5)
    for p in (p0 - math.sqrt(V), p0 + math.sqrt(V)):
        assert feller_density(p, p0, tau, a) == pytest.approx(gaussian_density(p, p0, V), rel=5e-3)


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "call,match",
    [
        (lambda: gaussian_density(0.0, 1.0, -1.0), "variance"),
        (lambda: gaussian_density(0.0, 1.0, 0.0), "variance"),
        (lambda: gaussian_density([0.0, np.nan], 1.0, 1.0), "p"),
        (lambda: mirror_gaussian_density(0.5, 1.0, -1.0), "variance"),
        (lambda: mirror_gaussian_density(0.5, -1.0, 1.0), "mean_pressure"),
        (lambda: mirror_gaussian_density(0.5, np.nan, 1.0), "mean_pressure"),
        (lambda: persson_zero_weight(1.0, -2.0), "variance"),
        (lambda: persson_contact_fraction(0.0, 2.0), "mean_pressure"),
        (lambda: mirror_gaussian_moments(1.0, np.inf), "variance"),
        (lambda: feller_density(0.5, 1.0, -1.0, 1.0), "tau"),
        (lambda: feller_density(0.5, 1.0, 1.0, 0.0), "slope"),
        (lambda: feller_zero_weight(-1.0, 1.0, 1.0), "mean_pressure"),
        (lambda: feller_moments(1.0, 1.0, np.nan), "slope"),
        (lambda: gaussian_density(0.0, "a", 1.0), "mean_pressure"),
    ],
)
def test_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# --------------------------------------------------------------------------- Feller with an affine drift (CIR)
#: (p0, tau, a, alpha, beta): exit walls (2 alpha/a < 2) with and without a restoring drift, a drift towards the
#: wall (alpha < 0), a growing drift (beta < 0), entrance walls (2 alpha/a >= 2), the boundary case 2 alpha/a = 2
CIR_CASES = [(1.0, 0.25, 1.0, 0.3, 0.0), (1.0, 0.25, 1.0, 0.5, 1.5), (0.1, 1.0, 3.0, -1.0, 0.5),
             (1.0, 0.5, 1.0, -0.8, -1.0), (0.01, 0.5, 50.0, 10.0, -2.0), (1.0, 0.25, 1.0, 2.0, 2.0),
             (1.0, 0.25, 1.0, 1.0, 0.7), (1.0, 0.25, 1.0, 3.0, 0.0)]


@pytest.mark.parametrize("p0,tau,a,alpha,beta", CIR_CASES)
def test_cir_normalization(p0, tau, a, alpha, beta):
    # the density (a Bessel function) and the zero weight (an incomplete gamma function) are independent formulas:
    # together they hold all the probability; quadrature tolerance 1e-10
    f = lambda p: cir_density(p, p0, tau, a, alpha, beta)
    scale = math.sqrt(2 * a * (p0 + abs(alpha) * tau) * tau) + a * tau
    total = _quad0inf(f, scale, p0) + cir_zero_weight(p0, tau, a, alpha, beta)
    assert total == pytest.approx(1.0, abs=1e-10)


@pytest.mark.parametrize("p0,tau,a,alpha,beta", [c for c in CIR_CASES if 2 * c[3] / c[2] < 2])
def test_cir_solves_the_equation_and_its_wall_flux_fills_the_zero_weight(p0, tau, a, alpha, beta):
    # residual of dPr/dtau = -d/dp[(alpha - beta p) Pr] + d^2(a p Pr)/dp^2 by central differences on the scale of
    # the spread, w (h = 1e-3 w, dtau = 1e-5 tau: truncation ~1e-6 relative, round-off ~1e-10; tolerance 1e-5 of
    # max |dPr/dtau|), and the flux into the wall, (a - alpha) Pr(0+) (diffusion's d(a p Pr)/dp at 0+ is
    # a Pr(0+)), equal to d zero_weight/dtau (rel 1e-6)
    w = max(p0, math.sqrt(2 * a * p0 * tau) + a * tau)
    p = np.linspace(0.02, 3.0, 400) * w
    h, dt = 1e-3 * w, 1e-5 * tau
    P = lambda pp, t: cir_density(pp, p0, t, a, alpha, beta)
    lhs = (P(p, tau + dt) - P(p, tau - dt)) / (2 * dt)
    flux = lambda pp: (alpha - beta * pp) * P(pp, tau)
    diff = lambda pp: a * pp * P(pp, tau)
    rhs = -(flux(p + h) - flux(p - h)) / (2 * h) + (diff(p + h) - 2 * diff(p) + diff(p - h)) / h**2
    assert np.max(np.abs(lhs - rhs)) < 1e-5 * np.max(np.abs(lhs))
    dzw = (cir_zero_weight(p0, tau + dt, a, alpha, beta) - cir_zero_weight(p0, tau - dt, a, alpha, beta)) / (2 * dt)
    assert dzw == pytest.approx((a - alpha) * cir_density(0.0, p0, tau, a, alpha, beta), rel=1e-6)


@pytest.mark.parametrize("p0,tau,a,alpha,beta", [c for c in CIR_CASES if 2 * c[3] / c[2] >= 2 and c[4] != 0])
def test_cir_entrance_against_the_noncentral_chi_square(p0, tau, a, alpha, beta):
    # Cox, Ingersoll and Ross: 2 k p is noncentral chi-square (scipy's ncx2, an independent implementation), and
    # the mean is p0 exp(-beta tau) + (alpha/beta)(1 - exp(-beta tau)); nothing is absorbed
    from scipy.stats import ncx2

    k = beta / (a * (1 - math.exp(-beta * tau)))
    law = ncx2(df=2 * alpha / a, nc=2 * k * p0 * math.exp(-beta * tau))
    f = lambda p: cir_density(p, p0, tau, a, alpha, beta)
    for x in (0.1, 0.5, 1.0, 2.0):
        assert quad(f, 0.0, x * p0, epsabs=1e-14, limit=200)[0] == pytest.approx(law.cdf(2 * k * x * p0), abs=1e-12)
    scale = math.sqrt(2 * a * p0 * tau) + a * tau
    mean = p0 * math.exp(-beta * tau) + alpha / beta * (1 - math.exp(-beta * tau))
    assert _quad0inf(lambda p: p * f(p), scale, p0) == pytest.approx(mean, rel=1e-9)
    assert cir_zero_weight(p0, tau, a, alpha, beta) == 0.0 and (f(0.0) == 0.0 or alpha == a)  # I_0(0) = 1


def test_cir_limits():
    # alpha = beta = 0 is Feller's solution (round-off); beta -> 0 is continuous (exprel's clock; 1e-9 relative)
    p = np.linspace(0.0, 4.0, 81)
    assert np.allclose(cir_density(p, 1.0, 0.3, 2.0), feller_density(p, 1.0, 0.3, 2.0), rtol=1e-13, atol=0)
    assert cir_zero_weight(1.0, 0.3, 2.0) == pytest.approx(feller_zero_weight(1.0, 0.3, 2.0), rel=1e-14)
    for alpha in (0.4, 3.0):
        near = cir_density(p[1:], 1.0, 0.3, 2.0, alpha, 1e-12)
        assert np.allclose(near, cir_density(p[1:], 1.0, 0.3, 2.0, alpha, 0.0), rtol=1e-9, atol=0)
    assert cir_density(-1.0, 1.0, 0.3, 2.0, 0.4, 1.0) == 0.0


@pytest.mark.parametrize("kw, name", [(dict(slope=0.0), "slope"), (dict(drift_at_wall=float("nan")), "drift_at_wall"),
                                      (dict(restoring_rate=float("inf")), "restoring_rate"),
                                      (dict(restoring_rate=1e4), "restoring_rate"), (dict(tau=-1.0), "tau")])
def test_cir_bad_input(kw, name):
    args = dict(mean_pressure=1.0, tau=0.5, slope=1.0, drift_at_wall=0.2, restoring_rate=0.0)
    args.update(kw)
    for fun in (cir_zero_weight, lambda **k: cir_density(0.5, **k)):
        with pytest.raises(ValueError, match=name):
            fun(**args)


# --------------------------------------------------------------------------- the mirror Gaussian with a constant drift
#: (p0, V, S): towards the wall (S < 0: by 5 spreads, then one that empties the contact), none, away from it
DRIFTED_CASES = [(1.0, 0.01, -0.5), (0.3, 1.0, -2.0), (1.0, 1.5, 0.0), (0.1, 1.0, 5.0), (2.0, 0.5, -40.0)]


@pytest.mark.parametrize("p0,V,S", DRIFTED_CASES)
def test_drifted_mirror_normalization_and_limit(p0, V, S):
    # the density and the weight are separate formulas (images, and the hitting law of Brownian motion with drift):
    # together they hold all the probability (quadrature 1e-10); S = 0 is Persson's mirror Gaussian exactly
    f = lambda p: drifted_mirror_gaussian_density(p, p0, V, S)
    total = _quad0inf(f, math.sqrt(V), max(p0 + S, 1e-3 * p0)) + drifted_mirror_gaussian_zero_weight(p0, V, S)
    assert total == pytest.approx(1.0, abs=1e-10)
    p = np.linspace(-0.5, 4.0, 91)
    if S == 0.0:
        assert np.array_equal(drifted_mirror_gaussian_density(p, p0, V, S), mirror_gaussian_density(p, p0, V))
        assert drifted_mirror_gaussian_zero_weight(p0, V, S) == pytest.approx(persson_zero_weight(p0, V), rel=1e-13)
    assert np.all(drifted_mirror_gaussian_density(p[p <= 0], p0, V, S) == 0.0)


def test_drifted_mirror_solves_the_equation_and_its_wall_flux_fills_the_zero_weight():
    # dPr/dtau = d^2 Pr/dp^2 - a dPr/dp at V = 2 tau, S = a tau, by central differences (h = 1e-4, dtau = 1e-5 tau;
    # truncation ~1e-7 relative, tolerance 1e-5 of max |dPr/dtau|); the flux into the wall, dPr/dp at 0+ (the density
    # vanishes there, so the drift carries nothing), equals d zero_weight/dtau (rel 1e-6)
    a, p0, tau = -3.0, 0.7, 0.1
    P = lambda x, t: drifted_mirror_gaussian_density(x, p0, 2 * t, a * t)
    p = np.linspace(0.01, 2.0, 300)
    h, dt = 1e-4, 1e-5 * tau
    lhs = (P(p, tau + dt) - P(p, tau - dt)) / (2 * dt)
    rhs = (P(p + h, tau) - 2 * P(p, tau) + P(p - h, tau)) / h**2 - a * (P(p + h, tau) - P(p - h, tau)) / (2 * h)
    assert np.max(np.abs(lhs - rhs)) < 1e-5 * np.max(np.abs(lhs))
    zw = lambda t: drifted_mirror_gaussian_zero_weight(p0, 2 * t, a * t)
    dzw = (zw(tau + dt) - zw(tau - dt)) / (2 * dt)
    wall_flux = (4 * P(h, tau) - P(2 * h, tau)) / (2 * h)  # one-sided, second order (P(0) = 0)
    assert dzw == pytest.approx(wall_flux, rel=1e-6)


def test_drifted_mirror_strong_drift_to_the_wall_has_no_overflow():
    # exp(-2 S p0 / V) = exp(3200) alone overflows; in logarithms the weight is 1 to round-off and the density tiny
    assert drifted_mirror_gaussian_zero_weight(2.0, 0.005, -4.0) == pytest.approx(1.0, abs=1e-15)
    assert np.all(np.isfinite(drifted_mirror_gaussian_density(np.linspace(0, 3, 31), 2.0, 0.005, -4.0)))


@pytest.mark.parametrize("kw, name", [(dict(drift_shift=float("nan")), "drift_shift"),
                                      (dict(variance=0.0), "variance"), (dict(mean_pressure=-1.0), "mean_pressure")])
def test_drifted_mirror_bad_input(kw, name):
    args = dict(mean_pressure=1.0, variance=0.5, drift_shift=-0.2)
    args.update(kw)
    for fun in (drifted_mirror_gaussian_zero_weight, lambda **k: drifted_mirror_gaussian_density(0.5, **k)):
        with pytest.raises(ValueError, match=name):
            fun(**args)


# ----------------------------------------------------------------------------- fitted hard-wall corrections
@pytest.mark.parametrize("p0", [1e-3, 0.02, 0.5, 3.0])
@pytest.mark.parametrize("gamma", [0.45, 5.0 / 9.0, 0.9])
def test_persson_corrected_variance_against_the_ode(p0, gamma):
    """Oracle: the re-timing ODE ``d tau_eff/d tau = gamma + (1 - gamma) erf(p0/(2 sqrt(tau_eff)))^2`` integrated
    forward by DOP853 (rtol 1e-12); the closed form inverts the quadrature instead.  Measured agreement 1e-12; the
    bar 1e-8 is the ODE's tolerance with room for its start at tau_eff = 1e-300."""
    from scipy.integrate import solve_ivp
    from scipy.special import erf

    from diffusion_pr.closed_forms import persson_corrected_variance

    V = 0.7
    sol = solve_ivp(lambda t, y: [gamma + (1 - gamma) * erf(p0 / (2 * np.sqrt(max(y[0], 1e-300)))) ** 2],
                    (0.0, V / 2), [1e-300], method="DOP853", rtol=1e-12, atol=1e-20)
    v_eff = persson_corrected_variance(p0, V, gamma)
    assert v_eff == pytest.approx(2 * sol.y[0, -1], rel=1e-8)
    assert gamma * V <= v_eff <= V


def test_persson_corrected_variance_limits_and_bad_input():
    """gamma = 1 is Persson (V itself); at a vanishing load the area stays small all along, so V_eff -> gamma V
    (to first order in p0/sqrt(V): 0.45001 at p0 = 1e-3 sqrt(V))."""
    from diffusion_pr.closed_forms import persson_corrected_variance

    assert persson_corrected_variance(0.3, 2.0, 1.0) == 2.0
    assert persson_corrected_variance(1e-6, 1.0, 0.45) == pytest.approx(0.45, rel=1e-4)
    for gamma in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="gamma"):
            persson_corrected_variance(0.3, 1.0, gamma)


@pytest.mark.parametrize("p0", [1e-4, 0.02, 0.5, 1.0, 3.0])
def test_sum_rule_variance_against_the_retiming_ode(p0):
    """Oracle: the sum rule Var(p) = a_r(T) V held at every V, integrated forward as the ODE
    dT/dV = 1 / (1 + V |d ln a_r/dT|) (LSODA, rtol 1e-11) from full contact; the closed form solves the end point
    instead.  Both: the mirror Gaussian of variance T has the pressure variance a_r V (closed-form moments, 1e-12),
    T between V/2 and V.  Measured agreement 1e-9; bar 1e-7 (the ODE's start at V = 1e-12 V0)."""
    from scipy.integrate import solve_ivp
    from scipy.special import erf

    from diffusion_pr.closed_forms import mirror_gaussian_moments, sum_rule_variance

    V = 1.0

    def dlna(T):
        z = p0 / np.sqrt(2 * T)
        return (2 / np.sqrt(np.pi)) * np.exp(-z * z) * z / (2 * T) / erf(z)

    v1 = 1e-12 * V
    ode = solve_ivp(lambda v, y: [1 / (1 + v * dlna(y[0]))], (v1, V), [v1], method="LSODA", rtol=1e-11,
                    atol=1e-14 * V)
    T = sum_rule_variance(p0, V)
    assert T == pytest.approx(ode.y[0, -1], rel=1e-7)
    moments = mirror_gaussian_moments(p0, T)
    assert moments.variance == pytest.approx(erf(p0 / np.sqrt(2 * T)) * V, rel=1e-12)
    assert 0.5 * V <= T <= V


def test_sum_rule_limits():
    """Small loads: T -> V/2, so a_r -> 4/sqrt(pi) p0/(E* gbar) (kappa 2.257 against Persson's sqrt(8/pi));
    full contact: T -> V (Persson)."""
    from diffusion_pr.closed_forms import sum_rule_variance

    assert sum_rule_variance(1e-7, 1.0) == pytest.approx(0.5, rel=1e-6)
    assert sum_rule_variance(10.0, 1.0) == pytest.approx(1.0, rel=1e-12)
    E_star, gbar, p0 = 1.0, 0.1, 1e-6
    V = (E_star * gbar / 2) ** 2
    a_r = math.erf(p0 / math.sqrt(2 * sum_rule_variance(p0, V)))
    assert a_r / (p0 / (E_star * gbar)) == pytest.approx(4 / math.sqrt(math.pi), rel=1e-5)
