"""Compiled coefficient rows of the shell closures (:mod:`diffusion_pr.closures`), imported on first use.

One model for many shells on one pressure grid in a single pass (numpy needs three or four passes over the row
block and its temporaries: 1.2-1.5x the time of a balanced closure's call on the Fig. 1 scene).

Units: pressures ``p`` and the wall products ``kz q`` [pressure]; rows dimensionless (``f``), [pressure per unit
tau] (``b``) and [pressure per unit tau per unit A] (``w``).
"""
from __future__ import annotations

import math

from numba import njit

__all__ = ["DIFFUSIVITY", "DRIFT", "BALANCE", "model_rows"]

#: the models of :func:`model_rows`
DIFFUSIVITY, DRIFT, BALANCE = 0, 1, 2


@njit(cache=True, nogil=True, error_model="numpy")
def model_rows(kq, kq_part, p, model, out):  # pragma: no cover - numba
    """Row ``k`` of one model at the pressures ``p`` clamped at 0 (a NaN stays NaN), written into ``out``
    (``kq.size x p.size``); returns whether every value is finite.  The models (``kq = kz q_k``,
    ``kq_part = kz q_part``):

    * ``DIFFUSIVITY``: ``f[k, i] = g^2``, ``g = p_i / (p_i + kq_k)``;
    * ``DRIFT``: ``b[k, i] = part * p_i / (p_i + kq_k)^2``, ``part = kq_part_k / (p_i + kq_part_k)``;
    * ``BALANCE``: ``w[k, i] = kq_part_k p_i / (p_i + kq_part_k)``.
    """
    finite = True
    for k in range(kq.size):
        for i in range(p.size):
            pp = 0.0 if p[i] < 0.0 else p[i]
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
