"""Chebyshev rational approximation (CRAM) of order 16 of the matrix exponential.

``exp(t L) y`` for a tridiagonal ``L`` whose spectrum lies on (or near) the
negative real axis, in the incomplete partial factorization form of
M. Pusa, "Higher-order Chebyshev rational approximation method and
application to burnup equations", Nucl. Sci. Eng. 182, 297-318 (2016),
doi:10.13182/NSE15-26 (coefficients: Table II of that paper)::

    y <- y + 2 Re[ alpha_j (t L - theta_j I)^-1 y ],  j = 1..8;   y <- alpha_0 y

The uniform error on ``(-inf, 0]`` is about ``2e-16`` (the Halphen constant ``9.289^-16``); for a
diagonalizable ``L`` the error in ``y`` is at most that times the condition number of its eigenvectors.
"""
from __future__ import annotations

import functools

import numpy as np

__all__ = ["ALPHA", "THETA", "ALPHA0", "PFD_RESIDUES", "ERROR_BOUND", "expm_tridiagonal"]

ALPHA = np.array([
    +5.464930576870210e+3 - 3.797983575308356e+4j,
    +9.045112476907548e+1 - 1.115537522430261e+3j,
    +2.344818070467641e+2 - 4.228020157070496e+2j,
    +9.453304067358312e+1 - 2.951294291446048e+2j,
    +7.283792954673409e+2 - 1.205646080220011e+5j,
    +3.648229059594851e+1 - 1.155509621409682e+2j,
    +2.547321630156819e+1 - 2.639500283021502e+1j,
    +2.394538338734709e+1 - 5.650522971778156e+0j])
THETA = np.array([
    +3.509103608414918 + 8.436198985884374j,
    +5.948152268951177 + 3.587457362018322j,
    -5.264971343442647 + 16.22022147316793j,
    +1.419375897185666 + 10.92536348449672j,
    +6.416177699099435 + 1.194122393370139j,
    +4.993174737717997 + 5.996881713603942j,
    -1.413928462488886 + 13.49772569889275j,
    -10.84391707869699 + 19.27744616718165j])
ALPHA0 = 2.124853710495224e-16
#: uniform error of the approximation of exp on (-inf, 0] (dimensionless)
ERROR_BOUND = 3.2e-16


def _partial_fraction_residues() -> np.ndarray:
    """Residues ``c_j`` of the same rational function in partial fractions, ``r(z) = alpha0 + 2 Re sum_j c_j/(z -
    theta_j)``: ``c_j = alpha0 alpha_j prod_{k != j} [1 + alpha_k/(theta_j - theta_k) + conj(alpha_k)/(theta_j -
    conj(theta_k))]``."""
    out = np.empty(THETA.size, dtype=complex)
    for j, th in enumerate(THETA):
        others = [1.0 + a / (th - t) + np.conj(a) / (th - np.conj(t)) for k, (a, t) in enumerate(zip(ALPHA, THETA))
                  if k != j]
        out[j] = ALPHA0 * ALPHA[j] * np.prod(others)
    return out


#: partial-fraction residues: ``exp(t L) y = alpha0 y + 2 Re sum_j c_j (t L - theta_j)^-1 y`` (round-off about
#: 1e-13 of ``max |y|``, against 1e-15 for the IPF form: the residues reach 2e2)
PFD_RESIDUES = _partial_fraction_residues()


@functools.cache
def _gtsv():
    """LAPACK ``zgtsv`` (complex tridiagonal solve with partial pivoting) through SciPy's public API."""
    from scipy.linalg import get_lapack_funcs

    return get_lapack_funcs("gtsv", dtype=np.complex128)


def expm_tridiagonal(lower: np.ndarray, diag: np.ndarray, upper: np.ndarray, t: float, y: np.ndarray, *,
                     flux_form: bool = False) -> np.ndarray:
    """``exp(t L) y`` for the tridiagonal ``L = (lower, diag, upper)`` [1/time], ``t >= 0``: CRAM-16 in the IPF
    form, eight LAPACK ``zgtsv`` solves (round-off about 1e-15 of ``max |y|``).  With ``flux_form`` (``L``'s
    columns summing to 0) each factor is ``r y + t L w`` with ``t L w`` as differences of face fluxes, so ``sum y``
    is conserved to round-off even where ``|t L_ii|`` is huge (the face fluxes telescope).  Raises ``FloatingPointError``
    where a shifted system is singular.
    """
    y = np.array(y, dtype=float)
    if t == 0.0:
        return y
    tl = (t * lower).astype(np.complex128)
    tu = (t * upper).astype(np.complex128)
    td = (t * diag).astype(np.complex128)
    gtsv = _gtsv()
    for alpha, theta in zip(ALPHA, THETA):
        _, _, _, x, info = gtsv(tl.copy(), td - theta, tu.copy(), y.astype(np.complex128), 1, 1, 1, 1)
        if info != 0:
            raise FloatingPointError(f"CRAM: singular shifted tridiagonal system (LAPACK zgtsv info={info})")
        if flux_form:  # y + 2 Re(alpha x) = (1 - 2 Re(alpha/theta)) y + t L 2 Re(alpha x / theta)
            y = _flux_sum(lower, upper, t, y, 2.0 * (alpha / theta * x).real, 1.0 - 2.0 * (alpha / theta).real)
        else:
            y += 2.0 * (alpha * x).real
    return ALPHA0 * y


def _flux_sum(lower: np.ndarray, upper: np.ndarray, t: float, y: np.ndarray, w: np.ndarray, r: float) -> np.ndarray:
    """``r y + t L w`` for a probability-conserving tridiagonal ``L``, ``t L w`` as differences of the net fluxes
    ``t (lower_i w_i - upper_i w_{i+1})`` from state ``i`` to ``i + 1`` (the diagonal is not read)."""
    flux = t * (lower * w[:-1] - upper * w[1:])
    out = r * y
    out[:-1] -= flux
    out[1:] += flux
    return out
