"""Compiled coefficient rows of the shell closures (:mod:`diffusion_pr.closures`), loaded on first use.

Each kernel evaluates one model for many shells on one pressure grid in a single
pass, with the same floating-point operations in the same order as the numpy
formulas they replace (``tests/diffusion_pr/test_closures.py`` checks the bits),
3-4x faster than numpy on the 96 x (N + 2N + 4N) rows of a closure solve: the
numpy form made three temporaries of the full row block per model.

Units: pressures ``p`` and the wall products ``kz q`` [pressure]; rows dimensionless
(``f``), [pressure per unit tau] (``b``) and [pressure per unit tau per unit A] (``w``).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _clamped(x):  # pragma: no cover - numba
    """``max(x, 0)`` that keeps a NaN (as ``np.maximum`` does)."""
    return 0.0 if x < 0.0 else x


#: the models of :func:`_model_rows`
DIFFUSIVITY, DRIFT, BALANCE = 0, 1, 2


@njit(cache=True, nogil=True)
def _model_rows(kq, kq_part, p, model):  # pragma: no cover - numba
    """Row ``k`` of one model (``DIFFUSIVITY``, ``DRIFT`` or ``BALANCE``) at the clamped pressures ``p``."""
    out = np.empty((kq.size, p.size))
    for k in range(kq.size):
        for i in range(p.size):
            pp = _clamped(p[i])
            if model == DIFFUSIVITY:
                g = pp / (pp + kq[k])
                out[k, i] = g * g
            elif model == DRIFT:
                part = kq_part[k] / (pp + kq_part[k])
                denom = pp + kq[k]
                out[k, i] = part * pp / (denom * denom)
            else:
                out[k, i] = kq_part[k] * pp / (pp + kq_part[k])
    return out


def diffusivity_rows(kq: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``f[k, i] = g^2``, ``g = p_i / (p_i + kq_k)`` (``p`` clamped at 0; ``kq = kz q_k``)."""
    return _model_rows(kq, kq, p, DIFFUSIVITY)


def drift_rows(kq: np.ndarray, kq_part: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``b[k, i] = part * p / (p + kq_k)^2``, ``part = kq_part_k / (p + kq_part_k)``."""
    return _model_rows(kq, kq_part, p, DRIFT)


def balance_rows(kq_part: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``w[k, i] = kq_part_k p / (p + kq_part_k)``."""
    return _model_rows(kq_part, kq_part, p, BALANCE)


# cached loads skip numba's registry refresh (only a compile needs it): diffusion_pr._numba_load
from ._numba_load import load_without_refresh  # noqa: E402

load_without_refresh(globals())
