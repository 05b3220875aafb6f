"""Speed against error of every closure on the Fig. 1 scene, per backend.

For each closure and wall (zeta = 0.01, 0.25, 4; continuum Fig. 1 spectrum with the
default 96 shells, and one seed's DiscreteSpectrum), the warm wall time (median
of repeats, after one warm-up call that also compiles numba kernels) and the
error: sup |F - F_ref| over p >= p0/20 against a fine run of the reference
solver (3200 cells and steps; its own error is about 3e-5 there).

Backends: ``reference`` (the independent solver of
``diffusion_pr._closure_reference`` at several resolutions) and, when the engine
solves :class:`~diffusion_pr.problem.StagedProblem`, ``native``/``pypde``/``fipy``
at rtol 1e-6.  The machine is shared (2 cores, other jobs running): read ratios
measured in the same run, not absolute times.

    python benchmarks/bench_closures.py [--repeats 5] [--backends reference,native,pypde,fipy]

(FiPy assembles its matrix per shell and grid: about 50 s per closure solve; py-pde about 0.6 s.)
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import diffusion_pr as dp

E, P0 = 8.0 / 3.0, 0.004


def _closure(spectrum, *, backend="auto", **kw):
    """:func:`diffusion_pr.closures.closure_distribution`, or the closures' reference solver (the tests' oracle,
    ``tests/oracles/closure_reference.py``) for ``backend="reference"``."""
    if backend == "reference":
        sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
        from oracles.closure_reference import reference_distribution

        return reference_distribution(spectrum, **kw)
    from diffusion_pr.closures import closure_distribution

    return closure_distribution(spectrum, backend=backend, **kw)


#: the shell-by-shell closures (the engine solves them as StagedProblems)
CLOSURES = ("local_g1", "local_g1_balanced", "local_g1_shell_balanced")


def sup_cdf(a, b) -> float:
    x = np.linspace(P0 / 20, 0.3, 8000)
    return float(np.max(np.abs(np.asarray(a.cdf(x)) - np.asarray(b.cdf(x)))))


def timed(fn, repeats):
    fn()  # warm-up (numba compile / caches)
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--backends", default="reference,native")
    ap.add_argument("--zetas", default="0.01,0.25,4")
    args = ap.parse_args()
    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    zetas = [float(z) for z in args.zetas.split(",")]
    backends = args.backends.split(",")
    print("| closure | zeta | backend | resolution | warm time (ms, median) | sup CDF error (p >= p0/20) | success |")
    print("|---|---|---|---|---|---|---|")
    for zeta in zetas:
        refs = {}
        for cl in CLOSURES:
            refs[cl] = _closure(spec, E_star=E, mean_pressure=P0, zeta=zeta, closure=cl,
                                            backend="reference", n_cells=3200, n_steps=3200)
        # closed forms / second order
        t, r = timed(lambda: _closure(spec, E_star=E, mean_pressure=P0, zeta=zeta,
                                                  closure="lognormal_gap"), args.repeats)
        print(f"| lognormal_gap | {zeta:g} | closed_form | 4000 cells in ln p | {1e3 * t:.2f} | exact | {r.success} |")
        t, r = timed(lambda: _closure(spec, E_star=E, mean_pressure=P0, zeta=zeta, closure="second_order",
                                                  cutoff="smoothstep", p_c=0.0027, rtol=1e-6), args.repeats)
        print(f"| second_order (smoothstep, p_c 0.0027) | {zeta:g} | {r.backend} | rtol 1e-6 | {1e3 * t:.2f} | "
              f"est. {r.error_estimate:.1e} | {r.success} |")
        for cl in CLOSURES:
            for be in backends:
                if be == "reference":
                    for n in (400, 800, 1600):
                        t, r = timed(lambda: _closure(spec, E_star=E, mean_pressure=P0, zeta=zeta,
                                                                  closure=cl, backend="reference", n_cells=n,
                                                                  n_steps=n), args.repeats)
                        # the reference solver runs twice (n/2 and n) for its error estimate
                        print(f"| {cl} | {zeta:g} | reference | {n} cells x {n} steps (+ half) | {1e3 * t:.1f} | "
                              f"{sup_cdf(r, refs[cl]):.1e} | {r.success} |")
                else:
                    try:
                        # the reference solves the 96-shell problem: the engine the same one
                        t, r = timed(lambda: _closure(spec, E_star=E, mean_pressure=P0, zeta=zeta,
                                                                  closure=cl, backend=be, rtol=1e-6,
                                                                  shell_extrapolation=False), args.repeats)
                    except Exception as exc:  # noqa: BLE001 - report, do not hide
                        print(f"| {cl} | {zeta:g} | {be} | rtol 1e-6 | - | {type(exc).__name__}: {exc} | False |")
                        continue
                    print(f"| {cl} | {zeta:g} | {be} | rtol 1e-6 | {1e3 * t:.1f} | {sup_cdf(r, refs[cl]):.1e} | "
                          f"{r.success} |")


if __name__ == "__main__":
    main()
