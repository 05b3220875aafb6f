"""Pressure factors: measured continuity order of each cutoff, tails, factories.

The continuity order is measured, not read from the ``continuity`` attribute:
on each side of a switch point ``b`` (0 and ``p_c``) a quartic is fitted to
samples at ``b -/+ (1..8) delta`` and its value and first three derivatives
are extrapolated to ``b``.  A jump larger than 1e-3 of the derivative's scale
(``p_c^-k``) counts as a discontinuity; smooth sides agree to ~1e-6 of it.
"""
from __future__ import annotations

import numpy as np
import pytest

from diffusion_pr.models import (
    GaussianTail,
    LinearTail,
    MaxLinearTail,
    MuserCutoff,
    PressureFactor,
    ProportionalDiffusivity,
    RaisedCosineCutoff,
    SharpCutoff,
    SmoothstepCutoff,
    make_cutoff,
    make_tail,
)

P_C = 0.37


def one_sided_derivatives(fun, b: float, side: int, delta: float) -> np.ndarray:
    """Value and derivatives 1..3 of ``fun`` at ``b`` from one side (+1 right, -1 left)."""
    t = side * delta * np.arange(1, 9)
    coef = np.polyfit(t / delta, fun(b + t), 4)  # polynomial in the scaled offset
    poly = np.poly1d(coef)
    return np.array([poly.deriv(k)(0.0) / delta**k if k else poly(0.0) for k in range(4)])


def jumps(fun, b: float) -> np.ndarray:
    """|right - left| of value, c', c'', c''' at ``b``, scaled by ``p_c^k``."""
    delta = 1e-3 * P_C
    left = one_sided_derivatives(fun, b, -1, delta)
    right = one_sided_derivatives(fun, b, +1, delta)
    return np.abs(right - left) * P_C ** np.arange(4)


def measured_continuity(fun) -> int:
    """Highest k such that c, ..., c^(k) are continuous at 0 and at p_c (-1: c itself jumps)."""
    worst = np.maximum(jumps(fun, 0.0), jumps(fun, P_C))
    for k in range(4):
        if worst[k] > 1e-3:
            return k - 1
    return 3


@pytest.mark.parametrize(
    "cutoff, expected",
    [
        (MuserCutoff(P_C), -1),  # the seed's printed factor jumps from 2 to 1 at p_c
        (RaisedCosineCutoff(P_C), 1),  # c'' jumps by pi^2/(2 p_c^2) at both ends
        (SmoothstepCutoff(P_C), 2),  # c''' jumps (60/p_c^3 at 0)
    ],
)
def test_cutoff_continuity_order_is_measured(cutoff, expected):
    # the oracle is the finite-difference fit above, independent of the attribute
    assert measured_continuity(cutoff) == expected
    assert cutoff.continuity == expected


def test_muser_cutoff_jump_size_and_smooth_start():
    j0 = jumps(MuserCutoff(P_C), 0.0)
    jc = jumps(MuserCutoff(P_C), P_C)
    # at 0: c = 0 on both sides and c' = 0 (1 - cos starts quadratically), c'' jumps by pi^2
    assert j0[0] < 1e-9 and j0[1] < 1e-6
    assert j0[2] == pytest.approx(np.pi**2, rel=1e-4)
    # at p_c: 2 below, 1 above -> jump of exactly 1
    assert jc[0] == pytest.approx(1.0, abs=1e-6)


def test_cosine_cutoffs_have_no_cancellation_at_tiny_pressure():
    # 1 - cos(x) underflows to 0 in double precision for x < ~1e-8; the series is the oracle
    p = np.array([1e-12, 1e-9, 1e-6]) * P_C
    x = np.pi * p / P_C
    np.testing.assert_allclose(MuserCutoff(P_C)(p), x**2 / 2, rtol=1e-10)
    np.testing.assert_allclose(RaisedCosineCutoff(P_C)(p), x**2 / 4, rtol=1e-10)


def test_cutoff_limits_and_sharp():
    p = np.array([-1.0, 0.0, P_C, 2 * P_C])
    np.testing.assert_array_equal(SharpCutoff()(p), [0, 0, 1, 1])
    for c in (RaisedCosineCutoff(P_C), SmoothstepCutoff(P_C)):
        np.testing.assert_allclose(c(p), [0, 0, 1, 1], atol=1e-15)
    np.testing.assert_allclose(MuserCutoff(P_C)(p), [0, 0, 1, 1], atol=1e-15)
    assert MuserCutoff(P_C)(np.array([P_C * (1 - 1e-9)]))[0] == pytest.approx(2.0)


def test_tails_and_products():
    p = np.array([0.0, 0.5, 2.0])
    np.testing.assert_allclose(GaussianTail()(p), 1.0)
    np.testing.assert_allclose(LinearTail(1.0)(p), [1.0, 1.5, 3.0])
    np.testing.assert_allclose(MaxLinearTail(1.0)(p), [1.0, 1.0, 2.0])
    f = PressureFactor(SmoothstepCutoff(1.0), LinearTail(1.0))
    np.testing.assert_allclose(f(p), SmoothstepCutoff(1.0)(p) * LinearTail(1.0)(p))
    prop = ProportionalDiffusivity(4.0)
    np.testing.assert_allclose(prop(np.array([-1.0, 2.0, 8.0])), [0.0, 0.5, 2.0])
    assert prop.slope == 0.25 and prop.zero_power == 1.0


def test_pressure_factor_without_a_tail_is_the_gaussian_tail_and_rejects_non_callables():
    # tail=None means t = 1 (as make_tail(None)); a part that is not callable is refused at construction, naming it,
    # instead of a TypeError deep inside a solve
    f = PressureFactor(SmoothstepCutoff(1.0))
    p = np.array([0.0, 0.5, 2.0])
    np.testing.assert_array_equal(f(p), SmoothstepCutoff(1.0)(p))
    assert isinstance(f.tail, GaussianTail) and f.zero_power == SmoothstepCutoff(1.0).zero_power
    with pytest.raises(ValueError, match="PressureFactor.cutoff must be a vectorized callable"):
        PressureFactor("muser")
    with pytest.raises(ValueError, match="PressureFactor.tail must be a vectorized callable"):
        PressureFactor(SmoothstepCutoff(1.0), 2.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf])
def test_bad_cutoff_pressures(bad):
    for cls in (MuserCutoff, RaisedCosineCutoff, SmoothstepCutoff):
        with pytest.raises(ValueError, match="p_c"):
            cls(bad)
    with pytest.raises(ValueError, match="p_c"):
        make_cutoff("smoothstep", bad)
    with pytest.raises(ValueError, match="p_1"):
        ProportionalDiffusivity(bad)


def test_factories():
    assert isinstance(make_cutoff(None), SharpCutoff)
    assert isinstance(make_cutoff("seed", 1.0), MuserCutoff)
    assert isinstance(make_tail("max_linear", 2.0), MaxLinearTail)
    with pytest.raises(ValueError, match="cutoff"):
        make_cutoff("bogus", 1.0)
    with pytest.raises(ValueError, match="p_c"):
        make_cutoff("muser")
    with pytest.raises(ValueError, match="callable"):
        make_cutoff(3.0)
    with pytest.raises(ValueError, match="p_t"):
        make_tail("linear")


# ---------------------------------------------------------------- model protocol
from diffusion_pr.models import (MaxLinearTail as _MLT, PressureFactor as _PF, breakpoints_of, wall_reached,
                                 zero_power_of)


@pytest.mark.parametrize("fun, k", [
    (lambda p: np.ones_like(p), 0.0),
    (lambda p: p / 3.0, 1.0),
    (lambda p: np.where(p < 0.0027, 1 - np.cos(np.pi * p / 0.0027), 1.0), 2.0),  # underflows to 0 near p = 0
    (lambda p: np.where(p < 0.0027, 2 * np.sin(0.5 * np.pi * p / 0.0027) ** 2, 1.0), 2.0),
    (lambda p: (p / (p + 0.01)) ** 2, 2.0),
    (lambda p: np.minimum(p / 0.01, 1.0) ** 3, 3.0),
    (lambda p: 0.0 * p, np.inf),
])
def test_fallback_zero_power_of_plain_callables(fun, k):
    """The probe recovers the exact power of f ~ p^k (oracle: the formula) and Feller's k < 2 classifies."""
    assert zero_power_of(fun, 0.0027) == k
    assert wall_reached(zero_power_of(fun, 0.0027)) == (k < 2)


def test_declared_protocol_matches_probe():
    """Every built-in model's declared zero_power equals what the fallback probe measures on it."""
    for model in (SharpCutoff(), MuserCutoff(0.01), RaisedCosineCutoff(0.01), SmoothstepCutoff(0.01),
                  ProportionalDiffusivity(2.0), _PF(SmoothstepCutoff(0.01), _MLT(0.1))):
        probed = zero_power_of(lambda p, m=model: m(p), 0.01)
        assert model.zero_power == probed, model


def test_breakpoints_of_user_callable_found_by_bisection():
    """A user's literal cutoff jumps (2 -> 1) at p_c: the probe+bisection finds p_c to 1e-12 relative."""
    p_c = 0.0027
    lit = lambda p: np.where(p < p_c, 1 - np.cos(np.pi * p / p_c), 1.0)  # noqa: E731
    (bp,) = breakpoints_of(lit, 0.0, 0.02)
    assert abs(bp - p_c) < 1e-12 * p_c
    assert breakpoints_of(_PF(MuserCutoff(p_c), _MLT(0.01)), 0.0, 1.0) == (p_c, 0.01)


def test_wrong_shape_callable_is_a_clear_error():
    with pytest.raises(ValueError, match="vectorized"):
        zero_power_of(lambda p: np.ones(3), 1.0)
