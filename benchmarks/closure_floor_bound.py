"""How much of the balanced closures' time at small ``zeta`` the deep layer below ``p*`` costs: a bound.

The forty-eighth session concluded that the closure row of issue 10 (every closure under 10 ms per Fig. 1 scene)
needs "fewer cells in the deep layer" at ``zeta <= 0.1``: a discretization that resolves the ``ln p`` random walk
between ``p* = zeta q_min E*/2`` and the closure's floor (``closures.BALANCED_FLOOR p*``, 1e-16 ``p*``) with fewer
cells. This script bounds what any such discretization can gain. It solves the same closures with the floor raised
to ``1e-8``, ``1e-4`` and ``1e-2 p*``: the deep layer shortened or removed, the cells there with it. That is a
*different problem* (the floor is part of the balanced closures' definition, docs/closures.md, and ``F(p0/20)``
moves by up to 2.3e-2 here), so these answers are not offered to users; their time is the time of a solve whose
deep layer costs nothing, which no better discretization of the deep layer can beat.

Each call is paired with a call of ``fp_competitor.py``'s competitor on the Fig. 1 scene at ``zeta = 0.25`` (as in
``closures_vs_competitor.py``); a round's ratio is the median of its pairs' ratios. The table gives, per closure,
``zeta`` and floor: the median ratio over the rounds and their range, the warm median [ms], the output cells, the
cells of the three grids of the last level and ``F(p0/20)``. The line is ``10 / 1.2 = 8.3`` (the issue's 10 ms in
the competitor's units). Writes ``results/closure_floor_bound.md``.

    python benchmarks/closure_floor_bound.py [--rounds 2] [--repeats 7] [--zetas 0.1 0.01 0.001]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

from diffusion_pr.closures import BALANCED_FLOOR, closure_distribution
from diffusion_pr.solvers.fv import engine

from bench_fokker_planck import OUT, SPECTRUM
from closures_vs_competitor import COMPETITOR_MS, TARGET_MS, competitor_reference, paired_ratio

CLOSURES = ("local_g1_balanced", "local_g1_shell_balanced")
#: the floor in units of p* = zeta q_min E*/2: the closures' own (BALANCED_FLOOR) first
FLOORS = (BALANCED_FLOOR, 1e-8, 1e-4, 1e-2)
E_STAR, P0 = 8 / 3, 0.004


def kernel_grids(solve) -> list:
    """``(cells, stages, seconds)`` of every grid the compiled stage kernel integrates in one call of ``solve``, in
    the order the calls end (both threads)."""
    seen = []
    original = engine._Kernels.run_rows

    def counted(self, edges, f_rows, *args, **kwargs):
        t0 = time.perf_counter()
        out = original(self, edges, f_rows, *args, **kwargs)
        seen.append((len(edges) - 1, f_rows.shape[0], time.perf_counter() - t0))
        return out

    engine._Kernels.run_rows = counted
    try:
        solve()
    finally:
        engine._Kernels.run_rows = original
    return seen


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.1, 0.01, 0.001])
    args = ap.parse_args()
    reference = competitor_reference()
    line = TARGET_MS / COMPETITOR_MS
    keys = [(c, z, fl) for c in CLOSURES for z in args.zetas for fl in FLOORS]
    ratios: dict = {k: [] for k in keys}
    times: dict = {k: [] for k in keys}
    info: dict = {}
    load = os.getloadavg()[0]
    for rnd in range(args.rounds):
        for closure, zeta, floor in keys:
            p_star = 0.5 * zeta * E_STAR * SPECTRUM.q_min

            def solve(zeta=zeta, closure=closure, floor=floor, p_star=p_star):
                return closure_distribution(SPECTRUM, E_star=E_STAR, mean_pressure=P0, zeta=zeta, closure=closure,
                                            rtol=1e-6, p_floor=floor * p_star)

            if rnd == 0:
                r = solve()
                grids = kernel_grids(solve)
                info[closure, zeta, floor] = (r.success, r.diagnostics["n_cells"], grids, float(r.cdf(P0 / 20)),
                                              r.error_estimate)
            ratios[closure, zeta, floor].append(paired_ratio(solve, reference, args.repeats,
                                                             times[closure, zeta, floor], []))
            print(f"round {rnd + 1}: {closure:24s} zeta {zeta:6g} floor {floor:6g} p*: ratio "
                  f"{ratios[closure, zeta, floor][-1]:5.2f}", flush=True)
    lines = [f"Load average at the start {load:.2f}; {args.rounds} rounds of {args.repeats} interleaved warm call "
             f"pairs (closure, then the competitor on the Fig. 1 scene at zeta = 0.25), rtol 1e-6, two threads. The "
             f"floor in units of p* = zeta q_min E*/2; {BALANCED_FLOOR:g} p* is the closures' definition, the others "
             f"are different problems (the deep layer shortened or removed), timed only to bound what a better "
             f"discretization of the deep layer could save. The line: {line:.1f}.", "",
             "| closure | zeta | floor [p*] | ratio | rounds' range | warm median [ms] | output cells | "
             "last level's grids (main solve) | F(p0/20) | estimate | success |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for key in keys:
        closure, zeta, floor = key
        ok, n_cells, grids, cdf, est = info[key]
        rr = ratios[key]
        stages = grids[0][1]  # the main solve's shells (the ladder's rungs have more or fewer)
        main_grids = [n for n, k, _ in grids if k == stages][-3:]  # its last level
        lines.append(f"| `{closure}` | {zeta:g} | {floor:g} | {statistics.median(rr):.2f} | {min(rr):.2f}-"
                     f"{max(rr):.2f} | {1e3 * statistics.median(times[key]):.1f} | {n_cells} | "
                     f"{'/'.join(map(str, sorted(main_grids)))} | {cdf:.6f} | {est:.1e} | {ok} |")
    lines += ["", "The compiled stage kernel's calls in one warm call (both threads; cells x stages: ms), from the "
              "first round's extra call: the main solve's levels (three grids each), then the shell ladder's plain "
              "solves and rungs.", "", "| closure | zeta | floor [p*] | kernel calls | their sum [ms] |",
              "|---|---|---|---|---|"]
    for key in keys:
        closure, zeta, floor = key
        grids = info[key][2]
        calls = ", ".join(f"{n}x{k}: {1e3 * t:.2f}" for n, k, t in grids)
        lines.append(f"| `{closure}` | {zeta:g} | {floor:g} | {calls} | {1e3 * sum(t for *_, t in grids):.1f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    OUT.mkdir(exist_ok=True)
    (OUT / "closure_floor_bound.md").write_text(text)
    print(f"wrote {OUT / 'closure_floor_bound.md'}")


if __name__ == "__main__":
    main()
