"""``solve_contact``: the equilibrium of an elastic half-space on a rigid rough surface.

Conventions and residuals: docs/gfmd.md. Solid surface ``z = z0 + u`` (``<u> = 0``), gap
``g = z - h``; each mode ``q != 0`` is a spring ``q E*/2`` per unit area, so
``u = IFFT[(2/(q E*)) FFT(p)]``.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .._validation import check_heights, check_int, check_positive, check_real, check_tol
from .._validation import check_periodic as _check_periodic
from ..interactions import ExponentialRepulsion, HardWall
from .ccg import ccg
from .elastic import Elastic
from .fire import fire
from .newton import newton

__all__ = ["solve_contact", "ContactResult", "ConvergenceWarning", "METHODS", "EXP_CONTACT_THRESHOLD"]

#: methods per interaction ("auto" picks the first, the fastest).
METHODS = {"HardWall": ("ccg", "pk", "fire"), "ExponentialRepulsion": ("newton", "fire")}

#: exponential wall: refuse problems whose round-off floor of the residual exceeds this.
EXP_FLOOR_LIMIT = 1e-3

#: exponential wall: contact means ``pressure > EXP_CONTACT_THRESHOLD * p0``.
EXP_CONTACT_THRESHOLD = 0.01


class ConvergenceWarning(UserWarning):
    """A solver stopped before reaching the requested tolerance."""


@dataclass(frozen=True, eq=False)
class ContactResult:
    """Solution of one contact problem.

    ``pressure`` has mean ``mean_pressure`` to round-off (load control), ``gap =
    displacement - heights``. ``contact_fraction`` is :meth:`contact_area` at its default
    threshold ``contact_threshold``: hard wall, fraction of nodes with ``pressure > 0``;
    exponential wall, fraction with ``pressure > EXP_CONTACT_THRESHOLD * p0 = 0.01 p0``.
    ``length`` is the cell side ``L`` (a float) or ``(Lx, Ly)`` for a rectangular cell.
    ``iterations`` counts the costly operator applications (one FFT pair each: CG/FIRE
    steps, Newton line-search evaluations). ``residual`` is relative to ``mean_pressure``.
    """

    pressure: np.ndarray
    gap: np.ndarray
    displacement: np.ndarray
    converged: bool
    iterations: int
    residual: float
    wall_time: float
    method: str
    message: str
    residual_history: np.ndarray
    interaction: object
    mean_pressure: float
    E_star: float
    length: float | tuple
    tol: float
    contact_threshold: float = 0.0
    info: dict = field(default_factory=dict)

    @property
    def contact_fraction(self) -> float:
        """:meth:`contact_area` at its default threshold :attr:`contact_threshold`."""
        return self.contact_area()

    def contact_area(self, threshold: float | None = None) -> float:
        """Relative contact area: the fraction of nodes with ``pressure > threshold``
        [pressure]; default :attr:`contact_threshold` (hard wall 0, exponential wall
        ``EXP_CONTACT_THRESHOLD * mean_pressure``)."""
        thr = self.contact_threshold if threshold is None else check_real("threshold", threshold, low=0.0)
        return float(np.count_nonzero(self.pressure > thr)) / self.pressure.size


def solve_contact(
    heights,
    *,
    length,
    E_star,
    mean_pressure,
    interaction,
    tol: float = 1e-8,
    max_iter: int | None = None,
    method: str = "auto",
    progress: bool = False,
    threads: int = 1,
    check_periodic: bool = True,
) -> ContactResult:
    """Equilibrium of an elastic half-space pressed on a rigid periodic rough surface.

    Units: any consistent system. Lengths (``heights``, ``length``, ``zeta``, and the
    returned ``gap``/``displacement``) share one length unit; pressures (``E_star``,
    ``mean_pressure``, the returned ``pressure``) share one pressure unit (e.g. the
    paper's Fig. 1 scene: lengths in grid spacings, ``E* = 8/3``, ``p0 = 0.004`` in units
    of the shear modulus). Only ratios matter: the pressure field scales with ``p0``,
    the displacements with ``p0 / E*`` times a length.

    Parameters
    ----------
    heights : (nx, ny) array
        Rigid surface heights [length] on one periodic cell (any ``nx, ny >= 2``, square
        or rectangular, not only powers of two). Contact happens where ``h`` is high.
        The map must be periodic (see ``check_periodic``).
    length : float or (float, float)
        Cell side(s) [length] (> 0): ``L`` along the first axis with the same spacing
        ``L / nx`` along the second (``Ly = L ny / nx``), or ``(Lx, Ly)``.
    E_star : float
        Contact modulus ``E* = E/(1 - nu^2)`` [pressure] (> 0).
    mean_pressure : float
        Imposed mean pressure ``p0`` [pressure] (> 0), load control.
    interaction : HardWall or ExponentialRepulsion
        ``ExponentialRepulsion(zeta)``: ``zeta`` [length].
    tol : float
        Convergence tolerance on the residual [dimensionless], relative to ``p0``
        (see module doc); in ``(0, 0.1]``.
    max_iter : int, optional
        Cap on operator applications (FFT pairs; default depends on method and size).
    method : {"auto", "ccg", "pk", "newton", "fire"}
        ``"ccg"``: Polonsky-Keer constrained conjugate gradients with a Fourier-diagonal
        preconditioner ``q E*/2`` (hard wall only); ``"pk"``: the same without it;
        ``"newton"``: dual Newton-CG (exponential wall only); ``"fire"``: GFMD with
        mass-weighted FIRE (both). ``"auto"`` picks ``ccg`` / ``newton``. With
        ``ccg``/``pk``, a load high enough for full contact is answered by the closed form
        ``p = p0 + IFFT[(q E*/2) FFT(h)]`` (exact when it is ``>= 0`` everywhere;
        ``info["closed_form"] = True``, zero iterations).
    progress : bool
        Show a tqdm progress bar in decades of residual reduction (from the first
        residual down to ``tol``).
    threads : int
        FFT threads (>= 1). The answer does not depend on it beyond round-off.
    check_periodic : bool
        Refuse (ValueError) a map whose jump across the cell boundary exceeds 3 times its
        largest step between neighbours inside (:func:`gfmd_ref._validation.check_periodic`:
        a measured, non-periodic map must be detrended and windowed, or padded, first).
        False solves the map as it is, as one period.

    Returns
    -------
    ContactResult
        ``pressure`` [pressure], ``gap`` and ``displacement`` [length]. Warns
        :class:`ConvergenceWarning` (and has ``converged=False``) if the tolerance was
        not reached: ``max_iter`` exhausted or the residual stalled (it did not halve
        within a window of iterations, e.g. a tol below round-off); ``message`` gives
        the residual reached, the iterations and the reason (``info["stop"]``).

    Raises
    ------
    ValueError
        Bad input, naming the parameter; also when the elastic response of the
        exponential wall is below double-precision resolution of ``p0`` (round-off
        floor of the residual ``eps p0 / (E* q1 zeta) > 1e-3``, ``q1 = 2 pi / L``:
        ``E_star`` far too small for ``mean_pressure``).
    """
    t0 = time.perf_counter()
    h = check_heights(heights)
    if np.ndim(length) == 1 and len(length) == 2:
        lengths = (check_positive("length[0]", length[0]), check_positive("length[1]", length[1]))
    else:
        lx = check_positive("length", length)
        lengths = (lx, lx * h.shape[1] / h.shape[0])
    length = lengths[0] if h.shape[0] == h.shape[1] and lengths[0] == lengths[1] else lengths
    E_star = check_positive("E_star", E_star)
    p0 = check_positive("mean_pressure", mean_pressure)
    tol = check_tol(tol)
    if check_periodic:
        _check_periodic(h)
    threads = check_int("threads", 1 if threads is None else threads)
    if not isinstance(interaction, (HardWall, ExponentialRepulsion)):
        raise ValueError("interaction must be gfmd_ref.HardWall() or gfmd_ref.ExponentialRepulsion(zeta); "
                         f"got {interaction!r}")
    kind = type(interaction).__name__
    allowed = ("auto",) + METHODS[kind]
    if not isinstance(method, str) or method not in allowed:
        raise ValueError(f"method must be one of {allowed} for {kind}; got {method!r}")
    method = METHODS[kind][0] if method == "auto" else method
    zeta = getattr(interaction, "zeta", None)
    if max_iter is None:  # FIRE's steps are cheap and many; CG's grow with the grid
        max_iter = (20000 if zeta is None else 100000) if method == "fire" else 5000 + 20 * max(h.shape)
    max_iter = check_int("max_iter", max_iter)
    if zeta is not None:
        # u = G p has absolute error ~ eps p0/(E* q1): a residual floor eps p0/(E* q1 zeta).
        # Refuse a floor above 1e-3; below it an unreachable tol ends by stall detection.
        q1 = 2.0 * math.pi / max(lengths)
        floor = 2.2e-16 * (p0 / E_star) / (q1 * zeta)
        if not floor < EXP_FLOOR_LIMIT:
            raise ValueError(
                f"E_star={E_star!r} is too small for mean_pressure={p0!r} and zeta={zeta!r}: the elastic response "
                f"is below double precision (force-residual floor {floor:.1e} p0); need E_star > "
                f"{2.2e-16 * p0 / (q1 * zeta * EXP_FLOOR_LIMIT):.1e}")
    el = Elastic(h.shape, lengths, E_star, threads)
    closed = None
    if method in ("ccg", "pk"):  # full contact: the solid follows the surface, exact iff min p >= 0
        with np.errstate(over="ignore", invalid="ignore"):
            closed = p0 + el.apply(el.K, h)
        closed = closed if np.all(np.isfinite(closed)) and np.min(closed) >= 0.0 else None
    if closed is not None:
        load = abs(float(np.mean(closed)) - p0) / p0
        out = dict(pressure=closed, gap=np.zeros_like(h), displacement=h.copy(), converged=load < tol,
                   iterations=0, residual=load, history=np.array([load]),
                   stop="converged" if load < tol else "max_iter", info=dict(fft_pairs=1, closed_form=True))
    elif method in ("ccg", "pk"):
        hs = float(np.std(h))
        out = ccg(h, p0, el, tol, max_iter, progress, hs if hs > 0 else max(lengths), precond=method == "ccg")
    elif method == "fire":
        out = fire(h, p0, zeta, el, tol, max_iter, progress)
    else:
        out = newton(h, p0, zeta, el, tol, max_iter, progress)
    info = dict(out["info"], stop=out["stop"], fft_threads=threads, closed_form=closed is not None)
    if out["converged"]:
        how = "closed form (full contact)" if info["closed_form"] else method
        msg = f"converged: residual {out['residual']:.3e} < tol {tol:.1e} after {out['iterations']} iterations ({how})"
    else:
        reason = f"max_iter={max_iter} reached" if out["stop"] == "max_iter" else out["stop"]
        msg = (f"NOT converged: residual {out['residual']:.3e} > tol {tol:.1e} "
               f"after {out['iterations']} iterations ({method}; {reason})")
        warnings.warn(msg, ConvergenceWarning, stacklevel=2)
    return ContactResult(
        pressure=out["pressure"], gap=out["gap"], displacement=out["displacement"], converged=bool(out["converged"]),
        iterations=int(out["iterations"]), residual=float(out["residual"]), wall_time=time.perf_counter() - t0,
        method=method, message=msg, residual_history=out["history"], interaction=interaction, mean_pressure=p0,
        E_star=E_star, length=length, tol=tol, contact_threshold=0.0 if zeta is None else EXP_CONTACT_THRESHOLD * p0,
        info=info)
