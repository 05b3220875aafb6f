"""The main job (diffusion_pr.jobs.fig1.run_fig1): its numbers against independent values.

One small run (64^2, hard wall + two exponential walls) is shared by the tests.
Oracles, all recomputed here from the surface and the GFMD pressure field
without the package's comparison code:

* the theory's stress variance: ``V = (E*/2)^2 sum_q q^2 G1(q)^2 |h~(q)|^2``
  (paper Eqs. 3 and 10) straight from the heights' FFT, so a theory drawn at
  the wrong ``zeta`` (e.g. 0) is caught (V(0) differs from V(0.25) by a factor 3);
* contact fractions: GFMD's by counting ``p > 0.01 p0`` (hard wall ``p > 0``)
  on the field, the theory's by integrating its finite-volume cells above the
  same threshold;
* histogram: edges every ``p0/10`` from 0 past the largest pressure, bin masses
  from ``numpy.histogram`` of the field, total mass 1 to round-off.
"""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

import gfmd_ref
from diffusion_pr.jobs import fig1
from diffusion_pr.closed_forms import persson_zero_weight
from diffusion_pr.jobs.reference_data import ReferenceCase, paper_theory
from diffusion_pr.spectra import DiscreteSpectrum

N, SEED, ZETAS = 64, 2, (0.01, 0.25)
E_STAR, P0, L = 8.0 / 3.0, 0.004, 1024.0  # the paper's values, written out (oracle independent of paper.py)


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig1")
    report = fig1.run_fig1(n=N, zetas=ZETAS, seed=SEED, rtol=1e-4, out_dir=out, log=lambda s: None)
    return report, out


@pytest.fixture(scope="module")
def heights():
    return gfmd_ref.self_affine_surface(N, length=L, hurst=0.3, q_min=2 * math.pi / L, q_max=2 * math.pi / 32,
                                        rms_slope=0.031, seed=SEED)


def variance_from_heights(h: np.ndarray, zeta: float) -> float:
    n = h.shape[0]
    ht = np.fft.fft2(h) / h.size
    k = 2 * np.pi * np.fft.fftfreq(n, d=L / n)
    q = np.sqrt(k[:, None] ** 2 + k[None, :] ** 2)
    g1 = 1.0 / (1.0 + zeta * q * E_STAR / (2.0 * P0))  # paper Eq. 10
    return float(np.sum((E_STAR * q / 2.0) ** 2 * g1**2 * np.abs(ht) ** 2))


def mass_above(theory, threshold: float) -> tuple[float, float]:
    """Continuous mass above ``threshold`` from the finite-volume cells: the mass of the cells
    entirely above it, and the mass of the cell that contains it (how the cell's mass is split
    at the threshold depends on the in-cell reconstruction, so that much is left open)."""
    e = np.asarray(theory.edges)
    m = np.asarray(theory.weights) * np.asarray(theory.density)
    above = float(np.sum(m[e[:-1] >= threshold]))
    straddle = float(np.sum(m[(e[:-1] < threshold) & (e[1:] > threshold)]))
    return above, straddle


def test_walls_and_order(job):
    report, _ = job
    assert [c.zeta for c in report.cases] == [None, *ZETAS]


def test_theory_is_drawn_at_each_walls_zeta(job, heights):
    report, _ = job
    v0 = variance_from_heights(heights, 0.0)
    # the generator fixes the realized slope: V0 = (E*/2 * 0.031)^2 exactly
    assert v0 == pytest.approx((E_STAR / 2 * 0.031) ** 2, rel=1e-12)
    assert report.variance_persson == pytest.approx(v0, rel=1e-12)
    assert report.persson.variance == pytest.approx(v0, rel=1e-12)
    for c in report.cases:
        v = variance_from_heights(heights, 0.0 if c.zeta is None else c.zeta)
        # the input variance of the theory solved for this wall (relative 1e-10: two FFT sums)
        assert c.theory.variance == pytest.approx(v, rel=1e-10), c.wall
        assert c.theory.mean_pressure == P0
        # the report's sd_theory column is the drawn curve's own sd: the central moment about its own
        # mean, the delta peak at p = 0 included.  Cell-centre rule here; an in-cell reconstruction
        # adds at most sum(mass_i width_i^2)/12 (exact for piecewise constant), plus round-off.
        w, pp, d, zw = c.theory.weights, c.theory.p, c.theory.density, c.theory.zero_weight
        m = np.sum(w * pp * d)
        var_centre = np.sum(w * (pp - m) ** 2 * d) + zw * m**2
        in_cell = np.sum(w * d * np.diff(c.theory.edges) ** 2) / 12 if c.theory.edges is not None else 0.0
        var = c.comparison.moments_theory["variance"]
        assert abs(var - var_centre) <= 1.01 * in_cell + 1e-9 * var_centre
    assert variance_from_heights(heights, 0.25) < 0.5 * v0  # zeta matters: the check above can fail


def test_theory_is_the_claims_path(job, heights):
    report, _ = job
    spectrum = DiscreteSpectrum.from_heights(heights, L)
    for c in report.cases:
        case = ReferenceCase("x", c.zeta, None, spectrum, {"E_star": E_STAR, "mean_pressure": P0})
        ref = paper_theory(case, rtol=1e-4)
        np.testing.assert_array_equal(c.theory.density, ref.density)
        assert c.theory.zero_weight == ref.zero_weight
        if c.zeta is not None:
            assert c.gfmd_info["p_c"] == {0.01: 0.0082, 0.25: 0.0027}[c.zeta]


def test_contact_fractions_compare_like_with_like(job):
    report, _ = job
    for c in report.cases:
        p = c.pressure
        threshold = 0.0 if c.zeta is None else 0.01 * P0  # docs/gfmd.md: "pressure > 0.01 p0"
        assert c.contact_threshold == threshold
        a_sim = np.count_nonzero(p > threshold) / p.size
        assert c.comparison.contact_fraction_sim == a_sim == c.gfmd_info["contact_fraction"]
        if c.zeta is None:
            a_th = 1.0 - persson_zero_weight(P0, report.variance_persson)
            assert c.comparison.contact_fraction_theory == pytest.approx(a_th, abs=1e-9)
        else:
            above, straddle = mass_above(c.theory, threshold)
            a_th = c.comparison.contact_fraction_theory
            assert above - 1e-12 <= a_th <= above + straddle + 1e-12
            # the bracket is tight enough to tell GFMD's threshold 0.01 p0 from, e.g., 0.1 p0
            assert straddle < 0.5 * abs(a_th - (1.0 - float(c.theory.cdf(0.1 * P0))))
            # the theory's own default is the same threshold; 1 - zero_weight is a different number here
            assert c.theory.contact_area() == a_th and abs(1 - c.theory.zero_weight - a_th) > 1e-3


def test_histograms_against_the_field(job):
    report, _ = job
    for c in report.cases:
        p = c.pressure.ravel()
        e = c.histogram.edges
        assert e[0] == 0.0
        np.testing.assert_allclose(np.diff(e), P0 / 10, rtol=1e-9)
        assert e[-2] < p.max() <= e[-1]
        counts, _ = np.histogram(p[p > 0], bins=e)
        np.testing.assert_allclose(c.histogram.density * np.diff(e), counts / p.size, rtol=1e-12, atol=0)
        assert c.histogram.zero_weight == np.count_nonzero(p == 0) / p.size
        total = np.sum(c.histogram.density * np.diff(e)) + c.histogram.zero_weight
        assert total == pytest.approx(1.0, abs=1e-12)


def test_written_files_hold_the_reports_numbers(job):
    report, out = job
    with (out / "fig1_curves.csv").open() as fh:
        rows = list(csv.reader(fh))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    assert header[:2] == ["p", "persson"]
    p = data[:, 0]
    assert p[-1] == pytest.approx(max(c.histogram.edges[-1] for c in report.cases))
    np.testing.assert_allclose(data[:, 1], report.persson.pdf(p), rtol=1e-12)
    for c in report.cases[1:]:
        np.testing.assert_allclose(data[:, header.index(f"theory_zeta{c.zeta:g}")], c.theory.pdf(p), rtol=1e-12)
    with (out / "fig1_histograms.csv").open() as fh:
        hist_rows = list(csv.DictReader(fh))
    for c in report.cases:
        dens = np.array([float(r["density"]) for r in hist_rows if r["wall"] == c.wall])
        np.testing.assert_allclose(dens, c.histogram.density, rtol=1e-7)
    text = (out / "fig1_report.txt").read_text()
    for c in report.cases:
        assert f"{c.comparison.contact_fraction_sim:8.4f}" in text


def test_plot_draws_the_reports_arrays(job):
    import matplotlib.pyplot as plt

    report, _ = job
    ax = fig1.plot_fig1(report)
    lines = {line.get_gid(): line for line in ax.get_lines()}
    for c in report.cases:
        hist = c.histogram.rebinned(2)
        sym = lines[f"gfmd:{c.wall}"]
        np.testing.assert_array_equal(sym.get_xdata(), hist.centers)
        np.testing.assert_array_equal(sym.get_ydata(), np.where(hist.density > 0, hist.density, np.nan))
        if c.zeta is not None:
            th = lines[f"theory:{c.wall}:paper"]
            x = np.asarray(th.get_xdata())
            assert x[0] == 0.0 and x[-1] == hist.edges[-1]
            dens = c.theory.pdf(x)
            np.testing.assert_array_equal(th.get_ydata(), np.where(dens > 0, dens, np.nan))
    per = lines["persson"]
    dens = report.persson.pdf(per.get_xdata())
    np.testing.assert_allclose(per.get_ydata(), np.where(dens > 0, dens, np.nan), rtol=1e-12)
    assert ax.get_yscale() == "log" and ax.get_ylim()[0] == 1e-2
    plt.close(ax.figure)


def test_another_theory_curve_goes_through_theory_curves(monkeypatch, tmp_path):
    """The extension point: one more entry in theory_curves reaches comparisons, report, CSV and plot."""
    original = fig1.theory_curves

    def with_extra(case, **kw):
        curves = original(case, **kw)
        curves["extra"] = curves[fig1.PAPER]
        return curves

    monkeypatch.setattr(fig1, "theory_curves", with_extra)
    report = fig1.run_fig1(n=64, zetas=(0.25,), hard_wall=False, rtol=1e-4, out_dir=tmp_path, log=lambda s: None)
    (case,) = report.cases
    assert list(case.comparisons) == ["paper", fig1.BEST_CLOSURE, "extra"]
    assert case.comparisons["extra"] == case.comparisons["paper"]
    header = (tmp_path / "fig1_curves.csv").read_text().splitlines()[0].split(",")
    assert "extra_zeta0.25" in header
    assert "   extra " in report.text()


@pytest.mark.parametrize("kwargs, name", [
    ({"n": 0}, "n"), ({"n": 64.0}, "n"), ({"zetas": (0.25, -1.0)}, "zeta"), ({"zetas": (float("nan"),)}, "zeta"),
    ({"zetas": "0.25"}, "zetas"), ({"seed": 1.0}, "seed"), ({"tol": 0.0}, "tol"), ({"hard_wall": "yes"}, "hard_wall"),
    ({"zetas": (), "hard_wall": False}, "nothing to compare"), ({"cutoff": "nope"}, "cutoff"),
    ({"backend": "nope"}, "backend"), ({"rtol": -1.0}, "rtol"), ({"log": 3}, "log"),
])
def test_bad_input_fails_before_any_gfmd(monkeypatch, tmp_path, kwargs, name):
    def no_gfmd(*a, **k):
        raise AssertionError("GFMD ran before the input was checked")

    monkeypatch.setattr(gfmd_ref, "solve_contact", no_gfmd)
    args = {"n": 64, "zetas": (0.25,), "out_dir": tmp_path, **kwargs}
    with pytest.raises(ValueError, match=name):
        fig1.run_fig1(**args)


def test_unwritable_output_fails_before_any_gfmd(monkeypatch, tmp_path):
    monkeypatch.setattr(gfmd_ref, "solve_contact", lambda *a, **k: (_ for _ in ()).throw(AssertionError("ran")))
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(ValueError, match="out_dir"):
        fig1.run_fig1(n=32, zetas=(0.25,), out_dir=blocker / "sub")
