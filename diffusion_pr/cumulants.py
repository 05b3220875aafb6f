r"""Second-order cumulant results: ``G1(q)``, the stress variance and ``D(eta)``.

For a linear-elastic half-space of contact modulus ``E*`` against a rigid rough surface with exponential repulsion of
range ``zeta`` at mean pressure ``p0``, the second-order cumulant expansion gives the linear response
``u~(q) = G1(q) h~(q)`` with (M. H. Müser, Phys. Rev. Lett. 100, 055504 (2008), Eq. 10,
doi:10.1103/PhysRevLett.100.055504)::

    G1(q) = 1 / (1 + zeta q E* / (2 p0)),

and, since ``sigma~(q) = (q E*/2) u~(q)`` (Eq. 3), the stress variance::

    V(zeta) = sum_q (q E*/2)^2 |G1(q)|^2 <|h~(q)|^2>
            -> (E*/2)^2 2 pi \int q^3 C(q) |G1(q)|^2 dq       (continuum).

``zeta = 0`` gives Persson's full-contact variance ``V0 = (E*/2)^2 gbar^2`` (B. N. J. Persson, J. Chem. Phys. 115,
3840 (2001), doi:10.1063/1.1388626).

Magnification ``eta = q / q_min``: ``V(eta)`` accumulates the modes with ``|q| <= eta q_min`` and
``D(eta) = (1/2) dV/deta`` is the diffusivity of the magnification-dependent Fokker-Planck equation (docs/theory.md).

Units: ``E_star`` and ``mean_pressure`` in one pressure unit, ``zeta`` and wavelengths in one length unit;
variances come out in pressure^2."""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from ._validation import check_finite_array, check_nonnegative, check_positive
from .spectra import DiscreteSpectrum, Spectrum

__all__ = ["G1", "stress_variance", "variance_vs_magnification", "diffusivity_vs_magnification"]


def _check_spectrum(spectrum: Spectrum) -> Spectrum:
    if not isinstance(spectrum, Spectrum):
        raise ValueError("spectrum must be a diffusion_pr.spectra.Spectrum (SelfAffineSpectrum or DiscreteSpectrum); "
                         f"got {type(spectrum).__name__}")
    return spectrum


def _check_magnification_inputs(spectrum: Spectrum, eta: ArrayLike, E_star: float, mean_pressure: float,
                                zeta: ArrayLike) -> tuple[np.ndarray, float, float, float]:
    """Checked ``eta`` (array), ``E*``, ``p0`` and scalar ``zeta`` of the ``*_vs_magnification`` functions."""
    _check_spectrum(spectrum)
    E = check_positive("E_star", E_star)
    p0 = check_positive("mean_pressure", mean_pressure)
    z = check_nonnegative("zeta", zeta)
    if np.ndim(z) != 0:
        raise ValueError(f"zeta must be a scalar here (vectorize over eta); got an array of shape {np.shape(z)}")
    return check_finite_array("eta", eta, min_size=0), E, p0, float(z)


def G1(q: ArrayLike, *, zeta: ArrayLike, E_star: float, mean_pressure: float) -> np.ndarray | float:
    """Leading response coefficient ``G1(q) = 1 / (1 + zeta q E* / (2 p0))`` (Müser 2008, Eq. 10), in (0, 1].

    ``q`` [rad/length] >= 0 and ``zeta`` [length] >= 0 broadcast together; ``E_star`` (``E/(1 - nu^2)``) and
    ``mean_pressure`` [pressure] > 0."""
    qa = check_nonnegative("q", q)
    za = check_nonnegative("zeta", zeta)
    E = check_positive("E_star", E_star)
    p0 = check_positive("mean_pressure", mean_pressure)
    g = 1.0 / (1.0 + np.multiply(za, qa) * (E / (2.0 * p0)))
    return float(g) if np.ndim(g) == 0 else g


def stress_variance(spectrum: Spectrum, *, E_star: float, mean_pressure: float,
                    zeta: ArrayLike = 0.0) -> np.ndarray | float:
    r"""Second-order cumulant stress variance ``V = <Delta sigma^2>`` [pressure^2].

    ``V = (E*/2)^2 sum_q q^2 |G1(q)|^2 |h~(q)|^2`` for a :class:`~diffusion_pr.spectra.DiscreteSpectrum` (exact sum over
    its modes) and ``(E*/2)^2 2 pi \int q^3 C(q) |G1(q)|^2 dq`` for a continuum spectrum (Gauss-Legendre in ``ln q``,
    relative error ~1e-14). ``zeta = 0`` is Persson's ``V0 = (E*/2)^2 gbar^2``; ``V`` decreases monotonically with
    ``zeta`` and behaves as ``p0^2 h_rms^2 / zeta^2`` for ``zeta q_max E* >> p0``.

    ``E_star`` [pressure] > 0; ``mean_pressure`` [pressure] > 0 and ``zeta`` [the spectrum's length unit] >= 0
    broadcast together (one matrix product over all values); ``V`` has their broadcast shape (a float for
    scalars).  An ``E_star`` so large that ``V`` overflows is a ``ValueError`` naming it."""
    _check_spectrum(spectrum)
    E = check_positive("E_star", E_star)
    p0 = check_positive("mean_pressure", mean_pressure)
    z = np.asarray(check_nonnegative("zeta", zeta), dtype=float)
    if np.ndim(E) != 0:
        raise ValueError(f"E_star must be a scalar (pressure); got an array of shape {np.shape(E)}")
    z, p0 = np.broadcast_arrays(z, np.asarray(p0, dtype=float))  # vectorized over zeta and mean_pressure
    q, w = spectrum.quadrature()
    base = w * (q * q) * (0.25 * E * E)
    zk = (z * (E / (2.0 * p0))).ravel()
    v = np.empty(zk.size)
    # blocks of <= 2^16 matrix entries keep the temporaries in cache (large discrete spectra)
    step = max(1, (1 << 16) // max(q.size, 1))
    for i in range(0, zk.size, step):
        g = np.multiply.outer(zk[i : i + step], q)
        g += 1.0
        np.reciprocal(g, out=g)
        g *= g
        v[i : i + step] = g @ base
    if np.isinf(v).any():
        raise ValueError(f"E_star={E!r} with this spectrum's rms slope {spectrum.rms_slope:.4g} overflows the stress "
                         "variance (E*/2)^2 gbar^2 (float64 ends at 1.8e308): give pressures in a unit where E_star "
                         "is of order 1")
    return float(v[0]) if z.ndim == 0 else v.reshape(z.shape)


def variance_vs_magnification(spectrum: Spectrum, eta: ArrayLike, *, E_star: float, mean_pressure: float,
                              zeta: float = 0.0) -> np.ndarray | float:
    r"""Variance ``V(eta)`` [pressure^2] accumulated from modes with ``|q| <= eta q_min``.

    Continuum: ``V(eta) = (E*/2)^2 2 pi \int_{q_min}^{min(eta, eta_max) q_min} q^3 C |G1|^2 dq``, 0 for ``eta <= 1``.
    Discrete: the staircase sum over shells with ``|q| <= eta q_min`` (inclusive; ``V(1)`` already holds the lowest
    shell). ``V(eta_max = q_max/q_min)`` equals :func:`stress_variance`.

    ``eta`` (``q / q_min``, dimensionless) of any shape, the result of its shape; ``E_star`` and ``mean_pressure``
    [pressure] > 0; ``zeta`` [length] >= 0, a scalar."""
    ea, E, p0, z = _check_magnification_inputs(spectrum, eta, E_star, mean_pressure, zeta)
    k = z * E / (2.0 * p0)

    def weight(q: np.ndarray) -> np.ndarray:
        g = 1.0 / (1.0 + k * q)
        return (0.25 * E * E) * q * q * g * g

    return spectrum.cumulative(weight, ea * spectrum.q_min)


def diffusivity_vs_magnification(spectrum: Spectrum, eta: ArrayLike, *, E_star: float, mean_pressure: float,
                                 zeta: float = 0.0, bins: ArrayLike | None = None) -> np.ndarray | float:
    r"""Magnification diffusivity ``D(eta) = (1/2) dV/deta`` [pressure^2].

    Continuum (exact derivative of :func:`variance_vs_magnification`), with ``q = eta q_min``::

        D(eta) = (1/2) (E*/2)^2 2 pi q^3 C(q) |G1(q)|^2 q_min   for 1 <= eta <= q_max/q_min,

    and 0 outside (``C`` vanishes there), so ``\int_1^{eta_max} D deta = V/2``.

    Discrete spectra: ``dV/deta`` is a sum of delta functions at the shells ``eta_k = |q_k|/q_min``. This function then
    returns the *binned* diffusivity ``D_j = [V(e_{j+1}) - V(e_j)] / (2 (e_{j+1} - e_j))`` on bins ``(e_j, e_{j+1}]``
    (right-closed; 0 outside the bins), whose integral over any union of bins is exactly half the variance of the shells
    in it. Default bins: unit width in ``eta`` centred on the integers, ``e = 0.5, 1.5, 2.5, ...`` (annuli of width
    ``q_min``, the usual radial average; with ``q_min = 2 pi/L`` no lattice shell lies on an edge). The
    staircase itself is :func:`variance_vs_magnification`.

    Arguments as :func:`variance_vs_magnification`; ``bins``: strictly increasing edges in ``eta`` (discrete
    spectra only).  ``D`` [pressure^2 per unit magnification] has the shape of ``eta``."""
    ea, E, p0, z = _check_magnification_inputs(spectrum, eta, E_star, mean_pressure, zeta)
    qmin = spectrum.q_min
    if isinstance(spectrum, DiscreteSpectrum):
        edges = (np.arange(0.5, spectrum.q_max / qmin + 1.0, 1.0) if bins is None
                 else check_finite_array("bins", bins, ndim=1, min_size=2))
        if np.any(np.diff(edges) <= 0):
            raise ValueError("bins must be strictly increasing edges in eta")
        v_edges = np.asarray(variance_vs_magnification(spectrum, edges, E_star=E, mean_pressure=p0, zeta=z))
        d_bins = 0.5 * np.diff(v_edges) / np.diff(edges)
        j = np.searchsorted(edges, ea, side="left") - 1  # eta in (e_j, e_{j+1}]
        inside = (j >= 0) & (j < d_bins.size)
        out = np.where(inside, d_bins[np.clip(j, 0, d_bins.size - 1)], 0.0)
        return float(out) if out.ndim == 0 else out
    if bins is not None:
        raise ValueError("bins applies to discrete spectra only; the continuum D(eta) is exact")
    q = ea * qmin
    c = np.asarray(spectrum.psd(q), dtype=float)
    g = 1.0 / (1.0 + (z * E / (2.0 * p0)) * q)
    out = 0.5 * (0.25 * E * E) * 2.0 * math.pi * q**3 * c * g * g * qmin
    return float(out) if out.ndim == 0 else out
