"""Work-precision benchmark of the finite-volume engine and its backends (issue 10 items 1-3, 5).

Problems (docs/theory.md, docs/fig1.md):

``mirror``   ``f = 1``, ``p0 = V = 1``: Persson's mirror Gaussian (exact L1 of cell masses + zero weight).
``feller``   ``f = p``, ``p0 = V = 1``: Feller's Bessel solution (exact, same metric).
``fig1-z``   the Fig. 1 scenes (continuum spectrum, ``E* = 8/3``, ``p0 = 0.004``, zeta = 4, 1, 0.25, 0.01,
             Muser's literal cutoff at the paper's ``p_c``); oracle: native at rtol 1e-10, error = L1 of
             the cell masses against its cumulative plus ``|zero_weight error|``.
``literal``  zeta = 0.25 with the literal cutoff written by a user (``1 - cos``, no model protocol).

Backends: ``native``; ``pypde`` and ``fipy`` (their operators on the engine's grids, its rational exponential: CF-10, CF-12 or CRAM-16 by rtol);
``pypde-loop`` and ``fipy-loop`` (the libraries' own time loops, loose rtol only: seconds per solve).
Warm medians of ``--repeats`` calls after one discarded call.  Also: a 100-zeta sweep at rtol 1e-6 (a loop,
and ``pressure_distributions``, which starts each solve at the previous zeta's coarse cells),
``fit_cutoff_pressure`` at rtol 1e-4 and the cold start (first solve in a fresh process, after import).

Writes ``benchmarks/results/fp_table.md``, ``fp_work_precision.json``, ``fp_work_precision.png``,
``fp_estimate_vs_true.png``.  Run ``python benchmarks/bench_fokker_planck.py`` (about 3 min on a loaded
2-core machine; ``--quick`` about 1 min).
"""
from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

import diffusion_pr as dp
from diffusion_pr import closed_forms as cf
from diffusion_pr.problem import FokkerPlanckProblem
from diffusion_pr.solvers import get_backend, warm_up

OUT = Path(__file__).resolve().parent / "results"
SPECTRUM = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
PAPER_PC = {4.0: 0.0027, 1.0: 0.0027, 0.25: 0.0027, 0.01: 0.0082}


def cell_mass(fun, edges, n=8):
    x, w = np.polynomial.legendre.leggauss(n)
    a, b = edges[:-1], edges[1:]
    pts = 0.5 * (b - a)[:, None] * x[None, :] + 0.5 * (a + b)[:, None]
    return np.sum(0.5 * (b - a)[:, None] * w[None, :] * fun(pts), axis=1)


def problems():
    out = {
        "mirror": (FokkerPlanckProblem(1.0, 1.0),
                   lambda r: float(np.sum(np.abs(r.density * r.weights - cell_mass(
                       lambda p: cf.mirror_gaussian_density(p, 1.0, 1.0), r.edges)))
                       + abs(r.zero_weight - cf.persson_zero_weight(1.0, 1.0)))),
        "feller": (FokkerPlanckProblem(1.0, 1.0, dp.ProportionalDiffusivity(1.0)),
                   lambda r: float(np.sum(np.abs(r.density * r.weights - cell_mass(
                       lambda p: cf.feller_density(p, 1.0, 0.5, 1.0), r.edges)))
                       + abs(r.zero_weight - cf.feller_zero_weight(1.0, 0.5, 1.0)))),
    }
    for z, pc in PAPER_PC.items():
        V = float(dp.stress_variance(SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=z))
        pr = FokkerPlanckProblem(0.004, V, dp.PressureFactor(dp.MuserCutoff(pc), dp.GaussianTail()))
        out[f"fig1-z{z:g}"] = (pr, _oracle(pr))
    V = float(dp.stress_variance(SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=0.25))
    lit = lambda p: np.where(p < 0.0027, 1 - np.cos(np.pi * p / 0.0027), 1.0)  # noqa: E731
    pr = FokkerPlanckProblem(0.004, V, lit)
    out["literal"] = (pr, _oracle(FokkerPlanckProblem(0.004, V, dp.PressureFactor(dp.MuserCutoff(0.0027),
                                                                                     dp.GaussianTail()))))
    return out


def l1_against(ref, r) -> float:
    """L1 distance of a finite-volume result's cell masses and zero weight from ``ref`` (its cdf on the cells)."""
    return float(np.sum(np.abs(np.diff(ref.cdf(r.edges)) - r.density * r.weights))
                 + abs(r.zero_weight - ref.zero_weight))


def _oracle(problem):
    ref = get_backend("native")(problem, rtol=1e-10)
    return lambda r: l1_against(ref, r)


def timed(fn, repeats):
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = fn()
        ts.append(time.perf_counter() - t0)
    return r, statistics.median(ts)


def cold_start():
    """``(import, first solve)`` [s] of the paper's problem, medians of 3 fresh processes (``cold_start.py``'s
    child: byte code cached as in a default installation)."""
    from cold_start import child  # benchmarks/cold_start.py (this script's folder is on sys.path)

    runs = [child("paper", 0.0, "package") for _ in range(3)]
    return statistics.median(r["import_s"] for r in runs), statistics.median(r["first_s"] for r in runs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer tolerances and repeats (default: off)")
    ap.add_argument("--repeats", type=int, default=5, help="timed calls per point, median reported (default: 5)")
    args = ap.parse_args()
    OUT.mkdir(exist_ok=True)
    rtols = [1e-3, 1e-5, 1e-7] if args.quick else [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8]
    repeats = 3 if args.quick else args.repeats
    for name in ("pypde", "fipy"):
        print(f"warm_up({name!r}): {warm_up(name):.2f} s (imports, not billed to the solves)")
    rows = []
    probs = problems()
    for pname, (problem, err) in probs.items():
        for backend in ("native", "pypde", "fipy", "pypde-loop", "fipy-loop"):
            loop = backend.endswith("-loop")
            if loop and pname not in ("mirror", "feller"):
                continue
            for rtol in ([1e-3, 1e-4] if loop else rtols):
                solve = get_backend(backend.replace("-loop", ""))
                kw = {"method": "loop"} if loop else {}
                r, t = timed(lambda: solve(problem, rtol=rtol, **kw), 1 if loop else repeats)
                e = err(r)
                rows.append(dict(problem=pname, backend=backend, rtol=rtol, time=t, error=e,
                                 estimate=r.error_estimate, ratio=r.error_estimate / e if e > 0 else float("nan"),
                                 cells=int(r.p.size), success=bool(r.success)))
                print(f"{pname:10s} {backend:11s} rtol {rtol:.0e}  {t * 1e3:9.2f} ms  error {e:.2e}  "
                      f"estimate {r.error_estimate:.2e}  est/true {rows[-1]['ratio']:.2f}  cells {r.p.size}"
                      f"  {'ok' if r.success else 'FAIL'}")
    zetas = np.geomspace(1e-3, 4.0, 100)

    def run_sweep(hinted: bool) -> float:
        """100 zetas; ``hinted``: ``pressure_distributions``, each solve starting at the previous one's cells."""
        kw = dict(E_star=8 / 3, mean_pressure=0.004, cutoff="muser", p_c=0.0027, rtol=1e-6)
        t0 = time.perf_counter()
        if hinted:
            dp.pressure_distributions(SPECTRUM, zetas=zetas, **kw)
        else:
            for z in zetas:
                dp.pressure_distribution(SPECTRUM, zeta=float(z), **kw)
        return time.perf_counter() - t0

    sweeps: dict = {False: [], True: []}
    for _ in range(3):  # interleaved, medians of 3
        for hinted in (False, True):
            sweeps[hinted].append(run_sweep(hinted))
    sweep, sweep_hinted = statistics.median(sweeps[False]), statistics.median(sweeps[True])
    print(f"100-zeta sweep (muser p_c = 0.0027, rtol 1e-6): {sweep:.2f} s as a loop; pressure_distributions "
          f"(n_start from the previous zeta): {sweep_hinted:.2f} s (medians of 3)")
    from diffusion_pr.comparison import fit_cutoff_pressure
    from diffusion_pr.reference_data import case_name, load_reference

    case = load_reference(case_name(0.01, 1))
    t0 = time.perf_counter()
    fit = fit_cutoff_pressure(case.histogram.rebinned(2), case.spectrum, E_star=8 / 3, mean_pressure=0.004,
                              zeta=0.01, cutoff="muser", rtol=1e-4)
    t_fit = time.perf_counter() - t0
    print(f"fit_cutoff_pressure (zeta 0.01, rtol 1e-4): {t_fit:.2f} s, p_c = {fit.p_c:.5f}")
    t_imp, t_first = cold_start()
    print(f"cold start (median of 3 fresh processes): import {t_imp:.3f} s, first solve {t_first:.3f} s")
    summary = dict(rows=rows, sweep_100_zeta_s=sweep, sweep_100_zeta_hinted_s=sweep_hinted,
                   fit_cutoff_pressure_s=t_fit, cold_import_s=t_imp,
                   cold_first_solve_s=t_first)
    (OUT / "fp_work_precision.json").write_text(json.dumps(summary, indent=1))
    lines = ["| problem | backend | rtol | warm time (ms) | achieved L1 error | estimate | estimate/true | cells | ok |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['problem']} | {r['backend']} | {r['rtol']:.0e} | {r['time'] * 1e3:.2f} | {r['error']:.1e} |"
                     f" {r['estimate']:.1e} | {r['ratio']:.2f} | {r['cells']} | {'yes' if r['success'] else 'no'} |")
    lines += ["", f"100-zeta sweep at rtol 1e-6: {sweep:.2f} s ({sweep_hinted:.2f} s by pressure_distributions, "
              f"n_start from the previous zeta); fit_cutoff_pressure: {t_fit:.2f} s; "
              f"cold start: import {t_imp:.3f} s, first solve {t_first:.3f} s"]
    (OUT / "fp_table.md").write_text("\n".join(lines) + "\n")
    _plots(rows)


def _plots(rows):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = sorted({r["problem"] for r in rows}, key=lambda s: (not s.startswith(("mirror", "feller")), s))
    fig, axes = plt.subplots(2, (len(names) + 1) // 2, figsize=(4 * ((len(names) + 1) // 2), 7), squeeze=False)
    for ax, pname in zip(axes.ravel(), names):
        for backend in ("native", "pypde", "fipy", "pypde-loop", "fipy-loop"):
            pts = [(r["error"], r["time"]) for r in rows if r["problem"] == pname and r["backend"] == backend]
            if pts:
                e, t = zip(*sorted(pts))
                ax.loglog(e, np.array(t) * 1e3, "o-", label=backend)
        ax.set_title(pname)
        ax.set_xlabel("achieved L1 error")
        ax.set_ylabel("warm time (ms)")
    axes.ravel()[0].legend(fontsize=7)
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(OUT / "fp_work_precision.png", dpi=110)
    fig, ax = plt.subplots(figsize=(5, 4.5))
    for backend in ("native", "pypde", "fipy", "pypde-loop", "fipy-loop"):
        pts = [(r["error"], r["estimate"]) for r in rows if r["backend"] == backend and r["error"] > 0]
        if pts:
            e, s = zip(*pts)
            ax.loglog(e, s, "o", label=backend, alpha=0.7)
    lim = np.array([1e-12, 1e-2])
    ax.loglog(lim, lim, "k-", lw=0.8)
    ax.loglog(lim, 10 * lim, "k:", lw=0.8)
    ax.loglog(lim, lim / 10, "k:", lw=0.8)
    ax.set_xlabel("achieved L1 error")
    ax.set_ylabel("error estimate")
    ax.set_title("estimate against truth (dotted: factor 10)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(OUT / "fp_estimate_vs_true.png", dpi=110)


if __name__ == "__main__":
    main()
