"""Cold start: the first closure result in a fresh Python process, numba's cache warm and cold.

Each measurement is one fresh process that imports ``diffusion_pr``, builds the Fig. 1 spectrum and solves one
closure (rtol 1e-6); ``first result`` is the time from before the import to the answer, ``process`` the child's
whole wall time seen from the parent (interpreter start-up included).

* ``warm``: the source tree as it is, after one process has filled numba's cache (every run after the first
  one after installing);
* ``cold``: a fresh copy of the tree's packages without any ``__pycache__``, with ``NUMBA_CACHE_DIR`` and
  ``XDG_CACHE_HOME`` pointing at empty directories: the first run after installing (numba compiles).

    python benchmarks/cold_start.py [--quick]
"""
from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import HERE, cli, fmt, section, table

CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
import diffusion_pr as dp
import numpy as np
t1 = time.perf_counter()
S = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
r = dp.pressure_distribution(S, E_star=8 / 3, mean_pressure=0.004, zeta=float(sys.argv[2]), closure=sys.argv[1],
                             rtol=1e-6)
t2 = time.perf_counter()
print(json.dumps(dict(import_s=t1 - t0, first_s=t2 - t0, success=bool(r.success))))
"""
PACKAGES = ("diffusion_pr", "gfmd_ref")


def child_env(tree: Path, **extra: str) -> dict:
    """The environment of a child process that runs the packages of ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree), **extra}
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # byte code cached, as in a default installation
    return env


def first_result(tree: Path, closure: str = "local_g1_balanced", zeta: float = 0.25, cold: bool = False) -> dict:
    """One fresh process: ``import_s``, ``first_s`` (import to answer), ``process_s``, ``success``."""
    tmp = Path(tempfile.mkdtemp(prefix="cold_start_")) if cold else None
    try:
        if cold:
            for pkg in PACKAGES:
                if (Path(tree) / pkg).is_dir():
                    shutil.copytree(Path(tree) / pkg, tmp / "src" / pkg,
                                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc"))
            env = child_env(tmp / "src", NUMBA_CACHE_DIR=str(tmp / "numba"), XDG_CACHE_HOME=str(tmp / "xdg"))
        else:
            env = child_env(Path(tree))
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", CHILD, closure, repr(zeta)], capture_output=True, text=True,
                             env=env, cwd=tempfile.gettempdir())
        wall = time.perf_counter() - t0
        if out.returncode != 0:
            raise RuntimeError(f"child failed (rc {out.returncode}): {out.stderr.strip()[-400:]}")
        return {**json.loads(out.stdout.strip().splitlines()[-1]), "process_s": wall}
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def run(quick: bool = False, tree: Path = HERE.parent) -> str:
    cases = [("local_g1_balanced", 0.25)] if quick else [(c, z) for c in ("local_g1", "local_g1_balanced",
                                                                           "local_g1_shell_balanced")
                                                         for z in (0.25, 0.01)]
    rounds, cold_rounds = (3, 0) if quick else (5, 1)  # a cold process compiles for minutes on a loaded machine
    rows = []
    for closure, zeta in cases:
        first_result(tree, closure, zeta)  # fill the cache
        warm = [first_result(tree, closure, zeta) for _ in range(rounds)]
        cold = [first_result(tree, closure, zeta, cold=True) for _ in range(cold_rounds)] \
            if (closure, zeta) == ("local_g1_balanced", 0.25) else []  # one compile: minutes on a loaded machine
        for name, rr in (("warm", warm), ("cold", cold)):
            if rr:
                rows.append((f"`{closure}`", f"{zeta:g}", name, len(rr),
                             fmt(statistics.median(r["import_s"] for r in rr), ".3f"),
                             fmt(statistics.median(r["first_s"] for r in rr), ".3f"),
                             fmt(statistics.median(r["process_s"] for r in rr), ".3f"), all(r["success"] for r in rr)))
    body = table(["closure", "zeta", "numba cache", "processes", "import [s]", "first result [s]", "process [s]",
                  "success"], rows)
    return section("Cold start: first closure result in a fresh process", body,
                   "Medians over fresh processes; cold: a fresh copy of the packages, empty NUMBA_CACHE_DIR and "
                   "XDG_CACHE_HOME (numba compiles every kernel the call needs)."
                   + (" The quick run skips the cold process." if quick else ""))


if __name__ == "__main__":
    cli(run, __doc__)
