"""Public entry points: :func:`propagate` and :func:`pressure_distribution`.

``propagate`` solves the Fokker-Planck problem of docs/theory.md in the diffusion time ``tau``;
``pressure_distribution`` does the whole scene of Müser, PRL 100, 055504 (2008),
doi:10.1103/PhysRevLett.100.055504: the stress variance of the spectrum, the pressure factor ``f(p) = c(p) t(p)``,
an optional drift, and the solve.  ``backend="auto"`` takes the closed form wherever it is exact, else
``"native"`` (docs/backends.md, "Backends"); every backend returns the same ``zero_weight`` and density within ``rtol``.
A result with ``success=False`` is returned with a :class:`ConvergenceWarning` carrying its message."""
from __future__ import annotations

import warnings
from dataclasses import replace
from typing import Any, Callable, Optional

import numpy as np

from ._validation import check_callable, check_finite_array, check_int, check_nonnegative, check_positive
from .models import PressureFactor, make_cutoff, make_tail
from .paper import contact_threshold
from .problem import FokkerPlanckProblem, StagedProblem
from .result import PressureDistribution

#: the closures of :func:`pressure_distribution` when none is named, on exponential walls and at the hard wall:
#: the parameter-free closures closest to GFMD on the held-out scenes of the evidence base (docs/closures.md)
DEFAULT_CLOSURE, HARD_WALL_DEFAULT = "local_g1_shell_balanced", "sum_rule"

__all__ = ["warm_up", "propagate", "pressure_distribution", "pressure_distributions", "solve_problem",
           "choose_backend", "BACKENDS", "DEFAULT_CLOSURE", "HARD_WALL_DEFAULT", "ConvergenceWarning"]

#: names accepted by ``backend=`` (besides any registered later)
BACKENDS = ("auto", "closed_form", "native", "pypde", "fipy")

#: magnification nodes for a drift A(p, eta) (log-spaced from 1 to q_max/q_min)
N_ETA = 513

#: the most cells ``max_cells`` may allow (about 1 GB of the engine's float64 work arrays)
MAX_CELLS_LIMIT = 1 << 22


class ConvergenceWarning(UserWarning):
    """A solve returned ``success=False`` (its ``message`` says why); filter it with
    ``warnings.simplefilter("ignore", diffusion_pr.ConvergenceWarning)``."""


def _checked(result: PressureDistribution) -> PressureDistribution:
    """``result``, with a :class:`ConvergenceWarning` (pointing at the user's call) when it failed."""
    if not result.success:
        warnings.warn(f"backend {result.backend!r} returned success=False: {result.message}", ConvergenceWarning,
                      stacklevel=3)
    return result


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
    from .fokker_planck.backends import get_backend, keyword_options
    from .fokker_planck.backends.closed_form import exact_kind

    if not isinstance(problem, FokkerPlanckProblem) or exact_kind(problem) is None:
        return "native"
    return "native" if set(options or ()) - set(keyword_options(get_backend("closed_form"))) else "closed_form"


def _check_cells(problem: Any, options: dict) -> None:
    """``max_cells``, ``n_cells`` (the coarsest of three nested grids, the finest 4x as fine) within the limits,
    and ``p_floor`` only where the wall is not reached (Feller: ``f ~ p^k`` with ``k >= 2``)."""
    from .fokker_planck.engine import MAX_CELLS
    from .models import breakpoints_of, wall_reached, zero_power_of

    cap = check_int("max_cells", options.get("max_cells", MAX_CELLS), minimum=32)
    if cap > MAX_CELLS_LIMIT:
        raise ValueError(f"max_cells must be an integer in [32, {MAX_CELLS_LIMIT}] (memory); got max_cells={cap}")
    n = options.get("n_cells")
    if n is not None and check_int("n_cells", n, minimum=8) > cap // 4:
        raise ValueError(f"n_cells must be an integer in [8, max_cells/4 = {cap // 4}] (its finest grid has "
                         f"4 n_cells cells, at most max_cells={cap}); got n_cells={n}")
    if options.get("p_floor") is None or getattr(problem, "time_dependent", False):
        return
    p0 = problem.mean_pressure
    fs = [s.diffusivity for s in problem.stages] if isinstance(problem, StagedProblem) else [problem.diffusivity]
    k = min(zero_power_of(f, min([p0, *breakpoints_of(f, 0.0, p0)])) for f in fs)
    if wall_reached(k):
        raise ValueError(f"p_floor applies where no mass reaches p = 0 (f ~ p^k with k >= 2); this diffusivity has "
                         f"k = {k:g}: p = 0 absorbs and has no floor; got p_floor={options['p_floor']!r}")


def _solve_full(problem: Any, backend: str, rtol: float, options: dict) -> Any:
    """The solve, with the engine's :class:`~diffusion_pr.fokker_planck.engine.FVSolution` (a closed form gives a
    solution holding its result alone)."""
    import sys

    from .fokker_planck.backends import get_backend, keyword_options
    from .fokker_planck.engine import FVSolution

    backend, rtol = _check_backend(backend), _check_rtol(rtol)
    chosen = choose_backend(problem, options) if backend == "auto" else backend
    solver = get_backend(chosen)
    unknown = set(options) - keyword_options(solver)
    if unknown:
        raise ValueError(f"unknown option(s) {sorted(unknown)} for backend {chosen!r}; it accepts "
                         f"{sorted(keyword_options(solver))}")
    full = getattr(sys.modules[solver.__module__], "solve_full", None)
    if full is None:
        sol = FVSolution(result=solver(problem, rtol=rtol, **options))
    else:
        _check_cells(problem, options)
        sol = full(problem, rtol=rtol, **options)
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
        The backend's own options (e.g. ``n_cells`` <= ``max_cells/4``, ``max_cells`` <= 2^22, ``p_floor`` where
        the wall is not reached); an unknown name is an error.

    Raises
    ------
    ValueError
        Unknown backend or option, bad ``rtol``, or ``closed_form`` asked for a problem without a closed form.
    BackendUnavailableError
        The backend's optional dependency is missing (the message names the pip extra).

    Warns
    -----
    ConvergenceWarning
        When the result has ``success=False``.
    """
    if not isinstance(problem, (FokkerPlanckProblem, StagedProblem)):
        raise ValueError(f"problem must be a FokkerPlanckProblem or StagedProblem; got {type(problem).__name__}")
    return _checked(_solve_full(problem, backend, rtol, options).result)


def propagate(mean_pressure: float, variance: float, *,
              diffusivity: Optional[Callable[[np.ndarray], np.ndarray]] = None,
              drift: Optional[Callable[[np.ndarray, float], np.ndarray]] = None, backend: str = "auto",
              rtol: float = 1e-6, **options: Any) -> PressureDistribution:
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
        Backend options, as in :func:`solve_problem`.

    Returns
    -------
    PressureDistribution
        With a :class:`ConvergenceWarning` when ``success`` is False.

    Raises
    ------
    ValueError
        Bad ``mean_pressure``/``variance`` (NaN, <= 0, complex), a non-callable or negative ``diffusivity``, a
        non-callable ``drift``; otherwise as :func:`solve_problem`.

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
    for name, fn in (("diffusivity", diffusivity), ("drift", drift)):
        if fn is not None:
            check_callable(name, fn)
    problem = FokkerPlanckProblem(float(p0), float(var), diffusivity, drift=drift)
    return _checked(_solve_full(problem, backend, rtol, options).result)


def pressure_distribution(spectrum: Any, *, E_star: float, mean_pressure: float, zeta: float = 0.0,
                          cutoff: Any = "sharp", p_c: Optional[float] = None, tail: Any = None,
                          p_t: Optional[float] = None,
                          drift: Optional[Callable[[np.ndarray, float], np.ndarray]] = None, backend: str = "auto",
                          rtol: float = 1e-6, closure: Optional[str] = None, **options: Any) -> PressureDistribution:
    """Pressure distribution of a rough contact (Müser 2008, Eqs. 2, 9, 10; docs/theory.md).

    ``closure`` picks the theory (docs/closures.md, :data:`diffusion_pr.closures.CLOSURES`).  ``None`` (default):
    the closures chosen on held-out GFMD ensembles, :data:`DEFAULT_CLOSURE` on exponential walls and
    :data:`HARD_WALL_DEFAULT` at ``zeta = 0``; the paper's ``"second_order"`` where one of its own options (a cutoff
    other than ``"sharp"``, ``p_c``, ``tail``, ``p_t``, ``drift``, ``backend="closed_form"``) is given.  Named:
    ``"second_order"`` (the paper; Persson's mirror Gaussian at ``zeta = 0``), the hard-wall closures
    ``"sum_rule"`` and the fitted ``"yang_persson"``, ``"wang_muser"`` (``zeta = 0``), the
    parameter-free ``"lognormal_gap"`` (a closed form:
    ``backend`` ``"auto"``/``"closed_form"`` only, no solver options; defined for exponential walls ``zeta > 0``
    and meaningful where the gap's linear response holds, i.e. ``V/p0^2`` small, large ``zeta``),
    ``"local_g1"``, ``"local_g1_balanced"``, ``"local_g1_shell_balanced"`` (no cutoff, tail or drift; solved by
    :mod:`diffusion_pr.closures` on a finite-volume backend; on a continuum spectrum extrapolated to the continuum
    limit in the number of shells).  ``diagnostics["closure"]`` names the closure in every result.

    Steps: ``V = stress_variance(...)`` (Eqs. 9-10); ``f(p) = c(p) t(p)``; one solve of ``dPr/dtau = d^2(f Pr)/dp^2``
    to ``tau = V/2``; a drift ``A(p, eta)`` is mapped onto ``tau`` through ``V(eta)`` (``eta = q/q_min``).

    Parameters
    ----------
    spectrum : Spectrum
        :class:`~diffusion_pr.spectra.SelfAffineSpectrum` or :class:`~diffusion_pr.spectra.DiscreteSpectrum`.
    E_star : float
        Contact modulus (pressure), > 0.
    mean_pressure : float
        ``p0`` (pressure), > 0.
    zeta : float
        Range of the exponential repulsion, >= 0 (0 = hard wall), in the length unit of the spectrum (that of its
        ``L = 2 pi / q_min``).
    cutoff : str or callable
        ``"sharp"`` (default; exact mirror Gaussian, takes no ``p_c``), ``"muser"``/``"seed"`` (the paper's printed
        factor, discontinuous at ``p_c``), ``"raised_cosine"`` (C1), ``"smoothstep"`` (C2), or a callable ``c(p)``.
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
        As in :func:`propagate`.  The shell closures take two more options: ``n_shells`` (the number of shells,
        default 96; with the extrapolation its first solve's, default 48) and ``shell_extrapolation`` (default
        None: True for a continuum spectrum without ``n_shells``; True: the continuum closure, its
        ``error_estimate`` the grids' estimate plus the shells' residual; False: the ``n_shells`` problem itself,
        exact for a :class:`~diffusion_pr.spectra.DiscreteSpectrum`'s own shells).

    Returns
    -------
    PressureDistribution
        With ``diagnostics["stress_variance"]`` (``V``, pressure squared), ``diagnostics["zeta"]`` and, with a
        drift, the ``eta`` grid used; a :class:`ConvergenceWarning` when ``success`` is False.  ``contact_area()``
        counts ``p > 0`` at ``zeta = 0``, ``p > 0.01 p0`` (GFMD's threshold) at ``zeta > 0``.

    Raises
    ------
    ValueError
        Bad numbers (NaN, out of range, complex) naming the parameter, NaN spectra, an overflowing ``E_star``, a
        ``p_c``/``p_t`` missing or one the cutoff/tail would ignore, unknown names, a backend or option the
        closure does not use.
    """
    return _checked(_pressure_distribution(spectrum, E_star=E_star, mean_pressure=mean_pressure, zeta=zeta,
                                           cutoff=cutoff, p_c=p_c, tail=tail, p_t=p_t, drift=drift, backend=backend,
                                           rtol=rtol, closure=closure, **options))


def _pressure_distribution(spectrum: Any, *, E_star: float, mean_pressure: float, zeta: float = 0.0,
                           cutoff: Any = "sharp", p_c: Optional[float] = None, tail: Any = None,
                           p_t: Optional[float] = None, drift: Optional[Callable] = None, backend: str = "auto",
                           rtol: float = 1e-6, closure: Optional[str] = None,
                           **options: Any) -> PressureDistribution:
    """:func:`pressure_distribution`'s result before the :class:`ConvergenceWarning` check."""
    from .closures import PERSSON_CORRECTIONS, check_closure, closure_distribution

    backend, rtol = _check_backend(backend), _check_rtol(rtol)
    if closure is None:
        paper_options = cutoff != "sharp" or backend == "closed_form" or any(
            v is not None for v in (p_c, tail, p_t, drift))
        closure = "second_order" if paper_options else HARD_WALL_DEFAULT if np.all(np.asarray(zeta) == 0) \
            else DEFAULT_CLOSURE
    gamma = PERSSON_CORRECTIONS.get(check_closure(closure))
    retimed = gamma is not None or closure == "sum_rule"  # Persson on another clock: a mirror Gaussian
    if retimed and (np.any(np.asarray(zeta) != 0) or cutoff != "sharp" or tail is not None or drift is not None):
        raise ValueError(f"closure={closure!r} corrects Persson's hard-wall theory: it needs zeta=0 and no cutoff, "
                         f"tail or drift; got zeta={zeta!r}, cutoff={cutoff!r}, tail={tail!r}, drift={drift!r}")
    if closure != "second_order" and not retimed:
        for name, value in (("drift", drift), ("cutoff", None if cutoff == "sharp" else cutoff), ("p_c", p_c),
                            ("tail", tail), ("p_t", p_t)):
            if value is not None:
                raise ValueError(f"{name} applies to closure='second_order' only (the paper's theory: pass it); "
                                 f"closure={closure!r} has no fitted cutoff, tail or drift (got {name}={value!r})")
        given = sorted(k for k, v in options.items() if v is not None)
        if closure == "lognormal_gap" and (backend not in ("auto", "closed_form") or given):
            raise ValueError(f"closure='lognormal_gap' is a closed form: backend must be 'auto' or 'closed_form' "
                             f"(got backend={backend!r}) and solver options do not apply (got {given})")
        result = closure_distribution(spectrum, E_star=E_star, mean_pressure=mean_pressure, zeta=zeta,
                                      closure=closure, backend=backend, rtol=rtol, **options)
        return replace(result, contact_threshold=contact_threshold(zeta, mean_pressure))
    for name in ("n_shells", "shell_extrapolation"):
        if options.pop(name, None) is not None:
            raise ValueError(f"{name} applies to the shell closures, not to 'second_order'")
    from .cumulants import stress_variance, variance_vs_magnification

    E = check_positive("E_star", E_star)
    p0 = check_positive("mean_pressure", mean_pressure)
    z = check_nonnegative("zeta", zeta)
    if np.ndim(z) or np.ndim(p0) or np.ndim(E):
        raise ValueError("E_star, mean_pressure and zeta must be scalars here "
                         "(stress_variance is vectorized over zeta; pressure_distributions sweeps zetas)")
    for name, value in (("p_c", p_c), ("p_t", p_t)):
        if value is not None and np.ndim(check_positive(name, value)) != 0:
            raise ValueError(f"{name} must be one number > 0 (units of pressure); got {name}={value!r}")
    if drift is not None:
        check_callable("drift", drift)
    factor = PressureFactor(make_cutoff(cutoff, p_c), make_tail(tail, p_t))
    V = float(stress_variance(spectrum, E_star=E, mean_pressure=p0, zeta=z))
    if not np.isfinite(V) or V <= 0.0:
        raise ValueError(f"the stress variance of this spectrum is {V!r}; it must be finite and > 0 "
                         "(check the spectrum for NaN or zero amplitude)")
    extra: dict = {"stress_variance": V, "zeta": float(z), "E_star": float(E), "pressure_factor": factor,
                   "closure": closure}
    if retimed:
        from .closed_forms import persson_corrected_variance, sum_rule_variance

        extra.update(gamma=gamma, retimed_variance=sum_rule_variance(float(p0), V) if gamma is None
                     else persson_corrected_variance(float(p0), V, gamma))
    if drift is None:
        problem = FokkerPlanckProblem(float(p0), extra.get("retimed_variance", V), factor,
                                      label="pressure_distribution")
    else:
        eta = np.geomspace(1.0, float(spectrum.q_max / spectrum.q_min), N_ETA)
        v_eta = np.asarray(variance_vs_magnification(spectrum, eta, E_star=E, mean_pressure=p0, zeta=z), dtype=float)
        if not np.all(np.isfinite(v_eta)):
            raise ValueError("variance_vs_magnification returned non-finite values; check the spectrum")
        v_eta = np.maximum.accumulate(v_eta)
        problem = FokkerPlanckProblem.from_magnification(
            mean_pressure=float(p0), eta=eta, variance_of_eta=v_eta, pressure_factor=factor,
            drift_of_eta=drift, label="pressure_distribution", **_exact_schedule(spectrum, E, float(p0), float(z)))
        extra.update({"eta": eta, "variance_of_eta": v_eta})
    result = _solve_full(problem, backend, rtol, options).result
    return replace(result, diagnostics={**result.diagnostics, **extra}, contact_threshold=contact_threshold(z, p0))


def pressure_distributions(spectrum: Any, *, zetas: Any, backend: str = "auto", progress: bool = False,
                           **kwargs: Any) -> list:
    """:func:`pressure_distribution` for every wall range of ``zetas``, in the given order (a sweep).

    Each entry is solved on its own (equal to a single call's result).  ``zetas``: the wall ranges (the spectrum's
    length unit), one-dimensional, each >= 0; ``progress``: a tqdm progress bar; everything else as
    :func:`pressure_distribution`.
    Returns one :class:`PressureDistribution` per entry of ``zetas`` (a :class:`ConvergenceWarning` for each failed
    one)."""
    if np.ndim(zetas) != 1 or np.size(zetas) == 0:
        raise ValueError(f"zetas must be a non-empty one-dimensional sequence of wall ranges; got zetas={zetas!r}")
    z = check_finite_array("zetas", zetas, ndim=1)
    if "zeta" in kwargs:
        raise ValueError(f"zeta is set by the sweep (each entry of zetas); remove zeta={kwargs['zeta']!r}")
    if progress:
        from tqdm.auto import tqdm

        z = tqdm(z, desc="zeta sweep", unit="wall")
    return [_checked(_pressure_distribution(spectrum, zeta=float(zeta), backend=backend, **kwargs)) for zeta in z]


def warm_up(backend: str = "native") -> float:
    """Do the one-time work of ``backend`` now (imports; for ``"native"`` the compiled kernels of the engine and
    of the closures, from numba's cache or compiled on the first run after installing); return the seconds spent.

    Call it before timing solves: the first solve of a process otherwise carries this work."""
    import time

    from .fokker_planck.backends import warm_up as backend_warm_up

    t0 = time.perf_counter()
    backend_warm_up(_check_backend(backend) if backend != "auto" else "native")
    if backend in ("native", "auto"):
        from .closures._kernels import DIFFUSIVITY, model_rows

        model_rows(np.ones(1), np.ones(1), np.ones(1), DIFFUSIVITY, np.empty((1, 1)))
    return time.perf_counter() - t0
