"""Plot helpers draw the result's own arrays, on a readable range."""
from __future__ import annotations

import math

import numpy as np
import pytest

import diffusion_pr as dp
from diffusion_pr.plotting import plot_histogram

plt = pytest.importorskip("matplotlib.pyplot")


@pytest.fixture(scope="module")
def fig1_result():
    s = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    return dp.pressure_distribution(s, E_star=8 / 3, mean_pressure=0.004, zeta=0.25, cutoff="smoothstep",
                                    p_c=0.0027, rtol=1e-4)


@pytest.mark.parametrize("which", ["fig1", "gaussian"])
def test_plot_draws_the_results_arrays_on_a_readable_range(fig1_result, which):
    # the Fig. 1 theory (finite volumes) and the closed-form Gaussian, whose tail reaches 1e-23
    r = fig1_result if which == "fig1" else dp.propagate(1.0, 1.0)
    ax = r.plot()
    (line,) = ax.get_lines()
    np.testing.assert_array_equal(line.get_xdata(), r.p)
    np.testing.assert_array_equal(line.get_ydata(), np.where(r.density > 0, r.density, np.nan))
    peak = float(np.max(r.density))
    lo, hi = ax.get_ylim()
    # the solver's tail reaches below anything readable (1e-8 and 1e-22 of the peak) ...
    assert np.min(r.density[r.density > 0]) < peak * 1e-7
    # ... the axis shows 6 decades below the peak and the peak itself
    assert lo == pytest.approx(peak * 1e-6, rel=1e-12) and hi == pytest.approx(2 * peak, rel=1e-12)
    assert math.log10(hi / lo) < 7
    # x ends where the density last reaches the bottom of the y-axis
    last = r.p[np.nonzero(r.density >= lo)[0][-1]]
    assert ax.get_xlim() == pytest.approx((0.0, 1.02 * last))
    assert "E*" in ax.get_xlabel()
    plt.close(ax.figure)


def test_second_curve_widens_never_cuts(fig1_result):
    narrow = dp.propagate(0.004, 1e-6)  # a much narrower, taller Gaussian
    ax = fig1_result.plot()
    lo1, _ = ax.get_ylim()
    _, x1 = ax.get_xlim()
    narrow.plot(ax=ax)
    lo2, hi2 = ax.get_ylim()
    assert lo2 <= lo1 and hi2 >= 2 * np.max(narrow.density) * (1 - 1e-12)
    assert ax.get_xlim()[1] >= x1
    assert len(ax.get_lines()) == 2
    plt.close(ax.figure)


def test_histogram_symbols_are_the_given_arrays():
    centers = np.array([0.5, 1.5, 2.5])
    density = np.array([0.2, 0.0, 0.1])
    ax = plot_histogram(centers, density)
    (line,) = ax.get_lines()
    np.testing.assert_array_equal(line.get_xdata(), centers)
    np.testing.assert_array_equal(line.get_ydata(), [0.2, np.nan, 0.1])  # zero: not drawn on a log axis
    assert line.get_marker() == "o" and line.get_linestyle() == "None"
    plt.close(ax.figure)
