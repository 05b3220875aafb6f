"""Tests of diffusion_pr.cumulants (G1, stress variance, V(eta), D(eta)).

Oracles: the SPEC's printed numbers for the Fig. 1 system, scipy quad of the
integrals written out here, the real-space variance of a stress field built
mode by mode with numpy FFTs, finite differences, and limits (zeta -> 0,
zeta -> infinity).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import erf

from diffusion_pr.cumulants import G1, diffusivity_vs_magnification, stress_variance, variance_vs_magnification
from diffusion_pr.spectra import DiscreteSpectrum, SelfAffineSpectrum

E_STAR = 8.0 / 3.0
P0 = 0.004
QL = 2 * math.pi / 1024
QS = 2 * math.pi / 32


def fig1() -> SelfAffineSpectrum:
    return SelfAffineSpectrum(0.3, QL, QS, rms_slope=0.031)


def quad_variance(s: SelfAffineSpectrum, zeta: float, E=E_STAR, p0=P0, upper=None) -> float:
    """(E*/2)^2 2 pi int q^3 C |G1|^2 dq by adaptive quad in ln q, G1 written out here."""
    upper = s.q_max if upper is None else min(upper, s.q_max)

    def f(t):
        q = math.exp(t)
        g = 1.0 / (1.0 + zeta * q * E / (2 * p0))
        return (E / 2) ** 2 * 2 * math.pi * q**4 * float(s.psd(q)) * g * g

    total = 0.0
    for lo, hi in ((s.q_min, min(s.q_roll, upper)), (s.q_roll, upper)):
        if hi > lo:
            total += quad(f, math.log(lo), math.log(hi), epsabs=0.0, epsrel=1e-13, limit=500)[0]
    return total


def random_surface(rng, n, length, psd):
    """Real periodic surface with <|h~|^2> = C(2 pi/L)^2 (plain numpy, paper's 1/A transform)."""
    noise = np.fft.fft2(rng.standard_normal((n, n))) / n
    k = np.fft.fftfreq(n, d=1.0 / n)
    qabs = 2 * np.pi / length * np.hypot(k[:, None], k[None, :])
    ht = noise * np.sqrt(psd(qabs)) * (2 * np.pi / length)
    ht[0, 0] = 0.0
    return np.fft.ifft2(ht * n * n).real


# --------------------------------------------------------------------------- SPEC numbers
def test_spec_fig1_numbers():
    # SPEC section 3 prints sqrt(V0) = 0.041333 and Persson a_r = 0.07709 (5-6 digits):
    # check to half a unit in the last printed digit.
    s = fig1()
    V0 = stress_variance(s, E_star=E_STAR, mean_pressure=P0)
    assert isinstance(V0, float)
    assert math.sqrt(V0) == pytest.approx(0.041333, abs=5e-7)
    assert erf(P0 / math.sqrt(2 * V0)) == pytest.approx(0.07709, abs=5e-6)
    # and exactly Persson's V0 = (E*/2)^2 gbar^2 (closed form; round-off tolerance)
    assert V0 == pytest.approx((E_STAR / 2) ** 2 * 0.031**2, rel=1e-12)


# --------------------------------------------------------------------------- G1
def test_G1_values_and_broadcast():
    # Eq. 10 written out: zeta q E*/(2 p0) = 1 -> G1 = 1/2
    q = 2 * P0 / (0.5 * E_STAR)
    assert G1(q, zeta=0.5, E_star=E_STAR, mean_pressure=P0) == pytest.approx(0.5, rel=1e-15)
    assert G1(1.0, zeta=0.0, E_star=E_STAR, mean_pressure=P0) == 1.0
    g = G1(np.array([0.1, 1.0]), zeta=np.array([[0.0], [1.0]]), E_star=2.0, mean_pressure=1.0)
    np.testing.assert_allclose(g, [[1.0, 1.0], [1 / 1.1, 0.5]], rtol=1e-15)
    with pytest.raises(ValueError, match="zeta"):
        G1(1.0, zeta=-1.0, E_star=1.0, mean_pressure=1.0)
    with pytest.raises(ValueError, match="q"):
        G1(-1.0, zeta=1.0, E_star=1.0, mean_pressure=1.0)


# --------------------------------------------------------------------------- continuum V(zeta)
@pytest.mark.parametrize(
    "H,qmin,qmax,qr",
    [(0.3, QL, QS, QL), (0.1, 1e-3, 10.0, 1e-3), (0.9, 1e-4, 1.0, 1e-4), (0.9, 1e-2, 1e2, 0.1), (0.5, 0.1, 0.2, 0.15)],
)
def test_stress_variance_against_quad(H, qmin, qmax, qr):
    # Gauss-Legendre in ln q vs adaptive quad (epsrel 1e-13): 1e-10 relative; zeta 1e-4..10
    s = SelfAffineSpectrum(H, qmin, qmax, rms_slope=0.05, q_roll=qr)
    zetas = np.array([0.0, 1e-4, 1e-3, 0.01, 0.25, 1.0, 4.0, 10.0])
    v = stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=zetas)
    ref = [quad_variance(s, z) for z in zetas]
    np.testing.assert_allclose(v, ref, rtol=1e-10, atol=0)


def test_stress_variance_vectorized_shapes():
    s = fig1()
    z = np.geomspace(1e-4, 10, 12).reshape(3, 4)
    v = stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=z)
    assert v.shape == (3, 4)
    loop = np.array([stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=float(x)) for x in z.ravel()])
    np.testing.assert_allclose(v.ravel(), loop, rtol=1e-14)
    assert stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=[0.1]).shape == (1,)


def test_zeta_limits_and_monotonicity():
    s = fig1()
    V0 = (E_STAR / 2) ** 2 * s.mean_square_gradient
    # zeta -> 0: V -> V0 with relative deficit ~ 2 zeta <q E*/(2 p0)> (first order), here ~1e-8
    assert stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=1e-12) == pytest.approx(V0, rel=1e-8)
    z = np.geomspace(1e-6, 1e3, 200)
    v = stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=z)
    assert np.all(np.diff(v) < 0)
    # zeta -> inf: G1 -> 2 p0/(zeta q E*), V -> p0^2 h_rms^2 / zeta^2; the relative correction
    # is ~ -4 p0/(zeta q E*) <= 4 p0/(zeta q_min E*) ~ 1e-4 at zeta = 1e4 -> tolerance 3e-4
    zb = 1e4
    vb = stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=zb)
    assert vb * zb**2 == pytest.approx(P0**2 * s.h_rms**2, rel=3e-4)
    assert vb * zb**2 < P0**2 * s.h_rms**2


# --------------------------------------------------------------------------- discrete
def test_discrete_stress_variance_equals_real_space_stress(rng):
    # Build sigma(r) mode by mode: sigma~(q) = (|q| E*/2) G1(q) h~(q) (Eqs. 3, 10), back to real
    # space, and take its variance: Parseval makes it equal to the package's sum (round-off).
    n, L = 256, 256.0
    cont = SelfAffineSpectrum(0.3, 2 * np.pi / L, 2 * np.pi / 8, rms_slope=0.031)
    h = random_surface(rng, n, L, cont.psd)
    d = DiscreteSpectrum.from_heights(h, L)
    k = np.fft.fftfreq(n, d=1.0 / n)
    qa = 2 * np.pi / L * np.hypot(k[:, None], k[None, :])
    zetas = np.array([0.0, 0.001, 0.01, 0.25, 4.0])
    v = stress_variance(d, E_star=E_STAR, mean_pressure=P0, zeta=zetas)
    for z, vz in zip(zetas, v):
        g1 = 1.0 / (1.0 + z * qa * E_STAR / (2 * P0))
        sig = np.fft.ifft2(np.fft.fft2(h) * qa * E_STAR / 2 * g1).real
        assert vz == pytest.approx(sig.var(), rel=1e-10)
    # one realization scatters around the continuum; the full lattice sum of the continuum
    # PSD is the ensemble mean. 256^2 modes with |q| <= 2 pi/8: a few % scatter at most.
    v_cont = stress_variance(cont, E_star=E_STAR, mean_pressure=P0, zeta=zetas)
    np.testing.assert_allclose(v, v_cont, rtol=0.1)


def test_discrete_V_and_binned_D(rng):
    n, L = 64, 64.0
    cont = SelfAffineSpectrum(0.5, 2 * np.pi / L, 2 * np.pi / 4, rms_slope=0.1)
    d = DiscreteSpectrum.from_heights(random_surface(rng, n, L, cont.psd), L)
    kw = dict(E_star=E_STAR, mean_pressure=P0, zeta=0.05)
    # staircase V(eta): direct sum over shells with |q| <= eta q_min, G1 written out here
    qs, pw = d.q, d.power
    g = 1.0 / (1.0 + 0.05 * qs * E_STAR / (2 * P0))
    terms = (E_STAR / 2) ** 2 * qs**2 * g**2 * pw
    eta = np.array([0.5, 1.0, 1.2, 3.0, 7.9, 100.0])
    expect = [terms[qs <= e * d.q_min * (1 + 1e-14)].sum() for e in eta]
    np.testing.assert_allclose(variance_vs_magnification(d, eta, **kw), expect, rtol=1e-12, atol=0)
    vtot = stress_variance(d, **kw)
    assert variance_vs_magnification(d, d.q_max / d.q_min, **kw) == pytest.approx(vtot, rel=1e-13)
    # binned D: piecewise constant on unit bins, integral over all bins = V/2 exactly
    edges = np.arange(0.5, d.q_max / d.q_min + 1.0, 1.0)
    mids = 0.5 * (edges[1:] + edges[:-1])
    D = diffusivity_vs_magnification(d, mids, **kw)
    assert np.sum(D * np.diff(edges)) == pytest.approx(vtot / 2, rel=1e-12)
    assert diffusivity_vs_magnification(d, edges[-1] + 0.1, **kw) == 0.0
    # custom bins
    b = np.array([0.0, 2.0, 100.0])
    Db = diffusivity_vs_magnification(d, [1.0, 50.0], bins=b, **kw)
    assert Db[0] * 2.0 + Db[1] * 98.0 == pytest.approx(vtot / 2, rel=1e-12)


# --------------------------------------------------------------------------- V(eta), D(eta)
@pytest.mark.parametrize("zeta", [0.0, 0.01, 0.25, 4.0])
def test_variance_vs_magnification_against_quad(zeta):
    s = SelfAffineSpectrum(0.3, QL, QS, rms_slope=0.031, q_roll=4 * QL)
    eta = np.array([0.2, 1.0, 2.0, 4.0, 5.5, 17.0, 32.0, 50.0])
    _check_V_eta(s, eta, zeta)


@pytest.mark.parametrize("H", [0.1, 0.9])
def test_variance_vs_magnification_wide_range(H):
    # magnification 1e4 (the hard-case range), zeta 1e-4 and 10
    s = SelfAffineSpectrum(H, 1e-4, 1.0, rms_slope=0.1)
    eta = np.array([1.0, 3.0, 100.0, 2e3, 1e4])
    for zeta in (1e-4, 10.0):
        _check_V_eta(s, eta, zeta)


def _check_V_eta(s, eta, zeta):
    v = variance_vs_magnification(s, eta, E_star=E_STAR, mean_pressure=P0, zeta=zeta)
    ref = [quad_variance(s, zeta, upper=e * s.q_min) if e > 1 else 0.0 for e in eta]
    np.testing.assert_allclose(v, ref, rtol=1e-10, atol=0)
    assert v[-1] == pytest.approx(stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=zeta), rel=1e-12)


@pytest.mark.parametrize("zeta", [0.0, 0.25])
def test_diffusivity_is_half_derivative_of_variance(zeta):
    s = SelfAffineSpectrum(0.3, QL, QS, rms_slope=0.031, q_roll=4 * QL)
    kw = dict(E_star=E_STAR, mean_pressure=P0, zeta=zeta)
    eta = np.array([1.5, 3.0, 6.0, 20.0, 31.0])
    D = diffusivity_vs_magnification(s, eta, **kw)
    # central finite difference of V (step 1e-4, smooth away from eta = 4 and 32): O(h^2) ~ 1e-8
    hstep = 1e-4
    fd = (variance_vs_magnification(s, eta + hstep, **kw) - variance_vs_magnification(s, eta - hstep, **kw)) / (2 * hstep)
    np.testing.assert_allclose(D, 0.5 * fd, rtol=1e-6)
    # integral of 2 D over [1, eta_max] is the total variance (quad, split at the roll-off)
    f = lambda e: diffusivity_vs_magnification(s, e, **kw)
    total = 2 * (quad(f, 1, 4, epsrel=1e-12)[0] + quad(f, 4, 32, epsrel=1e-12)[0])
    assert total == pytest.approx(stress_variance(s, **kw), rel=1e-9)
    assert diffusivity_vs_magnification(s, [0.5, 33.0], **kw).tolist() == [0.0, 0.0]
    with pytest.raises(ValueError, match="bins"):
        diffusivity_vs_magnification(s, 2.0, bins=[1, 2, 3], **kw)


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(E_star=0.0, mean_pressure=P0), "E_star"),
        (dict(E_star=-1.0, mean_pressure=P0), "E_star"),
        (dict(E_star=E_STAR, mean_pressure=0.0), "mean_pressure"),
        (dict(E_star=E_STAR, mean_pressure=float("nan")), "mean_pressure"),
        (dict(E_star=E_STAR, mean_pressure=P0, zeta=-0.1), "zeta"),
        (dict(E_star=E_STAR, mean_pressure=P0, zeta=[0.1, float("inf")]), "zeta"),
        (dict(E_star=E_STAR, mean_pressure=P0, zeta=float("nan")), "zeta"),
    ],
)
def test_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        stress_variance(fig1(), **kwargs)


def test_bad_spectrum_and_zeta_array():
    with pytest.raises(ValueError, match="spectrum"):
        stress_variance(np.ones(3), E_star=1.0, mean_pressure=1.0)
    with pytest.raises(ValueError, match="zeta"):
        variance_vs_magnification(fig1(), 2.0, E_star=1.0, mean_pressure=1.0, zeta=[0.1, 0.2])
    with pytest.raises(ValueError, match="eta"):
        diffusivity_vs_magnification(fig1(), [1.0, np.nan], E_star=1.0, mean_pressure=1.0)
