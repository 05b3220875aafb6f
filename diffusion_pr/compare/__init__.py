"""Theory against simulation: histograms, distances, moments, curvature, fits.

A simulated pressure field (from :mod:`gfmd_ref` or any other contact solver)
enters as a :class:`SimulatedHistogram`: bin edges, the density of the
continuous part, the weight of exactly-zero pressures (the hard-wall
non-contact peak), and, where known, the raw moments and quantiles of the field
(computed from the field itself, not from the binned data).  Everything here is
numpy/scipy only: :mod:`diffusion_pr` does not need :mod:`gfmd_ref`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SimulatedHistogram:
    """A pressure histogram of one simulated contact.

    Attributes
    ----------
    edges : ndarray
        Bin edges (units of pressure), increasing, ``edges[0] >= 0``.
    density : ndarray
        Density of the continuous part in each bin (1 / pressure), normalized
        so that ``sum(density * widths) + zero_weight == 1``.
    zero_weight : float
        Fraction of the area with exactly zero pressure (hard wall).
    moments : dict
        ``mean``, ``variance``, ``third_central`` (pressure, pressure^2,
        pressure^3) of the whole field, computed from the field.
    quantile_levels, quantiles : ndarray, optional
        The empirical quantile function of the field (for a Kolmogorov distance
        at full resolution).
    metadata : dict
        Provenance (parameters, seed, solver tolerance, residual, ...).
    """

    edges: Array
    density: Array
    zero_weight: float = 0.0
    moments: dict = field(default_factory=dict)
    quantile_levels: Optional[Array] = None
    quantiles: Optional[Array] = None
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        edges = np.asarray(self.edges, dtype=float)
        density = np.asarray(self.density, dtype=float)
        if edges.ndim != 1 or density.shape != (edges.size - 1,) or edges.size < 2:
            raise ValueError(f"edges must have one more entry than density; got {edges.shape} and {density.shape}")
        if np.any(np.diff(edges) <= 0) or not np.all(np.isfinite(edges)):
            raise ValueError("edges must be finite and strictly increasing")
        if np.any(density < 0) or not np.all(np.isfinite(density)):
            raise ValueError("density must be finite and >= 0")
        object.__setattr__(self, "edges", edges)
        object.__setattr__(self, "density", density)

    @property
    def centers(self) -> Array:
        """Bin centres (units of pressure)."""
        return 0.5 * (self.edges[1:] + self.edges[:-1])

    @property
    def widths(self) -> Array:
        """Bin widths (units of pressure)."""
        return np.diff(self.edges)

    @property
    def contact_fraction(self) -> float:
        """``1 - zero_weight`` (meaningful for the hard wall)."""
        return 1.0 - float(self.zero_weight)

    def fraction_above(self, threshold: float = 0.0) -> float:
        """Fraction of the field with pressure ``> threshold`` (units of pressure).

        Exact for ``threshold = 0`` (``1 - zero_weight``) and for the
        threshold given to :meth:`from_pressures` (counted on the field);
        otherwise interpolated in the stored quantile function (resolution
        one quantile level, ``1/(len(quantile_levels) - 1)``).
        """
        threshold = float(threshold)
        if not np.isfinite(threshold) or threshold < 0:
            raise ValueError(f"threshold must be a finite number >= 0; got threshold={threshold!r}")
        if threshold == 0.0:
            return 1.0 - float(self.zero_weight)
        if self.moments.get("contact_threshold") == threshold and "contact_fraction" in self.moments:
            return float(self.moments["contact_fraction"])
        if self.quantiles is None or self.quantile_levels is None:
            raise ValueError("this histogram has no stored quantiles; give contact_threshold to from_pressures")
        below = np.searchsorted(self.quantiles, threshold, side="right")
        return float(1.0 - self.quantile_levels[max(int(below) - 1, 0)]) if below > 0 else 1.0

    @classmethod
    def from_pressures(cls, pressure: ArrayLike, *, bins: int | Sequence[float] = 200,
                       p_max: Optional[float] = None, n_quantiles: int = 2049,
                       contact_threshold: Optional[float] = None,
                       metadata: Optional[dict] = None) -> "SimulatedHistogram":
        """Histogram a pressure field.

        Parameters
        ----------
        pressure : array
            Local pressures (units of pressure), any shape, all ``>= 0``.
        bins : int or sequence
            Number of uniform bins on ``(0, p_max]`` or explicit edges.
        p_max : float, optional
            Upper end of the uniform bins (default: the largest pressure).
        n_quantiles : int
            Number of stored quantile levels of the field (>= 2).
        contact_threshold : float, optional
            Also count the fraction of the field with ``p > contact_threshold``
            (stored in ``moments``; see :meth:`fraction_above`).
        """
        if isinstance(bins, (bool, np.bool_)) or (np.ndim(bins) == 0 and not isinstance(bins, (int, np.integer))):
            raise ValueError(f"bins must be an integer >= 1 or a sequence of edges; got bins={bins!r}")
        if np.ndim(bins) == 0 and int(bins) < 1:
            raise ValueError(f"bins must be an integer >= 1 or a sequence of edges; got bins={bins!r}")
        if isinstance(n_quantiles, (bool, np.bool_)) or not isinstance(n_quantiles, (int, np.integer)) \
                or n_quantiles < 2:
            raise ValueError(f"n_quantiles must be an integer >= 2; got n_quantiles={n_quantiles!r}")
        if p_max is not None and (isinstance(p_max, (str, bytes, bool)) or not np.isfinite(p_max) or p_max <= 0):
            raise ValueError(f"p_max must be a finite number > 0; got p_max={p_max!r}")
        values = np.asarray(pressure, dtype=float).ravel()
        if values.size == 0 or not np.all(np.isfinite(values)):
            raise ValueError("pressure must be a non-empty array of finite values")
        if np.any(values < 0):
            raise ValueError(f"pressure must be >= 0; found min {values.min()!r}")
        n = values.size
        zero = values == 0.0
        zero_weight = float(np.count_nonzero(zero)) / n
        positive = values[~zero]
        if np.ndim(bins) == 0:
            top = float(p_max) if p_max is not None else float(positive.max() if positive.size else 1.0)
            edges = np.linspace(0.0, top, int(bins) + 1)
        else:
            edges = np.asarray(bins, dtype=float)
            if edges.ndim != 1 or edges.size < 2 or not np.all(np.isfinite(edges)) or np.any(np.diff(edges) <= 0) \
                    or edges[0] < 0:
                raise ValueError("bins given as edges must be finite, >= 0 and strictly increasing, at least two; "
                                 f"got bins={bins!r}")
        counts, _ = np.histogram(positive, bins=edges)
        density = counts / (n * np.diff(edges))
        mean = float(values.mean())
        centred = values - mean
        moments = {
            "mean": mean,
            "variance": float(np.mean(centred**2)),
            "third_central": float(np.mean(centred**3)),
            "outside_bins": float(positive.size - counts.sum()) / n,
        }
        if contact_threshold is not None:
            threshold = float(contact_threshold)
            if not np.isfinite(threshold) or threshold < 0:
                raise ValueError(f"contact_threshold must be a finite number >= 0; got {contact_threshold!r}")
            moments["contact_threshold"] = threshold
            moments["contact_fraction"] = float(np.count_nonzero(values > threshold)) / n
        levels = np.linspace(0.0, 1.0, n_quantiles)
        quantiles = np.quantile(values, levels)
        return cls(edges, density, zero_weight, moments, levels, quantiles, dict(metadata or {}))

    def rebinned(self, factor: int) -> "SimulatedHistogram":
        """Merge ``factor`` adjacent bins (fewer, less noisy bins)."""
        factor = int(factor)
        if factor < 1:
            raise ValueError(f"factor must be an integer >= 1; got factor={factor!r}")
        n = (self.density.size // factor) * factor
        mass = (self.density * self.widths)[:n].reshape(-1, factor).sum(axis=1)
        edges = self.edges[: n + 1 : factor]
        return SimulatedHistogram(edges, mass / np.diff(edges), self.zero_weight, dict(self.moments),
                                  self.quantile_levels, self.quantiles, dict(self.metadata))


def bin_averaged_density(theory: Any, edges: ArrayLike) -> Array:
    """Average of a theory's continuous density over each bin (1 / pressure).

    Uses the theory's cumulative distribution, so narrow features are
    integrated exactly rather than sampled at bin centres; the ``delta(p)``
    peak is excluded.
    """
    edges = np.asarray(edges, dtype=float)
    cdf = np.asarray(theory.cdf(edges), dtype=float)
    # theory.cdf includes zero_weight for p >= 0; differences cancel it except
    # across p = 0 itself, which no bin here straddles (edges[0] >= 0).
    return np.diff(cdf) / np.diff(edges)


@dataclass(frozen=True)
class Comparison:
    """Distances and moments between a theory and a simulated histogram.

    Attributes
    ----------
    l1 : float
        ``sum |m_theory - m_sim|`` over the bin masses, the ``delta(p)``
        peaks counted in the first bin (0 ... 2, dimensionless); see
        :func:`compare`.
    kolmogorov : float
        ``sup |F_theory - F_sim|`` over ``p >= edges[1]`` (dimensionless).
    moments_theory, moments_sim : dict
        ``mean``, ``variance``, ``third_central`` of both (pressure^k).
    contact_fraction_theory, contact_fraction_sim : float
        Fraction of the area with ``p > contact_threshold`` on both sides:
        ``1 - theory.cdf(threshold)`` and
        :meth:`SimulatedHistogram.fraction_above` (``1 - zero_weight`` each
        for the default threshold 0).
    contact_threshold : float
        The threshold (units of pressure).
    """

    l1: float
    kolmogorov: float
    moments_theory: dict
    moments_sim: dict
    contact_fraction_theory: float
    contact_fraction_sim: float
    contact_threshold: float = 0.0


def compare(theory: Any, hist: SimulatedHistogram, *, contact_threshold: float = 0.0) -> Comparison:
    """Compare a :class:`~diffusion_pr.result.PressureDistribution` with a histogram.

    Both distances are taken at the histogram's resolution: the ``delta(p)``
    peaks (the theory's ``zero_weight`` and the simulation's exactly-zero
    pressures) are counted in the first bin ``[0, edges[1])``.  A soft wall
    has pressures of 1e-300 where a hard wall has 0, and a smooth cutoff
    piles mass up at ``p -> 0+``; neither is distinguishable from ``p = 0``
    below one bin width, so a comparison that separated them would measure
    the convention, not the physics.  The contact fractions are reported
    separately.

    * ``l1 = sum_i |m_theory,i - m_sim,i|`` over bin masses, plus the theory's
      mass beyond the last edge and the simulation's pressures outside the bins.
    * ``kolmogorov = sup |F_theory(p) - F_sim(p)|`` over ``p >= edges[1]``,
      from the stored quantile function when available (both sides of every
      empirical jump), else at the bin edges.
    * contact fractions: the fraction with ``p > contact_threshold`` on both
      sides (0: hard wall; the main job uses ``0.01 p0`` for exponential
      walls, the definition of ``gfmd_ref``'s ``contact_fraction``).
    """
    threshold = float(contact_threshold)
    if not np.isfinite(threshold) or threshold < 0:
        raise ValueError(f"contact_threshold must be a finite number >= 0; got {contact_threshold!r}")
    widths = hist.widths
    m_theory = bin_averaged_density(theory, hist.edges) * widths
    m_sim = hist.density * widths
    m_theory[0] += float(theory.zero_weight)
    m_sim[0] += float(hist.zero_weight)
    beyond = max(0.0, 1.0 - float(theory.cdf(hist.edges[-1])))
    l1 = float(np.sum(np.abs(m_theory - m_sim))) + beyond + float(hist.moments.get("outside_bins", 0.0))
    p_floor = float(hist.edges[1])
    if hist.quantiles is not None and hist.quantile_levels is not None:
        ks = _kolmogorov_from_quantiles(theory, hist.quantiles, hist.quantile_levels, p_floor)
    else:
        f_sim = np.cumsum(m_sim)
        ks = float(np.max(np.abs(np.asarray(theory.cdf(hist.edges[1:])) - f_sim)))
    moments_theory = {
        "mean": theory.mean,
        "variance": theory.moment(2, central=True),
        "third_central": theory.moment(3, central=True),
    }
    a_theory = 1.0 - float(theory.cdf(threshold))
    return Comparison(l1, ks, moments_theory, dict(hist.moments), a_theory, hist.fraction_above(threshold), threshold)


def _kolmogorov_from_quantiles(theory: Any, quantiles: Array, levels: Array, p_floor: float = 0.0) -> float:
    """``sup |F_theory - F_sim|`` over ``p >= p_floor`` from the field's quantiles.

    At each distinct quantile value ``x`` the empirical CDF jumps from about
    the first to the last level whose quantile is ``x`` (ties: the delta peak
    at 0); both sides of the jump are compared with the theory's CDF on the
    same side.  Resolution: one level step, ``1/(len(levels) - 1)``.
    """
    uniq, first = np.unique(quantiles, return_index=True)
    last = np.searchsorted(quantiles, uniq, side="right") - 1
    keep = uniq >= p_floor
    uniq, first, last = uniq[keep], first[keep], last[keep]
    f_after = np.asarray(theory.cdf(uniq), dtype=float)
    f_before = f_after - np.where(uniq == 0.0, float(theory.zero_weight), 0.0)
    before = np.maximum(first - 1, 0)
    k = int(np.searchsorted(quantiles, p_floor, side="right")) - 1
    d_floor = abs(float(theory.cdf(p_floor)) - (float(levels[k]) if k >= 0 else 0.0))
    if uniq.size == 0:
        return d_floor
    return float(max(d_floor, np.max(np.abs(f_after - levels[last])), np.max(np.abs(f_before - levels[before]))))


def kolmogorov_between(first: SimulatedHistogram, second: SimulatedHistogram) -> float:
    """Kolmogorov distance between two simulated fields (e.g. two surface seeds).

    ``sup |F_1 - F_2|`` over ``p >= first.edges[1]`` (the same resolution as
    :func:`compare`), both empirical CDFs interpolated from their stored
    quantile functions.  Used as the realization scatter a theory can be
    expected to reach.
    """
    if first.quantiles is None or second.quantiles is None:
        raise ValueError("both histograms need stored quantiles (SimulatedHistogram.from_pressures keeps them)")
    x = np.union1d(first.quantiles, second.quantiles)
    x = x[x >= first.edges[1]]
    f1 = np.interp(x, first.quantiles, first.quantile_levels, left=0.0, right=1.0)
    f2 = np.interp(x, second.quantiles, second.quantile_levels, left=0.0, right=1.0)
    return float(np.max(np.abs(f1 - f2)))


def log_density_curvature(p: ArrayLike, density: ArrayLike, *, p_lo: float, p_hi: float,
                          weights: Optional[ArrayLike] = None) -> float:
    """Curvature ``d^2 ln Pr / dp^2`` of a quadratic fit on ``[p_lo, p_hi]``.

    For a Gaussian of variance ``V`` this is ``-1/V`` (1 / pressure^2).  The
    paper's claim "the curvature of ln Pr(p) is off by about 20 %" is tested
    with this number (theory and simulation fitted on the same window).

    Parameters
    ----------
    p, density : array
        Points (units of pressure) and density (1 / pressure); non-positive
        densities inside the window are ignored.
    p_lo, p_hi : float
        Fit window (units of pressure).
    weights : array, optional
        Least-squares weights (e.g. sqrt of histogram counts).
    """
    p = np.asarray(p, dtype=float)
    density = np.asarray(density, dtype=float)
    mask = (p >= p_lo) & (p <= p_hi) & (density > 0)
    if np.count_nonzero(mask) < 4:
        raise ValueError(f"fewer than 4 points with positive density in [{p_lo!r}, {p_hi!r}]")
    w = None if weights is None else np.asarray(weights, dtype=float)[mask]
    coeffs = np.polyfit(p[mask], np.log(density[mask]), 2, w=w)
    return float(2.0 * coeffs[0])


def tail_curvatures(theory: Any, hist: SimulatedHistogram, *, decades: float = 2.0,
                    rebin: Optional[int] = None) -> tuple[float, float, tuple[float, float]]:
    """Curvature of ``ln Pr`` on the high-pressure side, simulation and theory.

    The window starts at the mean pressure ``p0`` (taken from the histogram's
    moments) and ends where the simulated density has dropped by ``decades``
    decades below its value at ``p0``: the part of a log plot where the eye
    judges "the curvature of ln Pr(p)".  Both curvatures come from the same
    weighted quadratic fit (:func:`log_density_curvature`, weights
    ``sqrt(simulated bin mass)``) on the same bins, the theory bin-averaged.

    Parameters
    ----------
    theory : PressureDistribution
    hist : SimulatedHistogram
    decades : float
        How far (in decades of density) the window reaches down the tail.
    rebin : int, optional
        Merge this many bins first; default: the coarsest of 4, 2, 1 that
        leaves at least 8 bins in the window.

    Returns
    -------
    (curvature_sim, curvature_theory, (p_lo, p_hi))
        Curvatures in 1 / pressure^2; their ratio is the paper's measure.
    """
    for factor in ([rebin] if rebin is not None else [4, 2, 1]):
        h = hist.rebinned(factor) if factor > 1 else hist
        p0 = float(h.moments.get("mean", np.sum(h.centers * h.density * h.widths)))
        centres = h.centers
        start = int(np.searchsorted(centres, p0))
        ref = h.density[min(start, centres.size - 1)]
        below = np.nonzero(h.density[start:] < ref * 10.0 ** (-decades))[0]
        stop = start + (int(below[0]) if below.size else centres.size - start - 1)
        if stop - start >= 8:
            break
    else:
        raise ValueError(f"fewer than 8 bins between p0={p0!r} and {decades} decades down the tail")
    p_lo, p_hi = float(centres[start]), float(centres[stop])
    w = np.sqrt(h.density * h.widths)
    c_sim = log_density_curvature(centres, h.density, p_lo=p_lo, p_hi=p_hi, weights=w)
    c_th = log_density_curvature(centres, bin_averaged_density(theory, h.edges), p_lo=p_lo, p_hi=p_hi, weights=w)
    return c_sim, c_th, (p_lo, p_hi)


#: In least-squares fits on ln Pr the theory density is floored at this fraction
#: of the histogram's largest density, so that a bin where the theory's
#: Gaussian tail has underflowed costs about ln(1e6)^2 instead of ln(1e-300)^2
#: and cannot dominate the objective.
LOG_FLOOR = 1e-6


@dataclass(frozen=True)
class CutoffFit:
    """Least-squares fit of the cutoff pressure ``p_c``.

    Attributes
    ----------
    p_c : float
        Best cutoff pressure (units of pressure).
    objective : float
        Least-squares objective at the optimum (see :func:`fit_cutoff_pressure`).
    l1 : float
        L1 distance between theory and histogram at the optimum.
    evaluations : int
        Number of theory solves.
    success : bool
        Whether the bounded optimiser converged inside the bracket.
    message : str
    """

    p_c: float
    objective: float
    l1: float
    evaluations: int
    success: bool
    message: str


def fit_cutoff_pressure(hist: SimulatedHistogram, spectrum: Any, *, E_star: float, mean_pressure: float,
                        zeta: float, cutoff: str = "muser", tail: Any = None, p_t: Optional[float] = None,
                        bounds: tuple[float, float] | None = None, log_density: bool = True,
                        backend: str = "native", rtol: float = 1e-5, xatol: float = 1e-3) -> CutoffFit:
    """Fit ``p_c`` of a smoothed cutoff to a simulated histogram by least squares.

    The objective is ``sum_i w_i (y_theory,i - y_sim,i)^2`` over bins with a
    positive simulated density, where ``y`` is ``ln Pr`` (``log_density=True``,
    the paper's Fig. 1 is a log plot, weights ``w_i = counts``-like
    ``Pr_sim * width``) or ``Pr`` itself (weights ``width``).  The theory is
    the second-order cumulant theory of :func:`diffusion_pr.pressure_distribution`
    for the given spectrum (use the surface's own
    :class:`~diffusion_pr.spectra.DiscreteSpectrum`).  The 1-D minimisation is
    a bounded Brent search in ``ln p_c``.  With ``log_density`` the theory's
    density is floored at ``LOG_FLOOR`` times the histogram's maximum.

    Parameters
    ----------
    hist : SimulatedHistogram
    spectrum : spectrum object
    E_star, mean_pressure, zeta : float
        Contact modulus, mean pressure (units of pressure), wall range
        (units of length).
    cutoff : str
        ``"muser"``, ``"raised_cosine"`` or ``"smoothstep"``.
    bounds : (float, float), optional
        Bracket for ``p_c`` (default ``(0.02, 5) * mean_pressure``).
    """
    from scipy.optimize import minimize_scalar

    from ..api import pressure_distribution

    lo, hi = bounds if bounds is not None else (0.02 * mean_pressure, 5.0 * mean_pressure)
    if not (0 < lo < hi):
        raise ValueError(f"bounds must satisfy 0 < lo < hi; got bounds={(lo, hi)!r}")
    mask = hist.density > 0
    width = hist.widths
    floor = LOG_FLOOR * float(hist.density.max())
    calls = {"n": 0}

    def theory_for(p_c: float) -> Any:
        calls["n"] += 1
        return pressure_distribution(spectrum, E_star=E_star, mean_pressure=mean_pressure, zeta=zeta,
                                     cutoff=cutoff, p_c=p_c, tail=tail, p_t=p_t, backend=backend, rtol=rtol)

    def objective(log_pc: float) -> float:
        avg = bin_averaged_density(theory_for(float(np.exp(log_pc))), hist.edges)
        if log_density:
            y_t = np.log(np.maximum(avg[mask], floor))
            y_s = np.log(hist.density[mask])
            w = hist.density[mask] * width[mask]
        else:
            y_t, y_s, w = avg[mask], hist.density[mask], width[mask]
        return float(np.sum(w * (y_t - y_s) ** 2))

    res = minimize_scalar(objective, bounds=(np.log(lo), np.log(hi)), method="bounded",
                          options={"xatol": xatol})
    p_c = float(np.exp(res.x))
    at_edge = min(abs(res.x - np.log(lo)), abs(res.x - np.log(hi))) < 10 * xatol
    l1 = compare(theory_for(p_c), hist).l1
    msg = str(res.message) + ("; optimum at the bracket edge" if at_edge else "")
    return CutoffFit(p_c, float(res.fun), l1, calls["n"], bool(res.success) and not at_edge, msg)


def fit_tail_pressure(hist: SimulatedHistogram, spectrum: Any, *, E_star: float, mean_pressure: float,
                      zeta: float = 0.0, cutoff: str = "sharp", p_c: Optional[float] = None,
                      tail: str = "linear", bounds: tuple[float, float] | None = None,
                      backend: str = "native", rtol: float = 1e-5) -> tuple[float, float]:
    """Fit the crossover pressure ``p_t`` of an exponential-tail variant.

    Least squares on ``ln Pr`` over bins with positive simulated density,
    weighted by the simulated bin mass. Returns ``(p_t, objective)``.
    """
    from scipy.optimize import minimize_scalar

    from ..api import pressure_distribution

    lo, hi = bounds if bounds is not None else (0.05 * mean_pressure, 1e3 * mean_pressure)
    mask = hist.density > 0
    w = hist.density[mask] * hist.widths[mask]
    floor = LOG_FLOOR * float(hist.density.max())

    def objective(log_pt: float) -> float:
        th = pressure_distribution(spectrum, E_star=E_star, mean_pressure=mean_pressure, zeta=zeta,
                                   cutoff=cutoff, p_c=p_c, tail=tail, p_t=float(np.exp(log_pt)),
                                   backend=backend, rtol=rtol)
        avg = bin_averaged_density(th, hist.edges)
        return float(np.sum(w * (np.log(np.maximum(avg[mask], floor)) - np.log(hist.density[mask])) ** 2))

    res = minimize_scalar(objective, bounds=(np.log(lo), np.log(hi)), method="bounded", options={"xatol": 1e-3})
    return float(np.exp(res.x)), float(res.fun)


# ============================================================================ ensembles
# Theory against a GFMD ensemble (many seeds). Records are duck-typed: anything with
# ``levels``, ``quantiles`` (pressures at ``levels``), ``seed``, ``mean_pressure``,
# ``contact_fraction``, ``contact_threshold``, ``mean``, ``variance``, ``third_central``,
# ``converged`` (gfmd_ref.ensemble_store.EnsembleRecord has them); diffusion_pr does not
# import gfmd_ref.


def _record_cdf(rec: Any, p: Array) -> Array:
    """Empirical CDF of one record, linear between its quantiles, right-continuous at ties."""
    q = np.asarray(rec.quantiles, dtype=float)
    lev = np.asarray(rec.levels, dtype=float)
    idx = np.searchsorted(q, p, side="right")
    lo = np.clip(idx - 1, 0, q.size - 1)
    hi = np.clip(idx, 0, q.size - 1)
    ql, qh = q[lo], q[hi]
    gap = np.where(qh > ql, qh - ql, 1.0)
    t = np.where(qh > ql, (p - ql) / gap, 0.0)
    out = lev[lo] + np.clip(t, 0.0, 1.0) * (lev[hi] - lev[lo])
    return np.where(p < q[0], 0.0, np.where(p >= q[-1], 1.0, out))


def _theory_moments(theory: Any, p_hi: float) -> tuple[float, float, float]:
    """Mean, variance, third central moment of a theory (its own ``moment`` if it has
    one, else from its CDF on a fine grid up to the pressure where ``F = 1 - 1e-9``)."""
    if hasattr(theory, "moment") and hasattr(theory, "mean"):
        return (float(theory.mean), float(theory.moment(2, central=True)), float(theory.moment(3, central=True)))
    top = float(p_hi)
    while float(np.asarray(theory.cdf(top))) < 1.0 - 1e-9 and top < 1e6 * p_hi:
        top *= 2.0
    x = np.linspace(0.0, top, 200001)
    F = np.asarray(theory.cdf(x), dtype=float)
    m = np.diff(np.concatenate(([0.0], F)))
    c = np.concatenate(([0.0], 0.5 * (x[1:] + x[:-1])))
    mean = float(np.sum(m * c))
    return mean, float(np.sum(m * (c - mean) ** 2)), float(np.sum(m * (c - mean) ** 3))


@dataclass(frozen=True)
class EnsembleComparison:
    """A theory against a pooled GFMD ensemble, with the ensemble's own noise.

    Attributes
    ----------
    kolmogorov : float
        ``K = sup |F_theory - F_pool|`` over ``p >= p_min`` (dimensionless); the pool
        gives every seed the same area.
    kolmogorov_ci : (float, float)
        2.5 and 97.5 percentiles of ``K`` against bootstrap pools (seeds resampled).
    noise_bootstrap : float
        Median of ``sup |F_boot - F_pool|`` over bootstrap pools: the typical distance
        of the pool from the infinite-ensemble distribution. A theory with ``K`` at or
        below this is as close as the ensemble can tell.
    noise_split : float
        Mean over random splits of ``sup |F_A - F_B| / 2`` for two disjoint halves
        (each half has the noise of the pool times ``sqrt 2``; their distance adds
        the two in quadrature: ``2 x`` the pool's noise).
    kolmogorov_per_seed : ndarray
        ``K`` of the theory against each seed alone (the realization scatter).
    l1, l1_noise : float
        ``sum |m_theory - m_pool|`` over the bin masses of ``edges`` (first bin from 0
        with the delta peaks, last bin open to infinity) and its bootstrap median noise.
    contact_fraction_theory, contact_fraction_gfmd, contact_fraction_gfmd_sd : float
        One definition for both: ``P(p > threshold)`` with GFMD's ``threshold``
        (0 for the hard wall, ``0.01 p0`` for exponential walls); the GFMD value is
        the mean over seeds, ``_sd`` the seed-to-seed standard deviation.
    sd_theory, sd_gfmd, sd_gfmd_sd, skewness_theory, skewness_gfmd, skewness_gfmd_sd : float
        Standard deviation (pressure units) and skewness; GFMD: mean and
        seed-to-seed sd of the per-seed values. ``sd_pool``/``skewness_pool`` are
        those of the pooled distribution.
    p, cdf_theory, cdf_pool, cdf_lo, cdf_hi : ndarray
        For plots: pressures ``>= p_min`` (at most 2000), the theory's and the pooled
        CDF there, and the pool's 95 % bootstrap band.
    """

    kolmogorov: float
    kolmogorov_ci: tuple
    noise_bootstrap: float
    noise_split: float
    kolmogorov_per_seed: Array
    l1: float
    l1_noise: float
    p_min: float
    edges: Array
    n_seeds: int
    n_excluded: int
    seeds: tuple
    threshold: float
    contact_fraction_theory: float
    contact_fraction_gfmd: float
    contact_fraction_gfmd_sd: float
    sd_theory: float
    sd_gfmd: float
    sd_gfmd_sd: float
    sd_pool: float
    skewness_theory: float
    skewness_gfmd: float
    skewness_gfmd_sd: float
    skewness_pool: float
    p: Array = field(default_factory=lambda: np.zeros(0))
    cdf_theory: Array = field(default_factory=lambda: np.zeros(0))
    cdf_pool: Array = field(default_factory=lambda: np.zeros(0))
    cdf_lo: Array = field(default_factory=lambda: np.zeros(0))
    cdf_hi: Array = field(default_factory=lambda: np.zeros(0))

    def __repr__(self) -> str:  # the report, not the arrays
        return "EnsembleComparison(\n  " + self.summary().replace("\n", "\n  ") + "\n)"

    def summary(self) -> str:
        """Multi-line text report."""
        ps = self.kolmogorov_per_seed
        return "\n".join([
            f"K over p >= {self.p_min:.4g}: {self.kolmogorov:.4f} (95% bootstrap {self.kolmogorov_ci[0]:.4f}-"
            f"{self.kolmogorov_ci[1]:.4f}); ensemble noise {self.noise_bootstrap:.4f} (bootstrap), "
            f"{self.noise_split:.4f} (split halves); {self.n_seeds} seeds ({self.n_excluded} not converged, excluded)",
            f"per-seed K: median {np.median(ps):.4f}, 5-95% {np.percentile(ps, 5):.4f}-{np.percentile(ps, 95):.4f}",
            f"L1 of bin masses: {self.l1:.4f} (noise {self.l1_noise:.4f})",
            f"contact fraction (p > {self.threshold:.3g}): theory {self.contact_fraction_theory:.4f}, "
            f"GFMD {self.contact_fraction_gfmd:.4f} +- {self.contact_fraction_gfmd_sd:.4f} (seed sd)",
            f"sd: theory {self.sd_theory:.4g}, GFMD {self.sd_gfmd:.4g} +- {self.sd_gfmd_sd:.2g} (pool {self.sd_pool:.4g})",
            f"skewness: theory {self.skewness_theory:.3f}, GFMD {self.skewness_gfmd:.3f} +- "
            f"{self.skewness_gfmd_sd:.3f} (pool {self.skewness_pool:.3f})",
        ])


def compare_ensemble(theory: Any, records_or_group: Any, *, p_min: Optional[float] = None,
                     edges: Optional[ArrayLike] = None, n_boot: int = 400, n_split: int = 200,
                     seed: int = 0) -> EnsembleComparison:
    """Compare a theory with a pooled GFMD ensemble, with the ensemble's noise beside it.

    Parameters
    ----------
    theory : PressureDistribution or any object with ``cdf(p)``
        ``cdf`` includes the delta peak at ``p = 0``. Moments come from
        ``theory.moment`` when present, else from the CDF.
    records_or_group : group or sequence of records
        One pool: one wall, load and grid (e.g. ``bundled_ensemble("fig1_n1024")
        .group(0.25)`` or the list of its ``records``). Non-converged records are
        excluded and counted.
    p_min : float, optional
        Lower end of the Kolmogorov supremum. **Convention: K is taken over
        p >= p0/20** (the default, ``p0`` the records' mean pressure): below it a
        comparison would weigh how the hard-wall delta peak and the soft walls' tiny
        pressures are split, a convention rather than physics.
    edges : array, optional
        Bin edges for the L1 of bin masses (default 50 uniform bins on
        ``[0, pooled 99.9 % quantile]``, plus the open bin above).
    n_boot, n_split : int
        Bootstrap resamples of seeds and random half splits.
    seed : int
        Random seed of the resampling.

    Returns
    -------
    EnsembleComparison
        Distances are dimensionless; sd in pressure units.
    """
    recs_all = list(getattr(records_or_group, "records", records_or_group))
    recs_all += list(getattr(records_or_group, "excluded", ()))
    recs = [r for r in recs_all if bool(getattr(r, "converged", True))]
    n_excl = len(recs_all) - len(recs)
    if len(recs) < 2:
        raise ValueError(f"records_or_group must hold at least 2 converged records; got {len(recs)} "
                         f"({n_excl} not converged)")
    p0 = float(recs[0].mean_pressure)
    if any(abs(float(r.mean_pressure) - p0) > 1e-12 * p0 for r in recs):
        raise ValueError("records_or_group mixes mean pressures: compare one pool (one wall, load, grid)")
    zetas = {getattr(r, "zeta", None) for r in recs}
    ns = {getattr(r, "n", None) for r in recs}
    if len(zetas) > 1 or len(ns) > 1:
        raise ValueError(f"records_or_group mixes walls {zetas} or grids {ns}: compare one pool")
    p_min = p0 / 20.0 if p_min is None else float(p_min)
    if not (np.isfinite(p_min) and p_min >= 0):
        raise ValueError(f"p_min must be a finite pressure >= 0; got {p_min!r}")
    S = len(recs)
    x = np.unique(np.concatenate([np.asarray(r.quantiles, float) for r in recs] + [[p_min]]))
    x = x[x >= p_min]
    if x.size > 40000:
        x = x[np.linspace(0, x.size - 1, 40000).astype(int)]
    C = np.array([_record_cdf(r, x) for r in recs])
    T = np.asarray(theory.cdf(x), dtype=float)
    F = C.mean(axis=0)
    K = float(np.max(np.abs(T - F)))
    per_seed = np.max(np.abs(C - T), axis=1)
    rng = np.random.default_rng(seed)
    boot_idx = [rng.integers(0, S, S) for _ in range(n_boot)]
    pools = np.array([C[i].mean(0) for i in boot_idx])
    k_boot = np.max(np.abs(T - pools), axis=1)
    noise_b = float(np.median(np.max(np.abs(pools - F), axis=1)))
    sub = np.unique(np.linspace(0, x.size - 1, min(2000, x.size)).astype(int))
    band = np.percentile(pools[:, sub], [2.5, 97.5], axis=0)
    h = S // 2
    splits = []
    for _ in range(n_split):
        perm = rng.permutation(S)
        splits.append(np.max(np.abs(C[perm[:h]].mean(0) - C[perm[h:2 * h]].mean(0))) / 2.0)
    # bins
    if edges is None:
        top = float(np.mean([np.interp(0.999, r.levels, r.quantiles) for r in recs]))
        edges_arr = np.linspace(0.0, top, 51)
    else:
        edges_arr = np.asarray(edges, dtype=float)
        if edges_arr.ndim != 1 or edges_arr.size < 2 or np.any(np.diff(edges_arr) <= 0) or edges_arr[0] < 0:
            raise ValueError("edges must be increasing pressures >= 0 (at least 2)")
    Ce = np.array([_record_cdf(r, edges_arr) for r in recs])
    Ce[:, 0] = 0.0  # first bin starts at 0 and holds the delta peak
    Me = np.concatenate([np.diff(Ce, axis=1), 1.0 - Ce[:, -1:]], axis=1)
    Te = np.asarray(theory.cdf(edges_arr), dtype=float)
    Te[0] = 0.0
    Mt = np.concatenate([np.diff(Te), [1.0 - Te[-1]]])
    Mp = Me.mean(0)
    l1 = float(np.sum(np.abs(Mt - Mp)))
    l1_noise = float(np.median([np.sum(np.abs(Me[i].mean(0) - Mp)) for i in boot_idx]))
    # contact fraction, sd, skewness
    thr = float(getattr(recs[0], "contact_threshold", 0.0))
    cf_t = float(1.0 - np.asarray(theory.cdf(thr)))
    cf = np.array([float(r.contact_fraction) for r in recs])
    mean_s = np.array([float(r.mean) for r in recs])
    var_s = np.array([float(r.variance) for r in recs])
    th_s = np.array([float(r.third_central) for r in recs])
    sd_s = np.sqrt(var_s)
    sk_s = th_s / np.maximum(sd_s, 1e-300) ** 3
    m = mean_s.mean()
    var_p = float(np.mean(var_s + (mean_s - m) ** 2))
    th_p = float(np.mean(th_s + 3 * var_s * (mean_s - m) + (mean_s - m) ** 3))
    tm, tv, tt = _theory_moments(theory, float(np.max([r.quantiles[-1] for r in recs])))
    sd_t = float(np.sqrt(max(tv, 0.0)))
    return EnsembleComparison(
        kolmogorov=K, kolmogorov_ci=(float(np.percentile(k_boot, 2.5)), float(np.percentile(k_boot, 97.5))),
        noise_bootstrap=noise_b, noise_split=float(np.mean(splits)), kolmogorov_per_seed=per_seed,
        l1=l1, l1_noise=l1_noise, p_min=p_min, edges=edges_arr, n_seeds=S, n_excluded=n_excl,
        seeds=tuple(int(getattr(r, "seed", -1)) for r in recs), threshold=thr,
        contact_fraction_theory=cf_t, contact_fraction_gfmd=float(cf.mean()),
        contact_fraction_gfmd_sd=float(cf.std(ddof=1)),
        sd_theory=sd_t, sd_gfmd=float(sd_s.mean()), sd_gfmd_sd=float(sd_s.std(ddof=1)), sd_pool=float(np.sqrt(var_p)),
        skewness_theory=float(tt / sd_t**3) if sd_t > 0 else 0.0, skewness_gfmd=float(sk_s.mean()),
        skewness_gfmd_sd=float(sk_s.std(ddof=1)), skewness_pool=float(th_p / var_p**1.5) if var_p > 0 else 0.0,
        p=x[sub], cdf_theory=T[sub], cdf_pool=F[sub], cdf_lo=band[0], cdf_hi=band[1],
    )
