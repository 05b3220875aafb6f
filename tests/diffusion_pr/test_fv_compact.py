"""The compact fourth-order scheme's parts (diffusion_pr.solvers.fv.compact) against oracles of their own.

Oracles: derivatives known in closed form (the pencil's order), ``scipy.linalg.expm`` of the dense ``P^-1 Q`` (the
compiled exponential and its derivative), and the heat kernel's closed-form CDF (the delta start's order on a
graded grid).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm as dense_expm
from scipy.special import ndtr

from diffusion_pr.solvers.fv.compact import (absorbing_bottom, corrected_delta_start, expm_pencil, hoc_bands,
                                           index_coordinate, mean_weights, run_stages, stage_rows, with_derivatives)


def _dense(bands: tuple) -> np.ndarray:
    lower, diag, upper = bands
    return np.diag(diag) + np.diag(lower, -1) + np.diag(upper, 1)


def _pencil_error(n: int) -> float:
    """``max |P^-1 Q u - (A u'' + B u')|`` for ``A = 1 + sin(x)/2``, ``B = 3 cos 2x``, ``u = sin 3x`` on ``[0, 2]``
    with ``n`` intervals (the end rows given the exact values)."""
    x = np.linspace(0.0, 2.0, n + 1)
    xi = x[1:-1]
    pb, qb = hoc_bands(x[1] - x[0], (1 + 0.5 * np.sin(xi), 0.5 * np.cos(xi), -0.5 * np.sin(xi)),
                       (3 * np.cos(2 * xi), -6 * np.sin(2 * xi), -12 * np.cos(2 * xi)))
    exact = (1 + 0.5 * np.sin(x)) * (-9 * np.sin(3 * x)) + 3 * np.cos(2 * x) * 3 * np.cos(3 * x)
    rhs = _dense(qb) @ np.sin(3 * x)
    rhs[0], rhs[-1] = exact[0], exact[-1]
    return float(np.max(np.abs(np.linalg.solve(_dense(pb), rhs) - exact)))


def test_hoc_bands_fourth_order():
    """The pencil's truncation error falls 16x per halving of ``h`` (measured 16.1-16.7: the leading term is
    ``h^4``, the next ``h^6``, so the ratio is 16 (1 + O(h^2)); [14, 19] allows that and fails a scheme of lower
    order: a wrong sign of ``beta`` or a missing ``A''`` in ``kappa`` gives 4-5)."""
    errors = [_pencil_error(n) for n in (20, 40, 80, 160)]
    ratios = [a / b for a, b in zip(errors, errors[1:])]
    assert all(14.0 <= r <= 19.0 for r in ratios), ratios
    assert errors[-1] < 1e-6


def _synthetic(n: int, a: float) -> tuple:
    """A pencil whose ``P`` depends strongly on ``a``: ``P = (0.1 + 0.2 a, 1 + 0.3 a, 0.1 + 0.1 a)``,
    ``Q = -(1 + a) K`` with ``K`` a stiffness of smooth positive ``k`` (``P^-1 Q`` has its spectrum near the
    negative real axis, where CRAM holds); its derivatives in ``a``."""
    k = 1.0 + 0.5 * np.sin(np.linspace(0.0, 3.0, n + 1))
    kd, ko = k[:-1] + k[1:], -k[1:-1]
    pb = (np.full(n - 1, 0.1 + 0.2 * a), np.full(n, 1.0 + 0.3 * a), np.full(n - 1, 0.1 + 0.1 * a))
    qb = (-(1 + a) * ko, -(1 + a) * kd, -(1 + a) * ko)
    return pb, qb, (np.full(n - 1, 0.2), np.full(n, 0.3), np.full(n - 1, 0.1)), (-ko, -kd, -ko)


def test_expm_pencil_against_dense_expm():
    """``exp(t P^-1 Q) y`` against ``scipy.linalg.expm`` (CRAM-16's error about 1e-14 on the negative axis:
    1e-12), its derivative in ``a`` against a central difference of the dense one (step 1e-3, error about 1e-7
    of the derivative's scale of 1: 1e-6); and a break of the derivative's ``P_a`` terms is seen (0.06-0.4)."""
    n, a, t = 30, 0.4, 0.7
    y = np.exp(-np.linspace(-2.0, 2.0, n) ** 2)
    pb, qb, pa, qa = _synthetic(n, a)

    def exact(at: float) -> np.ndarray:
        p2, q2, _, _ = _synthetic(n, at)
        return dense_expm(t * np.linalg.solve(_dense(p2), _dense(q2))) @ y

    x, dx = expm_pencil(pb, qb, t, y, derivative=(pa, qa))
    assert np.max(np.abs(x - exact(a))) < 1e-12
    fd = (exact(a + 1e-3) - exact(a - 1e-3)) / 2e-3
    assert np.max(np.abs(dx - fd)) < 1e-6
    _, dx_no_pa = expm_pencil(pb, qb, t, y, derivative=(tuple(np.zeros_like(v) for v in pa), qa))
    assert np.max(np.abs(dx_no_pa - fd)) > 1e-2
    x_plain, none = expm_pencil(pb, qb, t, y)
    assert none is None and np.array_equal(x_plain, x)
    x_zero, _ = expm_pencil(pb, qb, 0.0, y)  # r(0) = 1 to CRAM's accuracy
    assert np.max(np.abs(x_zero - y)) < 1e-13


def _heat_kernel_error(n: int, corrected: bool) -> float:
    """Max nodal error of ``M`` for ``Pr_tau = D Pr_pp`` from ``delta(p - p0)``: the compact scheme on a grid uniform
    in ``xi``, ``p = p0 + c sinh(xi)`` (graded, ``p0`` the middle node), one exponential to ``t``, against
    ``Phi((p - p0) / sqrt(2 D t))``. ``A = D / p_xi^2`` and ``B = -D p_xixi / p_xi^3`` and their derivatives in
    closed form."""
    D, c, L, p0, t = 1.0, 0.3, 3.0, 1.0, 0.02
    x = np.linspace(-L, L, n + 1)
    xi = x[1:-1]
    C, S = np.cosh(xi), np.sinh(xi)
    a = (D / (c * c * C * C), -2 * D * S / (c * c * C ** 3), -2 * D / (c * c) * (C * C - 3 * S * S) / C ** 4)
    b = (-D * S / (c * c * C ** 3), -D / (c * c) * (C * C - 3 * S * S) / C ** 4,
         4 * D * S * (2 * C * C - 3 * S * S) / (c * c * C ** 5))
    pb, qb = hoc_bands(x[1] - x[0], a, b)
    M0 = corrected_delta_start(n + 1, n // 2)
    if not corrected:
        M0[n // 2 - 1], M0[n // 2 + 1] = 0.0, 1.0
    M, _ = expm_pencil(pb, qb, t, M0)
    p = p0 + c * np.sinh(x)
    return float(np.max(np.abs(M - ndtr((p - p0) / math.sqrt(2 * D * t)))))


def test_corrected_delta_start_keeps_fourth_order():
    """From the corrected delta the heat kernel's CDF converges at fourth order on a graded grid (measured ratios
    16.00-16.04 on 40-320 intervals; [15, 17]); from the sampled step at second (3.91-3.99): the correction is
    what keeps the order (1/16 instead of 1/24 fails the first assertion)."""
    corrected = [_heat_kernel_error(n, True) for n in (40, 80, 160, 320)]
    sampled = [_heat_kernel_error(n, False) for n in (40, 80, 160)]
    assert all(15.0 <= a / b <= 17.0 for a, b in zip(corrected, corrected[1:])), corrected
    assert corrected[-1] < 1e-8
    assert all(3.5 <= a / b <= 4.5 for a, b in zip(sampled, sampled[1:])), sampled


def test_corrected_delta_start_values():
    """The start itself: the step, ``M(p0) = 1/2``, the neighbours out by 1/24; total probability 1 at the top."""
    M = corrected_delta_start(7, 3)
    assert np.allclose(M, [0.0, 0.0, -1 / 24, 0.5, 1 + 1 / 24, 1.0, 1.0], rtol=0, atol=1e-16)


@pytest.mark.parametrize("call, match", [
    (lambda: hoc_bands(0.0, (np.ones(3),) * 3, (np.zeros(3),) * 3), "h must be > 0"),
    (lambda: hoc_bands(0.1, (np.array([1.0, -1.0, 1.0]),) * 3, (np.zeros(3),) * 3), "A must be > 0"),
    (lambda: corrected_delta_start(4, 2), "n_nodes must be"),
    (lambda: corrected_delta_start(9, 1), r"j must be an integer in \[2, 6\]"),
    (lambda: corrected_delta_start(9, 7), r"j must be an integer in \[2, 6\]"),
    (lambda: expm_pencil(*_synthetic(5, 0.0)[:2], -1.0, np.ones(5)), "t must be finite and >= 0"),
    (lambda: expm_pencil(*_synthetic(5, 0.0)[:2], 1.0, np.ones(6)), "p_bands must be"),
    (lambda: expm_pencil(*_synthetic(5, 0.0)[:2], 1.0, np.ones(5), order=8), "order must be 10, 12 or 16"),
    (lambda: expm_pencil(*_synthetic(5, 0.0)[:2], 1.0, np.ones(5), q_row0=np.zeros(3)), "q_row0 must have 2"),
    (lambda: absorbing_bottom(0.0, 1.0), "h must be > 0"),
    (lambda: absorbing_bottom(0.1, -1.0), "a_bottom must be >= 0"),
    (lambda: index_coordinate(np.arange(4.0)), "at least 5 nodes"),
    (lambda: index_coordinate(np.array([0.0, 1.0, 3.0, 2.0, 4.0])), "p_nodes must be increasing"),
    (lambda: mean_weights(np.arange(3.0)), "at least 4 nodes"),
    (lambda: stage_rows(np.arange(1.0, 7.0), np.ones((2, 6)), np.zeros((2, 5)), np.zeros((2, 6)), np.zeros((2, 6))),
     "f, f_p, b and w must be"),
    (lambda: stage_rows(np.arange(1.0, 7.0), np.zeros((1, 6)), np.zeros((1, 6)), np.zeros((1, 6)), np.zeros((1, 6))),
     "f must be > 0"),
    (lambda: run_stages(stage_rows(np.arange(1.0, 8.0), *(np.ones((2, 7)),) * 4), np.array([0.1, -0.1]),
                        np.linspace(0, 1, 7), weights=np.ones(7), p0=1.0), "durations must be"),
    (lambda: run_stages(stage_rows(np.arange(1.0, 8.0), *(np.ones((2, 7)),) * 4), np.array([0.1, 0.1]),
                        np.linspace(0, 1, 7), weights=np.ones(7), p0=0.0), "p0 must be"),
])
def test_bad_input_raises_with_the_parameter(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def _absorbed_heat_kernel_error(n: int) -> float:
    """Max nodal error of ``M`` (``M_0`` the absorbed weight ``z``) for ``Pr_tau = D Pr_pp`` on ``p > 0`` with an
    absorbing wall at 0 (:func:`absorbing_bottom`), from ``delta(p - p0)``: against the method of images,
    ``M = 2 Phi(-p0/s) + [Phi((p - p0)/s) - Phi(-p0/s)] - [Phi((p + p0)/s) - Phi(p0/s)]``, ``s = sqrt(2 D t)``."""
    D, p0, t, top = 1.0, 0.3, 0.02, 2.0
    s = math.sqrt(2 * D * t)
    p = np.linspace(0.0, top, n + 1)
    h = p[1] - p[0]
    m = n - 1
    pb, qb = hoc_bands(h, (np.full(m, D), np.zeros(m), np.zeros(m)), (np.zeros(m),) * 3)
    q00, q01, row0 = absorbing_bottom(h, D)
    qb[1][0], qb[2][0] = q00, q01
    M, _ = expm_pencil(pb, qb, t, corrected_delta_start(n + 1, int(round(p0 / h))), q_row0=row0)
    exact = 2 * ndtr(-p0 / s) + (ndtr((p - p0) / s) - ndtr(-p0 / s)) - (ndtr((p + p0) / s) - ndtr(p0 / s))
    return float(np.max(np.abs(M - exact)))


def test_absorbing_bottom_fourth_order():
    """The absorbing bottom (a third-order one-sided row, the kernel's bordered first row) with the corrected delta
    start: the image solution's ``M`` and zero weight converge at nearly fourth order (measured ratios 15.1, 15.7,
    13.9 on 40-320 intervals; [12, 17]: a second-order bottom or a dropped border gives 4 or less)."""
    errors = [_absorbed_heat_kernel_error(n) for n in (40, 80, 160, 320)]
    assert all(12.0 <= a / b <= 17.0 for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 1e-8


def test_bordered_row_against_dense_expm():
    """The kernel's bordered first row (``q_row0``) and its derivative (``Q_a``'s ``q_row0``) against the dense
    exponential and its central difference (tolerances as in the tridiagonal test): the synthetic pencil with an
    absorbing bottom whose ``A`` is ``1 + a``."""
    n, a, t = 30, 0.4, 0.7
    y = np.exp(-np.linspace(-2.0, 2.0, n) ** 2)
    h = 0.1

    def parts(at: float) -> tuple:
        pb, qb, pa, qa = _synthetic(n, at)
        pb[1][0], pb[2][0], pa[1][0], pa[2][0] = 1.0, 0.0, 0.0, 0.0
        q00, q01, row0 = absorbing_bottom(h, 1.0 + at)
        qb[1][0], qb[2][0] = q00, q01
        d00, d01, drow0 = absorbing_bottom(h, 1.0)  # d/da of a row linear in A
        qa[1][0], qa[2][0] = d00, d01
        return pb, qb, row0, pa, qa, drow0

    def exact(at: float) -> np.ndarray:
        pb, qb, row0, _, _, _ = parts(at)
        Q = _dense(qb)
        Q[0, 2:4] = row0
        return dense_expm(t * np.linalg.solve(_dense(pb), Q)) @ y

    pb, qb, row0, pa, qa, drow0 = parts(a)
    x, dx = expm_pencil(pb, qb, t, y, q_row0=row0, derivative=(pa, qa, drow0))
    assert np.max(np.abs(x - exact(a))) < 1e-12
    fd = (exact(a + 1e-3) - exact(a - 1e-3)) / 2e-3
    assert np.max(np.abs(dx - fd)) < 1e-6
    x_unbordered, _ = expm_pencil(pb, qb, t, y)
    assert np.max(np.abs(x_unbordered - x)) > 1e-3


def test_index_coordinate_exact_for_quartics():
    """Five-point differences, one-sided at the ends, are exact for quartics in the index (round-off: 1e-10 of
    derivatives of size 1e2-1e3)."""
    k = np.arange(12.0)
    p = 1.0 + 2.0 * k + 0.3 * k ** 2 + 0.02 * k ** 3 + 0.001 * k ** 4
    d1, d2 = index_coordinate(p)
    assert np.allclose(d1, 2.0 + 0.6 * k + 0.06 * k ** 2 + 0.004 * k ** 3, rtol=1e-12, atol=1e-10)
    assert np.allclose(d2, 0.6 + 0.12 * k + 0.012 * k ** 2, rtol=1e-12, atol=1e-10)


def _heat_kernel_from_nodes(n: int) -> float:
    """:func:`_heat_kernel_error`'s problem with the coefficients from the nodes alone (``index_coordinate``,
    ``with_derivatives``; the node index as the coordinate, ``h = 1``)."""
    D, c, L, p0, t = 1.0, 0.3, 3.0, 1.0, 0.02
    p = p0 + c * np.sinh(np.linspace(-L, L, n + 1))
    p_xi, p_xixi = index_coordinate(p)
    pb, qb = hoc_bands(1.0, with_derivatives(D / p_xi ** 2), with_derivatives(-D * p_xixi / p_xi ** 3))
    M, _ = expm_pencil(pb, qb, t, corrected_delta_start(n + 1, n // 2))
    return float(np.max(np.abs(M - ndtr((p - p0) / math.sqrt(2 * D * t)))))


def test_coefficients_from_the_nodes_keep_fourth_order():
    """The pencil's coefficients from the grid's nodes alone (second-order derivatives of ``A`` and ``B``): the
    heat kernel still converges at fourth order (measured 15.6-16.0 per halving; [15, 17]) and within 20 % of the
    closed-form coefficients' error."""
    errors = [_heat_kernel_from_nodes(n) for n in (40, 80, 160, 320)]
    assert all(15.0 <= a / b <= 17.0 for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 1.2 * _heat_kernel_error(320, True)


def test_mean_weights_exact_for_cubics():
    """The mean's weights integrate a cubic ``M`` exactly on a graded grid (``ww . M = p_n M_n - p_0 M_0 - int M``;
    round-off 1e-13 of values of order 1e2)."""
    p = 0.2 + np.sinh(np.linspace(0.0, 2.5, 23))
    M = 0.3 + 0.5 * p - 0.2 * p ** 2 + 0.01 * p ** 3
    integral = lambda x: 0.3 * x + 0.25 * x ** 2 - 0.2 / 3 * x ** 3 + 0.0025 * x ** 4  # noqa: E731
    exact = p[-1] * M[-1] - p[0] * M[0] - (integral(p[-1]) - integral(p[0]))
    assert abs(mean_weights(p) @ M - exact) < 1e-11


def _ou_error(n: int) -> tuple:
    """A balanced Ornstein-Uhlenbeck problem through :func:`run_stages`: ``f = D``, ``b = -k p``, ``w = -1``, so the
    drift ``-k p + A`` keeps the mean at ``p0`` with ``A = k p0`` exactly, and from ``delta(p - p0)`` the
    distribution is Gaussian, variance ``D/k (1 - exp(-2 k t))``. 8 stages, graded grid ``p0 + c sinh(xi)`` closed
    at both ends 15 spreads away. Returns the max nodal error of ``M`` and the multipliers' largest relative error."""
    D, k, p0, L, c, T, stages = 1.0, 2.0, 1.0, 4.0, 0.35, 0.4, 8
    p = p0 + c * np.sinh(np.linspace(-L, L, n + 1))
    ones = np.ones((stages, n + 1))
    rows = stage_rows(p, D * ones, 0.0 * ones, -k * p * ones, -ones)
    M, A, _ = run_stages(rows, np.full(stages, T / stages), corrected_delta_start(n + 1, n // 2),
                         weights=mean_weights(p), p0=p0, absorbing=False, mean_tol=1e-13)
    s = math.sqrt(D / k * (1 - math.exp(-2 * k * T)))
    return float(np.max(np.abs(M - ndtr((p - p0) / s)))), float(np.max(np.abs(A / (k * p0) - 1.0)))


def test_run_stages_balanced_fourth_order():
    """Every stage with its balance in one compiled call: the balanced OU problem converges at fourth order
    (measured 15.9-16.2 per halving; [14.5, 17.5]) and finds ``A = k p0`` (measured to 1e-12; 1e-9: the balance's
    tolerance of 1e-13 p0 over a slope of order 1)."""
    results = [_ou_error(n) for n in (40, 80, 160, 320)]
    errors = [e for e, _ in results]
    assert all(14.5 <= a / b <= 17.5 for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 5e-8
    assert max(da for _, da in results) < 1e-9


def test_run_stages_reports_a_failed_balance():
    """A balance that cannot act (``w = 0``: the mean does not respond to ``A``) raises with the stage, never
    returns a half-result."""
    n = 40
    p = 1.0 + 0.35 * np.sinh(np.linspace(-4.0, 4.0, n + 1))
    ones = np.ones((3, n + 1))
    rows = stage_rows(p, ones, 0.0 * ones, -2.0 * p * ones, 0.0 * ones)
    with pytest.raises(RuntimeError, match="stage 0 failed .the balance did not converge"):
        run_stages(rows, np.full(3, 0.05), corrected_delta_start(n + 1, n // 2), weights=mean_weights(p),
                   p0=1.2, absorbing=False)
