"""Does the GFMD reference give the same answers as another version of it, bit for bit?  A check for changes of the
hard-wall solver meant to be speed only (the gap, direction and step kernels, the layout of the contact set).

``save`` solves 12 hard-wall problems and writes their pressures, displacements and counters (iterations, FFT pairs,
increments) to a file; ``check`` solves them again with the code as it is now and lists those whose bits differ,
with the largest pressure change (so that round-off can be told from a change of answer):

    python benchmarks/gfmd_same_bits.py save /tmp/gfmd_base.npz     # before the change
    python benchmarks/gfmd_same_bits.py check /tmp/gfmd_base.npz    # after it

The problems: the Fig. 1 surface at 64², 255² (odd: the scipy FFT path), 256², 512² and 1024², tiny and moderate
contact areas, ``ccg`` with every switch of the single-precision search (the default, no increments, the step
length in double, all double), plain ``pk``, and ``ccg`` from the private start pressure ``p_start``.  tol 1e-9.
About 15 s.
"""
from __future__ import annotations

import argparse
import warnings

import numpy as np

import gfmd_ref as g
from gfmd_ref import solver as sv

from bench_gfmd import solver_switches

E_STAR, TOL = 8 / 3, 1e-9
CASES = [("ccg", 1024, 1, 0.004, {}), ("ccg", 256, 2, 0.004, {}), ("ccg", 256, 3, 1e-4, {}),
         ("ccg", 512, 1, 0.004, {}), ("ccg", 256, 1, 0.004, {"INCREMENT_U32": False}),
         ("ccg", 256, 1, 0.004, {"SINGLE_STEP": False}), ("ccg", 256, 1, 0.004, {"SINGLE_PRECOND": False}),
         ("pk", 256, 1, 0.004, {}), ("pk", 512, 2, 0.004, {}), ("ccg", 64, 1, 0.004, {}), ("ccg", 255, 1, 0.01, {})]


def answers() -> dict:
    out = {}
    for i, (method, n, seed, p0, flags) in enumerate(CASES):
        h, length = g.fig1_surface(n, seed=seed)
        with solver_switches(**flags), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = g.solve_contact(h, length=length, E_star=E_STAR, mean_pressure=p0, interaction=g.HardWall(), tol=TOL,
                                method=method)
        out[f"pressure_{i}"], out[f"displacement_{i}"] = r.pressure, r.displacement
        out[f"counts_{i}"] = np.array([r.iterations, r.info["fft_pairs"], r.info.get("u_increments", 0)])
        print(f"{i:2d} {method} {n}^2 seed {seed} p0 {p0:g} {flags or ''}: {r.iterations} it, "
              f"{r.info['fft_pairs']} pairs, converged {r.converged}", flush=True)
    h, length = g.fig1_surface(256, seed=1)
    el = sv._Elastic(256, length, E_STAR)
    start = np.clip(h - h.mean(), 0.0, None) + 1e-3
    r = sv._ccg_hard(h, 0.004, el, TOL, 10_000, False, 1e-3, precond=True, lazy=1, p_start=start)
    out["pressure_p_start"] = r["pressure"]
    out["counts_p_start"] = np.array([r["iterations"], r["info"]["fft_pairs"]])
    print(f"p_start 256^2: {r['iterations']} it, {r['info']['fft_pairs']} pairs", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mode", choices=["save", "check"])
    ap.add_argument("path")
    args = ap.parse_args(argv)
    now = answers()
    if args.mode == "save":
        np.savez(args.path, **now)
        print(f"saved {len(now)} arrays to {args.path}")
        return 0
    base = np.load(args.path)
    differ = [k for k in base.files if not np.array_equal(base[k], now[k])]
    for k in differ:
        d = np.max(np.abs(base[k] - now[k])) if base[k].shape == now[k].shape else "shape"
        print(f"DIFFERS {k}: largest change {d}" + (f" ({base[k]} -> {now[k]})" if k.startswith("counts") else ""))
    print(f"{len(base.files) - len(differ)} of {len(base.files)} the same bits")
    return 1 if differ else 0


if __name__ == "__main__":
    raise SystemExit(main())
