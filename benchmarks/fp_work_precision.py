"""Fokker-Planck work-precision: native against the py-pde and FiPy backends on problems with exact solutions.

Problems (``p0``, ``V``; the wall at ``p = 0`` absorbs):

* ``mirror``: ``f = 1``, ``p0 = V = 1``: Persson's mirror Gaussian;
* ``feller``: ``f = p``, ``p0 = V = 1``: Feller's Bessel solution;
* ``gaussian``: ``f = 1``, ``p0 = 8``, ``V = 1``: the wall eight standard deviations away, a Gaussian.

For each backend and rtol: the warm wall time (median of repeats after one discarded call), the achieved L1
error (cell masses against the closed form plus the non-contact weight's error), the error estimate, and the
time over the native backend's at the same rtol.  A backend that is not installed is skipped with a note.
The plot goes to ``results/fp_work_precision.png``.

    python benchmarks/fp_work_precision.py [--quick]
"""
from __future__ import annotations

import numpy as np

from common import RESULTS, cli, fmt, interleaved, l1_to_density, section, table

BACKENDS = ("native", "pypde", "fipy")


def problems() -> dict:
    """``name -> (p0, V, diffusivity or None, exact density, exact zero weight)``."""
    import diffusion_pr as dp

    return {
        "mirror": (1.0, 1.0, None, lambda p: dp.mirror_gaussian_density(p, 1.0, 1.0),
                   dp.persson_zero_weight(1.0, 1.0)),
        "feller": (1.0, 1.0, dp.ProportionalDiffusivity(1.0), lambda p: dp.feller_density(p, 1.0, 0.5, 1.0),
                   dp.feller_zero_weight(1.0, 0.5, 1.0)),
        "gaussian": (8.0, 1.0, None, lambda p: dp.gaussian_density(p, 8.0, 1.0), 0.0),
    }


def measure(quick: bool) -> list:
    """One row per (problem, backend, rtol)."""
    import diffusion_pr as dp

    rtols = (1e-3, 1e-5, 1e-7) if quick else (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
    repeats = 3 if quick else 7
    backends = [b for b in BACKENDS if dp.is_available(b)]
    rows = []
    for name, (p0, V, f, density, zero) in problems().items():
        for rtol in rtols:
            def call(backend, p0=p0, V=V, f=f, rtol=rtol):
                return lambda: dp.propagate(p0, V, diffusivity=f, backend=backend, rtol=rtol)

            # FiPy takes about a second a call: one rtol in the quick run
            calls = {b: call(b) for b in backends if not (quick and b == "fipy" and rtol != 1e-5)}
            t = interleaved(calls, repeats)
            for b in calls:
                r = calls[b]()
                err = l1_to_density(r, density, zero)
                rows.append(dict(problem=name, backend=b, rtol=rtol, time=t[b], error=err,
                                 estimate=r.error_estimate, success=bool(r.success), ratio=t[b] / t["native"]))
    return rows


def plot(rows: list) -> None:
    """Error against time per problem and backend, to ``results/fp_work_precision.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["problem"] for r in rows))
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.8), squeeze=False)
    for ax, name in zip(axes[0], names):
        for b in BACKENDS:
            pts = sorted((r["error"], r["time"]) for r in rows if r["problem"] == name and r["backend"] == b)
            if pts:
                e, t = zip(*pts)
                ax.loglog(e, 1e3 * np.array(t), "o-", label=b)
        ax.set_title(name)
        ax.set_xlabel("achieved L1 error")
        ax.set_ylabel("warm time [ms]")
        ax.legend(fontsize=8)
    fig.tight_layout()
    RESULTS.mkdir(exist_ok=True)
    fig.savefig(RESULTS / "fp_work_precision.png", dpi=110)
    plt.close(fig)


def run(quick: bool = False) -> str:
    import diffusion_pr as dp

    rows = measure(quick)
    try:
        plot(rows)
    except ImportError:
        pass
    missing = [b for b in BACKENDS if not dp.is_available(b)]
    body = table(["problem", "backend", "rtol", "time [ms]", "L1 error", "estimate", "estimate / error",
                  "success", "time / native"],
                 [(r["problem"], r["backend"], f"{r['rtol']:.0e}", fmt(1e3 * r["time"], ".2f"), fmt(r["error"], ".1e"),
                   fmt(r["estimate"], ".1e"), fmt(r["estimate"] / r["error"] if r["error"] > 0 else None, ".2f"),
                   r["success"], fmt(r["ratio"], ".2f")) for r in rows])
    return section("Fokker-Planck work-precision (native, py-pde, FiPy)", body,
                   "Warm medians of interleaved calls; errors against the closed forms."
                   + (f" Not installed, skipped: {', '.join(missing)}." if missing else ""))


if __name__ == "__main__":
    cli(run, __doc__)
