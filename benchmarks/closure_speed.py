"""The shell closures on the Fig. 1 scenes: warm time and error estimate per closure and zeta, in the units of
the independent competitor.

Each closure (``local_g1``, ``local_g1_balanced``, ``local_g1_shell_balanced``) is solved by
``pressure_distribution`` on the Fig. 1 spectrum (``E* = 8/3``, ``p0 = 0.004``, rtol 1e-6) at zeta = 4 ... 0.001,
interleaved with the competitor of ``fp_competitor.py`` (its own estimate, rtol 1e-6) on the Fig. 1 second-order
scene at zeta = 0.25, in the same process.  Absolute times on a shared machine move by 2-3x from day to day; the
ratio closure / competitor moves much less.

    python benchmarks/closure_speed.py [--quick]
"""
from __future__ import annotations

from common import CLOSURE_ZETAS, CLOSURES, E_STAR, P0, cli, fig1_spectrum, fmt, interleaved, section, table


def competitor_call():
    """The competitor's solve of the Fig. 1 scene at zeta = 0.25 (rtol 1e-6, its own estimate)."""
    from fp_competitor import adaptive, cases

    p0, V, f, opts, _ = cases()["fig1 zeta 0.25"]
    return lambda: adaptive(1e-6, f, p0, V, **opts)


def run(quick: bool = False) -> str:
    import diffusion_pr as dp

    spectrum = fig1_spectrum()
    reference = competitor_call()
    repeats = 3 if quick else 9
    rows = []
    for closure in CLOSURES:
        for zeta in CLOSURE_ZETAS:
            def solve(zeta=zeta, closure=closure):
                return dp.pressure_distribution(spectrum, E_star=E_STAR, mean_pressure=P0, zeta=zeta,
                                                closure=closure, rtol=1e-6)

            t = interleaved({"closure": solve, "competitor": reference}, repeats)
            r = solve()
            rows.append((f"`{closure}`", f"{zeta:g}", fmt(1e3 * t["closure"], ".1f"), fmt(r.error_estimate, ".1e"),
                         r.success, fmt(1e3 * t["competitor"], ".2f"), fmt(t["closure"] / t["competitor"], ".1f")))
    body = table(["closure", "zeta", "time [ms]", "error estimate", "success", "competitor [ms]",
                  "closure / competitor"], rows)
    return section("Closures on the Fig. 1 scenes", body,
                   f"Warm medians of {repeats} interleaved call pairs (closure, then the competitor on the Fig. 1 "
                   "second-order scene at zeta = 0.25); rtol 1e-6.")


if __name__ == "__main__":
    cli(run, __doc__)
