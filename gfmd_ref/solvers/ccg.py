"""Constrained conjugate gradients for the hard wall (Polonsky & Keer 1999).

Polonsky & Keer, Wear 231, 206 (1999), doi:10.1016/S0043-1648(99)00113-1: conjugate
gradients on the pressures with the constraints ``p >= 0`` and ``mean(p) = p0``; the
displacement ``u = G p`` is computed from the pressure, so the force balance of every
mode holds by construction. Residual (relative to ``p0``, ``h_s`` the height scale):
``max(|<p> - p0|/p0, max|p g|/(p0 h_s), max(-g)_+/h_s)``: load error, complementarity,
penetration.
"""
from __future__ import annotations

import numpy as np

from . import _kernels as kr
from .monitor import Monitor

#: stall windows (iterations without halving the best residual): preconditioned ``ccg``
#: (longest stretch seen on the Fig. 1 surface 5-10, 64^2-512^2) and plain ``pk`` (8-33).
CCG_STALL_WINDOW = 50
PK_STALL_WINDOW = 200
#: the rounding of one single-precision ``G dv`` relative to its largest value (a bound:
#: 2-4e-7 seen over every increment of tol-1e-10 solves of Fig. 1 surfaces, 256^2-1024^2)
INCREMENT_ROUNDING = 2e-6
#: an exact ``u = G p`` is taken where the increments' rounding accumulated since the last
#: one could exceed this share of the residual (in units of ``h_scale``), after
#: :data:`REFRESH` increments, where the residual has not halved for
#: :data:`INCREMENT_STALL` iterations, and before convergence is declared
INCREMENT_SHARE = 1e-4
INCREMENT_STALL = 10
REFRESH = 50


def ccg(h, p0, el, tol, max_iter, progress, h_scale, precond=True):
    """Polonsky-Keer constrained CG on the pressures; returns the solver's answer dict.

    ``precond=True`` (``method="ccg"``): the search direction is built from ``z = K (g on
    the contact set)``, ``K = q E*/2`` the inverse of the Green's function (a
    Fourier-diagonal preconditioner; one more FFT pair per iteration), shifted to zero mean
    on the contact set; ``beta = (g.z)_new / (g.z)_old``. On the Fig. 1 surface it takes
    about 4x fewer iterations than the plain search (``precond=False``, ``method="pk"``, the
    algorithm of Tamaas' ``PolonskyKeerRey``).

    The search runs in single precision: the preconditioner's FFT pair and ``r = G t`` of
    the step length (``float32`` data and multipliers; the sums over the contact set in
    double). ``p``, the step itself and every residual stay in double precision, so the
    rounding (relative 1e-7) only perturbs the search direction and the step length.
    ``u = G p`` is updated by the step's whole pressure change ``dv`` (projections and new
    contacts included), transformed in single precision: ``u <- scale (u + G dv)``, folded
    into the next gap pass (:func:`~gfmd_ref.solvers._kernels.pk_gap`). A step that kept
    the contact set changed ``p`` by ``-tau t`` alone, so its ``G dv`` is ``-tau r`` and its
    FFT pair is saved. The rounding of the increments is relative to the increment, not to
    ``u``, and the bound :data:`INCREMENT_ROUNDING` ``sum max |G dv|`` is tracked: an exact
    ``u`` (double precision) is taken where it could exceed :data:`INCREMENT_SHARE` of the
    residual, where the residual stalls, every :data:`REFRESH` steps, and always before
    convergence is declared (docs/gfmd.md).

    Start: uniform ``p0``. One full pass per iteration (the gap, which also applies the last
    increment of ``u``); the rest works on the contact set's sorted index list, with the
    pressure and the direction packed in its order (the full grid ``p`` is written only for
    an exact ``u`` and the answer; see :mod:`gfmd_ref.solvers._kernels`).
    """
    n2 = h.size
    f32 = np.float32
    p = np.zeros(el.shape)  # the full grid pressure (for an exact u and the answer)
    u = np.zeros(el.shape)  # u = G p (a uniform pressure does not deform)
    index = np.int32 if n2 < 2 ** 31 else np.int64
    # the contact set, its sorted flat indices, and the pressure and direction packed in their order
    # (two lists each, swapped every step)
    c = np.ones(el.shape, dtype=np.bool_)
    idx, idx_next = np.arange(n2, dtype=index), np.empty(n2, dtype=index)
    pc, pc_next = np.full(n2, float(p0)), np.empty(n2)
    tc, tc_next = np.zeros(n2), np.empty(n2)
    nc = n2
    gcon = np.empty(n2)  # the gap on the contact set, in the order of idx
    ol, olg = np.empty(n2, dtype=index), np.empty(n2)  # overlaps (g < 0 off the set) and their gaps
    # single precision: the masked gap and K of it, the direction t, r = G t, the step's pressure change dv
    z32, t32, r32, dv32 = (np.zeros(el.shape, dtype=f32) for _ in range(4))
    Gn32 = el.Gn.astype(f32)
    Kn32 = (el.K / n2).astype(f32)
    psum = p0 * n2
    n_fft = n_single = n_increments = n_reused = 0
    delta, gold, it, since_exact = 0.0, 1.0, 0, 0
    u_rounding = 0.0  # the increments' rounding accumulated in u since the last exact u (bound)
    # the last step's increment of u, u <- scale (u + a gv), waits for the next gap pass
    fold, fold_scale, fold_a, fold_gv = False, 1.0, 1.0, dv32
    mon = Monitor("ccg" if precond else "pk", tol, max_iter, CCG_STALL_WINDOW if precond else PK_STALL_WINDOW,
                  progress)

    def residual():
        sg, gn, comp, pen, n_ol, gv_max = kr.pk_gap(u, h, pc, c, idx, nc, z32, precond, gcon, ol, olg, fold_gv,
                                                    fold_a, fold_scale, fold)
        load = abs(psum / n2 - p0) / p0
        return sg, gn, n_ol, max(load, comp / (p0 * h_scale), pen / h_scale), gv_max

    def exact_u():
        nonlocal n_fft, since_exact, u_rounding
        kr.scatter_contact(pc, idx, nc, p)
        el.fft.apply_route(el.Gn, p, u, dot=False)
        n_fft += 1
        since_exact, u_rounding = 0, 0.0

    while True:
        sg, gn, n_ol, res, gv_max = residual()
        if fold:
            u_rounding = fold_scale * (u_rounding + INCREMENT_ROUNDING * abs(fold_a) * gv_max)
            fold = False
        if mon.done(res, it) and since_exact > 0:  # every stop is judged on an exact u
            exact_u()
            sg, gn, n_ol, res, _ = residual()
        if mon.check(res, it):
            break
        if precond:  # z = K (masked g) in place; g.z over the contact set
            el.fft.apply_route(Kn32, z32, z32, dot=False)
            n_single += 1
            zsum, sgz = kr.contact_sums(z32, gcon, idx, nc)
            zbar = zsum / nc if nc > 0 else 0.0
            gz = sgz - zbar * sg  # sum_c g (z - zbar), the preconditioned residual norm
            beta = delta * gz / gold if gold > 0.0 else 0.0
            st, sgt = kr.pk_direction(z32, False, gcon, idx, nc, tc, zbar, beta, t32)
            gold = gz
        else:
            beta = delta * gn / gold if gold > 0.0 else 0.0
            st, sgt = kr.pk_direction(z32, True, gcon, idx, nc, tc, 0.0, beta, t32)
            gold = gn
        el.fft.apply_route(Gn32, t32, r32, dot=False)  # r = G t (the step length only)
        n_single += 1
        rsum, srt = kr.contact_dot(r32, tc, idx, nc)
        den = srt - (rsum / nc if nc > 0 else 0.0) * st  # sum_c (r - rbar) t
        tau = sgt / den if den != 0 else 0.0
        # the increment's G dv instead of an exact u, unless the rounding u may have gathered is no longer far
        # below the residual, or the residual stalls, or REFRESH increments ran
        use_incr = not (u_rounding > INCREMENT_SHARE * res * h_scale or since_exact + 1 >= REFRESH
                        or it - mon.it_best > INCREMENT_STALL)
        nc_before = nc
        nproj, psum, nc = kr.pk_step(pc, c, tc, idx, nc, ol, olg, n_ol, tau, idx_next, pc_next, tc_next, t32, dv32,
                                     use_incr)
        idx, idx_next = idx_next, idx
        pc, pc_next = pc_next, pc
        tc, tc_next = tc_next, tc
        if not psum > 0.0:  # the step removed every contact: no load can be restored
            mon.fail(f"a step removed every contact (sum p = {psum:g} after step {it + 1})")
            break
        scale = p0 * n2 / psum
        delta = 0.0 if n_ol > 0 else 1.0
        it += 1
        since_exact += 1
        psum = kr.pk_rescale(pc, nc, scale)
        if use_incr:
            n_increments += 1
            if nproj == 0 and nc == nc_before:  # the set kept: dv = -tau t, G dv = -tau r
                kr.zero_at(dv32, idx, nc)
                fold_gv, fold_a = r32, -tau
                n_reused += 1
            else:
                el.fft.apply_route(Gn32, dv32, dv32, dot=False)
                n_single += 1
                fold_gv, fold_a = dv32, 1.0
            fold, fold_scale = True, scale
        else:
            exact_u()
    kr.scatter_contact(pc, idx, nc, p)
    # displacement: z0 such that the gap vanishes on the contact set
    mask = p > 0
    z0 = float(np.mean((h - u)[mask])) if np.any(mask) else float(np.max(h - u))
    disp = u + z0
    return mon.outcome(it, pressure=p, gap=disp - h, displacement=disp,
                       info=dict(h_scale=h_scale, fft_pairs=n_fft + n_single, fft_pairs_single=n_single,
                                 u_increments=n_increments, u_increments_reusing_r=n_reused))
