"""GFMD ensembles: throughput of ``gfmd_ref.run_ensemble`` in this process and on a local Dask cluster.

The Fig. 1 scene (hard wall and zeta = 0.25, tol 1e-6, seeds 1, 2, ...) at each size, run into a fresh store:
``serial=True`` (one case after the other in this process) against ``workers=2`` (a local cluster of two
single-threaded workers, started and closed by the call, so its start-up is billed).  Cases per minute = cases /
the call's wall time; the ratio is cluster over serial.  A first serial run of one small case compiles the kernels.
Without Dask the cluster rows are skipped with a note.

    python benchmarks/bench_ensemble.py [--quick]
"""
from __future__ import annotations

import shutil
import tempfile
import time

from common import cli, fmt, section, table


def timed_run(n: int, seeds: str, **kw) -> tuple:
    """``(seconds, cases, success)`` of one ``run_ensemble`` call into a temporary store."""
    import gfmd_ref as g

    store = tempfile.mkdtemp(prefix="bench_ensemble_")
    try:
        t0 = time.perf_counter()
        run = g.run_ensemble(store, n=n, seeds=seeds, walls="hard,0.25", progress=False, verbose=False, **kw)
        return time.perf_counter() - t0, run.n_computed, bool(run.success)
    finally:
        shutil.rmtree(store, ignore_errors=True)


def run(quick: bool = False) -> str:
    sizes, seeds = ((256,), "1-2") if quick else ((256, 512, 1024), "1-4")
    timed_run(64, "1", serial=True)  # compile
    try:
        import dask.distributed  # noqa: F401
        modes = {"serial": dict(serial=True), "2 workers x 1 thread": dict(workers=2, threads_per_worker=1)}
        note = ""
    except ImportError:
        modes, note = {"serial": dict(serial=True)}, "Dask is not installed: the cluster rows are skipped."
    rows = []
    for n in sizes:
        serial = None
        for name, kw in modes.items():
            seconds, cases, ok = timed_run(n, seeds, **kw)
            serial = serial or seconds
            rows.append((f"{n}^2", name, cases, fmt(seconds, ".1f"), fmt(60 * cases / seconds, ".1f"),
                         fmt(seconds / serial, ".2f"), ok))
    body = table(["n", "run", "cases", "wall time [s]", "cases / min", "time / serial", "success"], rows)
    return section("GFMD ensembles (run_ensemble)", body,
                   "One run per row; the cluster's start-up is in its time. On a machine shared with other jobs "
                   "the cluster's gain is below the core count.", note)


if __name__ == "__main__":
    cli(run, __doc__)
