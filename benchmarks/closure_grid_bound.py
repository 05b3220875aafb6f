"""How far the last lever of issue 10's closure row can reach: fewer grid integrations per call (a bound).

A balanced closure's call integrates a first level (three grids), the last level (three grids ``N, 2N, 4N``) and
the shell ladder's plain rungs beside the last level. The fifty-first session left this lever unmeasured. This
script times, on the Fig. 1 scene (``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``, ``E* = 8/3``,
``p0 = 0.004``, rtol 1e-6), for each balanced closure and wall:

* **call**: the closure as a user calls it (``pressure_distribution``, two threads);
* **hinted**: the call given the hints a sweep passes from its result (``n_start`` its ``cells_needed``,
  ``wall_grading`` and ``wall_depth`` those it recommends): the first level's cells and grading known, not its remap;
* **on its own grid**: the same call inside ``grid_family`` of its own result, with ``n_cells`` its last level's
  coarsest grid: what a perfect prediction of the last level's grid family would cost (no first level; its shell
  rungs then run after the main solve, not alongside its last level, which needs the engine's own family);
* **one level**: the call's own main problem (its first solve's shells and grading, ``_shell_problem``) on the call's
  own last-level grids (``grid_family`` and ``n_cells``): the three grids ``N, 2N, 4N`` of one level, two threads,
  no first level, no shell rungs, no extrapolation in the shells. Not an answer to the continuum closure (its shell
  error is 1e-4-1e-3): the least any call on these grids could cost while keeping Richardson's estimate;
* **finest grid**: that problem's ``4N`` grid alone (``plain_masses("finest")``), one thread, and the compiled stage
  kernel's share of it (``closure_timeline.py``'s wrappers of the engine, a few microseconds per call, on every
  kind timed): the least any call whose answer is extrapolated from that grid could cost, on any number of threads.

Each is a median of ``--repeats`` warm calls, the competitor (``fp_competitor.py`` on the Fig. 1 scene at
``zeta = 0.25``, rtol 1e-6) timed alternately in the same process; the ratios are to its median, against the line
8.3 (the issue's 10 ms over its competitor's 1.2 ms). Writes ``results/closure_grid_bound.md``.

    python benchmarks/closure_grid_bound.py [--zetas 0.25 0.1 0.01 0.001] [--repeats 9]
"""
from __future__ import annotations

import argparse
import functools
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diffusion_pr as dp  # noqa: E402
from bench_fokker_planck import SPECTRUM  # noqa: E402
from closure_timeline import _instrument  # noqa: E402
from closures_vs_competitor import COMPETITOR_MS, TARGET_MS, competitor_reference  # noqa: E402
from fp_competitor import interleaved  # noqa: E402
from diffusion_pr.closures import EXTRAPOLATION_SHELLS, _shell_problem  # noqa: E402
from diffusion_pr.solvers.fv.engine import grid_family, plain_masses  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "closure_grid_bound.md"
E_STAR, P0, RTOL = 8.0 / 3.0, 0.004, 1e-6
CLOSURES = ("local_g1_balanced", "local_g1_shell_balanced")


def closure_call(zeta: float, closure: str, **options):
    """The closure on the Fig. 1 scene at ``zeta``, rtol :data:`RTOL`, with the backend's ``options``."""
    return dp.pressure_distribution(SPECTRUM, E_star=E_STAR, mean_pressure=P0, zeta=zeta, closure=closure, rtol=RTOL,
                                    **options)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.25, 0.1, 0.01, 0.001])
    ap.add_argument("--repeats", type=int, default=9)
    args = ap.parse_args(argv)
    line = TARGET_MS / COMPETITOR_MS
    reference = competitor_reference()
    events: list = []  # (main thread?, start, end, label) of the engine's kernels, grids and prepare
    _instrument(events)
    lines = ["# Fewer grid integrations per call: a bound (`python benchmarks/closure_grid_bound.py`)", "",
             f"Fig. 1 scene, rtol {RTOL:g}. Medians of {args.repeats} warm calls, each kind timed alternately with "
             "the competitor in the same process; in brackets the ratio to the competitor's median (the line: "
             f"{line:.1f}). 'Hinted': the call given a sweep's hints from its own result (n_start, wall_grading, "
             "wall_depth: no remap). 'On its own grid': the call given its own last level's grid family "
             "(grid_family, n_cells; no first level). 'One level': the call's main problem on the call's last-level "
             "grids N/2N/4N, two threads, no first level and no shell rungs (not an answer to the continuum "
             "closure). 'Finest grid': its 4N grid alone, one thread, and the compiled stage kernel's share of that "
             "(the grid's integration without its problem, domain, edges and coefficient rows).", "",
             "| closure | zeta | main shells | last level's grids | call [ms] | hinted [ms], its last level | "
             "on its own grid [ms] | one level [ms] | finest grid [ms] | its kernel alone [ms] | competitor [ms] |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for closure in CLOSURES:
        for zeta in args.zetas:
            call = functools.partial(closure_call, zeta, closure)
            res = call()
            d = res.diagnostics
            scene = (SPECTRUM, E_STAR, P0, zeta, closure, None, d["shell_grading"])
            if "shells_first_tried" in d or "grids_tightened" in d:
                raise RuntimeError(f"{closure}, zeta {zeta}: the call restarted its first solve; not a bound's case")
            main_shells = EXTRAPOLATION_SHELLS  # the first solve's shells
            problem = _shell_problem(scene, main_shells)[0]
            p_floor = float(d["p_floor"])
            grid, levels = d["grid"], list(d["levels"])

            hints = dict(n_start=int(d["cells_needed"]), wall_grading=float(d["wall_grading_needed"]),
                         wall_depth=float(d["wall_depth_needed"]))

            hinted = functools.partial(closure_call, zeta, closure, **hints)

            hinted_levels = "/".join(map(str, hinted().diagnostics["levels"]))

            def known(zeta=zeta, closure=closure, grid=grid, n=levels[0]):
                with grid_family(grid):
                    return closure_call(zeta, closure, n_cells=n)

            on_grid = known()
            if not on_grid.success or list(on_grid.diagnostics["levels"]) != levels:
                raise RuntimeError(f"{closure}, zeta {zeta}: the call on its own grid did not repeat it")

            def one_level(problem=problem, p_floor=p_floor, grid=grid, n=levels[0]):
                with grid_family(grid):
                    return dp.solve_problem(problem, backend="native", rtol=RTOL, p_floor=p_floor, n_cells=n)

            def finest(problem=problem, p_floor=p_floor, grid=grid, n=levels[0]):
                with grid_family(grid), plain_masses("finest"):
                    return dp.solve_problem(problem, backend="native", rtol=RTOL, p_floor=p_floor, n_cells=n,
                                            threads=1)

            lvl = one_level()
            if list(lvl.diagnostics["levels"]) != levels:
                raise RuntimeError(f"one level on {lvl.diagnostics['levels']}, the call's last level {levels}")
            t = interleaved({"call": call, "hinted": hinted, "known": known, "level": one_level, "finest": finest,
                             "ref": reference}, args.repeats)
            kernel = []
            for _ in range(args.repeats):
                events.clear()
                finest()
                kernel.append(sum(end - start for _, start, end, label in events if label == "kernel"))
            t["kernel"] = statistics.median(kernel)
            ms = {k: 1e3 * v for k, v in t.items()}
            r = {k: v / ms["ref"] for k, v in ms.items()}
            cells = [f"{ms[k]:.2f} ({r[k]:.1f})" for k in ("call", "hinted", "known", "level", "finest", "kernel")]
            cells[1] += f", {hinted_levels}"
            lines.append(f"| `{closure}` | {zeta:g} | {main_shells} | {'/'.join(map(str, levels))} | "
                         + " | ".join(cells) + f" | {ms['ref']:.2f} |")
            print(lines[-1], flush=True)
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
