"""Compiled Newton iterations of a grid family's edges (:func:`.grid.edges_for`), the same bits as the numpy form.

An edge is the inverse of the monitor at its target: Newton on ``Phi`` (:func:`.grid._invert`) and, for a remapped
family, first safeguarded Newton on the remap ``F`` (:meth:`.grid.Remap.inverse`). In numpy each iteration is some
25 array calls on a few hundred points; a balanced closure's remapped second level spent 0.8-1.9 ms of its call
there on the Fig. 1 scenes, in the main thread while the worker waited. Compiled, each edge is iterated on its own
(each edge's value depends on its own target only, in the numpy form too) with the same floating-point operations
in the same order: numpy's ``a ** 4`` and ``a ** 3`` are the C library's ``pow``, its ``log``, ``arcsinh`` and
``sqrt`` the C library's (on this machine's numpy, which has no AVX-512 paths), and so are numba's ``math``
functions here. ``tests/diffusion_pr/test_grid.py`` compares the edges bit for bit with the numpy form. The
engine asks for them where its solve is compiled anyway (:func:`.engine._compiled`); other solves keep numpy (no
numba import for them).

Units: pressures ``p``, ``p_wall``, ``p0``, ``delta``, ``w0``, ``scale`` [pressure]; the monitor's values
dimensionless.
"""
from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def _piece(x, v):  # pragma: no cover - numba
    """``clip(searchsorted(x, v, side="right") - 1, 0, x.size - 2)`` for one value (a NaN sorts last)."""
    n = x.size
    if v != v:
        return n - 2
    lo, hi = 0, n  # the first index with x[i] > v lies in [lo, hi]
    while lo < hi:
        mid = (lo + hi) // 2
        if x[mid] <= v:
            lo = mid + 1
        else:
            hi = mid
    i = lo - 1
    if i < 0:
        return 0
    if i > n - 2:
        return n - 2
    return i


@njit(cache=True, nogil=True, error_model="numpy")
def _remap_both(x, y_last, pieces, v):  # pragma: no cover - numba
    """``(F(v), D(v))`` of :meth:`.grid.Remap._both` for one value: the piece's numbers from its table, the same
    expressions."""
    i = _piece(x, v)
    x_last = x[x.size - 1]
    xl, xr, h, ml, mr = pieces[0, i], pieces[1, i], pieces[2, i], pieces[3, i], pieces[4, i]
    h6, c_l, c_r, cum, h4 = pieces[5, i], pieces[6, i], pieces[7, i], pieces[8, i], pieces[9, i]
    h24, c_l2, hh, c_r2 = pieces[10, i], pieces[11, i], pieces[12, i], pieces[13, i]
    w = x_last if v > x_last else v  # np.minimum(v, x_last), a NaN kept
    b = w - xl
    a = h - b
    f = cum + (ml * (h4 - math.pow(a, 4.0)) + mr * math.pow(b, 4.0)) / h24 + c_l2 * (hh - a * a) + c_r2 * b * b
    beyond = v - x_last
    f = f + y_last * (0.0 if beyond < 0.0 else beyond)  # np.maximum(v - x_last, 0.0), a NaN kept
    if v > x_last:
        d = y_last
    else:
        a = xr - w
        d = (ml * math.pow(a, 3.0) + mr * math.pow(b, 3.0)) / h6 + c_l * a + c_r * b
    return f, d


@njit(cache=True, nogil=True, error_model="numpy")
def remap_both_many(x, y_last, pieces, v, f_out, d_out):  # pragma: no cover - numba
    """``F`` and ``D`` of :meth:`.grid.Remap._both` at every ``v``, written into ``f_out`` and ``d_out``."""
    for j in range(v.size):
        f_out[j], d_out[j] = _remap_both(x, y_last, pieces, v[j])


@njit(cache=True, nogil=True, error_model="numpy")
def remap_inverse(t, x0, lo0, hi0, tol, iterations, x, y_last, pieces, out):  # pragma: no cover - numba
    """:func:`.grid._safeguarded_newton` on ``F`` (:meth:`.grid.Remap.inverse`): for each target ``t[j]`` from
    ``x0[j]`` in the bracket ``[lo0[j], hi0[j]]``, Newton steps, bisection where a step would leave the bracket,
    until ``|F - t| <= tol`` or ``iterations`` evaluations; written into ``out``."""
    for j in range(t.size):
        v, lo, hi = x0[j], lo0[j], hi0[j]
        for _ in range(iterations):
            f, df = _remap_both(x, y_last, pieces, v)
            r = f - t[j]
            if abs(r) <= tol:
                break
            if r < 0:
                lo = v
            if r > 0:
                hi = v
            step = v - r / df
            if step <= lo or step >= hi:
                v = 0.5 * (lo + hi)
            else:
                v = step
        out[j] = v


@njit(cache=True, nogil=True, error_model="numpy")
def monitor_newton(targets, x0, tol, a, b, p_wall, scale, c_wall, delta, c_0, p0, w0, w0_squared,
                   out):  # pragma: no cover - numba
    """:func:`.grid._invert`'s plain Newton on the monitor ``Phi`` (:meth:`.grid.GridSpec.phi`, ``dphi``) for each
    target from ``x0``, at most 8 checks; written into ``out``. Returns False where an edge left ``[a, b]`` (or
    became NaN) or did not converge: the numpy form then starts its safeguarded Newton for all edges
    (:func:`.grid._invert_safe`), and so does the caller."""
    for j in range(targets.size):
        p = x0[j]
        converged = False
        for _ in range(8):
            rel = p - p_wall
            phi = rel / scale
            if c_wall > 0.0:
                phi = phi + math.log((rel + delta) / delta) * c_wall
            if c_0 > 0.0:
                phi = phi + math.asinh((p - p0) / w0) * c_0
            r = phi - targets[j]
            if abs(r) <= tol[j]:
                converged = True
                break
            dphi = 1.0 / scale
            if c_wall > 0.0:
                dphi = dphi + c_wall / ((p - p_wall) + delta)
            if c_0 > 0.0:
                z = p - p0
                dphi = dphi + c_0 / math.sqrt(z * z + w0_squared)
            p = p - r / dphi
            if not (a <= p and p <= b):
                return False
        if not converged:
            return False
        out[j] = p
    return True


def remap_inverse_types() -> tuple:
    """The one argument signature :func:`remap_inverse` is loaded for."""
    from numba import types as t

    f1 = t.float64[::1]
    return (f1, f1, f1, f1, t.float64, t.int64, f1, t.float64, t.float64[:, ::1], f1)


def remap_both_types() -> tuple:
    """The one argument signature :func:`remap_both_many` is loaded for."""
    from numba import types as t

    f1 = t.float64[::1]
    return (f1, t.float64, t.float64[:, ::1], f1, f1, f1)


def monitor_newton_types() -> tuple:
    """The one argument signature :func:`monitor_newton` is loaded for."""
    from numba import types as t

    f1 = t.float64[::1]
    return (f1, f1, f1) + (t.float64,) * 10 + (f1,)


# cached loads skip numba's registry refresh (only a compile needs it): diffusion_pr._numba_load
from ..._numba_load import LoadedBySignature, load_without_refresh  # noqa: E402

load_without_refresh(globals())

#: the kernels loaded for their one signature on first use
remap_inverse_kernel = LoadedBySignature(remap_inverse, remap_inverse_types)
monitor_newton_kernel = LoadedBySignature(monitor_newton, monitor_newton_types)
remap_both_kernel = LoadedBySignature(remap_both_many, remap_both_types)
