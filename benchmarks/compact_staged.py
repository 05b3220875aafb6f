"""The compact scheme's whole stage loop compiled, timed against the engine's own staged kernel (issue 10).

``compact_kernel_cost.py`` timed one exponential. A closure call integrates every shell with its balance on
three nested grids per level, and the engine's kernel (:func:`diffusion_pr.solvers.fv._kernels.staged_run`) does
that with a predictor that usually needs a single plain exponential per stage. This script times the compact
scheme's stage loop as one compiled call (the package's ``_compact_kernels.staged_run``: the pencil's rows made per Newton iterate
from the coefficient rows, the absorbing bottom as the bordered first row, the balance by Newton on the exact
derivative of ``pencil_pfd`` from a predicted multiplier, the engine's first-order state update once the miss is
below ``lin_tol``) against the engine's ``staged_run`` on the prototype's problem (``fourth_order_space.py
--absorbing --skip 0``: the Fig. 1 scene, 48 uniform midpoint shells, the bottom at ``1e-16 p*``), each on the
three nested grids of the finest it needs for 3e-7 (that script's tables): the work of one level.

First the kernel is checked against the prototype's numpy solver (``run_compact``) on the same grid: the two
balance searches stop at different points within their tolerances, so they agree to about the balance tolerance.

    python benchmarks/compact_staged.py [--zetas 0.1 0.01] [--repeats 7] [--balance newton|predicted]

(A third balance, plain exponentials and secant steps first, was measured at commit 7c759d0,
``results/compact_staged_secant.md``: about three exponentials per stage, 3.7-4.3x the engine; removed since.)
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_variance import median_time  # noqa: E402
from diffusion_pr.solvers.fv import _kernels as K  # noqa: E402
from diffusion_pr.solvers.fv._compact_kernels import _band_product, pencil_pfd, pencil_rows, staged_run  # noqa: E402
from diffusion_pr.solvers.fv.compact import absorbing_bottom, corrected_delta_start  # noqa: E402
from diffusion_pr.solvers.fv.cram import pfd_coefficients  # noqa: E402
from fourth_order_space import P0, SHELLS, CompactAbsorbing, SchemeAbsorbing, grid, run_compact  # noqa: E402
from shell_rule_balance import Scene  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "compact_staged.md"
THETA, RES, R_INF, _ = pfd_coefficients(16)
RTOL = 1e-6
MEAN_TOL, LIN_TOL = 1e-2 * RTOL, math.sqrt(1e-2 * RTOL)  # the engine's at rtol 1e-6 (MEAN_TOL_FRACTION, ...)


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
    """``out = T y`` for the tridiagonal ``T`` with row 0's entries in columns 2 and 3 (``row0``)."""
    _band_product(lower, diag, upper, y, out)
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
    """The package's ``staged_run`` with the engine's predictor (``_kernels.balanced_stage``) carried over: ``A_mid``
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
        pencil_rows(*args, a_lin, bottom[k], bands[0], bands[1], bands[2], bands[3], bands[4], bands[5], bands[6],
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
            pencil_rows(*args, A, bottom[k], pl, pd, pu, ql, qd, qu, ppl, ppd, ppu, qql, qqd, qqu, row0)
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


def compact_inputs(scene: Scene, e: np.ndarray, shells: list) -> tuple:
    """The arguments of the package's ``staged_run`` on the edges ``e`` (the prototype's coefficients)."""
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
    return (comp.h, *stack, np.ascontiguousarray(np.array(bottom)), dt, np.ones(dt.size, dtype=np.bool_), M0, ww,
            P0, MEAN_TOL, LIN_TOL, 30, RES, THETA, R_INF)


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


def _runner(args):
    """``(M, n_exp, n_newton, info, stage)`` of the chosen balance on :func:`compact_inputs`' arguments."""
    if args.balance == "predicted":
        return lambda *inp: compact_staged_predicted(*inp[:12], *inp[13:])  # (no stage flags: all balanced)
    return lambda *inp: (lambda r: (r[0], *r[2:]))(staged_run(*inp))


def _args(args, inputs: tuple) -> tuple:
    return inputs


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.1, 0.01])
    ap.add_argument("--closures", nargs="+", default=["local_g1_balanced", "local_g1_shell_balanced"])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--balance", choices=("newton", "predicted"), default="newton",
                    help="the compact balance: Newton on the derivative (the package's staged_run, default), or the "
                    "engine's predictor carried over (compact_staged_predicted)")
    args = ap.parse_args(argv)
    lines = ["# The compact stage loop compiled, against the engine's staged kernel (`python benchmarks/compact_staged.py`)",
             "", f"`fourth_order_space.py --absorbing --skip 0`'s problem (48 shells, bottom at 1e-16 p*), rtol "
             f"{RTOL:g}'s balance tolerances (mean {MEAN_TOL:g} p0, first-order update below {LIN_TOL:g} p0), "
             f"CRAM-16, one thread, medians of {args.repeats} calls per grid; the compact balance "
             + {"newton": "by Newton on the exact derivative (the package's `staged_run`)",
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
            inp = compact_inputs(scene, e, shells)
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
                ci = compact_inputs(scene, e, shells)
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
