"""Chebyshev rational approximation (CRAM) of the matrix exponential: order 16, and CF orders 10 and 12.

``exp(t L) y`` for a tridiagonal ``L`` whose spectrum lies on (or near) the
negative real axis, in the incomplete partial factorization form of
M. Pusa, "Higher-order Chebyshev rational approximation method and
application to burnup equations", Nucl. Sci. Eng. 182, 297-318 (2016),
doi:10.13182/NSE15-26 (coefficients: Table II of that paper)::

    y <- y + 2 Re[ alpha_j (t L - theta_j I)^-1 y ],  j = 1..8;   y <- alpha_0 y

Eight complex tridiagonal solves (LAPACK ``zgtsv``, partial pivoting).  The
uniform error of the order-16 Chebyshev rational approximation of ``exp(x)``
on ``(-inf, 0]`` is about ``2e-16`` (Carpenter, Ruttan, Varga 1984: the
Halphen constant ``9.289^-16``); for a diagonalizable ``L`` the error in ``y``
is at most that times the condition number of ``L``'s eigenvector matrix
(bounded here by the diagonal similarity of the finite-volume operator).
"""
from __future__ import annotations

import importlib.util
import os
import sys

from typing import Sequence

import numpy as np

from ..._extensions import extension_file, load_extension

__all__ = ["ALPHA", "THETA", "ALPHA0", "PFD_RESIDUES", "ERROR_BOUND", "PFD_ERROR_BOUNDS", "pfd_coefficients",
           "cf_coefficients", "expm_tridiagonal", "CANCELLED"]

#: ``info`` of the compiled stage loops (:func:`._kernels.staged_run`, :func:`._kernels.staged_run_rows`) when their
#: ``cancel`` flag was set before a stage: ``y`` is the state before that stage (a speculative integration another
#: thread no longer needs; engine.plain_batch_ahead). Here, in a module without numba, so that the engine reads it
#: without importing the kernels.
CANCELLED = -2

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
    """Residues ``c_j`` of the same rational function in partial fractions (double precision, ~2e-15 relative).

    The IPF product is ``r(z) = alpha0 prod_k [1 + alpha_k/(z - theta_k) + conj(alpha_k)/(z - conj(theta_k))]``
    for real ``z``; its residue at ``theta_j`` is
    ``c_j = alpha0 alpha_j prod_{k != j} [1 + alpha_k/(theta_j - theta_k) + conj(alpha_k)/(theta_j - conj(theta_k))]``,
    so ``r(z) = alpha0 + 2 Re sum_j c_j/(z - theta_j)``.
    """
    out = np.empty(THETA.size, dtype=complex)
    for j, th in enumerate(THETA):
        others = [1.0 + a / (th - t) + np.conj(a) / (th - np.conj(t)) for k, (a, t) in enumerate(zip(ALPHA, THETA))
                  if k != j]
        out[j] = ALPHA0 * ALPHA[j] * np.prod(others)
    return out


#: partial-fraction residues of the same approximation: ``exp(t L) y = alpha0 y + 2 Re sum_j c_j (t L - theta_j)^-1 y``
#: (independent solves, all poles at once in :func:`._kernels.cram_pfd`; round-off about 1e-13 of ``max |y|``
#: against 1e-15 for the IPF form, since the residues reach 2e2)
PFD_RESIDUES = _partial_fraction_residues()


# Lower orders for looser tolerances: the Caratheodory-Fejer (CF) approximations of type (n, n) to exp on
# (-inf, 0] of L. N. Trefethen, J. A. C. Weideman and T. Schmelzer, "Talbot quadratures and rational
# approximations", BIT 46, 653-670 (2006), doi:10.1007/s10543-006-0077-9 (their Fig. 4.1; computed by
# :func:`cf_coefficients`, stored here so that importing costs nothing): near-best, the uniform errors measured
# on 40000 points of [-1e6, 0] are 1.36e-10 (n = 10) and 1.63e-12 (n = 12), the best approximations' 1.4e-10 and
# 1.6e-12 (Carpenter, Ruttan, Varga 1984).  Partial fractions only: ``r(x) = r_inf + 2 Re sum_j c_j/(x - theta_j)``
# over the poles in the upper half plane.

#: CF-10 poles (upper half plane)
CF10_THETA = np.array([
    -5.161191251645943 + 11.375156254838243j,
    -0.8944046821711842 + 8.582756902505864j,
    1.7154060337877302 + 6.038934929043315j,
    3.28375290009884 + 3.5943867748123672j,
    4.0277324837297535 + 1.1938560673334335j,
])
#: CF-10 residues
CF10_RESIDUES = np.array([
    -0.005784903977335338 + 0.0006858507045167331j,
    0.2725869854616625 + 0.014211728317987423j,
    -2.5655849971270768 - 1.2163857358593981j,
    7.117165209500308 + 8.819533323105892j,
    -4.818382059006333 - 21.05459759714486j,
])
#: CF-10 value at -infinity
CF10_R_INF = 1.361007417877147e-10

#: CF-12 poles (upper half plane)
CF12_THETA = np.array([
    -6.998687356007474 + 13.995916098133264j,
    -2.2359676498900862 + 11.109295737044016j,
    0.8517077579997216 + 8.503832410627936j,
    2.9178692532263377 + 6.017345628905333j,
    4.206124927739715 + 3.5909205906680715j,
    4.827494174587326 + 1.1939879377093998j,
])
#: CF-12 residues
CF12_RESIDUES = np.array([
    0.0008184336485926534 - 0.0005813543348441404j,
    -0.06857151701061659 + 0.03841913873466452j,
    1.3194123250131524 - 0.18352420676420697j,
    -8.2382622513838 - 2.796190995628886j,
    18.785993226847545 + 20.2372960743366j,
    -11.799390212515666 - 46.41166620881087j,
])
#: CF-12 value at -infinity
CF12_R_INF = 1.5925039065223245e-12


#: uniform error on (-inf, 0] of each order's partial fractions (dimensionless; CF-10 and CF-12 measured
#: 1.36e-10 and 1.63e-12, rounded up)
PFD_ERROR_BOUNDS = {10: 1.4e-10, 12: 1.7e-12, 16: ERROR_BOUND}


def pfd_coefficients(order: int) -> tuple:
    """``(theta, residues, r_inf, error_bound)`` of the order-``order`` approximation in partial fractions.

    ``exp(t L) y ~ r_inf y + 2 Re sum_j c_j (t L - theta_j)^-1 y``; ``order`` 16 is
    CRAM-16 (Pusa's coefficients), 10 and 12 the CF approximations above.
    """
    if order == 16:
        return THETA, PFD_RESIDUES, ALPHA0, ERROR_BOUND
    if order == 12:
        return CF12_THETA, CF12_RESIDUES, CF12_R_INF, PFD_ERROR_BOUNDS[12]
    if order == 10:
        return CF10_THETA, CF10_RESIDUES, CF10_R_INF, PFD_ERROR_BOUNDS[10]
    raise ValueError(f"order must be 10, 12 or 16; got order={order!r}")


def cf_coefficients(order: int, *, n_cheb: int = 75, n_fft: int = 1024, scale: float = 9.0) -> tuple:
    """The CF approximation of type ``(order, order)`` to ``exp`` on ``(-inf, 0]`` (even ``order`` <= 14).

    Trefethen, Weideman and Schmelzer (2006), Fig. 4.1, in numpy: ``exp`` is
    mapped to ``[-1, 1]`` by ``x = scale (t - 1)/(t + 1)``, its ``n_cheb``
    Chebyshev coefficients give a Hankel matrix whose singular vector
    ``order`` gives the poles; the residues follow from the numerator's
    Laurent coefficients.  Returns ``(theta, residues, r_inf)`` with the poles in
    the upper half plane, sorted by real part (the stored CF10_*/CF12_* constants
    are this function's output; double precision limits the method to
    ``order <= 14``).
    """
    if order % 2 or not 2 <= order <= 14:
        raise ValueError(f"order must be even and in [2, 14]; got order={order!r}")
    w = np.exp(2j * np.pi * np.arange(n_fft) / n_fft)  # roots of unity
    t = w.real  # Chebyshev points (twice over)
    with np.errstate(divide="ignore", over="ignore"):
        f_map = np.exp(scale * (t - 1.0) / (t + 1.0 + 1e-16))  # exp transplanted to [-1, 1]
    cheb = np.real(np.fft.fft(f_map)) / n_fft
    analytic = np.polyval(cheb[n_cheb::-1], w)
    ij = np.add.outer(np.arange(n_cheb), np.arange(n_cheb))
    hankel = np.where(ij < n_cheb, cheb[np.minimum(1 + ij, n_cheb)], 0.0)
    u_mat, sv, vh = np.linalg.svd(hankel)
    sigma, u, v = sv[order], u_mat[n_cheb - 1::-1, order], vh[order, :]
    pad = np.zeros(n_fft - n_cheb)
    blaschke = np.fft.fft(np.r_[u, pad]) / np.fft.fft(np.r_[v, pad])
    r_tilde = analytic - sigma * w**n_cheb * blaschke
    roots = np.roots(v)
    qk = roots[np.abs(roots) > 1.0]
    numer = np.real(np.fft.fft(r_tilde * np.polyval(np.poly(qk), w)) / n_fft)[order::-1]
    ck = np.array([np.polyval(numer, q) / np.polyval(np.poly(np.delete(qk, k)), q) for k, q in enumerate(qk)])
    zk = scale * (qk - 1.0) ** 2 / (qk + 1.0) ** 2  # poles in the x plane
    ck = 4.0 * ck * zk / (qk**2 - 1.0)  # residues in the x plane
    r_inf = float(np.real(0.5 * (1.0 + np.sum(ck / zk))))
    upper = zk.imag > 0.0
    order_ = np.argsort(zk[upper].real)
    return zk[upper][order_], ck[upper][order_], r_inf



def _zgtsv():
    """LAPACK ``zgtsv`` from scipy's compiled LAPACK module, without importing ``scipy.linalg``.

    ``import scipy.linalg`` costs about 0.2 s (its package imports ``numpy.f2py``
    and the array-API layer), most of the first solve in a fresh process; the
    f2py extension ``scipy/linalg/_flapack`` itself loads in about 10 ms.  It is
    loaded from its file under its own name (so a later ``import scipy.linalg``
    reuses it); if that fails for any reason, the documented
    ``scipy.linalg.get_lapack_funcs`` is used.
    """
    if "scipy.linalg" not in sys.modules:
        try:
            flapack = sys.modules.get("scipy.linalg._flapack")
            if flapack is None:
                spec = importlib.util.find_spec("scipy")
                path = extension_file(os.path.join(spec.submodule_search_locations[0], "linalg"), "_flapack*")
                flapack = load_extension("scipy.linalg._flapack", path)
                sys.modules["scipy.linalg._flapack"] = flapack
            return flapack.zgtsv
        except Exception:  # pragma: no cover - an unusual scipy layout: the public route
            pass
    from scipy.linalg import get_lapack_funcs

    return get_lapack_funcs("gtsv", dtype=np.complex128)


def _gtsv():
    """LAPACK's ``zgtsv`` (:func:`_zgtsv`), loaded on first use: the closures' staged solves never call it (their
    kernels are compiled), and loading ``_flapack`` is 10 ms of a fresh process's first closure solve."""
    gtsv = globals().get("_GTSV")
    if gtsv is None:
        gtsv = globals()["_GTSV"] = _zgtsv()
    return gtsv


def __getattr__(name: str):
    if name == "_GTSV":  # the module attribute, loaded on first access
        return _gtsv()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def expm_tridiagonal(lower: np.ndarray, diag: np.ndarray, upper: np.ndarray, t: float, y: np.ndarray,
                     order: int = 16, *, flux_form: bool = False) -> np.ndarray:
    """``exp(t L) y`` for the tridiagonal ``L = (lower, diag, upper)``: CRAM-16 in the IPF form, or (``order`` 10
    or 12) the CF approximation in partial fractions (5 or 6 solves instead of 8; see :func:`pfd_coefficients`).

    With ``flux_form`` (``L`` must conserve probability, its columns summing to 0) each partial-fraction sum, or
    each factor of the IPF form, is written as ``r y + t L w`` with ``t L w`` as differences of face fluxes, so that
    ``sum y`` is conserved to round-off even where ``|t L_ii|`` is huge in cells that hold probability: the compiled
    kernels' form (:func:`~diffusion_pr.solvers.fv._kernels._flux_form`, docs/backends.md "Probability conserved in
    stiff cells").  The diagonal then only enters the shifted solves.  In flux form with ``order`` 10 or 12 this is
    :func:`expm_tridiagonal_many` on one grid (all poles in one LAPACK call).

    Parameters
    ----------
    lower, upper : ndarray, shape (n-1,)
        Sub- and super-diagonal of ``L``.
    diag : ndarray, shape (n,)
        Diagonal of ``L``.
    t : float
        Time (the units of ``1/L``), >= 0.
    y : ndarray, shape (n,)
        Start vector.

    Raises
    ------
    FloatingPointError
        When a shifted system is singular (LAPACK ``info > 0``).
    """
    if order != 16 and flux_form:
        return expm_tridiagonal_many([(lower, diag, upper)], t, [y], order)[0]
    y = np.array(y, dtype=float)
    if t == 0.0:
        return y
    tl = (t * lower).astype(np.complex128)
    tu = (t * upper).astype(np.complex128)
    td = (t * diag).astype(np.complex128)
    gtsv = _gtsv()
    if order != 16:
        thetas, residues, r_inf, _ = pfd_coefficients(order)
        zero = np.zeros(1, dtype=np.complex128)
        x = _shifted_solves(np.concatenate((tl, zero)), td, np.concatenate((tu, zero)), y, thetas, order, [y.size])
        # 2 Re sum_j c_j x_j (the rows added in order, from 0, as a loop of += adds them: numpy reduces over the
        # first axis of a C-ordered array row by row)
        return r_inf * y + np.add.reduce(2.0 * (residues[:, None] * x).real, axis=0)
    for alpha, theta in zip(ALPHA, THETA):
        _, _, _, x, info = gtsv(tl.copy(), td - theta, tu.copy(), y.astype(np.complex128), 1, 1, 1, 1)
        if info != 0:
            raise FloatingPointError(f"CRAM: singular shifted tridiagonal system (LAPACK zgtsv info={info})")
        if flux_form:  # y + 2 Re(alpha x) = (1 - 2 Re(alpha/theta)) y + t L 2 Re(alpha x / theta)
            y = _flux_sum(lower, upper, t, y, 2.0 * (alpha / theta * x).real, 1.0 - 2.0 * (alpha / theta).real)
        else:
            y += 2.0 * (alpha * x).real
    return ALPHA0 * y


def expm_tridiagonal_many(systems: Sequence[tuple], t: float, ys: Sequence[np.ndarray], order: int) -> list:
    """``exp(t L_g) y_g`` for several probability-conserving tridiagonal ``L_g = (lower, diag, upper)`` at once:
    :func:`expm_tridiagonal` with ``flux_form`` and the CF approximation of ``order`` (10 or 12) in partial
    fractions, every grid's and every pole's shifted system stacked into one LAPACK ``zgtsv`` call (zero couplings
    between the blocks: each block's solution has the bits of its own solve, :func:`_shifted_solves`).  The
    answers are :func:`expm_tridiagonal`'s, bit for bit; one call instead of one per grid saves its fixed costs
    (a level's three grids).

    Raises
    ------
    FloatingPointError
        When a shifted system is singular (LAPACK ``info > 0``), naming the grid, the pole and the row.
    """
    ys = [np.array(y, dtype=float) for y in ys]
    if t == 0.0:
        return ys
    thetas, residues, r_inf, _ = pfd_coefficients(order)
    sizes = [y.size for y in ys]
    total = sum(sizes)
    # the grids' bands and states one after another; a grid's last state is coupled to nothing (zero bands there)
    lower_row = np.zeros(total)
    upper_row = np.zeros(total)
    diag_row = np.empty(total)
    y_row = np.empty(total)
    off = 0
    for (lower, diag, upper), y, n in zip(systems, ys, sizes):
        lower_row[off:off + n - 1] = lower
        upper_row[off:off + n - 1] = upper
        diag_row[off:off + n] = diag
        y_row[off:off + n] = y
        off += n
    x = _shifted_solves(t * lower_row, t * diag_row, t * upper_row, y_row, thetas, order, sizes)
    # in flux form w = 2 Re sum_j (c_j/theta_j) x_j, the rows added in order, from 0, as a loop of += adds them
    # (numpy reduces over the first axis of a C-ordered array row by row); then r y + t L w as flux differences
    # (:func:`_flux_sum`), the zero bands between grids carrying no flux
    w = np.add.reduce(2.0 * ((residues / thetas)[:, None] * x).real, axis=0)
    out = _flux_sum(lower_row[:-1], upper_row[:-1], t, y_row, w, r_inf - 2.0 * float(np.sum((residues / thetas).real)))
    ends = np.cumsum(sizes).tolist()
    return [out[a:b].copy() for a, b in zip([0, *ends[:-1]], ends)]  # (each grid its own array)


def _shifted_solves(dl_row: np.ndarray, d_row: np.ndarray, du_row: np.ndarray, y_row: np.ndarray, thetas: np.ndarray,
                    order: int, sizes: Sequence[int]) -> np.ndarray:
    """``x_j = (t L - theta_j)^-1 y`` for every pole ``theta_j``, as the rows of a ``(poles, n)`` array, for grids laid
    end to end (``sizes`` their states): ``dl_row``, ``du_row`` the sub- and super-diagonal of ``t L`` with a zero at
    each grid's last state, ``d_row`` its diagonal.

    One LAPACK ``zgtsv`` call solves all of them: the shifted systems stacked on one diagonal, with zero couplings
    between the blocks.  Where a sub-diagonal entry is zero ``zgtsv`` neither eliminates nor interchanges rows, and
    the back substitution subtracts exact zeros, so every block's solution has the bits of its own solve (checked
    against separate solves in the tests); one call instead of one per pole and grid saves their fixed costs.

    Raises
    ------
    FloatingPointError
        When a shifted system is singular (LAPACK ``info > 0``), naming the pole, the row and (of several grids)
        the grid.
    """
    m, n = thetas.size, y_row.size
    dl = np.empty((m, n), dtype=np.complex128)
    dl[:] = dl_row
    du = np.empty((m, n), dtype=np.complex128)
    du[:] = du_row
    d = d_row[None, :] - thetas[:, None]
    b = np.empty((m, n), dtype=np.complex128)
    b[:] = y_row
    _, _, _, x, info = _gtsv()(dl.ravel()[:-1], d.ravel(), du.ravel()[:-1], b.ravel(), 1, 1, 1, 1)
    if info != 0:
        pole, row = divmod(int(info) - 1, n)
        grid = int(np.searchsorted(np.cumsum(sizes), row, side="right"))
        where = f"grid {grid}, " if len(sizes) > 1 else ""
        raise FloatingPointError(f"CF-{order}: singular shifted tridiagonal system (LAPACK zgtsv info={info}: {where}"
                                 f"pole {pole}, row {row - sum(sizes[:grid]) + 1})")
    return x.reshape(m, n)


def _flux_sum(lower: np.ndarray, upper: np.ndarray, t: float, y: np.ndarray, w: np.ndarray, r: float) -> np.ndarray:
    """``r y + t L w`` for a probability-conserving tridiagonal ``L``, ``t L w`` as differences of the net fluxes
    ``t (lower_i w_i - upper_i w_{i+1})`` from state ``i`` to ``i + 1`` (the diagonal is not read)."""
    flux = t * (lower * w[:-1] - upper * w[1:])
    out = r * y
    out[:-1] -= flux
    out[1:] += flux
    return out
