"""The engine's coefficient-row plans (diffusion_pr.fokker_planck.domain) and its thread safety.

The plans are a speed measure with no effect on any answer: the oracle is the path they replace (a model type's
``rows``), compared bit for bit.
"""
from __future__ import annotations

import threading

import numpy as np
import pytest

import diffusion_pr as dp
from diffusion_pr import StagedProblem, Stage
from diffusion_pr.closures import (LoadExcessDrift, LocalResponseDiffusivity, RigidApproachBalance,
                                   spectrum_shells)
from diffusion_pr.fokker_planck import domain

E = 8 / 3
P0 = 0.004


@pytest.fixture(scope="module")
def fig1():
    return dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)


def _models(fig1, kz):
    sh = spectrum_shells(fig1, E_star=E)
    return {
        "f": tuple(LocalResponseDiffusivity(float(x), kz) for x in sh.q),
        "b": tuple(LoadExcessDrift(float(x), float(sh.q_min), kz) for x in sh.q),
        "w": tuple(RigidApproachBalance(float(sh.q_min), kz) for _ in sh.q),
    }


def test_row_plans_are_the_models_rows_bit_for_bit(fig1):
    """A plan (made once per problem) gives the bits of its models called one by one (which test_closures checks
    against the numpy formulas), into a given C-contiguous ``out`` in place and into any other ``out`` by a copy; a
    non-finite value gives None (the engine's checked path then says where); no plan where the shells do not
    share one wall product (the hard wall, mixed ``kz``)."""
    kz = 0.5 * 0.25 * E
    p = np.r_[-1.0, 0.0, np.geomspace(1e-300, 10.0, 501)]
    for key, items in _models(fig1, kz).items():
        plan = type(items[0]).row_plan(items)
        expect = np.array([it(p) for it in items])
        assert len(plan) == len(items)
        np.testing.assert_array_equal(plan(p), expect)
        out = np.empty(expect.shape)
        assert plan(p, out) is out
        np.testing.assert_array_equal(out, expect)
        strided = np.empty((expect.shape[0], 2 * expect.shape[1]))[:, ::2]
        assert plan(p, strided) is strided
        np.testing.assert_array_equal(strided, expect)
        assert plan(np.r_[p, np.nan]) is None
    assert LocalResponseDiffusivity.row_plan(_models(fig1, 0.0)["f"]) is None
    mixed = _models(fig1, kz)["f"][:3] + _models(fig1, 2 * kz)["f"][:3]
    assert LocalResponseDiffusivity.row_plan(mixed) is None


def test_row_plans_follow_the_pieces_that_have_each_coefficient(fig1):
    """``row_plans``: the drift's stages, callables and plan are those of the stages with a drift, in their order
    (the rows ``_coefficients`` scatters back to those stages); a user's callables have no plan."""
    m = _models(fig1, 0.5 * 0.25 * E)
    stages = tuple(Stage(1e-6, f, drift=b if k % 3 else None) for k, (f, b) in enumerate(zip(m["f"], m["b"])))
    _, pieces, _, _ = domain._pieces_of(StagedProblem(P0, stages))
    plans = domain.row_plans(pieces)
    with_b = tuple(s.drift for s in stages if s.drift is not None)
    assert plans["b"].stages == tuple(k for k in range(len(stages)) if k % 3) and plans["b"].funcs == with_b
    assert plans["f"].every and not plans["b"].every and plans["w"].stages == () and plans["w"].plan is None
    assert len(plans["f"].plan) == len(stages) and len(plans["b"].plan) == len(with_b)
    p = np.linspace(0.0, 0.02, 33)
    np.testing.assert_array_equal(plans["b"].plan(p), np.array([m(p) for m in with_b]))
    user = tuple(Stage(0.1, lambda p: np.ones_like(p)) for _ in range(3))
    assert all(v.plan is None for v in domain.row_plans(domain._pieces_of(StagedProblem(1.0, user))[1]).values())


def _bits(r):
    return np.concatenate([[r.zero_weight, r.error_estimate], r.edges, r.cdf(r.edges)])


def _partial_drift_problem():
    """24 stages, a drift on two of three (the zero rows of the others come from reused memory)."""
    one = lambda p: np.ones_like(p)  # noqa: E731
    return StagedProblem(1.0, tuple(Stage(1.0 / 24, one, drift=(lambda p: 0.5 + 0 * p) if k % 3 else None)
                                    for k in range(24)))


def test_two_user_threads_solving_at_once_get_the_serial_bits(fig1):
    """Two threads of one process (a Dask worker with two threads) solving different closure scenes at once share
    the engine; no state is shared between solves, so every answer is its serial solve's bit for
    bit (each scene solved 4 times per thread, so that the solves overlap)."""
    scenes = (("local_g1_balanced", 0.25), ("local_g1_shell_balanced", 1.0))

    def solve(closure, zeta):
        return _bits(dp.pressure_distribution(fig1, E_star=E, mean_pressure=P0, zeta=zeta, closure=closure,
                                              rtol=1e-6))

    serial = [solve(*sc) for sc in scenes]
    got: dict = {}
    errors: list = []

    def run(k):
        try:
            got[k] = [solve(*scenes[k]) for _ in range(4)]
        except Exception as exc:  # noqa: BLE001 (re-raised below, in the test's thread)
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for k in range(2):
        for answer in got[k]:
            np.testing.assert_array_equal(answer, serial[k])
