"""Command line: ``diffusion-pr fig1`` (the main job), ``theory``, ``make-reference``."""
from __future__ import annotations

import argparse
import sys
import time
from typing import Optional, Sequence


def _zeta_list(text: str) -> list:
    out = []
    for item in text.split(","):
        item = item.strip()
        if item:
            out.append(None if item == "hard" else float(item))
    return out


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="diffusion-pr",
        description="Pressure distributions in rough elastic contacts (Müser, PRL 100, 055504 (2008)).")
    sub = parser.add_subparsers(dest="command")

    fig = sub.add_parser("fig1", help="GFMD against theory on the paper's Fig. 1 scene (the main job)")
    fig.add_argument("--n", type=int, default=512, help="grid points per side (paper: 1024; default 512)")
    fig.add_argument("--zetas", type=str, default="0.001,0.01,0.25,1,4",
                     help="comma-separated exponential-wall ranges in grid units of the 1024^2 system")
    fig.add_argument("--no-hard-wall", action="store_true", help="skip the hard-wall / Persson comparison")
    fig.add_argument("--seed", type=int, default=1)
    fig.add_argument("--tol", type=float, default=1e-6, help="GFMD tolerance relative to p0")
    fig.add_argument("--cutoff", default="muser", choices=["muser", "raised_cosine", "smoothstep"])
    fig.add_argument("--backend", default="auto", help="theory backend: auto, native, pypde, fipy")
    fig.add_argument("--rtol", type=float, default=1e-5, help="theory tolerance (L1)")
    fig.add_argument("--out", default="fig1_out", help="output folder")
    fig.add_argument("--progress", action="store_true", help="GFMD progress bars")

    th = sub.add_parser("theory", help="theory curve for the Fig. 1 continuum spectrum")
    th.add_argument("--zeta", type=float, default=0.0)
    th.add_argument("--p-c", type=float, default=None, help="cutoff pressure (needed for smooth cutoffs)")
    th.add_argument("--cutoff", default="sharp", choices=["sharp", "muser", "raised_cosine", "smoothstep"])
    th.add_argument("--backend", default="auto")
    th.add_argument("--rtol", type=float, default=1e-6)

    ref = sub.add_parser("make-reference", help="regenerate the bundled GFMD reference data")
    ref.add_argument("--n", type=int, default=1024)
    ref.add_argument("--seeds", type=int, nargs="+", default=[1])
    ref.add_argument("--zetas", type=str, default="hard,0.001,0.01,0.1,0.25,0.5,1,2,4")
    ref.add_argument("--tol", type=float, default=1e-6)
    ref.add_argument("--surface", default="fig1", choices=["fig1", "fig1-skewed"])
    ref.add_argument("--out", default=None, help="output folder (default: the package's data folder)")
    return parser


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``diffusion-pr`` command (bad input: message, exit code 2)."""
    try:
        return _main(argv)
    except ValueError as exc:
        print(f"diffusion-pr: error: {exc}", file=sys.stderr)
        return 2


def _main(argv: Optional[Sequence[str]] = None) -> int:
    args = _parser().parse_args(argv)
    command = args.command or "fig1"
    if args.command is None:  # bare `diffusion-pr` runs the default scene
        args = _parser().parse_args(["fig1"])
    if command == "fig1":
        from .fig1 import run_fig1

        t0 = time.perf_counter()
        zetas = [z for z in _zeta_list(args.zetas) if z is not None]
        report = run_fig1(n=args.n, zetas=zetas, hard_wall=not args.no_hard_wall, seed=args.seed, tol=args.tol,
                          cutoff=args.cutoff, backend=args.backend, rtol=args.rtol, out_dir=args.out,
                          progress=args.progress)
        print()
        print(report.text())
        print()
        for kind, path in report.files.items():
            print(f"wrote {kind}: {path}")
        print(f"total {time.perf_counter() - t0:.1f} s")
        return 0
    if command == "theory":
        from .api import pressure_distribution
        from .reference_data import FIG1_SCENE
        from .spectra import SelfAffineSpectrum

        s = FIG1_SCENE
        spectrum = SelfAffineSpectrum(s["hurst"], s["q_min"], s["q_max"], rms_slope=s["rms_slope"])
        res = pressure_distribution(spectrum, E_star=s["E_star"], mean_pressure=s["mean_pressure"], zeta=args.zeta,
                                    cutoff=args.cutoff, p_c=args.p_c, backend=args.backend, rtol=args.rtol)
        print(res)
        return 0 if res.success else 1
    if command == "make-reference":
        from .reference_data import generate_reference

        generate_reference(zetas=_zeta_list(args.zetas), seeds=args.seeds, n=args.n, tol=args.tol,
                           out_dir=args.out, surface=args.surface)
        return 0
    raise AssertionError(command)  # argparse rejects unknown commands


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
