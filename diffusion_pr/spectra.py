r"""Isotropic height spectra of randomly rough surfaces.

Conventions (docs/theory.md; M. H. Müser, Phys. Rev. Lett. 100, 055504 (2008), doi:10.1103/PhysRevLett.100.055504;
B. N. J. Persson, J. Chem. Phys. 115, 3840 (2001), doi:10.1063/1.1388626):

* Fourier transform of a periodic ``L x L`` height field ``h(r)`` (``A = L^2``)::

      h~(q) = (1/A) \int d^2r exp(i q.r) h(r),      q = 2 pi (m, n) / L

  so ``h~`` has the units of length.
* Isotropic power spectral density ``C(q)`` [length^4] with ``<|h~(q)|^2> = C(|q|) (2 pi / L)^2``; in the continuum::

      h_rms^2 = 2 pi \int q C(q) dq,        gbar^2 = <|grad h|^2> = 2 pi \int q^3 C(q) dq.

Two kinds of spectra share one interface (:class:`Spectrum`): continuum ones (:class:`SelfAffineSpectrum`, tabulated
data in :mod:`diffusion_pr.topography`; Gauss-Legendre quadrature in ``ln q``) and :class:`DiscreteSpectrum`, the
non-zero modes of one realization (exact sums).  Wavevectors are angular (rad / length), in the length unit of ``L``.
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Callable, Literal

import numpy as np
from numpy.typing import ArrayLike

from ._validation import check_finite_array, check_in_range, check_positive

__all__ = ["Spectrum", "SegmentedSpectrum", "SelfAffineSpectrum", "DiscreteSpectrum"]

Weight = Callable[[np.ndarray], ArrayLike]


def _periods(length: float | tuple[float, float], nx: int, ny: int) -> tuple[float, float]:
    """``(Lx, Ly)`` [length] of an ``(nx, ny)`` map from ``L`` (square pixels ``L/nx``) or ``(Lx, Ly)``."""
    if np.ndim(length) == 0:
        Lx = check_positive("length", length)
        return float(Lx), float(Lx) * ny / nx
    if np.shape(length) != (2,):
        raise ValueError(f"length must be a number or a pair (Lx, Ly) [length]; got length={length!r}")
    return tuple(float(check_positive("length", v)) for v in length)  # type: ignore[return-value]


def _merge_shells(key: np.ndarray, power: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct ``key`` values (sorted), the summed ``power`` and the number of modes of each."""
    uk, inv = np.unique(key, return_inverse=True)
    return uk, np.bincount(inv, weights=power, minlength=uk.size), np.bincount(inv, minlength=uk.size)


@lru_cache(maxsize=64)
def _leggauss(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [-1, 1] (cached, read-only)."""
    return _read_only(*np.polynomial.legendre.leggauss(n))


def _read_only(*arrays: np.ndarray) -> tuple:
    for a in arrays:
        a.setflags(write=False)
    return arrays


def _n_nodes(log_span: float) -> int:
    """Gauss-Legendre nodes for a segment of length ``log_span`` in ln q: weights built from
    ``G1(q)^2 = (1 + q/q*)^-2`` and powers of ``q`` are analytic in ``ln q`` within a strip of half-width pi, so
    40 + 16 nodes per unit of ``ln q`` reach round-off."""
    return int(min(2048, 40 + 16 * math.ceil(max(log_span, 0.0))))


def _eval_weight(weight: Weight | None, q: np.ndarray) -> np.ndarray:
    """Evaluate a vectorized weight on ``q`` and broadcast the result to ``q.shape``."""
    if weight is None:
        return np.ones_like(q)
    if not callable(weight):
        raise ValueError(f"weight must be a vectorized callable of q (rad/length) or None; got {weight!r}")
    return np.broadcast_to(np.asarray(weight(q), dtype=float), q.shape)


class Spectrum(abc.ABC):
    """Common interface of isotropic height spectra; ``q_min``, ``q_max`` [rad/length]: the smallest and largest
    wavenumbers carrying roughness."""

    q_min: float
    q_max: float

    @abc.abstractmethod
    def quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        r"""Nodes ``q_i`` [rad/length] and weights ``w_i`` [length^2] (read-only): ``sum_i w_i f(q_i)`` approximates
        ``2 pi \int q C(q) f(q) dq`` for smooth ``f`` (continuum) or equals ``sum_q |h~(q)|^2 f(|q|)`` (discrete)."""

    @abc.abstractmethod
    def cumulative(self, weight: Weight | None, q: ArrayLike) -> np.ndarray | float:
        r"""``2 pi \int_{q' <= q} q' C(q') weight(q') dq'`` (or the discrete sum) [length^2 x units of ``weight``]
        for upper limits ``q`` [rad/length] of any shape; ``weight``: a vectorized function of ``q`` or None (1)."""

    def psd(self, q: ArrayLike) -> np.ndarray | float:
        """Continuum PSD ``C(q)`` [length^4]; not defined for every spectrum."""
        raise NotImplementedError(f"{type(self).__name__} has no continuum PSD C(q)")

    def integrate(self, weight: Weight | None = None, *, method: Literal["gauss", "quad"] = "gauss") -> float:
        r"""``2 pi \int q C(q) weight(q) dq`` (continuum) or ``sum |h~|^2 weight`` (discrete) [length^2 x units of
        ``weight``]; ``weight``: a vectorized function of ``q`` [rad/length], None for 1 (``h_rms^2``).  ``method``:
        the quadrature of a continuum spectrum (:meth:`SelfAffineSpectrum.integrate`); discrete sums ignore it."""
        if method not in ("gauss", "quad"):
            raise ValueError(f"method must be 'gauss' or 'quad'; got {method!r}")
        q, w = self.quadrature()
        return float(np.dot(w, _eval_weight(weight, q)))

    @property
    def h_rms(self) -> float:
        """Root-mean-square height [length]."""
        return math.sqrt(self.integrate(None))

    @property
    def mean_square_gradient(self) -> float:
        """``gbar^2 = <|grad h|^2> = 2 pi int q^3 C dq`` [dimensionless]."""
        return self.integrate(lambda q: q * q)

    @property
    def rms_slope(self) -> float:
        """``gbar = sqrt(<|grad h|^2>)`` [dimensionless]."""
        return math.sqrt(self.mean_square_gradient)


class SegmentedSpectrum(Spectrum):
    """A continuum spectrum whose ``C(q)`` [length^4] is smooth on each of the segments ``_segments()``
    (``(lo, hi)`` pairs in rad/length): Gauss-Legendre in ``ln q`` on each, ``_n_nodes(ln(hi/lo))`` nodes."""

    _n_nodes = staticmethod(_n_nodes)

    @abc.abstractmethod
    def _segments(self) -> list[tuple[float, float]]:
        """Segments ``(lo, hi)`` [rad/length] of the support, on each of which ``C(q)`` is smooth."""

    @cached_property
    def _rule(self) -> tuple[np.ndarray, np.ndarray]:
        qs, ws = [], []
        for lo, hi in self._segments():
            a, b = math.log(lo), math.log(hi)
            x, w = _leggauss(self._n_nodes(b - a))
            q = np.exp(0.5 * (a + b) + 0.5 * (b - a) * x)
            qs.append(q)  # dq = q ds: 2 pi q C(q) dq = 2 pi q^2 C(q) ds
            ws.append(0.5 * (b - a) * w * 2 * math.pi * q * q * self.psd(q))
        return _read_only(np.concatenate(qs), np.concatenate(ws))

    def quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        r"""Gauss-Legendre nodes ``q`` [rad/length] in ``ln q`` on each segment, weights [length^2]: ``sum w f(q)``
        is ``2 pi \int q C f dq`` to round-off for ``f`` analytic near the real ``ln q`` axis (powers of q, G1^2)."""
        return self._rule

    def cumulative(self, weight: Weight | None, q: ArrayLike) -> np.ndarray | float:
        r"""``2 pi \int_{q_min}^{min(q, q_max)} q' C(q') weight(q') dq'``, vectorized over ``q``: Gauss-Legendre in
        ``ln q'`` on each (truncated) segment; ``weight`` is called with a 2-d array of ``q``."""
        qa = check_finite_array("q", q, min_size=0)
        flat = qa.ravel()
        out = np.zeros(flat.shape)
        for lo, hi in self._segments():
            a, b = math.log(lo), np.log(np.clip(flat, lo, hi))
            active = b > a
            if not np.any(active):
                continue
            x, w = _leggauss(self._n_nodes(math.log(hi / lo)))
            ba = b[active][:, None]
            qq = np.exp(0.5 * (a + ba) + 0.5 * (ba - a) * x[None, :])
            vals = 2 * math.pi * qq * qq * self.psd(qq) * _eval_weight(weight, qq)
            out[active] += (0.5 * (ba[:, 0] - a)) * (vals @ w)
        out = out.reshape(qa.shape)
        return float(out) if out.ndim == 0 else out


@dataclass(frozen=True, init=False)
class SelfAffineSpectrum(SegmentedSpectrum):
    r"""Continuum self-affine (power-law) PSD with optional roll-off.

    ``C(q) = C0 (q / q_r)^(-2 (1 + H))`` for ``q_r <= q <= q_max``, ``C(q) = C0`` for ``q_min <= q < q_r``
    (roll-off), ``0`` elsewhere, with ``q_r = q_roll`` (default ``q_min``: no roll-off). Persson, J. Chem. Phys.
    115, 3840 (2001), doi:10.1063/1.1388626; Müser, PRL 100, 055504 (2008).

    Parameters
    ----------
    hurst : float
        Hurst exponent ``H``, in (0, 1).
    q_min : float
        Lower cutoff ``q_L`` [rad/length], > 0.
    q_max : float
        Upper cutoff ``q_s`` [rad/length], > q_min.
    rms_slope : float, optional
        Amplitude via ``gbar = sqrt(<|grad h|^2>)`` [dimensionless].
    h_rms : float, optional
        Amplitude via the rms height [length].
    C0 : float, optional
        Amplitude via the plateau value ``C(q_r)`` [length^4].
    q_roll : float, optional
        Roll-off wavenumber ``q_r`` [rad/length] in ``[q_min, q_max]``.

    Exactly one of ``rms_slope``, ``h_rms``, ``C0`` must be given. The object stores the canonical ``C0`` and
    ``q_roll``; ``h_rms`` and ``rms_slope`` are closed forms. ``dataclasses.replace`` keeps ``C0`` fixed.

    Examples
    --------
    The paper's Fig. 1 surface (lengths in grid units):

    >>> s = SelfAffineSpectrum(0.3, 2*np.pi/1024, 2*np.pi/32, rms_slope=0.031)
    >>> round(s.rms_slope, 6)
    0.031
    """

    hurst: float
    q_min: float
    q_max: float
    C0: float
    q_roll: float

    def __init__(self, hurst: float, q_min: float, q_max: float, *, rms_slope: float | None = None,
                 h_rms: float | None = None, C0: float | None = None, q_roll: float | None = None) -> None:
        hurst = check_in_range("hurst", hurst, 0.0, 1.0, lo_inclusive=False, hi_inclusive=False)
        q_min = check_positive("q_min", q_min)
        q_max = check_positive("q_max", q_max)
        if not q_max > q_min:
            raise ValueError(f"q_max must be > q_min; got q_min={q_min!r}, q_max={q_max!r}")
        q_roll = check_in_range("q_roll", q_min if q_roll is None else q_roll, q_min, q_max)
        given = {k: v for k, v in (("rms_slope", rms_slope), ("h_rms", h_rms), ("C0", C0)) if v is not None}
        if len(given) != 1:
            raise ValueError("exactly one amplitude of rms_slope, h_rms, C0 must be given; got "
                             + (", ".join(f"{k}={v!r}" for k, v in given.items()) if given else "none"))
        (name, value), = given.items()
        value = check_positive(name, value)
        for attr, v in (("hurst", hurst), ("q_min", q_min), ("q_max", q_max), ("q_roll", q_roll), ("C0", 1.0)):
            object.__setattr__(self, attr, float(v))
        try:
            if name == "C0":
                c0 = value
                self._moment_unit(1), self._moment_unit(3)  # (raise OverflowError where they overflow)
            elif name == "h_rms":
                c0 = value**2 / (2 * math.pi * self._moment_unit(1))
            else:
                c0 = value**2 / (2 * math.pi * self._moment_unit(3))
        except OverflowError:
            raise ValueError(f"the spectrum's moments overflow double precision for q_min={q_min!r}, q_max={q_max!r}, "
                             f"hurst={hurst!r}: use a narrower or less extreme band (|log10 q| below about 150)") from None
        if not (math.isfinite(c0) and c0 > 0):
            raise ValueError(f"derived C0 is not a positive finite number ({c0!r}); check {name}={value!r}")
        object.__setattr__(self, "C0", float(c0))

    def __repr__(self) -> str:
        return (f"SelfAffineSpectrum(hurst={self.hurst!r}, q_min={self.q_min:.6g}, q_max={self.q_max:.6g}, "
                f"q_roll={self.q_roll:.6g}, C0={self.C0:.6g}, h_rms={self.h_rms:.6g}, rms_slope={self.rms_slope:.6g})")

    def _moment_unit(self, n: int) -> float:
        r"""``\int q^n C(q) dq / C0`` over the support, in closed form [rad^(n+1) / length^(n+1)]."""
        m, r, M, H = self.q_min, self.q_roll, self.q_max, self.hurst
        flat = (r ** (n + 1) - m ** (n + 1)) / (n + 1)
        e = n - 1 - 2 * H  # exponent of q in q^n C(q)/C0 r^(-2-2H) after integration
        L = math.log(M / r)
        power = r ** (n + 1) * (L if e == 0 else math.expm1(e * L) / e)
        return flat + power

    @property
    def h_rms(self) -> float:
        """Root-mean-square height [length] (closed form)."""
        return math.sqrt(2 * math.pi * self.C0 * self._moment_unit(1))

    @property
    def mean_square_gradient(self) -> float:
        """``gbar^2 = 2 pi int q^3 C dq`` [dimensionless] (closed form)."""
        return 2 * math.pi * self.C0 * self._moment_unit(3)

    def psd(self, q: ArrayLike) -> np.ndarray | float:
        """``C(q)`` [length^4] for ``q`` [rad/length] of any shape; 0 outside ``[q_min, q_max]``."""
        qa = np.asarray(q, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            c = np.where(qa < self.q_roll, self.C0,
                         self.C0 * (np.maximum(qa, self.q_roll) / self.q_roll) ** (-2.0 * (1.0 + self.hurst)))
        c = np.where((qa >= self.q_min) & (qa <= self.q_max), c, 0.0)
        return float(c) if c.ndim == 0 else c

    def _segments(self) -> list[tuple[float, float]]:
        """Power-law segments ``(lo, hi)`` [rad/length] of the support."""
        return [(lo, hi) for lo, hi in ((self.q_min, self.q_roll), (self.q_roll, self.q_max)) if hi > lo]

    def integrate(self, weight: Weight | None = None, *, method: Literal["gauss", "quad"] = "gauss") -> float:
        r"""``2 pi \int_{q_min}^{q_max} q C(q) weight(q) dq`` [length^2 x units of ``weight``].

        ``method="gauss"``: fixed high-order Gauss-Legendre in ``ln q`` per segment (a vectorized, smooth
        ``weight``).  ``"quad"``: adaptive :func:`scipy.integrate.quad` in ``ln q`` (for weights with kinks)."""
        if method == "gauss":
            return super().integrate(weight)
        if method != "quad":
            raise ValueError(f"method must be 'gauss' or 'quad'; got {method!r}")
        from scipy import integrate as _integrate

        f = (lambda q: 1.0) if weight is None else weight
        total = 0.0
        for lo, hi in self._segments():
            total += _integrate.quad(
                lambda s: 2 * math.pi * math.exp(2 * s) * float(self.psd(math.exp(s))) * float(f(math.exp(s))),
                math.log(lo), math.log(hi), epsabs=0.0, epsrel=1e-12, limit=200)[0]
        return total


@dataclass(frozen=True, eq=False)
class DiscreteSpectrum(Spectrum):
    r"""The spectrum of one periodic realization: its non-zero modes.

    Modes of equal ``|q|`` are merged into one shell (their powers summed); all sums over modes are exact. Build
    with :meth:`from_heights` or :meth:`from_modes`.

    Parameters
    ----------
    q : numpy.ndarray
        Strictly increasing shell wavenumbers ``|q|`` [rad/length], > 0.
    power : numpy.ndarray
        ``sum |h~(q)|^2`` over the modes of each shell [length^2], > 0.
    multiplicity : numpy.ndarray
        Number of modes merged into each shell.
    length : float or None
        Period ``L`` [length] when built from heights, else ``None``.

    Notes
    -----
    ``integrate(f) = sum_q |h~(q)|^2 f(|q|)`` over all modes ``q != 0`` of the full (two-sided) lattice, so
    ``integrate(1)`` is the variance of the heights (Parseval) and ``integrate(q^2)`` the mean of ``|grad h|^2`` of
    the trigonometric interpolant. For an even grid the Nyquist modes enter with their lattice ``|q|``
    (``q_x = -pi n / L``); a band-limited surface has no power there.
    """

    q: np.ndarray  # type: ignore[assignment]
    power: np.ndarray
    multiplicity: np.ndarray
    length: float | None = None

    def __post_init__(self) -> None:
        q = check_finite_array("q", self.q, ndim=1)
        p = check_finite_array("power", self.power, shape=(q.size,))
        m = np.asarray(self.multiplicity)
        if m.shape != q.shape or np.any(m < 1):
            raise ValueError(f"multiplicity must be positive integers of shape {q.shape}; got shape {m.shape}")
        if np.any(q <= 0) or np.any(np.diff(q) <= 0):
            raise ValueError("q must be strictly increasing and > 0 (rad/length); use DiscreteSpectrum.from_modes")
        if np.any(p <= 0):
            raise ValueError("power must be > 0 for every stored shell; use DiscreteSpectrum.from_modes")
        if self.length is not None:
            object.__setattr__(self, "length", check_positive("length", self.length))
        for name, arr in zip(("q", "power", "multiplicity"), _read_only(q.copy(), p.copy(), m.astype(np.int64))):
            object.__setattr__(self, name, arr)

    @classmethod
    def from_modes(cls, q: ArrayLike, power: ArrayLike, *, length: float | None = None,
                   empty_tol: float = 1e-24) -> "DiscreteSpectrum":
        """Spectrum from a list of modes ``|q|`` and their ``|h~(q)|^2``.

        Parameters
        ----------
        q : array_like
            Wavenumbers ``|q|`` [rad/length] of the modes, > 0 (leave out ``q = 0``); the shape of ``power``.
        power : array_like
            ``|h~(q)|^2`` [length^2] of each mode, >= 0.
        length : float, optional
            Period ``L`` [length], stored for information.
        empty_tol : float, default 1e-24
            Modes with ``power <= empty_tol * sum(power)`` count as empty (FFT round-off of a band-limited
            surface) and are dropped; they do not set ``q_min``/``q_max``.

        Returns
        -------
        DiscreteSpectrum
        """
        qa = check_finite_array("q", q)
        pa = check_finite_array("power", power)
        if qa.shape != pa.shape:
            raise ValueError(f"q and power must have the same shape; got {qa.shape} and {pa.shape}")
        if np.any(qa <= 0):
            raise ValueError("q must be > 0 for every mode (exclude the mean mode q = 0)")
        if np.any(pa < 0):
            raise ValueError(f"power must be >= 0; got minimum {pa.min()!r}")
        check_in_range("empty_tol", empty_tol, 0.0, 1.0, hi_inclusive=False)
        qa, pa = qa.ravel(), pa.ravel()
        total = pa.sum()
        if not total > 0:
            raise ValueError("power is zero for every mode: a flat surface has no spectrum")
        keep = pa > empty_tol * total
        return cls(*_merge_shells(qa[keep], pa[keep]), length)

    @classmethod
    def on_lattice(cls, spectrum: "Spectrum", n: int, length: float, *,
                   rms_slope: float | None = None) -> "DiscreteSpectrum":
        r"""The expected spectrum of ``spectrum`` on the modes of an ``n x n`` periodic cell.

        Every lattice mode ``q = 2 pi (m, k)/L`` (``-n/2 <= m, k < n/2``, ``q != 0``) gets its expected power
        ``<|h~(q)|^2> = C(|q|) (2 pi/L)^2``; modes of equal ``|q|`` are merged into shells.  The mean of
        :meth:`from_heights` over many realizations converges to it, and it is the spectrum to use when a theory is
        compared with simulations of such cells: the continuum integral spreads the power of the few lowest shells
        (4 modes at exactly ``q_min``, 4 at ``sqrt(2) q_min``, ...) over ``[q_min, 1.5 q_min]``, which matters where
        ``G1`` leaves only the lowest shells (large ``zeta``; docs/fig1.md).

        Parameters
        ----------
        spectrum : Spectrum
            A continuum spectrum with ``psd(q)`` [length^4].
        n : int
            Grid points per side (>= 2).
        length : float
            Period ``L`` [length] (> 0).
        rms_slope : float, optional
            If given, the powers are rescaled so that ``sum q^2 |h~|^2 = rms_slope^2`` (dimensionless), as
            ``gfmd_ref.self_affine_surface`` normalizes each realization; by default the continuum's amplitude.

        Returns
        -------
        DiscreteSpectrum
        """
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
            raise ValueError(f"n must be an integer >= 2 (grid points per side); got n={n!r}")
        L = check_positive("length", length)
        unit = 2.0 * np.pi / L
        k = np.fft.fftfreq(int(n), d=1.0 / n).astype(np.int64)
        k2 = (k[:, None] ** 2 + k[None, :] ** 2).ravel()
        uk2, mult = np.unique(k2[k2 > 0], return_counts=True)
        q = unit * np.sqrt(uk2.astype(float))
        power = np.asarray(spectrum.psd(q), dtype=float) * unit**2 * mult
        keep = power > 0
        if not np.any(keep):
            raise ValueError(f"no lattice mode of an n={n}, length={length!r} cell carries power of this spectrum")
        q, power, mult = q[keep], power[keep], mult[keep]
        if rms_slope is not None:
            power = power * (check_positive("rms_slope", rms_slope) ** 2 / float(np.sum(q**2 * power)))
        return cls(q, power, mult, L)

    @classmethod
    def from_heights(cls, heights: ArrayLike, length: float | tuple[float, float], *,
                     empty_tol: float = 1e-24) -> "DiscreteSpectrum":
        r"""Spectrum of one periodic ``(nx, ny)`` height map (square or rectangular).

        ``h~(q) = (1/(nx ny)) sum_r h(r) exp(i q.r)`` (the paper's transform on the grid) on all non-zero lattice
        modes ``q = 2 pi (m/Lx, k/Ly)`` of the full FFT; modes of equal ``|q|`` are merged (exactly, by an integer
        key, for square pixels).  Non-periodic data: :func:`diffusion_pr.topography.spectrum_from_map`.

        Parameters
        ----------
        heights : array_like, shape (nx, ny)
            Heights [length] on a periodic grid; the mean is irrelevant (``q = 0`` is excluded).
        length : float or (float, float)
            Period ``Lx`` [length] along the first axis with the same spacing ``Lx/nx`` along the second, or
            ``(Lx, Ly)``.  Stored as :attr:`length`: ``Lx``.
        empty_tol : float, default 1e-24
            Relative power below which a mode counts as empty (see :meth:`from_modes`).

        Returns
        -------
        DiscreteSpectrum
            With ``integrate(1) == heights.var()`` to round-off.
        """
        h = check_finite_array("heights", heights, ndim=2)
        nx, ny = h.shape
        if min(nx, ny) < 2:
            raise ValueError(f"heights must be an (nx, ny) array with nx, ny >= 2; got shape {h.shape}")
        Lx, Ly = _periods(length, nx, ny)
        check_in_range("empty_tol", empty_tol, 0.0, 1.0, hi_inclusive=False)
        ht = np.fft.fft2(h) / h.size
        pw = (ht.real**2 + ht.imag**2).ravel()
        pw[0] = 0.0
        mx, my = (np.fft.fftfreq(n, d=1.0 / n).astype(np.int64) for n in (nx, ny))
        if math.isclose(Lx * ny, Ly * nx, rel_tol=1e-12):  # square pixels: q = unit sqrt(integer key)
            g = math.gcd(nx, ny)
            key = ((mx * (ny // g))[:, None] ** 2 + (my * (nx // g))[None, :] ** 2).ravel()
            unit = 2 * math.pi * g / (ny * Lx)
        else:
            key, unit = ((mx / Lx)[:, None] ** 2 + (my / Ly)[None, :] ** 2).ravel(), 2 * math.pi
        total = pw.sum()
        if not total > 0:
            raise ValueError("heights are constant: a flat surface has no spectrum")
        keep = (pw > empty_tol * total) & (key > 0)
        uk, shell_power, mult = _merge_shells(key[keep], pw[keep])
        return cls(unit * np.sqrt(uk.astype(float)), shell_power, mult, float(Lx))

    def truncated(self, q_max: float) -> "DiscreteSpectrum":
        """The shells with ``|q| <= q_max`` [rad/length] (e.g. a measurement's short reliability cutoff)."""
        keep = self.q <= check_positive("q_max", q_max)
        if not np.any(keep):
            raise ValueError(f"q_max={q_max!r} is below every shell of this spectrum (q_min = {self.q_min:.6g})")
        return DiscreteSpectrum(self.q[keep], self.power[keep], self.multiplicity[keep], self.length)

    @property
    def q_min(self) -> float:  # type: ignore[override]
        """Smallest non-empty ``|q|`` [rad/length]."""
        return float(self.q[0])

    @property
    def q_max(self) -> float:  # type: ignore[override]
        """Largest non-empty ``|q|`` [rad/length]."""
        return float(self.q[-1])

    @property
    def n_modes(self) -> int:
        """Number of non-empty lattice modes (both halves of the Hermitian plane)."""
        return int(self.multiplicity.sum())

    def quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        """Shell wavenumbers [rad/length] and shell powers [length^2] (exact sum)."""
        return self.q, self.power

    def cumulative(self, weight: Weight | None, q: ArrayLike) -> np.ndarray | float:
        r"""Staircase ``sum_{|q'| <= q} |h~(q')|^2 weight(|q'|)``, vectorized over ``q`` (inclusive limits)."""
        qa = check_finite_array("q", q, min_size=0)
        cs = np.concatenate(([0.0], np.cumsum(self.power * _eval_weight(weight, self.q))))
        idx = np.searchsorted(self.q, qa, side="right")
        out = cs[idx]
        return float(out) if out.ndim == 0 else out

    def __repr__(self) -> str:
        return (
            f"DiscreteSpectrum(n_shells={self.q.size}, n_modes={self.n_modes}, q_min={self.q_min:.6g}, "
            f"q_max={self.q_max:.6g}, h_rms={self.h_rms:.6g}, rms_slope={self.rms_slope:.6g}, length={self.length})"
        )
