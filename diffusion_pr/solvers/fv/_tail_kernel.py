"""The domain probe's tail bounds for drifts that grow with ``p``, compiled: the affine envelope of the drift and its
moments (:func:`.engine._affine_envelope_bound`) and the Riccati recursion of the Chernoff bound
(:func:`.engine._affine_chernoff_bound`).

The envelope and its moments are a few array passes over the stages x probe rows and a loop over the stages, 0.1-0.2
ms of numpy and Python per probe round for the 48 stages of a balanced closure (two rounds per solve); compiled, one
pass each, with the numpy form's operations.

The bound's recursion runs backwards through the stages, each stage a dozen operations on every ``theta`` of its
grid (241 points). As numpy array expressions that is about 25 calls per stage: 5.5-6.8 ms for the 48 stages of
``local_g1_shell_balanced`` at ``zeta = 4`` on the Fig. 1 scene, a quarter of that closure's call. Compiled: the same
floating-point operations in the same order as the numpy expressions (numpy's ``w ** 3`` is the C library's
``pow(w, 3.0)``, its ``log1p`` the C library's), so the moments are the same bits
(``tests/diffusion_pr/test_native.py`` compares the rows of the two on random stages and on the closure's). The
engine calls it where a problem has :data:`.engine.COMPILED_MIN_PIECES` stages or more (its solve loads numba
anyway); a problem of fewer stages keeps the numpy form (no numba import for it, 20-60 us of numpy).

Units: ``theta`` [1/pressure]; the envelopes ``f0 + f1 p`` of the diffusivity and ``c + g p`` of the drift in the
problem's units (``f1``, ``g`` per unit of pressure); ``psi`` in the problem's diffusion time; ``grow`` dimensionless;
the moments ``A`` dimensionless, ``B`` [1/pressure].
"""
from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def _chernoff_rows(theta, f1, f0, g, c, psi, grow, a_out, b_out, ok_out):  # pragma: no cover - numba
    """The moments ``A``, ``B`` at every ``theta`` and whether they stayed finite, written into ``a_out``, ``b_out``,
    ``ok_out``.

    The stages are given in their order and applied from the last to the first, as
    :func:`.engine._chernoff_moments`'s numpy loop does: ``w = f1 B psi``; a ``theta`` whose ``w`` reached 1 (or was
    not finite) drops out and has ``w = 0`` from then on; ``A += c B psi L(w) + f0 B^2 psi (1/(1 - w) + g psi
    H(w))``, ``B <- B grow/(1 - w)``, ``L`` and ``H`` by their series where ``|w| < 1e-3``. Each ``theta`` is
    independent of the others, so the loops are exchanged (``theta`` outside): the same operations per value.
    """
    for i in range(theta.size):
        a = 0.0
        b = theta[i]
        ok = True
        for k in range(f1.size - 1, -1, -1):
            w = f1[k] * b * psi[k]
            ok = ok and (w < 1.0)
            if not ok:
                w = 0.0
            if abs(w) < 1e-3:
                w3 = math.pow(w, 3.0)  # numpy's w ** 3 (the C library's pow, not w * w * w)
                ell = 1.0 + w / 2.0 + w * w / 3.0 + w3 / 4.0
                h = 0.5 + 2.0 * w / 3.0 + 0.75 * w * w + 0.8 * w3
            else:
                lg = math.log1p(-w)
                ell = -lg / w
                h = (w / (1.0 - w) + lg) / (w * w)
            a = a + c[k] * b * psi[k] * ell + f0[k] * b * b * psi[k] * (1.0 / (1.0 - w) + (g[k] * psi[k]) * h)
            b = b * grow[k] / (1.0 - w)
            ok = ok and math.isfinite(a) and math.isfinite(b)
        a_out[i] = a
        b_out[i] = b
        ok_out[i] = ok


@njit(cache=True, nogil=True, error_model="numpy")
def _max0(x):  # pragma: no cover - numba
    """``np.maximum(x, 0.0)`` for one value (a NaN kept)."""
    return x if (x >= 0.0 or x != x) else 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def affine_envelope_rows(rows, probe, clamp, slopes, intercepts):  # pragma: no cover - numba
    """:func:`.engine._affine_envelope` of ``rows`` (of ``max(rows, 0)`` with ``clamp``) on ``probe``, written into
    ``slopes`` and ``intercepts``: each row's largest slope between probe points (at least 0; NaN where one is NaN,
    as numpy's ``max``) and the smallest intercept ``c >= 0`` with ``c + g p`` above the row at every point. The
    same operations as the numpy form (``(r[j+1] - r[j]) / (p[j+1] - p[j])``, ``r[j] - g p[j]``); the maxima are
    exact in any order."""
    n, m = rows.shape
    for k in range(n):
        best = -math.inf
        nan = False
        for j in range(m - 1):
            a, b = rows[k, j], rows[k, j + 1]
            if clamp:
                a, b = _max0(a), _max0(b)
            v = (b - a) / (probe[j + 1] - probe[j])
            if v != v:
                nan = True
            elif v > best:
                best = v
        g = _max0(math.nan if nan else best)
        best = -math.inf
        nan = False
        for j in range(m):
            r = _max0(rows[k, j]) if clamp else rows[k, j]
            v = r - g * probe[j]
            if v != v:
                nan = True
            elif v > best:
                best = v
        slopes[k] = g
        intercepts[k] = _max0(math.nan if nan else best)


@njit(cache=True, nogil=True, error_model="numpy")
def affine_moments(f_max, durations, g, c, p0):  # pragma: no cover - numba
    """``(ok, mean, var)`` of :func:`.engine._affine_envelope_bound`'s propagation through the stages in their order:
    ``M <- exp(g d) M + c expm1(g d)/g``, ``V <- exp(2 g d) V + F expm1(2 g d)/g`` (``M += c d``, ``V += 2 d F``
    where ``g = 0``); ``ok`` False where a stage's ``g d`` exceeds 350 (beyond double precision)."""
    mean, var = p0, 0.0
    for k in range(f_max.size):
        gk, ck, d = g[k], c[k], durations[k]
        if gk * d > 350.0:
            return False, mean, var
        if gk > 0.0:
            grow = math.exp(gk * d)
            mean = grow * mean + ck * math.expm1(gk * d) / gk
            var = grow * grow * var + f_max[k] * math.expm1(2.0 * gk * d) / gk
        else:
            mean += ck * d
            var += 2.0 * d * f_max[k]
    return True, mean, var


def envelope_types() -> tuple:
    """The signature :func:`affine_envelope_rows` is loaded for: a C-contiguous row block, the probe, the clamp and
    two output rows."""
    from numba import types as t

    f1 = t.float64[::1]
    return (t.float64[:, ::1], f1, t.boolean, f1, f1)


def moments_types() -> tuple:
    """The signature :func:`affine_moments` is loaded for: four rows and ``p0``."""
    from numba import types as t

    f1 = t.float64[::1]
    return (f1, f1, f1, f1, t.float64)


def chernoff_types() -> tuple:
    """The one argument signature :func:`_chernoff_rows` is loaded for: seven contiguous float rows in, two float
    rows and one boolean row out."""
    from numba import types as t

    f1 = t.float64[::1]
    return (f1, f1, f1, f1, f1, f1, f1, f1, f1, t.boolean[::1])


# cached loads skip numba's registry refresh (only a compile needs it): diffusion_pr._numba_load
from ..._numba_load import LoadedBySignature, load_without_refresh  # noqa: E402

load_without_refresh(globals())

#: the kernels loaded for their one signature on first use
chernoff_kernel = LoadedBySignature(_chernoff_rows, chernoff_types)
envelope_kernel = LoadedBySignature(affine_envelope_rows, envelope_types)
moments_kernel = LoadedBySignature(affine_moments, moments_types)
