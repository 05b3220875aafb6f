"""What a user sees: named errors instead of silent answers, one length convention,
GFMD on a user's (rectangular) map."""
import json
import time

import numpy as np
import pytest

import gfmd_ref
from gfmd_ref import ExponentialRepulsion, HardWall, solve_contact
from gfmd_ref.cli import main, run_default_scene

E, P0 = 8.0 / 3.0, 0.004


def _no_solve(monkeypatch):
    import gfmd_ref.cli as cli

    monkeypatch.setattr(cli, "solve_contact", lambda *a, **k: (_ for _ in ()).throw(AssertionError("solved")))


def _one_line_error(capsys, *words):
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert "Traceback" not in cap.err and len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)


# ------------------------------------------------------------------ silent failures


def test_tol_outside_its_range_is_refused_and_a_coarse_tol_is_not_met_by_the_start():
    h, L = gfmd_ref.fig1_surface(64, seed=1)
    with pytest.raises(ValueError, match=r"tol must be a number in \(0, 0.1\].*got tol=10"):
        solve_contact(h, length=L, E_star=E, mean_pressure=P0, interaction=HardWall(), tol=10)
    r = solve_contact(h, length=L, E_star=E, mean_pressure=P0, interaction=HardWall(), tol=0.1)
    assert r.converged and r.iterations > 0 and np.ptp(r.pressure) > 0 and r.contact_fraction < 0.5


def test_cli_tol_outside_its_range(monkeypatch, capsys, tmp_path):
    _no_solve(monkeypatch)
    assert main(["run", "--n", "64", "--tol", "10", "--out", str(tmp_path)]) == 2
    _one_line_error(capsys, "tol", "10", "(0, 0.1]")


def test_roughness_beyond_the_grids_nyquist_limit_is_refused(monkeypatch, capsys, tmp_path):
    with pytest.raises(ValueError, match=r"q_max must be <= the grid's Nyquist wavenumber .* = 3.14159.*q_max=100"):
        gfmd_ref.self_affine_surface(64, length=64.0, hurst=0.8, q_min=0.1, q_max=100, rms_slope=0.1, seed=1)
    # the Nyquist wavenumber itself is representable
    h = gfmd_ref.self_affine_surface(64, length=64.0, hurst=0.8, q_min=0.1, q_max=np.pi, rms_slope=0.1, seed=1)
    assert gfmd_ref.spectral_rms_slope(h, 64.0) == pytest.approx(0.1, rel=1e-12)
    with pytest.raises(ValueError, match=r"n must be >= 64.*got n=32"):
        gfmd_ref.fig1_surface(32)
    _no_solve(monkeypatch)
    assert main(["run", "--n", "32", "--out", str(tmp_path)]) == 2
    _one_line_error(capsys, "n must be >= 64", "n=32")


@pytest.mark.parametrize("args, words", [
    (("x", 64.0), ["heights"]),
    (([[0.0, 1.0], [1.0, 0.0]], -1), ["length", "-1"]),
    (([[0.0, 1.0], [1.0, 0.0]], np.nan), ["length", "nan"]),
    ((np.zeros((4, 6)), 1.0), ["square", "(4, 6)"]),
])
def test_spectral_rms_slope_checks_its_input(args, words):
    with pytest.raises(ValueError) as exc:
        gfmd_ref.spectral_rms_slope(*args)
    assert all(w in str(exc.value) for w in words), str(exc.value)


def test_zeta_implies_the_exponential_wall_and_a_hard_wall_with_zeta_is_an_error(monkeypatch, capsys, tmp_path):
    res, _, _ = run_default_scene(64, zeta=0.5, out_dir=None, verbose=False)
    assert res.interaction == ExponentialRepulsion(0.5)
    _no_solve(monkeypatch)
    assert main(["run", "--n", "64", "--interaction", "hard", "--zeta", "0.5", "--out", str(tmp_path)]) == 2
    _one_line_error(capsys, "zeta=0.5", "interaction 'exp'")


def test_no_command_prints_the_help_and_exits_0(capsys):
    """As `diffusion-pr` does; a wrong command is argparse's usage error (exit 2)."""
    assert main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: gfmd-ref") and "ensemble" in out and "Without a command: this help" in out
    with pytest.raises(SystemExit) as exc:
        main(["nope"])
    assert exc.value.code == 2 and "invalid choice: 'nope'" in capsys.readouterr().err


def test_ensemble_exits_1_when_no_case_converged(tmp_path, capsys):
    argv = ["ensemble", "--store", str(tmp_path / "s"), "--n", "64", "--seeds", "1", "--walls", "hard",
            "--tol", "1e-18", "--serial", "--no-progress"]
    assert main(argv) == 1
    assert "1 not converged" in capsys.readouterr().out


def test_ensemble_exits_1_when_every_case_failed(tmp_path, capsys, monkeypatch):
    """A case that raises (a killed worker, memory) is reported by label and retried by a rerun;
    when every case failed the command exits 1, not 0."""
    import gfmd_ref.ensemble.run as run

    monkeypatch.setattr(run, "solve_case", lambda *a, **k: (_ for _ in ()).throw(MemoryError("no memory")))
    assert main(["ensemble", "--store", str(tmp_path / "s"), "--n", "64", "--seeds", "1-2", "--walls", "hard",
                 "--serial", "--no-progress"]) == 1
    out = capsys.readouterr().out
    assert "0 computed now" in out and "2 failed" in out and "failed n64_hard_p0.004_s2: MemoryError: no memory" in out


def test_unwritable_store_fails_before_computing(monkeypatch):
    import gfmd_ref.ensemble.run as run

    monkeypatch.setattr(run, "solve_case", lambda *a, **k: (_ for _ in ()).throw(AssertionError("solved")))
    with pytest.raises(ValueError, match=r"store='/proc/xx' is not a writable folder"):
        gfmd_ref.run_ensemble("/proc/xx", n=64, seeds=1, serial=True, progress=False, verbose=False)


def test_damaged_record_names_its_file(tmp_path):
    store = tmp_path / "s"
    gfmd_ref.run_ensemble(store, n=64, seeds=1, serial=True, progress=False, verbose=False)
    (rec,) = store.glob("*__*.npz")
    np.savez(rec, params=np.array([{"n": 64}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match=f"{rec.name}.* is not a readable ensemble record"):
        gfmd_ref.load_ensemble(store)
    rec.write_bytes(b"truncated")
    with pytest.raises(ValueError, match=f"{rec.name}.* is not a readable ensemble record"):
        gfmd_ref.load_ensemble(store)


def test_unreachable_scheduler_is_named_at_once(tmp_path, capsys, monkeypatch):
    pytest.importorskip("dask.distributed")
    import gfmd_ref.ensemble.run as run

    monkeypatch.setattr(run, "solve_case", lambda *a, **k: (_ for _ in ()).throw(AssertionError("solved")))
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"scheduler='tcp://127.0.0.1:1': no Dask scheduler accepts"):
        gfmd_ref.run_ensemble(tmp_path / "s", n=64, seeds=1, scheduler="tcp://127.0.0.1:1", progress=False,
                              verbose=False)
    assert main(["ensemble", "--store", str(tmp_path / "s"), "--n", "64", "--seeds", "1",
                 "--scheduler", "tcp://127.0.0.1:1", "--no-progress"]) == 2
    _one_line_error(capsys, "tcp://127.0.0.1:1")
    assert time.perf_counter() - t0 < 3.0


# ------------------------------------------------------------------ one length convention


def test_run_and_ensemble_read_zeta_in_the_same_unit(tmp_path, capsys):
    """At n = 64 `run --zeta 0.25` and `ensemble --walls 0.25` are one wall (grid spacings
    of the solved grid, L = n) with one contact fraction; `--length-unit paper` is the
    paper's 1024^2 unit, zeta * n / 1024 on the solved grid, for both commands."""
    h, L = gfmd_ref.fig1_surface(64, seed=1)
    for unit, z_grid in (("grid", 0.25), ("paper", 0.25 * 64 / 1024)):
        out = tmp_path / unit
        assert main(["run", "--n", "64", "--zeta", "0.25", "--length-unit", unit, "--tol", "1e-6",
                     "--out", str(out)]) == 0
        (npz,) = out.glob("*.npz")
        meta = json.loads(str(np.load(npz)["meta"]))
        assert meta["zeta"] == 0.25 and meta["zeta_solver"] == z_grid and meta["length"] == 64.0
        assert "(L = n)" in meta["zeta_unit"] if unit == "grid" else "1024^2" in meta["zeta_unit"]
        assert main(["ensemble", "--store", str(out / "store"), "--n", "64", "--seeds", "1", "--walls", "0.25",
                     "--length-unit", unit, "--tol", "1e-6", "--serial", "--no-progress"]) == 0
        (rec,) = gfmd_ref.load_ensemble(out / "store").records
        assert rec.zeta == z_grid and rec.zeta_in("paper") == pytest.approx(z_grid * 1024 / 64, rel=1e-15)
        ref = solve_contact(h, length=L, E_star=E, mean_pressure=P0, interaction=ExponentialRepulsion(z_grid),
                            tol=1e-6)
        assert rec.contact_fraction == ref.contact_fraction == meta["contact_fraction"]
        info = json.loads((out / "store" / "ensemble.json").read_text())
        assert info["runs"][-1]["length_unit"] == unit
    capsys.readouterr()


def test_every_length_help_states_its_unit():
    import argparse

    from gfmd_ref.cli import LENGTH_UNITS, ZETA_UNIT, add_ensemble_arguments, add_run_arguments

    run = {a.dest: a.help for a in add_run_arguments(argparse.ArgumentParser())._actions}
    ens = {a.dest: a.help for a in add_ensemble_arguments(argparse.ArgumentParser())._actions}
    for helps in (run, ens):
        assert LENGTH_UNITS["grid"] in helps["length_unit"] and ZETA_UNIT in helps["length_unit"]
        assert "default: grid" in helps["length_unit"]
    assert "--length-unit" in run["zeta"] and "--length-unit" in ens["walls"] and "unit" in run["length"]


def test_bundled_ensembles_keep_their_recorded_zeta():
    """The bundles were made with walls in grid spacings of their grid (L = n): the n = 512
    off-scene bundle's zeta 0.5 is 1.0 in the paper's 1024^2 unit."""
    off = gfmd_ref.bundled_ensemble("offscene_n512")
    assert off.zetas == [None, 0.01, 0.1, 0.5, 2.0]
    r = off.select(zeta=0.5)[0]
    assert r.n == 512 and r.length == 512.0 and r.zeta_in("paper") == 1.0 and r.zeta_in("grid") == 0.5
    fig1 = gfmd_ref.bundled_ensemble("fig1_n1024")
    r = next(r for r in fig1 if r.zeta is not None)
    assert r.zeta_in("paper") == r.zeta


# ------------------------------------------------------------------ a user's map


def test_rectangular_sinusoid_in_full_contact_is_westergaard():
    """Full contact: sigma~(q) = (q E*/2) h~(q) for every mode, with q from the two sides."""
    nx, ny, lx, ly, a = 24, 40, 3.0, 7.0, 1e-4
    x = (np.arange(nx) * lx / nx)[:, None]
    y = (np.arange(ny) * ly / ny)[None, :]
    modes = [(1, 0), (2, 3), (0, 5)]
    h = sum(a * np.cos(2 * np.pi * (i * x / lx + j * y / ly)) for i, j in modes)
    exact = P0 + sum(E / 2 * 2 * np.pi * np.hypot(i / lx, j / ly) * a * np.cos(2 * np.pi * (i * x / lx + j * y / ly))
                     for i, j in modes)
    assert exact.min() > 0
    for method in ("ccg", "fire"):
        r = solve_contact(h, length=(lx, ly), E_star=E, mean_pressure=P0, interaction=HardWall(), method=method,
                          tol=1e-10)
        assert r.converged and r.contact_fraction == 1.0 and r.length == (lx, ly)
        np.testing.assert_allclose(r.pressure, exact, rtol=0, atol=1e-8 * P0)
    # a scalar length is the first side with the same spacing along the second
    r = solve_contact(h, length=lx, E_star=E, mean_pressure=P0, interaction=HardWall())
    assert r.length == (lx, lx * ny / nx)


@pytest.mark.parametrize("inter", [HardWall(), ExponentialRepulsion(0.05)])
def test_rectangular_random_map_is_the_square_solution_tiled(inter):
    """A 32 x 64 map made of a 32 x 32 map twice is the same periodic surface: the
    pressures are the square solution's, tiled."""
    h = gfmd_ref.self_affine_surface(32, length=32.0, hurst=0.5, q_min=2 * np.pi / 32, q_max=np.pi, rms_slope=0.1,
                                     seed=4)
    sq = solve_contact(h, length=32.0, E_star=E, mean_pressure=P0, interaction=inter, tol=1e-10)
    rect = solve_contact(np.tile(h, (1, 2)), length=(32.0, 64.0), E_star=E, mean_pressure=P0, interaction=inter,
                         tol=1e-10)
    assert sq.converged and rect.converged and 0 < sq.contact_fraction < 1
    np.testing.assert_allclose(rect.pressure, np.tile(sq.pressure, (1, 2)), rtol=0, atol=1e-7 * P0)
    assert rect.contact_fraction == sq.contact_fraction


def test_non_periodic_map_is_refused_with_how_to_prepare_it():
    h = gfmd_ref.self_affine_surface(32, length=32.0, hurst=0.5, q_min=2 * np.pi / 32, q_max=np.pi, rms_slope=0.1,
                                     seed=4)
    tilted = h + 0.2 * np.arange(32)[None, :]
    with pytest.raises(ValueError, match=r"not periodic along its second \(columns\) axis.*detrend.*window.*pad"):
        solve_contact(tilted, length=32.0, E_star=E, mean_pressure=P0, interaction=HardWall())
    r = solve_contact(tilted, length=32.0, E_star=E, mean_pressure=P0, interaction=HardWall(), check_periodic=False)
    assert r.converged


def test_cli_runs_a_users_rectangular_map(tmp_path, capsys):
    h = np.tile(gfmd_ref.self_affine_surface(32, length=32.0, hurst=0.5, q_min=2 * np.pi / 32, q_max=np.pi,
                                             rms_slope=0.1, seed=4), (1, 2))
    np.savetxt(tmp_path / "map.csv", h * 1e3, delimiter=",")  # heights in nm, length in um
    assert main(["run", "--heights", str(tmp_path / "map.csv"), "--length", "32", "--out", str(tmp_path)]) == 0
    ref = solve_contact(h * 1e3, length=(32.0, 64.0), E_star=E, mean_pressure=P0, interaction=HardWall())
    assert f"contact fraction: {ref.contact_fraction:.6f}" in capsys.readouterr().out
    (npz,) = tmp_path.glob("map_hard_32x64_histogram.npz")
    assert json.loads(str(np.load(npz)["meta"]))["length"] == [32.0, 64.0]
    np.save(tmp_path / "tilted.npy", h + 0.2 * np.arange(64)[None, :])
    assert main(["run", "--heights", str(tmp_path / "tilted.npy"), "--out", str(tmp_path)]) == 2
    _one_line_error(capsys, "not periodic", "detrend")
    assert main(["run", "--heights", str(tmp_path / "missing.npy"), "--out", str(tmp_path)]) == 2
    _one_line_error(capsys, "heights=", "missing.npy")
    assert main(["run", "--heights", str(tmp_path / "map.csv"), "--length-unit", "paper", "--out",
                 str(tmp_path)]) == 2
    _one_line_error(capsys, "length_unit='paper'")


def test_one_histogram_type_from_gfmd_to_the_theory_comparison():
    """diffusion_pr compares a theory with gfmd_ref's own histogram type (there is no second one), with the
    contact area at the solver's threshold on both sides: the GFMD side is the field's own count."""
    import diffusion_pr as dp
    from diffusion_pr.compare import SimulatedHistogram, compare

    assert SimulatedHistogram is gfmd_ref.PressureHistogram
    h, L = gfmd_ref.fig1_surface(64, seed=1)
    r = solve_contact(h, length=L, E_star=E, mean_pressure=P0, interaction=ExponentialRepulsion(0.002))
    hist = gfmd_ref.pressure_histogram(r, bins=30)
    theory = dp.pressure_distribution(dp.DiscreteSpectrum.from_heights(h, L), E_star=E, mean_pressure=P0,
                                      zeta=0.002)
    c = compare(theory, hist, contact_threshold=r.contact_threshold)
    assert c.contact_fraction_sim == np.count_nonzero(r.pressure > r.contact_threshold) / r.pressure.size
    assert 0.0 <= c.kolmogorov <= 1.0 and c.contact_threshold == r.contact_threshold
