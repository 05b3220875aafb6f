"""The exponential wall's fused kernels against the numpy formulas and kernels they replace."""
from __future__ import annotations

import numpy as np
import pytest

from gfmd_ref.solvers import _kernels as kr


@pytest.fixture
def fields(rng):
    n = 64
    u = rng.normal(scale=0.3, size=(n, n))
    h = rng.normal(scale=0.3, size=(n, n))
    p = 0.004 * np.exp(rng.normal(scale=0.5, size=(n, n)))
    return u, h, p


def _log_mean_exp(u, h, zeta):
    x = -(u - h) / zeta
    return zeta * (x.max() + np.log(np.mean(np.exp(x - x.max()))))


@pytest.mark.parametrize("zeta", [1.0, 0.01, 1e-4])
def test_z0_residual_is_the_two_kernels_it_fuses(fields, zeta):
    """``newton.z0_residual`` (numpy's exponentials between two kernels) against numpy's
    log-sum-exp ``zeta log(mean(exp(-(u - h)/zeta)))`` (z0: relative 1e-14 after the
    logarithm) and the residual's formula in numpy,
    ``max |p0 exp(-(z0 + u - h)/zeta) - p| / p0`` (exponentials of a differently rounded exponent: both err by a few eps times the
    largest exponent |u - h|/zeta, which is 1e4 at zeta = 1e-4, where measured 1.7e-12
    apart; the bound asserted is 8 eps times it)."""
    from gfmd_ref.solvers.newton import z0_residual as _z0_residual

    u, h, p = fields
    z0, res = _z0_residual(u, h, p, 0.004, zeta, np.empty_like(u))
    assert z0 == pytest.approx(_log_mean_exp(u, h, zeta), rel=1e-14)
    bound = max(1e-13, 8 * np.finfo(float).eps * np.max(np.abs(u - h)) / zeta)
    with np.errstate(under="ignore"):
        want = np.max(np.abs(0.004 * np.exp(-(z0 + u - h) / zeta) - p)) / 0.004
    assert res == pytest.approx(want, rel=bound)


def test_masked_exponentials_are_numpys_bit_for_bit(rng):
    """``exp_exponents`` skips the exponentials that round to ``+0`` (exponents below
    ``EXP_ZERO = -746``; the C library's underflow path is slow) and numpy takes the
    rest with ``where=``. Oracle: numpy's exponential of every exponent ``x - m`` with no
    mask, bit for bit, on exponents spread over [-800, 0] so that subnormal results
    (-745 ... -708), zeros and ordinary values all occur; then ``_z0_residual``'s
    ``(z0, residual)`` against the same computed unmasked. A NaN exponent stays NaN. A
    threshold inside the subnormal range (e.g. -700) zeroes values that are not zero and
    fails."""
    from gfmd_ref.solvers.newton import z0_residual as _z0_residual

    n = 64
    zeta = 1.0
    h = np.zeros((n, n))
    u = rng.uniform(0.0, 800.0, size=(n, n))
    u.flat[0] = 0.0  # the largest exponent is 0, so e = x spans [-800, 0]
    e = np.empty((n, n))
    keep = np.empty((n, n), dtype=np.bool_)
    m = kr.exp_exponents(u, h, zeta, e, keep)
    np.exp(e, out=e, where=keep)
    want = np.exp(-(u - h) / zeta - m)
    assert m == 0.0
    assert np.array_equal(e.view(np.int64), want.view(np.int64))
    assert 0 < np.count_nonzero(~keep) < n * n and np.any((want > 0) & (want < np.finfo(float).tiny))
    p = 0.004 * np.exp(rng.normal(size=(n, n)))
    z0, res = _z0_residual(u, h, p, 0.004, zeta, np.empty_like(u))
    s = float(np.sum(want))  # numpy sums pairwise, the kernel in index order: round-off apart
    assert z0 == pytest.approx(zeta * (m + np.log(s / u.size)), rel=1e-15)
    assert res == pytest.approx(np.max(np.abs(0.004 * want * u.size / s - p)) / 0.004, rel=1e-13)
    u.flat[5] = np.nan
    kr.exp_exponents(u, h, zeta, e, keep)
    assert keep.flat[5] and np.isnan(e.flat[5])


def test_z0_residual_at_the_solution_is_zero(fields):
    """At ``p = p0 exp(-(z0 + u - h)/zeta)`` (the wall law itself) the residual is round-off."""
    from gfmd_ref.solvers.newton import z0_residual as _z0_residual

    u, h, _ = fields
    zeta = 0.3
    z0 = _log_mean_exp(u, h, zeta)
    p = 0.004 * np.exp(-(z0 + u - h) / zeta)
    _, res = _z0_residual(u, h, p, 0.004, zeta, np.empty_like(u))
    assert res < 1e-13 * np.max(p) / 0.004


def test_dual_energy_and_its_scale(fields):
    """The energy kernel returns mean(p u/2 - p h + zeta p ln(p/p0)) (numpy, 1e-13) and
    the mean magnitude of those terms (the scale of its round-off), the same with and
    without ``grad``; with it, it also writes u - h + zeta (ln(p/p0) + 1)."""
    u, h, p = fields
    zeta, p0 = 0.2, 0.004
    t = np.stack([0.5 * p * u, -p * h, zeta * p * np.log(p / p0)])
    grad = np.empty_like(u)
    lp = np.log(p / p0)
    e1, s1 = kr.dual_energy(u, h, p, lp, zeta, grad)
    e2, s2 = kr.dual_energy(u, h, p, lp, zeta)
    assert e1 == e2 and s1 == s2
    assert e1 == pytest.approx(np.mean(np.sum(t, axis=0)), rel=1e-12, abs=1e-15 * s1)
    assert s1 == pytest.approx(np.mean(np.sum(np.abs(t), axis=0)), rel=1e-13)
    assert np.allclose(grad, u - h + zeta * (np.log(p / p0) + 1.0), rtol=1e-14, atol=1e-15)


def test_newton_cg_passes_are_the_projected_pcg_update(fields, rng):
    """``ncg_update``, ``ncg_shift`` and ``ncg_direction`` against the numpy update of the
    projected PCG they fuse: x += a d, r -= a (Gd + w d), the shift r -= (minv.r)/sum minv,
    r.z with z = minv r, the predicted residual max |p (r - sum p r / sum p)|, and
    d = z + beta d with sum w d^2 (1e-12: round-off of sums of 4096 terms)."""
    u, h, p = fields
    x, r, d, gd = (rng.normal(size=u.shape) for _ in range(4))
    w = 0.01 / p
    minv = 1.0 / (0.5 + w)
    a, beta = 0.7, 0.3
    x0, r0, d0 = x.copy(), r.copy(), d.copy()
    sm, sp = kr.ncg_update(x, r, d, gd, w, minv, p, a)
    r1 = r0 - a * (gd + w * d0)
    assert np.allclose(x, x0 + a * d0, rtol=1e-15, atol=1e-15) and np.allclose(r, r1, rtol=1e-15, atol=1e-15)
    assert sm == pytest.approx(np.sum(minv * r1), rel=1e-12) and sp == pytest.approx(np.sum(p * r1), rel=1e-12)
    c, cp = sm / np.sum(minv), sp / np.sum(p)
    rz, pred = kr.ncg_shift(r, minv, p, c, cp)
    r2 = r1 - c
    assert np.allclose(r, r2, rtol=1e-14, atol=1e-14)
    assert rz == pytest.approx(np.sum(r2 * minv * r2), rel=1e-12)
    assert pred == pytest.approx(np.max(np.abs(p * (r1 - cp))), rel=1e-12)
    dwd = kr.ncg_direction(d, r, minv, w, beta, d)
    d1 = minv * r2 + beta * d0
    assert np.allclose(d, d1, rtol=1e-14, atol=1e-15)
    assert dwd == pytest.approx(np.sum(w * d1 * d1), rel=1e-12)
