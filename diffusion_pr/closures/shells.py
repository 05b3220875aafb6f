"""Magnification shells of a spectrum for the shell-by-shell closures (:mod:`diffusion_pr.closures`).

A shell ``k`` is a wavenumber ``q_k`` with its Persson increment ``dV0_k`` [pressure^2]; the diffusion time
advances by ``dV0_k/2`` across it.  Pressures in the unit of ``E_star``; wavenumbers [rad/length]."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from .._validation import check_nonnegative, check_positive
from ..spectra import DiscreteSpectrum, Spectrum

__all__ = ["Shells", "spectrum_shells", "shell_grading", "local_response", "DEFAULT_CONTINUUM_SHELLS",
           "EXTRAPOLATION_SHELLS", "SHELL_GRADINGS"]

#: the balanced closures and their partition wavenumber ("shell": each shell's own q_k)
BALANCED = {"local_g1_balanced": None, "local_g1_shell_balanced": "shell"}

#: shells of a continuum spectrum without extrapolation (``shell_extrapolation=False``)
DEFAULT_CONTINUUM_SHELLS = 96
#: shells of the continuum closure's first solve (:mod:`diffusion_pr.closures.continuum`)
EXTRAPOLATION_SHELLS = 48
#: the diffusion-time midpoint of a shell is solved to this fraction of the shell's power (:func:`_tau_midpoints`)
MIDPOINT_TOL = 1e-12
#: the shells' gradings (:func:`spectrum_shells`, chosen by :func:`shell_grading`)
SHELL_GRADINGS: tuple[str, ...] = ("uniform", "end", "ends")
#: ``kappa`` below which the shells are graded towards the end (:func:`shell_grading`)
WALL_LAYER_RATIO = 1.0
#: ``lambda`` below which a thin wall layer's shells are graded at the start too ("ends")
START_LAYER_RATIO = 4.0
#: where ``lambda <`` :data:`START_LAYER_RATIO`, the ``kappa`` below which the balanced closures grade both ends
START_WALL_LAYER_RATIO = 60.0


@dataclass(frozen=True)
class Shells:
    """Magnification shells of a spectrum for the shell-by-shell closures.

    Attributes
    ----------
    q : ndarray
        Shell wavenumbers ``q_k`` [rad/length], increasing (the order they are applied in).
    dV0 : ndarray
        Persson increments ``dV0_k = (E* q_k/2)^2 x (shell power)`` [pressure^2]; ``sum(dV0) = V0``.
    q_min : float
        Smallest wavenumber of the spectrum [rad/length] (the load-balanced partition uses it).
    exact : bool
        True for a :class:`~diffusion_pr.spectra.DiscreteSpectrum` (its own modes); False for a continuum.
    """

    q: np.ndarray
    dV0: np.ndarray
    q_min: float
    exact: bool

    @property
    def V0(self) -> float:
        """Persson's full-contact variance ``sum dV0`` [pressure^2]."""
        return float(np.sum(self.dV0))


def spectrum_shells(spectrum: Spectrum, *, E_star: float, n_shells: Optional[int] = None,
                    grading: str = "uniform") -> Shells:
    r"""Shells ``q_k`` and Persson increments ``dV0_k`` of a spectrum.

    * :class:`~diffusion_pr.spectra.DiscreteSpectrum`: its own shells of equal
      ``|q|``, ``dV0_k = (E* q_k/2)^2 sum_{|q| = q_k} |h~(q)|^2`` (exact).
    * continuum (e.g. :class:`~diffusion_pr.spectra.SelfAffineSpectrum`):
      ``n_shells`` shells uniform in ``ln q`` on ``[q_min, q_max]``, or graded (``grading``: edges
      ``ln q = a + (b - a) x(s)``, ``s`` uniform, ``a, b = ln q_min, ln q_max``, :data:`SHELL_GRADINGS`);
      ``dV0_k = (E*/2)^2 2 pi \int_shell q^3 C(q) dq`` exactly (the spectrum's
      quadrature), and the node ``q_k`` is the shell's midpoint in diffusion time
      (where the cumulative ``V0`` reaches half the shell), which makes the
      shell sum a second-order (midpoint) rule in ``tau``.

    Parameters
    ----------
    spectrum : Spectrum
        Height spectrum (lengths in the unit of ``1/q``).
    E_star : float
        Contact modulus [pressure], > 0.
    n_shells : int, optional
        Continuum only (default :data:`DEFAULT_CONTINUUM_SHELLS`), >= 2.
    grading : {"uniform", "end", "ends"}
        Continuum only: ``x(s) = s``, ``1 - (1 - s)^2`` (finer towards ``q_max``, the end of the diffusion
        time) or ``s^2 (3 - 2 s)`` (towards both ends).  A smooth map of a uniform ``s``: the rule stays
        symmetric in the width of ``s`` (:func:`shell_grading` says where which pays).

    Returns
    -------
    Shells
    """
    if not isinstance(spectrum, Spectrum):
        raise ValueError("spectrum must be a diffusion_pr.spectra.Spectrum (SelfAffineSpectrum or "
                         f"DiscreteSpectrum); got {type(spectrum).__name__}")
    E = float(check_positive("E_star", E_star))
    if not isinstance(grading, str) or grading not in SHELL_GRADINGS:
        raise ValueError(f"grading must be one of {SHELL_GRADINGS}; got grading={grading!r}")
    if isinstance(spectrum, DiscreteSpectrum):
        if n_shells is not None or grading != "uniform":
            raise ValueError("n_shells and grading apply to continuum spectra only; a DiscreteSpectrum uses its own "
                             "shells")
        q = np.asarray(spectrum.q, dtype=float)
        dv = (0.5 * E * q) ** 2 * np.asarray(spectrum.power, dtype=float)
        return Shells(q.copy(), dv, float(q[0]), True)
    n = DEFAULT_CONTINUUM_SHELLS if n_shells is None else n_shells
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 2:
        raise ValueError(f"n_shells must be an integer >= 2; got n_shells={n_shells!r}")
    ln_edges, cum_edges, weight = _shell_edges(spectrum, E, int(n), grading)
    dv = np.diff(cum_edges)
    qk = np.exp(_tau_midpoints(spectrum, weight, ln_edges, cum_edges))
    keep = dv > 0
    return Shells(qk[keep], dv[keep], float(spectrum.q_min), False)


def _shell_edges(spectrum: Spectrum, E: float, n: int, grading: str) -> tuple:
    """``(ln q at the edges, cumulative V0 there [pressure^2], the V0 weight)`` of ``n`` shells of a continuum
    spectrum graded by ``grading`` (:func:`spectrum_shells`)."""
    a, b = math.log(float(spectrum.q_min)), math.log(float(spectrum.q_max))
    weight = lambda q: (0.25 * E * E) * q * q  # noqa: E731
    if grading == "uniform":
        ln_edges = np.linspace(a, b, n + 1)
    else:
        u = np.linspace(0.0, 1.0, n + 1)
        x = 1.0 - (1.0 - u) ** 2 if grading == "end" else u * u * (3.0 - 2.0 * u)
        ln_edges = a + (b - a) * x
        ln_edges[0], ln_edges[-1] = a, b
    return ln_edges, np.asarray(spectrum.cumulative(weight, np.exp(ln_edges)), dtype=float), weight


def _tau_midpoints(spectrum: Spectrum, weight: Any, ln_edges: np.ndarray, cum_edges: np.ndarray) -> np.ndarray:
    """``ln q`` of each shell's midpoint in diffusion time: where the cumulative ``V0`` reaches half the shell.

    Solved to :data:`MIDPOINT_TOL` of the shell's power (Illinois regula falsi), not interpolated: only the exact
    midpoint keeps the rule even in the shell width.  Shells without power keep their geometric centre."""
    lo, hi = ln_edges[:-1].copy(), ln_edges[1:].copy()
    f_lo = cum_edges[:-1] - 0.5 * (cum_edges[:-1] + cum_edges[1:])  # <= 0
    f_hi = -f_lo
    target = 0.5 * (cum_edges[:-1] + cum_edges[1:])
    half = f_hi.copy()
    live = f_hi > 0.0
    x = 0.5 * (lo + hi)
    kept_hi = np.zeros(x.size, dtype=bool)  # the last step moved the lower end (the upper one was kept)
    started = np.zeros(x.size, dtype=bool)
    for _ in range(60):
        if not np.any(live):
            break
        # the secant point of the bracket (regula falsi), or its midpoint where that leaves the bracket
        with np.errstate(divide="ignore", invalid="ignore"):
            xs = lo - f_lo * (hi - lo) / (f_hi - f_lo)
        xs = np.where(np.isfinite(xs) & (xs > lo) & (xs < hi), xs, 0.5 * (lo + hi))
        f = np.asarray(spectrum.cumulative(weight, np.exp(xs[live])), dtype=float) - target[live]
        x[live] = xs[live]
        idx = np.flatnonzero(live)
        below = f < 0.0
        # Illinois: the end kept twice in a row has its value halved (plain regula falsi stalls on one side)
        f_hi[idx[below & kept_hi[idx]]] *= 0.5
        f_lo[idx[~below & ~kept_hi[idx] & started[idx]]] *= 0.5
        lo[idx[below]], f_lo[idx[below]] = xs[idx[below]], f[below]
        hi[idx[~below]], f_hi[idx[~below]] = xs[idx[~below]], f[~below]
        kept_hi[idx] = below
        started[idx] = True
        # converged: the residual below MIDPOINT_TOL of the shell's power, or the bracket at round-off of ln q
        done = (np.abs(f) <= MIDPOINT_TOL * half[live]) | \
               (hi[idx] - lo[idx] <= 4.0 * np.finfo(float).eps * np.maximum(1.0, np.abs(x[idx])))
        live[idx[done]] = False
    if np.any(live):
        raise RuntimeError(f"the diffusion-time midpoints of {int(live.sum())} shells did not converge in 60 "
                           "regula falsi steps")
    return x


#: shells (and end powers) kept for repeated solves on the same (hashable) spectrum, modulus and shell count
_CACHE: dict = {}
_CACHE_SIZE = 64


def _remembered(key: tuple, make: Any) -> Any:
    """``make()``, remembered under ``key`` where the key is hashable (else not cached)."""
    try:
        hit = _CACHE.get(key)
    except TypeError:
        return make()
    if hit is None:
        hit = make()
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = hit
    return hit


def cached_shells(spectrum: Spectrum, E: float, n_shells: Optional[int], grading: str = "uniform") -> Shells:
    """:func:`spectrum_shells`, remembered for hashable spectra; the remembered arrays are read-only."""
    def make() -> Shells:
        shells = spectrum_shells(spectrum, E_star=E, n_shells=n_shells, grading=grading)
        for a in (shells.q, shells.dV0):
            a.setflags(write=False)
        return shells

    return _remembered(("shells", spectrum, float(E), n_shells, grading), make)


def _end_shell_powers(spectrum: Spectrum, E: float) -> tuple[float, float]:
    """``dV0`` [pressure^2] of the first and last of :data:`EXTRAPOLATION_SHELLS` uniform shells with power."""
    def make() -> tuple[float, float]:
        dv = np.diff(_shell_edges(spectrum, E, EXTRAPOLATION_SHELLS, "uniform")[1])
        dv = dv[dv > 0]
        return float(dv[0]), float(dv[-1])

    return _remembered(("end powers", spectrum, float(E)), make)


def shell_grading(spectrum: Spectrum, *, E_star: float, zeta: float, mean_pressure: float,
                  closure: Optional[str] = None) -> tuple[str, float, float]:
    """``(grading, kappa, lambda)``: the shells' grading of the continuum closure (:func:`spectrum_shells`) and why.

    The shell sum freezes each shell's operator at its midpoint; where the wall's layer is thin the error comes
    from the ends, so the shells are graded towards them:

    * ``kappa = p*(q_max)^2 / tau_last``: the wall's layer ``p* = zeta q_max E*/2`` [pressure] against the
      diffusion length of the last of :data:`EXTRAPOLATION_SHELLS` uniform shells, ``tau_last = dV0_last/2``.  The
      last shells' frozen layer makes uniform shells' error fall like ``h^1.25``; graded towards ``q_max`` ("end")
      the order is two again.
    * ``lambda = p0^2 / tau_first``: below :data:`START_LAYER_RATIO` the first shells carry the start into the
      wall's layer too, and both ends are graded ("ends").

    "uniform" for ``kappa >=`` :data:`WALL_LAYER_RATIO` or ``zeta = 0``, else "end", or "ends" where also
    ``lambda <`` :data:`START_LAYER_RATIO`.  The balanced closures take "ends" where ``lambda <``
    :data:`START_LAYER_RATIO` up to ``kappa <`` :data:`START_WALL_LAYER_RATIO`; ``local_g1_shell_balanced`` takes
    "ends" wherever the layer is thin.

    Parameters
    ----------
    spectrum : Spectrum
        A continuum spectrum.
    E_star, mean_pressure : float
        Contact modulus and ``p0`` [pressure], > 0.
    zeta : float
        Wall range [length], >= 0.
    closure : str, optional
        The closure the shells are for.
    """
    kz = 0.5 * float(check_nonnegative("zeta", zeta)) * float(check_positive("E_star", E_star))
    p0 = float(check_positive("mean_pressure", mean_pressure))
    if kz == 0.0 or isinstance(spectrum, DiscreteSpectrum):
        return "uniform", math.inf, math.inf
    dv_first, dv_last = _end_shell_powers(spectrum, float(E_star))
    kappa = (kz * float(spectrum.q_max)) ** 2 / (0.5 * dv_last)
    lam = p0 * p0 / (0.5 * dv_first)
    thin_start = lam < START_LAYER_RATIO and kappa < START_WALL_LAYER_RATIO and closure in BALANCED
    if kappa >= WALL_LAYER_RATIO and not thin_start:
        return "uniform", kappa, lam
    both = lam < START_LAYER_RATIO or closure == "local_g1_shell_balanced"
    return ("ends" if both else "end"), kappa, lam


def local_response(q: Any, p: Any, *, zeta: float, E_star: float) -> np.ndarray:
    """``g(q; p) = 1 / (1 + zeta q E* / (2 p))``: Eq. 10 of the paper at the local pressure ``p``.

    Parameters
    ----------
    q : array_like
        Wavenumber [rad/length], >= 0.
    p : array_like
        Local pressure [pressure], >= 0 (``g(q; 0) = 0`` for ``zeta q > 0``).
    zeta : float
        Wall range [length], >= 0 (``g = 1`` for ``zeta = 0``).
    E_star : float
        Contact modulus [pressure], > 0.

    Returns
    -------
    ndarray
        Dimensionless, in ``[0, 1]``; broadcast shape of ``q`` and ``p``.
    """
    qa = np.asarray(check_nonnegative("q", q), dtype=float)
    pa = np.asarray(check_nonnegative("p", p), dtype=float)
    z = float(check_nonnegative("zeta", zeta))
    E = float(check_positive("E_star", E_star))
    kz = 0.5 * z * E
    if kz == 0.0:
        return np.ones(np.broadcast(qa, pa).shape)
    num = np.broadcast_to(pa, np.broadcast(qa, pa).shape)
    return num / (num + kz * qa)

