"""Compiled coefficient rows of the shell closures (:mod:`diffusion_pr.closures`), loaded on first use.

Each kernel evaluates one model for many shells on one pressure grid in a single
pass, with the same floating-point operations in the same order as the numpy
formulas they replace (``tests/diffusion_pr/test_closures.py`` checks the bits),
3-4x faster than numpy on the 96 x (N + 2N + 4N) rows of a closure solve: the
numpy form made three temporaries of the full row block per model.  Compiled with
numba's numpy error model (IEEE division): without the ZeroDivisionError branch on
every division the row loop vectorizes, 11 us instead of 45 us per 48 x 700 block.

Units: pressures ``p`` and the wall products ``kz q`` [pressure]; rows dimensionless
(``f``), [pressure per unit tau] (``b``) and [pressure per unit tau per unit A] (``w``).
"""
from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def _clamped(x):  # pragma: no cover - numba
    """``max(x, 0)`` that keeps a NaN (as ``np.maximum`` does)."""
    return 0.0 if x < 0.0 else x


#: the models of :func:`_model_rows` (numba-free in :mod:`._closure_rows`, with the rows' Python entry points)
from ._closure_rows import BALANCE, DIFFUSIVITY, DRIFT, RowPlan, _c1, model_rows  # noqa: E402,F401


@njit(cache=True, nogil=True, error_model="numpy")
def _model_rows(kq, kq_part, p, model, out):  # pragma: no cover - numba
    """Row ``k`` of one model at the clamped pressures ``p``, written into ``out`` (``kq.size x p.size``); returns
    whether every value is finite.  The models (``kq = kz q_k``, ``kq_part = kz q_part``):

    * ``DIFFUSIVITY``: ``f[k, i] = g^2``, ``g = p_i / (p_i + kq_k)``;
    * ``DRIFT``: ``b[k, i] = part * p_i / (p_i + kq_k)^2``, ``part = kq_part_k / (p_i + kq_part_k)``;
    * ``BALANCE``: ``w[k, i] = kq_part_k p_i / (p_i + kq_part_k)``.
    """
    finite = True
    for k in range(kq.size):
        for i in range(p.size):
            pp = _clamped(p[i])
            if model == DIFFUSIVITY:
                g = pp / (pp + kq[k])
                v = g * g
            elif model == DRIFT:
                part = kq_part[k] / (pp + kq_part[k])
                denom = pp + kq[k]
                v = part * pp / (denom * denom)
            else:
                v = kq_part[k] * pp / (pp + kq_part[k])
            out[k, i] = v
            if not math.isfinite(v):
                finite = False
    return finite


def model_rows_types() -> tuple:
    """The one argument signature :func:`_model_rows` is loaded for (``_rows_kernel``): the products, the
    pressures, the model and a C-contiguous row block."""
    from numba import types as t

    f1 = t.float64[::1]
    return (f1, f1, f1, t.int64, t.float64[:, ::1])


# cached loads skip numba's registry refresh (only a compile needs it): diffusion_pr._numba_load
from ._numba_load import LoadedBySignature, load_without_refresh  # noqa: E402

load_without_refresh(globals())

#: :func:`_model_rows` loaded for :func:`model_rows_types` on first use, as the engine loads its staged kernel (a first
#: call with arguments would go through numba's argument dispatch and its scan for extensions: 0-17 ms of a fresh
#: process's first closure call in alternating runs); other signatures still compile as usual
_rows_kernel = LoadedBySignature(_model_rows, model_rows_types)
