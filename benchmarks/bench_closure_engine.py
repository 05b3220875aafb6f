"""Warm time of the shell closures on the engine (native, rtol 1e-6) across walls: cells, exponentials, Newton steps.

With ``--threads 1,2`` each closure is timed with one and two threads (the finest grid in a second
thread), interleaved call by call, so the two columns share the machine's state.

Fig. 1 continuum scene (``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``,
``E* = 8/3``, ``p0 = 0.004``, 96 shells).  Median of ``--repeats`` warm runs after one warm-up.
To compare two versions of the package in the same run, call it twice with different
``PYTHONPATH`` (docs/closures.md reports such a before/after pair).  The machine is shared:
read ratios measured in the same run.

    python benchmarks/bench_closure_engine.py [--repeats 5] [--zetas 0.001,0.01,0.1,0.25,1,4] [--threads 1,2]
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import diffusion_pr as dp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--zetas", default="0.001,0.01,0.1,0.25,1,4")
    ap.add_argument("--closures", default="local_g1,local_g1_balanced,local_g1_shell_balanced")
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--threads", default="2", help="comma-separated thread counts, timed interleaved (default: 2)")
    args = ap.parse_args()
    threads = [int(t) for t in args.threads.split(",")]
    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    cols = " | ".join(f"warm time, {t} thread{'s' if t > 1 else ''} (ms, median)" for t in threads)
    print(f"| closure | zeta | {cols} | cells (N, 2N, 4N) | grids integrated | exponentials (finest) | Newton steps | "
          "estimate | success |")
    print("|---|---|" + "---|" * len(threads) + "---|---|---|---|---|---|")
    for cl in args.closures.split(","):
        for zeta in (float(z) for z in args.zetas.split(",")):
            runs = {t: (lambda t=t: dp.pressure_distribution(spec, E_star=8 / 3, mean_pressure=0.004, zeta=zeta,
                                                               closure=cl, rtol=args.rtol, threads=t,
                                                               shell_extrapolation=False))  # the 96-shell problem
                    for t in threads}
            for run in runs.values():
                r = run()
            times: dict = {t: [] for t in threads}
            for _ in range(args.repeats):
                for t, run in runs.items():
                    t0 = time.perf_counter()
                    r = run()
                    times[t].append(time.perf_counter() - t0)
            d = r.diagnostics
            cells = " | ".join(f"{1e3 * statistics.median(times[t]):.0f}" for t in threads)
            print(f"| {cl} | {zeta:g} | {cells} | {d['levels']} | {d.get('grids_integrated')} | "
                  f"{d.get('cram_applications')} | {d.get('newton_steps', 'n/a')} | {r.error_estimate:.1e} | "
                  f"{r.success} |", flush=True)


if __name__ == "__main__":
    main()
