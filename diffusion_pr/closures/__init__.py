r"""Parameter-free closures beyond the paper's second order (docs/closures.md).

The paper (M. H. Müser, Phys. Rev. Lett. 100, 055504 (2008),
doi:10.1103/PhysRevLett.100.055504) broadens a Gaussian with the second-order
(cumulant) variance ``V = sum_q (q E*/2)^2 G1(q)^2 |h~(q)|^2`` and needs a fitted
cutoff pressure ``p_c`` near ``p = 0``.  The closures here need no fitted number:

``"second_order"``
    The paper (the default of :func:`diffusion_pr.pressure_distribution`):
    ``dPr/dtau = d^2/dp^2 [f(p) Pr]`` to ``tau = V/2`` with the cutoff/tail factor
    ``f``.
``"lognormal_gap"``
    The gap fluctuation ``-(1 - G1(q)) h~(q)`` is Gaussian with variance
    ``zeta^2 V / p0^2``; the wall law ``p = p_w exp(-gap/zeta)`` maps it onto a
    log-normal pressure with ``Var(ln p) = s^2 = V / p0^2`` and the mean fixed to
    ``p0``.  Closed form.  Not defined for the hard wall (``zeta = 0``).
``"local_g1"``
    Shell by shell in ``q`` (diffusion time ``tau`` advancing by ``dV0_k/2``
    across shell ``k``): ``dPr/dtau = d^2/dp^2 [g(q_k; p)^2 Pr]`` with the response
    factor evaluated at the *local* pressure, ``g(q; p) = 1/(1 + zeta q E*/(2p))``.
``"local_g1_balanced"``
    As ``local_g1`` plus the drift ``b = (1 - g(q_min; p)) (g(q_k; p)^2/p - A p)``,
    ``A(tau)`` the one number per instant that keeps ``<p> = p0``.
``"local_g1_shell_balanced"``
    As ``local_g1_balanced`` with the partition at the shell's own wavenumber:
    ``b = (1 - g(q_k; p)) (g(q_k; p)^2/p - A p)``.  Found here; the best on the
    GFMD ensembles (docs/fig1.md).

Units: pressures in the unit of ``E_star`` and ``mean_pressure``; lengths
(``zeta``, ``1/q``) in the unit of the spectrum; ``tau`` in pressure^2.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Any, Optional

import numpy as np

from .._validation import check_nonnegative, check_positive
from ..spectra import DiscreteSpectrum, Spectrum

__all__ = [
    "CLOSURES",
    "Shells",
    "spectrum_shells",
    "shell_grading",
    "local_response",
    "lognormal_gap_distribution",
    "closure_distribution",
    "contact_fraction",
    "DEFAULT_CONTINUUM_SHELLS",
]

#: the closures by name; "second_order" is the paper's theory
CLOSURES: tuple[str, ...] = ("second_order", "lognormal_gap", "local_g1", "local_g1_balanced",
                             "local_g1_shell_balanced")

#: the balanced closures and their partition wavenumber ("shell": each shell's own q_k)
_BALANCED = {"local_g1_balanced": None, "local_g1_shell_balanced": "shell"}

#: shells of a continuum spectrum (uniform in ln q, tau-midpoint nodes) of the problem itself
#: (``shell_extrapolation=False``)
DEFAULT_CONTINUUM_SHELLS = 96
#: the first solve of the continuum closure (shell_extrapolation): 48 shells, corrected by the plain grids of 24, 12
#: and 6 shells (Romberg to sixth order where the observed order allows it; :func:`_shell_table`)
EXTRAPOLATION_SHELLS = 48
#: the most shells the extrapolation grows to where its residual misses rtol
MAX_CONTINUUM_SHELLS = 1536
#: the ladder's rungs after its first table (where it doubles: 96, 192, ... shells) are solved on the answer's N grid
#: alone, and the continuum's refinement they bring is added to the first table's correction (:func:`_shell_corrected`:
#: a third of each rung's integrations; docs/closures.md "The later rungs on the coarse grid").  Only on graded shells
#: (a thin wall layer): on a uniform ladder the refinement's spatial error went far past its count (random seed 21,
#: scene 232: 4.2e-6 from the oracle against an estimate of 8.9e-7; with both grids 7.6e-8 on 192 shells)
#: ... their refinement's spatial error counted as this multiple of its size times four times the first table's
#: correction's relative second-order error (the N grid's, of a difference of the same kind).  On the Fig. 1 scenes
#: that doubled, the answer moved from the one with both grids by 0.4-2.8x that proxy (margin 1).  It is not a bound
#: of that distance: in the audits (benchmarks/coarse_rungs_audit.py: 64 stress scenes and 45 random ones that used the
#: coarse rungs) the answers moved by more than the counted term on 62 of 109, by up to 54x; the estimates held on all
#: 109 (none above its estimate or rtol, with the switch on or off; docs/closures.md "The later rungs on the coarse
#: grid")
REFINEMENT_MARGIN = 3.0
#: ... where that counted error, predicted from the first table's residual, takes at most this share of the room the
#: grids' estimate leaves in rtol (else the later rungs get both grids from the start)
COARSE_ROOM = 0.5
#: the shells grow only while the grids' estimate leaves the extrapolation's residual this share of rtol at least
SHELL_SHARE = 0.9
#: where the grids' estimate alone takes SHELL_SHARE of rtol, the first solve is repeated at this fraction of rtol
GRID_RETRY_FRACTION = 0.25
#: the observed ratio of successive shell differences above which the midpoint rule's second order is taken as
#: asymptotic (4 at second order; 3.0 is an order of 1.58).  Measured on the Fig. 1 scene: 3.92-4.30 at every
#: wall and closure but local_g1 at zeta = 0.001 (2.42, a lower order) and local_g1_shell_balanced at
#: zeta = 0.001 (3.31 at 768 shells, where the fourth-order term still contaminates the ratio: R(192, 384) was
#: within 3.0e-7 of the oracle with the difference over 15 as its estimate, 6.7e-7)
SHELL_ORDER_RATIO = 3.0
#: ... and the ratio below which that second order is not yet clear (an order of 1.81): the shells' table then
#: divides the last ``R(n/2, n)`` difference by at most that ratio minus 1, not by the ``R`` differences' own
#: (:func:`_shell_table`; docs/closures.md "A ladder below second order on uniform shells")
SECOND_ORDER_CLEAR = 3.5
#: the observed ratio of successive ``R(n/2, n)`` differences above which their fourth order is taken as asymptotic
#: and Romberg's sixth-order column is used (16 at fourth order; 12 is an order of 3.58).  Measured on the Fig. 1
#: scene with exact tau-midpoints: 15.5-16.4 at every closure at zeta >= 0.1, 3-11 at zeta <= 0.01
ROMBERG_RATIO = 12.0
#: the largest such ratio Romberg trusts (16 x 1.0625): above it the ladder is taken as not yet asymptotic
#: (:func:`_shell_table`; measured 33 and 42 on two stress scenes whose Romberg estimates were 19x and 3.8x
#: optimistic, docs/closures.md "Pre-asymptotic shell ladders and thin starts"; 20 until the thirty-first session,
#: when the tables of 6-768-shell ladders on 500 uniform scenes showed Romberg 1.8-2.7x optimistic at ratios of
#: 17.8-19.5, at most 1.19x at 15.5-16.7, docs/closures.md "The correction's own error counted")
ROMBERG_MAX_RATIO = 17.0
#: where the wall's layer is thin (graded shells, :func:`shell_grading`), the largest ratio of successive
#: ``R(n/2, n)`` differences the shells' table trusts: ``2^2.5``, the order the frozen layer leaves after one
#: Richardson step (measured there: 5-9 per doubling, with single ratios of 13-16 between them that a sixth order
#: does not follow: Romberg on such a ratio was 4-7x optimistic, docs/closures.md "The thin layer's table")
THIN_LAYER_RATIO = 2.0 ** 2.5
#: the uniform shells' table decides its order on the zero weight and on the cells apart (each part its own branch,
#: continuum and residual; the residuals summed), as the thin layer's table counts them: the zero weight, the
#: probability below the floor, converges on its own and the cells' larger differences hid it in the L1 sums
#: (forty-ninth session: on the 649 uniform ladders of random seeds 17-22, above the estimate 11 -> 5, above rtol
#: 4 -> 1, the largest true/estimate 5.92 -> 2.22, 8 ladders on more shells, the Fig. 1 scenes' shells unchanged;
#: docs/closures.md "The zero weight's own order on uniform shells")
#: the plain grids' correction extrapolated in space from the N and 2N grids (:func:`_correction_in_space`): its
#: own error (counted on uniform shells; where the wall's layer is thin the second-order one is) is the
#: second-order estimate times this multiple
#: of the same extrapolation's observed error on the n-shell problem's own three grids, relative to their
#: second-order estimate.  Measured on 76 scenes (the Fig. 1 spectrum at six walls and the four stress spectra at
#: four walls and two loads, both balanced closures, against the correction from the 4N grids): the correction's
#: relative error was 0.28-3.3x the problem's on 67, 4.4-26x on eight whose extrapolated correction was off by at
#: most 3.3e-9 in L1, and one had a coarse correction far off (docs/closures.md "The correction extrapolated in
#: space"); the extrapolation is used where the factor is below 1
SPLIT_MARGIN = 4.0
#: ... and never less than this fraction of the second-order estimate (those eight: 0.007-0.41)
SPLIT_FLOOR = 0.1
#: the fewest shells a coarser plain solve of the table has (the n/8 of 48)
MIN_ROMBERG_SHELLS = 6
#: the diffusion-time midpoint of a shell is solved to this fraction of the shell's power (:func:`_tau_midpoints`)
MIDPOINT_TOL = 1e-12
#: The shells' gradings (:func:`spectrum_shells`): the edges ``ln q = a + (b - a) x(s)`` with ``s`` uniform and
#: ``x(s)`` = ``s`` ("uniform"), ``1 - (1 - s)^2`` ("end": the last shell ``~h^2`` wide) or ``s^2 (3 - 2 s)``
#: ("ends": the first and the last; :func:`shell_grading` chooses, docs/closures.md "Graded shells")
SHELL_GRADINGS: tuple[str, ...] = ("uniform", "end", "ends")
#: ``kappa = p*(q_max)^2 / tau_last`` (the wall's layer ``p* = zeta q_max E*/2`` against the diffusion length of the
#: last of :data:`EXTRAPOLATION_SHELLS` uniform shells, ``tau_last = dV0_last/2``) below which the shells are graded
#: towards the end.  Measured on the Fig. 1 scene: ``local_g1`` gains from the grading up to ``kappa`` 2 at least
#: (Romberg at 48 shells, ``zeta = 0.05``, ``kappa`` 1.9: 7.7e-8 graded against 4.1e-7 uniform; 6.6 against 9.0 ms)
#: and loses at 7.7 (``zeta = 0.1``: 1.6e-6 against 3.0e-8); ``local_g1_balanced`` loses from ``kappa`` 1.3 on
#: (``zeta = 0.04``: 64 ms graded against 30 ms uniform, 96 shells both: the graded 48-shell answer is further from
#: the continuum and its correction's spatial error sends it to the costlier paths) and gains at 0.75 (``zeta =
#: 0.03``: 65 against 70 ms; ``local_g1_shell_balanced`` 33 against 67 ms).  1: where all three gain.
#: :data:`START_LAYER_RATIO` likewise for the start
WALL_LAYER_RATIO = 1.0
#: ``lambda = p0^2 / tau_first`` (the load's distance from the wall against the diffusion length of the first of
#: :data:`EXTRAPOLATION_SHELLS` uniform shells) below which a thin wall layer's shells are graded at the start too
#: ("ends").  Measured (``local_g1_balanced``, ``zeta = 0.01``, R at 48/96 shells): "ends" wins at ``lambda = 1.4``
#: (Fig. 1 spectrum, ``p0 = 1e-3``: 2.6e-6/3.3e-7 against 5.2e-6/7.1e-7 "end") and far below (``H = 0.8``,
#: ``p0 = 1e-5``, ``zeta = 1e-3``: order two against one), "end" at ``lambda = 22`` (Fig. 1, ``p0 = 4e-3``)
START_LAYER_RATIO = 4.0
#: where the start's layer is thin (``lambda <`` :data:`START_LAYER_RATIO`), the ``kappa`` below which the balanced
#: closures grade both ends although the wall's layer is thick by :data:`WALL_LAYER_RATIO`.  Measured on the 36
#: stress scenes of ``benchmarks/stress_balance.py`` with ``1 <= kappa < 1000`` and ``lambda < 4`` (eighteenth session,
#: docs/closures.md "Pre-asymptotic shell ladders and thin starts"): "ends" took 0.3-0.9x the time of uniform shells on 16 of the 18 with
#: ``kappa <= 55`` (1.4x on one, 1.1x on one whose uniform answer was 30x off its estimate), and 1.0-2.4x on all 18
#: with ``kappa >= 74``
START_WALL_LAYER_RATIO = 60.0

#: GFMD's contact threshold for exponential walls, relative to p0
CONTACT_THRESHOLD = 0.01


def check_closure(closure: object) -> str:
    """Return ``closure`` if it names a closure, else raise ``ValueError`` listing the names."""
    if not isinstance(closure, str) or closure not in CLOSURES:
        raise ValueError(f"closure must be one of {list(CLOSURES)}; got closure={closure!r}")
    return closure


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

    Solved to 1e-12 of the shell's power (regula falsi, Illinois variant, on
    :meth:`~diffusion_pr.spectra.Spectrum.cumulative`), not interpolated: the rule is symmetric only with the exact
    midpoint.  A linearly interpolated midpoint (32 points per shell,
    up to the ninth session) is off by ``O(h^2) x O(h/32)`` in ``ln q``, which adds a third-order term to the
    shells' error expansion: ``R(n/2, n)`` then fell 8x per doubling instead of 16x, and the ``/15`` residual was 2x
    optimistic (Fig. 1 scene, ``local_g1``, ``zeta = 1``: 1.7e-7 at 96 shells against an estimate of 8.4e-8; with
    the exact midpoint 1.0e-7 against 1.0e-7, and the Romberg step to sixth order works: 2e-8 at 48 shells).
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


_SHELL_CACHE: dict = {}
#: shells kept for repeated solves on the same (hashable) spectrum, modulus and shell count
_SHELL_CACHE_SIZE = 32


def _cached_shells(spectrum: Spectrum, E: float, n_shells: Optional[int], grading: str = "uniform") -> Shells:
    """:func:`spectrum_shells`, remembered for hashable spectra (a sweep over zeta, p0 or closures reuses them).

    The cached arrays are read-only (the shells of a frozen spectrum never change).
    """
    try:
        key = (spectrum, float(E), n_shells, grading)
        hit = _SHELL_CACHE.get(key)
    except TypeError:  # an unhashable spectrum (e.g. one holding arrays): no cache
        return spectrum_shells(spectrum, E_star=E, n_shells=n_shells, grading=grading)
    if hit is None:
        hit = spectrum_shells(spectrum, E_star=E, n_shells=n_shells, grading=grading)
        for a in (hit.q, hit.dV0):
            a.setflags(write=False)
        if len(_SHELL_CACHE) >= _SHELL_CACHE_SIZE:
            _SHELL_CACHE.pop(next(iter(_SHELL_CACHE)))
        _SHELL_CACHE[key] = hit
    return hit


_END_POWERS: dict = {}


def _end_shell_powers(spectrum: Spectrum, E: float) -> tuple[float, float]:
    """``dV0`` [pressure^2] of the first and last of :data:`EXTRAPOLATION_SHELLS` uniform shells with power (no
    midpoints needed), remembered for hashable spectra as :func:`_cached_shells` remembers shells (a sweep over
    ``zeta`` or ``p0`` asks again for every solve)."""
    try:
        key = (spectrum, E)
        hit = _END_POWERS.get(key)
    except TypeError:  # an unhashable spectrum: no cache
        key = hit = None
    if hit is None:
        dv = np.diff(_shell_edges(spectrum, E, EXTRAPOLATION_SHELLS, "uniform")[1])
        dv = dv[dv > 0]
        hit = (float(dv[0]), float(dv[-1]))
        if key is not None:
            if len(_END_POWERS) >= _SHELL_CACHE_SIZE:
                _END_POWERS.pop(next(iter(_END_POWERS)))
            _END_POWERS[key] = hit
    return hit


def shell_grading(spectrum: Spectrum, *, E_star: float, zeta: float, mean_pressure: float,
                  closure: Optional[str] = None) -> tuple[str, float, float]:
    r"""``(grading, kappa, lambda)``: the shells' grading of the continuum closure (:func:`spectrum_shells`) and why.

    The shell sum freezes each shell's operator at its midpoint.  Where the wall's layer is thick, that error is
    spread over all shells and uniform shells are best.  Where it is thin, the error comes from the ends:

    * **the end**: ``kappa = p*(q_max)^2 / tau_last`` compares the wall's layer ``p* = zeta q_max E*/2``
      [pressure] (below it ``g(q; p) ~ p/p*``) with the diffusion length of the last of
      :data:`EXTRAPOLATION_SHELLS` uniform shells, ``tau_last = dV0_last/2`` [pressure^2].  Each shell freezes the
      layer at its own ``p*``; the error it leaves sits within a shell's diffusion length of the wall, where the
      later shells' diffusion smooths it away, but nothing smooths the last shells' (Fig. 1 scene, ``local_g1``,
      ``zeta = 0.001``: refining the last quarter of 96 uniform shells 2x gives the error of 192 uniform shells,
      2.0e-6; refining any other quarter leaves 4.9e-6).  That error falls like ``h^1.25`` (differences 2.4x per
      doubling up to 1536 shells), the order reduction of a frozen boundary layer, and uniform shells needed 384 to
      1536.  Graded towards ``q_max`` ("end", the last shell ``~h^2`` wide) the order is two again and Romberg
      applies: 48 shells leave 3.6e-7 before and 4.3e-8 after one Richardson step, against 1.2e-5 and 6.9e-6
      uniform; at ``zeta = 1`` (``kappa`` 770) uniform is better (Romberg from 48 shells 2.5e-8, graded 3.7e-7),
      and the balanced closures lose from ``kappa`` about 1 on (:data:`WALL_LAYER_RATIO`).
    * **the start** (with a thin layer only): ``lambda = p0^2 / tau_first``, the load's distance from the wall
      against the first uniform shell's diffusion length.  Below :data:`START_LAYER_RATIO` the first shells carry
      the start from ``delta(p - p0)`` into the wall's layer, and the order falls to one there too (``H = 0.8``,
      rms slope 0.031, ``p0 = 1e-5``, ``zeta = 1e-3``, balanced: differences 2.0x per doubling with uniform and
      "end" shells, 3.9x with "ends", whose 48 shells then leave 5e-9 after one Richardson step against 1e-6).

    "uniform" for ``kappa >=`` :data:`WALL_LAYER_RATIO`, else "end", or "ends" where also
    ``lambda <`` :data:`START_LAYER_RATIO`; the hard wall (``zeta = 0``, its shells commute) "uniform".
    The balanced closures take "ends" where ``lambda <`` :data:`START_LAYER_RATIO` up to ``kappa <``
    :data:`START_WALL_LAYER_RATIO`: a load far inside a layer that is thick at ``q_max`` only (``H = 0.8``, rms
    slope 0.1, ``q`` from ``2 pi/4096`` to ``2 pi/16``, ``zeta = 0.3``, ``p0 = 1e-5``: ``kappa`` 55, ``lambda``
    2e-6) left the uniform shells' Romberg table pre-asymptotic up to 48 shells (``R(n/2, n)`` 2e-4, 2e-6, 1.2e-5,
    8e-7 from the continuum at 12 ... 96 shells), and its estimate 30x optimistic (8.2e-7 against 2.5e-5); "ends"
    gives 2.8e-7 against an estimate of 3.7e-7.
    ``local_g1_shell_balanced`` takes "ends" wherever the layer is thin, whatever ``lambda``: measured on 21 scenes
    (two spectra, ``p0`` = 1e-3, 4e-3, 1.6e-2, ``zeta`` = 1e-3 ... 3e-2, docs/closures.md "The thin layer's table")
    it took at most 1.03x the time of "end" on 20 of them and half the shells or fewer on 11 (the Fig. 1 scene at
    ``zeta = 0.01``: 192 shells against 384); one scene lost 1.45x.

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
    thin_start = lam < START_LAYER_RATIO and kappa < START_WALL_LAYER_RATIO and closure in _BALANCED
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


def contact_fraction(theory: Any, *, zeta: float, mean_pressure: float) -> float:
    """Contact fraction of a theory with GFMD's definition (one definition for both).

    Hard wall (``zeta = 0``): ``P(p > 0) = 1 - zero_weight``.  Exponential wall:
    ``P(p > 0.01 p0)``, GFMD's threshold (``gfmd_ref`` reports the fraction of
    grid points above ``0.01 p0``).

    Parameters
    ----------
    theory : PressureDistribution
    zeta : float
        Wall range [length], >= 0.
    mean_pressure : float
        ``p0`` [pressure].
    """
    if float(zeta) == 0.0:
        return float(1.0 - theory.zero_weight)
    return float(1.0 - theory.cdf(CONTACT_THRESHOLD * float(mean_pressure)))


# --------------------------------------------------------------------------- model callables
def _common_kz(items: tuple) -> Optional[float]:
    """The ``kz > 0`` that all ``items`` share (their rows vectorize), else None.  The formulas clamp ``p`` at
    0."""
    kz = {it.kz for it in items}
    if len(kz) != 1 or kz == {0.0}:
        return None
    return kz.pop()


def _products(kz: float, items: tuple, name: str) -> np.ndarray:
    """``kz x [item.<name> for item in items]``: the shells' wall products ``kz q`` [pressure]."""
    return kz * np.array([getattr(it, name) for it in items], dtype=float)


class _RowPlan:
    """The rows of one shell model for a fixed set of shells, made once per problem and evaluated on many grids.

    ``plan(p, out=None)`` writes the rows at the pressures ``p`` (1-D, clamped at 0; a NaN stays NaN) into ``out``
    (a C-contiguous float array of shape ``(shells, p.size)``; a new one where None or of another layout) in one
    compiled pass (:func:`diffusion_pr.closures._kernels.model_rows`) and returns it, or None where a value is not
    finite (the caller then takes its checked path, which says where).
    """

    __slots__ = ("kq", "kq_part", "model")

    def __init__(self, kq: np.ndarray, kq_part: np.ndarray, model: int) -> None:
        self.kq, self.kq_part, self.model = kq, kq_part, int(model)

    def __len__(self) -> int:
        return int(self.kq.size)

    def __call__(self, p: np.ndarray, out: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
        from ._kernels import model_rows

        p = np.ascontiguousarray(p, dtype=float).reshape(-1)
        shape = (self.kq.size, p.size)
        target = out if (out is not None and out.shape == shape and out.dtype == np.float64
                         and out.flags.c_contiguous) else np.empty(shape)
        if not model_rows(self.kq, self.kq_part, p, self.model, target):
            return None
        if out is not None and target is not out:
            out[...] = target
            return out
        return target


class _ShellModel:
    """A shell model of ``p`` that is the constant ``_HARD_WALL`` for the hard wall (``kz = 0``) and one of the
    compiled formulas of :mod:`diffusion_pr.closures._kernels` otherwise (``p`` clamped at 0; imported on first
    use), evaluated row-wise for many shells at once.  Each model names its formula (``_MODEL``) and the wall
    products it takes (``_PRODUCTS``: the attributes multiplied by ``kz`` for ``kq`` and ``kq_part``)."""

    _HARD_WALL = 0.0

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=float)
        if self.kz == 0.0:
            return np.full_like(p, self._HARD_WALL)
        return type(self).rows((self,), p.reshape(-1))[0].reshape(p.shape)

    @classmethod
    def row_plan(cls, items: tuple) -> Optional[_RowPlan]:
        """The rows of ``items`` as a reusable evaluator (:class:`_RowPlan`: ``plan(p, out=None)``), or None where
        they do not share one ``kz > 0``.  The engine makes one per problem and model and evaluates it on every
        probe and grid."""
        kz = _common_kz(items)
        if kz is None:
            return None
        return _RowPlan(_products(kz, items, cls._PRODUCTS[0]), _products(kz, items, cls._PRODUCTS[1]), cls._MODEL)

    @classmethod
    def rows(cls, items: tuple, p: np.ndarray) -> np.ndarray:
        """``[m(p) for m in items]`` as a 2-D array in one vectorized pass (same values as calling each)."""
        plan = cls.row_plan(items)
        if plan is None:
            return np.array([it(p) for it in items])
        from ._kernels import model_rows

        p = np.ascontiguousarray(p, dtype=float).reshape(-1)
        out = np.empty((len(plan), p.size))
        model_rows(plan.kq, plan.kq_part, p, plan.model, out)  # (a plan's call says None where one is not finite)
        return out


class _LoadModel(_ShellModel):
    """A drift-type shell model: 0 on the hard wall.

    Model protocol (:mod:`diffusion_pr.models`): linear at ``p -> 0`` (``zero_power`` 1), smooth (no breakpoints).
    """

    zero_power = 1.0

    def breakpoints(self) -> tuple[float, ...]:
        return ()


@dataclass(frozen=True)
class LocalResponseDiffusivity(_ShellModel):
    """``f_k(p) = g(q_k; p)^2`` (dimensionless): the diffusivity of shell ``k``.

    Declares the model protocol of :mod:`diffusion_pr.models`: ``zero_power`` is 2 for
    ``zeta > 0`` (``f ~ (2p/(zeta q_k E*))^2``: the wall is never reached, ``ln p``
    diffuses) and 0 for the hard wall (``f = 1``: absorbing ``p = 0``, Persson).

    Parameters
    ----------
    q : float
        Shell wavenumber ``q_k`` [rad/length].
    kz : float
        ``zeta E*/2`` [pressure x length]; 0 for the hard wall.
    """

    q: float
    kz: float

    _HARD_WALL = 1.0  # f = 1: Persson
    _MODEL = 0  # _closure_kernels.DIFFUSIVITY: g(q_k)^2
    _PRODUCTS = ("q", "q")

    @property
    def zero_power(self) -> float:
        return 2.0 if self.kz > 0.0 else 0.0

    def breakpoints(self) -> tuple[float, ...]:
        return ()


@dataclass(frozen=True)
class LoadExcessDrift(_LoadModel):
    """``b_k(p) = (1 - g(q_part; p)) g(q_k; p)^2 / p`` [pressure per unit tau].

    The local load excess of the exponential response, removed in the fraction
    ``1 - g(q_part; p)`` (``q_part = q_min``).  Tends to 0 as ``p -> 0``
    (``~ 4 p/(kz q_k)^2``) and as ``zeta -> 0``.
    """

    q: float
    q_part: float
    kz: float

    _MODEL = 1  # _closure_kernels.DRIFT
    _PRODUCTS = ("q", "q_part")


@dataclass(frozen=True)
class RigidApproachBalance(_LoadModel):
    """``w(p) = (1 - g(q_part; p)) p`` [pressure per unit tau per unit A]: the rigid-body
    approach ``z0`` that restores the load, acting in the fraction ``1 - g(q_part; p)``."""

    q_part: float
    kz: float

    _MODEL = 2  # _closure_kernels.BALANCE
    _PRODUCTS = ("q_part", "q_part")


def closure_problem(shells: Shells, *, zeta: float, E_star: float, mean_pressure: float, closure: str,
                    partition_q: Optional[float] = None) -> Any:
    """The shell-by-shell closure as a :class:`~diffusion_pr.problem.StagedProblem`.

    One :class:`~diffusion_pr.problem.Stage` per shell ``k`` (duration ``dV0_k/2``,
    pressure^2) with ``f_k = g(q_k; p)^2``; for ``"local_g1_balanced"`` also
    ``b_k = (1 - g(q_min; p)) g(q_k; p)^2/p`` and the balance ``w = (1 - g(q_min; p)) p``
    (total drift ``b_k - A w``, ``A`` keeping ``<p> = p0``).  At the hard wall
    (``zeta = 0``: ``g = 1``, no drift) every stage holds the same diffusivity
    object ``f = 1`` (its ``q`` is ``q_min``), which the engine integrates as one
    exponential of the summed duration.

    Parameters
    ----------
    shells : Shells
        From :func:`spectrum_shells`.
    zeta : float
        Wall range [length], >= 0.
    E_star, mean_pressure : float
        ``E*`` and ``p0`` [pressure], > 0.
    closure : {"local_g1", "local_g1_balanced", "local_g1_shell_balanced"}
    partition_q : float or "shell", optional
        Wavenumber of the partition factor (default ``shells.q_min``; ``"shell"``
        takes each shell's own ``q_k``, which breaks the ``zeta -> 0`` limit and is
        there for the tests that show it).
    """
    from ..problem import Stage, StagedProblem

    if closure not in ("local_g1", *_BALANCED):
        raise ValueError("closure_problem builds 'local_g1', 'local_g1_balanced' or 'local_g1_shell_balanced'; "
                         f"got closure={closure!r}")
    if closure == "local_g1_shell_balanced":
        if partition_q is not None:
            raise ValueError("partition_q is fixed ('shell') for closure='local_g1_shell_balanced'")
        partition_q = "shell"
    kz = 0.5 * float(check_nonnegative("zeta", zeta)) * float(check_positive("E_star", E_star))
    stages = []
    # the hard wall: g = 1 in every shell; one diffusivity object for all (the engine then integrates the
    # commuting stages as one exponential: Persson's mirror Gaussian in one step)
    hard = LocalResponseDiffusivity(float(shells.q_min), 0.0) if kz == 0.0 else None
    # a partition at one wavenumber: one balance object for every shell (its w is the same function of p; the
    # engine asks a shared model for its breakpoints once)
    shared = None
    if closure != "local_g1" and kz > 0.0 and partition_q != "shell":
        shared = RigidApproachBalance(shells.q_min if partition_q is None else float(partition_q), kz)
    for q, dv in zip(shells.q.tolist(), shells.dV0.tolist()):
        f = hard if hard is not None else LocalResponseDiffusivity(q, kz)
        if closure == "local_g1" or kz == 0.0:
            stages.append(Stage(0.5 * dv, f))
        elif shared is not None:
            stages.append(Stage(0.5 * dv, f, LoadExcessDrift(q, shared.q_part, kz), shared))
        else:
            stages.append(Stage(0.5 * dv, f, LoadExcessDrift(q, q, kz), RigidApproachBalance(q, kz)))
    return StagedProblem(float(check_positive("mean_pressure", mean_pressure)), tuple(stages), label=closure,
                         balance_per_stage=True)


# --------------------------------------------------------------------------- closed form
def lognormal_gap_distribution(spectrum: Spectrum, *, E_star: float, mean_pressure: float, zeta: float,
                               n_cells: int = 4000) -> Any:
    r"""The ``"lognormal_gap"`` closure: a log-normal pressure, closed form.

    The gap fluctuation ``delta g~(q) = -(1 - G1(q)) h~(q)`` of the second-order
    response (Müser 2008, Eq. 10) is Gaussian with variance
    ``sum (1 - G1)^2 |h~|^2 = zeta^2 V / p0^2`` (since ``1 - G1 = (zeta q E*/(2 p0)) G1``);
    the wall law ``p = p_w exp(-g/zeta)`` makes ``ln p`` Gaussian with variance
    ``s^2 = V/p0^2`` (``V``: :func:`~diffusion_pr.cumulants.stress_variance`).  The
    mean is fixed to ``p0`` (force balance), so ``<ln p> = ln p0 - s^2/2``.

    The result is given on ``n_cells`` cells uniform in ``ln p`` over
    ``[<ln p> - 9.5 s, <ln p> + s^2 + 9.5 s]`` (plus ``[0, p_lo]``; the upper end
    covers where ``p Pr(p)`` lives) with the exact cell masses (normal CDF)
    and, as each cell's point, the exact conditional mean of ``p`` in the cell, so
    mass and mean are exact to round-off (the mass beyond ``9.5 s``, below 1e-20, is dropped).

    Parameters
    ----------
    spectrum : Spectrum
        Height spectrum (lengths in the unit of ``zeta``).
    E_star, mean_pressure : float
        ``E*`` and ``p0`` [pressure], > 0.
    zeta : float
        Wall range [length], > 0.  ``zeta = 0`` (hard wall) raises: the
        exponential wall law that makes the pressure log-normal does not exist there.
    n_cells : int
        Cells in ``ln p`` (>= 100).

    Returns
    -------
    PressureDistribution
        ``backend = "closed_form"``, ``diagnostics["closure"] = "lognormal_gap"``,
        ``diagnostics["ln_variance"] = s^2``.
    """
    from scipy.special import log_ndtr, ndtr

    from ..cumulants import stress_variance
    from ..result import PressureDistribution

    z = float(check_nonnegative("zeta", zeta))
    if z == 0.0:
        raise ValueError("closure='lognormal_gap' needs an exponential wall (zeta > 0); got zeta=0 (hard wall), "
                         "where no wall law maps gaps to pressures. Use 'second_order' (Persson) or 'local_g1_balanced'.")
    E = float(check_positive("E_star", E_star))
    p0 = float(check_positive("mean_pressure", mean_pressure))
    if not isinstance(n_cells, (int, np.integer)) or n_cells < 100:
        raise ValueError(f"n_cells must be an integer >= 100; got n_cells={n_cells!r}")
    t0 = time.perf_counter()
    V = float(stress_variance(spectrum, E_star=E, mean_pressure=p0, zeta=z))
    s2 = V / (p0 * p0)
    s = math.sqrt(s2)
    mu = math.log(p0) - 0.5 * s2
    # the mass lies within mu +- 9.5 s; the mean's integrand p Pr(p) is the same Gaussian in ln p
    # shifted by s^2, so the grid reaches mu + s^2 + 9.5 s
    top = mu + s2 + 9.5 * s
    if top - math.log(p0) > 690.0:
        raise ValueError(f"closure='lognormal_gap' is not defined here: its ln-variance s^2 = V/p0^2 = {s2:.4g} "
                         f"(zeta={z!r}, p0={p0!r}) puts the mean-carrying pressures exp({s2:.3g}/2) times above p0, "
                         "beyond floating point; the log-normal picture of the gap does not apply at such small "
                         "zeta / load (use 'local_g1_balanced')")
    x = np.linspace(mu - 9.5 * s, top, int(n_cells))
    edges = np.concatenate(([0.0], np.exp(x)))
    u = (x - mu) / s
    # cell masses from the CDF below the median and from the survival function above it
    # (differences of numbers near 1 would lose the far tail that carries the mean when s is large)
    lo_c, hi_c = ndtr(u[:-1]), ndtr(u[1:])
    lo_s, hi_s = ndtr(-u[:-1]), ndtr(-u[1:])
    upper = 0.5 * (u[:-1] + u[1:]) > 0
    mass = np.concatenate(([ndtr(u[0])], np.where(upper, lo_s - hi_s, hi_c - lo_c)))
    # partial expectations E[p; p < e] = exp(mu + s^2/2) Phi((ln e - mu - s^2)/s)
    pe = np.concatenate(([0.0], np.exp(mu + 0.5 * s2 + log_ndtr(u - s))))
    pm = np.diff(pe)
    widths = np.diff(edges)
    ok = mass > 0
    points = np.where(ok, pm / np.where(ok, mass, 1.0), 0.5 * (edges[1:] + edges[:-1]))
    points = np.clip(points, edges[:-1], edges[1:])
    density = mass / widths
    wall = time.perf_counter() - t0
    diag = {"closure": "lognormal_gap", "stress_variance": V, "ln_variance": s2, "ln_mean": mu, "zeta": z,
            "E_star": E}
    return PressureDistribution(points, density, widths, 0.0, p0, V, "closed_form", True,
                                "closed form (log-normal gap closure)", 0.0, wall, diag, edges)


# --------------------------------------------------------------------------- solving
#: floor of the balanced closure's non-contact region, relative to zeta q_min E*/2 (docs/closures.md)
BALANCED_FLOOR = 1e-16

def closure_distribution(spectrum: Spectrum, *, E_star: float, mean_pressure: float, zeta: float = 0.0,
                         closure: str = "local_g1_balanced", backend: str = "auto", rtol: float = 1e-6,
                         n_shells: Optional[int] = None, cutoff: Any = None, p_c: Optional[float] = None,
                         tail: Any = None, p_t: Optional[float] = None,
                         shell_extrapolation: Optional[bool] = None, **options: Any) -> Any:
    r"""Pressure distribution of a rough contact with a named closure (docs/closures.md).

    Parameters
    ----------
    spectrum : Spectrum
        :class:`~diffusion_pr.spectra.SelfAffineSpectrum` (continuum: shells by
        quadrature, :func:`spectrum_shells`) or
        :class:`~diffusion_pr.spectra.DiscreteSpectrum` (its own modes: use the
        realization's spectrum to compare with that realization).
    E_star : float
        Contact modulus ``E*`` [pressure], > 0.
    mean_pressure : float
        ``p0`` [pressure], > 0.
    zeta : float
        Wall range [length], >= 0; 0 is the hard wall.  At ``zeta = 0``:
        ``"second_order"`` (sharp cutoff) and the three shell closures are all
        Persson's mirror Gaussian (``g = 1``, no drift, absorbing wall);
        ``"lognormal_gap"`` raises.
    closure : {"second_order", "lognormal_gap", "local_g1", "local_g1_balanced", "local_g1_shell_balanced"}
        See the module docstring and docs/closures.md.
    backend : str
        ``"second_order"``: as :func:`diffusion_pr.pressure_distribution`.
        Shell-by-shell closures: the closure is a
        :class:`~diffusion_pr.problem.StagedProblem` (:func:`closure_problem`) solved
        by :func:`diffusion_pr.api.solve_problem` (``"auto"``, ``"native"``,
        ``"pypde"``, ``"fipy"``).
    rtol : float
        Target L1 error.
    n_shells : int, optional
        Continuum spectra: number of shells (default :data:`DEFAULT_CONTINUUM_SHELLS`).
    cutoff, p_c, tail, p_t
        Second order only (the paper's cutoff near ``p = 0`` and the tail factor).
        The other closures have no cutoff (``g(q; p)^2 ~ p^2`` is theirs) and no
        tail factor; passing one raises ``ValueError``.
    shell_extrapolation : bool, optional
        Shell closures on a continuum spectrum.  The shell sum is the
        exponential midpoint rule in ``tau``, second order in the shell width:
        96 shells alone differ from the continuum closure by 2.5-6e-5 in the
        cdf (1.3-1.6e-4 in L1) on the Fig. 1 scene, 50x rtol 1e-6.  Default
        (None): True for a continuum spectrum without ``n_shells``, else False.
        True: the continuum closure, extrapolated in the number of shells
        cell by cell on the ``n``-shell solve's grids (``n`` = ``n_shells``, a
        multiple of 4, default :data:`EXTRAPOLATION_SHELLS` = 48): the
        ``n/2``-, ``n/4``- and ``n/8``-shell problems are integrated on its two
        coarser grids (all three where the correction's own spatial error
        needs it), and :func:`_shell_table` combines them: Romberg to sixth
        order, ``(16 R(n/2, n) - R(n/4, n/2))/15`` with
        ``R(n/2, n) = (4 Pr(n) - Pr(n/2))/3``, where the observed order is four
        (the rule is symmetric: exact ``tau``-midpoints), else ``R(n/2, n)``
        with its residual divided by the observed order.  ``error_estimate``
        is the grids' estimate plus the correction's spatial error plus that
        residual in L1; where it misses ``rtol`` the shells double (up to
        :data:`MAX_CONTINUUM_SHELLS`, each doubling one more solve on the same
        grids; ``diagnostics["shells_solved"]``).
        ``diagnostics["shell_error"]`` is the ``n``-shell problem's distance from
        the continuum, ``L1 |Pr(n) - Pr(n/2)|/3``.  On the Fig. 1 scene at
        rtol 1e-6: 6-21 ms at ``zeta >= 0.1``; below, where the wall's layer is
        thin, the shells are graded towards the ends of the diffusion time
        (:func:`shell_grading`; uniform shells converge at an order of 1-1.25
        there): 6-96 ms, mostly the balanced closures' larger grids
        (docs/closures.md, "Graded shells").
        False: the ``n``-shell problem itself within ``rtol`` (its estimate
        does not contain the distance from the continuum; a
        :class:`~diffusion_pr.spectra.DiscreteSpectrum`'s shells are exact).
    **options
        The backend's options.

    Returns
    -------
    PressureDistribution
        ``diagnostics["closure"]`` names the closure.
    """
    return _closure_distribution(spectrum, E_star=E_star, mean_pressure=mean_pressure, zeta=zeta, closure=closure,
                                 backend=backend, rtol=rtol, n_shells=n_shells, cutoff=cutoff, p_c=p_c, tail=tail,
                                 p_t=p_t, shell_extrapolation=shell_extrapolation,
                                 **options)[0]


def _closure_distribution(spectrum: Spectrum, *, E_star: float, mean_pressure: float, zeta: float = 0.0,
                          closure: str = "local_g1_balanced", backend: str = "auto", rtol: float = 1e-6,
                          n_shells: Optional[int] = None, cutoff: Any = None, p_c: Optional[float] = None,
                          tail: Any = None, p_t: Optional[float] = None,
                          shell_extrapolation: Optional[bool] = None, warm_start: Any = None,
                          **options: Any) -> tuple:
    """``(result, solution)``: :func:`closure_distribution`'s result and the finite-volume solution of its (last)
    ``n``-shell solve (None where there is none), which started from ``warm_start`` (a sweep's, a
    :class:`~diffusion_pr.fokker_planck.engine.WarmStart`)."""
    closure = check_closure(closure)
    for name, value in (("E_star", E_star), ("mean_pressure", mean_pressure), ("zeta", zeta)):
        if np.ndim(value) != 0:
            raise ValueError(f"{name} must be a scalar (loop for several distributions); got an array of shape "
                             f"{np.shape(value)}")
    E = float(check_positive("E_star", E_star))
    p0 = float(check_positive("mean_pressure", mean_pressure))
    z = float(check_nonnegative("zeta", zeta))
    if shell_extrapolation is not None and not isinstance(shell_extrapolation, (bool, np.bool_)):
        raise ValueError(f"shell_extrapolation must be None, True or False; got "
                         f"shell_extrapolation={shell_extrapolation!r}")
    if shell_extrapolation is None:  # the default: the continuum closure where the shells are a quadrature
        shell_extrapolation = bool(closure not in ("second_order", "lognormal_gap")
                                   and not isinstance(spectrum, DiscreteSpectrum) and n_shells is None)
    if shell_extrapolation is not False and closure in ("second_order", "lognormal_gap"):
        raise ValueError("shell_extrapolation applies to the shell closures ('local_g1', 'local_g1_balanced', "
                         "'local_g1_shell_balanced') on the finite-volume backends; got "
                         f"closure={closure!r}, backend={backend!r}")
    if closure == "second_order":
        from ..api import pressure_distribution

        if n_shells is not None:
            raise ValueError("n_shells applies to the shell-by-shell closures, not to 'second_order'")
        return pressure_distribution(spectrum, E_star=E, mean_pressure=p0, zeta=z,
                                     cutoff="sharp" if cutoff is None else cutoff, p_c=p_c, tail=tail, p_t=p_t,
                                     backend=backend, rtol=rtol, **options), None
    for name, value in (("cutoff", cutoff), ("p_c", p_c), ("tail", tail), ("p_t", p_t)):
        if value is not None and not (name == "cutoff" and value == "sharp" and z == 0.0):
            raise ValueError(f"{name} applies to closure='second_order' only; closure={closure!r} has no fitted "
                             f"cutoff or tail (got {name}={value!r})")
    if closure == "lognormal_gap":
        if n_shells is not None:
            raise ValueError("shell options (n_shells) do not apply to closure='lognormal_gap' (closed form)")
        return lognormal_gap_distribution(spectrum, E_star=E, mean_pressure=p0, zeta=z), None
    grading, kappa, lam = shell_grading(spectrum, E_star=E, zeta=z, mean_pressure=p0, closure=closure) \
        if shell_extrapolation \
        else ("uniform", None, None)
    shells = _cached_shells(spectrum, E, EXTRAPOLATION_SHELLS if shell_extrapolation and n_shells is None
                            else n_shells, grading)
    problem = closure_problem(shells, zeta=z, E_star=E, mean_pressure=p0, closure=closure)
    if closure in _BALANCED and z > 0:
        # part of the closure's definition, not an accuracy knob: its drift cancels the Ito drift of
        # ln p below p* = zeta q_min E*/2, so mass returns from deep below p*; resolve down to
        # BALANCED_FLOOR p* (docs/closures.md), as the reference solver does
        options.setdefault("p_floor", BALANCED_FLOOR * 0.5 * z * E * shells.q_min)
    if shell_extrapolation:
        if shells.exact:
            raise ValueError("shell_extrapolation applies to continuum spectra; a DiscreteSpectrum's shells are its "
                             "own modes (exact)")
        if shells.q.size % 4:
            raise ValueError(f"shell_extrapolation needs n_shells divisible by 4 (n, n/2, n/4 shells); got "
                             f"n_shells={shells.q.size}")
    scene = (spectrum, E, p0, z, closure, grading)
    sol = _solve_shells(problem, shells, closure, backend, rtol, options, keep=shell_extrapolation,
                        warm_start=warm_start)
    if not shell_extrapolation:
        return sol.result, sol
    first = int(shells.q.size)
    tightened = False  # the first solve was repeated on tighter grids (once at most)
    spent = 0.0  # the discarded attempts' time (a retry on tighter grids, a restart from twice the shells)
    while True:
        out = _shell_extrapolated(sol, scene, rtol, options)
        n = int(sol.result.diagnostics["n_shells"])
        if (not out.success and not tightened and out.diagnostics.get("shell_extrapolation")
                and out.diagnostics.get("grid_estimate", 0.0) >= SHELL_SHARE * rtol):
            # the grids' share left no room for the shells' residual (the full-solve fallback weighs each solve's
            # estimate, 1.9x the sum with Romberg's weights: H = 0.5, slope 0.3, p0 = 1e-5, zeta = 30, shell
            # partition, grids 9.3e-7 + shells 4.4e-6): once more on the finer grids of a tighter first solve
            tightened = True
            spent += out.wall_time
            sol = _solve_shells(problem, shells, closure, backend, GRID_RETRY_FRACTION * rtol, options, keep=True,
                                warm_start=warm_start,
                                note={"grids_tightened": f"the grids' estimate {out.diagnostics['grid_estimate']:.2e} "
                                                         f"left no room for the shells' residual at rtol {rtol:.1e}"})
            continue
        if "shell_extrapolation_failed" not in out.diagnostics or 2 * n > MAX_CONTINUUM_SHELLS:
            out = replace(out, diagnostics={**out.diagnostics, "shell_grading": grading, "wall_layer_ratio": kappa,
                                            "start_layer_ratio": lam})
            return (out if spent == 0.0 else replace(out, wall_time=out.wall_time + spent)), sol
        # a coarser-shell problem did not solve on these grids (wide shells on a steep spectrum at a small load):
        # all three with twice the shells, on the grids of the finer first solve
        spent += out.wall_time
        problem, shells = _shell_problem(scene, 2 * n)
        sol = _solve_shells(problem, shells, closure, backend, rtol, options, keep=True, warm_start=warm_start,
                            note={"shells_first_tried": first})


def _shell_residual(m_n: np.ndarray, m_h: np.ndarray, m_q: np.ndarray) -> tuple:
    """``(estimate, rho, difference)``: the L1 error of ``R(n/2, n) = (4 m(n) - m(n/2))/3`` from the masses of
    ``n``, ``n/2`` and ``n/4`` shells, the observed ratio ``rho = |m(n/2) - m(n/4)| / |m(n) - m(n/2)|`` (L1; 4 for
    the midpoint rule's second order) and ``|R(n/2, n) - R(n/4, n/2)|`` in L1.

    With an error ``a n^-p`` the extrapolation leaves ``a n^-p (4 - 2^p)/3`` and
    ``R(n/2, n) - R(n/4, n/2) = a n^-p (4 - 2^p)(1 - 2^p)/3``: the error is that difference over ``rho - 1``
    (``rho = 2^p``).  Where ``rho`` >= :data:`SHELL_ORDER_RATIO` the second order is taken as asymptotic and
    the difference is the fourth-order term, over 15; below it (measured: ``local_g1`` at ``zeta = 0.001``,
    2.3-2.4 in the sup of the cdf up to 1536 uniform shells: the last shells freeze the wall's thin layer,
    :func:`shell_grading`) over ``max(rho - 1, 1)``."""
    d_top = float(np.sum(np.abs(m_n - m_h)))
    d_half = float(np.sum(np.abs(m_h - m_q)))
    rho = d_half / d_top if d_top > 0.0 else math.inf
    difference = float(np.sum(np.abs((4.0 * m_n - m_h) / 3.0 - (4.0 * m_h - m_q) / 3.0)))
    return difference / (15.0 if rho >= SHELL_ORDER_RATIO else max(rho - 1.0, 1.0)), rho, difference


def _shell_problem(scene: tuple, m: int) -> tuple:
    """``(problem, shells)``: the closure of ``scene = (spectrum, E, p0, z, closure, grading)`` on
    ``m`` shells of its continuum spectrum."""
    spectrum, E, p0, z, closure, grading = scene
    shells = _cached_shells(spectrum, E, m, grading)
    return closure_problem(shells, zeta=z, E_star=E, mean_pressure=p0, closure=closure), shells


def _ladder_below(top: int) -> list:
    """The shell counts :func:`_shell_corrected` solves first below ``top``: ``top/2``, ``top/4`` and, where it
    divides and is at least :data:`MIN_ROMBERG_SHELLS`, ``top/8``."""
    return [top // 2, top // 4] + ([top // 8] if top % 8 == 0 and top // 8 >= MIN_ROMBERG_SHELLS else [])


def _solve_shells(problem: Any, shells: Shells, closure: str, backend: str, rtol: float, options: dict, *,
                  keep: bool, warm_start: Any = None, note: Optional[dict] = None) -> Any:
    """The closure's :class:`~diffusion_pr.fokker_planck.engine.FVSolution` with the closure and the shell count in
    the result's diagnostics (and ``note``); with ``keep`` the last level's plain masses too (the shell
    extrapolation's corrections are taken from them)."""
    from ..api import _solve_full

    sol = _solve_full(problem, backend, rtol, options, plain="keep" if keep else None, warm_start=warm_start)
    res = sol.result
    return replace(sol, result=replace(res, diagnostics={**res.diagnostics, "closure": closure,
                                                         "n_shells": int(shells.q.size), **(note or {})}))


def _coarser_on_grid(sol: Any, m: int, scene: tuple, rtol: float, options: dict, *, plain: Optional[str]) -> Any:
    """The ``m``-shell problem of ``scene = (spectrum, E, p0, z, closure, grading)`` solved on the
    grids of ``sol`` (the ``n``-shell solution), in full (``plain=None``) or for the plain masses of some of its
    grids alone (``plain`` a mode of :data:`~diffusion_pr.fokker_planck.engine.PLAIN_GRIDS`); a balance with no root
    there is a failed solution that says so."""
    from ..api import _solve_full
    from ..fokker_planck.engine import FVSolution

    res = sol.result
    sub = {k: v for k, v in options.items() if k != "n_cells"}  # (the grid fixes the cells)
    problem, _ = _shell_problem(scene, m)
    try:
        return _solve_full(problem, res.backend, rtol, sub, grid=sol.grid, plain=plain)
    except RuntimeError as exc:
        why = f"{type(exc).__name__}: {exc}"
        return FVSolution(result=replace(res, success=False, message=why, wall_time=0.0,
                                         diagnostics={"n_stages": len(problem.stages)}),
                          plain_failure=str(exc))


def _failed_extrapolation(res: Any, why: str) -> Any:
    """``res`` (the ``n``-shell answer) marked as a failed shell extrapolation, saying why."""
    n = int(res.diagnostics["n_shells"])
    diag = {**res.diagnostics, "shell_error": None, "shell_extrapolation": False, "shell_extrapolation_failed": why}
    return replace(res, success=False, diagnostics=diag,
                   message=f"shell extrapolation failed: {why}; the {n}-shell answer is returned")


def _shell_extrapolated(sol: Any, scene: tuple, rtol: float, options: dict) -> Any:
    """The continuum closure from the ``n``-shell solution ``sol`` (:func:`_shell_corrected` where its plain masses
    were kept, else :func:`_shell_combined`)."""
    z = scene[3]
    res = sol.result
    if z == 0.0 or not res.success or res.edges is None or sol.grid is None:
        diag = {**res.diagnostics, "shell_error": 0.0 if z == 0.0 else None, "shell_extrapolation": False}
        return replace(res, diagnostics=diag)
    if sol.plain is not None:
        out = _shell_corrected(sol, scene, rtol, options)
        if out.success:
            return out
        # the plain grids' correction misses rtol (on steep spectra at small loads its spatial error dominates):
        # the n/2 and n/4-shell problems are solved in full instead
        combined = _shell_combined(sol, scene, rtol, options)
        tried = out.diagnostics["timings"].get("shells", 0.0)
        timings = dict(combined.diagnostics["timings"])
        timings["shells"] = timings.get("shells", 0.0) + tried
        return replace(combined, wall_time=combined.wall_time + tried,
                       diagnostics={**combined.diagnostics, "timings": timings,
                                    "shell_correction_missed": out.message})
    return _shell_combined(sol, scene, rtol, options)


def _shell_corrected(sol: Any, scene: tuple, rtol: float, options: dict) -> Any:
    """The continuum closure as ``res = sol.result`` plus a correction from plain grids.

    ``res`` (``n`` shells) is extrapolated in space; the difference between it and the continuum is a
    difference between problems on the same grid, whose spatial errors are correlated: it is taken from the
    plain masses ``P`` of the last level's grids alone (``plain=`` of :func:`~diffusion_pr.fokker_planck.engine.solve_fv_full`),
    solved for ``n/2``, ``n/4`` and ``n/8`` shells on ``res``'s grids.  With ``top`` the most shells solved, the
    shells' table (:func:`_shell_table`) gives the continuum ``X`` on each grid (Richardson ``R(top/2, top)``, or
    Romberg's sixth order where the observed order allows it) and its residual; the correction is
    ``c = X(top) - P(n)`` per grid, and the answer ``m(res) + c``.

    First from the ``N`` and ``2N`` grids alone: ``c`` on the ``2N`` grid extrapolated in space
    (:func:`_correction_in_space`; ``c_2N`` itself where the problem's own grids do not trust that).  Its error is
    counted as the extrapolation's own estimate on uniform shells, and at the second-order size
    ``|agg(c_2N) - c_N|/3`` (the error of ``c_2N``) where the wall's layer is thin: the thin layer's tables were
    2-3.5x optimistic on scenes where that margin hid it (docs/closures.md "The correction's own error counted").
    The second-order size grows with the correction (0.55-0.66e-6 on the Fig. 1 scene at 48 shells, where the
    correction is 6e-4 in L1).  Where the counted error leaves the sum above ``rtol``, the ``4N``
    grids are integrated too and the correction is extrapolated in space as the answer is,
    ``(4 agg(c_4N) - c_2N)/3`` on the ``2N`` grid, its error the engine's estimate of that extrapolation (the full
    solves' price, nothing integrated twice).  Where the sum still misses ``rtol`` the ``2 top``-shell problem is
    solved on the same grids (per doubling, the grids the correction uses).  The cost: the ``n/2``, ``n/4`` and
    ``n/8``-shell problems on the two coarser grids, 0.38x ``res`` (0.88x with the ``4N`` grids)."""
    from ..fokker_planck.engine import RICHARDSON_DIVISOR
    from ..fokker_planck.grid import same_grid

    res = sol.result
    n = int(res.diagnostics["n_shells"])
    plain = {n: list(sol.plain)}
    timing = {"shells": 0.0}
    finest = False  # the correction from the 4N grids too, extrapolated in space
    evaluated: dict = {}  # ("base", n) -> the first table's evaluation (the later rungs' tables add to it)
    thin = scene[5] != "uniform"  # graded shells: the wall's layer is thin (shell_grading)
    # the later rungs on the N grid alone (graded shells only): their refinement of the first table's continuum is
    # added to that table's correction; "coarse" off once the 2N grids are wanted after all (the margin misses, or
    # the 4N grids)
    state = {"coarse": thin, "base": n}

    def masses_of(s: Any, mode: str) -> Optional[list]:
        # (the answer's grid is the 2N grid: the N grid is its every second edge, the 4N grid's every second edge it)
        own = s.result.edges[::2] if mode == "finest" else s.result.edges
        theirs = res.edges[::2] if mode == "coarsest" else res.edges
        ok = not (s.plain_failure or s.plain is None or not same_grid(own, theirs))
        return list(s.plain) if ok else None

    def solve_plain(ms: list, mode: str) -> dict:
        out = {}
        for m in ms:
            s = _coarser_on_grid(sol, m, scene, rtol, options, plain=mode)
            timing["shells"] += s.result.wall_time
            out[m] = masses_of(s, mode)
        return out

    def on_the_grids(ms: list) -> None:
        mode = "coarsest" if state["coarse"] and ms and min(ms) > state["base"] else "only"
        for m, got in solve_plain([m for m in ms if m not in plain], mode).items():
            plain[m] = got
        if finest:
            add_grid(2, "finest", ms)

    def add_grid(g: int, mode: str, ms: list) -> None:
        """Grid ``g`` (the plain mode ``mode`` integrates it alone) of the shell counts ``ms`` that lack it."""
        for m, got in solve_plain([m for m in ms if plain[m] is not None and plain[m][g] is None], mode).items():
            if got is None:
                plain[m] = None
            else:
                plain[m][g] = got[g]

    def fill_answer_grids() -> None:
        """The 2N grids of the rungs solved on the N grid alone: every table on both grids again."""
        state["coarse"] = False
        add_grid(1, "answer", list(plain))

    l1, agg = _l1, _aggregated

    def table(top: int, masses: dict, g: int) -> tuple:
        eighth = top % 8 == 0 and masses.get(top // 8) is not None
        used = [top >> k for k in range(4 if eighth else 3)]
        return _shell_table([masses[m][g] for m in used], thin=thin, start=scene[5] == "ends")

    def evaluate(top: int, masses: dict, finest: bool) -> dict:
        """The correction and its errors from the table of ``top`` shells (``masses`` the plain masses by shell
        count, every rung of ``_ladder_below(top)`` in it)."""
        if state["coarse"] and top > state["base"]:
            return evaluate_coarse(top, masses)
        c = [None, None, None]
        ev: dict = {"split": False, "split_error": None, "refinement_error": None}  # split: from the N and 2N grids
        for g in ((0, 1, 2) if finest else (0, 1)):
            x, res_g, table_g = table(top, masses, g)
            c[g] = x - masses[n][g]
            if g == 1:  # the answer's grid: its residual and orders
                ev["residual"], ev["table"] = res_g, table_g
        if finest:
            ev["corr"] = (4.0 * agg(c[2]) - c[1]) / 3.0
            ev["corr_error"] = l1(agg(ev["corr"]) - (4.0 * agg(c[1]) - c[0]) / 3.0) / RICHARDSON_DIVISOR
        else:
            ev["corr"], ev["split_error"], ev["corr_error"], ev["split"] = _correction_in_space(c[0], c[1],
                                                                                             masses[n])
        # counted: on uniform shells the extrapolated correction's own error; where the wall's layer is thin the
        # second-order size, a margin the thin layer's table needs (docs/closures.md "The correction's own error
        # counted")
        ev["counted"] = ev["split_error"] if ev["split"] and not finest and not thin else ev["corr_error"]
        ev["grids"] = res.error_estimate + ev["counted"]
        # the N grid's continuum, and that grid's relative error of the correction (4 s / |c_2N|: the later rungs'
        # refinement, a difference of the same kind, is counted with it)
        size = l1(c[1])
        ev["x_coarse"], ev["n_relative"] = c[0] + masses[n][0], 4.0 * ev["corr_error"] / size if size > 0.0 else 0.0
        return ev

    def evaluate_coarse(top: int, masses: dict) -> dict:
        """:func:`evaluate` where the rungs above the first table's (``state["base"]``) are on the N grid alone: the
        first table's correction (extrapolated in space as there) plus the refinement of the N grid's continuum
        from the first table's to this one's, split onto the 2N grid; that refinement's spatial error is counted as
        :data:`REFINEMENT_MARGIN` times its size times the N grid's relative error of the first correction
        (``4 s / |c_2N|``, ``s`` that correction's second-order estimate on the 2N grid)."""
        base = state["base"]
        ev0 = evaluated["base", base]  # (kept by the loop where it doubled from the first table)
        x_n, residual, table_n = table(top, masses, 0)
        refinement = x_n - ev0["x_coarse"]
        ev = dict(ev0)
        ev["corr"] = ev0["corr"] + _split_to_finer(refinement)
        ev["refinement_error"] = REFINEMENT_MARGIN * ev0["n_relative"] * l1(refinement)
        ev["counted"] = ev0["counted"] + ev["refinement_error"]
        ev["grids"] = res.error_estimate + ev["counted"]
        ev["residual"], ev["table"] = residual, table_n
        return ev

    def next_step(top: int, ev: dict, finest: bool) -> str:
        """What the ladder does after the table of ``top`` shells: "done", "finest" (the correction's spatial
        error misses: the 4N grids), "full" (the later rungs' 2N grids: their refinement's counted error is what
        misses), "stop" (no room or no more shells) or "double"."""
        if ev["grids"] + ev["residual"] <= rtol:
            return "done"
        coarse = ev["refinement_error"] is not None
        if coarse and ev["grids"] - ev["refinement_error"] + ev["residual"] <= rtol:
            return "full"
        if not finest and plain[n][2] is not None and ev["counted"] > ev["residual"]:
            return "full" if coarse else "finest"
        if 2 * top > MAX_CONTINUUM_SHELLS or ev["grids"] >= SHELL_SHARE * rtol:
            return "full" if coarse else "stop"
        return "double"

    top = n
    while True:
        wanted = _ladder_below(top)
        on_the_grids(wanted)
        if plain[top] is None or plain[top // 2] is None or plain[top // 4] is None:
            return _failed_extrapolation(res, f"a coarser-shell problem did not solve on the {n}-shell grids")
        ev = evaluate(top, plain, finest)
        step = next_step(top, ev, finest)
        if step == "full":  # the later rungs' 2N grids after all: the table of this top on both grids
            fill_answer_grids()
            continue
        if step == "finest":
            finest = True  # the correction's spatial error is what misses: extrapolate it in space
            on_the_grids(list(plain))
            continue
        if step != "double":
            break
        if top == state["base"]:
            evaluated["base", top] = ev  # the first table, on both grids (the later rungs' tables add to it)
            # the later rungs on the N grid alone where their refinement's counted error, predicted from this
            # table's residual (the refinement's expected size), leaves room for theirs
            if REFINEMENT_MARGIN * ev["n_relative"] * ev["residual"] > COARSE_ROOM * (rtol - ev["grids"]):
                state["coarse"] = False
        top *= 2
        on_the_grids([top])
        if plain[top] is None:
            top //= 2
            break
    corr, corr_error, split_error, split = ev["corr"], ev["corr_error"], ev["split_error"], ev["split"]
    counted, grids, residual, table_diag = ev["counted"], ev["grids"], ev["residual"], ev["table"]
    estimate = grids + residual
    coarse_rungs = tuple(sorted(m for m in plain if plain[m] is not None and plain[m][1] is None))
    # the first moments per cell: the answer's, corrected with the plain cells' (at their centres)
    mom = res.p * (res.density * res.weights) + 0.5 * (res.edges[:-1] + res.edges[1:]) * corr[1:]
    return _continuum_result(res, _masses(res) + corr, mom, estimate=estimate, grids=grids, residual=residual,
                             shell_error=l1(plain[n][1] - plain[n // 2][1]) / 3.0, n=top, p0=scene[2], rtol=rtol,
                             extra={"shell_correction_error": corr_error, "shell_correction_counted": counted,
                                    "shell_correction_extrapolated_error": split_error if split and not finest
                                    else None, **table_diag,
                                    "shells_solved": tuple(sorted(m for m in plain if plain[m] is not None)),
                                    "shells_on_the_coarse_grid": coarse_rungs,
                                    "shell_refinement_error": ev["refinement_error"],
                                    "shell_scheme": "correction from plain grids" + (
                                        ", extrapolated in space (4N grids)" if finest else
                                        ", extrapolated in space (N and 2N grids)" if split else "") + (
                                        f", refined by the N grid's rungs {coarse_rungs}" if coarse_rungs else "")},
                             extra_time=timing["shells"])


def _l1(x: np.ndarray) -> float:
    """The L1 norm of masses ``[zero weight, cells]``."""
    return float(np.sum(np.abs(x)))


def _aggregated(x: np.ndarray) -> np.ndarray:
    """Masses ``[zero weight, cells]`` of a grid aggregated to the grid half as fine (the inverse of
    :func:`_split_to_finer`)."""
    return np.concatenate(((x[0],), x[1::2] + x[2::2]))


def _split_to_finer(x: np.ndarray) -> np.ndarray:
    """Masses ``[zero weight, cells]`` of a grid onto the grid twice as fine (its cells halved in the monitor
    coordinate): each cell's mass shared by its two halves as a density linear across the cell would share it, the
    slope from the neighbours (one-sided at the ends); the zero weight as it is.  ``agg`` of the result is ``x``."""
    cells = x[1:]
    slope = np.zeros_like(cells)  # the left half's deficit = the right half's excess
    if cells.size >= 2:
        slope[1:-1] = (cells[2:] - cells[:-2]) / 16.0
        slope[0] = (cells[1] - cells[0]) / 8.0
        slope[-1] = (cells[-1] - cells[-2]) / 8.0
    out = np.empty(1 + 2 * cells.size)
    out[0] = x[0]
    out[1::2] = 0.5 * cells - slope
    out[2::2] = 0.5 * cells + slope
    return out


def _correction_in_space(c_coarse: np.ndarray, c_fine: np.ndarray, own: list) -> tuple:
    """``(correction, its L1 error estimate, the second-order estimate, extrapolated)``: the shells' correction
    ``c`` of the ``N`` and ``2N`` grids (``[zero weight, cells]`` each) extrapolated in space onto the ``2N`` grid.

    ``c`` converges at second order in the cell width, so ``R = (4 agg(c_2N) - c_N)/3`` is the fourth-order
    correction on the ``N`` grid.  On the ``2N`` grid: ``c_2N + split(agg(c_2N) - c_N)/3``
    (:func:`_split_to_finer`), which aggregates to ``R``.  Its error is not observed (that needs the ``4N``
    grids); it is taken as the second-order estimate ``s = |agg(c_2N) - c_N|/3`` times
    ``max(SPLIT_MARGIN rho, SPLIT_FLOOR)``, with ``rho`` the same extrapolation's observed error on the
    ``n``-shell problem's own masses ``own = [P_N, P_2N, P_4N]`` (against ``(4 agg(P_4N) - P_2N)/3``) over its
    ``s``.  Where that factor is not below 1, or ``P_4N`` is missing, ``c_2N`` with ``s`` (second order).  The
    caller counts ``s`` in the answer's estimate either way.

    Measured (docs/closures.md "The correction extrapolated in space"): against the correction from the ``4N``
    grids, the extrapolated one is 40-1000x closer than ``c_2N`` on the Fig. 1 scenes (``rho`` of the correction
    0.001-0.025, of the problem 0.003-0.026)."""
    l1, agg = _l1, _aggregated
    second = l1(agg(c_fine) - c_coarse) / 3.0
    p_n, p_2n, p_4n = own
    if p_4n is None or second == 0.0:
        return c_fine, second, second, False
    own_second = l1(agg(p_2n) - p_n) / 3.0
    if own_second == 0.0:
        return c_fine, second, second, False
    own_error = l1(p_2n + _split_to_finer(agg(p_2n) - p_n) / 3.0 - (4.0 * agg(p_4n) - p_2n) / 3.0)
    factor = max(SPLIT_MARGIN * own_error / own_second, SPLIT_FLOOR)
    if factor >= 1.0:
        return c_fine, second, second, False
    return c_fine + _split_to_finer(agg(c_fine) - c_coarse) / 3.0, factor * second, second, True


def _shell_table(ladder: list, thin: bool = False, start: bool = False) -> tuple:
    """``(continuum, residual, diagnostics)`` from the masses ``[P(n), P(n/2), P(n/4)(, P(n/8))]`` of one grid.

    The exponential midpoint rule with exact ``tau``-midpoints is symmetric: its error is even in the shell width,
    ``a h^2 + b h^4 + c h^6 + ...`` where the coefficients are smooth (every closure at ``zeta >= 0.1`` on the
    Fig. 1 scene: ``R(n/2, n) = (4 P(n) - P(n/2))/3`` falls 15.5-16.4x per doubling).  Near ``p* = zeta q E*/2``
    at small ``zeta`` the order is lower (``zeta = 0.01``: ``R`` falls 3-11x per doubling; ``zeta = 0.001``: 2.4-4x).
    The observed ratio of ``R``'s successive differences decides, with ``P(n/8)``:

    * above :data:`ROMBERG_MAX_RATIO`: the order is not observed (the coarse end of the ladder is pre-asymptotic and
      a finer ``R`` may lie near the continuum by a crossing of its terms: 33 and 42 on two stress scenes where
      Romberg was 19x and 3.8x optimistic, docs/closures.md "Pre-asymptotic shell ladders and thin starts"): ``R(n/2, n)`` with its
      last difference, undivided, as the residual;
    * at least :data:`ROMBERG_RATIO` (fourth order asymptotic): Romberg's next column,
      ``(16 R(n/2, n) - R(n/4, n/2))/15``, with its difference from the same at half the shells over 15 as the
      residual (that assumes a fourth order only; the sixth it has gives /63, so the estimate is about 4x safe:
      2-4e-8 at 48 shells against estimates of 0.8-1.0e-7);
    * below: ``R(n/2, n)`` with its difference from ``R(n/4, n/2)`` over ``rho - 1`` (``rho`` that ratio,
      ``rho - 1`` at most 15), never less than :func:`_shell_residual` says from the ``P`` alone; where the ``P``
      differences fall slower than :data:`SECOND_ORDER_CLEAR` (no clear second order), ``rho`` is at most their
      ratio: a term below second order remains in ``R`` and need not fall faster than they do.

    Without ``P(n/8)`` (a balance with no root on 6 shells, or ``n`` not divisible by 8), ``R(n/2, n)`` with
    :func:`_shell_residual`.  ``diagnostics["shell_weights"]``: the continuum as weights of ``P(n) ... P(n/8)``
    (for the first moments and the spatial errors of full solves, :func:`_shell_combined`).

    With ``P(n/8)``, these rules decide on the zero weight (the probability below the
    floor) and on the cells apart (:func:`_uniform_table` on each): each part takes its own branch, continuum and
    residual, and the residuals add. The zero weight converges on its own (its ``R`` ratios 1.3-52 where the cells'
    were 6-22 on the seven worst-estimated of 649 random uniform ladders), and in the L1 sums the cells' larger
    differences hid it. The diagnostics keep the whole ladder's ratios; ``shell_extrapolation_order`` and
    ``shell_weights`` are the cells', ``zero_weight_extrapolation_order`` and ``zero_weight_order_ratios`` the zero
    weight's, ``grid_weights`` the larger of the two parts' weights.

    With ``thin`` (graded shells: the wall's layer is thin, :func:`shell_grading`) :func:`_thin_layer_table`;
    ``start``: the shells are graded at both ends ("ends")."""
    if thin:
        return _thin_layer_table(ladder, start)
    if len(ladder) < 4:
        x, residual, info = _uniform_table(ladder)
        info.pop("l1", None)
        return x, residual, info
    # (the zero weight as numpy scalars: the same arithmetic as on a one-element array, without its overhead)
    (x0, r0, i0), (x1, r1, i1) = (_uniform_table([m[part] for m in ladder]) for part in (0, slice(1, None)))
    p_top, p_half, r_top, r_half = (a + b for a, b in zip(i0.pop("l1"), i1.pop("l1")))  # the whole ladder's
    info = dict(i1, shell_order_ratio=p_half / p_top if p_top > 0.0 else math.inf,
                richardson_order_ratio=r_half / r_top if r_top > 0.0 else math.inf,
                zero_weight_extrapolation_order=i0["shell_extrapolation_order"],
                zero_weight_order_ratios=(i0["shell_order_ratio"], i0["richardson_order_ratio"]))
    # the solves' spatial errors weighted by the larger of the two parts' weights (:func:`_shell_combined`)
    info["grid_weights"] = max(i0["shell_weights"], i1["shell_weights"], key=lambda w: sum(abs(c) for c in w))
    return np.concatenate(((x0,), x1)), r0 + r1, info


def _uniform_table(ladder: list) -> tuple:
    """:func:`_shell_table`'s rules on uniform shells for one vector of masses (the whole ladder, or one part)."""
    p_n, p_h, p_q = ladder[:3]
    r_n, r_h = (4.0 * p_n - p_h) / 3.0, (4.0 * p_h - p_q) / 3.0
    residual, rho_p, d_top = _shell_residual(p_n, p_h, p_q)
    info = {"shell_order_ratio": rho_p, "shell_extrapolation_order": 4, "shell_weights": (4 / 3, -1 / 3, 0.0, 0.0)}
    if len(ladder) < 4:
        return r_n, residual, info
    r_q = (4.0 * p_q - ladder[3]) / 3.0
    d_half = float(np.sum(np.abs(r_h - r_q)))
    rho_r = d_half / d_top if d_top > 0.0 else math.inf
    info["richardson_order_ratio"] = rho_r
    # the L1 differences of the P and of the R, which add over parts (:func:`_shell_table`'s whole-ladder ratios)
    info["l1"] = (float(np.sum(np.abs(p_n - p_h))), float(np.sum(np.abs(p_h - p_q))), d_top, d_half)
    if rho_r > ROMBERG_MAX_RATIO:
        return r_n, max(residual, d_top), info
    if rho_p >= SHELL_ORDER_RATIO and rho_r >= ROMBERG_RATIO:
        x_n, x_h = (16.0 * r_n - r_h) / 15.0, (16.0 * r_h - r_q) / 15.0
        info["shell_extrapolation_order"] = 6
        info["shell_weights"] = (64 / 45, -20 / 45, 1 / 45, 0.0)  # x_n in the P's
        return x_n, float(np.sum(np.abs(x_n - x_h))) / 15.0, info
    # where the P differences fall clearly slower than second order, a term below second order is in the ladder: R
    # keeps part of it, and its remainder need not fall faster than the P differences do (random seed 5, scene
    # 234: rho_P 3.03, rho_R 5.45, R(24, 48) 1.35e-6 off against a claimed 8.6e-7; the next R ratio was 3.3)
    rho = rho_r if rho_p >= SECOND_ORDER_CLEAR else min(rho_r, rho_p)
    return r_n, max(residual, d_top / min(15.0, max(rho - 1.0, 1.0))), info


def _thin_layer_table(ladder: list, start: bool = False) -> tuple:
    """``(continuum, residual, diagnostics)`` of :func:`_shell_table` where the wall's layer is thin.

    There the shells' error after one Richardson step is not of fourth order: the ratios of successive
    ``R(n/2, n)`` differences run 5-9 per doubling (the frozen layer), with single ratios of 13-16 between them
    that the next doubling does not follow; and the zero weight, the probability below the floor, converges on
    its own, at first order on the coarse shells of some scenes, hidden in the L1 sums by the cells' larger
    differences.  So ``R(n/2, n)`` is the continuum (never Romberg), and its residual is summed over the zero weight
    and the cells, each ``|R(n/2, n) - R(n/4, n/2)|`` over ``min(rho_R, THIN_LAYER_RATIO) - 1`` (``rho_R`` its own
    observed ratio), or over ``max(rho_P - 1, 1)`` where its ``P`` differences fall slower than
    :data:`SHELL_ORDER_RATIO` (not yet second order).  Measured (docs/closures.md "The thin layer's table"): the
    table of the L1 sums claimed 7-9.7e-7 where the error was 1.1-6.1e-6 (Romberg on a ratio of 13-15; ``R`` on a
    ratio of 8.4 followed by 2.9).

    ``start`` (shells graded at both ends, "ends"): an ``R`` ratio above :data:`ROMBERG_MAX_RATIO` is taken for a
    crossing of terms on a pre-asymptotic ladder, and that entry's last ``R`` difference counts undivided, as the
    uniform table counts it (random seed 7, scene 54: ``R`` ratios of 70, ``R(24, 48)`` 1.28e-6 from the continuum
    against a residual of 6.1e-7; docs/closures.md "A ladder below second order on uniform shells").  Only there:
    on shells graded at one end the same rule doubled the shells of two Fig. 1 cells and found no error to fix."""
    p_n, p_h, p_q = ladder[:3]
    r_n, r_h = (4.0 * p_n - p_h) / 3.0, (4.0 * p_h - p_q) / 3.0
    r_q = (4.0 * p_q - ladder[3]) / 3.0 if len(ladder) > 3 else None

    def r_ratio(part: slice, d_r: float) -> float:  # of the R differences, from P(n/8)
        if r_q is None:
            return THIN_LAYER_RATIO
        d_half = float(np.sum(np.abs(r_h[part] - r_q[part])))
        return d_half / d_r if d_r > 0.0 else math.inf

    residual = 0.0
    ratios = []
    for part in (slice(0, 1), slice(1, None)):  # the zero weight, the cells
        below_second, rho_p, d_r = _shell_residual(p_n[part], p_h[part], p_q[part])
        rho_r = r_ratio(part, d_r)
        if rho_p < SHELL_ORDER_RATIO:
            residual += below_second
        elif start and rho_r > ROMBERG_MAX_RATIO:  # both ends graded, a crossing of terms: the last difference
            residual += d_r
        else:
            residual += d_r / max(min(rho_r, THIN_LAYER_RATIO) - 1.0, 1.0)
        ratios.append((rho_p, rho_r))
    _, rho_all, d_all = _shell_residual(p_n, p_h, p_q)
    info = {"shell_order_ratio": rho_all, "shell_extrapolation_order": 4,
            "shell_weights": (4 / 3, -1 / 3, 0.0, 0.0), "zero_weight_order_ratios": ratios[0]}
    if r_q is not None:
        info["richardson_order_ratio"] = r_ratio(slice(None), d_all)
    return r_n, residual, info


def _masses(r: Any) -> np.ndarray:
    """``[zero weight, cell masses]`` of a finite-volume result."""
    return np.concatenate(([r.zero_weight], r.density * r.weights))


def _continuum_result(res: Any, masses: np.ndarray, mom: np.ndarray, *, estimate: float, grids: float,
                      residual: float, shell_error: float, n: int, p0: float, rtol: float, extra: dict,
                      extra_time: float) -> Any:
    """The result of the shell extrapolation: ``res`` with the continuum's masses ``[zero weight, cells]``, the
    cells' barycentres from their first moments ``mom`` (kept inside their cells, the midpoint where the mass is
    not positive, as the engine's results), its checks (estimate, mass, negative probability) and diagnostics."""
    cells = masses[1:]
    w = res.weights
    ok = cells > 1e-300
    centre = 0.5 * (res.edges[:-1] + res.edges[1:])
    bary = np.clip(np.where(ok, mom / np.where(ok, cells, 1.0), centre), res.edges[:-1], res.edges[1:])
    negative = float(-cells[cells < 0.0].sum())
    mass = float(masses.sum())
    mean = float(bary @ cells + res.edges[0] * masses[0])
    problems = []
    if not estimate <= rtol:
        problems.append(f"error estimate {estimate:.2e} (grids {grids:.2e} + shell extrapolation {residual:.2e}) "
                        f"misses rtol={rtol:.1e}" + (f" at {n} shells (MAX_CONTINUUM_SHELLS = "
                                                     f"{MAX_CONTINUUM_SHELLS})" if residual > grids else ""))
    if not abs(mass - 1.0) <= rtol:
        problems.append(f"mass {mass:.12g} not conserved to rtol")
    if negative > rtol:
        problems.append(f"negative probability {negative:.2e} > rtol")
    success = not problems
    message = (f"converged: L1 error estimate {estimate:.2e} <= rtol {rtol:.1e} (continuum closure, Richardson "
               f"in shells {n // 4}/{n // 2}/{n})" if success else "; ".join(problems))
    density = cells / w
    diag = {**res.diagnostics, "shell_extrapolation": True, "shell_error": shell_error,
            "shell_extrapolation_residual": residual, "grid_estimate": grids, "n_shells": (n, n // 2, n // 4),
            "mass_error": mass - 1.0, "mean_error": mean - p0, "negative_mass": negative,
            "min_density": float(density.min()),
            "timings": {**res.diagnostics["timings"], "shells": extra_time}, **extra}
    diag.pop("floor_ghosts", None)  # the n-shell solve's masses below the floor, not these: the spline ends there
    return replace(res, p=bary, density=density, zero_weight=float(masses[0]), success=success, message=message,
                   error_estimate=float(estimate), wall_time=res.wall_time + extra_time, diagnostics=diag)


def _shell_combined(sol: Any, scene: tuple, rtol: float, options: dict) -> Any:
    """The continuum closure from the ``n``-shell result ``res`` and full solves of fewer shells on its grids.

    The ``n/2``-, ``n/4``- and (where ``n/8 >= MIN_ROMBERG_SHELLS`` shells solve there) ``n/8``-shell problems
    are solved on ``res``'s grids (``grid=`` of :func:`~diffusion_pr.fokker_planck.engine.solve_fv_full`),
    so the cell masses combine cell by cell as :func:`_shell_table` says (Richardson, or Romberg where the
    observed order allows it), its residual added to the grids' estimate: the solves' own estimates with the
    table's weights in absolute value (``(4 e(n) + e(n/2))/3`` for Richardson; the spatial errors of the solves
    are not assumed to cancel).  Where the sum misses ``rtol``, the ``2n``-shell problem is solved on the same
    grids and the table is made again from the top (one solve per doubling, up to :data:`MAX_CONTINUUM_SHELLS`).
    Used where the plain grids' correction misses (:func:`_shell_extrapolated`) or no plain masses were kept."""
    from ..fokker_planck.grid import same_grid

    res = sol.result
    n = int(res.diagnostics["n_shells"])
    solved = {n: res}

    def on_the_grid(m: int) -> Any:
        return _coarser_on_grid(sol, m, scene, rtol, options, plain=None).result

    def usable(r: Any) -> bool:
        return bool(r.success and r.edges is not None and same_grid(r.edges, res.edges))

    while True:
        for m in (n // 2, n // 4) + ((n // 8,) if n % 8 == 0 and n // 8 >= MIN_ROMBERG_SHELLS else ()):
            if m not in solved:
                solved[m] = on_the_grid(m)
        three = [solved[n >> k] for k in range(3)]
        if not all(usable(r) for r in three):
            why = "; ".join(f"{int(r.diagnostics.get('n_stages', 0))} stages: {r.message}" for r in three
                            if not r.success)
            return _failed_extrapolation(res, why or "a solve's grids differ from the first one's")
        used = three + ([solved[n // 8]] if n % 8 == 0 and n // 8 in solved and usable(solved[n // 8]) else [])
        masses = [_masses(r) for r in used]
        x, residual, table = _shell_table(masses, thin=scene[5] != "uniform", start=scene[5] == "ends")
        weights = table["shell_weights"][:len(used)]
        grids = sum(abs(c) * r.error_estimate for c, r in zip(table.get("grid_weights", weights), used))
        if grids + residual <= rtol or 2 * n > MAX_CONTINUUM_SHELLS or grids >= SHELL_SHARE * rtol:
            break
        n *= 2  # the residual falls 16x per doubling: one more solve on the same grids
        solved[n] = on_the_grid(n)
    estimate = grids + residual
    # the first moments per cell, extrapolated alike
    w = res.weights
    mom = sum(c * r.p * r.density * w for c, r in zip(weights, used))
    return _continuum_result(res, x, mom, estimate=estimate, grids=grids, residual=residual,
                             shell_error=float(np.sum(np.abs(masses[0] - masses[1]))) / 3.0, n=n, p0=scene[2],
                             rtol=rtol,
                             extra={"shells_solved": tuple(sorted(m for m, r in solved.items() if usable(r))),
                                    "shell_scheme": "combined solves", **table},
                             extra_time=sum(r.wall_time for r in solved.values() if r is not res))
