"""Is the error estimate honest?  Answers at rtol 1e-6 against exact or converged truths on random problems.

Two draws (a fixed seed, so a run repeats its problems):

* ``second order``: ``propagate``/``pressure_distribution`` on random problems of four kinds: ``mirror``
  (``f = 1``) and ``feller`` (``f = p/p_1``) against their closed forms (``backend="closed_form"``), ``cutoff``
  (a smooth or literal cutoff times a tail) and ``drift`` (a random self-affine spectrum and wall with a
  restoring drift) against the same solve at rtol 1e-8 (1e-7 where that fails);
* ``closures``: a random self-affine spectrum, wall, load and shell closure, against the same at rtol 1e-8.

The box (dimensionless where ``V = 1``): ``p0/sqrt(V)`` 1e-3 ... 30, ``p_c/sqrt(V)`` 1e-3 ... 1, ``p_t/sqrt(V)``
0.1 ... 10, ``p0 p_1/tau`` 0.03 ... 30; spectra ``H`` 0.2-0.9, rms slope 0.01-0.3, sizes 256-8192 and cutoffs
4-64 lattice units, ``zeta`` 1e-4 ... 10, ``p0`` 1e-5 ... 0.3 (``E* = 8/3``).  The true error is the L1 distance of
the answer's cell masses plus its non-contact weight.  The table counts the problems whose true error is above
rtol, above the estimate, above 3x and 10x the estimate, and lists the worst ratios.

    python benchmarks/estimate_honesty.py [--quick]
"""
from __future__ import annotations

import time

import numpy as np

from common import CLOSURES, E_STAR, cli, fmt, l1_to_answer, section, table

RTOL = 1e-6
CUTOFFS = ("muser", "raised_cosine", "smoothstep")
TAILS = (None, "linear", "max_linear")


def _log_uniform(rng, lo: float, hi: float) -> float:
    return float(10.0 ** rng.uniform(np.log10(lo), np.log10(hi)))


def random_spectrum_scene(rng) -> tuple:
    """``(label, spectrum, zeta, p0)``: ``H`` uniform, the rms slope, ``zeta`` and ``p0`` log-uniform, the size and
    the cutoff wavelength powers of 2 at least 8 apart."""
    import diffusion_pr as dp

    hurst, slope = float(rng.uniform(0.2, 0.9)), _log_uniform(rng, 0.01, 0.3)
    size = 2 ** int(rng.integers(8, 14))
    cutoff = min(2 ** int(rng.integers(2, 7)), size // 8)
    zeta, p0 = _log_uniform(rng, 1e-4, 10.0), _log_uniform(rng, 1e-5, 0.3)
    label = f"H {hurst:.2f}, slope {slope:.3f}, q 2pi/{size}..2pi/{cutoff}, zeta {zeta:.3g}, p0 {p0:.3g}"
    return label, dp.SelfAffineSpectrum(hurst, 2 * np.pi / size, 2 * np.pi / cutoff, rms_slope=slope), zeta, p0


def second_order_problems(n: int, seed: int):
    """``n`` problems ``(kind, label, solve(rtol, backend))``."""
    import diffusion_pr as dp

    rng = np.random.default_rng(seed)
    for _ in range(n):
        kind = str(rng.choice(("mirror", "feller", "cutoff", "drift")))
        p0 = _log_uniform(rng, 1e-3, 30.0)
        if kind == "mirror":
            f, label = None, f"p0/sqrtV {p0:.3g}"
        elif kind == "feller":
            p_1 = _log_uniform(rng, 0.03, 30.0) * 0.5 / p0  # p0 p_1 / tau with tau = V/2 = 0.5
            f, label = dp.ProportionalDiffusivity(p_1), f"p0 {p0:.3g}, p_1 {p_1:.3g}"
        elif kind == "cutoff":
            cutoff, tail = str(rng.choice(CUTOFFS)), TAILS[int(rng.integers(len(TAILS)))]
            p_c, p_t = _log_uniform(rng, 1e-3, 1.0), _log_uniform(rng, 0.1, 10.0)
            p_t = p_t if tail in ("linear", "max_linear") else None  # the Gaussian tail takes no p_t
            f = dp.PressureFactor(dp.make_cutoff(cutoff, p_c), dp.make_tail(tail, p_t))
            label = f"p0 {p0:.3g}, {cutoff} p_c {p_c:.3g}" + (f", {tail}" if tail else "") + (
                f" p_t {p_t:.3g}" if p_t else "")
        if kind != "drift":
            yield kind, label, (lambda rtol, backend, p0=p0, f=f:
                                dp.propagate(p0, 1.0, diffusivity=f, rtol=rtol, backend=backend))
            continue
        label, spec, zeta, load = random_spectrum_scene(rng)
        strength, cutoff = _log_uniform(rng, 0.1, 2.0), str(rng.choice(("muser", "smoothstep")))
        pc_ratio = _log_uniform(rng, 1e-3, 1.0)
        V = float(dp.stress_variance(spec, E_star=E_STAR, mean_pressure=load, zeta=zeta))

        def drift(p, eta, spec=spec, load=load, zeta=zeta, strength=strength, V=V):
            D = dp.diffusivity_vs_magnification(spec, eta, E_star=E_STAR, mean_pressure=load, zeta=zeta)
            return -strength * D * (p - load) / (2.0 * np.sqrt(V))

        yield kind, f"{label}, {cutoff} p_c/sqrtV {pc_ratio:.3g}, c {strength:.2f}", (
            lambda rtol, backend, spec=spec, load=load, zeta=zeta, cutoff=cutoff, p_c=pc_ratio * np.sqrt(V),
            drift=drift: dp.pressure_distribution(spec, E_star=E_STAR, mean_pressure=load, zeta=zeta, cutoff=cutoff,
                                                  p_c=p_c, drift=drift, rtol=rtol, backend=backend))


def closure_problems(n: int, seed: int):
    """``n`` random closure scenes ``(closure, label, solve(rtol, backend))``."""
    import diffusion_pr as dp

    rng = np.random.default_rng(seed)
    for _ in range(n):
        label, spec, zeta, p0 = random_spectrum_scene(rng)
        closure = str(rng.choice(CLOSURES))
        yield closure, label, (lambda rtol, backend, spec=spec, zeta=zeta, p0=p0, closure=closure:
                               dp.pressure_distribution(spec, E_star=E_STAR, mean_pressure=p0, zeta=zeta,
                                                        closure=closure, rtol=rtol, backend=backend))


def truth(kind: str, solve) -> dict:
    """The answer at :data:`RTOL` against its oracle: ``true`` (inf where either fails), ``estimate``, ``ms``."""
    out = dict(true=float("inf"), estimate=float("nan"), ms=float("nan"), note="")
    try:
        t0 = time.perf_counter()
        r = solve(RTOL, "native")
        out["ms"] = 1e3 * (time.perf_counter() - t0)
    except (RuntimeError, ValueError, FloatingPointError) as exc:
        out["note"] = f"no answer: {exc}"[:80]
        return out
    out["estimate"] = r.error_estimate
    if not r.success:
        out["note"] = f"no answer: {r.message}"[:80]
        return out
    tries = (("closed_form", 1e-8),) if kind in ("mirror", "feller") else (("native", 1e-8), ("native", 1e-7))
    for backend, rtol in tries:
        try:
            oracle = solve(rtol, backend)
        except (RuntimeError, ValueError, FloatingPointError):
            continue
        if oracle.success:
            out["true"], out["note"] = l1_to_answer(r, oracle), f"{backend} {rtol:g}"
            return out
    out["note"] = "no oracle"
    return out


def summary(name: str, rows: list) -> tuple:
    """One line of the summary table."""
    solved = [r for r in rows if np.isfinite(r["true"])]
    ratios = [r["true"] / r["estimate"] for r in solved if r["estimate"] > 0]
    return (name, len(rows), len(solved), sum(r["true"] > RTOL for r in solved),
            sum(r["true"] > r["estimate"] for r in solved), sum(r["true"] > 3 * r["estimate"] for r in solved),
            sum(r["true"] > 10 * r["estimate"] for r in solved), fmt(np.median(ratios) if ratios else None, ".2f"),
            fmt(max(ratios) if ratios else None, ".2f"), fmt(np.median([r["ms"] for r in solved]) if solved else None,
                                                             ".1f"))


def run(quick: bool = False) -> str:
    n_second, n_closure, seed = (12, 8, 1) if quick else (100, 60, 1)
    draws = {"second order": second_order_problems(n_second, seed), "closures": closure_problems(n_closure, seed)}
    results = {}
    for name, problems in draws.items():
        rows = []
        for kind, label, solve in problems:
            rows.append(dict(kind=kind, label=label, **truth(kind, solve)))
            print(f"{name}: {kind} {label}: true {rows[-1]['true']:.2e}, estimate {rows[-1]['estimate']:.2e} "
                  f"({rows[-1]['note']})", flush=True)
        results[name] = rows
    body = table(["draw", "problems", "solved", "true > rtol", "true > estimate", "> 3x estimate", "> 10x estimate",
                  "median true / estimate", "largest true / estimate", "median time [ms]"],
                 [summary(name, rows) for name, rows in results.items()])
    worst = sorted((r for rows in results.values() for r in rows if np.isfinite(r["true"]) and r["estimate"] > 0),
                   key=lambda r: r["true"] / r["estimate"], reverse=True)[:5]
    worst_table = table(["kind", "problem", "true L1", "estimate", "true / estimate", "oracle"],
                        [(r["kind"], r["label"], fmt(r["true"], ".2e"), fmt(r["estimate"], ".2e"),
                          fmt(r["true"] / r["estimate"], ".2f"), r["note"]) for r in worst])
    failed = [f"{r['kind']} ({r['label']}): {r['note']}" for rows in results.values() for r in rows
              if not np.isfinite(r["true"])]
    return section("Error estimates against the truth (random problems, rtol 1e-6)", body,
                   f"Seed {seed}. The worst ratios:", worst_table,
                   ("Not solved: " + "; ".join(failed)) if failed else "")


if __name__ == "__main__":
    cli(run, __doc__)
