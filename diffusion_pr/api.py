"""Public entry points: :func:`propagate` and :func:`pressure_distribution`.

``propagate`` solves the Fokker-Planck problem of docs/theory.md in the diffusion time ``tau``;
``pressure_distribution`` does the whole scene of Müser, PRL 100, 055504 (2008),
doi:10.1103/PhysRevLett.100.055504: the stress variance of the spectrum, the pressure factor ``f(p) = c(p) t(p)``,
an optional drift, and the solve.  ``backend="auto"`` takes the closed form wherever it is exact, else
``"native"`` (docs/backends.md); every backend returns the same ``zero_weight`` and density within ``rtol``."""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Callable, Optional

import numpy as np

from ._validation import InputTypeError, check_callable, check_nonnegative, check_positive
from .models import PressureFactor, make_cutoff, make_tail
from .problem import FokkerPlanckProblem, StagedProblem
from .result import PressureDistribution

__all__ = ["warm_up", "propagate", "pressure_distribution", "pressure_distributions", "solve_problem",
           "choose_backend", "BACKENDS"]

#: names accepted by ``backend=`` (besides any registered later)
BACKENDS = ("auto", "closed_form", "native", "pypde", "fipy")

#: magnification nodes for a drift A(p, eta) (log-spaced from 1 to q_max/q_min)
N_ETA = 513


def _exact_schedule(spectrum: Any, E_star: float, mean_pressure: float, zeta: float) -> dict:
    """The exact ``V(eta)`` and ``D(eta)`` of a continuum spectrum for
    :meth:`FokkerPlanckProblem.from_magnification` (none for a discrete spectrum: its ``V`` is a staircase)."""
    from .cumulants import diffusivity_vs_magnification, variance_vs_magnification
    from .spectra import DiscreteSpectrum

    if isinstance(spectrum, DiscreteSpectrum):
        return {}
    kw = dict(E_star=E_star, mean_pressure=mean_pressure, zeta=zeta)
    return {"variance_function": lambda e: variance_vs_magnification(spectrum, e, **kw),
            "diffusivity_function": lambda e: diffusivity_vs_magnification(spectrum, e, **kw)}


def _check_backend(backend: object) -> str:
    from .fokker_planck.backends import backend_names

    names = sorted(set(BACKENDS) | set(backend_names()))
    if not isinstance(backend, str) or backend not in names:
        raise ValueError(f"backend must be one of {names}; got backend={backend!r}")
    return backend


def _check_rtol(rtol: object) -> float:
    value = check_positive("rtol", rtol)
    if np.ndim(value) != 0 or not (1e-14 <= float(value) < 1.0):
        raise ValueError(f"rtol must be a number in [1e-14, 1); got rtol={rtol!r}")
    return float(value)


def choose_backend(problem: Any, options: Optional[dict] = None) -> str:
    """The ``"auto"`` choice: ``"closed_form"`` if exact (and no finite-volume option given), else ``"native"``."""
    from .fokker_planck.backends.closed_form import exact_kind

    if not isinstance(problem, FokkerPlanckProblem) or exact_kind(problem) is None:
        return "native"
    if options and set(options) - _accepted_options("closed_form"):
        return "native"
    return "closed_form"


def _accepted_options(name: str) -> set:
    """Keyword options of backend ``name``'s ``solve`` (besides ``rtol``)."""
    from .fokker_planck.backends import get_backend, keyword_options

    return set(keyword_options(get_backend(name)))


def _solve(problem: Any, backend: str, rtol: float, options: dict) -> PressureDistribution:
    """Solve with inputs already validated (``backend`` checked, ``rtol`` a float in range)."""
    return _solve_full(problem, backend, rtol, options).result


def _solve_full(problem: Any, backend: str, rtol: float, options: dict, **engine: Any) -> Any:
    """:func:`_solve` with the engine's :class:`~diffusion_pr.fokker_planck.engine.FVSolution` (``engine``: its
    ``grid``, ``plain``, ``warm_start``); a closed form gives a solution holding its result alone."""
    import sys

    from .fokker_planck.backends import get_backend, keyword_options
    from .fokker_planck.engine import FVSolution

    backend = _check_backend(backend)
    rtol = _check_rtol(rtol)
    chosen = choose_backend(problem, options) if backend == "auto" else backend
    solver = get_backend(chosen)
    unknown = set(options) - keyword_options(solver)
    if unknown:
        raise ValueError(f"unknown option(s) {sorted(unknown)} for backend {chosen!r}; it accepts "
                         f"{sorted(keyword_options(solver))}")
    full = getattr(sys.modules[solver.__module__], "solve_full", None)
    engine = {k: v for k, v in engine.items() if v is not None}
    if full is None:  # (a warm start is a hint: a closed form needs none)
        if set(engine) - {"warm_start"}:
            raise ValueError(f"backend {chosen!r} is not a finite-volume backend: it takes no {sorted(engine)}")
        sol = FVSolution(result=solver(problem, rtol=rtol, **options))
    else:
        sol = full(problem, rtol=rtol, **options, **engine)
    return replace(sol, result=replace(sol.result, diagnostics={**sol.result.diagnostics,
                                                                "backend_requested": backend}))


def solve_problem(problem: Any, *, backend: str = "auto", rtol: float = 1e-6,
                  **options: Any) -> PressureDistribution:
    """Solve a :class:`FokkerPlanckProblem` or :class:`StagedProblem` with the named backend.

    Parameters
    ----------
    problem : FokkerPlanckProblem or StagedProblem
        The problem in the diffusion time ``tau``.
    backend : str
        ``"auto"``, ``"closed_form"``, ``"native"``, ``"pypde"`` or ``"fipy"``.
    rtol : float
        Target L1 error of ``Pr`` (dimensionless), in [1e-14, 1).
    **options
        The backend's own options (e.g. ``n_cells``, ``max_cells``, ``p_floor``); an unknown name is an error.

    Raises
    ------
    ValueError
        Unknown backend or option, bad ``rtol``, or ``closed_form`` asked for a problem without a closed form.
    BackendUnavailableError
        The backend's optional dependency is missing (the message names the pip extra).
    """
    if not isinstance(problem, (FokkerPlanckProblem, StagedProblem)):
        raise ValueError(f"problem must be a FokkerPlanckProblem or StagedProblem; got {type(problem).__name__}")
    backend = _check_backend(backend)
    rtol = _check_rtol(rtol)
    return _solve(problem, backend, rtol, options)


def propagate(
    mean_pressure: float,
    variance: float,
    *,
    diffusivity: Optional[Callable[[np.ndarray], np.ndarray]] = None,
    drift: Optional[Callable[[np.ndarray, float], np.ndarray]] = None,
    backend: str = "auto",
    rtol: float = 1e-6,
    **options: Any,
) -> PressureDistribution:
    """Solve ``dPr/dtau = -d/dp[a Pr] + d^2/dp^2[f(p) Pr]`` from ``delta(p - p0)`` to ``tau = V/2``.

    ``p = 0`` absorbs: what reaches it is ``zero_weight`` (the non-contact peak).  With ``f = 1`` the answer is
    Persson's mirror Gaussian of variance ``V`` plus ``erfc(p0/sqrt(2V)) delta(p)``.  Where ``f(p) -> 0`` at
    ``p = 0`` and the drift away from it outweighs diffusion there (Feller's test; e.g. ``f = p/p_1`` with
    ``a(0) p_1 >= 1``), ``p = 0`` is an entrance boundary and ``zero_weight`` is exactly 0
    (``diagnostics["wall"]`` says which case applied).

    Parameters
    ----------
    mean_pressure : float
        ``p0`` (units of pressure), finite and > 0.
    variance : float
        ``V`` (pressure squared), finite and > 0: ``f = 1`` without the wall would give a Gaussian of variance ``V``.
    diffusivity : callable, optional
        Vectorized ``f(p) >= 0`` (dimensionless); ``None`` means 1.  E.g. a
        :class:`~diffusion_pr.models.PressureFactor` or :class:`~diffusion_pr.models.ProportionalDiffusivity`.
    drift : callable, optional
        Vectorized ``a(p, tau)`` (pressure per unit ``tau``).
    backend : str
        ``"auto"`` (closed form where exact, else ``"native"``), ``"closed_form"``, ``"native"``, ``"pypde"``,
        ``"fipy"``.
    rtol : float
        Target L1 error (density integral plus zero weight), in [1e-14, 1).
    **options
        Backend options (e.g. ``n_cells``, ``max_cells`` for ``"native"``).

    Returns
    -------
    PressureDistribution
        ``p``, ``density``, ``weights``, ``zero_weight``, ``mass``, ``mean``, ``success``, ``error_estimate``,
        ``wall_time``, ``backend``, ``plot()``.

    Raises
    ------
    ValueError
        Bad ``mean_pressure``/``variance``/``rtol`` (NaN, <= 0), a non-callable ``diffusivity`` or ``drift``, an
        unknown backend.
    BackendUnavailableError
        Optional backend not installed.

    Examples
    --------
    >>> r = propagate(1.0, 1.0)            # mirror Gaussian, exact
    >>> round(r.zero_weight, 6)
    0.317311
    """
    p0 = check_positive("mean_pressure", mean_pressure)
    var = check_positive("variance", variance)
    if np.ndim(p0) or np.ndim(var):
        raise ValueError("mean_pressure and variance must be scalars")
    if diffusivity is not None:
        check_callable("diffusivity", diffusivity)
    if drift is not None:
        check_callable("drift", drift)
    backend = _check_backend(backend)
    rtol = _check_rtol(rtol)
    problem = FokkerPlanckProblem(float(p0), float(var), diffusivity, drift=drift)
    return _solve(problem, backend, rtol, options)


def pressure_distribution(
    spectrum: Any,
    *,
    E_star: float,
    mean_pressure: float,
    zeta: float = 0.0,
    cutoff: Any = "sharp",
    p_c: Optional[float] = None,
    tail: Any = None,
    p_t: Optional[float] = None,
    drift: Optional[Callable[[np.ndarray, float], np.ndarray]] = None,
    backend: str = "auto",
    rtol: float = 1e-6,
    closure: str = "second_order",
    **options: Any,
) -> PressureDistribution:
    """Pressure distribution of a rough contact (Müser 2008, Eqs. 2, 9, 10; docs/theory.md).

    ``closure`` picks the theory (docs/closures.md, :data:`diffusion_pr.closures.CLOSURES`): ``"second_order"``
    (the paper, default; everything below), or the parameter-free ``"lognormal_gap"`` (closed form),
    ``"local_g1"``, ``"local_g1_balanced"``, ``"local_g1_shell_balanced"`` (no cutoff, tail or drift; solved by
    :mod:`diffusion_pr.closures`; on a continuum spectrum extrapolated to the continuum limit in the number of
    shells).  ``diagnostics["closure"]`` names the closure in every result.

    Steps: ``V = stress_variance(spectrum, E_star, p0, zeta)`` (Eqs. 9-10); ``f(p) = c(p) t(p)``; one solve of
    ``dPr/dtau = d^2(f Pr)/dp^2`` to ``tau = V/2``; with a drift ``A(p, eta)`` the problem is mapped onto ``tau``
    through ``V(eta)`` (:func:`~diffusion_pr.cumulants.variance_vs_magnification`, ``eta = q/q_min``).

    Parameters
    ----------
    spectrum : Spectrum
        :class:`~diffusion_pr.spectra.SelfAffineSpectrum` or :class:`~diffusion_pr.spectra.DiscreteSpectrum`
        (lengths in the unit of ``zeta``).
    E_star : float
        Contact modulus (pressure), > 0.
    mean_pressure : float
        ``p0`` (pressure), > 0.
    zeta : float
        Range of the exponential repulsion (length), >= 0; 0 = hard wall.
    cutoff : str or callable
        ``"sharp"`` (default; exact mirror Gaussian), ``"muser"``/``"seed"`` (the paper's printed factor,
        discontinuous at ``p_c``), ``"raised_cosine"`` (C1), ``"smoothstep"`` (C2), or a callable ``c(p)``.
    p_c : float, optional
        Cutoff pressure (pressure) for the smooth cutoffs, > 0.
    tail : str or callable, optional
        ``None``/``"gaussian"``, ``"linear"`` (``1 + p/p_t``), ``"max_linear"`` (``max(1, p/p_t)``), or a
        callable ``t(p)``.
    p_t : float, optional
        Tail crossover pressure (pressure), > 0.
    drift : callable, optional
        ``A(p, eta)`` (pressure per unit magnification).
    backend, rtol, **options
        As in :func:`propagate`.  The shell closures take a finite-volume backend (``"auto"`` is ``"native"``) and
        two more options: ``n_shells`` (the number of shells, default 96; with the extrapolation its first
        solve's, default 48) and ``shell_extrapolation`` (default None: True for a continuum spectrum without
        ``n_shells``; True: the continuum closure, its ``error_estimate`` the grids' estimate plus the shells'
        residual; False: the ``n_shells`` problem itself, exact for a
        :class:`~diffusion_pr.spectra.DiscreteSpectrum`'s own shells).

    Returns
    -------
    PressureDistribution
        With ``diagnostics["stress_variance"]`` (``V``, pressure squared), ``diagnostics["zeta"]`` and, with a
        drift, the ``eta`` grid used.

    Raises
    ------
    ValueError
        Bad numbers (NaN, out of range) naming the parameter, NaN spectra, ``p_c <= 0``, unknown
        cutoff/tail/backend names.
    """
    return _pressure_distribution(spectrum, E_star=E_star, mean_pressure=mean_pressure, zeta=zeta, cutoff=cutoff,
                                  p_c=p_c, tail=tail, p_t=p_t, drift=drift, backend=backend, rtol=rtol,
                                  closure=closure, **options)[0]


def _pressure_distribution(spectrum: Any, *, E_star: float, mean_pressure: float, zeta: float = 0.0,
                           cutoff: Any = "sharp", p_c: Optional[float] = None, tail: Any = None,
                           p_t: Optional[float] = None, drift: Optional[Callable] = None, backend: str = "auto",
                           rtol: float = 1e-6, closure: str = "second_order", warm_start: Any = None,
                           **options: Any) -> tuple:
    """``(result, solution)``: :func:`pressure_distribution`'s result and the finite-volume solution it came from
    (:class:`~diffusion_pr.fokker_planck.engine.FVSolution`, None where there is none), started from ``warm_start``
    (a sweep's :class:`~diffusion_pr.fokker_planck.engine.WarmStart`)."""
    if closure != "second_order":
        from .closures import _closure_distribution, check_closure

        check_closure(closure)
        for name, value in (("drift", drift), ("cutoff", None if cutoff == "sharp" else cutoff), ("p_c", p_c),
                            ("tail", tail), ("p_t", p_t)):
            if value is not None:
                raise ValueError(f"{name} applies to closure='second_order' only; closure={closure!r} has no fitted "
                                 f"cutoff, tail or drift (got {name}={value!r})")
        return _closure_distribution(spectrum, E_star=E_star, mean_pressure=mean_pressure, zeta=zeta,
                                     closure=closure, backend=_check_backend(backend), rtol=_check_rtol(rtol),
                                     warm_start=warm_start, **options)
    for name in ("n_shells", "shell_extrapolation"):
        if options.get(name) is not None:
            raise ValueError(f"{name} applies to the shell closures, not to 'second_order'")
        options.pop(name, None)
    from .cumulants import stress_variance, variance_vs_magnification

    E = check_positive("E_star", E_star)
    p0 = check_positive("mean_pressure", mean_pressure)
    z = check_nonnegative("zeta", zeta)
    if np.ndim(z) or np.ndim(p0) or np.ndim(E):
        raise ValueError("E_star, mean_pressure and zeta must be scalars here "
                         "(stress_variance is vectorized over zeta; loop for several distributions)")
    for name, value in (("p_c", p_c), ("p_t", p_t)):
        if value is not None and np.ndim(check_positive(name, value)) != 0:
            raise ValueError(f"{name} must be one number > 0 (units of pressure); got {name}={value!r} "
                             "(loop over values for several distributions)")
    if drift is not None and not callable(drift):
        raise InputTypeError(f"drift must be None or a vectorized callable A(p, eta); got {type(drift).__name__}")
    backend = _check_backend(backend)
    rtol = _check_rtol(rtol)
    factor = PressureFactor(make_cutoff(cutoff, p_c), make_tail(tail, p_t))
    V = float(stress_variance(spectrum, E_star=E, mean_pressure=p0, zeta=z))
    if not np.isfinite(V) or V <= 0.0:
        raise ValueError(f"the stress variance of this spectrum is {V!r}; it must be finite and > 0 "
                         "(check the spectrum for NaN or zero amplitude)")
    extra: dict = {"stress_variance": V, "zeta": float(z), "E_star": float(E), "pressure_factor": factor,
                   "closure": "second_order"}
    if drift is None:
        problem = FokkerPlanckProblem(float(p0), V, factor, label="pressure_distribution")
    else:
        eta_max = float(spectrum.q_max / spectrum.q_min)
        eta = np.geomspace(1.0, eta_max, N_ETA)
        v_eta = np.asarray(variance_vs_magnification(spectrum, eta, E_star=E, mean_pressure=p0, zeta=z), dtype=float)
        if not np.all(np.isfinite(v_eta)):
            raise ValueError("variance_vs_magnification returned non-finite values; check the spectrum")
        v_eta = np.maximum.accumulate(v_eta)
        problem = FokkerPlanckProblem.from_magnification(
            mean_pressure=float(p0), eta=eta, variance_of_eta=v_eta, pressure_factor=factor,
            drift_of_eta=drift, label="pressure_distribution", **_exact_schedule(spectrum, E, float(p0), float(z)))
        extra.update({"eta": eta, "variance_of_eta": v_eta})
    sol = _solve_full(problem, backend, rtol, options, warm_start=warm_start)
    return replace(sol.result, diagnostics={**sol.result.diagnostics, **extra}), sol


def pressure_distributions(spectrum: Any, *, zetas: Any, backend: str = "auto", progress: bool = False,
                           **kwargs: Any) -> list:
    """:func:`pressure_distribution` for every wall range of ``zetas``, in the given order (a sweep).

    Each native solve starts from the grid the previous one's estimate predicts (docs/backends.md).  Every answer
    meets ``rtol`` on its own; it may differ from a single call's (another grid) by less than ``rtol``.  Sort
    ``zetas`` for the best effect.

    Parameters
    ----------
    spectrum : Spectrum
        As in :func:`pressure_distribution`.
    zetas : array_like
        Wall ranges (length), one-dimensional, each >= 0.
    backend : str
        As in :func:`pressure_distribution`; the chaining applies to ``"native"`` results.
    progress : bool
        Show a tqdm progress bar.
    **kwargs
        Everything else :func:`pressure_distribution` takes, except ``zeta``.

    Returns
    -------
    list of PressureDistribution
        One per entry of ``zetas``.
    """
    z = np.asarray(zetas, dtype=float)
    if z.ndim != 1 or z.size == 0:
        raise ValueError(f"zetas must be a non-empty one-dimensional sequence of wall ranges; got zetas={zetas!r}")
    if "zeta" in kwargs:
        raise ValueError(f"zeta is set by the sweep (each entry of zetas); remove zeta={kwargs['zeta']!r}")
    items = z
    if progress:
        from tqdm.auto import tqdm

        items = tqdm(z, desc="zeta sweep", unit="wall")
    from .fokker_planck.engine import MAX_CELLS

    # the engine's bound on a first level's cells: its finest grid within max_cells
    cap = int(kwargs.get("max_cells", MAX_CELLS)) // 4
    out = []
    start = needed = None
    for zeta in items:
        result, sol = _pressure_distribution(spectrum, zeta=float(zeta), backend=backend, warm_start=start, **kwargs)
        out.append(result)
        start, needed = _sweep_start(result, sol, needed, cap)
    return out


#: the largest growth of the start from one sweep entry to the next (an upward trend of the cells is followed)
SWEEP_TREND_MAX = 1.5


def _sweep_start(result: PressureDistribution, sol: Any, previous_needed: Optional[int], cap: int) -> tuple:
    """``(warm start, cells_needed)`` for the next solve of a sweep after ``result``: ``sol.next_start``, its cells
    grown with the need since ``previous_needed`` (at most SWEEP_TREND_MAX), at most ``cap``; None after another
    backend's or a failed result."""
    if sol is None or result.backend != "native" or not result.success or sol.next_start is None:
        return None, None
    needed = sol.cells_needed
    start = sol.next_start
    if previous_needed:  # where the need grows from entry to entry, start ahead of it
        grown = start.n_start * min(max(needed / previous_needed, 1.0), SWEEP_TREND_MAX)
        start = replace(start, n_start=int(min(math.ceil(grown), cap)))
    return start, needed


def warm_up(backend: str = "native") -> float:
    """Do the one-time work of ``backend`` now (imports; for ``"native"`` the compiled kernels of the engine and
    of the closures, from numba's cache or compiled on the first run after installing); return the seconds spent.

    Call it before timing solves: the first solve of a process otherwise carries this work.
    """
    import time

    from .fokker_planck.backends import warm_up as backend_warm_up

    t0 = time.perf_counter()
    backend_warm_up(_check_backend(backend) if backend != "auto" else "native")
    if backend in ("native", "auto"):
        from .closures._kernels import DIFFUSIVITY, model_rows

        model_rows(np.ones(1), np.ones(1), np.ones(1), DIFFUSIVITY, np.empty((1, 1)))
    return time.perf_counter() - t0
