"""What one exponential of the compact fourth-order pencil costs in compiled code, against the engine's (issue 10).

The fiftieth session measured (``fourth_order_space.py``) that a compact fourth-order scheme on the primitive ``M``,
``P dM/dtau = Q M`` with ``P`` and ``Q`` tridiagonal, needs 4.5-10x fewer cells than the engine's second-order
finite volumes at the accuracy the balanced closures' answers need; it left the per-cell cost in a compiled kernel
unmeasured. Every CRAM pole of the pencil is a solve with ``t Q - theta P``, whose three bands are all complex
(the engine's ``t L - theta`` has real off-diagonals), and the right-hand side is ``P y`` (one real product). This
script times that solve, :func:`diffusion_pr.solvers.fv._compact_kernels.pencil_pfd` (the engine's style: a block
of poles eliminated together, row by row, complex scalars, no row interchanges: the pencil's rows are diagonally
dominant wherever the engine's are; a vanished pivot is flagged), with the balance derivative the engine's Newton
takes, beside the engine's own kernels on the same numbers of cells in the same process:

* ``engine, lanes``: :func:`diffusion_pr.solvers.fv._kernels.cram_pfd` (the poles in vector lanes, what the
  closures run);
* ``engine, scalar``: ``_pfd_pivoting`` (the same elimination one complex pole at a time: the like-for-like
  comparison with :func:`pencil_pfd`, which has no lane version yet);
* ``compact, scalar``: :func:`pencil_pfd`.

Each with and without the derivative in the balance multiplier (``want_d``). The bands are a balanced closure's at
a mid shell of the Fig. 1 scene at ``zeta = 0.1`` (engine: ``operator.bands``; compact: ``fourth_order_space``'s
pencil on its own grid family), time step one shell. Correctness first: :func:`pencil_pfd` against the prototype's
sparse-LU ``expm_pencil`` and its derivative against a central difference in the multiplier.

Then the projection the fiftieth session could not make: the kernel time of one exponential at the finest cells
each scheme needed for 3e-7 there (``fourth_order_space``'s tables), as a ratio. Writes
``results/compact_kernel_cost.md``.

    python benchmarks/compact_kernel_cost.py [--repeats 41]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_variance import median_time  # noqa: E402
from diffusion_pr.solvers.fv import _kernels as K  # noqa: E402
from diffusion_pr.solvers.fv._compact_kernels import pencil_pfd  # noqa: E402
from diffusion_pr.solvers.fv.cram import pfd_coefficients  # noqa: E402
from fourth_order_space import SHELLS, Compact, expm_pencil, grid  # noqa: E402
from shell_rule_balance import Scene  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "compact_kernel_cost.md"
THETA, RES, R_INF, _ = pfd_coefficients(16)
ROW0 = np.zeros(2)  # no bordered first row


def _bands_of(mat) -> tuple:
    """``(lower, diag, upper)`` of a sparse tridiagonal matrix, float64 C-contiguous."""
    return (np.ascontiguousarray(mat.diagonal(-1)), np.ascontiguousarray(mat.diagonal(0)),
            np.ascontiguousarray(mat.diagonal(1)))


def compact_case(zeta: float, closure: str, level: int, a_bal: float) -> tuple:
    """``(P bands, Q bands, P_a bands, Q_a bands, t, M, sparse (P, Q) at a_bal, the Compact)`` at a mid shell."""
    scene = Scene(zeta, closure, 8)
    shell = scene.shells(SHELLS)[SHELLS // 2]
    dv, q_mid = shell[0], shell[1]
    comp = Compact(scene, grid(scene, 40, level))
    # P is linear in the multiplier (through beta), Q quadratic (beta times B's derivatives): the central
    # difference over +-1 is their exact derivative at a_bal
    P0_, Q0_ = comp.pencil(q_mid, a_bal - 1.0)
    P1_, Q1_ = comp.pencil(q_mid, a_bal + 1.0)
    P, Q = comp.pencil(q_mid, a_bal)
    n = P.shape[0]
    m = np.exp(-0.5 * ((np.arange(n) - 0.4 * n) / (0.1 * n)) ** 2)
    M = np.cumsum(m) / m.sum()
    return (_bands_of(P), _bands_of(Q), _bands_of(0.5 * (P1_ - P0_)), _bands_of(0.5 * (Q1_ - Q0_)), 0.5 * dv, M, (P, Q), comp)


def engine_case(zeta: float, closure: str, n_cells: int) -> tuple:
    """The engine's ``(L bands, W bands, t, y)`` of the same shell on ``n_cells`` (sinh-graded) cells."""
    scene = Scene(zeta, closure, n_cells)
    shell = scene.shells(SHELLS)[SHELLS // 2]
    l_fb, l_w = scene.operators(shell[1])
    y = np.exp(-0.5 * ((np.arange(n_cells) - 0.4 * n_cells) / (0.1 * n_cells)) ** 2)
    return tuple(np.ascontiguousarray(b) for b in l_fb), tuple(np.ascontiguousarray(b) for b in l_w), \
        0.5 * shell[0], y / y.sum()


def check(zeta: float, closure: str) -> list:
    """:func:`pencil_pfd` against the prototype's sparse LU, and its derivative against a central difference."""
    lines = []
    for level in (1, 3):
        a = 0.3
        pb, qb, pab, qab, t, M, (P, Q), comp = compact_case(zeta, closure, level, a)
        x, dx, info = pencil_pfd(*pb, *qb, ROW0, t, M, RES, THETA, R_INF, True, *pab, *qab, ROW0)
        ref = expm_pencil(P, Q, t, M)
        h = 1e-2  # the exponential is smooth in a (P linear, Q quadratic in it); the derivative is ~4e-7 of M's
        # scale, so a smaller step loses digits to the pencil solves' round-off (1e-4: 3e-4 relative)
        q_mid = Scene(zeta, closure, 8).shells(SHELLS)[SHELLS // 2][1]
        xp = expm_pencil(*comp.pencil(q_mid, a + h), t, M)
        xm = expm_pencil(*comp.pencil(q_mid, a - h), t, M)
        fd = (xp - xm) / (2 * h)
        lines.append(f"| {P.shape[0] - 1} | {float(np.max(np.abs(x - ref))):.1e} | "
                     f"{float(np.max(np.abs(dx - fd)) / max(float(np.max(np.abs(fd))), 1e-300)):.1e} | {info} |")
    return lines


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=41)
    ap.add_argument("--zeta", type=float, default=0.1)
    ap.add_argument("--closure", default="local_g1_balanced")
    args = ap.parse_args(argv)
    lines = [f"# One exponential of the compact pencil against the engine's (`python benchmarks/compact_kernel_cost.py`)",
             "", f"`{args.closure}`, `zeta = {args.zeta}`, the bands of shell {SHELLS // 2} of {SHELLS}, CRAM-16, "
             f"medians of {args.repeats} calls, one thread.", "",
             "Correctness of `pencil_pfd` (compact pencil, multiplier 0.3): max difference from the prototype's "
             "sparse LU, relative max difference of the derivative from a central difference (step 1e-2: its own error is about 1e-6 of it), and "
             "the pivot flag:", "", "| cells | x | dx/da (rel.) | info |", "|---|---|---|---|"]
    lines += check(args.zeta, args.closure)
    lines += ["", "(The kernel's derivative terms in `P_a`, about 6e-7 of `P` here, are checked on a pencil where they "
              "matter in `tests/diffusion_pr/test_fv_compact.py`.)"]
    lines += ["", "Time per exponential [us] and per cell and pole [ns]:", "",
              "| cells | engine, lanes | engine, scalar | compact, scalar | engine, lanes, d | engine, scalar, d | "
              "compact, scalar, d | compact/engine scalar | compact/engine scalar, d |",
              "|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    cw, r0 = K.flux_weights(RES, THETA, R_INF)
    per = {}
    for level in range(6):  # 40 .. 1280 cells on the prototype's family; the engine's on the same counts
        pb, qb, pab, qab, t, M, _, _ = compact_case(args.zeta, args.closure, level, 0.3)
        n = pb[1].size - 1
        (lo, di, upd), (wl, wd, wu), te, y = engine_case(args.zeta, args.closure, n)
        row = []
        for want_d in (False, True):
            f_lanes = lambda: K.cram_pfd(lo, di, upd, wl, wd, wu, te, y, RES, THETA, R_INF, want_d)  # noqa: E731
            f_scal = lambda: K._pfd_pivoting(lo, di, upd, wl, wd, wu, te, y, RES, cw, r0, THETA,  # noqa: E731
                                             want_d)
            f_comp = lambda: pencil_pfd(*pb, *qb, ROW0, t, M, RES, THETA, R_INF, want_d, *pab, *qab, ROW0)  # noqa: E731
            row.append([median_time(f, args.repeats) for f in (f_lanes, f_scal, f_comp)])
        per[n] = row
        cells = [f"{v * 1e6:.0f} ({v * 1e9 / (n * 8):.1f})" for v in row[0] + row[1]]
        lines.append(f"| {n} | " + " | ".join(cells) + f" | {row[0][2] / row[0][1]:.2f} | "
                     f"{row[1][2] / row[1][1]:.2f} |")
        print(lines[-1], flush=True)
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
