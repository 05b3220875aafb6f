"""The Fokker-Planck solvers: the finite-volume engine and the backends that share it.

Layers (each imports only the ones before it): :mod:`.operator` (the finite-volume bands),
:mod:`.grid` (monitor-function grids), :mod:`.expm` (CRAM-16 exponentials), :mod:`._kernels`
(the compiled stage loop), :mod:`.domain` (the wall, the floor, the domain: :func:`~.domain.prepare`),
:mod:`.stages` (one grid's integration), :mod:`.grading` (the grid family adapted after the first level),
:mod:`.engine` (nested grids, Richardson, the one result builder) and
:mod:`.backends` (``native``, ``closed_form``, ``pypde``, ``fipy``, registered by name and imported
lazily).  Importing this package imports none of them.
"""
from __future__ import annotations

import importlib
from typing import Any

_LAZY = {"solve_fv": "engine", "prepare": "domain", "build_result": "engine", "FLOOR": "domain",
         "MAX_CELLS": "engine", "DIAGNOSTIC_KEYS": "engine"}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)
