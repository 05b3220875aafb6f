"""Backends for the Fokker-Planck problem, registered by name, imported lazily.

Every backend module exposes ``solve(problem, *, rtol, **options) -> PressureDistribution``.  Importing
:mod:`diffusion_pr` imports none of them: py-pde and FiPy load only when their backend is asked for.
"""
from __future__ import annotations

import functools
import importlib
from typing import Callable, Dict, Tuple

# name -> (module, function, pip extra that provides its dependency or None)
_REGISTRY: Dict[str, Tuple[str, str, str | None]] = {
    "native": ("diffusion_pr.fokker_planck.backends.native", "solve", None),
    "closed_form": ("diffusion_pr.fokker_planck.backends.closed_form", "solve", None),
    "pypde": ("diffusion_pr.fokker_planck.backends.pypde", "solve", "pypde"),
    "fipy": ("diffusion_pr.fokker_planck.backends.fipy", "solve", "fipy"),
}

# the third-party module each optional backend needs
_REQUIRES = {"pypde": "pde", "fipy": "fipy"}


class BackendUnavailableError(ImportError):
    """A registered backend whose third-party dependency is not installed."""


def register_backend(name: str, module: str, function: str = "solve", extra: str | None = None) -> None:
    """Register a backend ``module:function`` under ``name`` (imported on first use)."""
    _REGISTRY[name] = (module, function, extra)


def backend_names() -> list[str]:
    """Names of all registered backends (installed or not)."""
    return sorted(_REGISTRY)


def get_backend(name: str) -> Callable:
    """Import and return the ``solve`` function of backend ``name``.

    Raises
    ------
    ValueError
        Unknown backend name.
    BackendUnavailableError
        The backend's dependency is not installed (the message names the pip extra).
    """
    if name not in _REGISTRY:
        raise ValueError(f"backend must be one of {backend_names()} or 'auto'; got backend={name!r}")
    module, function, _ = _REGISTRY[name]
    if name in _REQUIRES:
        timed_import(_REQUIRES[name], name, _REQUIRES[name])
    return getattr(importlib.import_module(module), function)


def timed_import(module: str, backend: str, label: str) -> tuple[object, float]:
    """Import a backend's third-party ``module``; return ``(module, seconds)`` (0 s if already imported).

    Raises
    ------
    BackendUnavailableError
        When the package is missing; the message names the pip extra.
    """
    import sys
    import time

    cached = sys.modules.get(module) is not None
    t0 = time.perf_counter()
    try:
        mod = importlib.import_module(module)
    except ImportError as exc:
        raise BackendUnavailableError(
            f"backend {backend!r} needs the package {module!r} ({label}), which is not installed; "
            f"install it with: pip install 'diffusion-pr[{_REGISTRY[backend][2]}]'"
        ) from exc
    return mod, (0.0 if cached else time.perf_counter() - t0)


def is_available(name: str) -> bool:
    """Whether backend ``name`` can be imported here (imports its dependency)."""
    try:
        get_backend(name)
    except BackendUnavailableError:
        return False
    return True


def warm_up(name: str) -> float:
    """Do backend ``name``'s one-time work now (imports, compiled kernels); return the seconds spent.

    Call it before timing a backend: solves never warm up silently.
    """
    if name not in _REGISTRY:
        raise ValueError(f"backend must be one of {backend_names()}; got backend={name!r}")
    module = importlib.import_module(_REGISTRY[name][0])
    fn = getattr(module, "warm_up", None)
    return float(fn()) if fn is not None else 0.0


@functools.lru_cache(maxsize=None)
def keyword_options(solve: Callable) -> frozenset:
    """Keyword options of a backend's ``solve`` function (besides ``rtol``), read once per function."""
    import inspect

    params = inspect.signature(solve).parameters
    return frozenset(k for k, v in params.items() if v.kind == v.KEYWORD_ONLY and k != "rtol")
