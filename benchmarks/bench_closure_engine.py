"""Warm time of the shell closures on the engine (native, rtol 1e-6) across walls: cells, exponentials, Newton steps.

Fig. 1 continuum scene (``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``,
``E* = 8/3``, ``p0 = 0.004``, 96 shells).  Median of ``--repeats`` warm runs after one warm-up.
To compare two versions of the package in the same run, call it twice with different
``PYTHONPATH`` (docs/closures.md reports such a before/after pair).  The machine is shared:
read ratios measured in the same run.

    python benchmarks/bench_closure_engine.py [--repeats 5] [--zetas 0.001,0.01,0.1,0.25,1,4]
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
    args = ap.parse_args()
    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    print("| closure | zeta | warm time (ms, median) | cells (N, 2N, 4N) | exponentials (finest) | Newton steps | "
          "estimate | success |")
    print("|---|---|---|---|---|---|---|---|")
    for cl in args.closures.split(","):
        for zeta in (float(z) for z in args.zetas.split(",")):
            run = lambda: dp.pressure_distribution(spec, E_star=8 / 3, mean_pressure=0.004, zeta=zeta,  # noqa: E731
                                                   closure=cl, rtol=args.rtol)
            r = run()
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                r = run()
                times.append(time.perf_counter() - t0)
            d = r.diagnostics
            print(f"| {cl} | {zeta:g} | {1e3 * statistics.median(times):.0f} | {d['levels']} | "
                  f"{d.get('cram_applications')} | {d.get('newton_steps', 'n/a')} | {r.error_estimate:.1e} | "
                  f"{r.success} |", flush=True)


if __name__ == "__main__":
    main()
