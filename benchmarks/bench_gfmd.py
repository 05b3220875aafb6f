"""Benchmarks of the gfmd_ref contact solvers on the paper's Fig. 1 surface.

Parts (``--part``):

* ``hard``: hard wall, CCG vs Tamaas (same surface, same run; Tamaas skipped if not
  importable) to tol 1e-8, medians over ``--repeats``; plus FIRE GFMD. Work-precision
  (residual vs time) plot, contact fractions, pressure-field differences.
* ``exp``: exponential wall, every zeta in {4, 2, 1, 0.5, 0.25, 0.1, 0.01, 0.001} with
  the dual Newton-CG to 1e-6 p0 (medians), and a work-precision plot Newton vs FIRE.
* ``scaling``: CCG hard wall, n = 128 ... 2048 (``--n4096`` adds 4096), each size in a
  fresh subprocess: iterations, time/iteration, total time, peak RSS.

``--quick`` uses small sizes (256^2, scaling up to 512^2) so that a run takes about
a minute. Outputs go to ``benchmarks/results/gfmd_*`` (PNG plots, JSON, Markdown).
No assertions: this measures, the tests check correctness.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
E_STAR, P0 = 8.0 / 3.0, 0.004
ZETAS = [4.0, 2.0, 1.0, 0.5, 0.25, 0.1, 0.01, 0.001]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


@contextlib.contextmanager
def solver_switches(**switches):
    """``gfmd_ref.solver``'s module switches (``INCREMENT_U32=False``, ...) set for the block, restored after it."""
    from gfmd_ref import solver

    old = {k: getattr(solver, k) for k in switches}
    for k, v in switches.items():
        setattr(solver, k, v)
    try:
        yield
    finally:
        for k, v in old.items():
            setattr(solver, k, v)


@contextlib.contextmanager
def _capture_fd(fd=1):
    """Capture C-level output written to a file descriptor (Tamaas logs there)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), fd)
        box = {}
        try:
            yield box
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            box["text"] = tmp.read().decode(errors="replace")


def tamaas_solve(h, length, tol):
    try:
        import tamaas as tm
    except ImportError:
        return None
    n = h.shape[0]
    model = tm.ModelFactory.createModel(tm.model_type.basic_2d, [length, length], [n, n])
    model.E = E_STAR
    model.nu = 0.0
    hh = np.ascontiguousarray(h, dtype=np.float64)
    solver = tm.PolonskyKeerRey(model, hh, tol)
    with _capture_fd(1) as out1, _capture_fd(2) as out2:
        t0 = time.perf_counter()
        solver.solve(P0)
        wall = time.perf_counter() - t0
    text = out1.get("text", "") + out2.get("text", "")
    its = [int(m.group(1)) for m in re.finditer(r"^\s*(\d+)\s+\S+\s+\S+\s*$", text, re.M)]
    p = np.array(model.traction, dtype=np.float64).reshape(n, n)
    d = np.array(model.displacement, dtype=np.float64).reshape(n, n)
    return dict(pressure=p, gap=d - h, wall_time=wall, iterations=max(its) if its else -1)


def hard_residual_of(p, gap, h):
    """Our hard-wall residual (solver module doc) evaluated on any (p, gap) pair."""
    hs = float(np.std(h))
    c = p > 0
    g = gap - np.mean(gap[c])  # same z0 convention: gap zero on average on contact
    comp = np.max(np.abs(p * g)) / (P0 * hs)
    pen = max(0.0, float(-np.min(g[~c]))) / hs if np.any(~c) else 0.0
    load = abs(p.mean() - P0) / P0
    return max(comp, pen, load)


def part_hard(n, repeats, fire, seed=1):
    import gfmd_ref as g

    h, L = g.fig1_surface(n, seed=seed)
    rows = []
    ours = []
    tam = []
    have_tamaas = True
    # alternate ours / Tamaas so that both see the same machine load
    for _ in range(repeats):
        r = g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0,
                            interaction=g.HardWall(), tol=1e-8)
        ours.append(r)
        print(f"  ccg   n={n}: {r.wall_time:.2f} s, {r.iterations} it, res {r.residual:.2e}",
              flush=True)
        if have_tamaas:
            t = tamaas_solve(h, L, 1e-8)
            if t is None:
                print("  tamaas not importable: skipped")
                have_tamaas = False
                continue
            tam.append(t)
            print(f"  tamaas n={n}: {t['wall_time']:.2f} s, {t['iterations']} it", flush=True)
    best = ours[0]
    out = dict(n=n, seed=seed)
    out["ccg"] = dict(
        times=[r.wall_time for r in ours], median_time=float(np.median([r.wall_time for r in ours])),
        iterations=best.iterations, residual=best.residual,
        contact_fraction=best.contact_fraction,
    )
    if tam:
        t = tam[0]
        cf_t = float(np.count_nonzero(t["pressure"] > 0)) / h.size
        out["tamaas"] = dict(
            times=[x["wall_time"] for x in tam],
            median_time=float(np.median([x["wall_time"] for x in tam])),
            iterations=t["iterations"], contact_fraction=cf_t,
            our_residual_metric=hard_residual_of(t["pressure"], t["gap"], h),
        )
        # time our CCG needs to reach the accuracy Tamaas delivered (our metric)
        acc = out["tamaas"]["our_residual_metric"]
        st = best.info["history_stamps"]
        hit = np.nonzero(best.residual_history <= acc)[0]
        t_acc = float(st[hit[0], 1]) if hit.size else float("nan")
        out["compare"] = dict(
            time_ratio=out["ccg"]["median_time"] / out["tamaas"]["median_time"],
            ccg_time_to_tamaas_accuracy=t_acc,
            ccg_iterations_to_tamaas_accuracy=int(st[hit[0], 0]) if hit.size else -1,
            contact_fraction_rel_diff=abs(best.contact_fraction - cf_t) / cf_t,
            max_pressure_diff_over_p0=float(np.max(np.abs(best.pressure - t["pressure"])) / P0),
            rms_pressure_diff_over_p0=float(np.sqrt(np.mean((best.pressure - t["pressure"]) ** 2)) / P0),
        )
    if fire:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rf = g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0,
                                 interaction=g.HardWall(), tol=1e-8, method="fire",
                                 max_iter=fire)
        print(f"  fire  n={n}: {rf.wall_time:.2f} s, {rf.iterations} it, res {rf.residual:.2e}",
              flush=True)
        out["fire"] = dict(time=rf.wall_time, iterations=rf.iterations, residual=rf.residual,
                           converged=rf.converged, contact_fraction=rf.contact_fraction,
                           max_pressure_diff_vs_ccg_over_p0=float(
                               np.max(np.abs(rf.pressure - best.pressure)) / P0))
    # work-precision plot
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4.2))
    st = best.info["history_stamps"]
    ax.semilogy(st[:, 1], best.residual_history, label=f"gfmd_ref ccg ({best.iterations} it)")
    if fire:
        st = rf.info["history_stamps"]
        ax.semilogy(st[:, 1], rf.residual_history, label=f"gfmd_ref fire ({rf.iterations} it)")
    if tam:
        ax.axvline(out["tamaas"]["median_time"], color="k", ls="--",
                   label=f"Tamaas PKR to 1e-8 ({out['tamaas']['iterations']} it)")
    ax.axhline(1e-8, color="gray", lw=0.5)
    ax.set_xlabel("wall time [s]")
    ax.set_ylabel("residual / p0")
    ax.set_title(f"hard wall, Fig. 1 surface, {n}^2", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(RESULTS, f"gfmd_hard_wp_n{n}.png"), dpi=110)
    plt.close(fig)
    rows.append(out)
    return out


def part_exp(n, repeats, n_fire, fire_cap, seed=1):
    import gfmd_ref as g

    h, L = g.fig1_surface(n, seed=seed)
    out = dict(n=n, seed=seed, newton={})
    hard = [g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0,
                            interaction=g.HardWall(), tol=1e-8).wall_time for _ in range(repeats)]
    out["hard_ccg_median_time"] = float(np.median(hard))
    print(f"  hard ccg n={n}: median {out['hard_ccg_median_time']:.2f} s", flush=True)
    for z in ZETAS:
        ts = []
        for _ in range(repeats):
            r = g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0,
                                interaction=g.ExponentialRepulsion(z), tol=1e-6)
            ts.append(r.wall_time)
        out["newton"][str(z)] = dict(
            median_time=float(np.median(ts)), times=ts, iterations=r.iterations,
            newton_steps=r.info["newton_steps"], residual=r.residual, converged=r.converged,
            contact_fraction=r.contact_fraction,
            ratio_to_hard=float(np.median(ts)) / out["hard_ccg_median_time"],
        )
        print(f"  newton zeta={z:g}: {np.median(ts):.2f} s, {r.iterations} it "
              f"({r.info['newton_steps']} Newton), res {r.residual:.1e}, "
              f"{np.median(ts) / out['hard_ccg_median_time']:.2f} x hard", flush=True)
    # work precision Newton vs FIRE at n_fire
    hf, Lf = g.fig1_surface(n_fire, seed=seed)
    plt = _plt()
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.8), sharey=True)
    out["work_precision"] = {}
    for ax, z in zip(axs, [1.0, 0.01, 0.001]):
        rn = g.solve_contact(hf, length=Lf, E_star=E_STAR, mean_pressure=P0,
                             interaction=g.ExponentialRepulsion(z), tol=1e-8)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rf = g.solve_contact(hf, length=Lf, E_star=E_STAR, mean_pressure=P0,
                                 interaction=g.ExponentialRepulsion(z), tol=1e-8,
                                 method="fire", max_iter=fire_cap)
        out["work_precision"][str(z)] = dict(
            newton=dict(time=rn.wall_time, iterations=rn.iterations, residual=rn.residual),
            fire=dict(time=rf.wall_time, iterations=rf.iterations, residual=rf.residual,
                      converged=rf.converged),
            max_pressure_diff_over_p0=float(np.max(np.abs(rn.pressure - rf.pressure)) / P0),
        )
        print(f"  wp n={n_fire} zeta={z:g}: newton {rn.wall_time:.2f} s/{rn.iterations} it, "
              f"fire {rf.wall_time:.2f} s/{rf.iterations} it (res {rf.residual:.1e})", flush=True)
        ax.semilogy(rn.info["history_stamps"][:, 1], rn.residual_history, "o-", ms=3,
                    label="dual Newton-CG")
        ax.semilogy(rf.info["history_stamps"][:, 1], rf.residual_history, label="FIRE GFMD")
        ax.set_title(f"zeta = {z:g}, {n_fire}^2", fontsize=10)
        ax.set_xlabel("wall time [s]")
        ax.legend(fontsize=8)
    axs[0].set_ylabel("max |sigma - p_el| / p0")
    fig.tight_layout()
    fig.savefig(os.path.join(RESULTS, f"gfmd_exp_wp_n{n_fire}.png"), dpi=110)
    plt.close(fig)
    # times vs zeta
    fig, ax = plt.subplots(figsize=(5.5, 4))
    zs = np.array(ZETAS)
    ax.loglog(zs, [out["newton"][str(z)]["median_time"] for z in ZETAS], "o-",
              label="exp wall, Newton-CG, 1e-6")
    ax.axhline(out["hard_ccg_median_time"], color="k", ls="--", label="hard wall CCG, 1e-8")
    ax.axhline(3 * out["hard_ccg_median_time"], color="r", ls=":", label="3 x hard wall")
    ax.set_xlabel("zeta")
    ax.set_ylabel("wall time [s]")
    ax.set_title(f"exponential wall, Fig. 1 surface, {n}^2", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(RESULTS, f"gfmd_exp_times_n{n}.png"), dpi=110)
    plt.close(fig)
    return out


def child_scaling(n):
    import resource

    import gfmd_ref as g

    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    h, L = g.fig1_surface(n, seed=1)
    # warm-up (numba cache / FFT plans) on a tiny problem
    hs, Ls = g.fig1_surface(64, seed=1)
    g.solve_contact(hs, length=Ls, E_star=E_STAR, mean_pressure=P0, interaction=g.HardWall())
    base2 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    r = g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0,
                        interaction=g.HardWall(), tol=1e-8)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps(dict(n=n, iterations=r.iterations, time=r.wall_time,
                          time_per_iteration=r.wall_time / max(r.iterations, 1),
                          residual=r.residual, converged=r.converged,
                          contact_fraction=r.contact_fraction,
                          peak_rss_mb=peak / 1024, baseline_rss_mb=base2 / 1024,
                          import_rss_mb=base / 1024)))


def plot_scaling(rows):
    plt = _plt()
    fig, axs = plt.subplots(1, 2, figsize=(10, 3.8))
    ns = np.array([r["n"] for r in rows], dtype=float)
    axs[0].loglog(ns**2, [r["time_per_iteration"] for r in rows], "o-", label="time / iteration")
    axs[0].loglog(ns**2, [r["time"] for r in rows], "s-", label="total time")
    ref = rows[0]["time_per_iteration"] * (ns**2 * np.log(ns**2)) / (ns[0] ** 2 * np.log(ns[0] ** 2))
    axs[0].loglog(ns**2, ref, "k:", label="N log N")
    axs[0].set_xlabel("grid points N = n^2")
    axs[0].set_ylabel("seconds")
    axs[0].legend(fontsize=8)
    axs[1].loglog(ns**2, [r["peak_rss_mb"] for r in rows], "o-", label="peak RSS")
    axs[1].loglog(ns**2, [r["peak_rss_mb"] - r["import_rss_mb"] for r in rows], "s-",
                  label="peak RSS - RSS after imports (surface + solver)")
    axs[1].set_xlabel("grid points N = n^2")
    axs[1].set_ylabel("MB")
    axs[1].legend(fontsize=8)
    fig.suptitle("CCG hard wall, Fig. 1 surface, tol 1e-8", fontsize=10)
    fig.tight_layout()
    name = "gfmd_scaling.png" if len(rows) > 3 else "gfmd_scaling_quick.png"
    fig.savefig(os.path.join(RESULTS, name), dpi=110)
    plt.close(fig)


def part_scaling(sizes, with_tamaas_small=False):
    rows = []
    for n in sizes:
        cmd = [sys.executable, os.path.abspath(__file__), "--child-scaling", str(n)]
        out = subprocess.run(cmd, capture_output=True, text=True)
        line = [x for x in out.stdout.splitlines() if x.startswith("{")]
        if not line:
            print(out.stdout, out.stderr)
            continue
        row = json.loads(line[-1])
        rows.append(row)
        print(f"  n={n:5d}: {row['iterations']:4d} it, {row['time']:8.2f} s, "
              f"{1e3 * row['time_per_iteration']:8.2f} ms/it, peak RSS {row['peak_rss_mb']:.0f} MB",
              flush=True)
    plot_scaling(rows)
    return rows


def _median_time(fn, reps):
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def _raw_pair(pair, x=None):
    """A function that runs one raw FFT pair with the plans the hard-wall solver runs:
    two extra work arrays (4, kept -> spectrum -> 5); plan execution only, no copy and
    no multiply, and the data do not grow from call to call. A scipy pair: ``apply``."""
    src, dst = pair.work_array(4), pair.work_array(5)
    src[...] = np.random.default_rng(0).normal(size=src.shape) if x is None else x
    if pair.name != "fftw":
        ones = np.ones((src.shape[0], src.shape[1] // 2 + 1))
        return lambda: pair.apply(ones, src)
    fwd, bwd = pair._plans_of(src)[1], pair._plans_of(dst)[2]
    return lambda: (fwd.execute(), bwd.execute())


def _raw_single_pair(pair):
    """A function that runs the single-precision FFT pair of the ``ccg`` preconditioner
    (the solver's own plans, in place on the pair's float32 array), plan execution only."""
    w = pair.single_array()
    w[...] = np.random.default_rng(0).normal(size=w.shape)
    if pair.name != "fftw":
        ones = np.ones((w.shape[0], w.shape[1] // 2 + 1), dtype=np.float32)
        return lambda: pair.apply_single(ones)
    _, fwd, bwd = pair._single[0]
    return lambda: (fwd.execute(), bwd.execute())


def _uptime():
    try:
        with open("/proc/loadavg") as fh:
            return " ".join(fh.read().split()[:3])
    except OSError:
        return "n/a"


def part_threads(sizes, rounds=5, reps=8, solve_n=1024, solve_rounds=2):
    """FFTW pair time with 1 and 2 threads, interleaved (1, 2, 1, 2, ...), medians;
    and the full CCG solve at ``solve_n`` with each thread count, interleaved."""
    import gfmd_ref as g
    from gfmd_ref._fft import fft_pair

    out = dict(load_before=_uptime(), pairs=[], solves=[])
    for n in sizes:
        pairs = {th: fft_pair((n, n), th)[0] for th in (1, 2)}
        raw = {th: _raw_pair(pr) for th, pr in pairs.items()}
        meds = {1: [], 2: []}
        for _ in range(rounds):
            for th in pairs:
                meds[th].append(_median_time(raw[th], reps))
        row = dict(n=n, pair_ms_1=1e3 * float(np.median(meds[1])), pair_ms_2=1e3 * float(np.median(meds[2])))
        out["pairs"].append(row)
        print(f"  n={n:5d}: FFTW pair 1 thread {row['pair_ms_1']:8.2f} ms, 2 threads "
              f"{row['pair_ms_2']:8.2f} ms  (load {_uptime()})", flush=True)
    if solve_n:
        h, L = g.fig1_surface(solve_n, seed=1)
        times = {1: [], 2: []}
        for _ in range(solve_rounds):
            for th in (1, 2):
                r = g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0,
                                    interaction=g.HardWall(), tol=1e-8, threads=th)
                times[th].append(r.wall_time - r.info["fft_planning_time"])
                print(f"  solve n={solve_n} threads={th}: {times[th][-1]:.2f} s, {r.iterations} it",
                      flush=True)
        out["solves"] = dict(n=solve_n, times_1=times[1], times_2=times[2],
                             median_1=float(np.median(times[1])), median_2=float(np.median(times[2])))
    out["load_after"] = _uptime()
    return out


def part_breakdown(n, reps=15, threads=None, rounds=0):
    """Where the time of one CCG iteration goes at ``n^2``: each kernel and FFT of the
    iteration timed on the arrays of a converged solve (medians of ``reps``), against
    the floor = (FFT pairs per iteration) x (one raw FFT pair, plan execution only, the
    plans the solver runs) + the vector work of a textbook Polonsky-Keer iteration (4
    streaming passes: 8 array reads, 4 writes, the memory traffic of its gap,
    direction, step and update; the floor's definition since issue 10, although the
    solver now makes one full pass per iteration and works on the contact set's index
    list otherwise). Both ``ccg`` (preconditioned: per iteration the preconditioner's and
    the step length's pairs and, between the few exact ``u = G p`` in double, the
    increment's, all three in single precision; the floor counts each pair at its own raw
    cost) and ``pk`` (plain, about 1.3 pairs) are measured in the same run.

    ``rounds`` > 0 adds paired rounds for ``ccg``: each round times the raw pairs and the vector floor (medians of
    ``reps``) right before and right after one solve, and takes that round's ratio against the mean of the two. The
    machine's speed drifts by up to 1.6x within minutes on some days; a ratio from parts measured seconds apart
    follows it, where one from a table measured minutes away from the solve does not. The median and the range of
    the rounds' ratios are printed."""
    import gfmd_ref as g
    from gfmd_ref import _kernels as kr
    from gfmd_ref.solver import _Elastic

    h, L = g.fig1_surface(n, seed=1)
    el = _Elastic(n, L, E_STAR, threads)
    pr = el.fft
    runs = {}
    for method in ("ccg", "pk", "ccg", "pk"):  # interleaved; the second of each is kept
        runs[method] = g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0,
                                       interaction=g.HardWall(), tol=1e-8, threads=threads,
                                       method=method)
    # the solver's state at convergence, in the pair's work arrays
    p, u, t, w = (pr.work_array(k) for k in range(g.N_WORK_ARRAYS))
    p[...] = runs["ccg"].pressure
    pr.apply_route(el.Gn, p, u)
    c = p > 0
    n2 = p.size
    idx = np.flatnonzero(c).astype(np.int32 if n2 < 2 ** 31 else np.int64)  # as the solver keeps it
    nc = idx.size
    gcon, olg = np.empty(n2), np.empty(n2)
    ol = np.empty(n2, dtype=idx.dtype)
    pc = p.ravel()[idx]  # the contact set's pressure and direction, packed as the solver keeps them
    tc = np.zeros(nc)
    pc_next, tc_next = np.empty(nc), np.empty(nc)
    kr.pk_gap(u, h, pc, c, idx, nc, w, True, gcon, ol, olg, w, 1.0, 1.0, False)
    t[...] = 0.0
    kr.pk_direction(w, True, gcon, idx, nc, tc, 0.0, 0.5, t)
    ops = {}
    if pr.name == "fftw":
        ops["FFT pair (plan execution only)"] = _raw_pair(pr)
        ops["FFT pair, single precision (plan execution only)"] = _raw_single_pair(pr)
    w32 = pr.single_array()
    Kn32 = (el.K / (n * n)).astype(np.float32)
    ops["apply_single (single-precision pair, multiplier)"] = lambda: pr.apply_single(Kn32)
    Gn32 = el.Gn.astype(np.float32)
    pr.single_array(1)[...] = t
    ops["apply_single, t32 -> r32 (the step length's r = G t)"] = lambda: pr.apply_single(Gn32, 1, 2)
    ops["contact_dot (contact set, float32 r)"] = lambda: kr.contact_dot(pr.single_array(2), tc, idx, nc)
    ops["apply_route (pair, multiplier and Parseval dot)"] = lambda: pr.apply_route(el.Gn, t, w)
    ops["apply_route, no dot (the exact u = G p)"] = lambda: pr.apply_route(el.Gn, t, w, dot=False)
    ops["pk_gap (the one full pass: u, h, mask -> masked gap)"] = lambda: kr.pk_gap(
        u, h, pc, c, idx, nc, w32, True, gcon, ol, olg, w32, 1.0, 1.0, False)
    ops["gather_sum (contact set)"] = lambda: kr.gather_sum(w, idx, nc)
    ops["contact_sums (contact set, float32 z)"] = lambda: kr.contact_sums(w32, gcon, idx, nc)
    ops["pk_direction (contact set)"] = lambda: kr.pk_direction(w32, False, gcon, idx, nc, tc, 0.0, 1.0, t)
    # tau = 0: the step and the rescaling leave the state as it is
    idx2 = np.empty_like(idx)
    ops["pk_step (contact set + overlaps, new index list)"] = lambda: kr.pk_step(
        pc, c, tc, idx, nc, ol, olg, 0, 0.0, idx2, pc_next, tc_next, t, t, False)
    ops["pk_rescale (contact set; exact u)"] = lambda: kr.pk_rescale(pc, nc, 1.0, u, w, 0.0, True)
    ops["pk_rescale (incremental u: a full pass)"] = lambda: kr.pk_rescale(pc, nc, 1.0, u, w, 0.0, False)
    gv32 = pr.single_array(3)
    gv32[...] = 0.0  # folded in with scale 1: u stays as it is
    ops["pk_gap, increment folded in (u updated, G dv zeroed)"] = lambda: kr.pk_gap(
        u, h, pc, c, idx, nc, w32, True, gcon, ol, olg, gv32, 1.0, 1.0, True)
    ops["scatter_contact (the full p of an exact u)"] = lambda: kr.scatter_contact(pc, idx, nc, w)
    a = [p.copy(), u.copy(), t.copy(), w.copy()]

    def traffic():  # 4 streaming passes: 8 reads, 4 writes
        for k, src in enumerate((h, w, p, u)):
            np.add(src, a[k], out=a[k])

    ops["vector floor (4 passes: 8 reads, 4 writes)"] = traffic
    times = {}
    for _ in range(2):  # two interleaved rounds, keep the smaller median of each op
        for k, f in ops.items():
            f()
            v = 1e3 * _median_time(f, reps)
            times[k] = min(times.get(k, np.inf), v)
    raw = times.get("FFT pair (plan execution only)", times["apply_route (pair, multiplier and Parseval dot)"])
    raw32 = times.get("FFT pair, single precision (plan execution only)",
                      times["apply_single (single-precision pair, multiplier)"])
    vec = times["vector floor (4 passes: 8 reads, 4 writes)"]
    out = dict(n=n, fft=pr.name, threads=pr.threads, load=_uptime(), op_ms=times, methods={})
    print(f"  breakdown n={n} ({pr.name}, {pr.threads} thread(s), load {out['load']}):")
    for k, v in times.items():
        print(f"    {k:55s} {v:8.2f} ms")
    for method, r in runs.items():
        per_it = 1e3 * (r.wall_time - r.info["fft_planning_time"]) / r.iterations
        ppi = r.info["fft_pairs"] / r.iterations
        spi = r.info.get("fft_pairs_single", 0) / r.iterations  # of which in single precision
        floor = (ppi - spi) * raw + spi * raw32 + vec
        out["methods"][method] = dict(
            iterations=r.iterations, fft_pairs=r.info["fft_pairs"], wall_time=r.wall_time,
            fft_pairs_single=r.info.get("fft_pairs_single", 0), u_increments=r.info.get("u_increments", 0),
            ms_per_iteration=per_it, fft_pairs_per_iteration=ppi, floor_ms_per_iteration=floor,
            ratio_to_floor=per_it / floor, one_pair_plus_vector_ms=raw + vec,
            ms_per_fft_pair=1e3 * r.wall_time / r.info["fft_pairs"])
        out["methods"][method].update(_in_situ(r, per_it, vec, (ppi - spi) * raw + spi * raw32))
        m = out["methods"][method]
        print(f"    {method}: {r.iterations} it, {r.info['fft_pairs']} FFT pairs ({ppi:.2f}/it, {spi:.2f} single), "
              f"{per_it:.2f} ms/it; floor {floor:.2f} ms/it ({ppi - spi:.2f} x {raw:.2f} + {spi:.2f} x {raw32:.2f}"
              f" + {vec:.2f}); "
              f"ratio {per_it / floor:.2f}; total {r.wall_time:.2f} s", flush=True)
        print(f"      inside the solve: FFTs {m['fft_in_situ_ms_per_iteration']:.2f} ms/it "
              f"({m['fft_in_situ_over_raw']:.2f}x the raw pairs), multiplies {m['multiply_ms_per_iteration']:.2f}, "
              f"the rest {m['rest_ms_per_iteration']:.2f} (vector floor {vec:.2f}); ratio to the FFTs as they ran "
              f"plus the vector floor {m['ratio_to_in_situ_floor']:.2f}", flush=True)
    if rounds:
        raw_ops = {k: ops[k] for k in ("FFT pair (plan execution only)",
                                       "FFT pair, single precision (plan execution only)",
                                       "vector floor (4 passes: 8 reads, 4 writes)") if k in ops}

        def parts():
            return {k: 1e3 * _median_time(f, reps) for k, f in raw_ops.items()}

        paired = []
        for _ in range(rounds):
            before = parts()
            r = g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0, interaction=g.HardWall(), tol=1e-8,
                                threads=threads, method="ccg")
            after = parts()
            mean = {k: 0.5 * (before[k] + after[k]) for k in before}
            raw = mean.get("FFT pair (plan execution only)", times["apply_route (pair, multiplier and Parseval dot)"])
            raw32 = mean.get("FFT pair, single precision (plan execution only)",
                             times["apply_single (single-precision pair, multiplier)"])
            vec = mean["vector floor (4 passes: 8 reads, 4 writes)"]
            per_it = 1e3 * (r.wall_time - r.info["fft_planning_time"]) / r.iterations
            spi = r.info.get("fft_pairs_single", 0) / r.iterations
            floor = (r.info["fft_pairs"] / r.iterations - spi) * raw + spi * raw32 + vec
            paired.append(dict(ms_per_iteration=per_it, floor_ms_per_iteration=floor, ratio_to_floor=per_it / floor,
                               raw_pair_ms=raw, raw_single_pair_ms=raw32, vector_ms=vec,
                               raw_single_drift=after.get("FFT pair, single precision (plan execution only)", 0.0)
                               / before.get("FFT pair, single precision (plan execution only)", 1.0),
                               **_in_situ(r, per_it, vec, floor - vec)))
            x = paired[-1]
            print(f"    paired round: ccg {per_it:.2f} ms/it, floor {floor:.2f} (single pair {raw32:.2f} ms, "
                  f"{x['raw_single_drift']:.2f}x after/before); ratio {per_it / floor:.2f}; inside: FFTs "
                  f"{x['fft_in_situ_ms_per_iteration']:.2f} ({x['fft_in_situ_over_raw']:.2f}x raw), rest "
                  f"{x['rest_ms_per_iteration']:.2f}, ratio {x['ratio_to_in_situ_floor']:.2f}", flush=True)
        ratios = [x["ratio_to_floor"] for x in paired]
        inside = [x["ratio_to_in_situ_floor"] for x in paired]
        rest = [x["rest_ms_per_iteration"] for x in paired]
        cold = [x["fft_in_situ_over_raw"] for x in paired]
        out["paired_rounds"] = paired
        print(f"    ccg, {rounds} paired rounds: ratio median {np.median(ratios):.2f} (range {min(ratios):.2f}-"
              f"{max(ratios):.2f}); to the FFTs as they ran plus the vector floor: median {np.median(inside):.2f} "
              f"({min(inside):.2f}-{max(inside):.2f}); the rest {np.median(rest):.2f} ms/it "
              f"({min(rest):.2f}-{max(rest):.2f}); the FFTs inside {np.median(cold):.2f}x the raw pairs "
              f"({min(cold):.2f}-{max(cold):.2f})", flush=True)
    return out


def _in_situ(r, per_it, vec, raw_fft_ms):
    """A solve's time per iteration split by its own timers (``info["fft_seconds"]``, ``info["multiply_seconds"]``):
    the FFTs as they ran inside the solve, the multiplies, and the rest (kernels, Python); the ratio of the
    iteration to those FFTs plus the vector floor ``vec``, and the FFTs' time against ``raw_fft_ms``, the same
    pairs' raw cost per iteration (repeated, cache-warm). Drift-free where the raw pairs are not: the parts are
    measured on the same iterations."""
    fft = 1e3 * r.info["fft_seconds"] / r.iterations
    mult = 1e3 * r.info["multiply_seconds"] / r.iterations
    return dict(fft_in_situ_ms_per_iteration=fft, multiply_ms_per_iteration=mult,
                rest_ms_per_iteration=per_it - fft - mult, ratio_to_in_situ_floor=per_it / (fft + mult + vec),
                fft_in_situ_over_raw=fft / raw_fft_ms if raw_fft_ms > 0 else float("nan"))


def _field_error(p, ref):
    d = p - ref
    return float(np.max(np.abs(d)) / P0), float(np.sqrt(np.mean(d * d)) / P0)


def part_match(n, repeats, our_tols=(1e-6, 1e-7, 1e-8), tamaas_tol=1e-8, ref_tol=1e-10,
               seed=1, with_pk=True):
    """Hard wall at matched final-field error against Tamaas.

    Reference field: our ``ccg`` at ``ref_tol`` (cross-checked against Tamaas' own
    result). Then ``repeats`` interleaved rounds (ours at every tol in ``our_tols``,
    Tamaas at ``tamaas_tol``, ours ``pk`` at 1e-8, ...); each run's pressure field is
    compared with the reference (max and L2 error in units of p0). The matched
    comparison uses the fastest (median time) of our tols whose max error is <= Tamaas'
    max error."""
    import gfmd_ref as g

    from gfmd_ref._fft import fft_pair

    h, L = g.fig1_surface(n, seed=seed)
    g.warm_up_fft(n)
    pair = fft_pair((n, n))[0]
    pair_s = _median_time(_raw_pair(pair), 9)
    pair32_s = _median_time(_raw_single_pair(pair), 9)  # the search's and the increments' pairs
    out = dict(n=n, seed=seed, load_before=_uptime(), runs=[], fft_pair_seconds=pair_s,
               fft_pair_single_seconds=pair32_s)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0,
                              interaction=g.HardWall(), tol=ref_tol)
    out["reference"] = dict(tol=ref_tol, converged=ref.converged, residual=ref.residual,
                            iterations=ref.iterations, time=time.perf_counter() - t0,
                            message=ref.message, contact_fraction=ref.contact_fraction)
    print(f"  reference n={n}: {ref.message} ({out['reference']['time']:.1f} s)", flush=True)
    have_tamaas = True
    for k in range(repeats):
        plan = [("ccg", tol) for tol in our_tols] + [("tamaas", tamaas_tol)]
        if with_pk and k == 0:
            plan.append(("pk", 1e-8))
        for solver, tol in plan:
            if solver == "tamaas":
                if not have_tamaas:
                    continue
                t = tamaas_solve(h, L, tol)
                if t is None:
                    print("  tamaas not importable: skipped")
                    have_tamaas = False
                    continue
                p, wall, its = t["pressure"], t["wall_time"], t["iterations"]
                pairs = 2 * its  # PolonskyKeerRey: G t and G p per iteration (estimate)
                floor = pairs * pair_s
            else:
                r = g.solve_contact(h, length=L, E_star=E_STAR, mean_pressure=P0,
                                    interaction=g.HardWall(), tol=tol, method=solver)
                p, wall, its = r.pressure, r.wall_time, r.iterations
                pairs = r.info["fft_pairs"]
                singles = r.info.get("fft_pairs_single", 0)
                floor = (pairs - singles) * pair_s + singles * pair32_s
            emax, el2 = _field_error(p, ref.pressure)
            row = dict(solver=solver, tol=tol, round=k, time=wall, iterations=its, fft_pairs=pairs,
                       fft_floor=floor,
                       max_err_p0=emax, l2_err_p0=el2, load=_uptime(),
                       contact_fraction=float(np.count_nonzero(p > 0)) / p.size)
            out["runs"].append(row)
            print(f"  {solver:6s} tol {tol:.0e}: {wall:8.2f} s, {its:4d} it, max err "
                  f"{emax:.2e} p0, L2 err {el2:.2e} p0 (load {row['load']})", flush=True)
    # summary: medians per (solver, tol)
    summ = {}
    for row in out["runs"]:
        summ.setdefault((row["solver"], row["tol"]), []).append(row)
    table = []
    for (solver, tol), rows in summ.items():
        table.append(dict(solver=solver, tol=tol, median_time=float(np.median([r["time"] for r in rows])),
                          times=[r["time"] for r in rows], iterations=rows[0]["iterations"],
                          fft_pairs=rows[0]["fft_pairs"], fft_floor=rows[0]["fft_floor"],
                          max_err_p0=max(r["max_err_p0"] for r in rows),
                          l2_err_p0=max(r["l2_err_p0"] for r in rows)))
    out["table"] = table
    tam = [r for r in table if r["solver"] == "tamaas"]
    if tam:
        tm = tam[0]
        ok = [r for r in table if r["solver"] == "ccg" and r["max_err_p0"] <= tm["max_err_p0"]]
        matched = min(ok, key=lambda r: r["median_time"]) if ok else None
        for r in table:
            r["ratio_to_tamaas"] = r["median_time"] / tm["median_time"]
        out["matched"] = dict(tamaas=tm, ours=matched,
                              ratio=(matched["median_time"] / tm["median_time"]) if matched else None)
        out["cross_check_ref_vs_tamaas_max_err_p0"] = tm["max_err_p0"]
    out["load_after"] = _uptime()
    print(f"  n={n} (load before {out['load_before']}, after {out['load_after']}):")
    print(f"    (one FFT pair: {1e3 * pair_s:.1f} ms, single precision {1e3 * pair32_s:.1f} ms; the floor counts each "
          f"of ours at its own cost; Tamaas' pairs estimated as 2 double per iteration)")
    print("    | solver | tol | median time [s] | iterations | s / iteration | FFT pairs | FFT floor [s] "
          "| max err [p0] | L2 err [p0] | / Tamaas |")
    for r in sorted(table, key=lambda r: (r["solver"], -r["tol"])):
        print(f"    | {r['solver']} | {r['tol']:.0e} | {r['median_time']:.2f} | {r['iterations']} | "
              f"{r['median_time'] / max(r['iterations'], 1):.3f} | {r['fft_pairs']} | "
              f"{r['fft_floor']:.2f} | {r['max_err_p0']:.1e} | "
              f"{r['l2_err_p0']:.1e} | {r.get('ratio_to_tamaas', float('nan')):.3f} |", flush=True)
    if out.get("matched"):
        m = out["matched"]
        if m["ours"]:
            print(f"    matched error: ours ccg tol {m['ours']['tol']:.0e} ({m['ours']['max_err_p0']:.1e} p0) "
                  f"{m['ours']['median_time']:.2f} s vs Tamaas {m['tamaas']['median_time']:.2f} s "
                  f"({m['tamaas']['max_err_p0']:.1e} p0): ratio {m['ratio']:.3f}", flush=True)
    return out


def plot_match(results):
    plt = _plt()
    fig, axs = plt.subplots(1, len(results), figsize=(5.2 * len(results), 4), squeeze=False)
    for ax, res in zip(axs[0], results):
        for solver, mk in (("ccg", "o-"), ("pk", "s"), ("tamaas", "k^")):
            rows = sorted([r for r in res["table"] if r["solver"] == solver], key=lambda r: r["max_err_p0"])
            if rows:
                ax.loglog([r["max_err_p0"] for r in rows], [r["median_time"] for r in rows], mk,
                          label={"ccg": "gfmd_ref ccg (preconditioned)", "pk": "gfmd_ref pk (plain)",
                                 "tamaas": "Tamaas PolonskyKeerRey"}[solver])
        ax.set_xlabel("max |p - p_ref| / p0")
        ax.set_ylabel("wall time [s] (median)")
        ax.set_title(f"hard wall, Fig. 1 surface, {res['n']}^2", fontsize=10)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(RESULTS, "gfmd_match.png"), dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=["hard", "exp", "scaling", "threads", "breakdown", "match", "all"], default="all")
    ap.add_argument("--quick", action="store_true", help="small sizes (about a minute)")
    ap.add_argument("--n", type=int, default=None, help="size of the hard/exp runs")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--rounds", type=int, default=0,
                    help="breakdown: paired rounds (raw pairs timed right before and after each ccg solve)")
    ap.add_argument("--n4096", action="store_true", help="add 4096^2 to the scaling table")
    ap.add_argument("--no-fire", action="store_true", help="skip the FIRE runs")
    ap.add_argument("--sizes", type=int, nargs="+", default=None, help="scaling sizes")
    ap.add_argument("--fire-cap", type=int, default=3000,
                    help="max FIRE iterations for the hard-wall run (default 3000)")
    ap.add_argument("--child-scaling", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--replot-scaling", default=None, metavar="JSON",
                    help="redraw gfmd_scaling.png from a saved scaling JSON")
    ap.add_argument("--tamaas-threads", type=int, default=1,
                    help="OMP_NUM_THREADS for Tamaas (default 1: faster than 2 on the loaded "
                         "2-core machine, 7.1-8.7 s vs 9.8 s at 512^2; our FFTs also use 1)")
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", str(args.tamaas_threads))
    if args.replot_scaling:
        with open(args.replot_scaling) as fh:
            plot_scaling(json.load(fh)["scaling"])
        return 0
    if args.child_scaling:
        child_scaling(args.child_scaling)
        return 0
    os.makedirs(RESULTS, exist_ok=True)
    n = args.n or (256 if args.quick else 1024)
    repeats = args.repeats or (3 if args.quick else 3)
    tag = "quick" if args.quick else f"n{n}"
    results = dict(machine=dict(cpus=os.cpu_count(), python=sys.version.split()[0],
                                date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())))
    if args.part == "threads":
        print("== FFT threads")
        results["threads"] = part_threads(args.sizes or [256, 512, 1024, 2048])
    if args.part == "match":
        sizes = args.sizes or [1024, 2048]
        results["match"] = []
        for m in sizes:
            print(f"== matched error, n={m}")
            results["match"].append(part_match(m, args.repeats or (3 if m <= 1024 else 2)))
            plot_match(results["match"])
            with open(os.path.join(RESULTS, "gfmd_match.json"), "w") as fh:
                json.dump(results, fh, indent=1, default=float)
    if args.part == "breakdown":
        results["breakdown"] = [part_breakdown(m, rounds=args.rounds) for m in (args.sizes or [1024, 2048])]
    if args.part in ("hard", "all"):
        print(f"== hard wall, n={n}")
        results["hard"] = part_hard(n, repeats, fire=0 if args.no_fire else args.fire_cap)
    if args.part in ("exp", "all"):
        print(f"== exponential wall, n={n}")
        n_fire = 128 if args.quick else 512
        results["exp"] = part_exp(n, repeats, n_fire, fire_cap=20000)
    if args.part in ("scaling", "all"):
        sizes = args.sizes or ([128, 256, 512] if args.quick else [128, 256, 512, 1024, 2048])
        if args.n4096:
            sizes.append(4096)
        print(f"== scaling {sizes}")
        results["scaling"] = part_scaling(sizes)
    if args.part == "scaling":
        tag = "quick" if args.quick else "sizes"
    if args.part in ("threads", "breakdown", "match"):
        tag = "_".join(str(m) for m in args.sizes) if args.sizes else "default"
    path = os.path.join(RESULTS, f"gfmd_{args.part}_{tag}.json")
    with open(path, "w") as fh:
        json.dump(results, fh, indent=1, default=float)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
