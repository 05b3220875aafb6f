"""Command line: ``gfmd-ref run`` solves the paper's Fig. 1 scene and writes the
pressure histogram (``.npz``, ``.csv``, ``.png``); ``gfmd-ref ensemble`` runs (or
resumes) an ensemble of cases on Dask into a store directory, ``gfmd-ref
ensemble-summary DIR`` prints its per-group table, ``gfmd-ref ensemble-ingest``
reduces saved pressure fields into a store and ``gfmd-ref ensemble-bundle``
writes compact package data from stores (see docs/ensembles.md).

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
from .solvers import ConvergenceWarning, solve_contact

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
    parser.add_argument("--method", choices=["auto", "ccg", "pk", "newton", "fire"], default="auto",
                        help="solver: ccg (preconditioned constrained CG), pk (plain Polonsky-Keer), fire "
                             "(hard wall); newton, fire (exponential wall) (default: auto = ccg / newton)")
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


def add_ensemble_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Options of ``gfmd-ref ensemble``."""
    parser.add_argument("--store", required=True, help="store directory (created; finished cases are skipped)")
    parser.add_argument("--n", default="1024", help="grid size(s), comma separated (default 1024; L = n)")
    parser.add_argument("--seeds", default="1-4", help="surface seeds, e.g. 1-64 or 1,3,5-7 (default 1-4)")
    parser.add_argument("--walls", default="hard",
                        help="walls: 'hard' and/or exponential ranges zeta, in grid spacings of the solved n^2 grid "
                             "(L = n; the same as the run command's unit at n = 1024, where the paper's system "
                             "is solved; the same physical wall at another n is zeta * n / 1024), "
                             "e.g. hard,4,0.25 (default: hard)")
    parser.add_argument("--mean-pressures", default=None,
                        help="loads p0, comma separated (default the paper's 0.004)")
    parser.add_argument("--E-star", type=float, default=None, help="contact modulus (default 8/3)")
    parser.add_argument("--hurst", type=float, default=None, help="surface Hurst exponent (default 0.3)")
    parser.add_argument("--rms-slope", type=float, default=None, help="surface rms slope (default 0.031)")
    parser.add_argument("--n-waves", type=int, default=None,
                        help="q_max/q_min, shortest wavelength L/n_waves (default 32)")
    parser.add_argument("--tol", type=float, default=1e-6, help="solver tolerance relative to p0 (default 1e-6)")
    parser.add_argument("--method", choices=["auto", "ccg", "pk", "newton", "fire"], default="auto",
                        help="solver, as for the run command (default: auto = ccg / newton)")
    parser.add_argument("--workers", type=int, default=None,
                        help="local cluster worker processes (default: one per core)")
    parser.add_argument("--threads-per-worker", type=int, default=None,
                        help="FFT threads per worker (default 1)")
    parser.add_argument("--scheduler", default=None, help="address of a running Dask scheduler (tcp://host:8786)")
    parser.add_argument("--serial", action="store_true", help="no cluster: solve the cases in this process")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def ensemble_from_args(args, argv=None) -> int:
    from .ensemble import FIG1_SURFACE, EnsembleSurface, run_ensemble

    try:
        surface = EnsembleSurface(
            FIG1_SURFACE.hurst if args.hurst is None else args.hurst,
            FIG1_SURFACE.rms_slope if args.rms_slope is None else args.rms_slope,
            FIG1_SURFACE.n_waves if args.n_waves is None else args.n_waves,
        )
        ns = [int(v) if v.strip().lstrip("-").isdigit() else v for v in str(args.n).split(",")]
        loads = None if args.mean_pressures is None else args.mean_pressures.split(",")
        command = "gfmd-ref " + " ".join(sys.argv[1:] if argv is None else argv)
        run = run_ensemble(args.store, n=ns, seeds=args.seeds, walls=args.walls, mean_pressures=loads,
                           surface=surface, E_star=args.E_star, tol=args.tol, method=args.method,
                           workers=args.workers, threads_per_worker=args.threads_per_worker,
                           scheduler=args.scheduler, serial=args.serial, progress=not args.no_progress,
                           command=command)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0 if run.success else 1


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
    add_ensemble_arguments(sub.add_parser("ensemble", help="run or resume an ensemble on Dask into a store"))
    ps = sub.add_parser("ensemble-summary", help="per-group table of an ensemble store")
    ps.add_argument("store", help="store directory")
    pi = sub.add_parser("ensemble-ingest", help="reduce saved pressure fields (npz: pressure + meta) into a store")
    pi.add_argument("fields", help="directory of *.npz fields")
    pi.add_argument("--store", required=True, help="store directory")
    pi.add_argument("--field-command", default="", help="the command that computed the fields (provenance)")
    pi.add_argument("--no-progress", action="store_true")
    pb = sub.add_parser("ensemble-bundle", help="write compact per-seed quantiles (package data) from stores")
    pb.add_argument("stores", nargs="+", help="store directories")
    pb.add_argument("--out", required=True, help="output .npz")
    pb.add_argument("--name", required=True, help="ensemble name stored in the file")
    pb.add_argument("--regenerate", default="", help="the commands that regenerate the stores (provenance)")
    pb.add_argument("--seeds", default=None, help="only these seeds, e.g. 1-32 (default all)")
    args = parser.parse_args(argv)
    if args.command == "run":
        with warnings.catch_warnings():
            warnings.simplefilter("always", ConvergenceWarning)
            return run_from_args(args)
    if args.command == "ensemble":
        return ensemble_from_args(args, argv)
    if args.command == "ensemble-summary":
        from .ensemble import load_ensemble

        try:
            print(load_ensemble(args.store).summary())
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        return 0
    if args.command == "ensemble-ingest":
        from .ensemble import ingest_fields

        command = "gfmd-ref " + " ".join(sys.argv[1:] if argv is None else argv)
        try:
            run = ingest_fields(args.fields, args.store, field_command=args.field_command, command=command,
                                progress=not args.no_progress)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        return 0 if run.success else 1
    if args.command == "ensemble-bundle":
        from .ensemble.data import write_bundle
        from .ensemble.run import parse_seeds

        command = "gfmd-ref " + " ".join(sys.argv[1:] if argv is None else argv)
        try:
            path, size = write_bundle(args.stores, args.out, name=args.name, command=command,
                                      regenerate=args.regenerate,
                                      seeds=None if args.seeds is None else parse_seeds(args.seeds))
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(f"wrote {path} ({size / 1e6:.2f} MB)")
        return 0
    parser.print_help()
    return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
