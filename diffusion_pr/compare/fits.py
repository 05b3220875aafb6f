"""Shapes and fits of a theory against a histogram: the curvature of ``ln Pr`` in the tail (:func:`tail_curvatures`) and
least-squares fits of the paper's cutoff and tail pressures (:func:`fit_cutoff_pressure`, :func:`fit_tail_pressure`).

Pressures in any unit shared by theory and simulation."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
from numpy.typing import ArrayLike

from .distances import SimulatedHistogram, bin_averaged_density, compare


def log_density_curvature(p: ArrayLike, density: ArrayLike, *, p_lo: float, p_hi: float,
                          weights: Optional[ArrayLike] = None) -> float:
    """Curvature ``d^2 ln Pr / dp^2`` of a quadratic fit on ``[p_lo, p_hi]``.

    For a Gaussian of variance ``V`` this is ``-1/V`` (1 / pressure^2).  The paper's claim "the curvature of ln Pr(p) is
    off by about 20 %" is tested with this number (theory and simulation fitted on the same window).

    Parameters
    ----------
    p, density : array
        Points (units of pressure) and density (1 / pressure); non-positive densities inside the window are ignored.
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

    The window starts at the mean pressure ``p0`` (taken from the histogram's moments) and ends where the simulated
    density has dropped by ``decades`` decades below its value at ``p0``: the part of a log plot where the eye judges
    "the curvature of ln Pr(p)".  Both curvatures come from the same weighted quadratic fit
    (:func:`log_density_curvature`, weights ``sqrt(simulated bin mass)``) on the same bins, the theory bin-averaged.

    Parameters
    ----------
    theory : PressureDistribution
    hist : SimulatedHistogram
    decades : float
        How far (in decades of density) the window reaches down the tail.
    rebin : int, optional
        Merge this many bins first; default: the coarsest of 4, 2, 1 that leaves at least 8 bins in the window.

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


#: floor of the theory density in fits on ln Pr, relative to the histogram's largest density (an underflowed
#: Gaussian tail would otherwise dominate the objective)
LOG_FLOOR = 1e-6


@dataclass(frozen=True)
class CutoffFit:
    """Least-squares fit of the cutoff pressure: the best ``p_c`` (units of pressure), the ``objective`` there
    (:func:`fit_cutoff_pressure`), the ``l1`` distance of theory and histogram there, the number of theory solves
    (``evaluations``), ``success`` (the bounded optimiser converged inside the bracket) and its ``message``."""

    p_c: float
    objective: float
    l1: float
    evaluations: int
    success: bool
    message: str


def _fit_log_density(hist: SimulatedHistogram, theory_at: Any, bounds: tuple[float, float], xatol: float) -> Any:
    """Bounded Brent search in ``ln x`` over ``bounds`` (pressure) for the least squares
    ``sum_i w_i (ln Pr_theory,i - ln Pr_sim,i)^2`` over the bins with a positive simulated density, weights the
    simulated bin masses, the bin-averaged density of ``theory_at(x)`` floored at :data:`LOG_FLOOR` times the
    histogram's largest density; returns scipy's ``OptimizeResult``."""
    from scipy.optimize import minimize_scalar

    lo, hi = bounds
    if not (0 < lo < hi):
        raise ValueError(f"bounds must satisfy 0 < lo < hi; got bounds={(lo, hi)!r}")
    mask = hist.density > 0
    w, y_sim = hist.density[mask] * hist.widths[mask], np.log(hist.density[mask])
    floor = LOG_FLOOR * float(hist.density.max())

    def objective(log_x: float) -> float:
        avg = bin_averaged_density(theory_at(float(np.exp(log_x))), hist.edges)
        return float(np.sum(w * (np.log(np.maximum(avg[mask], floor)) - y_sim) ** 2))

    return minimize_scalar(objective, bounds=(np.log(lo), np.log(hi)), method="bounded", options={"xatol": xatol})


def fit_cutoff_pressure(hist: SimulatedHistogram, spectrum: Any, *, E_star: float, mean_pressure: float,
                        zeta: float, cutoff: str = "muser", tail: Any = None, p_t: Optional[float] = None,
                        bounds: tuple[float, float] | None = None, backend: str = "native", rtol: float = 1e-5,
                        xatol: float = 1e-3) -> CutoffFit:
    """Fit ``p_c`` of a smoothed cutoff to a simulated histogram by least squares on ``ln Pr`` (the paper's
    Fig. 1 is a log plot).

    The objective is ``sum_i w_i (ln Pr_theory,i - ln Pr_sim,i)^2`` over the bins with a positive simulated density,
    weights the simulated bin masses, the theory's density floored at :data:`LOG_FLOOR` times the histogram's maximum.
    The theory is :func:`diffusion_pr.pressure_distribution` for the given spectrum (use the surface's own
    :class:`~diffusion_pr.spectra.DiscreteSpectrum`); a bounded Brent search in ``ln p_c`` to ``xatol``.

    Parameters
    ----------
    hist : SimulatedHistogram
    spectrum : Spectrum
    E_star, mean_pressure, zeta : float
        Contact modulus, mean pressure (units of pressure), wall range (units of length).
    cutoff : str
        ``"muser"``, ``"raised_cosine"`` or ``"smoothstep"``; ``tail``, ``p_t``, ``backend``, ``rtol`` go to
        :func:`~diffusion_pr.pressure_distribution`.
    bounds : (float, float), optional
        Bracket for ``p_c`` (default ``(0.02, 5) * mean_pressure``).
    """
    from ..api import pressure_distribution

    calls = {"n": 0}

    def theory_for(p_c: float) -> Any:
        calls["n"] += 1
        return pressure_distribution(spectrum, E_star=E_star, mean_pressure=mean_pressure, zeta=zeta,
                                     cutoff=cutoff, p_c=p_c, tail=tail, p_t=p_t, backend=backend, rtol=rtol,
                                     closure="second_order")

    lo, hi = bounds if bounds is not None else (0.02 * mean_pressure, 5.0 * mean_pressure)
    res = _fit_log_density(hist, theory_for, (lo, hi), xatol)
    p_c = float(np.exp(res.x))
    at_edge = min(abs(res.x - np.log(lo)), abs(res.x - np.log(hi))) < 10 * xatol
    l1 = compare(theory_for(p_c), hist).l1
    msg = str(res.message) + ("; optimum at the bracket edge" if at_edge else "")
    return CutoffFit(p_c, float(res.fun), l1, calls["n"], bool(res.success) and not at_edge, msg)


def fit_tail_pressure(hist: SimulatedHistogram, spectrum: Any, *, E_star: float, mean_pressure: float,
                      zeta: float = 0.0, cutoff: str = "sharp", p_c: Optional[float] = None,
                      tail: str = "linear", bounds: tuple[float, float] | None = None,
                      backend: str = "native", rtol: float = 1e-5) -> tuple[float, float]:
    """Fit the crossover pressure ``p_t`` of an exponential-tail variant by the least squares of
    :func:`fit_cutoff_pressure` (bracket default ``(0.05, 1000) * mean_pressure``); returns ``(p_t, objective)``."""
    from ..api import pressure_distribution

    def theory_for(p_t: float) -> Any:
        return pressure_distribution(spectrum, E_star=E_star, mean_pressure=mean_pressure, zeta=zeta, cutoff=cutoff,
                                     p_c=p_c, tail=tail, p_t=p_t, backend=backend, rtol=rtol, closure="second_order")

    res = _fit_log_density(hist, theory_for, bounds or (0.05 * mean_pressure, 1e3 * mean_pressure), 1e-3)
    return float(np.exp(res.x)), float(res.fun)
