"""The partial-fraction kernel's block of poles against the grid's size: where splitting the block pays.

:func:`diffusion_pr.solvers.fv._kernels.cram_pfd` eliminates a block of poles together, row by row, in vector
lanes; while the block's arrays exceed ``_PFD_BLOCK_WORDS`` lane-row-arrays it is halved (``_block_size``). The
constant is compiled into the kernels, so each value is measured in a fresh process on a copy of the package with
that value (its own numba cache, the machine-code store off). Per value, order (CF-10, CF-12, CRAM-16) and cells:
the median time of one application [ns per cell and pole], plain and with the balance derivative (``want_d``), on
a diffusion matrix with balance bands. Writes ``results/pfd_block_words.md``.

    python benchmarks/pfd_block_words.py [--words 80000 250000 100000000] [--cells 1264 2528 5056 10112 20224]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = Path(__file__).resolve().parent / "results" / "pfd_block_words.md"

CHILD = r"""
import json, sys, time
import numpy as np
from diffusion_pr.solvers.fv import _kernels as K
from diffusion_pr.solvers.fv.cram import pfd_coefficients
cells = json.loads(sys.argv[1])
out = {"words": K._PFD_BLOCK_WORDS, "rows": []}
for order in (10, 12, 16):
    theta, c, alpha0, _ = pfd_coefficients(order)
    for n in cells:
        h = 1.0 / n
        lower = np.full(n, 1 / h**2); upper = np.full(n, 1 / h**2); diag = np.full(n, -2 / h**2)
        lower[0] = 0.0; upper[-1] = 0.0
        wl = np.full(n, 0.1); wd = np.full(n, -0.2); wu = np.full(n, 0.1)
        y = np.random.default_rng(0).random(n)
        row = {"order": order, "n": n, "split": {}, "ns": {}}
        for want_d in (False, True):
            row["split"][str(want_d)] = int(K._block_size(n, theta.size, want_d))
            K.cram_pfd(lower, diag, upper, wl, wd, wu, 1e-3, y, c, theta, alpha0, want_d)
            ts = []
            for _ in range(max(20, int(2e5 / n))):
                t0 = time.perf_counter()
                K.cram_pfd(lower, diag, upper, wl, wd, wu, 1e-3, y, c, theta, alpha0, want_d)
                ts.append(time.perf_counter() - t0)
            row["ns"][str(want_d)] = float(np.median(ts)) * 1e9 / n / theta.size
        out["rows"].append(row)
print(json.dumps(out))
"""


def measure(words: int, cells: list) -> dict:
    """The child's table on a copy of the package with ``_PFD_BLOCK_WORDS = words``."""
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copytree(ROOT / "diffusion_pr", Path(tmp) / "diffusion_pr",
                        ignore=shutil.ignore_patterns("__pycache__", "*.mc"))
        src = Path(tmp) / "diffusion_pr" / "solvers" / "fv" / "_kernels.py"
        text, count = re.subn(r"^_PFD_BLOCK_WORDS = .*$", f"_PFD_BLOCK_WORDS = {int(words)}", src.read_text(),
                              flags=re.M)
        if count != 1:
            raise RuntimeError("_PFD_BLOCK_WORDS not found once in _kernels.py")
        src.write_text(text)
        env = {**os.environ, "PYTHONPATH": tmp, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba"),
               "DIFFUSION_PR_MACHINE_CODE": "0"}
        done = subprocess.run([sys.executable, "-c", CHILD, json.dumps(cells)], env=env, cwd=tmp, check=True,
                              capture_output=True, text=True)
        return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--words", type=int, nargs="+", default=[80000, 250000, 100_000_000])
    ap.add_argument("--cells", type=int, nargs="+", default=[1264, 2528, 5056, 10112, 20224])
    args = ap.parse_args(argv)
    tables = [measure(w, args.cells) for w in args.words]
    head = " | ".join(f"{t['words']}: plain / with d (poles per block)" for t in tables)
    lines = ["# The partial-fraction kernel's block of poles (`python benchmarks/pfd_block_words.py`)", "",
             f"Load average {os.getloadavg()[0]:.2f}. Median time of one application of `cram_pfd` [ns per cell and "
             "pole], by `_PFD_BLOCK_WORDS` (each in a fresh process on a copy of the package).", "",
             f"| order | cells | {head} |", "|---|---|" + "---|" * len(tables)]
    for k, row in enumerate(tables[0]["rows"]):
        cells = []
        for t in tables:
            r = t["rows"][k]
            cells.append(f"{r['ns']['False']:.2f} / {r['ns']['True']:.2f} ({r['split']['False']} / "
                         f"{r['split']['True']})")
        lines.append(f"| {row['order']} | {row['n']} | " + " | ".join(cells) + " |")
    print("\n".join(lines))
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
