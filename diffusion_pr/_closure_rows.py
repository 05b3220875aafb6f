"""The shell closures' coefficient rows from Python: the compiled kernel of :mod:`._closure_kernels` called
without importing numba where its machine code is stored (:mod:`._machine_code`).

Units: pressures ``p`` and the wall products ``kz q`` [pressure]; rows dimensionless (``f``), [pressure per unit
tau] (``b``) and [pressure per unit tau per unit A] (``w``).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ._machine_code import kernel

__all__ = ["DIFFUSIVITY", "DRIFT", "BALANCE", "model_rows", "RowPlan"]

#: the models of :func:`diffusion_pr._closure_kernels._model_rows`
DIFFUSIVITY, DRIFT, BALANCE = 0, 1, 2


def _rows_kernel():
    """:func:`diffusion_pr._closure_kernels._model_rows` for its one signature (stored machine code or numba)."""
    return kernel("diffusion_pr._closure_kernels", "_rows_kernel")


def _c1(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float).reshape(-1)


def model_rows(kq: np.ndarray, kq_part: np.ndarray, p: np.ndarray, model: int) -> np.ndarray:
    """The rows of ``model`` for the shells' products ``kq`` (and ``kq_part``) at the pressures ``p`` (a new array;
    a NaN of ``p`` stays NaN)."""
    kq, kq_part, p = _c1(kq), _c1(kq_part), _c1(p)
    out = np.empty((kq.size, p.size))
    _rows_kernel()(kq, kq_part, p, int(model), out)
    return out


class RowPlan:
    """The rows of one model for a fixed set of shells, made once per problem and evaluated on many grids.

    ``plan(p, out=None)`` writes the rows at the pressures ``p`` (1-D) into ``out`` (a C-contiguous float array of
    shape ``(shells, p.size)``; a new one where None or of another layout) in one compiled call that releases the
    GIL, and returns it, or None where a value is not finite (the caller then takes its checked path, which says
    where).  The same bits as :func:`model_rows`.
    """

    __slots__ = ("kq", "kq_part", "model")

    def __init__(self, kq: np.ndarray, kq_part: np.ndarray, model: int) -> None:
        self.kq, self.kq_part, self.model = _c1(kq), _c1(kq_part), int(model)

    def __len__(self) -> int:
        return int(self.kq.size)

    def __call__(self, p: np.ndarray, out: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
        p = _c1(p)
        shape = (self.kq.size, p.size)
        target = out if (out is not None and out.shape == shape and out.dtype == np.float64
                         and out.flags.c_contiguous) else np.empty(shape)
        if not _rows_kernel()(self.kq, self.kq_part, p, self.model, target):
            return None
        if out is not None and target is not out:
            out[...] = target
            return out
        return target
