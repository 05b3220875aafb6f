"""Command line: ``gfmd-ref run`` solves the paper's Fig. 1 scene and writes the
pressure histogram (``.npz``, ``.csv``, ``.png``).

The same job is callable from Python: :func:`run_default_scene`, and another CLI
can mount the sub-command with :func:`add_run_arguments` + :func:`run_from_args`.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import warnings

import numpy as np

from .histogram import pressure_histogram
from .interactions import ExponentialRepulsion, HardWall
from ._validation import check_int, check_writable_dir
from .scene import FIG1, fig1_surface, zeta_on_grid
from .solver import ConvergenceWarning, solve_contact

__all__ = ["main", "run_default_scene", "add_run_arguments", "run_from_args"]


def run_default_scene(
    n: int = 256,
    *,
    interaction: str = "hard",
    zeta: float = 0.01,
    seed: int = 1,
    tol: float = 1e-8,
    method: str = "auto",
    bins: int = 60,
    out_dir: str | os.PathLike | None = "gfmd_out",
    progress: bool = False,
    verbose: bool = True,
):
    """Solve the Fig. 1 scene (H = 0.3, rms slope 0.031, E* = 8/3, p0 = 0.004,
    wavelengths L ... L/32) and write the pressure histogram.

    Parameters
    ----------
    n : int
        Grid points per side (>= 2).
    interaction : str
        ``"hard"`` or ``"exp"`` (exponential repulsion, the paper's Eq. 7).
    zeta : float
        Decay length of the exponential wall in grid spacings of the paper's
        1024^2 Fig. 1 system (the unit ``diffusion-pr fig1 --zetas`` uses).  The
        scene is solved on :func:`~gfmd_ref.scene.fig1_surface` (``L = n``), so
        the solver gets ``zeta * n / 1024`` (:func:`~gfmd_ref.scene.zeta_on_grid`).
    seed : int
        Surface seed.
    tol : float
        Residual tolerance relative to p0.
    out_dir : path or None
        Output folder, checked for writability before the solve; None writes nothing.

    Returns ``(result, histogram, paths)``; ``paths`` maps "npz", "csv", "png" to the
    written files (empty if ``out_dir`` is None).
    """
    n = check_int("n", n, minimum=2)
    if interaction in ("hard", "hardwall", "hard-wall"):
        inter = HardWall()
    elif interaction in ("exp", "exponential"):
        inter = ExponentialRepulsion(zeta_on_grid(zeta, n))
    else:
        raise ValueError(f"interaction must be 'hard' or 'exp'; got {interaction!r}")
    if out_dir is not None:
        out_dir = check_writable_dir("out_dir", out_dir)
    h, length = fig1_surface(n, seed=seed)
    p0 = FIG1["mean_pressure"]
    res = solve_contact(
        h,
        length=length,
        E_star=FIG1["E_star"],
        mean_pressure=p0,
        interaction=inter,
        tol=tol,
        method=method,
        progress=progress,
    )
    pmax = float(res.pressure.max())
    hist = pressure_histogram(res, bins=bins, range=(0.0, pmax) if pmax > 0 else None)
    paths = {}
    label = "hard" if isinstance(inter, HardWall) else f"exp_zeta{zeta:g}"
    if out_dir is not None:
        stem = os.path.join(out_dir, f"fig1_{label}_n{n}_seed{seed}")
        meta = dict(
            n=n, seed=seed, interaction=label, tol=tol, method=res.method,
            zeta_fig1_units=None if isinstance(inter, HardWall) else zeta,
            zeta_grid_units=None if isinstance(inter, HardWall) else inter.zeta,
            E_star=FIG1["E_star"], mean_pressure=p0, hurst=FIG1["hurst"],
            rms_slope=FIG1["rms_slope"], contact_fraction=res.contact_fraction,
            iterations=res.iterations, residual=res.residual, converged=res.converged,
            wall_time=res.wall_time, zero_weight=hist.zero_weight,
        )
        np.savez(
            stem + "_histogram.npz", edges=hist.edges, centers=hist.centers,
            density=hist.density, counts=hist.counts, zero_weight=hist.zero_weight,
            meta=json.dumps(meta),
        )
        with open(stem + "_histogram.csv", "w") as fh:
            fh.write(f"# {json.dumps(meta)}\n")
            fh.write(f"# zero_weight (exact-zero pressures) = {hist.zero_weight:.10g}\n")
            fh.write("p_left,p_right,p_center,density,count\n")
            for a, b, c, d, k in zip(hist.edges[:-1], hist.edges[1:], hist.centers,
                                     hist.density, hist.counts):
                fh.write(f"{a:.10g},{b:.10g},{c:.10g},{d:.10g},{int(k)}\n")
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5.5, 4))
        m = hist.density > 0
        ax.semilogy(hist.centers[m], hist.density[m], "o-", ms=3,
                    label=f"GFMD {label}, n={n}")
        ax.set_xlabel("local pressure p")
        ax.set_ylabel("Pr(p) (continuous part)")
        ax.set_title(f"Fig. 1 scene: contact fraction {res.contact_fraction:.4f}, "
                     f"zero weight {hist.zero_weight:.3f}", fontsize=9)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(stem + "_histogram.png", dpi=120)
        plt.close(fig)
        paths = dict(npz=stem + "_histogram.npz", csv=stem + "_histogram.csv",
                     png=stem + "_histogram.png")
    if verbose:
        print(f"scene: Fig. 1 surface, n={n}, seed={seed}, interaction={label}, "
              f"E*={FIG1['E_star']:.6g}, p0={p0}")
        print(f"method:           {res.method}")
        print(f"converged:        {res.converged}")
        print(f"contact fraction: {res.contact_fraction:.6f}")
        print(f"iterations:       {res.iterations}")
        print(f"residual:         {res.residual:.3e} (tol {tol:.1e}, relative to p0)")
        print(f"wall time:        {res.wall_time:.3f} s")
        for k, v in paths.items():
            print(f"wrote {k}: {v}")
    return res, hist, paths


#: The unit of ``--zeta``, worded identically in ``diffusion-pr fig1 --help``.
ZETA_UNIT = "grid spacings of the paper's 1024^2 Fig. 1 system"


def add_run_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``run`` options to an (sub)parser."""
    parser.add_argument("--n", type=int, default=256, help="grid points per side (default: 256)")
    parser.add_argument("--interaction", choices=["hard", "exp"], default="hard",
                        help="hard wall or exponential repulsion (default: hard)")
    parser.add_argument("--zeta", type=float, default=0.01,
                        help=f"decay length of the exponential wall, in {ZETA_UNIT}, "
                             "with --interaction exp (default: 0.01)")
    parser.add_argument("--seed", type=int, default=1, help="surface seed, integer >= 0 (default: 1)")
    parser.add_argument("--tol", type=float, default=1e-8,
                        help="residual tolerance, relative to p0 (dimensionless; default: 1e-8)")
    parser.add_argument("--method", choices=["auto", "ccg", "newton", "fire"], default="auto",
                        help="solver (default: auto)")
    parser.add_argument("--bins", type=int, default=60, help="histogram bins on [0, max p] (default: 60)")
    parser.add_argument("--out", default="gfmd_out",
                        help="output folder, checked for writability before solving (default: gfmd_out)")
    parser.add_argument("--progress", action="store_true", help="show a progress bar (default: off)")
    return parser


def run_from_args(args) -> int:
    try:
        res, _, _ = run_default_scene(
            args.n, interaction=args.interaction, zeta=args.zeta, seed=args.seed,
            tol=args.tol, method=args.method, bins=args.bins, out_dir=args.out,
            progress=args.progress,
        )
    except ValueError as exc:
        print(f"gfmd-ref: error: {exc}", file=sys.stderr)
        return 2
    return 0 if res.converged else 1


def main(argv=None) -> int:
    from importlib.metadata import PackageNotFoundError, version

    parser = argparse.ArgumentParser(
        prog="gfmd-ref", description="GFMD reference solver: `gfmd-ref run` solves the paper's Fig. 1 scene and "
                                     "writes the pressure histogram (.npz, .csv, .png).")
    try:
        ver = version("diffusion-pr")
    except PackageNotFoundError:  # pragma: no cover - source tree not installed
        ver = "unknown"
    parser.add_argument("--version", action="version", version=f"gfmd-ref (diffusion-pr {ver})")
    sub = parser.add_subparsers(dest="command")
    add_run_arguments(sub.add_parser("run", help="solve the Fig. 1 scene, write the histogram"))
    args = parser.parse_args(argv)
    if args.command != "run":
        parser.print_help()
        return 2
    with warnings.catch_warnings():
        warnings.simplefilter("always", ConvergenceWarning)
        return run_from_args(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
