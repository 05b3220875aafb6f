"""Load curves (diffusion_pr.load_curve) against oracles: Persson's closed-form contact area at the hard wall,
single solves of pressure_distribution, and monotonicity of a_r in p0."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy.special import erf

import diffusion_pr as dp
from diffusion_pr.load_curve import COLUMNS, LoadCurve, load_curve
from diffusion_pr.paper import FIG1_SCENE as F

SPECTRUM = dp.SelfAffineSpectrum(F["hurst"], F["q_min"], F["q_max"], rms_slope=F["rms_slope"])
E = F["E_star"]
#: loads giving a_r from about 1e-3 to 0.9 at the hard wall
LOADS = np.geomspace(5e-5, 0.07, 12)


def test_hard_wall_is_persson():
    """Hard wall: a_r = erf(p0 / sqrt(2 V)) with V = (E* gbar / 2)^2 (Persson; the closed form's own rtol)."""
    lc = load_curve(SPECTRUM, E_star=E, mean_pressures=LOADS, closure="second_order")
    exact = erf(LOADS / math.sqrt(2.0) / (E * F["rms_slope"] / 2))
    assert lc.table["contact_area"] == pytest.approx(exact, rel=1e-6)
    assert lc.table["contact_area"][0] < 2e-3 and lc.table["contact_area"][-1] > 0.9
    assert lc.monotone and lc.note == "" and lc.table["success"].all()
    assert np.all(lc.table["threshold"] == 0.0)


@pytest.mark.parametrize("closure", ["lognormal_gap", "local_g1", "local_g1_shell_balanced"])
def test_each_load_is_a_single_solve(closure):
    """Every row equals pressure_distribution at that load within rtol (contact area and mean)."""
    loads = LOADS[[0, 5, 11]]
    lc = load_curve(SPECTRUM, E_star=E, mean_pressures=loads, zeta=0.25, closure=closure, rtol=1e-4)
    for p0, row, r in zip(loads, lc.table, lc.results):
        one = dp.pressure_distribution(SPECTRUM, E_star=E, mean_pressure=p0, zeta=0.25, closure=closure, rtol=1e-4)
        assert row["contact_area"] == pytest.approx(one.contact_area(), abs=1e-4)
        assert row["threshold"] == pytest.approx(0.01 * p0, rel=1e-12)
        assert row["mean"] == pytest.approx(p0, rel=1e-4)
        assert row["sd"] == pytest.approx(math.sqrt(one.moment(2, central=True)), rel=1e-4)
        assert r.mean_pressure == p0


@pytest.mark.parametrize("closure, kwargs", [
    ("second_order", {"cutoff": "smoothstep", "p_c_ratio": 0.0027 / 0.004}),
    ("second_order", {"cutoff": "muser", "p_c_ratio": 0.0027 / 0.004}),
    ("lognormal_gap", {}),
    ("local_g1", {}),
    ("local_g1_balanced", {}),
    ("local_g1_shell_balanced", {}),
])
def test_monotone_for_every_closure(closure, kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # a non-monotone curve warns
        lc = load_curve(SPECTRUM, E_star=E, mean_pressures=LOADS, zeta=0.25, closure=closure, **kwargs)
    a = lc.table["contact_area"]
    assert lc.monotone and np.all(np.diff(a) >= -2e-4), a
    assert a[-1] > a[0]


def test_fixed_p_c_is_not_monotone_and_says_why():
    """The paper's second order with its fixed p_c = 0.0027: a_r -> 1 at loads p0 << p_c (measured: 1.0 at
    p0 = 5e-5, 0.52 near 0.004), and the result says so."""
    with pytest.warns(UserWarning, match="p_c_ratio"):
        lc = load_curve(SPECTRUM, E_star=E, mean_pressures=LOADS, zeta=0.25, cutoff="muser", p_c=0.0027)
    assert not lc.monotone and "fixed pressure" in lc.note
    assert lc.table["contact_area"][0] > 0.99 > lc.table["contact_area"].min()


def test_table_csv_and_plot(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    lc = load_curve(SPECTRUM, E_star=E, mean_pressures=LOADS[::-1][:4], zeta=1.0, closure="lognormal_gap")
    assert isinstance(lc, LoadCurve) and lc.table.dtype.names == COLUMNS
    path = tmp_path / "curve.csv"
    lc.to_csv(path)
    back = np.loadtxt(path, delimiter=",")
    assert back.shape == (4, len(COLUMNS))
    assert back[:, 1] == pytest.approx(lc.table["contact_area"], rel=1e-9)
    ax = lc.plot()
    assert ax.get_xscale() == "log" and len(ax.lines) == 1
    with pytest.raises(AttributeError):
        lc.zeta = 2.0  # frozen


@pytest.mark.parametrize("kwargs, match", [
    ({"mean_pressures": [0.01, -1.0]}, "mean_pressures"),
    ({"mean_pressures": []}, "mean_pressures"),
    ({"mean_pressures": [[0.01]]}, "mean_pressures"),
    ({"mean_pressures": [0.01], "p_c_ratio": 0.5, "closure": "local_g1"}, "p_c_ratio"),
    ({"mean_pressures": [0.01], "p_c_ratio": 0.5, "p_c": 0.1}, "p_c_ratio"),
    ({"mean_pressures": [0.01], "p_c_ratio": -0.5}, "p_c_ratio"),
])
def test_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        load_curve(SPECTRUM, E_star=E, **kwargs)


def test_cli_load_curve(tmp_path, capsys):
    from diffusion_pr.cli import main
    from gfmd_ref import self_affine_surface

    out = tmp_path / "lc.csv"
    assert main(["load-curve", "--n-loads", "4", "--closure", "second_order", "--out", str(out)]) == 0
    table = np.loadtxt(out, delimiter=",")
    exact = erf(np.geomspace(5e-5, 0.07, 4) / math.sqrt(2.0) / (E * F["rms_slope"] / 2))
    assert table[:, 1] == pytest.approx(exact, rel=1e-6)
    h = self_affine_surface(32, length=32.0, hurst=0.3, q_min=2 * np.pi / 32, q_max=2 * np.pi / 8, rms_slope=0.05,
                            seed=1)
    np.save(tmp_path / "h.npy", h)
    assert main(["load-curve", "--heights", str(tmp_path / "h.npy"), "--length", "32", "--zeta", "0.1",
                 "--closure", "local_g1", "--n-loads", "3"]) == 0
    assert "contact_area" in capsys.readouterr().out
    assert main(["load-curve", "--heights", str(tmp_path / "h.npy")]) == 2
    assert "--length" in capsys.readouterr().err
