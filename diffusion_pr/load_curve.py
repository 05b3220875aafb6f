"""Load curves: the pressure distribution and the relative contact area over a range of mean pressures.

Pressures in the unit of ``E_star``, lengths in the unit of the spectrum.  The contact area of each load is
``PressureDistribution.contact_area()``: ``P(p > 0)`` at the hard wall, ``P(p > 0.01 p0)`` at an exponential
wall (GFMD's threshold)."""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from ._validation import check_finite_array, check_positive

__all__ = ["LoadCurve", "load_curve"]

#: the columns of :attr:`LoadCurve.table` (pressure units except the dimensionless area, error and success)
COLUMNS = ("p0", "contact_area", "threshold", "mean", "sd", "error_estimate", "success")


@dataclass(frozen=True)
class LoadCurve:
    """Pressure distributions along a load path: ``results`` (one per load, in the order given), ``table`` (a
    structured array of :data:`COLUMNS`: ``p0``, ``contact_area`` a_r at ``threshold``, ``mean`` and ``sd`` of
    ``Pr``, in pressure units, the solver's ``error_estimate`` and ``success``), the ``closure`` and ``zeta``
    (length), ``monotone`` (a_r non-decreasing in p0 within the error estimates), the ``note`` saying why not, and
    the ``wall_time`` [s]."""

    results: tuple
    table: np.ndarray
    closure: str
    zeta: float
    monotone: bool
    note: str
    wall_time: float

    def plot(self, ax: Any = None) -> Any:
        """``a_r`` against ``p0`` on log-log axes (a new figure when ``ax`` is None); returns the axes."""
        import matplotlib.pyplot as plt

        ax = plt.figure(layout="constrained").gca() if ax is None else ax
        order = np.argsort(self.table["p0"])
        ax.loglog(self.table["p0"][order], self.table["contact_area"][order], "o-", ms=3,
                  label=f"{self.closure}, zeta = {self.zeta:g}")
        ax.set_xlabel("mean pressure p0 (same unit as E*)")
        ax.set_ylabel("relative contact area a_r")
        ax.legend()
        return ax

    def to_csv(self, path: Any) -> None:
        """Write :attr:`table` as CSV with a header line naming the closure and the wall."""
        rows = np.column_stack([self.table[c].astype(float) for c in COLUMNS])
        header = f"load curve: closure={self.closure}, zeta={self.zeta:g}\n" + ",".join(COLUMNS)
        np.savetxt(path, rows, delimiter=",", fmt="%.10g", header=header)


def load_curve(spectrum: Any, *, E_star: float, mean_pressures: Any, zeta: float = 0.0,
               closure: Optional[str] = None, backend: str = "auto", rtol: float = 1e-4,
               p_c_ratio: Optional[float] = None, progress: bool = False, **options: Any) -> LoadCurve:
    """:func:`~diffusion_pr.pressure_distribution` at every load of ``mean_pressures``, with a table of ``a_r``.

    Every load is an independent solve to ``rtol`` (the default 1e-4 is ample for a contact area: 50 loads on the
    Fig. 1 spectrum take 0.14 s at the hard wall, 1.7-2.4 s for a shell closure at zeta = 0.25; starting each solve
    from the previous one's grid, as :func:`~diffusion_pr.pressure_distributions` does, gained 0.97-1.32x).

    Parameters
    ----------
    spectrum, E_star, zeta, closure, backend, rtol, **options
        As in :func:`~diffusion_pr.pressure_distribution` (e.g. ``cutoff``, ``p_c`` of the second order).
    mean_pressures : array_like
        Loads ``p0`` (pressure), one-dimensional, each > 0.
    p_c_ratio : float, optional
        Second order only: ``p_c = p_c_ratio * p0`` at every load (the paper's Fig. 1 fit: 0.0027/0.004 = 0.675).
        A fixed ``p_c`` (in ``options``) is a pressure fitted at one load: at loads ``p0 << p_c`` the cutoff stops
        the broadening and ``a_r`` rises towards 1, so the curve is not monotone (Fig. 1 spectrum, zeta 0.01 to 1);
        the scaled rule gives monotone curves there.
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    LoadCurve
        A non-monotone curve also warns (``UserWarning``) with its ``note``.
    """
    from .api import pressure_distribution

    p0s = check_finite_array("mean_pressures", mean_pressures, ndim=1)
    check_positive("mean_pressures", p0s)
    if p_c_ratio is not None:
        check_positive("p_c_ratio", p_c_ratio)
        if closure not in (None, "second_order") or options.get("p_c") is not None:
            raise ValueError(f"p_c_ratio={p_c_ratio!r} sets the second order's p_c per load: it needs "
                             f"closure='second_order' and no p_c (got closure={closure!r}, p_c={options.get('p_c')!r})")
    if progress:
        from tqdm.auto import tqdm
    t0 = time.perf_counter()
    results = [pressure_distribution(spectrum, E_star=E_star, mean_pressure=float(p0), zeta=zeta, closure=closure,
                                     backend=backend, rtol=rtol, **options,
                                     **({} if p_c_ratio is None else {"p_c": p_c_ratio * float(p0)}))
               for p0 in (tqdm(p0s, desc="load curve", unit="load") if progress else p0s)]
    table = np.array([(r.mean_pressure, r.contact_area(), r.contact_threshold, r.mean,
                       np.sqrt(max(r.moment(2, central=True), 0.0)), r.error_estimate, r.success)
                      for r in results], dtype=[(c, bool if c == "success" else float) for c in COLUMNS])
    closure = results[0].diagnostics["closure"]
    note = _monotonicity_note(table, closure, options, p_c_ratio)
    if note:
        warnings.warn(note, UserWarning, stacklevel=2)
    return LoadCurve(tuple(results), table, closure, float(zeta), not note, note, time.perf_counter() - t0)


def _monotonicity_note(table: np.ndarray, closure: str, options: dict, p_c_ratio: Optional[float]) -> str:
    """Empty if ``a_r`` is non-decreasing in ``p0`` within the error estimates, else where and why it is not."""
    t = np.sort(table, order="p0")
    a, err = t["contact_area"], t["error_estimate"]
    drop = np.diff(a) < -(err[1:] + err[:-1] + 1e-12)
    if not np.any(drop):
        return ""
    i = int(np.argmax(drop))
    where = (f"a_r falls from {a[i]:.4g} at p0 = {t['p0'][i]:.4g} to {a[i + 1]:.4g} at p0 = {t['p0'][i + 1]:.4g}"
             f" ({int(drop.sum())} decreasing steps)")
    if closure == "second_order" and options.get("cutoff", "sharp") != "sharp" and p_c_ratio is None:
        return (f"{where}: the second order's cutoff p_c = {options.get('p_c')!r} is a fixed pressure, fitted at "
                "one load; at loads p0 << p_c it stops the broadening and a_r rises towards 1. Give p_c_ratio "
                "(p_c proportional to p0) for a monotone load curve.")
    return f"{where}: not expected of this closure; check the results' success and error_estimate."


def add_cli(sub: Any, zeta_unit: str) -> None:
    """Add the ``load-curve`` command to the ``diffusion-pr`` subparsers ``sub`` (``zeta_unit``: the CLI's wording
    of the Fig. 1 length unit)."""
    from .closures import CLOSURES

    lc = sub.add_parser("load-curve", help="relative contact area against the mean pressure",
                        description="Contact area against load for the Fig. 1 spectrum or a periodic height map "
                                    "(.npy); prints the table, --out writes it as CSV. Pressures in the unit of "
                                    "--E-star.")
    lc.add_argument("--closure", default=None, choices=CLOSURES,
                    help="theory (default: as diffusion_pr.pressure_distribution's, docs/closures.md)")
    lc.add_argument("--zeta", type=float, default=0.0,
                    help=f"range of the exponential wall, in the length unit of the surface (Fig. 1 spectrum: "
                         f"{zeta_unit}; --heights: the unit of --length); 0 is the hard wall (default: 0)")
    lc.add_argument("--p0", type=float, nargs=2, default=(5e-5, 0.07), metavar=("MIN", "MAX"),
                    help="smallest and largest mean pressure, in the unit of --E-star (default: 5e-5 0.07)")
    lc.add_argument("--n-loads", type=int, default=50, help="loads, log-spaced (default: 50)")
    lc.add_argument("--E-star", type=float, default=8 / 3, help="contact modulus (default: 8/3, the paper's)")
    lc.add_argument("--heights", default=None, help="periodic height map, .npy (default: the Fig. 1 spectrum)")
    lc.add_argument("--length", type=float, default=None,
                    help="side of --heights along its first axis, in its length unit (default: none)")
    lc.add_argument("--cutoff", default="sharp", choices=["sharp", "muser", "raised_cosine", "smoothstep"],
                    help="second order: cutoff of the diffusivity (default: sharp)")
    lc.add_argument("--p-c-ratio", type=float, default=None,
                    help="second order: p_c = ratio * p0 at each load (the paper's Fig. 1: 0.675; default: none)")
    lc.add_argument("--rtol", type=float, default=1e-4, help="tolerance of each solve (default: 1e-4)")
    lc.add_argument("--out", default=None, help="write the table as CSV to this file (default: print only)")


def run_cli(args: Any) -> int:
    """Run ``diffusion-pr load-curve``; exit code 1 if a solve failed."""
    from .paper import FIG1_SCENE as F
    from .spectra import DiscreteSpectrum, SelfAffineSpectrum

    if args.n_loads < 1 or not 0 < args.p0[0] <= args.p0[1]:
        raise ValueError(f"--n-loads must be >= 1 and 0 < MIN <= MAX for --p0; got {args.n_loads}, {args.p0}")
    if args.heights is None:
        spectrum = SelfAffineSpectrum(F["hurst"], F["q_min"], F["q_max"], rms_slope=F["rms_slope"])
    elif args.length is None:
        raise ValueError("--heights needs --length (the map's side along its first axis, in its length unit)")
    else:
        spectrum = DiscreteSpectrum.from_heights(np.load(args.heights), args.length)
    options = {} if args.cutoff == "sharp" else {"cutoff": args.cutoff}
    lc = load_curve(spectrum, E_star=args.E_star, mean_pressures=np.geomspace(*args.p0, args.n_loads),
                    zeta=args.zeta, closure=args.closure, rtol=args.rtol, p_c_ratio=args.p_c_ratio, **options)
    print("  ".join(f"{c:>14s}" for c in COLUMNS))
    for row in lc.table:
        print("  ".join(f"{float(v):14.6g}" for v in row))
    print(f"{lc.wall_time:.2f} s" + (f"; {lc.note}" if lc.note else ""))
    if args.out is not None:
        lc.to_csv(args.out)
        print(f"wrote table: {args.out}")
    return 0 if lc.table["success"].all() else 1
