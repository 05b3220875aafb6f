"""FFTW planning flags for one real 2-D FFT pair: ``FFTW_MEASURE`` (the package's plans) against ``FFTW_PATIENT``.

Each flag and precision is planned and timed in its own fresh process (no wisdom shared between them), alternating,
so that a plan is not favoured by what the previous one left in the cache.  Prints the planning time and the median
and minimum of 30 executions of ``rfft2`` + ``irfft2`` (1 thread) per process (docs/gfmd.md, "FFTW_PATIENT plans
measured").

    python benchmarks/fftw_planning.py [--n 1024] [--rounds 4]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r"""
import json, sys, time
import numpy as np, pyfftw
n, flag, real = int(sys.argv[1]), sys.argv[2], sys.argv[3]
cplx = "complex128" if real == "float64" else "complex64"
r = pyfftw.empty_aligned((n, n), dtype=real)
s = pyfftw.empty_aligned((n, n // 2 + 1), dtype=cplx)
t = time.perf_counter()
fwd = pyfftw.FFTW(r, s, axes=(0, 1), threads=1, flags=(flag, "FFTW_DESTROY_INPUT"), planning_timelimit=120)
bwd = pyfftw.FFTW(s, r, axes=(0, 1), direction="FFTW_BACKWARD", threads=1, flags=(flag, "FFTW_DESTROY_INPUT"),
                  planning_timelimit=120)
plan = time.perf_counter() - t
rng = np.random.default_rng(0)
times = []
for _ in range(30):
    r[...] = rng.standard_normal((n, n))
    t = time.perf_counter()
    fwd.execute()
    bwd.execute()
    times.append(time.perf_counter() - t)
print(json.dumps(dict(plan_s=plan, median_ms=1e3 * float(np.median(times)), min_ms=1e3 * min(times))))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=1024, help="grid size n (n x n) (default: 1024)")
    ap.add_argument("--rounds", type=int, default=4, help="fresh processes per flag and precision (default: 4)")
    args = ap.parse_args()
    print(f"| precision | flag | planning [s] | pair, median of 30 [ms] | pair, min [ms] |  (n = {args.n}, 1 thread)")
    print("|---|---|---|---|---|")
    for real in ("float64", "float32"):
        for _ in range(args.rounds):
            for flag in ("FFTW_MEASURE", "FFTW_PATIENT"):
                out = subprocess.run([sys.executable, "-c", CHILD, str(args.n), flag, real], capture_output=True,
                                     text=True, check=True)
                row = json.loads(out.stdout.strip().splitlines()[-1])
                print(f"| {real} | {flag} | {row['plan_s']:.1f} | {row['median_ms']:.2f} | {row['min_ms']:.2f} |",
                      flush=True)


if __name__ == "__main__":
    main()
