"""Command line ``gfmd-ref``: ``run`` (Fig. 1 scene or ``--heights`` map -> pressure
histogram), ``ensemble``, ``ensemble-summary``, ``ensemble-ingest``, ``ensemble-bundle``
(docs/ensembles.md). ``run`` from Python: :func:`run_default_scene`; another CLI mounts it
with :func:`add_run_arguments` + :func:`run_from_args`.
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
from ._validation import check_heights, check_int, check_positive, check_tol, check_writable_dir
from .scene import FIG1, fig1_surface, zeta_on_grid
from .solvers import ConvergenceWarning, solve_contact

__all__ = ["main", "run_default_scene", "add_run_arguments", "run_from_args"]


#: The paper's length unit (``--length-unit paper``), worded identically in ``diffusion-pr fig1 --help``.
ZETA_UNIT = "grid spacings of the paper's 1024^2 Fig. 1 system"
#: The units of ``--length-unit`` for the Fig. 1 scene: lengths (zeta) in units of the cell's L.
LENGTH_UNITS = {"grid": "grid spacings of the solved n^2 grid (L = n)", "paper": f"{ZETA_UNIT} (L = 1024)"}


def load_heights(path) -> np.ndarray:
    """A 2-D height map from ``.npy`` or text (``.txt``, ``.csv``, ``.dat``: whitespace or
    comma separated rows); ValueError naming the file otherwise."""
    path = os.fspath(path)
    try:
        if path.endswith(".npy"):
            h = np.load(path, allow_pickle=False)
        else:
            with open(path) as fh:
                comma = "," in fh.read(4096)
            h = np.loadtxt(path, delimiter="," if comma else None, ndmin=2)
    except (OSError, ValueError) as exc:
        raise ValueError(f"heights={path!r}: not a readable 2-D height map (.npy, or .txt/.csv rows): {exc}") from None
    if h.ndim != 2:
        raise ValueError(f"heights={path!r}: a 2-D height map is needed; got shape {h.shape}")
    return h


def run_default_scene(
    n: int = 256,
    *,
    interaction: str | None = None,
    zeta: float | None = None,
    length_unit: str = "grid",
    heights=None,
    length=None,
    E_star: float | None = None,
    mean_pressure: float | None = None,
    seed: int = 1,
    tol: float = 1e-8,
    method: str = "auto",
    bins: int = 60,
    out_dir: str | os.PathLike | None = "gfmd_out",
    progress: bool = False,
    verbose: bool = True,
):
    """Solve the Fig. 1 scene (H = 0.3, rms slope 0.031, E* = 8/3, p0 = 0.004,
    wavelengths L ... L/32) or a user's height map, and write the pressure histogram.

    Parameters
    ----------
    n : int
        Grid points per side of the Fig. 1 scene (>= 64: its shortest wavelength L/32 needs
        two points).
    interaction : {"hard", "exp"}, optional
        Hard wall or exponential repulsion (the paper's Eq. 7). Default: ``"exp"`` when
        ``zeta`` is given, else ``"hard"``; ``"hard"`` with a ``zeta`` is an error.
    zeta : float, optional
        Decay length of the exponential wall (default 0.01), in the unit of the cell's
        side L: for the Fig. 1 scene set by ``length_unit``, for a height map the unit of
        ``length``.
    length_unit : {"grid", "paper"}
        Fig. 1 scene only: ``"grid"`` (default), lengths in grid spacings of the solved
        ``n x n`` grid (``L = n``, as :func:`~gfmd_ref.fig1_surface` and the ensembles);
        ``"paper"``, in grid spacings of the paper's 1024^2 system (``L = 1024``; the
        solver gets ``zeta * n / 1024``, :func:`~gfmd_ref.scene.zeta_on_grid`).
    heights : array or path, optional
        A periodic height map (or a ``.npy``/``.txt``/``.csv`` file of one) instead of the
        Fig. 1 scene; rows and columns may differ (:func:`~gfmd_ref.solve_contact`).
    length : float or (float, float), optional
        With ``heights``: the map's side along its first axis or both sides, in the user's
        length unit (default: the number of rows, i.e. lengths in grid spacings).
    E_star, mean_pressure : float, optional
        Contact modulus and mean pressure (default: the paper's 8/3 and 0.004).
    seed : int
        Surface seed (Fig. 1 scene).
    tol : float
        Residual tolerance relative to p0, in (0, 0.1].
    method, progress
        As :func:`~gfmd_ref.solve_contact`.
    bins : int
        Bins of the pressure histogram.
    out_dir : path or None
        Output folder, checked for writability before the solve; None writes nothing.
    verbose : bool
        Print a summary and the written files.

    Returns
    -------
    tuple
        ``(result, histogram, paths)``: the :class:`~gfmd_ref.ContactResult`, the
        :class:`~gfmd_ref.PressureHistogram` and a dict mapping "npz", "csv", "png" to the
        written files (empty if ``out_dir`` is None).

    Raises
    ------
    ValueError
        Bad input, before any solve.
    """
    if interaction is None:
        interaction = "hard" if zeta is None else "exp"
    if interaction not in ("hard", "exp"):
        raise ValueError(f"interaction must be 'hard' or 'exp'; got interaction={interaction!r}")
    if interaction == "hard" and zeta is not None:
        raise ValueError(f"zeta={zeta!r} is the range of the exponential wall: use interaction 'exp' "
                         "(or omit it: a zeta implies the exponential wall)")
    if length_unit not in LENGTH_UNITS:
        raise ValueError(f"length_unit must be one of {tuple(LENGTH_UNITS)}; got length_unit={length_unit!r}")
    zeta = 0.01 if zeta is None else check_positive("zeta", zeta)
    tol = check_tol(tol)
    E_star = FIG1["E_star"] if E_star is None else check_positive("E_star", E_star)
    p0 = FIG1["mean_pressure"] if mean_pressure is None else check_positive("mean_pressure", mean_pressure)
    if heights is None:
        if length is not None:
            raise ValueError("length applies to a height map (heights=...); the Fig. 1 scene's L is set by "
                             "length_unit")
        n = check_int("n", n, minimum=2)
        z_solver = zeta_on_grid(zeta, n) if length_unit == "paper" else zeta
        unit = LENGTH_UNITS[length_unit]
        name = f"fig1_{{}}_n{n}_seed{seed}"
        scene = f"Fig. 1 surface, n={n}, seed={seed}"
    else:
        if length_unit != "grid":
            raise ValueError(f"length_unit={length_unit!r} applies to the Fig. 1 scene; a height map's lengths are "
                             "in the unit of length")
        src = heights
        heights = load_heights(heights) if isinstance(heights, (str, os.PathLike)) else heights
        h = check_heights(heights)
        length = float(h.shape[0]) if length is None else length
        z_solver, unit = zeta, "the unit of the map's length"
        stem = os.path.splitext(os.path.basename(os.fspath(src)))[0] if isinstance(src, (str, os.PathLike)) else "map"
        name = stem + f"_{{}}_{h.shape[0]}x{h.shape[1]}"
        scene = f"height map {stem}, {h.shape[0]} x {h.shape[1]}, length {length}"
    inter = HardWall() if interaction == "hard" else ExponentialRepulsion(z_solver)
    if out_dir is not None:
        out_dir = check_writable_dir("out_dir", out_dir)
    if heights is None:
        h, length = fig1_surface(n, seed=seed)
    res = solve_contact(h, length=length, E_star=E_star, mean_pressure=p0, interaction=inter, tol=tol,
                        method=method, progress=progress)
    pmax = float(res.pressure.max())
    hist = pressure_histogram(res, bins=bins, range=(0.0, pmax) if pmax > 0 else None)
    paths = {}
    label = "hard" if interaction == "hard" else f"exp_zeta{zeta:g}" + ("" if heights is not None else length_unit)
    if out_dir is not None:
        stem = os.path.join(out_dir, name.format(label))
        meta = dict(scene=scene, interaction=label, tol=tol, method=res.method,
                    zeta=None if interaction == "hard" else zeta, zeta_unit=None if interaction == "hard" else unit,
                    zeta_solver=None if interaction == "hard" else z_solver, length=res.length, E_star=E_star,
                    mean_pressure=p0, contact_fraction=res.contact_fraction, contact_threshold=res.contact_threshold,
                    iterations=res.iterations, residual=res.residual, converged=res.converged,
                    wall_time=res.wall_time, zero_weight=hist.zero_weight)
        if heights is None:
            meta.update(n=n, seed=seed, hurst=FIG1["hurst"], rms_slope=FIG1["rms_slope"])
        paths = {k: f"{stem}_histogram.{k}" for k in ("npz", "csv", "png")}
        np.savez(paths["npz"], edges=hist.edges, centers=hist.centers, density=hist.density, counts=hist.counts,
                 zero_weight=hist.zero_weight, meta=json.dumps(meta))
        np.savetxt(paths["csv"], np.column_stack([hist.edges[:-1], hist.edges[1:], hist.centers, hist.density,
                                                  hist.counts]), fmt=["%.10g"] * 4 + ["%d"], delimiter=",",
                   comments="", header=f"# {json.dumps(meta)}\n# zero_weight (exact-zero pressures) = "
                                       f"{hist.zero_weight:.10g}\np_left,p_right,p_center,density,count")
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5.5, 4))
        m = hist.density > 0
        ax.semilogy(hist.centers[m], hist.density[m], "o-", ms=3, label=f"GFMD {label}")
        ax.set(xlabel="local pressure p", ylabel="Pr(p) (continuous part)")
        ax.set_title(f"{scene}: contact fraction {res.contact_fraction:.4f}, zero weight {hist.zero_weight:.3f}",
                     fontsize=8)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(paths["png"], dpi=120)
        plt.close(fig)
    if verbose:
        wall = "hard wall" if interaction == "hard" else f"exponential wall, zeta={zeta:g} in {unit}"
        print(f"scene: {scene}, {wall}, E*={E_star:.6g}, p0={p0}\n"
              f"method:           {res.method}\n"
              f"converged:        {res.converged}\n"
              f"contact fraction: {res.contact_fraction:.6f} (p > {res.contact_threshold:.3g})\n"
              f"iterations:       {res.iterations}\n"
              f"residual:         {res.residual:.3e} (tol {tol:.1e}, relative to p0)\n"
              f"wall time:        {res.wall_time:.3f} s")
        for k, v in paths.items():
            print(f"wrote {k}: {v}")
    return res, hist, paths


def _length_arg(text: str):
    parts = [float(v) for v in text.split(",")]
    if len(parts) not in (1, 2):
        raise ValueError(text)
    return parts[0] if len(parts) == 1 else tuple(parts)


def _solver_arguments(parser: argparse.ArgumentParser, tol: float, zeta_of: str) -> None:
    """The options ``run`` and ``ensemble`` share: ``--length-unit``, ``--E-star``, ``--tol``, ``--method``."""
    parser.add_argument("--length-unit", choices=list(LENGTH_UNITS), default="grid",
                        help=f"the unit of {zeta_of} (the unit of the cell's side L): grid = {LENGTH_UNITS['grid']}; "
                             f"paper = {LENGTH_UNITS['paper']}, converted to zeta * n / 1024 on the solved grid "
                             "(default: grid)")
    parser.add_argument("--E-star", type=float, default=None, help="contact modulus E* (default: the paper's 8/3)")
    parser.add_argument("--tol", type=float, default=tol,
                        help=f"residual tolerance, relative to p0, in (0, 0.1] (dimensionless; default: {tol:g})")
    parser.add_argument("--method", choices=["auto", "ccg", "pk", "newton", "fire"], default="auto",
                        help="solver: ccg (preconditioned constrained CG), pk (plain Polonsky-Keer), fire "
                             "(hard wall); newton, fire (exponential wall) (default: auto = ccg / newton)")


def add_run_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``run`` options to an (sub)parser."""
    parser.add_argument("--n", type=int, default=256,
                        help="grid points per side of the Fig. 1 scene, >= 64 (default: 256)")
    parser.add_argument("--heights", default=None,
                        help="solve this periodic height map (.npy, or .txt/.csv rows; rows and columns may differ) "
                             "instead of the Fig. 1 scene (default: the Fig. 1 scene)")
    parser.add_argument("--length", type=_length_arg, default=None,
                        help="with --heights: the map's side along its first axis (same spacing along the second), "
                             "or 'Lx,Ly', in the user's length unit (default: the number of rows, i.e. grid spacings)")
    parser.add_argument("--interaction", choices=["hard", "exp"], default=None,
                        help="hard wall or exponential repulsion (default: exp if --zeta is given, else hard)")
    parser.add_argument("--zeta", type=float, default=None,
                        help="decay length of the exponential wall (implies --interaction exp), in the unit of "
                             f"--length-unit (grid: {LENGTH_UNITS['grid']}; paper: {ZETA_UNIT}) or, with "
                             "--heights, of --length (default: 0.01)")
    _solver_arguments(parser, 1e-8, "--zeta for the Fig. 1 scene")
    parser.add_argument("--mean-pressure", type=float, default=None,
                        help="mean pressure p0, in the unit of --E-star (default: the paper's 0.004)")
    parser.add_argument("--seed", type=int, default=1, help="Fig. 1 surface seed, integer >= 0 (default: 1)")
    parser.add_argument("--bins", type=int, default=60, help="histogram bins on [0, max p] (default: 60)")
    parser.add_argument("--out", default="gfmd_out",
                        help="output folder, checked for writability before solving (default: gfmd_out)")
    parser.add_argument("--progress", action="store_true", help="show a progress bar (default: off)")
    return parser


def _error(exc: Exception) -> int:
    print(f"gfmd-ref: error: {exc}", file=sys.stderr)
    return 2


def run_from_args(args) -> int:
    """Run the ``run`` sub-command from parsed arguments: exit code 0 (converged), 1 (not
    converged) or 2 (bad input)."""
    try:
        res, _, _ = run_default_scene(
            args.n, interaction=args.interaction, zeta=args.zeta, length_unit=args.length_unit,
            heights=args.heights, length=args.length, E_star=args.E_star, mean_pressure=args.mean_pressure,
            seed=args.seed, tol=args.tol, method=args.method, bins=args.bins, out_dir=args.out,
            progress=args.progress,
        )
    except ValueError as exc:
        return _error(exc)
    return 0 if res.converged else 1


def add_ensemble_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Options of ``gfmd-ref ensemble``."""
    parser.add_argument("--store", required=True, help="store directory (created; finished cases are skipped)")
    parser.add_argument("--n", default="1024", help="grid size(s), comma separated (default 1024; L = n)")
    parser.add_argument("--seeds", default="1-4", help="surface seeds, e.g. 1-64 or 1,3,5-7 (default 1-4)")
    parser.add_argument("--walls", default="hard",
                        help="walls: 'hard' and/or exponential ranges zeta in the unit of --length-unit, "
                             "e.g. hard,4,0.25 (default: hard)")
    _solver_arguments(parser, 1e-6, "the zeta of --walls; the store records zeta in grid spacings with L = n")
    parser.add_argument("--mean-pressures", default=None, help="loads p0, comma separated (default the paper's 0.004)")
    parser.add_argument("--hurst", type=float, default=None, help="surface Hurst exponent (default 0.3)")
    parser.add_argument("--rms-slope", type=float, default=None, help="surface rms slope (default 0.031)")
    parser.add_argument("--n-waves", type=int, default=None,
                        help="q_max/q_min, shortest wavelength L/n_waves (default 32)")
    parser.add_argument("--workers", type=int, default=None,
                        help="local cluster worker processes (default: one per core)")
    parser.add_argument("--threads-per-worker", type=int, default=None, help="FFT threads per worker (default 1)")
    parser.add_argument("--scheduler", default=None, help="address of a running Dask scheduler (tcp://host:8786)")
    parser.add_argument("--serial", action="store_true", help="no cluster: solve the cases in this process")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _ensemble_command(args, command: str) -> int:
    """The ``ensemble*`` sub-commands (ValueError on bad input)."""
    from . import ensemble as ens

    if args.command == "ensemble":
        surface = ens.EnsembleSurface(**{k: getattr(args, k) for k in ("hurst", "rms_slope", "n_waves")
                                         if getattr(args, k) is not None})
        loads = None if args.mean_pressures is None else args.mean_pressures.split(",")
        run = ens.run_ensemble(args.store, n=args.n.split(","), seeds=args.seeds, walls=args.walls, length_unit=args.length_unit,
                               mean_pressures=loads, surface=surface, E_star=args.E_star, tol=args.tol,
                               method=args.method, workers=args.workers, threads_per_worker=args.threads_per_worker,
                               scheduler=args.scheduler, serial=args.serial, progress=not args.no_progress,
                               command=command)
        # like `run`: a case that did not converge is not a success (it stays in the store, marked)
        return 0 if run.success and run.n_not_converged == 0 else 1
    if args.command == "ensemble-summary":
        print(ens.load_ensemble(args.store).summary())
        return 0
    if args.command == "ensemble-ingest":
        run = ens.ingest_fields(args.fields, args.store, field_command=args.field_command, command=command,
                                progress=not args.no_progress)
        return 0 if run.success else 1
    from .ensemble.data import write_bundle
    from .ensemble.run import parse_seeds

    path, size = write_bundle(args.stores, args.out, name=args.name, command=command, regenerate=args.regenerate,
                              seeds=None if args.seeds is None else parse_seeds(args.seeds))
    print(f"wrote {path} ({size / 1e6:.2f} MB)")
    return 0


def main(argv=None) -> int:
    from importlib.metadata import PackageNotFoundError, version

    parser = argparse.ArgumentParser(
        prog="gfmd-ref", description="GFMD reference solver: `gfmd-ref run` solves the paper's Fig. 1 scene (or "
                                     "a height map) and writes the pressure histogram (.npz, .csv, .png); "
                                     "lengths are in the unit of the cell's side L. Without a command: this help "
                                     "(exit code 0).")
    try:
        ver = version("diffusion-pr")
    except PackageNotFoundError:  # pragma: no cover - source tree not installed
        ver = "unknown"
    parser.add_argument("--version", action="version", version=f"gfmd-ref (diffusion-pr {ver})")
    sub = parser.add_subparsers(dest="command")
    add_run_arguments(sub.add_parser("run", help="solve the Fig. 1 scene or a height map, write the histogram"))
    add_ensemble_arguments(sub.add_parser("ensemble", help="run or resume an ensemble on Dask into a store (exit code 1 "
                                                       "if a case failed or did not converge)"))
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
    if args.command is None:
        parser.print_help()  # no command: the help, as `diffusion-pr` does
        return 0
    if args.command == "run":
        with warnings.catch_warnings():
            warnings.simplefilter("always", ConvergenceWarning)
            return run_from_args(args)
    try:
        return _ensemble_command(args, "gfmd-ref " + " ".join(sys.argv[1:] if argv is None else argv))
    except ValueError as exc:
        return _error(exc)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
