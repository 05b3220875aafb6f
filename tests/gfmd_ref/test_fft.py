"""The planned-FFTW path and the scipy path compute the same transforms."""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import gfmd_ref
from gfmd_ref import ConvergenceWarning, ExponentialRepulsion, HardWall, fig1_surface, solve_contact
from gfmd_ref._fft import FFTWPair, ScipyPair, fft_pair

pyfftw = pytest.importorskip("pyfftw", reason="pyfftw not installed: scipy.fft is used everywhere")


def test_fftw_pair_matches_scipy(rng):
    shape = (256, 256)
    x = rng.normal(size=shape)
    mult = rng.normal(size=(256, 129))
    a, b = FFTWPair(shape, threads=2), ScipyPair(shape)
    # both are exact transforms in double precision; round-off ~ 1e-15 * log2(n) * |x|
    X = a.rfft(x)
    assert np.max(np.abs(X - b.rfft(x))) < 1e-10
    assert np.max(np.abs(a.irfft(X) - x)) < 1e-12
    assert np.max(np.abs(a.apply(mult, x) - b.apply(mult, x))) < 1e-12
    # results are fresh arrays, not views of the plan's buffers
    y = a.rfft(x)
    a.rfft(2 * x)
    assert np.max(np.abs(y - X)) == 0.0


def test_cached_plan_costs_nothing_the_second_time():
    _, first = fft_pair((256, 256))
    pair, second = fft_pair((256, 256))
    assert second == 0.0 and pair.name == "fftw"


def test_solver_gives_the_same_answer_with_either_fft(monkeypatch):
    h, length = fig1_surface(256, seed=3)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-9)
    fast = solve_contact(h, **kw)
    monkeypatch.setenv("GFMD_REF_FFT", "scipy")
    monkeypatch.setattr("gfmd_ref._fft._LOCAL", threading.local())
    slow = solve_contact(h, **kw)
    assert fast.info["fft"] == "fftw" and slow.info["fft"] == "scipy"
    # both converge to 1e-9 p0; the pressure fields agree to that level and the
    # contact sets are identical
    assert np.max(np.abs(fast.pressure - slow.pressure)) < 1e-7 * 0.004
    assert fast.contact_fraction == slow.contact_fraction


@pytest.mark.parametrize("shape", [(6, 8), (7, 9), (256, 256)])
def test_spectral_multiply_dot_is_the_real_space_dot(rng, shape):
    """Parseval: the dot product the spectral multiply returns is sum x y for
    y = irfft2(mult X) n^2, on even and odd last axes (the Nyquist column has
    weight 1 only when it exists). Oracle: the real-space sum with numpy's FFT;
    both are round-off of a sum of ~n^2 terms, assert 1e-12 relative."""
    from gfmd_ref._kernels import spectral_multiply

    x = rng.normal(size=shape)
    X = np.fft.rfft2(x)
    mult = rng.random(X.shape)
    y = np.fft.irfft2(mult * X, s=shape) * x.size
    X2 = X.copy()
    dot = spectral_multiply(X2, mult, shape[1])
    assert np.max(np.abs(X2 - mult * X)) <= 1e-14 * np.max(np.abs(X))
    assert dot == pytest.approx(np.sum(x * y), rel=1e-12)


@pytest.mark.parametrize("dtype", [np.complex128, np.complex64])
def test_spectral_scale_and_multiply_are_numpys_product(rng, dtype):
    """Both multiply kernels write numpy's ``spec * mult`` bit for bit (they spell the
    complex-by-real product out in real arithmetic), in double and single precision."""
    from gfmd_ref._kernels import spectral_multiply, spectral_scale

    real = np.float64 if dtype == np.complex128 else np.float32
    X = (rng.normal(size=(64, 33)) + 1j * rng.normal(size=(64, 33))).astype(dtype)
    mult = rng.random((64, 33)).astype(real)
    a, b = X.copy(), X.copy()
    spectral_scale(a, mult)
    spectral_multiply(b, mult, 64)
    assert np.array_equal(a, X * mult) and np.array_equal(b, X * mult)


@pytest.mark.parametrize("make", [lambda s: FFTWPair(s), lambda s: ScipyPair(s)])
def test_apply_route_keeps_its_input_and_returns_the_dot(rng, make):
    """A route between two work arrays leaves the source as it was, a route onto the
    same array transforms it in place, and both return src . dst (Parseval). Oracle:
    numpy's FFT; round-off, assert 1e-12."""
    shape = (256, 256)
    pair = make(shape)
    src, dst = pair.work_array(0), pair.work_array(1)
    x = rng.normal(size=shape)
    mult = rng.random((256, 129))
    want = np.fft.irfft2(mult * np.fft.rfft2(x), s=shape)
    src[...] = x
    dot = pair.apply_route(mult / x.size, src, dst)
    assert np.array_equal(src, x)
    assert np.max(np.abs(dst - want)) < 1e-12 * np.max(np.abs(want))
    assert dot == pytest.approx(np.sum(x * want), rel=1e-12)
    dot2 = pair.apply_route(mult / x.size, src, src)
    assert np.max(np.abs(src - want)) < 1e-12 * np.max(np.abs(want)) and dot2 == pytest.approx(dot, rel=1e-12)
    assert pair.work_array(0) is src  # made once, then reused
    src[...] = x
    nodot = pair.apply_route(mult / x.size, src, dst, dot=False)  # the same field, no dot
    assert np.isnan(nodot) and np.array_equal(src, x)
    assert np.max(np.abs(dst - want)) < 1e-12 * np.max(np.abs(want))


def test_apply_route_refuses_a_foreign_array():
    pair = FFTWPair((256, 256))
    with pytest.raises(ValueError, match="work_array"):
        pair.apply_route(np.ones((256, 129)), np.zeros((256, 256)), pair.work_array(0))


def test_results_do_not_alias_the_cached_work_arrays():
    """The hard-wall solver iterates in the FFT pair's cached work arrays; a second
    solve on the same grid size must not change the first one's result."""
    h, length = fig1_surface(256, seed=3)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-8)
    a = solve_contact(h, **kw)
    keep = (a.pressure.copy(), a.gap.copy(), a.displacement.copy())
    solve_contact(np.roll(h, 17, axis=0) * 1.3, **kw)
    assert all(np.array_equal(x, y) for x, y in zip(keep, (a.pressure, a.gap, a.displacement)))


def test_lazy_plain_pk_agrees_with_ccg_at_512():
    """512^2 is the smallest grid on which plain Polonsky-Keer defers the exact u = G p
    (the incremental u and the projection bookkeeping of the lazy path). Oracle: the
    preconditioned solver (exact u every step) at the same tol 1e-10: measured
    pressures within 2e-9 p0 and the same contact set; assert 1e-7 p0 (the bound of
    test_preconditioned_ccg_agrees_with_plain_pk) and at most 4 edge nodes."""
    h, length = fig1_surface(512, seed=2)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-10)
    a = solve_contact(h, method="ccg", **kw)
    b = solve_contact(h, method="pk", **kw)
    assert a.converged and b.converged
    assert b.info["fft_pairs"] < 2 * b.iterations  # the lazy path really ran
    assert np.count_nonzero((a.pressure > 0) != (b.pressure > 0)) <= 4
    assert np.max(np.abs(a.pressure - b.pressure)) < 1e-7 * 0.004


def test_threads_of_one_process_do_not_share_a_solve():
    """Two threads solving different surfaces of the same size at once (a Dask worker
    with several threads): each gets the answer of its own serial solve, bit for bit
    (each thread has its own FFT pair and work arrays; shared ones would mix the two
    solves' states)."""
    h, length = fig1_surface(256, seed=3)
    surfaces = [h, np.roll(h, 17, axis=0) * 1.3, np.roll(h, 40, axis=1) * 0.8, h[::-1].copy()]
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-9)
    serial = [solve_contact(x, **kw).pressure for x in surfaces]
    barrier = threading.Barrier(2)

    def run(x):
        barrier.wait()  # both threads inside the solver together
        return solve_contact(x, **kw).pressure

    with ThreadPoolExecutor(max_workers=2) as pool:
        for k in (0, 2):
            both = list(pool.map(run, surfaces[k:k + 2]))
            assert all(np.array_equal(a, b) for a, b in zip(both, serial[k:k + 2]))


@pytest.mark.parametrize("make", [lambda s: FFTWPair(s), lambda s: ScipyPair(s)])
def test_single_precision_route_is_the_double_route_to_float32_rounding(rng, make):
    """The preconditioner's single-precision route (in place on the pair's float32 array)
    against numpy's double-precision FFT. A float32 transform pair of a 256^2 field
    errs by about 1e-7 * log2(n) relative to the field's largest value; assert 2e-6
    (a factor 10 below what a dropped or wrong multiplier, or a half-precision path,
    would leave) and more than 1e-12 (the route really runs in single precision)."""
    shape = (256, 256)
    pair = make(shape)
    w = pair.single_array()
    assert w.dtype == np.float32 and w.shape == shape and pair.single_array() is w
    x = rng.normal(size=shape)
    mult = rng.random((256, 129)) + 0.5
    want = np.fft.irfft2(mult * np.fft.rfft2(x), s=shape)
    w[...] = x
    pair.apply_single((mult / x.size).astype(np.float32))
    err = np.max(np.abs(w - want)) / np.max(np.abs(want))
    assert 1e-12 < err < 2e-6
    src, dst = pair.single_array(1), pair.single_array(2)  # between two arrays: src kept
    src[...] = x
    dot = pair.apply_single((mult / x.size).astype(np.float32), 1, 2, dot=True)
    assert np.array_equal(src, x.astype(np.float32))
    assert 1e-12 < np.max(np.abs(dst - want)) / np.max(np.abs(want)) < 2e-6
    # the Parseval dot of the float32 spectrum, summed in double: float32 rounding
    assert dot == pytest.approx(np.sum(x * want), rel=2e-6)


def test_step_increment_is_the_whole_pressure_change(rng):
    """``pk_step`` on the packed contact set against numpy's step on the full grid: the new
    set's indices, pressures (``p - tau t`` where positive, ``-tau g`` at the overlaps that
    join) and directions (kept, 0 for new contacts) in index order, bit for bit (the same
    operations); the mask and the full-grid direction ``t2`` zeroed where a node left.
    With ``want_dv`` it writes ``p_new - p_old`` (float32) at every node it visits: the
    contact set's nodes, projected ones included (``-p_old``), and the overlaps that
    join; elsewhere ``dv`` keeps its zeros, and so ``G dv`` is the whole change of ``u``
    (to float32 rounding, 1e-7 relative). ``scatter_contact`` gives the full grid. The
    next gap pass folds the increment in: ``u = scale (u + G dv)``, ``G dv`` zeroed."""
    from gfmd_ref._kernels import pk_gap, pk_step, scatter_contact

    n = 32
    p = np.zeros((n, n))
    c = np.zeros((n, n), dtype=np.bool_)
    idx = np.sort(rng.choice(n * n, size=300, replace=False)).astype(np.int32)
    p.ravel()[idx] = rng.random(300) + 0.05
    c.ravel()[idx] = True
    t = np.zeros((n, n))
    t.ravel()[idx] = rng.normal(size=300)
    off = np.flatnonzero(~c.ravel())
    ol = np.sort(rng.choice(off, size=40, replace=False)).astype(np.int32)
    olg = rng.normal(size=n * n)  # the overlaps' gaps: about half of them join the set
    tau = 0.2
    # numpy's step on the full grid
    p_want = p.copy()
    p_want.ravel()[idx] -= tau * t.ravel()[idx]
    p_want.ravel()[ol] = -tau * olg[:40]
    p_want[p_want < 0.0] = 0.0
    on = np.flatnonzero(p_want.ravel() > 0.0)
    t_want = np.where(c & (p_want > 0.0), t, 0.0)

    pc, tc = p.ravel()[idx].copy(), t.ravel()[idx].copy()
    pc_new, tc_new = np.full(n * n, np.nan), np.full(n * n, np.nan)
    dv = np.zeros((n, n), dtype=np.float32)
    idx_new = np.empty(n * n, dtype=np.int32)
    t2 = t.astype(np.float32)
    c2 = c.copy()
    nproj, s, nc = pk_step(pc, c2, tc, idx, 300, ol, olg, 40, tau, idx_new, pc_new, tc_new, t2, dv, True)
    assert nproj > 0 and nc > 300 - nproj  # projections and new contacts both happened
    assert np.array_equal(idx_new[:nc], on)
    assert np.array_equal(pc_new[:nc], p_want.ravel()[on]) and np.array_equal(tc_new[:nc], t_want.ravel()[on])
    assert np.array_equal(c2, p_want > 0.0) and np.array_equal(t2, t_want.astype(np.float32))
    assert s == pytest.approx(np.sum(p_want), rel=1e-13)
    assert np.allclose(dv.ravel(), (p_want - p).ravel(), rtol=1e-7, atol=0.0)
    visited = np.union1d(idx, ol)
    untouched = np.setdiff1d(np.arange(n * n), visited)
    assert not dv.ravel()[untouched].any()
    full = np.full((n, n), np.nan)
    scatter_contact(pc_new, idx_new, nc, full)
    assert np.array_equal(full, p_want)
    # without want_dv the same step leaves dv alone
    dv2 = np.zeros((n, n), dtype=np.float32)
    pk_step(pc.copy(), c.copy(), tc.copy(), idx, 300, ol, olg, 40, tau, idx_new, pc_new, tc_new, t2.copy(), dv2,
            False)
    assert not dv2.any()
    # the increment folded into the next gap pass: u = scale (u + G dv) (numpy's two operations, the same bits), G dv
    # zeroed, max |G dv| returned, and the gap that of the new u, bit for bit as a pass over the updated u gives it
    u = rng.normal(size=(n, n))
    h = rng.normal(size=(n, n))
    gv = rng.normal(size=(n, n)).astype(np.float32)
    u_want = 1.1 * (u + gv.astype(float))
    big_want = float(np.max(np.abs(gv)))
    outs = []
    for uu, fold in ((u, True), (u_want.copy(), False)):
        bufs = (np.empty((n, n)), np.empty(n * n), np.empty(n * n, dtype=np.int32), np.empty(n * n))
        r = pk_gap(uu, h, pc_new, c2, idx_new, nc, bufs[0], True, *bufs[1:], gv, 1.0, 1.1, fold)
        outs.append((r[:5], bufs[0], bufs[1][:nc], bufs[2][:r[4]], bufs[3][:r[4]], r[5]))
    assert np.array_equal(u, u_want) and not gv.any()
    assert outs[0][5] == big_want and outs[1][5] == 0.0
    assert outs[0][0] == outs[1][0] and all(np.array_equal(x, y) for x, y in zip(outs[0][1:5], outs[1][1:5]))


def test_gap_and_direction_read_the_packed_contact_set(rng):
    """``pk_gap`` and ``pk_direction`` with the contact set's pressure and direction packed
    in index order, against numpy on the full grid: the gap ``u - h - mean_c(u - h)`` on
    the set (packed and masked), the overlaps, ``max_c |p g|`` (the packed pressure must
    meet its own node) and the direction ``z - shift + beta t`` (packed, and on the full
    grid where the FFT reads it); sums to round-off of 300 terms (1e-12)."""
    from gfmd_ref._kernels import pk_direction, pk_gap

    n = 32
    c = np.zeros((n, n), dtype=np.bool_)
    idx = np.sort(rng.choice(n * n, size=300, replace=False)).astype(np.int32)
    c.ravel()[idx] = True
    u, h = rng.normal(size=(n, n)), rng.normal(size=(n, n))
    pc = rng.random(n * n) + 0.05
    gcon, olg = np.empty(n * n), np.empty(n * n)
    ol = np.empty(n * n, dtype=np.int32)
    masked = np.full((n, n), np.nan)
    gv = np.ones((n, n), dtype=np.float32)  # not read without fold
    sg, gn, comp, pen, m, big = pk_gap(u, h, pc, c, idx, 300, masked, True, gcon, ol, olg, gv, 1.0, 1.0, False)
    assert big == 0.0 and gv.all()
    d = (u - h).ravel()
    g = d - np.sum(d[idx]) / 300
    assert np.allclose(gcon[:300], g[idx], rtol=0, atol=1e-14)
    assert np.array_equal(masked.ravel()[idx], gcon[:300]) and not masked.ravel()[~c.ravel()].any()
    over = np.flatnonzero(~c.ravel() & (g < 0))
    assert np.array_equal(ol[:m], over)
    assert np.allclose(olg[:m], g[over], rtol=0, atol=1e-14)
    assert comp == pytest.approx(np.max(np.abs(pc[:300] * g[idx])), rel=1e-12)
    assert pen == pytest.approx(-np.min(g[over]), rel=1e-12)
    assert sg == pytest.approx(np.sum(g[idx]), abs=1e-11) and gn == pytest.approx(np.sum(g[idx] ** 2), rel=1e-12)
    z = rng.normal(size=(n, n)).astype(np.float32)
    tc = rng.normal(size=n * n)
    tc_old = tc[:300].copy()
    t2 = np.zeros((n, n), dtype=np.float32)
    st, sgt = pk_direction(z, False, gcon, idx, 300, tc, 0.3, 0.7, t2)
    want = z.ravel()[idx].astype(float) - 0.3 + 0.7 * tc_old
    assert np.array_equal(tc[:300], want) and np.array_equal(t2.ravel()[idx], want.astype(np.float32))
    assert not t2.ravel()[~c.ravel()].any()
    assert st == pytest.approx(np.sum(want), rel=1e-12) and sgt == pytest.approx(np.sum(gcon[:300] * want), rel=1e-12)


def test_contact_sums_are_the_sums_over_the_contact_set(rng):
    """``contact_sums`` (sum of z and of g z over the index list, float32 z accumulated in
    double) against numpy on the same float64 values: round-off of 500 terms, 1e-12."""
    from gfmd_ref._kernels import contact_sums

    z = rng.normal(size=(32, 32)).astype(np.float32)
    idx = np.sort(rng.choice(z.size, size=500, replace=False)).astype(np.int32)
    gcon = rng.normal(size=z.size)
    s, d = contact_sums(z, gcon, idx, 500)
    zz = z.ravel()[idx].astype(float)
    assert s == pytest.approx(np.sum(zz), rel=1e-12, abs=1e-12)
    assert d == pytest.approx(np.sum(gcon[:500] * zz), rel=1e-12)


def test_contact_dot_is_the_sums_over_the_contact_set(rng):
    """``contact_dot`` (sum of r and of r t over the index list, float32 r accumulated in
    double, t packed) against numpy on the same float64 values: round-off of 500 terms, 1e-12."""
    from gfmd_ref._kernels import contact_dot

    r = rng.normal(size=(32, 32)).astype(np.float32)
    tc = rng.normal(size=r.size)  # t on the contact set, packed in the order of idx
    idx = np.sort(rng.choice(r.size, size=500, replace=False)).astype(np.int32)
    s, d = contact_dot(r, tc, idx, 500)
    rr = r.ravel()[idx].astype(float)
    assert s == pytest.approx(np.sum(rr), rel=1e-12, abs=1e-12)
    assert d == pytest.approx(np.sum(rr * tc[:500]), rel=1e-12)


@pytest.mark.parametrize("n", [256, 512])
def test_single_precision_routes_change_nothing_beyond_tol(monkeypatch, n):
    """``ccg`` as it runs by default (the preconditioner's and the step length's FFT pairs in
    single precision, ``u`` updated by single-precision increments ``G dv`` between exact
    ones), with an exact ``u`` after every step instead, with the preconditioner's pair
    only in single precision, and with neither (the earlier solver), tol 1e-10 on Fig. 1
    surfaces: the rounding only perturbs search directions, step lengths and ``u``
    between exact ones (every convergence decision uses an exact ``u``), so all must
    converge in about the same number of iterations (measured identical at 256^2-2048^2
    for the three pairs' variants, and the increments within 1 of the exact ``u`` on 53
    scenes, benchmarks/results/gfmd_search_variants.md; assert within 2) to pressures
    within the bound that any two tol-1e-10
    answers obey (1e-7 p0, see test_preconditioned_ccg_agrees_with_plain_pk; measured
    2e-13 ... 2e-11 p0) with the same contact set up to 4 edge nodes. The counters show
    which routes ran in single precision."""
    import gfmd_ref.solver as sv

    h, length = fig1_surface(n, seed=3)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-10,
              method="ccg")
    incr = solve_contact(h, **kw)
    monkeypatch.setattr(sv, "INCREMENT_REUSE_R", False)
    no_reuse = solve_contact(h, **kw)
    monkeypatch.setattr(sv, "INCREMENT_U32", False)
    both = solve_contact(h, **kw)
    monkeypatch.setattr(sv, "SINGLE_STEP", False)
    precond = solve_contact(h, **kw)
    monkeypatch.setattr(sv, "SINGLE_PRECOND", False)
    double = solve_contact(h, **kw)
    # the increments replace the exact u but for a few (measured 4 of 38 and 49 here); those of steps that kept the
    # contact set reuse r = G t instead of a pair of their own (measured 13 of 35 and 9 of 46)
    for r in (incr, no_reuse):
        assert r.info["u_increments"] >= r.iterations - 6
        assert r.info["fft_pairs_single"] == (2 * r.iterations + r.info["u_increments"]
                                              - r.info["u_increments_reusing_r"])
    assert incr.info["u_increments_reusing_r"] >= 3 and no_reuse.info["u_increments_reusing_r"] == 0
    assert both.info["fft_pairs_single"] == 2 * both.iterations and both.info["u_increments"] == 0
    assert precond.info["fft_pairs_single"] == precond.iterations and double.info["fft_pairs_single"] == 0
    for r in (incr, no_reuse, both, precond):
        assert r.converged and double.converged
        assert abs(r.iterations - double.iterations) <= 2
        assert np.count_nonzero((r.pressure > 0) != (double.pressure > 0)) <= 4
        assert np.max(np.abs(r.pressure - double.pressure)) < 1e-7 * 0.004


@pytest.mark.parametrize("n", [128, 512])
def test_the_answer_carries_an_exact_displacement(n):
    """With ``u`` updated by single-precision increments between exact ones, the answer's
    displacement must still be ``G p`` of its pressure plus one constant, to double
    round-off: convergence is declared on an exact ``u`` only. Oracle: numpy's double
    ``irfft2(G rfft2(p))``. At tol 1e-4 the last increments are large enough for their
    rounding to show: the spread of ``displacement - G p`` over ``max |G p|`` measured
    1.8e-16 and 8.7e-16 (128^2, 512^2), and 8.1e-11 and 1.5e-10 without the final exact
    ``u``; assert 1e-13. The increments must have run."""
    import gfmd_ref.solver as sv

    h, length = fig1_surface(n, seed=2)
    r = solve_contact(h, length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-4,
                      method="ccg")
    assert r.converged and r.info["u_increments"] > 0.8 * r.iterations
    el = sv._Elastic(n, length, 8 / 3)
    u = np.fft.irfft2(el.G * np.fft.rfft2(r.pressure), s=h.shape)
    assert np.ptp(r.displacement - u) < 1e-13 * np.max(np.abs(u))


def test_a_stalled_solve_returns_its_last_pressure(monkeypatch):
    """The full pressure grid is written from the packed contact set only where it is needed (an exact ``u``, the
    answer). A solve that stops on a stall takes no exact ``u`` first, so the answer must be written from the packed
    set there: stopped at iteration 5 by a stall, it must return the very pressure that ``max_iter = 5`` returns (that
    exit takes an exact ``u``, which leaves ``p`` as it is), bit for bit, and not a grid left from an earlier exact ``u``
    or from the previous solve in the same work arrays."""
    import gfmd_ref.solver as sv

    # exact and incremental steps alternate (any rounding counts against a share of 0), so the stall comes after an
    # increment that followed an exact u: the grid that exact u wrote is one step old
    monkeypatch.setattr(sv, "INCREMENT_SHARE", 0.0)
    h, length = fig1_surface(128, seed=1)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-12, method="ccg")
    with pytest.warns(ConvergenceWarning):
        capped = solve_contact(h, max_iter=5, **kw)
    solve_contact(h, **dict(kw, tol=1e-6))  # another answer in the work arrays
    monkeypatch.setattr(sv._Stall, "__call__", lambda self, res, it: it >= 5)
    with pytest.warns(ConvergenceWarning, match="stalled"):
        stalled = solve_contact(h, **kw)
    assert stalled.iterations == capped.iterations == 5 and 0 < stalled.info["u_increments"] < 5
    assert np.array_equal(stalled.pressure, capped.pressure)


@pytest.mark.parametrize("n, seed, p0", [(256, 3, 0.004), (512, 2, 1e-4)])
def test_folding_the_increment_into_the_gap_pass_changes_no_bit(monkeypatch, n, seed, p0):
    """The increment of ``u`` applied by the next gap pass (``FOLD_INCREMENT``, the default) or
    by a pass of its own (``apply_increment``; the switch off, or a grid above
    ``FOLD_INCREMENT_MAX_NODES``): the same operations in the same order, so the same answer
    bit for bit, the same iterations and pairs. Both kinds of increment must have run
    (``G dv`` and the reused ``r``), and ``info["u_increments_folded"]`` says which path ran."""
    import gfmd_ref.solver as sv

    h, length = fig1_surface(n, seed=seed)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=p0, interaction=HardWall(), tol=1e-9, method="ccg")
    folded = solve_contact(h, **kw)
    # a grid above FOLD_INCREMENT_MAX_NODES takes the pass of its own (as on 4096^2 by default)
    monkeypatch.setattr(sv, "FOLD_INCREMENT_MAX_NODES", n * n - 1)
    above = solve_contact(h, **kw)
    monkeypatch.setattr(sv, "FOLD_INCREMENT_MAX_NODES", n * n)
    monkeypatch.setattr(sv, "FOLD_INCREMENT", False)
    own_pass = solve_contact(h, **kw)
    assert folded.converged and folded.info["u_increments_reusing_r"] > 0
    assert folded.info["u_increments"] > folded.info["u_increments_reusing_r"]
    assert folded.info["u_increments_folded"] and not above.info["u_increments_folded"]
    assert not own_pass.info["u_increments_folded"]
    for other in (own_pass, above):
        assert np.array_equal(folded.pressure, other.pressure)
        assert np.array_equal(folded.displacement, other.displacement)
        assert folded.iterations == other.iterations and folded.info["fft_pairs"] == other.info["fft_pairs"]


@pytest.mark.parametrize("n, seed, p0", [(256, 3, 0.004), (128, 1, 0.004)])
def test_increments_keep_u_the_displacement_of_p(monkeypatch, n, seed, p0):
    """Between exact ``u = G p`` the solver updates ``u`` by increments: ``G dv`` of a step's
    whole pressure change in single precision, or ``-tau G t`` from the step length's
    ``r`` where the step kept the contact set. After every increment (checked where the
    gap pass folds it in) ``u`` must be ``G p`` of the packed pressure to the increments'
    float32 rounding: measured at most 2.3e-7 and 2.0e-7 of ``max |G p|`` here; assert
    1e-6. Reusing ``r`` after a step that projected nodes missed it by 3.4e-5 and 1.4e-4
    (and stalled). Oracle: numpy's double ``irfft2(G rfft2(p))``."""
    import gfmd_ref.solver as sv
    from gfmd_ref import _kernels as kr

    h, length = fig1_surface(n, seed=seed)
    el = sv._Elastic(n, length, 8 / 3)
    real_gap = kr.pk_gap
    devs = []

    def checked_gap(u, h_, pc, c, idx, nc, *rest):
        out = real_gap(u, h_, pc, c, idx, nc, *rest)
        if rest[-1]:  # an increment was folded in
            p = np.zeros(u.size)
            p[idx[:nc]] = pc[:nc]
            want = np.fft.irfft2(el.G * np.fft.rfft2(p.reshape(u.shape)), s=u.shape)
            devs.append(np.max(np.abs(u - want)) / np.max(np.abs(want)))
        return out

    monkeypatch.setattr(kr, "pk_gap", checked_gap)
    r = solve_contact(h, length=length, E_star=8 / 3, mean_pressure=p0, interaction=HardWall(), tol=1e-10,
                      method="ccg")
    assert r.converged and r.info["u_increments_reusing_r"] >= 5 and len(devs) >= r.iterations - 6
    assert max(devs) < 1e-6


@pytest.mark.parametrize("n, seed, p0", [(256, 2, 1e-4), (64, 2, 0.004)])
def test_hard_scenes_converge_with_and_without_increments(monkeypatch, n, seed, p0):
    """Two hard cases for the search: a tiny contact area (the Fig. 1 surface at 256^2 with
    ``p0 = 1e-4``, 0.2 % of the nodes in contact, each early step changing much of the
    set), and the paper's Fig. 1 scene sampled coarsely (64^2 nodes on ``L = 1024``, the
    main job's test size, where a search with the direction centred on the contact set
    failed to converge; docs/gfmd.md "The step length by Parseval (measured, reverted)").
    With and without the increments of ``u`` both must converge at tol 1e-9 in the same
    number of iterations up to 2 (measured equal) to pressures within 1e-7 p0."""
    import gfmd_ref.solver as sv

    if n == 64:
        from diffusion_pr.fig1 import FIG1_SCENE as S

        h = gfmd_ref.self_affine_surface(n, length=S["length"], hurst=S["hurst"], q_min=S["q_min"],
                                         q_max=S["q_max"], rms_slope=S["rms_slope"], seed=seed)
        length = S["length"]
    else:
        h, length = fig1_surface(n, seed=seed)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=p0, interaction=HardWall(), tol=1e-9, method="ccg")
    incr = solve_contact(h, **kw)
    monkeypatch.setattr(sv, "INCREMENT_U32", False)
    exact = solve_contact(h, **kw)
    assert incr.converged and exact.converged
    assert incr.info["u_increments"] > 0
    assert abs(incr.iterations - exact.iterations) <= 2
    assert np.max(np.abs(incr.pressure - exact.pressure)) < 1e-7 * p0


@pytest.mark.parametrize("n, zeta", [(64, 0.01), (256, 0.001), (256, 1.0)])
def test_single_precision_newton_cg_changes_nothing_beyond_tol(monkeypatch, n, zeta):
    """The exponential wall's Newton-CG with G d in single precision (the default) against
    double, tol 1e-9, Fig. 1 surfaces (64^2 takes the scipy path, 256^2 FFTW): the line
    search, u = G p and the residual stay in double, so both converge; measured the same
    iterations (74/109 at 256^2, zeta 0.01/0.001) and pressures within 1e-12 p0 of each
    other. Asserted: iterations within 3 and pressures within 1e-8 p0 (ten times the
    answers' own residual bound at tol 1e-9: both are within tol of the equilibrium)."""
    import gfmd_ref.solver as sv

    h, length = fig1_surface(n, seed=2)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=ExponentialRepulsion(zeta),
              tol=1e-9, method="newton")
    single = solve_contact(h, **kw)
    monkeypatch.setattr(sv, "SINGLE_NEWTON_CG", False)
    double = solve_contact(h, **kw)
    assert single.converged and double.converged
    assert single.info["fft_pairs_single"] > 0.5 * single.info["cg_iterations"]
    assert double.info["fft_pairs_single"] == 0
    assert abs(single.iterations - double.iterations) <= 3
    assert np.max(np.abs(single.pressure - double.pressure)) < 1e-8 * 0.004


@pytest.mark.parametrize("make", [lambda s: FFTWPair(s), lambda s: ScipyPair(s)])
def test_make_work_arrays_plans_the_single_precision_arrays_too(make):
    """``make_work_arrays(count, single=k)`` (what ``warm_up_fft`` and the solvers call)
    makes the double and the single-precision work arrays up front, so that their
    planning is counted in ``fft_planning_time`` and not paid inside the iteration; a
    second call makes nothing and reports 0."""
    from gfmd_ref import N_SINGLE_ARRAYS, N_WORK_ARRAYS

    pair = make((256, 256))
    pair.make_work_arrays(N_WORK_ARRAYS, single=N_SINGLE_ARRAYS)
    assert sorted(pair._work) == list(range(N_WORK_ARRAYS))
    assert sorted(pair._single) == list(range(N_SINGLE_ARRAYS))
    assert pair.make_work_arrays(N_WORK_ARRAYS, single=N_SINGLE_ARRAYS) == 0.0


_WISDOM_CHILD = """
import json, sys
import numpy as np
import gfmd_ref as g
from gfmd_ref._fft import _WISDOM_STATE, wisdom_path
g.warm_up_fft(256)
h, L = g.fig1_surface(256, seed=3)
r = g.solve_contact(h, length=L, E_star=8 / 3, mean_pressure=0.004, interaction=g.HardWall(), tol=1e-9)
print(json.dumps(dict(path=wisdom_path(), fft=r.info["fft"], imported=_WISDOM_STATE["imported"],
                      p=r.pressure.ravel()[::97].tolist())))
"""


def _wisdom_child(env_value, tmp_path):
    import json
    import os
    import subprocess
    import sys

    env = dict(os.environ, GFMD_REF_FFTW_WISDOM=env_value)
    env.pop("GFMD_REF_FFT", None)
    out = subprocess.run([sys.executable, "-c", _WISDOM_CHILD], env=env, capture_output=True, text=True,
                         cwd=tmp_path, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_fftw_wisdom_is_kept_between_processes(tmp_path):
    """The first process measures its plans and writes FFTW's wisdom to the file; the next
    one reads it, plans the same transforms and so computes the same answer bit for bit
    (two processes that each measured could pick different plans: answers 1e-13 apart).
    The file is JSON with FFTW's three wisdom strings."""
    import json

    path = tmp_path / "wisdom.json"
    first = _wisdom_child(str(path), tmp_path)
    assert first["fft"] == "fftw" and first["path"] == str(path) and path.exists()
    assert not first["imported"]
    data = json.loads(path.read_text())
    assert set(data) == {"double", "single", "long"} and "fftw" in data["double"]
    assert "fftwf" in data["single"]  # the single-precision plans are kept too
    second = _wisdom_child(str(path), tmp_path)
    assert second["imported"] and second["p"] == first["p"]


def test_a_broken_wisdom_file_is_ignored_and_off_writes_none(tmp_path, monkeypatch):
    """Wisdom only saves time: an unreadable file does not stop a solve (and is replaced by
    a valid one after the process measured its plans), and ``off`` reads and writes none.
    Oracle for the answers: the scipy path's, to the solvers' tol-level agreement (1e-7
    p0, as test_solver_gives_the_same_answer_with_either_fft)."""
    import json

    path = tmp_path / "wisdom.json"
    path.write_text("not json {")
    broken = _wisdom_child(str(path), tmp_path)
    assert broken["fft"] == "fftw" and not broken["imported"]
    assert set(json.loads(path.read_text())) == {"double", "single", "long"}
    off = _wisdom_child("off", tmp_path)
    assert off["path"] is None and not off["imported"]
    h, length = fig1_surface(256, seed=3)
    monkeypatch.setenv("GFMD_REF_FFT", "scipy")
    monkeypatch.setattr("gfmd_ref._fft._LOCAL", threading.local())
    ref = solve_contact(h, length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-9)
    for r in (broken, off):
        assert np.max(np.abs(np.asarray(r["p"]) - ref.pressure.ravel()[::97])) < 1e-7 * 0.004


def test_make_work_arrays_writes_the_wisdom_file_once(monkeypatch):
    """The plans measured by one ``make_work_arrays`` call are saved in one write of the
    wisdom file at its end, not one per plan (7 work arrays: 7 writes before). Every plan
    is counted as measured here (threshold below 0), so the count does not depend on
    what wisdom this process already holds."""
    import gfmd_ref._fft as fft_mod
    from gfmd_ref import N_SINGLE_ARRAYS, N_WORK_ARRAYS

    writes = []
    monkeypatch.setattr(fft_mod, "_WISDOM_NEW_PLAN_SECONDS", -1.0)
    monkeypatch.setattr(fft_mod, "_save_wisdom", lambda: writes.append(1))
    pair = FFTWPair((256, 256))
    assert len(writes) == 1  # the pair's own plans
    pair.make_work_arrays(N_WORK_ARRAYS, single=N_SINGLE_ARRAYS)
    assert len(writes) == 2
    pair.work_array(N_WORK_ARRAYS)  # a plan made on its own is saved at once
    assert len(writes) == 3


class _Clock:
    """A stand-in for ``time`` in :mod:`gfmd_ref._fft`: ``perf_counter`` advances by exactly 1 per call, so every
    timed interval of a pair is a count of the calls inside it."""

    def __init__(self):
        self.now = 0.0

    def perf_counter(self):
        self.now += 1.0
        return self.now


@pytest.mark.parametrize("n", [64, 256])  # scipy's pair below FFTW_MIN_N, FFTW's (where installed) from it
@pytest.mark.parametrize("method", ["ccg", "pk"])
def test_a_solve_reports_the_time_of_each_of_its_transforms(monkeypatch, n, method):
    """``info["fft_seconds"]`` / ``info["multiply_seconds"]`` count every FFT pair of the solve: on a clock that
    ticks once per reading, a pair's two transforms read 2 ticks and its multiply 1 (4 readings: before the
    forward, between it and the multiply, between the multiply and the backward, after it). Oracle: the solver's
    own pair count, plus the full-contact check's pair (``el.apply``, not in ``fft_pairs``). It fails where a
    route is not timed, where the multiply is counted as a transform, or where a cached pair's earlier totals
    leak into a solve."""
    from gfmd_ref import _fft

    h, L = fig1_surface(n, seed=2)
    kw = dict(length=L, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-8, method=method)
    solve_contact(h, **kw)  # the pair and its work arrays made (and planned) on the real clock
    monkeypatch.setattr(_fft, "time", _Clock())
    r = solve_contact(h, **kw)
    pairs = r.info["fft_pairs"] + 1
    assert r.info["fft_seconds"] == 2.0 * pairs
    assert r.info["multiply_seconds"] == 1.0 * pairs
    assert r.converged


def test_transform_time_is_part_of_the_wall_time():
    """On the real clock the transforms and multiplies are positive and less than the whole solve."""
    h, L = fig1_surface(128, seed=1)
    r = solve_contact(h, length=L, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-8)
    assert 0.0 < r.info["multiply_seconds"] < r.info["fft_seconds"] < r.wall_time
