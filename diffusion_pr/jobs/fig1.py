"""The paper's Fig. 1: GFMD histograms against the theory, as a reusable job.

:func:`run_fig1` runs the GFMD reference (:mod:`gfmd_ref`) on the Fig. 1 system of Müser, Phys. Rev. Lett.
100, 055504 (2008), doi:10.1103/PhysRevLett.100.055504 (:mod:`diffusion_pr.paper`) at a chosen resolution (the
cell stays ``L = 1024`` grid spacings, so ``zeta`` keeps its meaning), draws :func:`theory_curves` for every
wall, and writes a figure, a CSV of curves and histograms and a text report (``diffusion-pr fig1``; docs page
``fig1``).  Every input is checked before any GFMD work."""
from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np

from ..api import DEFAULT_CLOSURE, HARD_WALL_DEFAULT
from ..paper import FIG1_SCENE, contact_threshold, cutoff_pressure

#: zeta values of the default scene: those the paper gives cutoff pressures for.
DEFAULT_ZETAS: tuple[float, ...] = (0.001, 0.01, 0.25, 1.0, 4.0)

#: Key of the paper's curve in :attr:`Fig1Case.theories`.
PAPER = "paper"

#: The closures drawn beside the paper's, on exponential walls and at the hard wall: pressure_distribution's
#: defaults, the parameter-free closures chosen on held-out GFMD ensembles (docs/closures.md).
BEST_CLOSURE, HARD_WALL_CLOSURE = DEFAULT_CLOSURE, HARD_WALL_DEFAULT

#: Bin width of the main job's histograms, in units of p0.
BIN_WIDTH_P0 = 0.1


def theory_curves(case: Any, *, cutoff: str, backend: str, rtol: float) -> dict[str, Any]:
    """The theory curves of one wall: ``{label: PressureDistribution}``. The one place where the main job's curves are
    chosen: every entry is compared with the wall's histogram, reported, written and drawn.  :data:`PAPER` is the
    paper's curve (:func:`~diffusion_pr.jobs.reference_data.paper_theory`); :data:`BEST_CLOSURE`
    (:data:`HARD_WALL_CLOSURE` at the hard wall) on the same spectrum (:func:`diffusion_pr.pressure_distribution`)."""
    from ..api import pressure_distribution
    from .reference_data import paper_theory

    paper = paper_theory(case, cutoff=cutoff, backend=backend, rtol=rtol)  # (first: its refusals come first)
    closure = BEST_CLOSURE if case.zeta else HARD_WALL_CLOSURE
    return {PAPER: paper, closure: pressure_distribution(case.spectrum, E_star=case.E_star, zeta=case.zeta or 0.0,
                                                         mean_pressure=case.mean_pressure, closure=closure,
                                                         backend=backend, rtol=rtol)}


@dataclass
class Fig1Case:
    """One wall of the Fig. 1 job: simulation, theory curves and their distances.

    Attributes
    ----------
    zeta : float or None
        Wall range (grid spacings of the 1024^2 system); None for the hard wall.
    histogram : SimulatedHistogram
        GFMD pressure histogram (bin width ``BIN_WIDTH_P0 * p0``, edges from 0 past the largest pressure).
    theories : dict
        ``label -> PressureDistribution`` from :func:`theory_curves`.
    comparisons : dict
        ``label -> Comparison`` (:func:`diffusion_pr.compare.compare`, contact fractions at :attr:`contact_threshold`).
    contact_threshold : float
        Pressure above which a point counts as in contact: :func:`diffusion_pr.paper.contact_threshold`.
    pressure : ndarray
        The GFMD pressure field (the scene's reduced pressure unit, in which E* = 8/3).
    """

    zeta: Optional[float]
    histogram: Any
    theories: dict
    comparisons: dict
    contact_threshold: float
    pressure: Any
    gfmd_time: float
    theory_time: float
    gfmd_info: dict = field(default_factory=dict)

    @property
    def theory(self) -> Any:
        """The paper's curve (``theories["paper"]``)."""
        return self.theories[PAPER]

    @property
    def comparison(self) -> Any:
        """The paper's curve against the histogram (``comparisons["paper"]``)."""
        return self.comparisons[PAPER]

    @property
    def wall(self) -> str:
        """``"hard"`` or ``"zeta=<zeta>"``."""
        return "hard" if self.zeta is None else f"zeta={self.zeta:g}"


@dataclass
class Fig1Report:
    """Everything :func:`run_fig1` computed, plus where it wrote files."""

    cases: list
    persson: Any
    variance_persson: float
    scene: dict
    files: dict = field(default_factory=dict)

    def text(self) -> str:
        """A short human-readable report."""
        lines = [
            "Fig. 1 of Müser, PRL 100, 055504 (2008): GFMD against the second-order cumulant theory "
            "and the parameter-free closures chosen on held-out GFMD ensembles",
            "scene: " + ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}"
                                  for k, v in self.scene.items()),
            f"Persson (zeta -> 0): sqrt(V0) = {np.sqrt(self.variance_persson):.6f}"
            + ("" if any(c.zeta is None for c in self.cases)  # (the hard wall's row has it)
               else f", contact area a_r = {self.persson.contact_area():.5f}"),
            "",
        ]
        width = max([6] + [len(" = ".join(c.comparisons)) for c in self.cases])
        lines.append(f"{'wall':>12} {'theory':>{width}} {'p_c':>8} {'L1':>8} {'Kolmog.':>8} {'a_sim':>8} "
                     f"{'a_theory':>8} {'sd_sim':>9} {'sd_theory':>9} {'GFMD it':>8} {'resid':>8} {'GFMD s':>7} "
                     f"{'theory s':>8}")
        for c in self.cases:
            p_c, rows = c.gfmd_info.get("p_c"), {}
            for label, cmp in c.comparisons.items():
                # p_c is the paper's fitted cutoff: it belongs to the paper's curve only
                p_c_text = "-" if (p_c is None or label != PAPER) else f"{p_c:.4f}"
                row = (f"{p_c_text:>8} {cmp.l1:8.4f} "
                       f"{cmp.kolmogorov:8.4f} {cmp.contact_fraction_sim:8.4f} {cmp.contact_fraction_theory:8.4f} "
                       f"{np.sqrt(cmp.moments_sim['variance']):9.5f} {np.sqrt(cmp.moments_theory['variance']):9.5f} "
                       f"{c.gfmd_info.get('iterations', 0):8d} {c.gfmd_info.get('residual', np.nan):8.1e} "
                       f"{c.gfmd_time:7.2f} {c.theory_time:8.3f}")
                rows.setdefault(row.replace(p_c_text, "-", 1), []).append((label, row))
            for same in rows.values():  # curves equal to the digits shown (the closures at the hard wall): one row
                lines.append(f"{c.wall:>12} {' = '.join(label for label, _ in same):>{width}} {same[0][1]}")
        lines += ["", "a_sim, a_theory: fraction of the area with p above the contact threshold, the same on both "
                      "sides: p > 0 for the hard wall, p > 0.01 p0 for exponential walls (gfmd_ref's definition; "
                      "for the theory contact_area()). p_c: the paper's fitted cutoff pressure (paper curve "
                      "only; the closures have no fitted parameter). theory s: all theory curves of that wall."]
        return "\n".join(lines)


def _check_inputs(n: Any, zetas: Any, hard_wall: Any, seed: Any, tol: Any, progress: Any,
                  log: Any) -> tuple[int, list[float]]:
    """Validate the scalar inputs of :func:`run_fig1` (ValueError naming the parameter)."""
    from .._validation import check_in_range, check_int, check_seed

    n = check_int("n", n, minimum=2)
    if isinstance(zetas, (str, bytes)) or not hasattr(zetas, "__iter__"):
        raise ValueError(f"zetas must be a sequence of numbers > 0; got zetas={zetas!r}")
    walls = [float(z) for z in zetas if cutoff_pressure(z)]  # (which refuses non-numbers, NaN, inf, <= 0 by name)
    for name, flag in (("hard_wall", hard_wall), ("progress", progress)):
        if not isinstance(flag, (bool, np.bool_)):
            raise ValueError(f"{name} must be True or False; got {name}={flag!r}")
    if not walls and not hard_wall:
        raise ValueError("nothing to compare: zetas is empty and hard_wall=False")
    check_seed("seed", seed)
    check_in_range("tol", tol, 0.0, 0.1, lo_inclusive=False)  # GFMD's own range, checked before any work
    if not callable(log):
        raise ValueError(f"log must be callable (e.g. print); got log={log!r}")
    return n, walls


def run_fig1(*, n: int = 512, zetas: Sequence[float] = DEFAULT_ZETAS, hard_wall: bool = True, seed: int = 1,
             tol: float = 1e-6, cutoff: str = "muser", backend: str = "auto", rtol: float = 1e-5,
             out_dir: Path | str | None = "fig1_out", progress: bool = False,
             log: Callable[[str], Any] = print) -> Fig1Report:
    """Run the Fig. 1 comparison.

    Parameters
    ----------
    n : int
        Grid points per side (the paper: 1024).
    zetas : sequence of float
        Exponential-wall decay lengths, in grid spacings of the paper's 1024^2 system (``L = 1024`` at every ``n``).
    hard_wall : bool
        Also run the hard wall and compare it with Persson's mirror Gaussian.
    seed : int
        Surface seed (integer >= 0).
    tol : float
        GFMD tolerance relative to ``p0`` (dimensionless).
    cutoff : str
        Cutoff variant for the theory (``"muser"`` = the paper's literal one).
    backend, rtol
        Passed to :func:`diffusion_pr.pressure_distribution` (rtol: L1 tolerance).
    out_dir : path or None
        Where to write ``fig1.png``, ``fig1_curves.csv``, ``fig1_histograms.csv`` and ``fig1_report.txt`` (created and
        checked for writability before any work); ``None`` writes nothing.
    progress : bool
        GFMD progress bars.
    log : callable
        Receives one progress line per wall.

    Raises
    ------
    ValueError
        For any bad input, before any GFMD work.
    """
    from .._validation import check_writable
    from ..compare import SimulatedHistogram, compare
    from ..cumulants import stress_variance
    from ..spectra import DiscreteSpectrum
    from .reference_data import ReferenceCase, fig1_heights, paper_theory, solve_fig1_wall

    n, walls = _check_inputs(n, zetas, hard_wall, seed, tol, progress, log)
    if out_dir is not None:
        out_dir = Path(check_writable("out_dir", out_dir))
    scene = dict(FIG1_SCENE)
    E_star, p0 = scene["E_star"], scene["mean_pressure"]
    heights = fig1_heights(n, seed)
    spectrum = DiscreteSpectrum.from_heights(heights, scene["length"])
    v0 = float(stress_variance(spectrum, E_star=E_star, mean_pressure=p0, zeta=0.0))

    def case_of(zeta: Optional[float]) -> Any:
        return ReferenceCase(f"fig1_n{n}_{'hard' if zeta is None else f'zeta{zeta:g}'}_s{seed}", zeta, None,
                             spectrum, {**scene, "n": n, "seed": seed, "zeta": zeta})

    # all theory curves first: cheap, and they validate cutoff, backend and rtol before any GFMD
    persson = paper_theory(case_of(None))
    planned = []
    for zeta in ([None] if hard_wall else []) + walls:
        t0 = time.perf_counter()
        curves = theory_curves(case_of(zeta), cutoff=cutoff, backend=backend, rtol=rtol)
        planned.append((zeta, curves, time.perf_counter() - t0))

    bin_width = BIN_WIDTH_P0 * p0
    cases = []
    for zeta, curves, t_theory in planned:
        res, t_gfmd = solve_fig1_wall(heights, zeta, tol=tol, progress=progress)
        pressure = np.asarray(res.pressure)
        edges = np.arange(int(np.ceil(float(pressure.max()) / bin_width)) + 1) * bin_width
        threshold = contact_threshold(zeta, p0)
        hist = SimulatedHistogram.from_pressures(pressure, bins=edges, contact_threshold=threshold)
        comparisons = {label: compare(th, hist) for label, th in curves.items()}  # (th.contact_threshold)
        info = {"iterations": int(res.iterations), "residual": float(res.residual), "converged": bool(res.converged),
                "contact_fraction": float(res.contact_fraction), "method": res.method,
                "p_c": None if zeta is None else cutoff_pressure(zeta)}
        case = Fig1Case(zeta, hist, curves, comparisons, threshold, pressure, t_gfmd, t_theory, info)
        cases.append(case)
        log(f"{case.wall}: GFMD {t_gfmd:.2f} s ({res.iterations} it, residual {res.residual:.1e}), "
            f"theory {t_theory * 1e3:.1f} ms, L1 {case.comparison.l1:.4f}")
    report = Fig1Report(cases, persson, v0, {**scene, "n": n, "seed": seed, "cutoff": cutoff})
    if out_dir is not None:
        report.files = write_outputs(report, out_dir)
    return report


def _column(case: Fig1Case, label: str) -> str:
    if case.zeta is None:
        return "hard" if label == PAPER else f"{label}_hard"
    return f"theory_zeta{case.zeta:g}" if label == PAPER else f"{label}_zeta{case.zeta:g}"


def _write_csv(path: Path, header: list, rows: Any) -> Path:
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(rows)
    return path


def write_outputs(report: Fig1Report, out_dir: Path) -> dict:
    """Write the figure, the curves/histograms CSVs and the text report; return their paths by kind."""
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    p = np.linspace(0.0, max((float(c.histogram.edges[-1]) for c in report.cases), default=0.2), 801)
    header = ["p", "persson", *(_column(c, label) for c in report.cases for label in c.theories)]
    columns = [p, report.persson.pdf(p), *(th.pdf(p) for c in report.cases for th in c.theories.values())]
    bins = [[c.wall, f"{lo:.8g}", f"{hi:.8g}", f"{d:.8g}", f"{c.histogram.zero_weight:.8g}"] for c in report.cases
            for lo, hi, d in zip(c.histogram.edges[:-1], c.histogram.edges[1:], c.histogram.density)]
    files = {"curves": _write_csv(out_dir / "fig1_curves.csv", header, np.column_stack(columns).tolist()),
             "histograms": _write_csv(out_dir / "fig1_histograms.csv",
                                      ["wall", "p_lo", "p_hi", "density", "zero_weight"], bins),
             "report": out_dir / "fig1_report.txt", "figure": out_dir / "fig1.png"}
    files["report"].write_text(report.text() + "\n")
    fig = plot_fig1(report)
    fig.savefig(files["figure"], dpi=130)
    plt.close(fig)
    return files


def plot_fig1(report: Fig1Report) -> Any:
    """One panel per wall, log density against pressure: GFMD symbols, the theory curves, Persson dashed (on the
    hard wall's panel, else the first); x up to the field's and the curves' 1 - 1e-4 quantile; the paper's
    Kolmogorov distance to GFMD in each title and its largest in the figure's.

    Every line carries a ``gid``: ``"gfmd:<wall>"`` (the histogram merged two bins at a time),
    ``"theory:<wall>:<label>"`` and ``"persson"``.  Pressures in the scene's units (those of ``E*`` and ``p0``).

    Returns
    -------
    matplotlib Figure
    """
    import matplotlib.pyplot as plt

    from ..plotting import QUANTILE, body_range, plot_histogram

    n = max(len(report.cases), 1)
    cols = min(3, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.0 * rows), layout="constrained", squeeze=False)
    styles = ["-", "-.", ":", (0, (5, 1))]
    units = "scene units"
    persson_at = next((i for i, c in enumerate(report.cases) if c.zeta is None), 0)
    for i, (ax, c) in enumerate(zip(axes.flat, report.cases)):
        hist = c.histogram.rebinned(2)
        plot_histogram(hist.centers, hist.density, ax=ax, color="0.3", label="GFMD", gid=f"gfmd:{c.wall}",
                       units=units)
        mass = np.cumsum(c.histogram.density * c.histogram.widths)
        p_hi = float(np.interp((1.0 - QUANTILE) * mass[-1], mass, c.histogram.edges[1:]))
        q = np.linspace(0.0, float(hist.edges[-1]), 600)
        for j, (name, th) in enumerate(c.theories.items()):
            p_hi = max(p_hi, body_range(th)[1])
            if c.zeta is None and name == PAPER:
                continue  # the hard wall's paper curve is Persson's, drawn below
            dens = th.pdf(q)
            label = f"paper: second order, p_c = {c.gfmd_info['p_c']:g}" if name == PAPER else name
            ax.plot(q, np.where(dens > 0, dens, np.nan), lw=1.2, ls=styles[j % len(styles)], color=f"C{j}",
                    gid=f"theory:{c.wall}:{name}", label=label)
        if i == persson_at:
            dens = report.persson.pdf(q)
            ax.plot(q, np.where(dens > 0, dens, np.nan), "k--", lw=1.2, label="Persson (mirror Gaussian)",
                    gid="persson")
        counts = hist.density[hist.density > 0]  # (a field with p0 > 0 has some)
        ax.set_ylim(0.5 * float(counts.min()), 3.0 * float(counts.max()))
        ax.set_xlim(0.0, min(p_hi, float(hist.edges[-1])))
        ax.set_title(f"{'hard wall' if c.zeta is None else f'zeta = {c.zeta:g}'}: K(paper, GFMD) = "
                     f"{c.comparison.kolmogorov:.3f}", fontsize=8)
        ax.legend(fontsize=6)
    for ax in axes.flat[len(report.cases):]:
        ax.set_visible(False)
    worst = max(report.cases, key=lambda c: c.comparison.kolmogorov, default=None)
    misfit = "" if worst is None else (f"; the paper's curve misses GFMD by up to K = "
                                       f"{worst.comparison.kolmogorov:.3f} ({worst.wall})")
    fig.suptitle(f"Fig. 1 scene, {report.scene.get('n')}^2 grid, seed {report.scene.get('seed')}: GFMD (symbols) "
                 f"against the paper's second order with its fitted p_c (solid){misfit}", fontsize=8)
    return fig
