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
    code = main(["fig1", "--n", "64", "--zetas", "0.25", "--out", str(tmp_path), "--rtol", "1e-4"])
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
