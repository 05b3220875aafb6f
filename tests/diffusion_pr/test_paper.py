"""The paper's constants (diffusion_pr.paper) against the paper's own sentences.

Oracle: the two sentences of Müser, PRL 100, 055504 (2008) quoted in
``diffusion_pr.paper.QUOTES``.  Their SHA-256 digests below were computed from
the project's copy of the paper (not in the repository, so CI pins the text by
digest); every constant is then parsed back out of that text, so changing a
number (e.g. 0.0082 -> 0.0028) or the quote fails here.  The contact threshold
is this project's convention, pinned to the docs page ``gfmd`` and to
``gfmd_ref``'s own copy.
"""
from __future__ import annotations

import hashlib
import io
import math
import re
import tokenize
from pathlib import Path

import numpy as np
import pytest

import gfmd_ref
from diffusion_pr import paper

ROOT = Path(__file__).resolve().parents[2]

SHA256 = {
    "system": "79d2a19a8cf3e5bc503e37ef669b0623ddd532be9bfaef7ad4500031e32071f3",
    "cutoffs": "b937545a79d5e85fbc045b426245bd5d111ba66b4e839e49cf19b9eb5f2f715c",
}


def number(pattern: str, text: str) -> float:
    m = re.search(pattern, text)
    assert m, f"{pattern!r} not found in the quote"
    return float(m.group(1))


def test_quotes_are_the_papers_text():
    for key, digest in SHA256.items():
        assert hashlib.sha256(paper.QUOTES[key].encode()).hexdigest() == digest, key


def test_module_docstring_quotes_the_same_sentences():
    doc = " ".join(paper.__doc__.split()).replace("\\\\", "\\")
    for quote in paper.QUOTES.values():
        assert " ".join(quote.split()) in doc


def test_scene_constants_parse_out_of_the_quote():
    q = paper.QUOTES["system"]
    assert paper.LAMBDA_MIN == number(r"wavelengths \$(\d+) \\leq", q) == 32
    assert paper.LENGTH == number(r"\\lambda \\leq (\d+)\$", q) == 1024
    assert paper.HURST == number(r"\$H = ([\d.]+)\$", q)
    assert paper.RMS_SLOPE == number(r"slope is ([\d.]+)\.", q)
    num, den = re.search(r"E' = (\d+)/(\d+)", q).groups()
    assert paper.E_STAR == float(num) / float(den)
    assert paper.MEAN_PRESSURE == number(r"p_0 = ([\d.]+)\$", q)
    lo, hi = re.search(r"varied between ([\d.]+) and ([\d.]+)\.", q).groups()
    assert paper.ZETA_RANGE == (float(lo), float(hi))
    assert paper.N_WAVES == paper.LENGTH / paper.LAMBDA_MIN
    s = paper.FIG1_SCENE
    assert s["q_max"] / s["q_min"] == pytest.approx(paper.N_WAVES, rel=1e-15)
    assert s["q_min"] == 2 * math.pi / paper.LENGTH and s["length"] == paper.LENGTH


def test_cutoff_pressures_parse_out_of_the_quote():
    q = paper.QUOTES["cutoffs"]
    m = re.search(r"p_c = ([\d.]+)\$ for all curves with \$\\zeta \\geq ([\d.]+)\$", q)
    assert paper.CUTOFF_PRESSURE_LARGE_ZETA == float(m.group(1))
    assert paper.LARGE_ZETA == float(m.group(2))
    m = re.search(r"p_c = ([\d.]+)\$ \[([\d.]+)\] for \$\\zeta = ([\d.]+)\$ \[([\d.]+)\]", q)
    pc_a, pc_b, z_a, z_b = map(float, m.groups())
    assert paper.PAPER_CUTOFF_PRESSURES == {z_a: pc_a, z_b: pc_b, paper.LARGE_ZETA: paper.CUTOFF_PRESSURE_LARGE_ZETA}
    for zeta, p_c in ((z_a, pc_a), (z_b, pc_b), (0.25, 0.0027), (1.0, 0.0027), (4.0, 0.0027)):
        assert paper.cutoff_pressure(zeta) == p_c


def test_cutoff_pressure_between_named_zetas_takes_the_log_nearest():
    # 0.003: |ln(0.003/0.001)| = 1.10 < |ln(0.01/0.003)| = 1.20 -> 0.001's value; 0.004 -> 0.01's;
    # 0.1: |ln(0.25/0.1)| = 0.92 < |ln(0.1/0.01)| = 2.30 -> 0.25's
    assert paper.cutoff_pressure(0.003) == 0.0068
    assert paper.cutoff_pressure(0.004) == 0.0082
    assert paper.cutoff_pressure(0.1) == 0.0027
    for bad in (0.0, -1.0, float("nan"), float("inf"), "0.25", None):
        with pytest.raises(ValueError, match="zeta"):
            paper.cutoff_pressure(bad)


def test_gfmd_ref_keeps_the_same_numbers():
    f = gfmd_ref.FIG1
    assert f["hurst"] == paper.HURST and f["rms_slope"] == paper.RMS_SLOPE
    assert f["E_star"] == paper.E_STAR and f["mean_pressure"] == paper.MEAN_PRESSURE
    assert f["n_waves"] == paper.N_WAVES and f["length"] == paper.LENGTH


def test_contact_threshold_agrees_with_gfmd_ref_and_its_docs():
    from gfmd_ref import EXP_CONTACT_THRESHOLD

    # docs/gfmd.md defines the exponential wall's contact fraction in words:
    text = (ROOT / "docs" / "gfmd.md").read_text()
    documented = number(r"fraction with `pressure > ([\d.]+) p0`", text)
    assert paper.EXP_CONTACT_THRESHOLD == EXP_CONTACT_THRESHOLD == documented == 0.01
    assert paper.contact_threshold(None) == 0.0
    assert paper.contact_threshold(0.25, 0.004) == 0.01 * 0.004


def test_gfmd_contact_fraction_uses_that_threshold():
    # behaviour, not only the constant: count p > 0.01 p0 on a small exponential-wall solve
    h, length = gfmd_ref.fig1_surface(64, seed=3)
    res = gfmd_ref.solve_contact(h, length=length, E_star=paper.E_STAR, mean_pressure=paper.MEAN_PRESSURE,
                                 interaction=gfmd_ref.ExponentialRepulsion(0.002), tol=1e-8)
    p = np.asarray(res.pressure)
    expected = np.count_nonzero(p > paper.contact_threshold(0.002, paper.MEAN_PRESSURE)) / p.size
    assert res.contact_fraction == expected
    # and the threshold matters on this field (else the test could not tell 0.01 from 0.1)
    assert np.count_nonzero(p > 0.1 * paper.MEAN_PRESSURE) / p.size != expected


def _numbers_in_code(path: Path) -> set[str]:
    """Numeric literals of a module, docstrings and comments excluded."""
    toks = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
    return {t.string for t in toks if t.type == tokenize.NUMBER}


def test_the_papers_numbers_live_only_in_paper_py():
    for path in sorted((ROOT / "diffusion_pr").rglob("*.py")):
        if path.name == "paper.py":
            continue
        found = _numbers_in_code(path) & {"0.0027", "0.0082", "0.0068", "0.031"}
        assert not found, f"{path.relative_to(ROOT)} hard-codes {found}; import them from diffusion_pr.paper"


def test_reference_data_cutoffs_by_bundled_zeta():
    from diffusion_pr.jobs.reference_data import PAPER_CUTOFF_PRESSURES

    assert PAPER_CUTOFF_PRESSURES == {0.001: 0.0068, 0.01: 0.0082, 0.25: 0.0027, 0.5: 0.0027, 1.0: 0.0027,
                                      2.0: 0.0027, 4.0: 0.0027}
