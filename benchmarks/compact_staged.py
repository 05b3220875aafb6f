"""The compact scheme's whole stage loop compiled, timed against the engine's own staged kernel (issue 10).

``compact_kernel_cost.py`` timed one exponential. A closure call integrates every shell with its balance on
three nested grids per level, and the engine's kernel (:func:`diffusion_pr.solvers.fv._kernels.staged_run`) does
that with a predictor that usually needs a single plain exponential per stage. This script writes the compact
scheme's stage loop as one compiled call (:func:`compact_staged_run`: the pencil's rows made per Newton iterate
from the coefficient rows, the absorbing bottom as the bordered first row, the balance by Newton on the exact
derivative of ``pencil_pfd`` from a predicted multiplier, the engine's first-order state update once the miss is
below ``lin_tol``) and times it against ``staged_run`` on the prototype's problem (``fourth_order_space.py
--absorbing --skip 0``: the Fig. 1 scene, 48 uniform midpoint shells, the bottom at ``1e-16 p*``), each on the
three nested grids of the finest it needs for 3e-7 (that script's tables): the work of one level.

First the kernel is checked against the prototype's numpy solver (``run_compact``) on the same grid: the two
balance searches stop at different points within their tolerances, so they agree to about the balance tolerance.

    python benchmarks/compact_staged.py [--zetas 0.1 0.01] [--repeats 7] [--balance newton|secant|predicted]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diffusion_pr.solvers.fv import _kernels as K  # noqa: E402
from diffusion_pr.solvers.fv._compact_kernels import pencil_pfd  # noqa: E402
from diffusion_pr.solvers.fv.compact import absorbing_bottom, corrected_delta_start  # noqa: E402
from diffusion_pr.solvers.fv.cram import pfd_coefficients  # noqa: E402
from fourth_order_space import P0, SHELLS, CompactAbsorbing, SchemeAbsorbing, grid, run_compact  # noqa: E402
from shell_rule_balance import Scene  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "compact_staged.md"
THETA, RES, R_INF, _ = pfd_coefficients(16)
RTOL = 1e-6
MEAN_TOL, LIN_TOL = 1e-2 * RTOL, math.sqrt(1e-2 * RTOL)  # the engine's at rtol 1e-6 (MEAN_TOL_FRACTION, ...)


@njit(cache=True, nogil=True, error_model="numpy")
def _pencil_rows(h, a, a1, a2, bf, bf1, bf2, bw, bw1, bw2, a_bal, a_bottom, pl, pd, pu, ql, qd, qu, ppl, ppd, ppu,
                 qql, qqd, qqu, row0):  # pragma: no cover - numba
    """The bands of ``P`` and ``Q`` (``hoc_bands``) at the multiplier ``a_bal`` (``B = B_f + a_bal B_w``) and their
    derivatives in it, the absorbing bottom in row 0 (``row0``: its columns 2 and 3), ``M`` held at the top."""
    m = a.size
    n = m + 2
    for k in range(n - 1):
        pl[k] = 0.0
        pu[k] = 0.0
        ql[k] = 0.0
        qu[k] = 0.0
        ppl[k] = 0.0
        ppu[k] = 0.0
        qql[k] = 0.0
        qqu[k] = 0.0
    for k in range(n):
        pd[k] = 1.0
        qd[k] = 0.0
        ppd[k] = 0.0
        qqd[k] = 0.0
    h2_12 = h * h / 12.0
    inv_h2 = 1.0 / (h * h)
    inv_2h = 0.5 / h
    for i in range(m):
        k = i + 1
        b = bf[i] + a_bal * bw[i]
        b1 = bf1[i] + a_bal * bw1[i]
        b2 = bf2[i] + a_bal * bw2[i]
        ia = 1.0 / a[i]
        beta = (b - 2.0 * a1[i]) * ia
        beta_a = bw[i] * ia
        gamma = b2 + beta * b1
        gamma_a = bw2[i] + beta_a * b1 + beta * bw1[i]
        kappa = 2.0 * b1 + a2[i] + beta * (a1[i] + b)
        kappa_a = 2.0 * bw1[i] + beta_a * (a1[i] + b) + beta * bw[i]
        pl[k - 1] = 1.0 / 12.0 - beta * h / 24.0
        pd[k] = 5.0 / 6.0
        pu[k] = 1.0 / 12.0 + beta * h / 24.0
        ppl[k - 1] = -beta_a * h / 24.0
        ppu[k] = beta_a * h / 24.0
        d2 = (a[i] + h2_12 * kappa) * inv_h2
        d1 = (b + h2_12 * gamma) * inv_2h
        d2a = kappa_a / 12.0
        d1a = (bw[i] + h2_12 * gamma_a) * inv_2h
        ql[k - 1] = d2 - d1
        qd[k] = -2.0 * d2
        qu[k] = d2 + d1
        qql[k - 1] = d2a - d1a
        qqd[k] = -2.0 * d2a
        qqu[k] = d2a + d1a
    qd[0] = a_bottom[0]
    qu[0] = a_bottom[1]
    row0[0] = a_bottom[2]
    row0[1] = a_bottom[3]


@njit(cache=True, nogil=True, error_model="numpy")
def compact_staged_run(h, a, a1, a2, bf, bf1, bf2, bw, bw1, bw2, bottom, dt, M, ww, p0, mean_tol, lin_tol, max_iter,
                       c, theta, alpha0, secant):  # pragma: no cover - numba
    """Every balanced stage of one grid: rows ``k`` of the coefficient arrays are stage ``k``'s (interior nodes),
    ``bottom[k]`` its absorbing row's ``(q00, q01, q02, q03)``; ``ww . M`` the mean. Per stage the multiplier is
    predicted (quadratic through the last three), then Newton on the exact derivative; once the miss is below
    ``lin_tol p0`` the state takes the step to first order (``M + dA dM/dA``) without another exponential, as the
    engine does. With ``secant``, plain exponentials first (no derivative): the predicted multiplier, then secant
    steps from the slope carried over from the last stage, Newton only where those fail to get within ``lin_tol``
    in two tries. Returns ``(M, n_exp, n_newton, info, stage)``."""
    n = M.size
    pl, pd, pu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    ql, qd, qu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    ppl, ppd, ppu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    qql, qqd, qqu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    row0 = np.zeros(2)
    drow0 = np.zeros(2)
    hist = np.zeros(3)
    carried = 0.0  # the mean's slope in the multiplier at the last stage
    n_exp = 0
    n_newton = 0
    for k in range(dt.size):
        if k >= 3:
            A = 3.0 * hist[0] - 3.0 * hist[1] + hist[2]
        elif k >= 1:
            A = hist[0]
        else:
            A = 0.0
        done = False
        if secant and k >= 1 and carried != 0.0:
            a_prev = 0.0
            m_prev = 0.0
            slope_s = carried
            for it in range(3):
                _pencil_rows(h, a[k], a1[k], a2[k], bf[k], bf1[k], bf2[k], bw[k], bw1[k], bw2[k], A, bottom[k], pl,
                             pd, pu, ql, qd, qu, ppl, ppd, ppu, qql, qqd, qqu, row0)
                x, dx, info = pencil_pfd(pl, pd, pu, ql, qd, qu, row0, dt[k], M, c, theta, alpha0, False, ppl, ppd,
                                         ppu, qql, qqd, qqu, drow0)
                n_exp += 1
                if info != 0:
                    return M, n_exp, n_newton, info, k
                miss = -p0
                for i in range(n):
                    miss += ww[i] * x[i]
                if it >= 1 and miss != m_prev:
                    slope_s = (miss - m_prev) / (A - a_prev)
                if abs(miss) <= mean_tol * p0:
                    M = x
                    done = True
                    carried = slope_s
                    break
                a_prev = A
                m_prev = miss
                A = A - miss / slope_s
                n_newton += 1
        for it in range(max_iter if not done else 0):
            _pencil_rows(h, a[k], a1[k], a2[k], bf[k], bf1[k], bf2[k], bw[k], bw1[k], bw2[k], A, bottom[k], pl, pd,
                         pu, ql, qd, qu, ppl, ppd, ppu, qql, qqd, qqu, row0)
            x, dx, info = pencil_pfd(pl, pd, pu, ql, qd, qu, row0, dt[k], M, c, theta, alpha0, True, ppl, ppd, ppu,
                                     qql, qqd, qqu, drow0)
            n_exp += 1
            if info != 0:
                return M, n_exp, n_newton, info, k
            miss = 0.0
            slope = 0.0
            for i in range(n):
                miss += ww[i] * x[i]
                slope += ww[i] * dx[i]
            miss -= p0
            carried = slope
            if abs(miss) <= mean_tol * p0:
                M = x
                done = True
                break
            if slope == 0.0:
                return M, n_exp, n_newton, -1, k
            step = -miss / slope
            n_newton += 1
            if abs(miss) <= lin_tol * p0:
                for i in range(n):
                    x[i] += step * dx[i]
                M = x
                A += step
                done = True
                break
            A += step
        if not done:
            return M, n_exp, n_newton, -1, k
        hist[2] = hist[1]
        hist[1] = hist[0]
        hist[0] = A
    return M, n_exp, n_newton, 0, -1


@njit(cache=True, nogil=True, error_model="numpy")
def _thomas(pl, pd, pu, rhs, x, cp):  # pragma: no cover - numba
    """``P x = rhs`` for the tridiagonal ``P`` (diagonally dominant; no pivoting)."""
    n = rhs.size
    x[0] = rhs[0] / pd[0]
    cp[0] = pu[0] / pd[0]
    for i in range(1, n):
        den = pd[i] - pl[i - 1] * cp[i - 1]
        cp[i] = pu[i] / den if i < n - 1 else 0.0
        x[i] = (rhs[i] - pl[i - 1] * x[i - 1]) / den
    for i in range(n - 2, -1, -1):
        x[i] -= cp[i] * x[i + 1]


@njit(cache=True, nogil=True, error_model="numpy")
def _band_mul(lower, diag, upper, row0, y, out):  # pragma: no cover - numba
    n = y.size
    for i in range(n):
        v = diag[i] * y[i]
        if i > 0:
            v += lower[i - 1] * y[i - 1]
        if i < n - 1:
            v += upper[i] * y[i + 1]
        out[i] = v
    out[0] += row0[0] * y[2] + row0[1] * y[3]


@njit(cache=True, nogil=True, error_model="numpy")
def _rate_parts(bands, row0, drow0, y, ww, x0, x1, t1, t2, cp):  # pragma: no cover - numba
    """The mean's rate ``ww . P(A)^-1 Q(A) y`` linearized at ``A = 0`` from the bands built there once (``bands``:
    ``P, Q, P_a, Q_a``): ``x0 = P^-1 Q y`` and ``x1 = P^-1 (Q_a y - P_a x0)``; returns ``(ww . x0, ww . x1)``."""
    _band_mul(bands[3], bands[4], bands[5], row0, y, t1)
    _thomas(bands[0], bands[1], bands[2], t1, x0, cp)
    _band_mul(bands[9], bands[10], bands[11], drow0, y, t1)
    _band_mul(bands[6], bands[7], bands[8], drow0, x0, t2)  # (P_a has no entries beyond the band: drow0 is 0)
    for i in range(y.size):
        t1[i] -= t2[i]
    _thomas(bands[0], bands[1], bands[2], t1, x1, cp)
    r0 = 0.0
    r1 = 0.0
    for i in range(y.size):
        r0 += ww[i] * x0[i]
        r1 += ww[i] * x1[i]
    return r0, r1


@njit(cache=True, nogil=True, error_model="numpy")
def compact_staged_predicted(h, a, a1, a2, bf, bf1, bf2, bw, bw1, bw2, bottom, dt, M, ww, p0, mean_tol, lin_tol,
                             max_iter, c, theta, alpha0):  # pragma: no cover - numba
    """:func:`compact_staged_run` with the engine's predictor (``_kernels.balanced_stage``) carried over: ``A_mid``
    from the mean's rate at the midpoint state (``ww . P^-1 Q(A) u = 0``, linear in ``A`` to ~1e-6), times the
    ratio ``A / A_mid`` of the last four stages extrapolated by a cubic, less the start's own miss over the carried
    slope; one plain exponential, a secant step with the carried slope where the miss is below ``lin_tol``, Newton
    with the derivative (and the first-order update) only where those fail."""
    n = M.size
    bands = np.zeros((12, n))  # P, Q, P_a, Q_a (lower and upper bands in the first n - 1 entries)
    row0 = np.zeros(2)
    drow0 = np.zeros(2)
    qy = np.empty(n)
    xr = np.empty(n)
    x1 = np.empty(n)
    t2 = np.empty(n)
    cp = np.empty(n)
    u = np.empty(n)
    pl, pd, pu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    ql, qd, qu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    ppl, ppd, ppu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    qql, qqd, qqu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    hist = np.zeros(K.PREDICTOR_SIZE)
    a_lin = 0.0
    n_exp = 0
    n_newton = 0
    for k in range(dt.size):
        args = (h, a[k], a1[k], a2[k], bf[k], bf1[k], bf2[k], bw[k], bw1[k], bw2[k])
        # the rate linearized at the last stage's multiplier (Q is quadratic in A, and A is large: about 1e5 here)
        _pencil_rows(*args, a_lin, bottom[k], bands[0], bands[1], bands[2], bands[3], bands[4], bands[5], bands[6],
                     bands[7], bands[8], bands[9], bands[10], bands[11], row0)
        r0, r1 = _rate_parts(bands, row0, drow0, M, ww, xr, x1, qy, t2, cp)
        A0 = a_lin - r0 / r1 if r1 != 0.0 else a_lin
        for i in range(n):
            u[i] = M[i] + 0.5 * dt[k] * (xr[i] + (A0 - a_lin) * x1[i])
        r0u, r1u = _rate_parts(bands, row0, drow0, u, ww, xr, x1, qy, t2, cp)
        a_mid = a_lin - r0u / r1u if r1u != 0.0 else A0
        s_lin = dt[k] * r1u
        s_pred = hist[4] * s_lin
        mean_y = -p0
        for i in range(n):
            mean_y += ww[i] * M[i]
        corr = mean_y / s_pred if s_pred < 0.0 else 0.0
        A = a_mid * K._predicted_ratio(hist) - corr
        have_d = not s_pred < 0.0
        slope = s_pred
        x = M
        dx = M
        err = 0.0
        a_prev = A
        done = False
        for it in range(max_iter):
            _pencil_rows(*args, A, bottom[k], pl, pd, pu, ql, qd, qu, ppl, ppd, ppu, qql, qqd, qqu, row0)
            x_new, dx_new, info = pencil_pfd(pl, pd, pu, ql, qd, qu, row0, dt[k], M, c, theta, alpha0, have_d, ppl,
                                             ppd, ppu, qql, qqd, qqu, drow0)
            n_exp += 1
            if info != 0:
                return M, n_exp, n_newton, info, k
            err_new = -p0
            for i in range(n):
                err_new += ww[i] * x_new[i]
            if have_d:
                slope = 0.0
                for i in range(n):
                    slope += ww[i] * dx_new[i]
            elif it >= 1 and A != a_prev and (err_new - err) / (A - a_prev) < 0.0:
                slope = (err_new - err) / (A - a_prev)
            x, dx, err = x_new, dx_new, err_new
            if abs(err) <= mean_tol * p0:
                done = True
                break
            if not slope < 0.0:
                return M, n_exp, n_newton, -1, k
            n_newton += 1
            step = -err / slope
            if have_d and abs(err) <= lin_tol * p0:  # the last step to first order on the state
                for i in range(n):
                    x[i] += step * dx[i]
                A += step
                err = 0.0
                done = True
                break
            a_prev = A
            A += step
            # a secant step with the carried slope first (plain); after it, the derivative
            have_d = it >= 1 or abs(err) > lin_tol * p0 or not s_pred < 0.0
        if not done:
            return M, n_exp, n_newton, -1, k
        M = x
        a_lin = A
        if slope < 0.0 and s_lin < 0.0:
            hist[4] = slope / s_lin
        if a_mid != 0.0:
            K._push_ratio(hist, (A - err / slope + corr) / a_mid if slope < 0.0 else A / a_mid)
    return M, n_exp, n_newton, 0, -1


def compact_inputs(scene: Scene, e: np.ndarray, shells: list, secant: bool = False) -> tuple:
    """The arguments of :func:`compact_staged_run` on the edges ``e`` (the prototype's coefficients)."""
    comp = CompactAbsorbing(scene, e)
    rows = [comp.parts(q) for _, q, _, _ in shells]
    stack = [np.ascontiguousarray(np.array([r[j][i] for r in rows])) for j in range(3) for i in range(3)]
    bottom = []
    for _, q, _, _ in shells:
        a0 = comp._at(comp.x[:1], q)[0][0]
        q00, q01, row0 = absorbing_bottom(comp.h, a0)
        bottom.append((q00, q01, row0[0], row0[1]))
    ww = comp.mean_weights.copy()
    ww[0] -= ww.sum()  # mean = ww . M (the weights of M - M_0)
    j = int(np.searchsorted(e, P0))
    M0 = corrected_delta_start(e.size, j)
    dt = np.array([0.5 * dv for dv, _, _, _ in shells])
    return (comp.h, *stack, np.ascontiguousarray(np.array(bottom)), dt, M0, ww, P0, MEAN_TOL, LIN_TOL, 30, RES,
            THETA, R_INF, secant)


def engine_inputs(scene: Scene, e: np.ndarray, shells: list) -> tuple:
    """The arguments of the engine's ``staged_run`` for the prototype's second-order scheme on ``e`` (``[z, m]``,
    the absorbing bottom), from the split delta at ``p0``."""
    sch = SchemeAbsorbing(scene, e)
    bands = [[], [], [], [], [], []]
    for _, q, _, _ in shells:
        l_fb, l_w = sch.operators(q)
        for j, op in enumerate((l_fb, l_w)):
            bands[3 * j].append(op.diagonal(-1))
            bands[3 * j + 1].append(op.diagonal(0))
            bands[3 * j + 2].append(op.diagonal(1))
    arrs = [np.ascontiguousarray(np.array(b)) for b in bands]
    n = e.size  # cells + 1 (z)
    y = np.zeros(n)
    j = int(np.searchsorted(e, P0))
    y[j] = y[j + 1] = 0.5  # [z, m]: the cells on both sides of p0
    dt = np.array([0.5 * dv for dv, _, _, _ in shells])
    theta, res, r_inf, _ = pfd_coefficients(16)
    return (*arrs, np.ones(len(shells), dtype=np.bool_), dt, np.ones(len(shells), dtype=np.int64),
            np.ascontiguousarray(sch.mean_weights), y, P0, MEAN_TOL, LIN_TOL, 30, True,
            np.ascontiguousarray(K.ALPHA), np.ascontiguousarray(theta), float(r_inf), np.ascontiguousarray(res),
            np.zeros(1, dtype=np.int64))


def median_time(fn, repeats: int) -> float:
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def _runner(args):
    return compact_staged_predicted if args.balance == "predicted" else compact_staged_run


def _args(args, inputs: tuple) -> tuple:
    return inputs[:-1] if args.balance == "predicted" else inputs


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.1, 0.01])
    ap.add_argument("--closures", nargs="+", default=["local_g1_balanced", "local_g1_shell_balanced"])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--balance", choices=("newton", "secant", "predicted"), default="newton",
                    help="the compact balance: Newton on the derivative (default), plain exponentials and secant "
                    "steps first, or the engine's predictor carried over (compact_staged_predicted)")
    args = ap.parse_args(argv)
    lines = ["# The compact stage loop compiled, against the engine's staged kernel (`python benchmarks/compact_staged.py`)",
             "", f"`fourth_order_space.py --absorbing --skip 0`'s problem (48 shells, bottom at 1e-16 p*), rtol "
             f"{RTOL:g}'s balance tolerances (mean {MEAN_TOL:g} p0, first-order update below {LIN_TOL:g} p0), "
             f"CRAM-16, one thread, medians of {args.repeats} calls per grid; the compact balance "
             + {"secant": "by plain exponentials and secant steps first", "newton": "by Newton on the exact derivative",
                "predicted": "by the engine's predictor carried over (`compact_staged_predicted`)"}[args.balance]
             + ". Check: the compiled compact run against "
             "the prototype's numpy one on the same grid (L1 of the masses).", ""]
    print("\n".join(lines), flush=True)
    for closure in args.closures:
        for zeta in args.zetas:
            scene = Scene(zeta, closure, 8)
            scene.floor_factor = 1e-16
            shells = scene.shells(SHELLS)
            e = grid(scene, 40, 2)
            inp = compact_inputs(scene, e, shells, args.balance == "secant")
            Mk, n_exp, n_newton, info, stage = _runner(args)(*_args(args, inp))
            y0 = np.concatenate(([0.0], np.diff(corrected_delta_start(e.size, int(np.searchsorted(e, P0)), 0.0))))
            ref = run_compact(CompactAbsorbing(scene, e), shells, y0, 1 / 24)
            mine = np.concatenate(([Mk[0]], np.diff(Mk)))
            lines.append(f"- `{closure}`, zeta {zeta:g}, {e.size - 1} cells: compiled against numpy "
                         f"{float(np.sum(np.abs(mine - ref))):.1e} (info {info}, {n_exp} exponentials and "
                         f"{n_newton} Newton steps for {len(shells)} stages)")
            print(lines[-1], flush=True)
    lines += ["", "Time per grid [ms], and the exponentials per call (compact: each with its derivative):", "",
              "| closure | zeta | cells | engine kernel, 2nd order | its exponentials | compact kernel | its exponentials "
              "| compact / engine |", "|---|---|---|---|---|---|---|---|"]
    for closure in args.closures:
        for zeta in args.zetas:
            scene = Scene(zeta, closure, 8)
            scene.floor_factor = 1e-16
            shells = scene.shells(SHELLS)
            for level in range(1, 7):
                e = grid(scene, 40, level)
                ci = compact_inputs(scene, e, shells, args.balance == "secant")
                ei = engine_inputs(scene, e, shells)
                run, ca = _runner(args), _args(args, ci)
                rc = run(*ca)
                re_ = K.staged_run(*ei)
                tc = median_time(lambda: run(*ca), args.repeats)
                te = median_time(lambda: K.staged_run(*ei), args.repeats)
                lines.append(f"| `{closure}` | {zeta:g} | {e.size - 1} | {te * 1e3:.2f} | {re_[1]} "
                             f"(info {re_[3]}) | {tc * 1e3:.2f} | {rc[1]} (info {rc[3]}) | {tc / te:.2f} |")
                print(lines[-1], flush=True)
    out = OUT.with_name(OUT.stem + ("" if args.balance == "newton" else "_" + args.balance) + ".md")
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
