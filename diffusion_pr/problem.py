"""The Fokker-Planck problem every backend solves (docs/theory.md).

In the diffusion time ``tau = integral D(eta) d eta`` (pressure squared)::

    d Pr / d tau = - d/dp [ a(p, tau) Pr ] + d^2/dp^2 [ f(p, tau) Pr ],   Pr(p, 0) = delta(p - mean_pressure),

on ``p >= 0``, to ``tau_end = variance / 2`` (``f = 1`` without the wall gives a Gaussian of variance ``variance``).
Where ``f ~ p^k`` with ``k < 2`` probability reaches ``p = 0`` (Feller) and is the non-contact weight
``zero_weight``; for ``k >= 2`` ``zero_weight`` is the probability below a floor.  A magnification-dependent drift
``A(p, eta)`` becomes ``a(p, tau) = A(p, eta(tau)) / D(eta(tau))`` (:meth:`FokkerPlanckProblem.from_magnification`)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def _unit(p: Array) -> Array:
    """``f = 1`` (dimensionless): the default diffusivity (Persson's mirror Gaussian)."""
    return np.ones_like(np.asarray(p, dtype=float))


def _number(name: str, value: object, unit: str, *, zero_ok: bool = False) -> float:
    """``value`` as a float, required finite and > 0 (>= 0 with ``zero_ok``); else a ``ValueError``."""
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        v = math.nan
    if not math.isfinite(v) or v < 0.0 or (v == 0.0 and not zero_ok):
        raise ValueError(f"{name} must be a finite number {'>=' if zero_ok else '>'} 0 ({unit}); got {name}={value!r}")
    return v


def _check_f(p: Array, f: Array) -> Array:
    """``f``, required finite and >= 0 at the pressures ``p`` (else a ``ValueError`` naming the first bad one)."""
    bad = ~(np.isfinite(f) & (f >= 0.0))
    if bad.any():
        raise ValueError(f"diffusivity must be finite and >= 0 (a diffusion coefficient); it is {f[bad][0]!r} at "
                         f"p={p[bad][0]!r}")
    return f


@dataclass(frozen=True)
class FokkerPlanckProblem:
    """Drift-diffusion problem in the diffusion time ``tau``.

    Parameters
    ----------
    mean_pressure : float
        ``p0`` (units of pressure), > 0: location of the initial ``delta``.
    variance : float
        ``V`` (pressure squared), > 0: the problem runs to ``tau_end = V/2``.
    diffusivity : callable
        Vectorized ``f(p)`` (dimensionless), ``f >= 0`` and finite on ``p > 0``; ``f(p, tau)`` if ``time_dependent``.
    drift : callable, optional
        Vectorized ``a(p, tau)`` (pressure per unit tau); ``None`` means 0.
    time_dependent : bool
        Whether ``diffusivity`` takes ``(p, tau)`` instead of ``p``.
    """

    mean_pressure: float
    variance: float
    diffusivity: Callable[..., Array] = _unit
    drift: Optional[Callable[[Array, float], Array]] = None
    time_dependent: bool = False
    label: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean_pressure", _number("mean_pressure", self.mean_pressure, "pressure"))
        object.__setattr__(self, "variance", _number("variance", self.variance, "pressure^2"))
        if self.diffusivity is None:
            object.__setattr__(self, "diffusivity", _unit)
        if not callable(self.diffusivity):
            raise ValueError("diffusivity must be a vectorized callable f(p) of the pressure; got "
                             f"{type(self.diffusivity).__name__}")
        if self.drift is not None and not callable(self.drift):
            raise ValueError(f"drift must be a vectorized callable a(p, tau) or None; got {type(self.drift).__name__}")
        if not self.time_dependent:  # a negative or non-finite f is refused here (the solvers would fail obscurely)
            probe = self.mean_pressure * np.geomspace(1e-6, 1e2, 25)
            try:
                values = np.asarray(self.diffusivity(probe), dtype=float)
            except Exception:  # (a failing callable is reported, with its error, by the solver)
                return
            if values.shape == probe.shape:
                _check_f(probe, values)

    @property
    def tau_end(self) -> float:
        """Final diffusion time ``variance / 2`` (pressure squared)."""
        return 0.5 * self.variance

    @property
    def autonomous(self) -> bool:
        """True when neither ``f`` nor the drift depend on ``tau``."""
        return self.drift is None and not self.time_dependent

    def f(self, p: Array, tau: float = 0.0) -> Array:
        """The pressure factor ``f`` on ``p`` (and ``tau``), broadcast to the shape of ``p``; a ``ValueError`` where
        it is negative or not finite."""
        p = np.asarray(p, dtype=float)
        out = np.asarray(self.diffusivity(p, tau) if self.time_dependent else self.diffusivity(p), dtype=float)
        return _check_f(p, np.broadcast_to(out, p.shape).astype(float))

    @classmethod
    def from_magnification(cls, *, mean_pressure: float, eta: Array, variance_of_eta: Array,
                           pressure_factor: Callable[[Array], Array],
                           drift_of_eta: Optional[Callable[[Array, float], Array]] = None,
                           variance_function: Optional[Callable[[Array], Array]] = None,
                           diffusivity_function: Optional[Callable[[Array], Array]] = None,
                           label: str = "") -> "FokkerPlanckProblem":
        """Build the ``tau`` problem from a magnification schedule.

        Parameters
        ----------
        mean_pressure : float
            ``p0`` (units of pressure).
        eta : array
            Increasing magnifications ``eta = q/q_L`` from 1.
        variance_of_eta : array
            ``V(eta)`` (pressure squared), non-decreasing, ``V(1) >= 0``.
        pressure_factor : callable
            ``f(p) = c(p) t(p)``.
        drift_of_eta : callable, optional
            ``A(p, eta)`` (pressure per unit magnification).  Converted to ``a = A / D(eta)`` with
            ``D = (1/2) dV/deta``; segments where ``D = 0`` are skipped (their drift cannot be represented in ``tau``;
            the conversion raises if a drift is given there).
        variance_function, diffusivity_function : callable, optional
            The exact, vectorized ``V(eta)`` (pressure squared) and ``D(eta) = (1/2) dV/deta`` (pressure squared per
            unit magnification), consistent with ``variance_of_eta`` at the nodes (a continuum spectrum's
            :func:`~diffusion_pr.cumulants.variance_vs_magnification` and
            :func:`~diffusion_pr.cumulants.diffusivity_vs_magnification`).  Given both, ``eta(tau)`` solves
            ``(V(eta) - V(1))/2 = tau`` to round-off and ``a(p, tau)`` is as smooth in ``tau`` as ``A`` and ``D`` are in
            ``eta`` (second-order convergence of the midpoint time segments).  Without them ``eta(tau)`` and ``D`` are
            interpolated linearly between the nodes: ``a`` has a kink at every node and a tight ``rtol`` may be out of
            reach.
        """
        eta = np.asarray(eta, dtype=float)
        v = np.asarray(variance_of_eta, dtype=float)
        if eta.ndim != 1 or v.shape != eta.shape or eta.size < 2:
            raise ValueError("eta and variance_of_eta must be 1-D arrays of equal length >= 2")
        if np.any(np.diff(eta) <= 0) or np.any(np.diff(v) < 0):
            raise ValueError("eta must increase and variance_of_eta must not decrease")
        if (variance_function is None) != (diffusivity_function is None):
            raise ValueError("variance_function and diffusivity_function go together (the exact V(eta) and "
                             "D(eta) = V'(eta)/2); give both or neither")
        for name, fn in (("variance_function", variance_function), ("diffusivity_function", diffusivity_function),
                         ("drift_of_eta", drift_of_eta)):
            if fn is not None and not callable(fn):
                raise ValueError(f"{name} must be a vectorized callable or None; got {fn!r}")
        variance = float(v[-1] - v[0])
        if drift_of_eta is None:
            return cls(mean_pressure, variance, pressure_factor, label=label)
        tau_nodes = 0.5 * (v - v[0])
        if variance_function is None:
            d_eta = np.gradient(v, eta) * 0.5

            def magnification(tau: float) -> tuple[float, float]:
                e = float(np.interp(tau, tau_nodes, eta))
                return e, float(np.interp(e, eta, d_eta))
        else:
            magnification = _ExactMagnification(eta, tau_nodes, v[0], variance_function, diffusivity_function)

        def drift(p: Array, tau: float) -> Array:
            e, d = magnification(float(tau))
            if d <= 0.0:
                raise ValueError(f"drift given where D(eta) = 0 (eta={e:.6g}); cannot map it to tau")
            return np.asarray(drift_of_eta(p, e), dtype=float) / d

        if variance_function is not None:
            drift.prefetch_times = magnification.solve  # type: ignore[attr-defined]

        return cls(mean_pressure, variance, pressure_factor, drift=drift, label=label)


#: Newton steps of the exact ``eta(tau)`` map before it gives up on round-off (a bisection step each where the
#: Newton step leaves the bracket; the bracket halves at least every other step)
MAGNIFICATION_NEWTON_STEPS = 60


class _ExactMagnification:
    """``tau -> (eta(tau), D(eta(tau)))`` solving ``(V(eta) - V(1))/2 = tau`` inside the table's bracket. Safeguarded
    Newton (bisection where a step leaves the bracket), vectorized over the times of :meth:`solve`; memoized per ``tau``
    (the engine announces each grid's segment midpoints at once through the drift's ``prefetch_times``)."""

    def __init__(self, eta: Array, tau_nodes: Array, v_start: float, variance_function: Callable,
                 diffusivity_function: Callable) -> None:
        self.eta, self.tau_nodes, self.v_start = eta, tau_nodes, float(v_start)
        self.variance_function, self.diffusivity_function = variance_function, diffusivity_function
        self.tol = 4.0 * np.finfo(float).eps * max(float(tau_nodes[-1]), np.finfo(float).tiny)
        self.cache: dict = {}

    def _tau_of(self, e: Array) -> Array:
        return 0.5 * (np.asarray(self.variance_function(e), dtype=float).reshape(e.shape) - self.v_start)

    def _d_of(self, e: Array) -> Array:
        return np.asarray(self.diffusivity_function(e), dtype=float).reshape(e.shape)

    def solve(self, taus: Array) -> None:
        """Solve the map at every time of ``taus`` not yet known (pressure squared, within ``[0, tau_end]``)."""
        todo = np.array(sorted({float(t) for t in np.ravel(taus)} - self.cache.keys()), dtype=float)
        if todo.size == 0:
            return
        eta, nodes = self.eta, self.tau_nodes
        i = np.clip(np.searchsorted(nodes, todo, side="right") - 1, 0, eta.size - 2)
        lo, hi = eta[i].copy(), eta[i + 1].copy()  # nodes[i] <= tau <= nodes[i + 1]
        width = nodes[i + 1] - nodes[i]
        frac = np.divide(todo - nodes[i], width, out=np.full(todo.shape, 0.5), where=width > 0)
        e = np.clip(lo + (hi - lo) * frac, lo, hi)
        r, d = self._tau_of(e) - todo, self._d_of(e)
        done = (np.abs(r) <= self.tol) | (hi - lo <= 4.0 * np.finfo(float).eps * hi)
        for _ in range(MAGNIFICATION_NEWTON_STEPS):
            if done.all():
                break
            act = ~done
            hi = np.where(act & (r > 0.0), e, hi)
            lo = np.where(act & (r <= 0.0), e, lo)
            with np.errstate(divide="ignore", invalid="ignore"):
                step = np.where(d > 0.0, e - r / np.where(d > 0.0, d, 1.0), np.nan)
            inside = (step > lo) & (step < hi)
            e = np.where(act, np.where(inside, step, 0.5 * (lo + hi)), e)
            k = np.flatnonzero(act)
            r[k], d[k] = self._tau_of(e[k]) - todo[k], self._d_of(e[k])
            done = done | (np.abs(r) <= self.tol) | (hi - lo <= 4.0 * np.finfo(float).eps * hi)
        if not done.all():
            j = int(np.flatnonzero(~done)[0])
            raise RuntimeError(f"the magnification map did not converge: tau={todo[j]!r} left a residual "
                               f"{r[j]:.3e} (pressure^2) after {MAGNIFICATION_NEWTON_STEPS} steps in eta "
                               f"[{lo[j]!r}, {hi[j]!r}]")
        self.cache.update(zip(todo.tolist(), zip(e.tolist(), d.tolist())))

    def __call__(self, tau: float) -> tuple[float, float]:
        if tau not in self.cache:
            self.solve(np.array([tau]))
        return self.cache[tau]


@dataclass(frozen=True)
class Stage:
    """One magnification shell (or segment) of the diffusion time.

    On the stage the distribution obeys (Ito form, docs/theory.md and docs/closures.md)::

        dPr/dtau = d^2/dp^2 [ f(p) Pr ] - d/dp [ (b(p) - A(tau) w(p)) Pr ],   p > 0,

    with the scalar ``A`` chosen to keep ``<p>`` at ``p0`` when ``balance`` is given (how:
    :class:`StagedProblem`'s ``balance_per_stage``).  The callables may declare the model protocol of
    :mod:`diffusion_pr.models` (``zero_power``, ``breakpoints()``).

    Attributes
    ----------
    duration : float
        Diffusion-time increment ``dtau >= 0`` (pressure squared).
    diffusivity : callable
        ``f(p) >= 0`` on this stage (dimensionless), vectorized.
    drift : callable or None
        ``b(p)`` (pressure per unit tau), vectorized; ``None`` means 0.
    balance : callable or None
        ``w(p)`` (pressure per unit tau per unit ``A``), vectorized; ``None`` means no balance (``A = 0``).
    """

    duration: float
    diffusivity: Callable[[Array], Array]
    drift: Optional[Callable[[Array], Array]] = None
    balance: Optional[Callable[[Array], Array]] = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "duration", _number("Stage.duration", self.duration, "pressure^2", zero_ok=True))
        for name in ("diffusivity", "drift", "balance"):
            value = getattr(self, name)
            if (value is not None or name == "diffusivity") and not callable(value):
                raise ValueError(f"Stage.{name} must be a vectorized callable of the pressure"
                                 f"{'' if name == 'diffusivity' else ' or None'}; got {value!r}")


@dataclass(frozen=True)
class StagedProblem:
    """A sequence of :class:`Stage` s applied in order from ``delta(p - mean_pressure)``.

    Attributes
    ----------
    mean_pressure : float
        ``p0`` (pressure), > 0: the start ``delta(p - p0)``.
    stages : tuple of Stage
        Applied in order; the total diffusion time is ``sum(durations)``.
    label : str
        Free text carried into the result's diagnostics.
    balance_per_stage : bool
        How a stage's balance multiplier ``A`` is defined.  False (default): ``A(tau)`` at every instant, so that
        ``d<p>/dtau = 0`` throughout (the engine resolves it by substeps refined with the grids).  True: one number
        ``A`` per stage, the one with ``<p> = p0`` at the stage's end (the closures: the rigid-body approach restores
        the load shell by shell).
    """

    mean_pressure: float
    stages: tuple
    label: str = ""
    balance_per_stage: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean_pressure", _number("mean_pressure", self.mean_pressure, "pressure"))
        stages = tuple(self.stages)
        if not stages or not all(isinstance(s, Stage) for s in stages):
            raise ValueError("stages must be a non-empty sequence of Stage objects")
        if sum(s.duration for s in stages) <= 0.0:
            raise ValueError("the stages' total duration must be > 0 (pressure^2)")
        object.__setattr__(self, "stages", stages)
        if not isinstance(self.balance_per_stage, (bool, np.bool_)):
            raise ValueError(f"balance_per_stage must be True or False; got {self.balance_per_stage!r}")

    @property
    def tau_end(self) -> float:
        """Total diffusion time ``sum(duration)`` (pressure squared)."""
        return float(sum(s.duration for s in self.stages))

    @property
    def variance(self) -> float:
        """``2 tau_end`` (pressure squared): the variance ``f = 1`` would give."""
        return 2.0 * self.tau_end
