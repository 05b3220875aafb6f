"""Measure the paper's Fig. 1 claims on the bundled 1024^2 GFMD data.

Prints markdown tables (theory against GFMD per zeta and seed, fitted cutoff
pressures per cutoff variant, the exponential-tail check) and writes the
figure ``docs/images/fig1_bundled.png``.  The numbers in ``docs/fig1.md`` come
from this script::

    python benchmarks/fig1_claims.py            # tables + figure
    python benchmarks/fig1_claims.py --fits     # also least-squares p_c per cutoff (slower)
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import diffusion_pr as dp
from diffusion_pr.comparison import (compare, fit_cutoff_pressure, fit_tail_pressure, kolmogorov_between,
                                     tail_curvatures)
from diffusion_pr.fig1 import paper_cutoff_pressure
from diffusion_pr.reference_data import FIG1_SCENE, case_name, load_reference, paper_theory

E_STAR, P0 = FIG1_SCENE["E_star"], FIG1_SCENE["mean_pressure"]
ZETAS = (None, 0.001, 0.01, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0)
ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--fits", action="store_true", help="least-squares p_c for every cutoff variant")
    parser.add_argument("--no-plot", action="store_true")
    args = parser.parse_args()

    print("## Theory (paper's cutoff and p_c) against GFMD, 1024^2, two seeds\n")
    print("| wall | p_c | seed | Kolmogorov | L1 | seed-to-seed Kolm. | sd_sim/sqrt(V_G1) | curvature ratio "
          "(theory/sim) | contact fraction sim / theory | theory ms |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    results = {}
    for zeta in ZETAS:
        cases = {s: load_reference(case_name(zeta, s)) for s in (1, 2)}
        scatter = kolmogorov_between(cases[1].histogram, cases[2].histogram)
        for seed, case in cases.items():
            t0 = time.perf_counter()
            th = paper_theory(case)
            dt = time.perf_counter() - t0
            cmp = compare(th, case.histogram)
            v = float(dp.stress_variance(case.spectrum, E_star=E_STAR, mean_pressure=P0, zeta=zeta or 0.0))
            c_sim, c_th, _ = tail_curvatures(th, case.histogram)
            results[zeta, seed] = (case, th)
            wall = "hard" if zeta is None else f"zeta={zeta:g}"
            p_c = "-" if zeta is None else f"{paper_cutoff_pressure(zeta):.4f}"
            a_sim = case.provenance["contact_fraction"] if zeta is not None else cmp.contact_fraction_sim
            print(f"| {wall} | {p_c} | {seed} | {cmp.kolmogorov:.4f} | {cmp.l1:.3f} | {scatter:.4f} | "
                  f"{np.sqrt(cmp.moments_sim['variance'] / v):.3f} | {c_th / c_sim:.3f} | "
                  f"{a_sim:.4f} / {cmp.contact_fraction_theory:.4f} | {1e3 * dt:.0f}"
                  f"{'' if th.success else ' (NOT converged)'} |")

    if args.fits:
        print("\n## Least-squares cutoff pressure per cutoff variant (seed 1, ln Pr objective)\n")
        print("| zeta | paper p_c | cutoff | fitted p_c | objective | Kolmogorov at fit | Kolmogorov at paper p_c |")
        print("|---|---|---|---|---|---|---|")
        for zeta in (0.001, 0.01, 0.25, 1.0, 4.0):
            case = results[zeta, 1][0]
            hist = case.histogram.rebinned(2)
            for cut in ("muser", "raised_cosine", "smoothstep"):
                fit = fit_cutoff_pressure(hist, case.spectrum, E_star=E_STAR, mean_pressure=P0, zeta=zeta,
                                          cutoff=cut, rtol=1e-4)
                ks_fit = compare(paper_theory(case, cutoff=cut, p_c=fit.p_c), case.histogram).kolmogorov
                ks_paper = compare(paper_theory(case, cutoff=cut), case.histogram).kolmogorov
                print(f"| {zeta:g} | {paper_cutoff_pressure(zeta):.4f} | {cut} | {fit.p_c:.5f} | "
                      f"{fit.objective:.3g} | {ks_fit:.4f} | {ks_paper:.4f} |")

    print("\n## Exponential-tail variant on a surface that is not coloured noise (hard wall, seed 1)\n")
    print("| surface | model | p_t | Kolmogorov | L1 | contact fraction theory (GFMD) |")
    print("|---|---|---|---|---|---|")
    for name in ("fig1-skewed_n1024_hard_s1", "fig1_n1024_hard_s1"):
        case = load_reference(name)
        hist = case.histogram.rebinned(4)
        gauss = compare(paper_theory(case), hist)
        print(f"| {name} | Gaussian (Persson) | - | {gauss.kolmogorov:.4f} | {gauss.l1:.3f} | "
              f"{gauss.contact_fraction_theory:.4f} ({gauss.contact_fraction_sim:.4f}) |")
        for tail in ("linear", "max_linear"):
            p_t, _ = fit_tail_pressure(hist, case.spectrum, E_star=E_STAR, mean_pressure=P0, tail=tail, rtol=1e-4)
            th = dp.pressure_distribution(case.spectrum, E_star=E_STAR, mean_pressure=P0, cutoff="sharp", tail=tail,
                                          p_t=p_t, rtol=1e-4)
            c = compare(th, hist)
            print(f"| {name} | {tail} tail | {p_t:.4g} | {c.kolmogorov:.4f} | {c.l1:.3f} | "
                  f"{c.contact_fraction_theory:.4f} ({c.contact_fraction_sim:.4f}) |")

    if not args.no_plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from diffusion_pr.plotting import plot_histogram

        fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for ax, zetas, xmax in ((axes[0], (0.001, 0.01, 0.1), 0.15), (axes[1], (0.25, 1.0, 4.0), 0.05)):
            for i, zeta in enumerate(zetas):
                case, th = results[zeta, 1]
                h = case.histogram.rebinned(2)
                plot_histogram(h.centers, h.density, ax=ax, color=colors[i], label=f"GFMD zeta={zeta:g}")
                q = np.linspace(0, xmax, 800)
                d = th.pdf(q)
                ax.plot(q, np.where(d > 0, d, np.nan), color=colors[i], lw=1.2)
            persson = results[None, 1][1]
            q = np.linspace(1e-6, xmax, 800)
            ax.plot(q, persson.pdf(q), "k--", lw=1, label="Persson")
            hard = results[None, 1][0].histogram.rebinned(2)
            plot_histogram(hard.centers, hard.density, ax=ax, color="k", marker="x", label="GFMD hard wall")
            ax.set_xlim(0, xmax)
            ax.set_ylim(1e-2, 3e3)
            ax.legend(fontsize=7)
        fig.suptitle("Fig. 1 system, 1024^2, seed 1: GFMD (symbols) against theory (lines, paper's p_c)", fontsize=9)
        fig.tight_layout()
        out = ROOT / "docs" / "images" / "fig1_bundled.png"
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=110)
        print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
