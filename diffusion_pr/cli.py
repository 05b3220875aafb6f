"""Command line: ``diffusion-pr fig1`` (the main job), ``theory``, ``make-reference``.

Every input is checked before any work; bad input prints
``diffusion-pr: error: ...`` naming the parameter and exits with code 2.
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Optional, Sequence

#: The unit of every zeta option, worded identically in ``gfmd-ref run --help``.
ZETA_UNIT = "grid spacings of the paper's 1024^2 Fig. 1 system"


def _zeta_list(text: str, *, allow_hard: bool) -> list:
    """Parse ``"hard,0.01,0.25"`` (argparse type: bad items are a usage error naming --zetas)."""
    out = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        if item == "hard":
            if not allow_hard:
                raise argparse.ArgumentTypeError("'hard' is not a zeta here (use --no-hard-wall to skip it)")
            out.append(None)
            continue
        try:
            z = float(item)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{item!r} is not a number") from None
        if not (z > 0 and z < float("inf")):
            raise argparse.ArgumentTypeError(f"zeta must be a finite number > 0; got {item!r}")
        out.append(z)
    return out


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("diffusion-pr")
    except PackageNotFoundError:  # pragma: no cover - source tree that is not installed
        from . import __version__

        return __version__


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="diffusion-pr",
        description="Pressure distributions in rough elastic contacts (Müser, PRL 100, 055504 (2008), "
                    "doi:10.1103/PhysRevLett.100.055504). Pressures are in units of E* (the paper's E'), "
                    f"lengths in {ZETA_UNIT}.")
    parser.add_argument("--version", action="version", version=f"diffusion-pr {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="{fig1,theory,make-reference,load-curve}")

    fig = sub.add_parser("fig1", help="GFMD against theory on the paper's Fig. 1 scene (the main job)",
                         description="GFMD against the paper's theory on the Fig. 1 scene; all inputs are "
                                     "checked before the GFMD runs.")
    fig.add_argument("--n", type=int, default=512,
                     help="grid points per side; the cell stays 1024 grid spacings of the paper's system "
                          "(paper: 1024; default: 512)")
    fig.add_argument("--zetas", type=lambda t: _zeta_list(t, allow_hard=False), default="0.001,0.01,0.25,1,4",
                     help=f"comma-separated decay lengths of the exponential walls, in {ZETA_UNIT} "
                          "(default: 0.001,0.01,0.25,1,4)")
    fig.add_argument("--no-hard-wall", action="store_true",
                     help="skip the hard-wall / Persson comparison (default: run it)")
    fig.add_argument("--seed", type=int, default=1, help="surface seed, integer >= 0 (default: 1)")
    fig.add_argument("--tol", type=float, default=1e-6,
                     help="GFMD residual tolerance, relative to p0 (dimensionless; default: 1e-6)")
    fig.add_argument("--cutoff", default="muser", choices=["muser", "raised_cosine", "smoothstep"],
                     help="cutoff of the theory's diffusivity at small p (default: muser, the paper's)")
    fig.add_argument("--backend", default="auto",
                     help="theory backend: auto, native, pypde, fipy (default: auto)")
    fig.add_argument("--rtol", type=float, default=1e-5,
                     help="theory tolerance, L1 error of the density (dimensionless; default: 1e-5)")
    fig.add_argument("--out", default="fig1_out",
                     help="output folder, checked for writability before any work (default: fig1_out)")
    fig.add_argument("--progress", action="store_true", help="GFMD progress bars (default: off)")

    th = sub.add_parser("theory", help="theory curve for the Fig. 1 continuum spectrum",
                        description="The theory's pressure distribution for the paper's Fig. 1 continuum "
                                    "spectrum (E* = 8/3, p0 = 0.004); prints a summary, --out writes the curve.")
    th.add_argument("--zeta", type=float, default=0.0,
                    help=f"decay length of the exponential wall, in {ZETA_UNIT}; 0 is the hard wall "
                         "(default: 0)")
    th.add_argument("--p-c", type=float, default=None,
                    help="cutoff pressure, units of E* (needed for smooth cutoffs; the paper: 0.0027 for "
                         "zeta >= 0.25; default: none)")
    th.add_argument("--cutoff", default="sharp", choices=["sharp", "muser", "raised_cosine", "smoothstep"],
                    help="cutoff of the diffusivity at small p (default: sharp, Persson's)")
    th.add_argument("--backend", default="auto", help="auto, closed_form, native, pypde, fipy (default: auto)")
    th.add_argument("--rtol", type=float, default=1e-6,
                    help="L1 tolerance of the density (dimensionless; default: 1e-6)")
    th.add_argument("--out", default=None,
                    help="write the curve as CSV (columns p [units of E*], density [1/E*], cdf; the "
                         "zero_weight in a comment line) to this file (default: print only)")

    ref = sub.add_parser("make-reference", help="regenerate GFMD reference data (like the bundled cases)",
                         description="Run GFMD on the Fig. 1 system and write .npz cases with provenance. "
                                     "Writes into --out; it never writes into the installed package unless "
                                     "--out points there.")
    ref.add_argument("--n", type=int, default=1024, help="grid points per side (default: 1024)")
    ref.add_argument("--seeds", type=int, nargs="+", default=[1], help="surface seeds, integers >= 0 (default: 1)")
    ref.add_argument("--zetas", type=lambda t: _zeta_list(t, allow_hard=True),
                     default="hard,0.001,0.01,0.1,0.25,0.5,1,2,4",
                     help=f"comma-separated walls: 'hard' or decay lengths in {ZETA_UNIT} "
                          "(default: hard,0.001,0.01,0.1,0.25,0.5,1,2,4)")
    ref.add_argument("--tol", type=float, default=1e-6,
                     help="GFMD residual tolerance, relative to p0 (dimensionless; default: 1e-6)")
    ref.add_argument("--surface", default="fig1", choices=["fig1", "fig1-skewed"],
                     help="Gaussian surface or its skewed transform (default: fig1)")
    ref.add_argument("--out", default="reference_out",
                     help="output folder, checked for writability before any work (default: reference_out)")
    from .load_curve import add_cli

    add_cli(sub, ZETA_UNIT)
    return parser


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


def _main(argv: Optional[Sequence[str]] = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command is None:  # bare `diffusion-pr`: say what it can do
        parser.print_help()
        return 0
    if args.command == "fig1":
        from .jobs.fig1 import run_fig1

        t0 = time.perf_counter()
        report = run_fig1(n=args.n, zetas=args.zetas, hard_wall=not args.no_hard_wall, seed=args.seed,
                          tol=args.tol, cutoff=args.cutoff, backend=args.backend, rtol=args.rtol,
                          out_dir=args.out, progress=args.progress)
        print()
        print(report.text())
        print()
        for kind, path in report.files.items():
            print(f"wrote {kind}: {path}")
        print(f"total {time.perf_counter() - t0:.1f} s")
        return 0
    if args.command == "theory":
        from .api import pressure_distribution
        from .paper import FIG1_SCENE
        from .spectra import SelfAffineSpectrum

        if args.out is not None:  # check before solving
            import os

            folder = os.path.dirname(os.path.abspath(args.out))
            if not os.path.isdir(folder) or not os.access(folder, os.W_OK) or os.path.isdir(args.out):
                raise ValueError(f"--out={args.out!r} is not a writable file path")
        s = FIG1_SCENE
        spectrum = SelfAffineSpectrum(s["hurst"], s["q_min"], s["q_max"], rms_slope=s["rms_slope"])
        res = pressure_distribution(spectrum, E_star=s["E_star"], mean_pressure=s["mean_pressure"], zeta=args.zeta,
                                    cutoff=args.cutoff, p_c=args.p_c, backend=args.backend, rtol=args.rtol)
        print(res)
        if args.out is not None:
            _write_curve(res, args.out)
            print(f"wrote curve: {args.out}")
        return 0 if res.success else 1
    if args.command == "make-reference":
        from .jobs.reference_data import generate_reference

        generate_reference(zetas=args.zetas, seeds=args.seeds, n=args.n, tol=args.tol, out_dir=args.out,
                           surface=args.surface)
        return 0
    if args.command == "load-curve":
        from .load_curve import run_cli

        return run_cli(args)
    raise AssertionError(args.command)  # argparse rejects unknown commands


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
