"""Work-precision benchmark of the Fokker-Planck backends (native, pypde, fipy).

Three problems (SPEC section 4; issue 3):

``mirror``
    ``f = 1``, ``p0 = 1``, ``V = 1``: Persson's mirror Gaussian plus the
    ``erfc`` weight at ``p = 0``.  Error: exact L1 of the cell averages
    (8-point Gauss-Legendre per cell) plus ``|zero_weight error|``.
``feller``
    ``f = p / p1`` with ``p1 = 1``, ``p0 = 1``, ``V = 1`` (``tau = 1/2``):
    Feller's Bessel solution, ``e^-2`` absorbed.  Same exact L1 error.
``fig1``
    The paper's Fig. 1 scene with the seed cutoff: ``p0 = 0.004``, ``V`` the
    second-order cumulant stress variance of the Fig. 1 continuum spectrum at
    ``zeta = 0.25`` (``E* = 8/3``), ``f = MuserCutoff(p_c = 0.0027)`` (jumps
    2 -> 1 at ``p_c``).  No closed form; reference: the finest native run
    (65536 cells, cached in ``results/fp_fig1_reference_65536.npz`` together
    with a hash of the native/_common source; recomputed when that changes).  Error:
    L1 of the cell masses on the backend's own grid against the reference's
    CDF, with the mass below ``p_lump = p_c/10`` plus ``zero_weight`` as one
    bin (the seed cutoff ``~ p^2`` near 0 sends mass to ever smaller ``p``,
    which no grid resolves; see ``pypde_backend.lump_pressure``).

Backends: ``native``; ``pypde``; ``fipy`` (default: FiPy assembles the
operator once, banded Crank-Nicolson); ``fipy-loop`` (``assemble_once=False``:
FiPy's ``eq.solve`` every half step, the pure-FiPy path that non-autonomous
problems take).

Two kinds of measurement:

1. Work-precision ladders at *fixed* resolution (``n_cells`` given; py-pde
   and FiPy with ``refine=False``, native with its one nested pair), warm:
   one discarded call, then the median of ``--repeats`` (>= 3) timed calls
   (``time.perf_counter`` around the call).  From these the time ratio to
   native at equal error (log-log interpolation on native's curve).
2. The user-facing adaptive call ``solve(problem, rtol)`` (refinement loop,
   error estimate), warm (median) and cold: a fresh Python process per
   backend and problem that imports the backend (import time), makes the
   first call (py-pde/FiPy warm-up or native's JIT, reported separately),
   and times the solve itself.

Outputs (``benchmarks/results/``): ``fp_work_precision.json`` (all numbers),
``fp_table.md`` (the printed tables), ``fp_wp_<problem>.png`` (plots).

Run: ``python benchmarks/bench_fokker_planck.py`` (about 5 min on 2 cores) or
``--quick`` (about 1 min: short ladders, fig1 reference on 16384 cells, one
cold run per backend).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
from numpy.polynomial.legendre import leggauss

from diffusion_pr.closed_forms import feller_density, feller_zero_weight, mirror_gaussian_density, persson_zero_weight
from diffusion_pr.models import GaussianTail, MuserCutoff, PressureFactor
from diffusion_pr.problem import FokkerPlanckProblem
from diffusion_pr.solvers import get_backend

RESULTS = Path(__file__).resolve().parent / "results"
BACKENDS = ("native", "pypde", "fipy", "fipy-loop")
#: variants: benchmark name -> (registry backend, extra keywords)
VARIANTS = {"native": ("native", {}), "pypde": ("pypde", {}), "fipy": ("fipy", {"assemble_once": True}),
            "fipy-loop": ("fipy", {"assemble_once": False})}
FIG1 = {"p0": 0.004, "p_c": 0.0027, "zeta": 0.25, "E_star": 8.0 / 3.0}
FELLER_P1 = 1.0
_XG, _WG = leggauss(8)


# ----------------------------------------------------------------------------- problems
def fig1_variance() -> tuple[float, str]:
    """Stress variance of the Fig. 1 continuum spectrum at zeta = 0.25 (pressure^2) and its source."""
    try:
        from diffusion_pr.cumulants import stress_variance
        from diffusion_pr.spectra import SelfAffineSpectrum

        spec = SelfAffineSpectrum(0.3, 2 * math.pi / 1024, 2 * math.pi / 32, rms_slope=0.031)
        v = float(stress_variance(spec, E_star=FIG1["E_star"], mean_pressure=FIG1["p0"], zeta=FIG1["zeta"]))
        return v, "diffusion_pr.cumulants.stress_variance (continuum, zeta=0.25)"
    except ImportError:  # pragma: no cover - fallback while cumulants is missing
        return 0.006404621979931326**2, "hard-coded value of stress_variance at zeta=0.25"


def make_problem(name: str) -> FokkerPlanckProblem:
    if name == "mirror":
        return FokkerPlanckProblem(1.0, 1.0, label="mirror Gaussian p0=1 V=1")
    if name == "feller":
        return FokkerPlanckProblem(1.0, 1.0, diffusivity=_Linear(FELLER_P1), label="Feller f=p/p1 p1=1 p0=1 V=1")
    if name == "fig1":
        v, _ = fig1_variance()
        return FokkerPlanckProblem(FIG1["p0"], v, diffusivity=PressureFactor(MuserCutoff(FIG1["p_c"]), GaussianTail()),
                                   label="Fig.1 scene, seed cutoff p_c=0.0027, zeta=0.25")
    raise ValueError(name)


class _Linear:
    """``f(p) = p / p1`` (a picklable, printable callable)."""

    def __init__(self, p1: float) -> None:
        self.p1 = p1

    def __call__(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(p, dtype=float) / self.p1


def _cell_average(density: Callable, edges: np.ndarray) -> np.ndarray:
    lo, hi = edges[:-1], edges[1:]
    pts = 0.5 * (lo + hi)[:, None] + 0.5 * (hi - lo)[:, None] * _XG[None, :]
    return 0.5 * np.sum(density(pts) * _WG[None, :], axis=1)


def lumped_masses(edges_src: np.ndarray, cum_src: np.ndarray, zero: float, edges: np.ndarray, p_lump: float) -> np.ndarray:
    m = np.diff(np.interp(edges, edges_src, cum_src))
    k = int(np.searchsorted(edges[1:], p_lump, side="right"))
    return np.concatenate(([m[:k].sum() + zero], m[k:]))


def _source_stamp() -> str:
    """Hash of the native backend's and ``_common``'s source (invalidates the cached reference)."""
    import hashlib

    import diffusion_pr.solvers._common as common
    import diffusion_pr.solvers.native as native

    digest = hashlib.sha256()
    for mod in (native, common):
        digest.update(Path(mod.__file__).read_bytes())
    return digest.hexdigest()[:16]


class ErrorMeter:
    """L1 error of a result for one problem (exact or against the fig1 reference)."""

    def __init__(self, name: str, problem: FokkerPlanckProblem, quick: bool) -> None:
        self.name = name
        self.problem = problem
        self.ref_info: dict[str, Any] = {}
        if name == "fig1":
            self._load_reference(quick)

    def _load_reference(self, quick: bool) -> None:
        n_ref = 2**14 if quick else 2**16
        path = RESULTS / f"fp_fig1_reference_{n_ref}.npz"
        stamp = _source_stamp()
        if path.exists():
            data = np.load(path)
            if str(data["stamp"]) == stamp:  # same native/_common source: the cache is valid
                self.ref_edges, self.ref_cum, self.ref_zero = data["edges"], data["cum"], float(data["zero_weight"])
                self.ref_info = {"cells": n_ref, "cached": str(path.name), "seconds": float(data["seconds"])}
                return
        t0 = time.perf_counter()
        ref = get_backend("native")(self.problem, n_cells=n_ref)
        sec = time.perf_counter() - t0
        cum = np.concatenate(([0.0], np.cumsum(ref.density * ref.weights)))
        self.ref_edges, self.ref_cum, self.ref_zero = ref.edges, cum, float(ref.zero_weight)
        RESULTS.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, edges=ref.edges, cum=cum, zero_weight=ref.zero_weight, seconds=sec, stamp=stamp)
        self.ref_info = {"cells": n_ref, "cached": None, "seconds": sec}

    @property
    def p_lump(self) -> float:
        return 0.1 * FIG1["p_c"]

    def __call__(self, res: Any) -> float:
        if self.name == "mirror":
            ex = _cell_average(lambda p: mirror_gaussian_density(p, 1.0, 1.0), res.edges)
            return float(np.sum(res.weights * np.abs(res.density - ex)) + abs(res.zero_weight - persson_zero_weight(1.0, 1.0)))
        if self.name == "feller":
            a, tau = 1.0 / FELLER_P1, self.problem.tau_end
            ex = _cell_average(lambda p: feller_density(p, 1.0, tau, a), res.edges)
            return float(np.sum(res.weights * np.abs(res.density - ex)) + abs(res.zero_weight - feller_zero_weight(1.0, tau, a)))
        cum = np.concatenate(([0.0], np.cumsum(res.density * res.weights)))
        mine = lumped_masses(res.edges, cum, res.zero_weight, res.edges, self.p_lump)
        ref = lumped_masses(self.ref_edges, self.ref_cum, self.ref_zero, res.edges, self.p_lump)
        return float(np.sum(np.abs(mine - ref)))


# ----------------------------------------------------------------------------- ladders
def ladders(quick: bool) -> dict[str, dict[str, list[int]]]:
    """Fixed resolutions per backend and problem (cells; FiPy steps = cells/2)."""
    if quick:
        return {
            "native": {p: [128, 512, 2048] for p in ("mirror", "feller", "fig1")},
            "pypde": {"mirror": [64, 256, 1024], "feller": [256, 1024, 4096], "fig1": [512, 2048]},
            "fipy": {p: [128, 512, 2048] for p in ("mirror", "feller", "fig1")},
            "fipy-loop": {"mirror": [32, 128], "feller": [64, 128], "fig1": [64, 128]},
        }
    return {
        "native": {p: [64, 128, 256, 512, 1024, 2048, 4096, 8192] for p in ("mirror", "feller", "fig1")},
        "pypde": {"mirror": [64, 128, 256, 512, 1024, 2048, 4096], "feller": [256, 512, 1024, 2048, 4096, 8192],
                  "fig1": [256, 512, 1024, 2048, 4096, 8192]},
        "fipy": {p: [64, 128, 256, 512, 1024, 2048, 4096, 8192] for p in ("mirror", "feller", "fig1")},
        "fipy-loop": {"mirror": [32, 64, 128, 256], "feller": [64, 128, 256], "fig1": [64, 128, 256]},
    }


def run_fixed(variant: str, problem: FokkerPlanckProblem, n: int) -> Any:
    backend, extra = VARIANTS[variant]
    solve = get_backend(backend)
    if backend == "native":
        return solve(problem, n_cells=n)
    if backend == "pypde":
        # BDF tolerance scaled with the grid (spatial error ~ 6/n^2 here), so the ODE error stays below it
        return solve(problem, rtol=1e-4, n_cells=n, refine=False, ode_rtol=min(2e-5, 0.13 / n**2))
    return solve(problem, rtol=1e-4, n_cells=n, n_steps=max(16, n // 2), refine=False, **extra)


def run_adaptive(variant: str, problem: FokkerPlanckProblem, pname: str, rtol: float) -> Any:
    backend, extra = VARIANTS[variant]
    return get_backend(backend)(problem, rtol=rtol, **extra)


def steps_of(res: Any) -> str:
    d = res.diagnostics
    if res.backend == "native":
        return str(d.get("n_steps"))
    if res.backend == "fipy":
        return str(d.get("steps"))
    return f"{d.get('rhs_evaluations')} rhs"


def timed(fn: Callable[[], Any], repeats: int) -> tuple[Any, float, list[float]]:
    """One discarded warm-up call, then the median of ``repeats`` timed calls."""
    res = fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = fn()
        times.append(time.perf_counter() - t0)
    return res, statistics.median(times), times


def interp_native_time(native_pts: list[dict], err: float) -> tuple[float, bool]:
    """Native's warm time to reach L1 error ``err``.

    The native points are reduced to their lower envelope (the time of the
    cheapest native run whose error is ``<= e``, which removes timing noise
    that makes a finer run look cheaper), then interpolated log-log;
    extrapolated linearly in log-log beyond the ends (flagged).
    """
    pts = sorted((p["error"], p["warm_time"]) for p in native_pts if p["error"] > 0)
    errs = np.array([e for e, _ in pts])
    times = np.minimum.accumulate(np.array([t for _, t in pts]))  # ascending error: cheapest run at least this good
    le, lt = np.log(errs), np.log(times)
    x = math.log(err)
    if le[0] <= x <= le[-1]:
        return float(np.exp(np.interp(x, le, lt))), False
    i, j = (0, 1) if x < le[0] else (-2, -1)
    slope = (lt[j] - lt[i]) / (le[j] - le[i]) if le[j] != le[i] else 0.0
    return float(np.exp(lt[i] + slope * (x - le[i]))), True


# ----------------------------------------------------------------------------- cold runs
_COLD_SCRIPT = r"""
import json, sys, time
t0 = time.perf_counter()
sys.path.insert(0, {bench_dir!r})
import bench_fokker_planck as B
from diffusion_pr.solvers import get_backend
t_pkg = time.perf_counter() - t0
problem = B.make_problem({problem!r})
backend, extra = B.VARIANTS[{backend!r}]
t1 = time.perf_counter()
solve = get_backend(backend)
t_import = time.perf_counter() - t1
t2 = time.perf_counter()
res = solve(problem, rtol={rtol!r}, **extra)
t_call = time.perf_counter() - t2
d = res.diagnostics
first = d.get("first_call_time", d.get("jit_compile_time", 0.0))
print(json.dumps({{"import_time": t_import + d.get("import_time", 0.0), "first_call_time": first,
                  "solve_wall_time": res.wall_time, "first_call_total": t_call, "process_to_result": time.perf_counter() - t0,
                  "package_import": t_pkg, "success": res.success}}))
"""


def run_cold(backend: str, problem: str, rtol: float) -> dict[str, Any]:
    code = _COLD_SCRIPT.format(bench_dir=str(Path(__file__).resolve().parent), problem=problem, backend=backend, rtol=rtol)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900,
                         env={**os.environ, "PYTHONWARNINGS": "ignore"})
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "failed"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def _git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).resolve().parent, timeout=10).stdout.strip()
    except Exception:  # pragma: no cover
        return "unknown"


# ----------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="short ladders, fig1 reference on 16384 cells")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats per point (median; >= 3)")
    ap.add_argument("--problems", default="mirror,feller,fig1")
    ap.add_argument("--backends", default=",".join(BACKENDS))
    ap.add_argument("--no-cold", action="store_true", help="skip the cold (fresh process) runs")
    ap.add_argument("--no-plot", action="store_true")
    args = ap.parse_args(argv)
    repeats = max(3, args.repeats)
    problems = [p for p in args.problems.split(",") if p]
    backends = [b for b in args.backends.split(",") if b]
    if "native" not in backends:
        backends.insert(0, "native")  # the reference for the ratios
    lad = ladders(args.quick)
    RESULTS.mkdir(parents=True, exist_ok=True)
    v_fig1, v_source = fig1_variance()
    report: dict[str, Any] = {"quick": args.quick, "repeats": repeats, "fig1_variance": v_fig1,
                              "fig1_variance_source": v_source, "cpu_count": os.cpu_count(),
                              "problems": {}, "started": time.strftime("%Y-%m-%d %H:%M:%S"),
                              "git_commit": _git_commit()}
    lines: list[str] = []

    def emit(s: str = "") -> None:
        print(s, flush=True)
        lines.append(s)

    emit(f"# Fokker-Planck backends: work-precision ({'quick' if args.quick else 'full'} run, "
         f"median of {repeats} warm calls)")
    emit(f"git commit {report['git_commit']}, {report['started']}, {os.cpu_count()} CPUs (shared with other jobs)")
    emit(f"Fig.1 scene: p0 = {FIG1['p0']}, sqrt(V) = {math.sqrt(v_fig1):.6g} ({v_source}), seed cutoff p_c = {FIG1['p_c']}")
    for pname in problems:
        problem = make_problem(pname)
        meter = ErrorMeter(pname, problem, args.quick)
        entry: dict[str, Any] = {"label": problem.label, "reference": meter.ref_info, "fixed": {}, "adaptive": {},
                                 "closed_form": None}
        # closed form reference line
        if pname in ("mirror", "feller"):
            try:
                from diffusion_pr.solvers import closed_form as cfm

                res, med, _ = timed(lambda: cfm.solve(problem), repeats)
                entry["closed_form"] = {"warm_time": med, "cells": int(res.p.size), "error_estimate": res.error_estimate}
            except Exception as exc:  # pragma: no cover - closed_form backend absent
                entry["closed_form"] = {"error": repr(exc)}
        for b in backends:
            pts = []
            for n in lad[b][pname]:
                res, med, times = timed(lambda: run_fixed(b, problem, n), repeats)
                pts.append({"cells": int(res.p.size), "steps": steps_of(res), "error": meter(res), "warm_time": med,
                            "times": times, "reported_wall_time": res.wall_time, "success": res.success,
                            "mass_error": res.mass - 1.0, "mean_error": res.mean - problem.mean_pressure,
                            "min_density": float(res.density.min())})
            entry["fixed"][b] = pts
        # ratios to native at equal error
        for b in backends:
            for pt in entry["fixed"][b]:
                t_nat, extrap = interp_native_time(entry["fixed"]["native"], pt["error"])
                pt["native_time_at_error"] = t_nat
                pt["ratio_to_native"] = pt["warm_time"] / t_nat
                pt["ratio_extrapolated"] = extrap
        # adaptive, user-facing calls
        for b in backends:
            rtols = {"native": [1e-4, 1e-6], "fipy": [1e-4, 1e-6], "pypde": [1e-4, 1e-5]}.get(b, [1e-4])
            for rtol in rtols:
                res, med, times = timed(lambda: run_adaptive(b, problem, pname, rtol), repeats)
                entry["adaptive"][f"{b}@{rtol:g}"] = {
                    "backend": b, "rtol": rtol, "cells": int(res.p.size), "steps": steps_of(res), "error": meter(res),
                    "error_estimate": res.error_estimate, "success": res.success, "warm_time": med, "times": times,
                    "message": res.message}
        report["problems"][pname] = entry

        emit()
        emit(f"## {pname}: {problem.label}")
        if meter.ref_info:
            emit(f"reference: native on {meter.ref_info['cells']} cells ({meter.ref_info['seconds']:.1f} s to compute)")
        if entry["closed_form"] and "warm_time" in entry["closed_form"]:
            emit(f"closed form (closed_form backend, {entry['closed_form']['cells']} nodes): "
                 f"{entry['closed_form']['warm_time'] * 1e3:.3f} ms warm")
        emit()
        emit("| backend | cells | steps | L1 error | warm time [ms] | native time at that error [ms] | ratio to native |")
        emit("|---|---|---|---|---|---|---|")
        for b in backends:
            for pt in entry["fixed"][b]:
                ratio = f"{pt['ratio_to_native']:.3g}" + (" (extrap.)" if pt["ratio_extrapolated"] else "")
                emit(f"| {b} | {pt['cells']} | {pt['steps']} | {pt['error']:.2e} | {pt['warm_time'] * 1e3:.2f} | "
                     f"{pt['native_time_at_error'] * 1e3:.3g} | {ratio} |")
        emit()
        emit("Adaptive calls `solve(problem, rtol)` (refinement + error estimate), warm:")
        emit()
        emit("| backend | rtol | cells | steps | L1 error | estimate | success | warm time [ms] |")
        emit("|---|---|---|---|---|---|---|---|")
        for key, a in entry["adaptive"].items():
            emit(f"| {a['backend']} | {a['rtol']:.0e} | {a['cells']} | {a['steps']} | {a['error']:.2e} | "
                 f"{a['error_estimate']:.2e} | {a['success']} | {a['warm_time'] * 1e3:.1f} |")
        with open(RESULTS / "fp_work_precision.json", "w") as fh:
            json.dump(report, fh, indent=1, default=float)

    # cold runs: fresh process per backend (and problem), the adaptive rtol=1e-4 call
    if not args.no_cold:
        emit()
        emit("## Cold start (fresh process, adaptive call with rtol = 1e-4)")
        emit()
        emit("| backend | problem | import [s] | first call / JIT [s] | solve wall_time [s] | first call total [s] | success |")
        emit("|---|---|---|---|---|---|---|")
        cold_problems = problems[:1] if args.quick else problems
        report["cold"] = {}
        for pname in cold_problems:
            for b in [x for x in backends if x != "fipy-loop" or pname == "mirror"]:
                runs = [run_cold(b, pname, 1e-4) for _ in range(1 if args.quick else 3)]
                ok = [r for r in runs if "error" not in r]
                if not ok:
                    emit(f"| {b} | {pname} | failed: {runs[0].get('error')} | | | | |")
                    continue
                med = {k: statistics.median(r[k] for r in ok) for k in ("import_time", "first_call_time",
                                                                          "solve_wall_time", "first_call_total")}
                report["cold"][f"{b}/{pname}"] = {"median": med, "runs": runs}
                emit(f"| {b} | {pname} | {med['import_time']:.2f} | {med['first_call_time']:.2f} | "
                     f"{med['solve_wall_time']:.3f} | {med['first_call_total']:.2f} | {all(r['success'] for r in ok)} |")
    report["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    with open(RESULTS / "fp_work_precision.json", "w") as fh:
        json.dump(report, fh, indent=1, default=float)
    (RESULTS / "fp_table.md").write_text("\n".join(lines) + "\n")
    if not args.no_plot:
        plot(report)
    return 0


def _rtols(ads: list[dict]) -> str:
    return ", ".join(format(a["rtol"], ".0e") for a in ads)


def plot(report: dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"native": "C0", "pypde": "C1", "fipy": "C2", "fipy-loop": "C3"}
    for pname, entry in report["problems"].items():
        fig, ax = plt.subplots(figsize=(6.4, 4.6))
        for b, pts in entry["fixed"].items():
            t = [p["warm_time"] for p in pts]
            e = [p["error"] for p in pts]
            ax.loglog(t, e, "o-", color=colors.get(b), ms=4, label=f"{b} (fixed grids, warm)")
            cold = report.get("cold", {}).get(f"{b}/{pname}")
            ads = [a for a in entry["adaptive"].values() if a["backend"] == b]
            if ads:
                ax.loglog([a["warm_time"] for a in ads], [max(a["error"], 1e-12) for a in ads], "s", color=colors.get(b),
                          mfc="none", ms=9, label=f"{b} solve(rtol={_rtols(ads)}), warm")
            ad = entry["adaptive"].get(f"{b}@0.0001")
            if ad:
                if cold:
                    tc = cold["median"]["first_call_total"] + cold["median"]["import_time"]
                    ax.loglog([tc], [ad["error"]], "x", color=colors.get(b), ms=9,
                              label=f"{b} rtol=1e-4 cold (import+first call)")
        cf = entry.get("closed_form") or {}
        if "warm_time" in cf:
            ax.axvline(cf["warm_time"], color="k", ls="--", lw=1, label="closed form evaluation")
        for target in (1e-4, 1e-6):
            ax.axhline(target, color="0.6", ls=":", lw=1)
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel("L1 error" + (" (lumped below p_c/10, vs finest native)" if pname == "fig1" else " (exact)"))
        ax.set_title(entry["label"], fontsize=9)
        ax.legend(fontsize=6.5, loc="best")
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        fig.savefig(RESULTS / f"fp_wp_{pname}.png", dpi=120)
        plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
