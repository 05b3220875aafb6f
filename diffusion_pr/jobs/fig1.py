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

from ..paper import FIG1_SCENE, contact_threshold, cutoff_pressure

#: zeta values of the default scene: those the paper gives cutoff pressures for.
DEFAULT_ZETAS: tuple[float, ...] = (0.001, 0.01, 0.25, 1.0, 4.0)

#: Key of the paper's curve in :attr:`Fig1Case.theories`.
PAPER = "paper"

#: The best parameter-free closure (docs/closures.md, docs/fig1.md), drawn beside the paper's curve.
BEST_CLOSURE = "local_g1_shell_balanced"

#: Bin width of the main job's histograms, in units of p0.
BIN_WIDTH_P0 = 0.1


def paper_cutoff_pressure(zeta: float) -> float:
    """The paper's fitted ``p_c`` for ``zeta`` (see :func:`diffusion_pr.paper.cutoff_pressure`)."""
    return cutoff_pressure(zeta)


def theory_curves(case: Any, *, cutoff: str, backend: str, rtol: float) -> dict[str, Any]:
    """The theory curves of one wall: ``{label: PressureDistribution}``.

    The one place where the main job's curves are chosen: every entry is compared with the wall's histogram,
    reported, written and drawn.  :data:`PAPER` is the paper's curve
    (:func:`~diffusion_pr.jobs.reference_data.paper_theory`); :data:`BEST_CLOSURE` the best parameter-free closure
    (:func:`diffusion_pr.pressure_distribution` with ``closure=BEST_CLOSURE``) on the same spectrum."""
    from ..api import pressure_distribution
    from .reference_data import paper_theory

    curves = {PAPER: paper_theory(case, cutoff=cutoff, backend=backend, rtol=rtol)}
    curves[BEST_CLOSURE] = pressure_distribution(case.spectrum, E_star=case.E_star, mean_pressure=case.mean_pressure,
                                                 zeta=0.0 if case.zeta is None else case.zeta, closure=BEST_CLOSURE,
                                                 backend=backend, rtol=rtol)
    return curves


@dataclass
class Fig1Case:
    """One wall of the Fig. 1 job: simulation, theory curves and their distances.

    Attributes
    ----------
    zeta : float or None
        Wall range (grid spacings of the 1024^2 system); None for the hard wall.
    histogram : SimulatedHistogram
        GFMD pressure histogram (bin width ``BIN_WIDTH_P0 * p0``, edges from 0
        past the largest pressure).
    theories : dict
        ``label -> PressureDistribution`` from :func:`theory_curves`.
    comparisons : dict
        ``label -> Comparison`` (:func:`diffusion_pr.compare.compare`, contact
        fractions at :attr:`contact_threshold` on both sides).
    contact_threshold : float
        Pressure above which a point counts as in contact: 0 (hard wall) or
        ``0.01 p0`` (exponential wall, :func:`diffusion_pr.paper.contact_threshold`).
    pressure : ndarray
        The GFMD pressure field (units of E*).
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
            "and the best parameter-free closure",
            "scene: " + ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}"
                                  for k, v in self.scene.items()),
        ]
        if not any(c.zeta is None for c in self.cases):  # (else the hard wall's row says it)
            lines.append(f"Persson (zeta -> 0): sqrt(V0) = {np.sqrt(self.variance_persson):.6f}, "
                         f"contact area a_r = {self.persson.contact_area():.5f}")
        lines.append("")
        width = max([6] + [len(label) for c in self.cases for label in c.comparisons])
        lines.append(f"{'wall':>12} {'theory':>{width}} {'p_c':>8} {'L1':>8} {'Kolmog.':>8} {'a_sim':>8} "
                     f"{'a_theory':>8} {'sd_sim':>9} {'sd_theory':>9} {'GFMD it':>8} {'resid':>8} {'GFMD s':>7} "
                     f"{'theory s':>8}")
        for c in self.cases:
            p_c = c.gfmd_info.get("p_c")
            for label, cmp in c.comparisons.items():
                # p_c is the paper's fitted cutoff: it belongs to the paper's curve only
                p_c_text = "-" if (p_c is None or label != PAPER) else f"{p_c:.4f}"
                lines.append(
                    f"{c.wall:>12} {label:>{width}} {p_c_text:>8} {cmp.l1:8.4f} "
                    f"{cmp.kolmogorov:8.4f} {cmp.contact_fraction_sim:8.4f} {cmp.contact_fraction_theory:8.4f} "
                    f"{np.sqrt(cmp.moments_sim['variance']):9.5f} {np.sqrt(cmp.moments_theory['variance']):9.5f} "
                    f"{c.gfmd_info.get('iterations', 0):8d} {c.gfmd_info.get('residual', np.nan):8.1e} "
                    f"{c.gfmd_time:7.2f} {c.theory_time:8.3f}")
        lines.append("")
        lines.append("a_sim, a_theory: fraction of the area with p above the contact threshold, the same on both "
                     "sides: p > 0 for the hard wall, p > 0.01 p0 for exponential walls (gfmd_ref's definition; "
                     "for the theory contact_area()). p_c: the paper's fitted cutoff pressure (paper curve "
                     "only; the closures have no fitted parameter). theory s: all theory curves of that wall.")
        return "\n".join(lines)


def _check_inputs(n: Any, zetas: Any, hard_wall: Any, seed: Any, tol: Any, progress: Any,
                  log: Any) -> tuple[int, list[float]]:
    """Validate the scalar inputs of :func:`run_fig1` (ValueError naming the parameter)."""
    from .._validation import check_int, check_positive, check_seed

    n = check_int("n", n, minimum=2)
    if isinstance(zetas, (str, bytes)) or not hasattr(zetas, "__iter__"):
        raise ValueError(f"zetas must be a sequence of numbers > 0; got zetas={zetas!r}")
    walls = []
    for z in zetas:
        cutoff_pressure(z)  # raises ValueError naming zeta for non-numbers, NaN, inf, <= 0
        walls.append(float(z))
    for name, flag in (("hard_wall", hard_wall), ("progress", progress)):
        if not isinstance(flag, (bool, np.bool_)):
            raise ValueError(f"{name} must be True or False; got {name}={flag!r}")
    if not walls and not hard_wall:
        raise ValueError("nothing to compare: zetas is empty and hard_wall=False")
    check_seed("seed", seed)
    check_positive("tol", tol)
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
        Exponential-wall decay lengths, in grid spacings of the paper's
        1024^2 Fig. 1 system (the cell is ``L = 1024`` of them at every ``n``).
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
        Where to write ``fig1.png``, ``fig1_curves.csv``, ``fig1_histograms.csv``
        and ``fig1_report.txt`` (created and checked for writability before
        any work); ``None`` writes nothing.
    progress : bool
        GFMD progress bars.
    log : callable
        Receives one progress line per wall.

    Raises
    ------
    ValueError
        For any bad input, before any GFMD work.
    """
    import gfmd_ref
    from .._validation import check_writable_dir

    from ..compare import SimulatedHistogram, compare
    from ..cumulants import stress_variance
    from .reference_data import ReferenceCase
    from ..spectra import DiscreteSpectrum

    n, walls = _check_inputs(n, zetas, hard_wall, seed, tol, progress, log)
    if out_dir is not None:
        out_dir = Path(check_writable_dir("out_dir", out_dir))
    scene = dict(FIG1_SCENE)
    E_star, p0, length = scene["E_star"], scene["mean_pressure"], scene["length"]
    heights = gfmd_ref.self_affine_surface(n, length=length, hurst=scene["hurst"], q_min=scene["q_min"],
                                           q_max=scene["q_max"], rms_slope=scene["rms_slope"], seed=seed)
    spectrum = DiscreteSpectrum.from_heights(heights, length)
    v0 = float(stress_variance(spectrum, E_star=E_star, mean_pressure=p0, zeta=0.0))

    def case_of(zeta: Optional[float]) -> Any:
        return ReferenceCase(f"fig1_n{n}_{'hard' if zeta is None else f'zeta{zeta:g}'}_s{seed}", zeta, None,
                             spectrum, {**scene, "n": n, "seed": seed, "zeta": zeta})

    # all theory curves first: cheap, and they validate cutoff, backend and rtol before any GFMD
    persson = theory_curves(case_of(None), cutoff=cutoff, backend=backend, rtol=rtol)[PAPER]
    planned = []
    for zeta in ([None] if hard_wall else []) + walls:
        t0 = time.perf_counter()
        curves = theory_curves(case_of(zeta), cutoff=cutoff, backend=backend, rtol=rtol)
        planned.append((zeta, curves, time.perf_counter() - t0))

    bin_width = BIN_WIDTH_P0 * p0
    cases = []
    for zeta, curves, t_theory in planned:
        interaction = gfmd_ref.HardWall() if zeta is None else gfmd_ref.ExponentialRepulsion(zeta)
        t0 = time.perf_counter()
        res = gfmd_ref.solve_contact(heights, length=length, E_star=E_star, mean_pressure=p0,
                                     interaction=interaction, tol=tol, progress=progress)
        t_gfmd = time.perf_counter() - t0
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


def write_outputs(report: Fig1Report, out_dir: Path) -> dict:
    """Write the figure, the curves/histograms CSVs and the text report."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {}
    # curves on a common grid
    p_max = max(float(c.histogram.edges[-1]) for c in report.cases) if report.cases else 0.2
    p = np.linspace(0.0, p_max, 801)
    header = ["p", "persson"]
    columns = [p, report.persson.pdf(p)]
    for c in report.cases:
        for label, th in c.theories.items():
            header.append(_column(c, label))
            columns.append(th.pdf(p))
    path = out_dir / "fig1_curves.csv"
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(np.column_stack(columns).tolist())
    files["curves"] = path
    path = out_dir / "fig1_histograms.csv"
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["wall", "p_lo", "p_hi", "density", "zero_weight"])
        for c in report.cases:
            for lo, hi, d in zip(c.histogram.edges[:-1], c.histogram.edges[1:], c.histogram.density):
                w.writerow([c.wall, f"{lo:.8g}", f"{hi:.8g}", f"{d:.8g}", f"{c.histogram.zero_weight:.8g}"])
    files["histograms"] = path
    path = out_dir / "fig1_report.txt"
    path.write_text(report.text() + "\n")
    files["report"] = path
    import matplotlib.pyplot as plt

    ax = plot_fig1(report)
    ax.figure.tight_layout()
    files["figure"] = out_dir / "fig1.png"
    ax.figure.savefig(files["figure"], dpi=130)
    plt.close(ax.figure)
    return files


def plot_fig1(report: Fig1Report, ax: Any = None) -> Any:
    """Log density against pressure: GFMD symbols, theory lines, Persson dashed.

    Every line carries a ``gid``: ``"gfmd:<wall>"`` (the histogram merged
    two bins at a time), ``"theory:<wall>:<label>"`` and ``"persson"``.

    Parameters
    ----------
    report : Fig1Report
    ax : matplotlib Axes, optional
        Axes to draw on (a new figure when omitted).

    Returns
    -------
    matplotlib Axes
    """
    import matplotlib.pyplot as plt

    from ..plotting import plot_histogram

    if ax is None:
        _, ax = plt.subplots(figsize=(6.4, 4.6))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    styles = ["-", "-.", ":", (0, (5, 1))]
    p_hi = 0.0
    for i, c in enumerate(report.cases):
        color = colors[i % len(colors)]
        label = "hard wall" if c.zeta is None else f"zeta = {c.zeta:g}"
        hist = c.histogram.rebinned(2)
        plot_histogram(hist.centers, hist.density, ax=ax, color=color, label=f"GFMD {label}",
                       gid=f"gfmd:{c.wall}")
        if c.zeta is not None:  # the hard wall's paper curve is Persson's, drawn below
            q = np.linspace(0.0, float(hist.edges[-1]), 600)
            for j, (name, th) in enumerate(c.theories.items()):
                dens = th.pdf(q)
                ax.plot(q, np.where(dens > 0, dens, np.nan), color=color, lw=1.2, ls=styles[j % len(styles)],
                        gid=f"theory:{c.wall}:{name}", label=None if name == PAPER else f"{name}, {label}")
        p_hi = max(p_hi, float(hist.edges[-1]))
    q = np.linspace(1e-6, p_hi if p_hi > 0 else 0.2, 600)
    dens = report.persson.pdf(q)
    ax.plot(q, np.where(dens > 0, dens, np.nan), "k--", lw=1.2, label="Persson (mirror Gaussian)", gid="persson")
    ax.set_yscale("log")
    ax.set_xlabel("pressure p (units of E*)")
    ax.set_ylabel("Pr(p) (1 / pressure)")
    d_max = max([float(np.max(c.histogram.density)) for c in report.cases if np.size(c.histogram.density)] or [1.0])
    ax.set_ylim(bottom=1e-2, top=max(3.0 * d_max, 1.0))  # the data's decades, not a tall theory spike
    ax.legend(fontsize=7)
    names = [n for c in report.cases for n in c.theories if n != PAPER]
    other = f"; dash-dot: {names[0]}" if names else ""
    ax.set_title(f"Fig. 1 scene, {report.scene.get('n')}^2 grid, seed {report.scene.get('seed')}\n"
                 f"solid: the paper's second order (fitted p_c){other}", fontsize=8)
    return ax
