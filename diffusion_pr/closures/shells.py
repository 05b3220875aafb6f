r"""Magnification shells of a spectrum for the shell-by-shell closures (:mod:`diffusion_pr.closures`).

A shell ``k`` is a wavenumber ``q_k`` with its Persson increment ``dV0_k = (E* q_k/2)^2 x (shell power)``
[pressure^2]; the diffusion time advances by ``dV0_k/2`` across it.  A
:class:`~diffusion_pr.spectra.DiscreteSpectrum` has its own shells; a continuum spectrum is cut into shells
uniform or graded in ``ln q`` (:func:`shell_grading` chooses), each with its exact power and its node at the
shell's midpoint in diffusion time.

Units: pressures in the unit of ``E_star``; wavenumbers [rad/length] in the unit of the spectrum.
"""
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

#: shells of a continuum spectrum (uniform in ln q, tau-midpoint nodes) of the problem itself
#: (``shell_extrapolation=False``)
DEFAULT_CONTINUUM_SHELLS = 96
#: the first solve of the continuum closure (:mod:`diffusion_pr.closures.continuum`): 48 shells, corrected by the
#: plain grids of 24, 12 and 6 shells
EXTRAPOLATION_SHELLS = 48
#: the diffusion-time midpoint of a shell is solved to this fraction of the shell's power (:func:`_tau_midpoints`)
MIDPOINT_TOL = 1e-12
#: The shells' gradings (:func:`spectrum_shells`): the edges ``ln q = a + (b - a) x(s)`` with ``s`` uniform and
#: ``x(s)`` = ``s`` ("uniform"), ``1 - (1 - s)^2`` ("end": the last shell ``~h^2`` wide) or ``s^2 (3 - 2 s)``
#: ("ends": the first and the last; :func:`shell_grading` chooses, docs/closures.md "Graded shells")
SHELL_GRADINGS: tuple[str, ...] = ("uniform", "end", "ends")
#: ``kappa = p*(q_max)^2 / tau_last`` (the wall's layer ``p* = zeta q_max E*/2`` against the diffusion length of the
#: last of :data:`EXTRAPOLATION_SHELLS` uniform shells, ``tau_last = dV0_last/2``) below which the shells are graded
#: towards the end.  On the Fig. 1 scene ``local_g1`` gains from the grading up to ``kappa`` 2 and loses at 7.7;
#: ``local_g1_balanced`` loses from ``kappa`` 1.3 on and gains at 0.75.  1: where all three closures gain
WALL_LAYER_RATIO = 1.0
#: ``lambda = p0^2 / tau_first`` (the load's distance from the wall against the diffusion length of the first of
#: :data:`EXTRAPOLATION_SHELLS` uniform shells) below which a thin wall layer's shells are graded at the start too
#: ("ends"): "ends" wins at ``lambda = 1.4`` (Fig. 1 spectrum, ``p0 = 1e-3``, ``zeta = 0.01``) and "end" at 22
START_LAYER_RATIO = 4.0
#: where the start's layer is thin (``lambda <`` :data:`START_LAYER_RATIO`), the ``kappa`` below which the balanced
#: closures grade both ends although the wall's layer is thick by :data:`WALL_LAYER_RATIO` (on stress scenes with
#: ``lambda < 4``: "ends" took 0.3-0.9x the time of uniform shells up to ``kappa`` 55, and 1.0-2.4x from 74 on)
START_WALL_LAYER_RATIO = 60.0


@dataclass(frozen=True)
class Shells:
    """Magnification shells of a spectrum for the shell-by-shell closures.

    Attributes
    ----------
    q : ndarray
        Shell wavenumbers ``q_k`` [rad/length], increasing (the order they are applied in).
    dV0 : ndarray
        Persson increments ``dV0_k = (E* q_k/2)^2 x (shell power)`` [pressure^2];
        ``sum(dV0) = V0 = (E*/2)^2 gbar^2``.  The diffusion time advances by ``dV0_k/2``
        across shell ``k``.
    q_min : float
        Smallest wavenumber of the spectrum [rad/length] (the partition of the
        load-balanced closure uses it).
    exact : bool
        True for a :class:`~diffusion_pr.spectra.DiscreteSpectrum` (its own modes);
        False for a continuum quadrature.
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

    Solved to :data:`MIDPOINT_TOL` of the shell's power (regula falsi, Illinois variant, on
    :meth:`~diffusion_pr.spectra.Spectrum.cumulative`), not interpolated: the rule is symmetric (even in the shell
    width, so that Romberg applies) only with the exact midpoint.
    Shells without power keep their geometric centre."""
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
        # converged: the residual below 1e-12 of the shell's power (round-off of the cumulative is about
        # 1e-16 V0), or the bracket at round-off of ln q
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
    """``make()``, remembered under ``key`` where the key is hashable (a sweep over ``zeta``, ``p0`` or the
    closures asks again for every solve; an unhashable spectrum, e.g. one holding arrays, is not cached)."""
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
    """``dV0`` [pressure^2] of the first and last of :data:`EXTRAPOLATION_SHELLS` uniform shells with power (no
    midpoints needed), remembered for hashable spectra."""
    def make() -> tuple[float, float]:
        dv = np.diff(_shell_edges(spectrum, E, EXTRAPOLATION_SHELLS, "uniform")[1])
        dv = dv[dv > 0]
        return float(dv[0]), float(dv[-1])

    return _remembered(("end powers", spectrum, float(E)), make)


def shell_grading(spectrum: Spectrum, *, E_star: float, zeta: float, mean_pressure: float,
                  closure: Optional[str] = None) -> tuple[str, float, float]:
    r"""``(grading, kappa, lambda)``: the shells' grading of the continuum closure (:func:`spectrum_shells`) and why.

    The shell sum freezes each shell's operator at its midpoint.  Where the wall's layer is thick, that error is
    spread over all shells and uniform shells are best.  Where it is thin, the error comes from the ends:

    * **the end**: ``kappa = p*(q_max)^2 / tau_last`` compares the wall's layer ``p* = zeta q_max E*/2``
      [pressure] (below it ``g(q; p) ~ p/p*``) with the diffusion length of the last of
      :data:`EXTRAPOLATION_SHELLS` uniform shells, ``tau_last = dV0_last/2`` [pressure^2].  The error of the
      last shells' frozen layer is not smoothed by later shells and falls like ``h^1.25`` on uniform shells (the
      order reduction of a frozen boundary layer); graded towards ``q_max`` ("end", the last shell ``~h^2``
      wide) the order is two again and Romberg applies (Fig. 1 scene, ``local_g1``, ``zeta = 0.001``: 48 shells
      leave 4.3e-8 after one Richardson step, against 6.9e-6 uniform).
    * **the start** (with a thin layer only): ``lambda = p0^2 / tau_first``, the load's distance from the wall
      against the first uniform shell's diffusion length.  Below :data:`START_LAYER_RATIO` the first shells carry
      the start from ``delta(p - p0)`` into the wall's layer, and the order falls to one there too unless both
      ends are graded ("ends").

    "uniform" for ``kappa >=`` :data:`WALL_LAYER_RATIO`, else "end", or "ends" where also
    ``lambda <`` :data:`START_LAYER_RATIO`; the hard wall (``zeta = 0``, its shells commute) "uniform".
    The balanced closures take "ends" where ``lambda <`` :data:`START_LAYER_RATIO` up to ``kappa <``
    :data:`START_WALL_LAYER_RATIO` (a load far inside a layer that is thick at ``q_max`` only leaves the uniform
    shells' table pre-asymptotic).  ``local_g1_shell_balanced`` takes "ends" wherever the layer is thin, whatever
    ``lambda`` (docs/closures.md "The thin layer's table").

    Parameters
    ----------
    spectrum : Spectrum
        A continuum spectrum.
    E_star, mean_pressure : float
        Contact modulus and ``p0`` [pressure], > 0.
    zeta : float
        Wall range [length], >= 0.
    closure : str, optional
        The closure the shells are for (``"local_g1_shell_balanced"`` grades thin layers at both ends).
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

