"""Plot helpers draw the result's pdf over its probability mass, labelled in the user's units."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtri

import diffusion_pr as dp
from diffusion_pr.plotting import plot_histogram

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")
plt = pytest.importorskip("matplotlib.pyplot")
FIG1 = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)


def mirror_quantiles(p0, var, levels):
    """Quantiles of the mirror Gaussian's continuous part (oracle: bisection on its exact cdf)."""
    from diffusion_pr.fokker_planck.backends.closed_form import ExactSolution

    law = ExactSolution("mirror", p0, 0.5 * var, 1.0)
    total, out = float(law.cdf(np.inf)), []
    for level in levels:
        lo, hi = 0.0, p0 + 10 * np.sqrt(var)
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if law.cdf(mid) < level * total else (lo, mid)
        out.append(lo)
    return out


def test_the_mirror_gaussian_is_drawn_over_its_mass():
    """propagate(0.3, 0.5, f = [p > 0]): a breakpoint found at 1e-21 once set x from 0 to 8e-22.  The axis holds
    the 1e-3 and 1 - 1e-3 quantiles, the line is the pdf, y spans 6 decades below its peak; the labels name the
    unit of p0, not E*, and survive savefig."""
    r = dp.propagate(0.3, 0.5, diffusivity=lambda p: np.where(p > 0, 1.0, 0.0), backend="native", rtol=1e-6)
    ax = r.plot()
    lo, hi = ax.get_xlim()
    q_lo, q_hi = mirror_quantiles(0.3, 0.5, [1e-3, 1 - 1e-3])
    assert lo <= q_lo and hi >= q_hi and hi < 10 * q_hi
    (line,) = ax.get_lines()
    x = line.get_xdata()
    np.testing.assert_array_equal(line.get_ydata(), np.where(r.pdf(x) > 0, r.pdf(x), np.nan))
    peak = np.nanmax(line.get_ydata())
    assert ax.get_ylim() == pytest.approx((peak * 1e-6, 2 * peak), rel=1e-12)
    assert "p0" in ax.get_xlabel() and "E*" not in ax.get_xlabel() + ax.get_ylabel()
    fig = ax.figure
    fig.canvas.draw()
    for text in (ax.xaxis.label, ax.yaxis.label):
        box = text.get_window_extent()
        assert box.x0 >= 0 and box.y0 >= 0 and box.x1 <= fig.bbox.x1 and box.y1 <= fig.bbox.y1
    plt.close(fig)


def test_a_shell_closure_at_a_small_wall_range_is_drawn_over_its_mass():
    """zeta = 1e-3, shell closure: once drawn on p in [0, 1.5e-15].  The axis holds the continuous part's 1e-3
    and 1 - 1e-3 quantiles (read off the result's own cdf at its edges)."""
    r = dp.pressure_distribution(FIG1, E_star=8 / 3, mean_pressure=0.004, zeta=1e-3,
                                 closure="local_g1_shell_balanced", rtol=1e-4)
    ax = r.plot(units="MPa")
    share = (r.cdf(r.edges) - r.zero_weight) / (1 - r.zero_weight)
    q_lo, q_hi = np.interp([1e-3, 1 - 1e-3], share, r.edges)
    lo, hi = ax.get_xlim()
    assert lo <= q_lo and hi >= q_hi > 1e-3 and ax.get_xlabel() == "pressure p [MPa]"
    plt.close(ax.figure)


def test_second_curve_widens_never_cuts():
    wide = dp.pressure_distribution(FIG1, E_star=8 / 3, mean_pressure=0.004, zeta=0.25, cutoff="smoothstep",
                                    p_c=0.0027, rtol=1e-4)
    narrow = dp.propagate(0.004, 1e-8)  # a much narrower, taller Gaussian
    ax = wide.plot()
    (x0, x1), (y0, _) = ax.get_xlim(), ax.get_ylim()
    narrow.plot(ax=ax)
    assert ax.get_xlim()[0] <= x0 and ax.get_xlim()[1] >= x1 and ax.get_ylim()[0] <= y0
    assert ax.get_ylim()[1] >= 2 * narrow.pdf(0.004) * (1 - 1e-12)
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


def test_quantile_oracle_is_consistent():
    """(the bisection above against the Gaussian limit p0 >> sqrt(V): quantiles p0 + sqrt(V) ndtri(level))"""
    assert mirror_quantiles(10.0, 1.0, [0.3])[0] == pytest.approx(10.0 + ndtri(0.3), abs=1e-9)
