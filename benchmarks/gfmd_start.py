"""GFMD hard wall: does a low-pass start pay? (issue 10, item 4: "measure: coarse-grid or low-pass start").

The coarse-grid start was measured in an earlier session (docs/gfmd.md: more fine-grid iterations). This script
measures the low-pass start on the full grid: the Fig. 1 surface with its modes above ``k_c`` removed (``k`` the
wavenumber in units of ``2 pi/L``; the surface has modes up to ``k = 32``) is solved first, by the same ``ccg``
solver to a loose tolerance, and its pressure starts the full problem (the private ``p_start`` of
``gfmd_ref.solver._ccg_hard``; the contact set starts where that pressure is positive).  Printed per variant:
the iterations of the low-pass solve and of the full solve, the total FFT pairs, the total time (median over
``--repeats`` solves, after a warm-up), and the largest pressure difference to the uniform start's answer.

    python benchmarks/gfmd_start.py [--n 1024] [--seeds 1 2] [--repeats 3]

Writes ``results/gfmd_start.md``.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

import gfmd_ref as g
from gfmd_ref import solver

OUT = Path(__file__).resolve().parent / "results" / "gfmd_start.md"
E_STAR, P0, TOL = 8.0 / 3.0, 0.004, 1e-8


def low_pass(h: np.ndarray, k_c: float) -> np.ndarray:
    """``h`` without its Fourier modes of ``|k| > k_c`` (``k`` in units of ``2 pi / L``)."""
    n = h.shape[0]
    hk = np.fft.rfft2(h)
    kx = np.fft.fftfreq(n, 1.0 / n)[:, None]
    ky = np.fft.rfftfreq(n, 1.0 / n)[None, :]
    hk[np.hypot(kx, ky) > k_c] = 0.0
    return np.fft.irfft2(hk, s=h.shape)


def solve(h, length, p_start=None, tol=TOL) -> tuple:
    """``(result dict, wall time)`` of the ccg hard-wall solve (as ``solve_contact(method="ccg")`` runs it)."""
    el = solver._Elastic(h.shape[0], length, E_STAR, None)
    h_scale = float(np.std(h))
    t0 = time.perf_counter()
    out = solver._ccg_hard(h, P0, el, tol, 10_000, False, h_scale, precond=True, lazy=1, p_start=p_start)
    return out, time.perf_counter() - t0


def variant(h, length, k_c, tol_lp) -> tuple:
    """``(iterations low-pass, iterations full, FFT pairs, time, pressure)`` of one start (``k_c = None``: uniform)."""
    t0 = time.perf_counter()
    it_lp = pairs = 0
    start = None
    if k_c is not None:
        lp, _ = solve(low_pass(h, k_c), length, tol=tol_lp)
        it_lp, pairs, start = lp["iterations"], lp["info"]["fft_pairs"], lp["pressure"]
    out, _ = solve(h, length, p_start=start)
    assert out["converged"], out["stop"]
    return it_lp, out["iterations"], pairs + out["info"]["fft_pairs"], time.perf_counter() - t0, out["pressure"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    variants = [(None, None)] + [(k, t) for k in (16.0, 8.0, 4.0) for t in (1e-3, 1e-5)]
    g.warm_up_fft(args.n)
    lines = [f"# Low-pass start of the hard-wall `ccg` solve ({args.n}^2, Fig. 1 surface, tol {TOL:g}; "
             "`python benchmarks/gfmd_start.py`)", "",
             "| seed | start | low-pass iterations | full iterations | FFT pairs | time [s] (median) | ratio | "
             "max dp / p0 against the uniform start |", "|---|---|---|---|---|---|---|---|"]
    for seed in args.seeds:
        h, length = g.fig1_surface(args.n, seed=seed)
        variant(h, length, None, None)  # warm-up (kernels, plans)
        base_time, base_p = None, None
        for k_c, tol_lp in variants:
            runs = [variant(h, length, k_c, tol_lp) for _ in range(args.repeats)]
            t = statistics.median(r[3] for r in runs)
            it_lp, it, pairs, _, p = runs[-1]
            if k_c is None:
                base_time, base_p = t, p
            name = "uniform p0" if k_c is None else f"low-pass k <= {k_c:g}, tol {tol_lp:g}"
            line = (f"| {seed} | {name} | {it_lp} | {it} | {pairs} | {t:.3f} | {t / base_time:.2f} | "
                    f"{np.max(np.abs(p - base_p)) / P0:.1e} |")
            lines.append(line)
            print(line, flush=True)
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
