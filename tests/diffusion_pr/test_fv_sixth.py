"""extrapolation="sixth": a second Richardson extrapolation on four nested grids.

Oracle everywhere: the engine's default (fourth-order) solve of the same problem at
rtol 1e-9 (a converged finer run, independent of the second extrapolation).
"""
from __future__ import annotations

import numpy as np
import pytest

import diffusion_pr as dp
from diffusion_pr.closures import closure_problem, spectrum_shells
from diffusion_pr.solvers.fv import engine

SPEC = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
KW = dict(E_star=8 / 3, mean_pressure=0.004)


def _l1(res, ref) -> float:
    """L1 distance of the cell masses and the zero weight from the oracle's."""
    e = res.edges
    return float(np.sum(np.abs(np.diff(ref.cdf(e)) - res.density * np.diff(e)))
                 + abs(res.zero_weight - ref.zero_weight))


def _cdf_sup(res, ref) -> float:
    """Largest cdf distance from the oracle's at 4000 pressures (between the edges too), 1e-12 p0 ... 1e3 p0."""
    x = np.geomspace(1e-12, 1e3, 4000) * KW["mean_pressure"]
    return float(np.max(np.abs(res.cdf(x) - ref.cdf(x))))


def _closure(closure, zeta, **kw):
    # the 96-shell problems themselves (scenes for the engine's sixth-order scheme; the continuum limit in the
    # number of shells is tested in test_closures.py)
    return dp.closure_distribution(SPEC, closure=closure, zeta=zeta, shell_extrapolation=False, **KW, **kw)


@pytest.fixture(scope="module")
def oracles():
    return {(c, z): _closure(c, z, rtol=1e-9) for c, z in (("local_g1", 0.25), ("local_g1", 4.0),
                                                           ("local_g1_balanced", 1.0))}


@pytest.mark.parametrize("closure, zeta", [("local_g1", 0.25), ("local_g1", 4.0), ("local_g1_balanced", 1.0)])
def test_sixth_meets_rtol_with_an_honest_estimate(oracles, closure, zeta):
    """At rtol 1e-6 the answer is within rtol of the oracle, in L1 of the cell masses and in the cdf anywhere
    (between the edges too); its estimate is within the issue's factor 10 of the larger of the two true errors
    and not below it (measured est/true 1.3, 1.7, 1.3 here); its mean is the oracle's to 1e-6 p0 (the engine
    refines until a conserved mean misses by at most 0.5 rtol p0); and it lives on the N grid of the four
    (M, N, 2N, 4N)."""
    res = _closure(closure, zeta, rtol=1e-6, backend="native", extrapolation="sixth")
    ref = oracles[closure, zeta]
    err = max(_l1(res, ref), _cdf_sup(res, ref))
    assert res.success and err <= 1e-6
    assert err <= res.error_estimate <= 10 * err
    assert abs(res.mean_pressure - ref.mean_pressure) <= 1e-6 * KW["mean_pressure"]
    m = res.diagnostics["levels"]
    assert len(m) == 4 and m[1:] == [2 * m[0], 4 * m[0], 8 * m[0]]
    assert res.edges.size - 1 <= m[1] and res.diagnostics["extrapolation"] == "sixth"


def test_sixth_estimate_covers_the_cdf_between_the_edges(oracles):
    """The sixth's output grid is 2-4x coarser than the fourth-order scheme's, and the cubic spline of the cdf
    between its edges erred by far more than the masses (local_g1, zeta 0.25, M = 53: 8.9e-5 just below p0 for an
    estimate of 3.2e-7; the masses 2.1e-8).  The estimate now carries that interpolation error (the spline at the
    cells' midpoints against R(2N, 4N), times 1.25): measured midpoint estimate 0.90-0.93 of the true sup on
    53-212 cells.  Assert the estimate at or above the true cdf error on fixed grids, and within 3x of it."""
    ref = oracles["local_g1", 0.25]
    for n in (53, 106, 160):
        res = _closure("local_g1", 0.25, rtol=1e-6, backend="native", extrapolation="sixth", n_cells=n)
        true = _cdf_sup(res, ref)
        assert true <= res.error_estimate <= 3 * true, n
        assert res.diagnostics["cdf_interpolation_error"] <= res.error_estimate


def test_sixth_converges_at_sixth_order(oracles):
    """Fixed grids M = 24 and 48 (local_g1, zeta 0.25): the error falls 37x (measured 6.9e-6
    -> 1.9e-7; sixth order would be 64x, fourth order 16x, which the fourth-order engine shows
    on the same grids: 9.1e-5 -> 5.2e-6, 17x). Assert more than 25x."""
    ref = oracles["local_g1", 0.25]
    coarse, fine = (_l1(_closure("local_g1", 0.25, rtol=1e-6, backend="native", extrapolation="sixth",
                                 n_cells=n), ref) for n in (24, 48))
    assert coarse / fine > 25


def test_pre_asymptotic_guard_keeps_the_estimate_honest(oracles):
    """On very coarse grids (local_g1, zeta 4, M = 8..16) the sixth-order estimate alone was
    up to 5x below the true error (3.4e-4 against 1.7e-3 at M = 8); where the fourth-order
    differences do not yet fall like h^4 the engine reports the fourth-order estimate
    (measured 1.1e-3, 3.8e-4, 4.2e-4 against 1.7e-3, 1.6e-4, 1.2e-4). Assert at most 2x below."""
    ref = oracles["local_g1", 4.0]
    for n in (8, 12, 16):
        res = _closure("local_g1", 4.0, rtol=1e-6, backend="native", extrapolation="sixth", n_cells=n)
        assert res.error_estimate >= _l1(res, ref) / 2, n


def test_two_threads_give_the_same_answer():
    a, b = (_closure("local_g1_balanced", 1.0, rtol=1e-6, backend="native", extrapolation="sixth", threads=t)
            for t in (1, 2))
    assert np.array_equal(a.density, b.density) and a.zero_weight == b.zero_weight


def test_bad_extrapolation_is_refused():
    with pytest.raises(ValueError, match="extrapolation must be 'fourth' or 'sixth'; got extrapolation='bogus'"):
        _closure("local_g1", 0.25, rtol=1e-6, backend="native", extrapolation="bogus")
    with pytest.raises(ValueError, match="extrapolation"):  # the peers do not take it
        _closure("local_g1", 0.25, rtol=1e-6, backend="pypde", extrapolation="sixth")
    problem = closure_problem(spectrum_shells(SPEC, E_star=8 / 3), zeta=0.25, E_star=8 / 3,
                             mean_pressure=0.004, closure="local_g1")
    with pytest.raises(ValueError, match="extrapolation='sixth' needs the native operator"):
        engine.solve_fv(problem, rtol=1e-6, backend="x", loop=lambda *a: None, extrapolation="sixth")


@pytest.mark.parametrize("zeta, bound", [(0.25, 5e-7), (4.0, 6e-8)])
def test_sixth_mean_is_extrapolated_too(oracles, zeta, bound):
    """The solver's first moment (``diagnostics["mean_error"]``, the mean the engine checks) is
    extrapolated like the masses. On coarse fixed grids (M = 12) it matches the oracle's to
    1.6e-7 p0 (zeta 0.25) and 1.9e-8 p0 (zeta 4); moments left at fourth order miss by 1.2e-6
    and 1.2e-7. Assert about 3x above the measured values."""
    ref = oracles["local_g1", zeta]
    res = _closure("local_g1", zeta, rtol=1e-6, backend="native", extrapolation="sixth", n_cells=12)
    miss = abs(res.diagnostics["mean_error"] - ref.diagnostics["mean_error"]) / KW["mean_pressure"]
    assert miss <= bound


def test_n_start_bound_follows_the_finest_grid():
    """With four grids the finest has 8x the coarsest's cells: n_start is capped at
    max_cells/8 (it was max_cells/4 for three grids), and a sweep's chained start is used."""
    with pytest.raises(ValueError, match=r"n_start must be an integer in \[8, max_cells/8 = 512\]"):
        _closure("local_g1", 0.25, rtol=1e-6, backend="native", extrapolation="sixth", max_cells=4096, n_start=600)
    first = _closure("local_g1_balanced", 0.25, rtol=1e-6, backend="native", extrapolation="sixth")
    again = _closure("local_g1_balanced", 0.3, rtol=1e-6, backend="native", extrapolation="sixth",
                     n_start=first.diagnostics["cells_needed"])
    assert len(first.diagnostics["history"]) == 2 and len(again.diagnostics["history"]) == 1
