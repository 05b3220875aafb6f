"""The paper's problem (``closure="second_order"``) on random scenes: is the error estimate honest?

The work-precision benchmark (``bench_fokker_planck.py``) measures estimate against true error on a
dozen chosen problems.  This script draws ``N`` problems at random from a box and solves each with
the native backend at rtol 1e-6 (the package's default), then measures its L1 error (the non-contact
weight plus the masses of the answer's cells) against an oracle:

* ``mirror``: ``f = 1`` (the sharp cutoff), against Persson's mirror Gaussian (closed form, exact to
  about 1e-13);
* ``feller``: ``f = p/p_1``, against Feller's solution (closed form);
* ``cutoff``: ``f = c(p) t(p)`` with one of the smooth or literal cutoffs (``muser``, ``raised_cosine``,
  ``smoothstep``) and one of the tails (Gaussian, ``linear``, ``max_linear``), against the same solver
  at rtol 1e-8 (a converged finer run: its own estimate is printed and is 100x below rtol);
* ``cir``: ``f = p/p_1`` with the affine drift ``alpha - beta p`` (the absorbed Cox-Ingersoll-Ross process: exit and
  entrance walls, restoring, growing and towards-the-wall drifts), against its closed form
  (:func:`~diffusion_pr.closed_forms.cir_density`, :func:`~diffusion_pr.closed_forms.cir_zero_weight`; cell masses
  by 24-point Gauss-Legendre quadrature);
* ``drift``: :func:`~diffusion_pr.api.pressure_distribution` on a random self-affine spectrum and wall
  with a restoring drift ``A = -c D(eta) (p - p0)/(2 sqrt(V))`` (the magnification path), against the
  same at rtol 1e-8.

Where the rtol-1e-8 oracle fails (a restoring drift on the Muser cutoff at tiny ``p_c``: its refinement
diverges, docs/backends.md) the oracle is the same at :data:`FALLBACK_ORACLE_RTOL` = 1e-7; the table
names the oracle and prints its own estimate.

The box (dimensionless, ``V = 1`` where no spectrum is drawn; the problem is scale-free in
``p/sqrt(V)``): ``p0/sqrt(V)`` 1e-3 ... 30, ``p_c/sqrt(V)`` 1e-3 ... 1, ``p_t/sqrt(V)`` 0.1 ... 10,
``p0 p_1/tau`` 0.03 ... 30 (Feller: non-contact weight ``exp(-p0 p_1/tau)``), for ``cir`` the Bessel dimension
``2 alpha p_1`` uniform in [-1, 4] (exit below 2) and ``beta tau`` uniform in [-2, 3], drift strength ``c`` 0.1 ... 2, spectra,
walls and loads as ``stress_balance.random_spectrum_scene``, all log-uniform but ``H``.  A scene is flagged where the true error is
above rtol or above 3x the estimate (issue 10 asks for the estimate within 10x of the truth and rtol
met).  Writes ``results/fp_truth_random_<seed>[_<kinds>].md``.

    python benchmarks/fp_random_truth.py [--n 200] [--seed 1] [--rtol 1e-6] [--kinds mirror,feller,cutoff]

About 1-3 minutes for 200 scenes on the 2-core development machine (the oracles dominate).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import diffusion_pr as dp
from diffusion_pr import closed_forms
from stress_balance import _l1_to, _report, random_spectrum_scene

#: the default draw (seeds drawn before the cir kind existed keep their problems)
KINDS = ("mirror", "feller", "cutoff", "drift")
#: every kind ``--kinds`` accepts
ALL_KINDS = KINDS + ("cir",)
#: the kinds whose oracle is a closed form (no rtol-1e-8 solve)
CLOSED_KINDS = ("mirror", "feller", "cir")
CUTOFFS = ("muser", "raised_cosine", "smoothstep")
TAILS = (None, "linear", "max_linear")
ORACLE_RTOL = 1e-8
#: the oracle's rtol where ORACLE_RTOL fails (a restoring drift on the Muser cutoff at tiny p_c diverges at 1e-8:
#: docs/backends.md); still 10x below the answers' default rtol, and the table says which oracle answered
FALLBACK_ORACLE_RTOL = 1e-7


class CirOracle:
    """The absorbed CIR process's closed form as an oracle with the result's ``cdf`` and ``zero_weight``."""

    def __init__(self, p0: float, V: float, p_1: float, alpha: float, beta: float) -> None:
        from scipy.special import roots_legendre

        self.args = (p0, V / 2, 1.0 / p_1, alpha, beta)
        self.zero_weight = closed_forms.cir_zero_weight(*self.args)
        self.success, self.error_estimate, self.edges = True, 0.0, None
        self._nodes = roots_legendre(24)

    def cdf(self, x) -> np.ndarray:
        """``P(p <= x)`` with the atom at 0: 24-point Gauss-Legendre on each interval between the sorted points."""
        x = np.asarray(x, dtype=float)
        order = np.argsort(x)
        xs = np.maximum(x[order], 0.0)
        lo, hi = np.concatenate(([0.0], xs[:-1]))[:, None], xs[:, None]
        t, w = self._nodes
        dens = closed_forms.cir_density(0.5 * (lo + hi) + 0.5 * (hi - lo) * t, *self.args)
        out = np.empty_like(x)
        out[order] = self.zero_weight + np.cumsum(0.5 * (hi - lo)[:, 0] * (dens @ w))
        return np.where(x < 0.0, 0.0, out)


def random_problems(n: int, seed: int, kinds=KINDS):
    """``n`` problems ``(kind, label, solve)`` drawn with ``seed`` among ``kinds``; ``solve(rtol, backend)``
    returns the result (``backend="closed_form"`` for the closed-form kinds' oracle)."""
    rng = np.random.default_rng(seed)
    log_uniform = lambda lo, hi: float(10.0 ** rng.uniform(np.log10(lo), np.log10(hi)))  # noqa: E731
    for _ in range(n):
        kind = str(rng.choice(kinds))
        p0 = log_uniform(1e-3, 30.0)
        if kind == "mirror":
            yield kind, f"p0/sqrtV {p0:.3g}", (lambda rtol, backend, p0=p0: dp.propagate(p0, 1.0, rtol=rtol,
                                                                                      backend=backend))
        elif kind == "feller":
            p_1 = log_uniform(0.03, 30.0) * 0.5 / p0  # p0 p_1 / tau, tau = V/2 = 0.5: zero weight exp(-that)
            f = dp.ProportionalDiffusivity(p_1)
            yield kind, f"p0 {p0:.3g}, p_1 {p_1:.3g}", (
                lambda rtol, backend, p0=p0, f=f: dp.propagate(p0, 1.0, diffusivity=f, rtol=rtol, backend=backend))
        elif kind == "cir":
            p_1 = log_uniform(0.03, 30.0) * 0.5 / p0  # p0 p_1 / tau as Feller's
            dim, beta_tau = float(rng.uniform(-1.0, 4.0)), float(rng.uniform(-2.0, 3.0))
            alpha, beta = dim / (2 * p_1), beta_tau / 0.5
            f = dp.ProportionalDiffusivity(p_1)
            yield kind, f"p0 {p0:.3g}, p_1 {p_1:.3g}, 2 alpha p_1 {dim:.3g}, beta tau {beta_tau:.3g}", (
                lambda rtol, backend, p0=p0, p_1=p_1, f=f, alpha=alpha, beta=beta:
                CirOracle(p0, 1.0, p_1, alpha, beta) if backend == "closed_form" else
                dp.propagate(p0, 1.0, diffusivity=f, drift=lambda p, tau: alpha - beta * p, rtol=rtol,
                             backend=backend))
        elif kind == "cutoff":
            cutoff, tail = str(rng.choice(CUTOFFS)), TAILS[int(rng.integers(len(TAILS)))]
            p_c, p_t = log_uniform(1e-3, 1.0), log_uniform(0.1, 10.0)
            f = dp.PressureFactor(dp.make_cutoff(cutoff, p_c), dp.make_tail(tail, p_t))
            label = f"p0 {p0:.3g}, {cutoff} p_c {p_c:.3g}" + (f", {tail} p_t {p_t:.3g}" if tail else "")
            yield kind, label, (
                lambda rtol, backend, p0=p0, f=f: dp.propagate(p0, 1.0, diffusivity=f, rtol=rtol, backend=backend))
        else:
            name, spec, zeta, load = random_spectrum_scene(rng)
            strength, cutoff, pc_ratio = log_uniform(0.1, 2.0), str(rng.choice(("muser", "smoothstep"))), \
                log_uniform(1e-3, 1.0)
            V = float(dp.stress_variance(spec, E_star=8 / 3, mean_pressure=load, zeta=zeta))

            def drift(p, eta, spec=spec, load=load, zeta=zeta, strength=strength, V=V):
                D = dp.diffusivity_vs_magnification(spec, eta, E_star=8 / 3, mean_pressure=load, zeta=zeta)
                return -strength * D * (p - load) / (2.0 * np.sqrt(V))

            label = (f"{name}, zeta {zeta:.3g}, p0/sqrtV {load / np.sqrt(V):.3g}, {cutoff} p_c/sqrtV {pc_ratio:.3g}, "
                     f"c {strength:.2f}")
            yield kind, label, (lambda rtol, backend, spec=spec, load=load, zeta=zeta, cutoff=cutoff,
                                p_c=pc_ratio * np.sqrt(V), drift=drift: dp.pressure_distribution(
                                    spec, E_star=8 / 3, mean_pressure=load, zeta=zeta, cutoff=cutoff, p_c=p_c,
                                    drift=drift, rtol=rtol, backend=backend))


def truth_row(kind: str, solve, rtol: float) -> tuple:
    """``(true L1, estimate, oracle estimate, cells, seconds, note, cdf sup)`` of one problem: the native answer at
    ``rtol`` against the closed form (mirror, Feller) or the native answer at :data:`ORACLE_RTOL`
    (:data:`FALLBACK_ORACLE_RTOL` where that fails)."""
    try:
        t0 = time.perf_counter()
        r = solve(rtol, "native")
        seconds = time.perf_counter() - t0
    except (RuntimeError, ValueError, FloatingPointError) as exc:
        return float("inf"), float("nan"), float("nan"), 0, 0.0, f"no answer: {exc}"[:80], float("nan")
    if not r.success:
        return float("inf"), float("nan"), float("nan"), 0, seconds, f"no answer: {r.message}"[:80], float("nan")
    closed = kind in CLOSED_KINDS
    oracle = None
    for oracle_rtol in (ORACLE_RTOL,) if closed else (ORACLE_RTOL, FALLBACK_ORACLE_RTOL):
        try:
            oracle = solve(oracle_rtol, "closed_form" if closed else "native")
        except (RuntimeError, ValueError, FloatingPointError):
            oracle = None
        if oracle is not None and oracle.success:
            break
    if oracle is None or not oracle.success:
        return (float("inf"), r.error_estimate, float("nan"), int(r.diagnostics["n_cells"]), seconds, "no oracle",
                float("nan"))
    # the users' quantity besides the masses: the answer's cdf between its edges (a spline in the grid's coordinate,
    # docs/backends.md), its largest distance from the oracle's exact cumulative at the oracle's edges (a
    # finite-volume oracle) or from the closed form at 5 points inside every answer cell
    if closed:
        x = np.concatenate([np.linspace(a, b, 7)[1:-1] for a, b in zip(r.edges[:-1], r.edges[1:])])
    else:
        x = oracle.edges
    cdf_sup = float(np.max(np.abs(r.cdf(x) - oracle.cdf(x))))
    note = ("closed form" if closed else f"rtol {oracle_rtol:g}") + f"; cdf between the edges {cdf_sup:.2e}"
    return (_l1_to(r, oracle), r.error_estimate, 0.0 if closed else oracle.error_estimate,
            int(r.diagnostics["n_cells"]), seconds, note, cdf_sup)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="how many random problems (default: 200)")
    ap.add_argument("--seed", type=int, default=1, help="the seed of the draw (default: 1)")
    ap.add_argument("--rtol", type=float, default=1e-6, help="the answers' rtol (default: 1e-6)")
    ap.add_argument("--kinds", default=",".join(KINDS),
                    help=f"comma-separated among {','.join(ALL_KINDS)} (default: {','.join(KINDS)})")
    args = ap.parse_args(argv)
    kinds = tuple(args.kinds.split(","))
    if not set(kinds) <= set(ALL_KINDS):
        raise SystemExit(f"--kinds must be among {ALL_KINDS}; got {args.kinds!r}")
    dp.propagate(1.0, 1.0, diffusivity=dp.ProportionalDiffusivity(1.0), backend="native")  # warm
    rows = []
    for i, (kind, label, solve) in enumerate(random_problems(args.n, args.seed, kinds)):
        true, est, oracle_est, cells, seconds, note, cdf_sup = truth_row(kind, solve, args.rtol)
        flagged = np.isfinite(true) and (true > args.rtol or true > 3 * est)
        print(f"{i} {kind} {label} | true {true:.2e} estimate {est:.2e} cells {cells} {1e3 * seconds:.1f} ms "
              f"{note}" + ("  <<<" if flagged else ""), flush=True)
        rows.append((true, est, oracle_est, cells, seconds, note, kind, label, cdf_sup))
    solved = [r for r in rows if np.isfinite(r[0])]
    ratios = [r[0] / r[1] for r in solved if r[1] > 0]
    by_kind = ", ".join(f"{k} {sum(r[6] == k for r in rows)}" for k in kinds)
    solved.sort(key=lambda r: r[0] / r[1] if r[1] > 0 else float("inf"), reverse=True)
    _report(f"# The paper's problem on random scenes: estimate against the true error ({len(rows)} problems, "
            f"seed {args.seed}, rtol {args.rtol:g})",
            f"{by_kind}; {len(rows) - len(solved)} not solved by both answer and oracle; true error above rtol on "
            f"{sum(r[0] > args.rtol for r in solved)}, above the estimate on {sum(r[0] > r[1] for r in solved)}, "
            f"above 3x it on {sum(r[0] > 3 * r[1] for r in solved)}, above 10x on "
            f"{sum(r[0] > 10 * r[1] for r in solved)}; true/estimate median {np.median(ratios):.2f}, smallest "
            f"{min(ratios):.2g}, largest {max(ratios):.2f}; median wall time of the rtol-{args.rtol:g} solves "
            f"{1e3 * np.median([r[4] for r in solved]):.1f} ms (summed {sum(r[4] for r in rows):.1f} s); the cdf "
            f"between the answers' edges above rtol on {sum(r[8] > args.rtol for r in solved)}, largest "
            f"{max(r[8] for r in solved):.2e}",
            ["true L1", "estimate", "true/estimate", "oracle", "oracle estimate", "cells", "ms", "kind", "problem"],
            [[f"{r[0]:.2e}", f"{r[1]:.2e}", f"{r[0] / r[1]:.2f}", r[5], f"{r[2]:.1e}", str(r[3]),
              f"{1e3 * r[4]:.1f}", r[6], r[7]] for r in solved[:30]],
            f"fp_truth_random_{args.seed}" + ("" if kinds == KINDS else "_" + "_".join(kinds)) + ".md")
    for r in rows:
        if not np.isfinite(r[0]):
            print("not solved:", r[6], r[7], r[5])


if __name__ == "__main__":
    main()
