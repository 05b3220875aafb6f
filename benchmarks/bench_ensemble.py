"""Ensemble runner benchmarks: throughput, memory per worker, scheduler overhead.

Usage::

    python benchmarks/bench_ensemble.py                 # throughput table (short)
    python benchmarks/bench_ensemble.py --sizes 256 1024 2048 --configs 1x1 1x2 2x1
    python benchmarks/bench_ensemble.py --overhead      # scheduler overhead per case
    python benchmarks/bench_ensemble.py --check-ingest DIR  # live run == ingested cached fields

Throughput: the Fig. 1 scene (hard wall and zeta = 0.25 alternating, tol 1e-6) on a
local cluster of ``W`` worker processes with ``T`` FFT threads each (config
``WxT``); every worker plans its FFTs before the clock starts (the planning, ~2 s
per grid size and process, is paid once per worker and reported apart). Cases per
minute = cases / (time from the first submit to the last record written).
Memory: peak resident set size of each worker process (``ru_maxrss``) after
its cases. Overhead: round trip of a no-op task through the scheduler, and a
tiny-case ensemble on the cluster against the same cases in this process.
Timings are medians of ``--repeats`` runs; the machine (2 cores) was shared
with other jobs when the numbers in docs/ensembles.md were taken.
"""
from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _noop(x):
    return x


def throughput(sizes, configs, cases_per, repeats, keep=None):
    from gfmd_ref import warm_up_fft
    from gfmd_ref.ensemble import _local_cluster, run_ensemble

    rows = []
    for n in sizes:
        k = cases_per.get(n, 2)
        for ci, cfg in enumerate(configs):
            W, T = (int(v) for v in cfg.split("x"))
            client, cluster, desc = _local_cluster(W, T)
            try:
                plan = client.run(warm_up_fft, n)
                t_plan = max(plan.values())
                times = []
                for rep in range(repeats):
                    tmp = tempfile.mkdtemp(prefix="bench_ens_")
                    # Fig. 1 seeds, distinct per config and repeat (kept stores give a finite-size view)
                    first = 1 + (ci * repeats + rep) * max(1, k // 2)
                    seeds = f"{first}-{first + k // 2 - 1}" if k > 1 else f"{first}"
                    walls = "hard,0.25" if k > 1 else "hard"
                    t1 = time.perf_counter()
                    run = run_ensemble(tmp, n=n, seeds=seeds, walls=walls, client=client, progress=False,
                                       verbose=False)
                    times.append(time.perf_counter() - t1)
                    assert run.n_computed == k and run.success, run.message
                    if keep:
                        dest = Path(keep) / f"n{n}_{cfg}_r{rep}"
                        shutil.rmtree(dest, ignore_errors=True)
                        shutil.move(tmp, dest)
                    else:
                        shutil.rmtree(tmp)
                rss = client.run(_peak_rss_mb)
                med = statistics.median(times)
                rows.append(dict(n=n, config=cfg, workers=W, fft_threads=T, cases=k, repeats=repeats,
                                 seconds_median=med, cases_per_min=60.0 * k / med,
                                 planning_s=t_plan, peak_rss_mb_per_worker=max(rss.values())))
                print(f"n={n:5d} {cfg:>4}: {60 * k / med:7.2f} cases/min ({k} cases, median {med:.1f} s of "
                      f"{repeats}; FFT planning {t_plan:.1f} s/worker; peak RSS {max(rss.values()):.0f} MB/worker)",
                      flush=True)
            finally:
                client.close()
                cluster.close()
    return rows


def overhead(n_tasks=300):
    from gfmd_ref.ensemble import _local_cluster, run_ensemble

    client, cluster, desc = _local_cluster(2, 1)
    try:
        client.submit(_noop, 0).result()
        t0 = time.perf_counter()
        futs = [client.submit(_noop, i, pure=False) for i in range(n_tasks)]
        client.gather(futs)
        per_task = (time.perf_counter() - t0) / n_tasks
        t_single = []
        for i in range(30):
            t1 = time.perf_counter()
            client.submit(_noop, i, pure=False).result()
            t_single.append(time.perf_counter() - t1)
        # tiny cases: cluster (2 workers) against this process
        tmp = tempfile.mkdtemp()
        # warm the workers (imports, numba cache) on other seeds first
        run_ensemble(tmp + "/w", n=64, seeds="900-903", walls="hard", client=client, progress=False, verbose=False)
        t1 = time.perf_counter()
        run_ensemble(tmp + "/c", n=64, seeds="1-20", walls="hard", client=client, progress=False, verbose=False)
        t_cluster = time.perf_counter() - t1
        t1 = time.perf_counter()
        run_ensemble(tmp + "/s", n=64, seeds="1-20", walls="hard", serial=True, progress=False, verbose=False)
        t_serial = time.perf_counter() - t1
        shutil.rmtree(tmp)
    finally:
        client.close()
        cluster.close()
    out = dict(noop_throughput_ms=1e3 * per_task, noop_roundtrip_ms=1e3 * statistics.median(t_single),
               tiny_cases=20, tiny_cluster_s=t_cluster, tiny_serial_s=t_serial,
               overhead_per_case_ms=1e3 * (t_cluster - t_serial / 2) / 20 * 2)
    print(f"no-op task: {out['noop_throughput_ms']:.2f} ms/task in bulk, {out['noop_roundtrip_ms']:.1f} ms round trip; "
          f"20 tiny cases (64^2): cluster (2 workers) {t_cluster:.2f} s, this process {t_serial:.2f} s: "
          f"overhead {out['overhead_per_case_ms']:.0f} ms per case and worker")
    return out


def check_ingest(field_dir, seed=3, walls=("hard", "0.25")):
    """Live runner (serial, this process) against ingested cached fields."""
    from gfmd_ref import ingest_fields, load_ensemble, run_ensemble

    tmp = Path(tempfile.mkdtemp())
    sub = tmp / "fields"
    sub.mkdir()
    for w in walls:
        name = f"n1024_{'hard' if w == 'hard' else 'zeta' + w}_s{seed}.npz"
        shutil.copy(Path(field_dir) / name, sub / name)
    ingest_fields(sub, tmp / "ing", progress=False, verbose=False)
    run_ensemble(tmp / "live", n=1024, seeds=[seed], walls=list(walls), serial=True, progress=False, verbose=False)
    rows = []
    for a, b in zip(load_ensemble(tmp / "ing"), load_ensemble(tmp / "live")):
        assert a.key == b.key
        m = b.quantiles > 0
        rel = float(np.max(np.abs(a.quantiles - b.quantiles)[m] / b.quantiles[m]))
        rows.append(dict(wall=a.wall, seed=a.seed, max_rel_quantile_diff=rel,
                         iterations=(a.provenance["iterations"], b.provenance["iterations"]),
                         contact_fraction_equal=a.contact_fraction == b.contact_fraction))
        print(f"{a.wall:>9} seed {a.seed}: max relative quantile difference {rel:.2e}, iterations "
              f"{a.provenance['iterations']} (cached) / {b.provenance['iterations']} (live), contact fraction "
              f"{'equal' if a.contact_fraction == b.contact_fraction else 'DIFFERENT'}")
    shutil.rmtree(tmp)
    return rows


def finite_size(stores, walls=("hard", 0.25), use_bundle=True):
    """Finite-size table from stores (any grids) plus, if asked, the bundled 1024^2 ensemble."""
    from gfmd_ref import bundled_ensemble, load_ensemble
    from gfmd_ref.ensemble_stats import finite_size_table
    from gfmd_ref.ensemble_store import Ensemble

    recs = []
    for s in stores:
        recs.extend(load_ensemble(s).records)
    if use_bundle:
        recs.extend(bundled_ensemble("fig1_n1024").records)
    ens = Ensemble(recs)
    out = {}
    for w in walls:
        rows = finite_size_table(ens, w, n_ref=1024)
        out[str(w)] = rows
        print(f"wall {w} (zeta in grid units of 1024^2, scaled as n/1024):")
        print("    n  seeds  contact fraction     sd/p0            skewness         K to finest (noise)")
        for r in rows:
            print(f"{r['n']:5d} {r['seeds']:6d}  {r['contact_fraction']:.4f} +- {r['contact_fraction_sem']:.4f}  "
                  f"{r['sd_over_p0']:.3f} +- {r['sd_over_p0_sem']:.3f}  {r['skewness']:.3f} +- {r['skewness_sem']:.3f}  "
                  f"{r['k_to_finest']:.4f} ({r['k_noise']:.4f})")
    return out


def noise_table(name="fig1_n1024"):
    """K(N) of a bundled ensemble per wall (split halves), against 0.037/sqrt(N)."""
    from gfmd_ref import bundled_ensemble
    from gfmd_ref.ensemble_stats import noise_floor

    ens = bundled_ensemble(name)
    out = []
    for g in ens.groups():
        nf = noise_floor(g, repeats=200)
        out.append(dict(wall=g.wall, seeds=g.n_seeds, sizes=nf.sizes.tolist(), k_noise=nf.k_noise.tolist(),
                        coefficient=nf.coefficient, k_full=nf.k_noise_full,
                        median_wall_time=float(np.median([r.provenance["wall_time"] for r in g])),
                        median_iterations=float(np.median([r.provenance["iterations"] for r in g]))))
        print(f"{g.wall:>10} {g.n_seeds:3d} seeds: K(N) " + " ".join(f"N={k}:{v:.4f}" for k, v in
                                                             zip(nf.sizes, nf.k_noise))
              + f"  c={nf.coefficient:.4f} (0.037 in the issue), K(all)={nf.k_noise_full:.4f}; median case "
                f"{out[-1]['median_wall_time']:.1f} s, {out[-1]['median_iterations']:.0f} it")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 1024, 2048])
    ap.add_argument("--configs", nargs="+", default=["1x1", "2x1"], help="WORKERSxFFT_THREADS")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--overhead", action="store_true")
    ap.add_argument("--check-ingest", default=None, metavar="FIELD_DIR")
    ap.add_argument("--json", default=None, help="write the results here")
    ap.add_argument("--keep", default=None, help="keep the throughput stores under this directory")
    ap.add_argument("--noise", action="store_true", help="K(N) of the bundled Fig. 1 ensemble per wall")
    ap.add_argument("--finite-size", nargs="+", default=None, metavar="STORE",
                    help="finite-size table of these stores plus the bundled 1024^2 Fig. 1 ensemble")
    args = ap.parse_args(argv)
    res = {}
    if args.noise:
        res["noise"] = noise_table()
    elif args.finite_size:
        res["finite_size"] = finite_size(args.finite_size)
    elif args.check_ingest:
        res["check_ingest"] = check_ingest(args.check_ingest)
    elif args.overhead:
        res["overhead"] = overhead()
    else:
        cases = {256: 8, 512: 4, 1024: 4, 2048: 2, 4096: 2}
        res["throughput"] = throughput(args.sizes, args.configs, cases, args.repeats, args.keep)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
