r"""Spectra from measured data: height maps (periodic or not), tabulated PSDs, SurfaceTopography objects.

Conventions: the package's (Persson's) isotropic PSD ``C(q)`` [length^4] with ``h_rms^2 = 2 pi int q C dq``
(:mod:`diffusion_pr.spectra`).  SurfaceTopography and contact.engineering use ``C_iso = (2 pi)^2 C`` and the 1D
(profile) PSD ``C_1D`` [length^3] with ``h_rms^2 = (1/pi) int_0^inf C_1D dq`` (T. D. B. Jacobs, T. Junge,
L. Pastewka, Surf. Topogr. Metrol. Prop. 5, 013001 (2017), doi:10.1088/2051-672X/aa51f8).

Every spectrum made here warns (:class:`ResolutionWarning`) where more than half of ``gbar^2`` comes from the
data's top octave of wavenumbers (maps: wavelengths below 4 pixels): the rms slope, hence the contact area, is then
set by the data's resolution; cut with ``q_max`` where the data stop being reliable."""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
from numpy.typing import ArrayLike

from ._validation import check_finite_array, check_in_range, check_positive
from .spectra import DiscreteSpectrum, SegmentedSpectrum, Spectrum, _periods, _read_only

__all__ = ["TabulatedSpectrum", "ResolutionWarning", "spectrum_from_map", "spectrum_from_psd",
           "spectrum_from_topography"]


class ResolutionWarning(UserWarning):
    """The data's shortest wavelengths carry most of the rms slope."""


def _check_resolution(spectrum: Spectrum, q_top: float) -> Spectrum:
    """Warn if more than half of ``gbar^2`` lies above ``q_top`` [rad/length]; return ``spectrum``."""
    share = 1.0 - float(spectrum.cumulative(lambda q: q * q, q_top)) / spectrum.mean_square_gradient
    if share > 0.5:
        warnings.warn(f"{share:.0%} of the squared rms slope comes from q > {q_top:.4g} (the data's top octave): "
                      f"the rms slope ({spectrum.rms_slope:.4g}) and the contact area depend on the resolution; give "
                      "q_max where the data are reliable", ResolutionWarning, stacklevel=3)
    return spectrum


@dataclass(frozen=True, eq=False)
class TabulatedSpectrum(SegmentedSpectrum):
    """An isotropic PSD ``C_points`` [length^4, > 0, the package's convention] given at strictly increasing
    ``q_points`` [rad/length, > 0]: a power law between the points, 0 outside them."""

    q_points: np.ndarray
    C_points: np.ndarray

    def __post_init__(self) -> None:
        q = check_finite_array("q_points", self.q_points, ndim=1, min_size=2)
        c = check_finite_array("C_points", self.C_points, shape=q.shape)
        if np.any(q <= 0) or np.any(np.diff(q) <= 0):
            raise ValueError("q_points must be strictly increasing wavenumbers > 0 (rad/length)")
        if np.any(c <= 0):
            raise ValueError(f"C_points must be > 0 (length^4); got minimum {c.min()!r}: drop empty points")
        for name, value in zip(("q_points", "C_points", "q_min", "q_max"), (*_read_only(q, c), q[0], q[-1])):
            object.__setattr__(self, name, value if np.ndim(value) else float(value))

    @staticmethod
    def _n_nodes(log_span: float) -> int:  # a power law times a smooth weight per segment
        return int(8 + 16 * math.ceil(log_span))

    def _segments(self) -> list[tuple[float, float]]:
        return list(zip(self.q_points[:-1].tolist(), self.q_points[1:].tolist()))

    def psd(self, q: ArrayLike) -> np.ndarray | float:
        """``C(q)`` [length^4] (log-log interpolation; 0 outside the table)."""
        qa = np.asarray(q, dtype=float)
        inside = (qa >= self.q_min) & (qa <= self.q_max)
        lq = np.log(np.where(inside, qa, self.q_min))
        c = np.where(inside, np.exp(np.interp(lq, np.log(self.q_points), np.log(self.C_points))), 0.0)
        return float(c) if c.ndim == 0 else c

    def __repr__(self) -> str:
        return (f"TabulatedSpectrum(n_points={self.q_points.size}, q_min={self.q_min:.6g}, q_max={self.q_max:.6g}, "
                f"h_rms={self.h_rms:.6g}, rms_slope={self.rms_slope:.6g})")


def spectrum_from_psd(q: ArrayLike, C: ArrayLike, *, kind: str = "isotropic", convention: str = "persson",
                      hurst: Optional[float] = None) -> TabulatedSpectrum:
    r"""A tabulated PSD as a spectrum for :func:`~diffusion_pr.pressure_distribution`.

    ``q`` [rad/length]: increasing, > 0; points with ``C <= 0`` or NaN (masked bins) are dropped.  ``C``: with
    ``kind="isotropic"`` ``C(q)`` [length^4] in the package's ``convention="persson"`` (``h_rms^2 = 2 pi int q C
    dq``) or Jacobs et al.'s / SurfaceTopography's ``"jacobs"`` (``(2 pi)^2`` larger); with ``kind="profile"`` the
    1D PSD ``C_1D(q)`` [length^3] of line scans (Jacobs' convention), converted with the Hurst exponent ``hurst``
    exactly for a power law, ``C_iso = C_1D / q * 2 sqrt(pi) Gamma(H + 1) / Gamma(H + 1/2)``, or without it by the
    standard ``C_iso = pi C_1D / q``, exact at ``H = 1/2``, which multiplies ``C`` by
    ``sqrt(pi) Gamma(H + 1/2) / (2 Gamma(H + 1))`` (1.15 at ``H = 0.3``, 0.85 at ``H = 0.8``).  A binned PSD
    misses the power below its first point (SurfaceTopography's of a 256^2 map: h_rms -13 %, rms slope -2 %)."""
    qa = check_finite_array("q", q, ndim=1)
    ca = np.asarray(np.ma.filled(np.ma.asarray(C, dtype=float), np.nan), dtype=float)
    if ca.shape != qa.shape:
        raise ValueError(f"q and C must have the same shape; got {qa.shape} and {ca.shape}")
    if kind not in ("isotropic", "profile") or convention not in ("persson", "jacobs"):
        raise ValueError(f"kind must be 'isotropic' or 'profile' and convention 'persson' or 'jacobs'; got "
                         f"kind={kind!r}, convention={convention!r}")
    keep = np.isfinite(ca) & (ca > 0) & (qa > 0)
    qa, ca = qa[keep], ca[keep]
    if kind == "profile":
        H = None if hurst is None else check_in_range("hurst", hurst, 0.0, 1.0, lo_inclusive=False)
        factor = math.pi if H is None else 2.0 * math.sqrt(math.pi) * math.gamma(H + 1.0) / math.gamma(H + 0.5)
        ca, convention = factor * ca / qa, "jacobs"
    if convention == "jacobs":
        ca = ca / (2.0 * math.pi) ** 2
    return _check_resolution(TabulatedSpectrum(qa, ca), qa[-1] / 2.0)


def _window(shape: tuple[int, int], window: Optional[str]) -> np.ndarray:
    """The separable 2D window (``None`` or ``"hann"``), scaled to ``mean(w^2) = 1`` (the variance is kept)."""
    if window is None:
        return np.ones(shape)
    if window != "hann":
        raise ValueError(f"window must be None or 'hann'; got window={window!r}")
    from scipy.signal.windows import hann

    w = hann(shape[0], sym=False)[:, None] * hann(shape[1], sym=False)[None, :]
    return w / math.sqrt(np.mean(w * w))


def _detrended(h: np.ndarray, detrend: Optional[str]) -> np.ndarray:
    """``h`` minus its mean (``"mean"``) or its least-squares plane (``"plane"``); ``None``: unchanged."""
    if detrend is None:
        return h
    if detrend == "mean":
        return h - h.mean()
    if detrend != "plane":
        raise ValueError(f"detrend must be None, 'mean' or 'plane'; got detrend={detrend!r}")
    x, y = np.meshgrid(np.linspace(-1, 1, h.shape[0]), np.linspace(-1, 1, h.shape[1]), indexing="ij")
    basis = np.stack([np.ones(h.size), x.ravel(), y.ravel()], axis=1)
    coef, *_ = np.linalg.lstsq(basis, h.ravel(), rcond=None)
    return h - (basis @ coef).reshape(h.shape)


def spectrum_from_map(heights: ArrayLike, length: float | tuple[float, float], *, periodic: bool = True,
                      detrend: Optional[str] = "default", window: Optional[str] = "default",
                      q_max: Optional[float] = None) -> DiscreteSpectrum:
    """The spectrum of a measured or simulated height map.

    A periodic map is used as it is (:meth:`DiscreteSpectrum.from_heights`).  A non-periodic one is made periodic
    for the FFT: its least-squares plane removed and a Hann window applied by default.  Biases, measured on 8
    seeded self-affine surfaces (``H = 0.3``, roughness from 1024 down to 8 pixels) cut to 256^2, against the
    generator's rms slope and the generating spectrum on the cut's lattice (mean +- seed sd; tested in
    tests/diffusion_pr/test_topography.py):

    * no window: the edges' jump leaks power to high ``q`` (``C ~ q^-4``): rms slope +46 +- 25 % (+34 +- 18 %
      with the plane removed);
    * Hann window (``mean(w^2) = 1``): rms slope -1 +- 2 %; it smooths ``C`` over a few lattice spacings in ``q``;
    * the plane also removes the tilt a finite cut of a self-affine surface carries: ``h_rms`` -13 +- 12 %
      (-5 +- 17 % with only the mean removed).

    ``heights`` [length], shape ``(nx, ny)``; ``length``: ``Lx`` [length] along the first axis (square pixels) or
    ``(Lx, Ly)``; ``periodic``: the map is one period of a periodic surface; ``detrend`` (None, ``"mean"``,
    ``"plane"``) and ``window`` (None, ``"hann"``) default to None for periodic maps, else ``"plane"`` and
    ``"hann"``; ``q_max`` [rad/length]: keep ``|q| <= q_max`` (the data's short reliability cutoff).
    """
    h = check_finite_array("heights", heights, ndim=2)
    detrend = (None if periodic else "plane") if detrend == "default" else detrend
    window = (None if periodic else "hann") if window == "default" else window
    h = _detrended(h, detrend)
    spectrum = DiscreteSpectrum.from_heights((h - h.mean()) * _window(h.shape, window), length)
    Lx, Ly = _periods(length, *h.shape)
    if q_max is not None:
        spectrum = spectrum.truncated(q_max)
    return _check_resolution(spectrum, 0.5 * math.pi * min(h.shape[0] / Lx, h.shape[1] / Ly))


def spectrum_from_topography(topography: Any, *, physical_sizes: Any = None, **kwargs: Any) -> Spectrum:
    """The spectrum of a SurfaceTopography topography, or of a file it reads (``pip install
    "diffusion-pr[topography]"``).

    Maps go through :func:`spectrum_from_map` (periodic as the topography says; ``kwargs``: ``detrend``,
    ``window``, ``q_max``); line scans through their profile PSD (``power_spectrum_from_profile``) and
    :func:`spectrum_from_psd` (``kwargs``: ``hurst``).  Heights and sizes in the topography's unit.

    ``topography``: a SurfaceTopography topography or line scan, or a file path read by
    ``SurfaceTopography.read_topography`` (about 40 formats) with ``physical_sizes`` [length] where the file has none.
    """
    if isinstance(topography, (str, bytes)) or hasattr(topography, "__fspath__"):
        try:
            from SurfaceTopography import read_topography
        except ImportError:
            raise ImportError("reading topography files needs SurfaceTopography: pip install "
                              '"diffusion-pr[topography]"') from None
        extra = {} if physical_sizes is None else {"physical_sizes": physical_sizes}
        topography = read_topography(topography, **extra)
    if not hasattr(topography, "heights") or not hasattr(topography, "physical_sizes"):
        raise ValueError("topography must be a SurfaceTopography topography or line scan or a file path; got "
                         f"{type(topography).__name__}")
    if topography.dim == 1:
        q, c = topography.power_spectrum_from_profile()
        return spectrum_from_psd(q, c, kind="profile", **kwargs)
    return spectrum_from_map(topography.heights(), tuple(topography.physical_sizes),
                             periodic=bool(topography.is_periodic), **kwargs)
