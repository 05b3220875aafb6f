"""The ``diffusion-pr`` command line."""
from __future__ import annotations

import pytest

from diffusion_pr.cli import main


def test_theory_command_prints_a_converged_result(capsys):
    assert main(["theory", "--zeta", "0.25", "--cutoff", "smoothstep", "--p-c", "0.0027", "--rtol", "1e-4"]) == 0
    out = capsys.readouterr().out
    assert "success=True" in out and "mean=0.004" in out


def test_bad_input_is_a_clear_error_not_a_traceback(capsys):
    assert main(["theory", "--cutoff", "muser"]) == 2
    err = capsys.readouterr().err
    assert "p_c" in err and "Traceback" not in err


def test_fig1_job_writes_its_files(tmp_path, capsys):
    code = main(["fig1", "--n", "64", "--length-unit", "paper", "--zetas", "0.25", "--out", str(tmp_path),
                 "--rtol", "1e-4"])
    assert code == 0
    for name in ("fig1.png", "fig1_curves.csv", "fig1_histograms.csv", "fig1_report.txt"):
        assert (tmp_path / name).stat().st_size > 0
    report = (tmp_path / "fig1_report.txt").read_text()
    # one row per wall, and Persson's line with the Fig. 1 rms slope: sqrt(V0) =
    # (E*/2) * 0.031 = 0.041333 exactly, since the generator fixes the realized slope
    assert "hard" in report and "zeta=0.25" in report
    assert "sqrt(V0) = 0.041333" in report
    header = (tmp_path / "fig1_curves.csv").read_text().splitlines()[0]
    assert header.startswith("p,persson")


def test_unknown_command_exits_with_usage():
    with pytest.raises(SystemExit):
        main(["no-such-command"])


# --------------------------------------------------------------------------- usability
import re  # noqa: E402

import numpy as np  # noqa: E402

import diffusion_pr  # noqa: E402
import gfmd_ref  # noqa: E402
from diffusion_pr.cli import _parser  # noqa: E402
from gfmd_ref.cli import main as gfmd_main  # noqa: E402


def test_bare_command_prints_help(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert "usage: diffusion-pr" in out and "fig1" in out and "theory" in out and "make-reference" in out
    assert gfmd_main([]) == 0  # gfmd-ref: the help, as diffusion-pr
    out = capsys.readouterr().out
    assert "usage: gfmd-ref" in out and "run" in out and "writes the pressure histogram" in out


@pytest.mark.parametrize("entry, prog", [(main, "diffusion-pr"), (gfmd_main, "gfmd-ref")])
def test_version(capsys, entry, prog):
    with pytest.raises(SystemExit) as exc:
        entry(["--version"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(prog) and diffusion_pr.__version__ in out


def _subparsers(parser):
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices
    return {}


def _gfmd_parser():
    import argparse

    from gfmd_ref.cli import add_run_arguments

    return add_run_arguments(argparse.ArgumentParser(prog="gfmd-ref run"))


def test_every_flag_states_its_default():
    parsers = list(_subparsers(_parser()).items()) + [("gfmd-ref run", _gfmd_parser())]
    for name, sub in parsers:
        for action in sub._actions:
            if action.dest == "help":
                continue
            assert action.help and "default" in action.help, f"{name} {action.option_strings}: {action.help!r}"


def test_zeta_unit_is_worded_identically_in_both_clis():
    """One convention: zeta in the unit of the cell's side L; on a grid --length-unit grid (default, L = n) or
    paper (L = 1024), worded identically in both commands; theory's unit is that of --length."""
    from diffusion_pr.cli import LENGTH_UNITS, ZETA_UNIT
    from gfmd_ref.cli import LENGTH_UNITS as GFMD_LENGTH_UNITS, ZETA_UNIT as GFMD_ZETA_UNIT

    assert ZETA_UNIT == GFMD_ZETA_UNIT == "grid spacings of the paper's 1024^2 Fig. 1 system"
    assert LENGTH_UNITS == GFMD_LENGTH_UNITS
    subs = _subparsers(_parser())
    for name in ("fig1", "make-reference"):
        acts = {a.dest: a for a in subs[name]._actions}
        assert acts["length_unit"].default == "grid" == next(a for a in _gfmd_parser()._actions
                                                             if a.dest == "length_unit").default
        assert all(unit in acts["length_unit"].help for unit in LENGTH_UNITS.values())
        assert "--length-unit" in acts["zetas"].help and ZETA_UNIT in acts["zetas"].help
    theory = {a.dest: a for a in subs["theory"]._actions}
    assert "--length" in theory["zeta"].help and ZETA_UNIT in theory["length"].help
    load = {a.dest: a for a in subs["load-curve"]._actions}
    assert ZETA_UNIT in load["zeta"].help and "--length" in load["zeta"].help


def test_grid_zetas_are_converted_to_the_jobs_paper_unit():
    """--length-unit grid: zeta in spacings of the n^2 grid, i.e. zeta * 1024/n in the paper's unit (the jobs')."""
    from diffusion_pr.cli import _paper_zetas

    parse = _subparsers(_parser())["fig1"].parse_args
    assert _paper_zetas(parse(["--n", "256", "--zetas", "0.25,1"]), "") == [1.0, 4.0]
    assert _paper_zetas(parse(["--n", "256", "--zetas", "0.25", "--length-unit", "paper"]), "") == [0.25]
    assert _paper_zetas(parse(["--n", "256"]), "0.01,4") == [0.01, 4.0]  # the defaults: the paper's walls


def test_gfmd_ref_zeta_is_the_same_wall_as_diffusion_pr_fig1():
    """`gfmd-ref run --n 32 --zeta 0.25` solves the problem `diffusion-pr fig1 --n 32` calls zeta = 0.25.

    Oracle: the contact problem is scale-free (fixed rms slope, E*, p0), so the
    paper-unit surface (L = 1024) and gfmd-ref's L = n surface give the same
    pressures once zeta is converted; solved here directly with solve_contact.
    """
    from gfmd_ref.cli import run_default_scene

    res, _, _ = run_default_scene(64, interaction="exp", zeta=0.25, length_unit="paper", out_dir=None,
                                  verbose=False, tol=1e-10)
    h = gfmd_ref.self_affine_surface(64, length=1024.0, hurst=0.3, q_min=2 * np.pi / 1024,
                                     q_max=2 * np.pi / 32, rms_slope=0.031, seed=1)
    ref = gfmd_ref.solve_contact(h, length=1024.0, E_star=8 / 3, mean_pressure=0.004,
                                 interaction=gfmd_ref.ExponentialRepulsion(0.25), tol=1e-10)
    np.testing.assert_allclose(res.pressure, ref.pressure, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("argv", [["fig1", "--n", "64"], ["make-reference", "--n", "64", "--zetas", "hard"]])
def test_unwritable_out_fails_before_any_work(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.setattr(gfmd_ref, "solve_contact", lambda *a, **k: (_ for _ in ()).throw(AssertionError("ran")))
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(argv + ["--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err
    assert "out_dir" in err and "not a writable folder" in err and "Traceback" not in err


def test_gfmd_ref_unwritable_out_and_bad_n(tmp_path, capsys, monkeypatch):
    import gfmd_ref.cli as gcli

    monkeypatch.setattr(gcli, "solve_contact", lambda *a, **k: (_ for _ in ()).throw(AssertionError("ran")))
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert gfmd_main(["run", "--n", "16", "--out", str(blocker / "sub")]) == 2
    assert "out_dir" in capsys.readouterr().err
    for n in ("0", "1", "-4"):
        assert gfmd_main(["run", "--n", n, "--out", str(tmp_path)]) == 2
        assert "n must be an integer >= 2" in capsys.readouterr().err


def test_fig1_bad_zetas_fail_before_any_gfmd(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(gfmd_ref, "solve_contact", lambda *a, **k: (_ for _ in ()).throw(AssertionError("ran")))
    for bad in ("0.25,-1", "0.25,abc", "nan", "hard"):
        with pytest.raises(SystemExit) as exc:
            main(["fig1", "--n", "64", "--zetas", bad, "--out", str(tmp_path)])
        assert exc.value.code == 2
        assert "--zetas" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["fig1", "--n", "64", "--cutoff", "muser", "--backend", "nope", "--out", str(tmp_path)])
    assert exc.value.code == 2 and "--backend" in capsys.readouterr().err


def test_make_reference_never_writes_into_the_package_by_default(tmp_path, monkeypatch):
    from diffusion_pr.jobs.reference_data import DATA_DIR, generate_reference

    action = next(a for a in _subparsers(_parser())["make-reference"]._actions if a.dest == "out")
    assert action.default == "reference_out"
    monkeypatch.chdir(tmp_path)
    before = sorted(p.name for p in DATA_DIR.iterdir())
    written = generate_reference(zetas=(None,), seeds=(3,), n=64, progress=False, log=lambda s: None)
    assert [p.parent.resolve() for p in written] == [(tmp_path / "reference_out").resolve()]
    assert sorted(p.name for p in DATA_DIR.iterdir()) == before
    with pytest.raises(ValueError, match="out_dir"):
        generate_reference(zetas=(None,), out_dir=None)


def test_theory_writes_its_curve_as_csv(tmp_path, capsys):
    out = tmp_path / "curve.csv"
    assert main(["theory", "--zeta", "0.25", "--cutoff", "smoothstep", "--p-c", "0.0027", "--rtol", "1e-4",
                 "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    zero_weight = float(re.search(r"zero_weight = ([0-9.e+-]+)", lines[0]).group(1))
    assert lines[1] == "p,density,cdf"
    data = np.loadtxt(out, delimiter=",", skiprows=2)
    p, dens, cdf = data.T
    # the same solve from Python: identical arrays (12 significant digits in the file)
    s = diffusion_pr.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    r = diffusion_pr.pressure_distribution(s, E_star=8 / 3, mean_pressure=0.004, zeta=0.25, cutoff="smoothstep",
                                           p_c=0.0027, rtol=1e-4)
    np.testing.assert_allclose(p, r.p, rtol=1e-11)
    np.testing.assert_allclose(dens, r.density, rtol=1e-11, atol=1e-300)
    assert zero_weight == pytest.approx(r.zero_weight, rel=1e-11, abs=1e-300)
    np.testing.assert_allclose(cdf, r.cdf(r.p), rtol=1e-11)
    assert np.all(np.diff(cdf) >= -1e-15) and cdf[-1] <= r.mass * (1 + 1e-11)  # 12 digits in the file
    assert main(["theory", "--out", str(tmp_path / "missing" / "c.csv")]) == 2


def test_theory_takes_a_users_surface_load_and_closure_and_prints_the_contact_area(capsys):
    """Oracles: at the hard wall Persson's a_r = erf(p0/sqrt(2 V0)) with V0 = (E*/2)^2 gbar^2 exactly; the
    log-normal gap closure's a_r = P(p > 0.01 p0) = Phi((ln p0 - s^2/2 - ln(0.01 p0))/s), s^2 = V/p0^2."""
    from math import erf, log, pi, sqrt

    from scipy.special import ndtr

    surface = ["--hurst", "0.7", "--rms-slope", "0.05", "--length", "1", "--n-waves", "100"]
    assert main(["theory", *surface, "--E-star", "2", "--mean-pressure", "0.01", "--closure", "second_order"]) == 0
    a_r = float(re.search(r"contact area a_r = ([0-9.e+-]+)", capsys.readouterr().out).group(1))
    assert a_r == pytest.approx(erf(0.01 / sqrt(2 * 0.05**2)), rel=1e-5)  # 6 digits printed
    assert main(["theory", *surface, "--mean-pressure", "0.01", "--zeta", "0.002", "--closure",
                 "lognormal_gap"]) == 0
    a_r = float(re.search(r"contact area a_r = ([0-9.e+-]+)", capsys.readouterr().out).group(1))
    spec = diffusion_pr.SelfAffineSpectrum(0.7, 2 * pi, 200 * pi, rms_slope=0.05)
    s = sqrt(diffusion_pr.stress_variance(spec, E_star=8 / 3, mean_pressure=0.01, zeta=0.002)) / 0.01
    assert a_r == pytest.approx(float(ndtr((-s * s / 2 - log(0.01)) / s)), rel=1e-5)
    assert main(["theory", "--closure", "lognormal_gap", "--zeta", "1", "--cutoff", "muser", "--p-c", "0.001"]) == 2
