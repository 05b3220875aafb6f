"""Self-affine random rough surfaces (conventions: docs page ``gfmd``).

Fourier convention: ``h~(q) = (1/A) integral exp(i q.r) h(r) d^2r``,
discretely ``h~ = numpy.fft.ifft2(h)`` (the ``1/N^2`` normalised sum with ``exp(+i q.r)``),
with ``q = 2 pi (m, k) / length`` and ``<|h~(q)|^2> = C(|q|) (2 pi/length)^2``.
With this convention Parseval reads ``mean(h^2) = sum_q |h~(q)|^2`` and
``mean(|grad h|^2) = sum_q q^2 |h~(q)|^2``.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft

from ._validation import check_heights, check_int, check_positive, check_real, check_seed

__all__ = ["self_affine_surface", "spectral_rms_slope"]


def spectral_rms_slope(heights: np.ndarray, length: float) -> float:
    """Full rms gradient ``sqrt(<|grad h|^2>) = sqrt(sum_q q^2 |h~(q)|^2)`` of a periodic
    square ``(n, n)`` array of side ``length`` [length, > 0] (dimensionless)."""
    h = check_heights(heights)
    length = check_positive("length", length)
    n = h.shape[0]
    if h.shape[1] != n:
        raise ValueError(f"heights must be a square (n, n) array; got shape {h.shape}")
    k = 2.0 * np.pi * np.fft.fftfreq(n, d=length / n)
    q2 = k[:, None] ** 2 + k[None, :] ** 2
    return float(np.sqrt(np.sum(q2 * np.abs(sfft.fft2(h) / h.size) ** 2)))


def self_affine_surface(
    n: int,
    *,
    length: float,
    hurst: float,
    q_min: float,
    q_max: float,
    rms_slope: float | None = None,
    h_rms: float | None = None,
    q_roll: float | None = None,
    seed,
    rayleigh: bool = True,
) -> np.ndarray:
    """Gaussian, isotropic, self-affine random surface on a periodic ``n x n`` grid.

    The power spectrum is ``C(q) ∝ q^(-2(1+H))`` for ``max(q_roll, q_min) <= |q| <= q_max``,
    flat (``C(q_roll)``) for ``q_min <= |q| < q_roll`` when ``q_roll`` is given, and zero
    elsewhere (in particular at ``q = 0``: the returned array has zero mean).

    Parameters
    ----------
    n : int
        Grid points per side (any integer >= 2; odd sizes work).
    length : float
        Side ``L`` of the periodic cell; wave vectors are ``2 pi (m, k)/L``.
    hurst : float
        Hurst exponent ``H`` in ``[0, 1]``.
    q_min, q_max : float
        Band limits ``0 < q_min < q_max`` (inclusive) [1/length]. ``q_max`` must not
        exceed the grid's Nyquist wavenumber ``pi / dx = pi n / length``: shorter waves
        are not representable on the grid (ValueError).
    rms_slope, h_rms : float
        Exactly one must be given. ``rms_slope`` is the full ``sqrt(<|grad h|^2>)``,
        evaluated spectrally from the realised modes (``sum_q q^2 |h~(q)|^2``);
        ``h_rms`` is the realised root-mean-square height.
    q_roll : float, optional
        Roll-off wavenumber (``q_min <= q_roll <= q_max``).
    seed : int or numpy SeedSequence
        Seed for :func:`numpy.random.default_rng`. Same seed, same array.
    rayleigh : bool
        If true (default) the mode amplitudes are Rayleigh distributed (Gaussian
        field); if false every mode has the amplitude ``sqrt(C (2 pi/L)^2)`` and only
        the phases are random.

    Notes
    -----
    The realisation is built by filtering real-space white noise
    ``w = rng.standard_normal((n, n))`` (C order, so the draw order is fixed):
    ``h = irfft2(rfft2(w) * sqrt(C))``. This gives independent Gaussian modes with
    Hermitian symmetry (``h`` real) for every ``n``, odd or even. Reproducibility
    across platforms is exact up to the floating-point round-off of the FFT.
    """
    n = check_int("n", n, minimum=2)
    length = check_positive("length", length)
    hurst = check_real("hurst", hurst, low=0.0, high=1.0)
    seed = check_seed("seed", seed)
    if not isinstance(rayleigh, (bool, np.bool_)):
        raise ValueError(f"rayleigh must be True or False; got rayleigh={rayleigh!r}")
    q_min = check_positive("q_min", q_min)
    q_max = check_positive("q_max", q_max)
    if not q_max > q_min:
        raise ValueError(f"q_max must be > q_min (= {q_min!r}); got q_max={q_max!r}")
    nyquist = math.pi * n / length
    if q_max > nyquist * (1 + 1e-12):
        raise ValueError(f"q_max must be <= the grid's Nyquist wavenumber pi n / length = {nyquist:.6g} "
                         f"(n={n}, length={length!r}); got q_max={q_max!r}: use n >= {math.ceil(q_max * length / math.pi)}")
    if (rms_slope is None) == (h_rms is None):
        raise ValueError(f"exactly one of rms_slope and h_rms must be given; got rms_slope={rms_slope!r}, "
                         f"h_rms={h_rms!r}")
    if rms_slope is not None:
        rms_slope = check_positive("rms_slope", rms_slope)
    else:
        h_rms = check_positive("h_rms", h_rms)
    q_roll = None if q_roll is None else check_positive("q_roll", q_roll)
    if q_roll is not None and not q_min <= q_roll <= q_max:
        raise ValueError(f"q_roll must lie in [q_min, q_max] = [{q_min!r}, {q_max!r}]; got {q_roll!r}")

    # work on the integer lattice (m, k) with q = (2 pi / length) |(m, k)|, so no
    # length or band limit, however large or small, overflows
    unit = 2.0 * np.pi / length
    mx = np.fft.fftfreq(n, d=1.0 / n)
    my = np.fft.rfftfreq(n, d=1.0 / n)
    qhat = np.sqrt(mx[:, None] ** 2 + my[None, :] ** 2)
    lo, hi = q_min / unit, q_max / unit
    band = (qhat >= lo * (1 - 1e-12)) & (qhat <= hi * (1 + 1e-12))
    if not np.any(band):
        raise ValueError(f"no lattice wave vector 2 pi (m, k)/length lies in [q_min, q_max] = "
                         f"[{q_min!r}, {q_max!r}] for n={n}, length={length!r}")
    qq = np.where(band, qhat, 1.0)
    if q_roll is not None:
        qq = np.maximum(qq, q_roll / unit)
    amp = np.where(band, (qq / qq[band].min()) ** (-(1.0 + hurst)), 0.0)  # sqrt(C(q)) up to a constant

    rng = np.random.default_rng(seed)
    white = rng.standard_normal((n, n))
    wt = sfft.rfft2(white)
    if not rayleigh:
        mag = np.abs(wt)
        wt = np.where(mag > 0, wt / np.where(mag > 0, mag, 1.0), 1.0) * n  # unit-variance modes
    h = sfft.irfft2(wt * amp, s=(n, n))
    h -= h.mean()
    if rms_slope is not None:
        cur = spectral_rms_slope(h, 2.0 * np.pi)  # slope on the integer lattice (length 2 pi: q = (m, k))
        target = rms_slope / unit
    else:
        cur = float(np.sqrt(np.mean(h**2)))
        target = h_rms
    if not cur > 0 or not math.isfinite(cur):
        raise ValueError("the requested band produced a zero surface; widen [q_min, q_max]")
    scale = target / cur
    if not math.isfinite(scale):
        raise ValueError(f"length={length!r} with rms_slope={rms_slope!r} gives heights outside the float range")
    h *= scale
    return np.ascontiguousarray(h, dtype=np.float64)
