"""Compiled extension modules loaded from their files, without importing the packages they belong to.

Importing a package's compiled submodule the usual way imports the package first: ``scipy.linalg`` (about 0.2 s:
``numpy.f2py``, the array-API layer) for LAPACK's ``_flapack``, numba (0.15-0.37 s) for its runtime and helpers.
The extension itself loads in a few milliseconds. Used by :mod:`diffusion_pr.solvers.fv.cram` (``zgtsv``) and
:mod:`diffusion_pr._machine_code` (numba's C helpers).
"""
from __future__ import annotations

import glob
import importlib.machinery
import importlib.util
from pathlib import Path
from types import ModuleType
from typing import Union

__all__ = ["extension_file", "load_extension"]


def extension_file(folder: Union[str, Path], pattern: str) -> Path:
    """The first file (sorted) in ``folder`` matching ``pattern`` (for instance ``"_flapack*"``)."""
    found = sorted(glob.glob(str(Path(folder) / pattern)))
    if not found:
        raise FileNotFoundError(f"no extension {pattern!r} in {folder}")
    return Path(found[0])


def load_extension(name: str, path: Union[str, Path]) -> ModuleType:
    """The extension module at ``path``, initialized under ``name`` (its init function is ``PyInit_`` and the last
    part of ``name``). Not put in ``sys.modules``: the caller decides."""
    loader = importlib.machinery.ExtensionFileLoader(name, str(path))
    module = importlib.util.module_from_spec(importlib.util.spec_from_file_location(name, str(path), loader=loader))
    loader.exec_module(module)
    return module
