"""Command line: ``diffusion-pr fig1`` (the main job), ``theory``, ``make-reference``.

Every input is checked before any work; bad input prints ``diffusion-pr: error: ...`` naming the parameter and
exits with code 2.  Lengths (``zeta``) are in the unit of the surface's side ``L``, as in the Python API and
``gfmd-ref``: on a grid, ``--length-unit grid`` (the default: ``L = n`` grid spacings) or ``paper`` (the paper's
1024^2 system, ``L = 1024`` at every ``n``); for ``theory``, the unit of ``--length``.
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Optional, Sequence

#: The paper's length unit (``--length-unit paper``), worded identically in ``gfmd-ref run --help``.
ZETA_UNIT = "grid spacings of the paper's 1024^2 Fig. 1 system"
#: The units of ``--length-unit``, worded as ``gfmd_ref.cli.LENGTH_UNITS``: lengths in units of the cell's L.
LENGTH_UNITS = {"grid": "grid spacings of the solved n^2 grid (L = n)", "paper": f"{ZETA_UNIT} (L = 1024)"}
#: The paper's walls (its cutoff pressures are given for them), in the paper's unit.
PAPER_ZETAS = "0.001,0.01,0.25,1,4"
#: The walls of the bundled reference cases (``jobs.reference_data.FIG1_ZETAS`` and the hard wall), paper's unit.
REFERENCE_WALLS = "hard,0.001,0.01,0.1,0.25,0.5,1,2,4"
#: Grid points per side below which the Fig. 1 roughness (shortest wavelength L/32) is under-sampled (Nyquist).
MIN_N = 64


def _zeta_list(text: str, *, allow_hard: bool) -> list:
    """Parse ``"hard,0.01,0.25"`` (argparse type: bad items are a usage error naming --zetas)."""
    out = []
    for item in filter(None, (t.strip() for t in text.split(","))):
        if item == "hard" and allow_hard:
            out.append(None)
            continue
        try:
            z = float(item)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{item!r} is not a number" + (
                "" if allow_hard else " ('hard' is not a zeta here: use --no-hard-wall to skip it)")) from None
        if not 0 < z < float("inf"):
            raise argparse.ArgumentTypeError(f"zeta must be a finite number > 0; got {item!r}")
        out.append(z)
    if not out:
        raise argparse.ArgumentTypeError(f"no wall in {text!r}: give comma-separated walls, e.g. "
                                         f"{'hard,' if allow_hard else ''}0.25,1")
    return out


def _number(lo: float, hi: float, *, integer: bool = False, lo_open: bool = True):
    """argparse type: a number in ``(lo, hi]`` (``[lo, hi]`` with ``lo_open=False``), else a usage error."""
    def parse(text: str):
        try:
            v = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if integer else 'a number'}") from None
        if not ((v > lo if lo_open else v >= lo) and v <= hi):
            raise argparse.ArgumentTypeError(f"must lie in {'(' if lo_open else '['}{lo:g}, {hi:g}]; got {text}")
        return v
    return parse


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("diffusion-pr")
    except PackageNotFoundError:  # pragma: no cover - source tree that is not installed
        from . import __version__

        return __version__


def _grid_options(sub: argparse.ArgumentParser, *, n: int, zetas: str, walls: str) -> None:
    """``--n``, ``--length-unit``, ``--zetas`` and ``--tol`` of the commands that run GFMD on the Fig. 1 scene."""
    sub.add_argument("--n", type=_number(MIN_N, 1 << 16, integer=True, lo_open=False), default=n,
                     help=f"grid points per side, >= {MIN_N} (the roughness's shortest wavelength L/32 needs 2; "
                          f"paper: 1024; default: {n})")
    sub.add_argument("--length-unit", choices=list(LENGTH_UNITS), default="grid",
                     help=f"the unit of --zetas (the unit of the cell's side L): grid = {LENGTH_UNITS['grid']}; "
                          f"paper = {LENGTH_UNITS['paper']} (default: grid, as gfmd-ref)")
    sub.add_argument("--zetas", type=lambda t: _zeta_list(t, allow_hard=walls.startswith("hard")), default=None,
                     help=f"comma-separated {walls} of the exponential walls, in the unit of --length-unit "
                          f"(default: the paper's {zetas} in {ZETA_UNIT}, i.e. x n/1024 in grid units)")
    sub.add_argument("--tol", type=_number(0.0, 0.1), default=1e-6,
                     help="GFMD residual tolerance, relative to p0, in (0, 0.1] (dimensionless; default: 1e-6)")


def _parser() -> argparse.ArgumentParser:
    from . import paper
    from .closures import CLOSURES

    parser = argparse.ArgumentParser(
        prog="diffusion-pr",
        description="Pressure distributions in rough elastic contacts (Müser, PRL 100, 055504 (2008), "
                    "doi:10.1103/PhysRevLett.100.055504). Pressures share the unit of --E-star (the paper's E'), "
                    "lengths in the unit of the surface's side L (--length-unit, --length).")
    parser.add_argument("--version", action="version", version=f"diffusion-pr {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="{fig1,theory,make-reference,load-curve}")

    fig = sub.add_parser("fig1", help="GFMD against theory on the paper's Fig. 1 scene (the main job)",
                         description="GFMD against the paper's theory on the Fig. 1 scene; all inputs are "
                                     "checked before the GFMD runs.")
    _grid_options(fig, n=512, zetas=PAPER_ZETAS, walls="decay lengths")
    fig.add_argument("--no-hard-wall", action="store_true",
                     help="skip the hard-wall / Persson comparison (default: run it)")
    fig.add_argument("--seed", type=int, default=1, help="surface seed, integer >= 0 (default: 1)")
    fig.add_argument("--cutoff", default="muser", choices=["muser", "raised_cosine", "smoothstep"],
                     help="cutoff of the theory's diffusivity at small p (default: muser, the paper's)")
    fig.add_argument("--backend", default="auto", choices=["auto", "native", "pypde", "fipy"],
                     help="theory backend (the cutoffs and closures have no closed form; default: auto)")
    fig.add_argument("--rtol", type=float, default=1e-5,
                     help="theory tolerance, L1 error of the density (dimensionless; default: 1e-5)")
    fig.add_argument("--out", default="fig1_out",
                     help="output folder, checked for writability before any work (default: fig1_out)")
    fig.add_argument("--progress", action="store_true", help="GFMD progress bars (default: off)")

    th = sub.add_parser("theory", help="theory curve for a self-affine continuum spectrum (default: Fig. 1's)",
                        description="The theory's pressure distribution for a self-affine spectrum (default: the "
                                    "paper's Fig. 1 scene); prints a summary and the contact area, --out writes "
                                    "the curve.")
    th.add_argument("--closure", default=None, choices=list(CLOSURES),
                    help="theory: the paper's second_order or a closure beyond it (default: as "
                         "diffusion_pr.pressure_distribution's, docs/closures.md)")
    th.add_argument("--zeta", type=float, default=0.0,
                    help="decay length of the exponential wall, in the unit of --length; 0 is the hard wall "
                         "(default: 0)")
    th.add_argument("--length", type=float, default=paper.LENGTH,
                    help=f"the surface's side L = 2 pi/q_min, the unit of every length (default: {paper.LENGTH:g}, "
                         f"i.e. lengths in {ZETA_UNIT})")
    th.add_argument("--n-waves", type=float, default=paper.N_WAVES,
                    help=f"q_max/q_min: the shortest wavelength is L/n_waves (default: {paper.N_WAVES})")
    th.add_argument("--hurst", type=float, default=paper.HURST,
                    help=f"Hurst exponent, in (0, 1) (default: {paper.HURST})")
    th.add_argument("--rms-slope", type=float, default=paper.RMS_SLOPE,
                    help=f"amplitude: the surface's rms slope (dimensionless; default: {paper.RMS_SLOPE})")
    th.add_argument("--E-star", type=float, default=paper.E_STAR, help="contact modulus E* (default: 8/3)")
    th.add_argument("--mean-pressure", type=float, default=paper.MEAN_PRESSURE,
                    help=f"mean pressure p0, in the unit of --E-star (default: {paper.MEAN_PRESSURE})")
    th.add_argument("--cutoff", default="sharp", choices=["sharp", "muser", "raised_cosine", "smoothstep"],
                    help="second_order: cutoff of the diffusivity at small p (default: sharp, Persson's)")
    th.add_argument("--p-c", type=float, default=None,
                    help="cutoff pressure of a smooth cutoff, in the unit of --E-star (the paper: 0.0027 for "
                         "zeta >= 0.25; default: none)")
    th.add_argument("--backend", default="auto", help="auto, closed_form, native, pypde, fipy (default: auto)")
    th.add_argument("--rtol", type=float, default=1e-6,
                    help="L1 tolerance of the density (dimensionless; default: 1e-6)")
    th.add_argument("--out", default=None,
                    help="write the curve as CSV (columns p [unit of --E-star], density [1/that unit], cdf; the "
                         "zero_weight in a comment line) to this file, checked before solving (default: print only)")

    ref = sub.add_parser("make-reference", help="regenerate GFMD reference data (like the bundled cases)",
                         description="Run GFMD on the Fig. 1 system and write .npz cases with provenance. "
                                     "Writes into --out; it never writes into the installed package unless "
                                     "--out points there.")
    _grid_options(ref, n=1024, zetas=REFERENCE_WALLS, walls="hard and/or decay lengths")
    ref.add_argument("--seeds", type=int, nargs="+", default=[1], help="surface seeds, integers >= 0 (default: 1)")
    ref.add_argument("--surface", default="fig1", choices=["fig1", "fig1-skewed"],
                     help="Gaussian surface or its skewed transform (default: fig1)")
    ref.add_argument("--out", default="reference_out",
                     help="output folder, checked for writability before any work (default: reference_out)")
    from .load_curve import add_cli

    add_cli(sub, ZETA_UNIT)
    return parser


def _paper_zetas(args: argparse.Namespace, default: str) -> list:
    """``--zetas`` in the paper's unit (``L = 1024``, what the jobs take): converted from grid units by 1024/n."""
    if args.zetas is None:
        return _zeta_list(default, allow_hard=True)
    scale = 1.0 if args.length_unit == "paper" else 1024.0 / args.n
    return [None if z is None else z * scale for z in args.zetas]


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``diffusion-pr`` command (bad input: message, exit code 2)."""
    try:
        return _main(argv)
    except ValueError as exc:
        print(f"diffusion-pr: error: {exc}", file=sys.stderr)
        return 2


def _write_curve(res, path: str) -> None:
    """Write a theory result as CSV: p, density, cdf (one row per grid point)."""
    import numpy as np

    p = np.asarray(res.p, dtype=float)
    rows = np.column_stack([p, np.asarray(res.density, dtype=float), np.asarray(res.cdf(p), dtype=float)])
    with open(path, "w") as fh:
        fh.write(f"# diffusion-pr {_version()} theory curve; zero_weight = {res.zero_weight:.12g} "
                 f"(probability of p = 0); success = {res.success}\n")
        fh.write("p,density,cdf\n")
        np.savetxt(fh, rows, delimiter=",", fmt="%.12g")


def _theory(args: argparse.Namespace) -> int:
    import math

    from ._validation import check_writable
    from .api import pressure_distribution
    from .paper import contact_threshold
    from .spectra import SelfAffineSpectrum

    if args.out is not None:
        check_writable("--out", args.out, folder=False)
    if not (args.length > 0 and args.n_waves > 1):
        raise ValueError(f"--length must be > 0 and --n-waves > 1; got --length {args.length}, --n-waves "
                         f"{args.n_waves}")
    q_min = 2.0 * math.pi / args.length
    spectrum = SelfAffineSpectrum(args.hurst, q_min, q_min * args.n_waves, rms_slope=args.rms_slope)
    res = pressure_distribution(spectrum, E_star=args.E_star, mean_pressure=args.mean_pressure, zeta=args.zeta,
                                closure=args.closure, cutoff=args.cutoff, p_c=args.p_c, backend=args.backend,
                                rtol=args.rtol)
    threshold = contact_threshold(args.zeta, args.mean_pressure)
    print(res)
    print(f"contact area a_r = {res.contact_area():.6g} (fraction with p > {threshold:g}: "
          f"{'p > 0 at the hard wall' if threshold == 0 else '0.01 p0 at an exponential wall, as GFMD counts'})")
    if args.out is not None:
        _write_curve(res, args.out)
        print(f"wrote curve: {args.out}")
    return 0 if res.success else 1


def _main(argv: Optional[Sequence[str]] = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command is None:  # bare `diffusion-pr`: say what it can do
        parser.print_help()
        return 0
    if args.command == "theory":
        return _theory(args)
    if args.command == "fig1":
        from .jobs.fig1 import run_fig1

        t0 = time.perf_counter()
        report = run_fig1(n=args.n, zetas=_paper_zetas(args, PAPER_ZETAS), hard_wall=not args.no_hard_wall,
                          seed=args.seed, tol=args.tol, cutoff=args.cutoff, backend=args.backend, rtol=args.rtol,
                          out_dir=args.out, progress=args.progress)
        print(f"\n(zeta below in {ZETA_UNIT})\n{report.text()}\n")
        for kind, path in report.files.items():
            print(f"wrote {kind}: {path}")
        print(f"total {time.perf_counter() - t0:.1f} s")
        return 0
    if args.command == "load-curve":
        from .load_curve import run_cli

        return run_cli(args)
    from .jobs.reference_data import generate_reference

    generate_reference(zetas=_paper_zetas(args, REFERENCE_WALLS), seeds=args.seeds, n=args.n, tol=args.tol,
                       out_dir=args.out, surface=args.surface)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
