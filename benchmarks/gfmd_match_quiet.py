"""Hard wall at n^2 (default 2048^2) at matched final-field error against Tamaas, with intermediate tolerances.

``bench_gfmd.part_match`` with our ``ccg`` at tol 1e-7, 4e-8, 2e-8 and 1e-8 (the
matched comparison takes the fastest of our tols whose max error is at most Tamaas'),
Tamaas 2.9 ``PolonskyKeerRey`` at 1e-8, interleaved rounds (2 at 2048^2, 3 below), one FFT thread and
``OMP_NUM_THREADS=1``.  Writes ``benchmarks/results/gfmd_match_{n}_quiet.json`` (the log beside it is
this script's output).  About 8 minutes at 2048^2 and 3 at 1024^2 on an idle 2-core machine; needs
``pip install -e ".[bench]"`` for Tamaas.

    python benchmarks/gfmd_match_quiet.py [--n 2048]
"""
import argparse
import json
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import bench_gfmd as b  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=2048, help="grid size (default: 2048)")
    n = ap.parse_args().n
    res = b.part_match(n, 2 if n >= 2048 else 3, our_tols=(1e-7, 4e-8, 2e-8, 1e-8), with_pk=False)
    res["date"] = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", f"gfmd_match_{n}_quiet.json")
    with open(out, "w") as fh:
        json.dump(res, fh, indent=1, default=float)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
