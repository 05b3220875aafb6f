"""The FFT pair, the hard-wall solver's kernels, and its single-precision search."""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import gfmd_ref
from gfmd_ref import ConvergenceWarning, ExponentialRepulsion, HardWall, fig1_surface, solve_contact
from gfmd_ref.fft import FFTPair
from gfmd_ref.solvers import _kernels as kr
from gfmd_ref.solvers import ccg as ccg_mod
from gfmd_ref.solvers.elastic import Elastic


@pytest.mark.parametrize("shape", [(6, 8), (7, 9), (256, 256)])
def test_spectral_multiply_dot_is_the_real_space_dot(rng, shape):
    """Parseval: the dot product the spectral multiply returns is sum x y for
    y = irfft2(mult X) n^2, on even and odd last axes (the Nyquist column has
    weight 1 only when it exists). Oracle: the real-space sum with numpy's FFT;
    both are round-off of a sum of ~n^2 terms, assert 1e-12 relative."""
    from gfmd_ref.fft import spectral_multiply

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
    from gfmd_ref.fft import spectral_multiply, spectral_scale

    real = np.float64 if dtype == np.complex128 else np.float32
    X = (rng.normal(size=(64, 33)) + 1j * rng.normal(size=(64, 33))).astype(dtype)
    mult = rng.random((64, 33)).astype(real)
    a, b = X.copy(), X.copy()
    spectral_scale(a, mult)
    spectral_multiply(b, mult, 64)
    assert np.array_equal(a, X * mult) and np.array_equal(b, X * mult)


def test_apply_route_keeps_its_input_and_returns_the_dot(rng):
    """A route between two arrays leaves the source as it was, a route onto the
    same array transforms it in place, and both return src . dst (Parseval). Oracle:
    numpy's FFT; round-off, assert 1e-12."""
    shape = (256, 256)
    pair = FFTPair(shape)
    src, dst = np.zeros(shape), np.zeros(shape)
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
    src[...] = x
    nodot = pair.apply_route(mult / x.size, src, dst, dot=False)  # the same field, no dot
    assert np.isnan(nodot) and np.array_equal(src, x)
    assert np.max(np.abs(dst - want)) < 1e-12 * np.max(np.abs(want))


def test_results_do_not_alias_the_solver_arrays():
    """A second solve on the same grid size must not change the first one's result."""
    h, length = fig1_surface(256, seed=3)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-8)
    a = solve_contact(h, **kw)
    keep = (a.pressure.copy(), a.gap.copy(), a.displacement.copy())
    solve_contact(np.roll(h, 17, axis=0) * 1.3, **kw)
    assert all(np.array_equal(x, y) for x, y in zip(keep, (a.pressure, a.gap, a.displacement)))


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


def test_single_precision_route_is_the_double_route_to_float32_rounding(rng):
    """The preconditioner's single-precision route (in place on a float32 array)
    against numpy's double-precision FFT. A float32 transform pair of a 256^2 field
    errs by about 1e-7 * log2(n) relative to the field's largest value; assert 2e-6
    (a factor 10 below what a dropped or wrong multiplier, or a half-precision path,
    would leave) and more than 1e-12 (the route really runs in single precision)."""
    shape = (256, 256)
    pair = FFTPair(shape)
    w = np.zeros(shape, dtype=np.float32)
    x = rng.normal(size=shape)
    mult = rng.random((256, 129)) + 0.5
    want = np.fft.irfft2(mult * np.fft.rfft2(x), s=shape)
    w[...] = x
    pair.apply_route((mult / x.size).astype(np.float32), w, w, dot=False)
    assert w.dtype == np.float32
    err = np.max(np.abs(w - want)) / np.max(np.abs(want))
    assert 1e-12 < err < 2e-6
    src, dst = np.zeros(shape, dtype=np.float32), np.zeros(shape, dtype=np.float32)  # between two arrays: src kept
    src[...] = x
    dot = pair.apply_route((mult / x.size).astype(np.float32), src, dst, dot=True)
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
    from gfmd_ref.solvers._kernels import pk_gap, pk_step, scatter_contact

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
    from gfmd_ref.solvers._kernels import pk_direction, pk_gap

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
    """``contact_sums`` (sum of z and of w z over the index list, float32 z accumulated in
    double, w packed in the order of idx) against numpy on the same float64 values:
    round-off of 500 terms, 1e-12."""
    from gfmd_ref.solvers._kernels import contact_sums

    z = rng.normal(size=(32, 32)).astype(np.float32)
    idx = np.sort(rng.choice(z.size, size=500, replace=False)).astype(np.int32)
    w = rng.normal(size=z.size)
    s, d = contact_sums(z, w, idx, 500)
    zz = z.ravel()[idx].astype(float)
    assert s == pytest.approx(np.sum(zz), rel=1e-12, abs=1e-12)
    assert d == pytest.approx(np.sum(w[:500] * zz), rel=1e-12)


@pytest.mark.parametrize("n", [128, 512])
def test_the_answer_carries_an_exact_displacement(n):
    """With ``u`` updated by single-precision increments between exact ones, the answer's
    displacement must still be ``G p`` of its pressure plus one constant, to double
    round-off: convergence is declared on an exact ``u`` only. Oracle: numpy's double
    ``irfft2(G rfft2(p))``. At tol 1e-4 the last increments are large enough for their
    rounding to show: the spread of ``displacement - G p`` over ``max |G p|`` measured
    1.8e-16 and 8.7e-16 (128^2, 512^2), and 8.1e-11 and 1.5e-10 without the final exact
    ``u``; assert 1e-13. The increments must have run."""
    h, length = fig1_surface(n, seed=2)
    r = solve_contact(h, length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-4,
                      method="ccg")
    assert r.converged and r.info["u_increments"] > 0.8 * r.iterations
    el = Elastic(n, length, 8 / 3)
    u = np.fft.irfft2(el.G * np.fft.rfft2(r.pressure), s=h.shape)
    assert np.ptp(r.displacement - u) < 1e-13 * np.max(np.abs(u))


def test_a_stalled_solve_returns_its_last_pressure(monkeypatch):
    """The full pressure grid is written from the packed contact set only where it is needed (an exact ``u``, the
    answer). A solve that stops on a stall takes no exact ``u`` first, so the answer must be written from the packed
    set there: stopped at iteration 5 by a stall, it must return the very pressure that ``max_iter = 5`` returns (that
    exit takes an exact ``u``, which leaves ``p`` as it is), bit for bit, and not a grid left from an earlier exact ``u``
    or from the previous solve."""
    from gfmd_ref.solvers.monitor import Monitor

    # exact and incremental steps alternate (any rounding counts against a share of 0), so the stall comes after an
    # increment that followed an exact u: the grid that exact u wrote is one step old
    monkeypatch.setattr(ccg_mod, "INCREMENT_SHARE", 0.0)
    h, length = fig1_surface(128, seed=1)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-12, method="ccg")
    with pytest.warns(ConvergenceWarning):
        capped = solve_contact(h, max_iter=5, **kw)
    solve_contact(h, **dict(kw, tol=1e-6))
    real_check = Monitor.check

    def stall_at_5(self, res, it, steps=None):
        if it >= 5 and not res < self.tol:
            self.history.append(res)
            self.residual, self.stop = res, "stalled: forced at iteration 5"
            return True
        return real_check(self, res, it, steps)

    monkeypatch.setattr(Monitor, "check", stall_at_5)
    with pytest.warns(ConvergenceWarning, match="stalled"):
        stalled = solve_contact(h, **kw)
    assert stalled.iterations == capped.iterations == 5 and 0 < stalled.info["u_increments"] < 5
    assert np.array_equal(stalled.pressure, capped.pressure)


@pytest.mark.parametrize("n, seed, p0", [(256, 3, 0.004), (128, 1, 0.004)])
def test_increments_keep_u_the_displacement_of_p(monkeypatch, n, seed, p0):
    """Between exact ``u = G p`` the solver updates ``u`` by increments: ``G dv`` of a step's
    whole pressure change in single precision, or ``-tau G t`` from the step length's
    ``r`` where the step kept the contact set. After every increment (checked where the
    gap pass folds it in) ``u`` must be ``G p`` of the packed pressure to the increments'
    float32 rounding: measured at most 2.3e-7 and 2.0e-7 of ``max |G p|`` here; assert
    1e-6. Reusing ``r`` after a step that projected nodes missed it by 3.4e-5 and 1.4e-4
    (and stalled). Oracle: numpy's double ``irfft2(G rfft2(p))``."""
    h, length = fig1_surface(n, seed=seed)
    el = Elastic(n, length, 8 / 3)
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


@pytest.mark.parametrize("n", [256, 512])
def test_single_precision_search_agrees_with_plain_pk(n):
    """``ccg`` (the preconditioner's and the step length's FFT pairs in single precision, ``u``
    updated by single-precision increments ``G dv`` between exact ones) against the plain
    Polonsky-Keer search, tol 1e-10 on Fig. 1 surfaces: the rounding only perturbs search
    directions, step lengths and ``u`` between exact ones (every convergence decision uses
    an exact ``u``), so both converge to pressures within the bound that any two tol-1e-10
    answers obey (1e-7 p0, see test_preconditioned_ccg_agrees_with_plain_pk) with the same
    contact set up to 4 edge nodes. The counters show the routes: two single-precision
    pairs per step plus one per increment that did not reuse ``r = G t``, and the
    increments replace the exact ``u`` but for a few."""
    h, length = fig1_surface(n, seed=3)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-10)
    a = solve_contact(h, method="ccg", **kw)
    b = solve_contact(h, method="pk", **kw)
    assert a.converged and b.converged
    assert a.info["u_increments"] >= a.iterations - 6 and a.info["u_increments_reusing_r"] >= 3
    assert a.info["fft_pairs_single"] == (2 * a.iterations + a.info["u_increments"]
                                          - a.info["u_increments_reusing_r"])
    assert np.count_nonzero((a.pressure > 0) != (b.pressure > 0)) <= 4
    assert np.max(np.abs(a.pressure - b.pressure)) < 1e-7 * 0.004


@pytest.mark.parametrize("n, seed, p0", [(256, 2, 1e-4), (64, 2, 0.004)])
def test_hard_scenes_converge(n, seed, p0):
    """Two hard cases for the search: a tiny contact area (the Fig. 1 surface at 256^2 with
    ``p0 = 1e-4``, 0.2 % of the nodes in contact, each early step changing much of the
    set), and the paper's Fig. 1 scene sampled coarsely (64^2 nodes on ``L = 1024``, the
    main job's test size, where a search with the direction centred on the contact set
    failed to converge). ``ccg`` with its increments of ``u`` must converge at tol 1e-9 to
    pressures within 1e-7 p0 of the plain search's."""
    if n == 64:
        from diffusion_pr.jobs.fig1 import FIG1_SCENE as S

        h = gfmd_ref.self_affine_surface(n, length=S["length"], hurst=S["hurst"], q_min=S["q_min"],
                                         q_max=S["q_max"], rms_slope=S["rms_slope"], seed=seed)
        length = S["length"]
    else:
        h, length = fig1_surface(n, seed=seed)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=p0, interaction=HardWall(), tol=1e-9)
    incr = solve_contact(h, method="ccg", **kw)
    plain = solve_contact(h, method="pk", **kw)
    assert incr.converged and plain.converged and incr.info["u_increments"] > 0
    assert np.max(np.abs(incr.pressure - plain.pressure)) < 1e-7 * p0


@pytest.mark.parametrize("n, zeta", [(64, 0.01), (256, 0.001), (256, 1.0)])
def test_single_precision_newton_cg_meets_tol(n, zeta):
    """The exponential wall's Newton-CG with ``G d`` in single precision: the line search,
    ``u = G p`` and the residual stay in double, so the answer must be within tol of the
    equilibrium. Oracle: the force residual of the returned pressure recomputed with numpy
    in double (``u = irfft2(G rfft2(p))``, ``z0`` by log-sum-exp), at most 10 tol; most CG
    pairs ran in single precision."""
    h, length = fig1_surface(n, seed=2)
    tol, p0 = 1e-9, 0.004
    r = solve_contact(h, length=length, E_star=8 / 3, mean_pressure=p0, interaction=ExponentialRepulsion(zeta),
                      tol=tol, method="newton")
    assert r.converged and r.info["fft_pairs_single"] > 0.5 * r.info["cg_iterations"]
    el = Elastic(n, length, 8 / 3)
    x = -(np.fft.irfft2(el.G * np.fft.rfft2(r.pressure), s=h.shape) - h) / zeta
    m = x.max()
    sigma = p0 * np.exp(x - m) * x.size / np.sum(np.exp(x - m))
    assert np.max(np.abs(sigma - r.pressure)) / p0 < 10 * tol
