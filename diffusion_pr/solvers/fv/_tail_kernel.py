"""The compiled Riccati recursion of the domain probe's Chernoff bound (:func:`.engine._affine_chernoff_bound`).

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


def chernoff_types() -> tuple:
    """The one argument signature :func:`_chernoff_rows` is loaded for: seven contiguous float rows in, two float
    rows and one boolean row out."""
    from numba import types as t

    f1 = t.float64[::1]
    return (f1, f1, f1, f1, f1, f1, f1, f1, f1, t.boolean[::1])


# cached loads skip numba's registry refresh (only a compile needs it): diffusion_pr._numba_load
from ..._numba_load import LoadedBySignature, load_without_refresh  # noqa: E402

load_without_refresh(globals())

#: :func:`_chernoff_rows` loaded for :func:`chernoff_types` on first use
chernoff_kernel = LoadedBySignature(_chernoff_rows, chernoff_types)
