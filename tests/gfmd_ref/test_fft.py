"""The planned-FFTW path and the scipy path compute the same transforms."""
from __future__ import annotations

import numpy as np
import pytest

from gfmd_ref import HardWall, fig1_surface, solve_contact
from gfmd_ref._fft import FFTWPair, ScipyPair, fft_pair

pyfftw = pytest.importorskip("pyfftw", reason="pyfftw not installed: scipy.fft is used everywhere")


def test_fftw_pair_matches_scipy(rng):
    shape = (256, 256)
    x = rng.normal(size=shape)
    mult = rng.normal(size=(256, 129))
    a, b = FFTWPair(shape, threads=2), ScipyPair(shape)
    # both are exact transforms in double precision; round-off ~ 1e-15 * log2(n) * |x|
    X = a.rfft(x)
    assert np.max(np.abs(X - b.rfft(x))) < 1e-10
    assert np.max(np.abs(a.irfft(X) - x)) < 1e-12
    assert np.max(np.abs(a.apply(mult, x) - b.apply(mult, x))) < 1e-12
    # results are fresh arrays, not views of the plan's buffers
    y = a.rfft(x)
    a.rfft(2 * x)
    assert np.max(np.abs(y - X)) == 0.0


def test_cached_plan_costs_nothing_the_second_time():
    _, first = fft_pair((256, 256))
    pair, second = fft_pair((256, 256))
    assert second == 0.0 and pair.name == "fftw"


def test_solver_gives_the_same_answer_with_either_fft(monkeypatch):
    h, length = fig1_surface(256, seed=3)
    kw = dict(length=length, E_star=8 / 3, mean_pressure=0.004, interaction=HardWall(), tol=1e-9)
    fast = solve_contact(h, **kw)
    monkeypatch.setenv("GFMD_REF_FFT", "scipy")
    monkeypatch.setattr("gfmd_ref._fft._CACHE", {})
    slow = solve_contact(h, **kw)
    assert fast.info["fft"] == "fftw" and slow.info["fft"] == "scipy"
    # both converge to 1e-9 p0; the pressure fields agree to that level and the
    # contact sets are identical
    assert np.max(np.abs(fast.pressure - slow.pressure)) < 1e-7 * 0.004
    assert fast.contact_fraction == slow.contact_fraction
