"""Shell schemes beyond the midpoint rule: what a higher-order rule in the diffusion time would buy (issue 10).

The balanced closures at ``zeta <= 0.01`` spend most of a call on the shells' ladder: besides the 48-shell main
solve, the plain problems of 96 and 192 shells on the answer's ``N`` and ``2N`` grids, because the midpoint
rule's error in the shell width is second order and Romberg needs the finer ladder there
(docs/closures.md "Higher-order shell rules measured").  This script measures two alternatives on the answer's
own ``N`` grid (the plain masses of :func:`~diffusion_pr.solvers.fv.engine.plain_batch`, so that only the shells
differ), as L1 errors of the zero weight and the cell masses:

* **the midpoint rule** (the closures' stages today), ``n = 6 ... 768`` shells, with ``R = (4 P(n) - P(n/2))/3``
  and, for the third-order term the graded shells leave (their grading maps have a zero derivative at the ends),
  ``T = (8 R(n) - R(n/2))/7`` with the estimate ``|T(n) - T(n/2)|/(min(rho_T, 16) - 1)`` (``rho_T`` the observed
  ratio of successive ``T`` differences);
* **a fourth-order commutator-free Magnus rule** (Blanes and Moan, Appl. Numer. Math. 56, 1519 (2006),
  doi:10.1016/j.apnum.2005.11.004; the form of Thalhammer, SIAM J. Numer. Anal. 44, 851 (2006),
  doi:10.1137/05063042): per shell of duration ``h``, two stages of ``h/2``, the first with the operator
  ``2 a1 L(tau_1) + 2 a2 L(tau_2)``, the second with ``2 a2 L(tau_1) + 2 a1 L(tau_2)``, ``a1,2 = 1/4 +- sqrt(3)/6`` at
  the Gauss points ``tau_1,2`` of the shell (solved on the spectrum's cumulative).  Each stage keeps its own
  balance multiplier ``A`` (mean ``p0`` at its end), so ``n`` shells cost ``2n`` exponentials.

The reference is ``T`` of the midpoint ladder at 192/384/768 shells; its movement from 96/192/384 is printed.

    python benchmarks/shell_schemes.py [--quick]

Writes ``results/shell_schemes.md``.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diffusion_pr.closures as C  # noqa: E402
from bench_fokker_planck import SPECTRUM  # noqa: E402
from diffusion_pr.problem import Stage, StagedProblem  # noqa: E402
from diffusion_pr.solvers.fv import engine  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "shell_schemes.md"
E_STAR, P0 = 8.0 / 3.0, 0.004
MIDPOINT = (6, 12, 24, 48, 96, 192, 384, 768)
MAGNUS = (6, 12, 24, 48, 96, 192)
SCENES = [(z, c) for z in (0.001, 0.01, 0.1, 0.25) for c in ("local_g1_balanced", "local_g1_shell_balanced")]
QUICK = [(0.01, "local_g1_balanced"), (0.01, "local_g1_shell_balanced")]
S3 = math.sqrt(3.0)
A1, A2 = 0.25 + S3 / 6.0, 0.25 - S3 / 6.0
C1, C2 = 0.5 - S3 / 6.0, 0.5 + S3 / 6.0


class Blend:
    """``sum_i w_i m_i(p)``: a stage coefficient blended from the shell models at the Gauss points."""

    def __init__(self, models, weights, zero_power: float) -> None:
        self.models, self.weights, self.zero_power = tuple(models), tuple(weights), zero_power

    def breakpoints(self) -> tuple:
        return ()

    def __call__(self, p):
        return sum(w * m(p) for m, w in zip(self.models, self.weights))


def magnus_problem(n: int, zeta: float, closure: str, grading: str) -> StagedProblem:
    """The closure on ``n`` shells of the Fig. 1 spectrum by the fourth-order commutator-free Magnus rule."""
    ln_edges, cum, weight = C._shell_edges(SPECTRUM, E_STAR, n, grading)
    kz = 0.5 * zeta * E_STAR
    q_min = float(SPECTRUM.q_min)
    stages = []
    for k in range(n):
        lo, hi = float(cum[k]), float(cum[k + 1])
        if hi <= lo:
            continue
        qs = []
        for c in (C1, C2):
            target = lo + c * (hi - lo)
            x = brentq(lambda x: float(SPECTRUM.cumulative(weight, np.exp(np.array([x])))[0]) - target,
                       ln_edges[k], ln_edges[k + 1], xtol=1e-14, rtol=1e-15)
            qs.append(math.exp(x))
        half = 0.25 * (hi - lo)  # (dV0/2)/2
        for ws in ((2 * A1, 2 * A2), (2 * A2, 2 * A1)):
            f = Blend([C.LocalResponseDiffusivity(q, kz) for q in qs], ws, 2.0)
            qp = [q_min, q_min] if closure == "local_g1_balanced" else qs
            b = Blend([C.LoadExcessDrift(q, qq, kz) for q, qq in zip(qs, qp)], ws, 1.0)
            w = Blend([C.RigidApproachBalance(qq, kz) for qq in qp], ws, 1.0)
            stages.append(Stage(half, f, b, w))
    return StagedProblem(P0, tuple(stages), label=f"{closure} (Magnus 4)", balance_per_stage=True)


def l1(x: np.ndarray) -> float:
    return float(np.sum(np.abs(x)))


def third_order(t: dict, top: int) -> tuple:
    """``(T(top), estimate)`` from the ``T`` column (needs ``T(top/4)``)."""
    d0, d1 = l1(t[top] - t[top // 2]), l1(t[top // 2] - t[top // 4])
    rho = d1 / d0 if d0 > 0 else math.inf
    return t[top], d0 / max(min(rho, 16.0) - 1.0, 1.0)


def scene(zeta: float, closure: str) -> list:
    res = C.closure_distribution(SPECTRUM, E_star=E_STAR, mean_pressure=P0, zeta=zeta, closure=closure, rtol=1e-6)
    d = res.diagnostics
    grading = d["shell_grading"]
    spec = (SPECTRUM, E_STAR, P0, zeta, closure, None, grading)
    problems = [C._shell_problem(spec, m)[0] for m in MIDPOINT] + \
               [magnus_problem(m, zeta, closure, grading) for m in MAGNUS]
    t0 = time.perf_counter()
    with engine.grid_family(d["grid"]), engine.plain_masses("only"):
        out = engine.plain_batch(problems, rtol=1e-6, n_cells=int(d["levels"][0]))
    seconds = time.perf_counter() - t0
    masses = [np.asarray(r.diagnostics["plain_masses"][0]) for r in out]
    mid = dict(zip(MIDPOINT, masses[:len(MIDPOINT)]))
    mag = dict(zip(MAGNUS, masses[len(MIDPOINT):]))
    r = {m: (4 * mid[m] - mid[m // 2]) / 3 for m in MIDPOINT[1:]}
    t = {m: (8 * r[m] - r[m // 2]) / 7 for m in MIDPOINT[2:]}
    ref = t[768]
    rows = []
    for m in (24, 48, 96, 192):
        tm, est = third_order(t, m) if m // 4 in t else (None, None)
        rows.append(dict(zeta=zeta, closure=closure, grading=grading, shells=m, used=d["n_shells"][0],
                         cells=int(d["levels"][0]), mid=l1(mid[m] - ref), rich=l1(r[m] - ref),
                         third=None if tm is None else l1(tm - ref), third_est=est,
                         magnus_half=l1(mag[m // 2] - ref), magnus=l1(mag[m] - ref) if m in mag else None,
                         ref_move=l1(ref - t[384]), seconds=seconds))
    return rows


def fmt(x) -> str:
    return "" if x is None else f"{x:.2e}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the two balanced closures at zeta = 0.01 only")
    args = ap.parse_args(argv)
    lines = ["# Shell schemes on the answer's N grid (`python benchmarks/shell_schemes.py`)", "",
             "Fig. 1 scene (H 0.3, rms slope 0.031, q 2pi/1024..2pi/32, E* 8/3, p0 0.004), rtol 1e-6 answer's "
             "coarsest grid. L1 errors (zero weight + cell masses) against T(192, 384, 768) of the midpoint rule. "
             "`n`: shells of the midpoint rule (n exponentials); Magnus n/2: n/2 shells of the fourth-order "
             "commutator-free Magnus rule (n exponentials, the same work); `T` the third-order extrapolation "
             "(8R(n) - R(n/2))/7 with its estimate.", "",
             "| closure | zeta | grading | shells used today | N | n | midpoint P(n) | R(n/2, n) | T(n/4 .. n) | "
             "T estimate | Magnus n/2 (n exps) | Magnus n (2n exps) | reference moves |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for zeta, closure in (QUICK if args.quick else SCENES):
        for row in scene(zeta, closure):
            line = (f"| `{row['closure']}` | {row['zeta']:g} | {row['grading']} | {row['used']} | {row['cells']} | "
                    f"{row['shells']} | {fmt(row['mid'])} | {fmt(row['rich'])} | {fmt(row['third'])} | "
                    f"{fmt(row['third_est'])} | {fmt(row['magnus_half'])} | {fmt(row['magnus'])} | "
                    f"{fmt(row['ref_move'])} |")
            lines.append(line)
            print(line, flush=True)
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
