"""What a result shows is what the solver vouches for: pdf, cdf and error_estimate against exact solutions.

Oracles: the closed forms (mirror Gaussian ``N(p; p0, V) - N(p; -p0, V)``, Feller's ``f = p``, a Gaussian far
from the wall), evaluated by :mod:`diffusion_pr.closed_forms` and, for their cdfs, by scipy's quadrature.
Bars (the result contract): the L1 distance of ``pdf`` at most ``10 rtol``; ``error_estimate`` within a
factor 10 of it either way; the largest density within 1 % of the exact maximum; the probability of any interval
within ``rtol``.  Measured on native (ratios L1 / estimate 0.32 to 0.52; the linear interpolation of cell averages
it replaces had 50 to 2e11)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

import diffusion_pr as dp
from diffusion_pr.closed_forms import feller_density, mirror_gaussian_density, persson_zero_weight
from diffusion_pr.fokker_planck.backends.closed_form import ExactSolution
from diffusion_pr.models import ProportionalDiffusivity

STEP = lambda p: np.where(p > 0, 1.0, 0.0)  # noqa: E731  (a callable the engine probes: f = 1, wall at 0)
PROBLEMS = {  # name: (p0, V, diffusivity, exact continuous part)
    "mirror": (0.3, 0.5, STEP, ExactSolution("mirror", 0.3, 0.25, 1.0)),
    "feller": (1.0, 1.0, ProportionalDiffusivity(1.0), ExactSolution("feller", 1.0, 0.5, 1.0)),
    "gaussian": (1.0, 0.01, STEP, ExactSolution("mirror", 1.0, 0.005, 1.0)),
}


def distances(r, exact, top):
    """``(L1 of pdf - exact, largest pdf / exact maximum, largest error of an interval's probability)``:
    16-point Gauss-Legendre on each cell (on 4000 uniform panels for a closed form) plus the exact mass outside."""
    edges = r.edges if r.edges is not None else np.linspace(0.0, top, 4001)
    x, w = np.polynomial.legendre.leggauss(16)
    a, b = edges[:-1, None], edges[1:, None]
    q, wq = (0.5 * (b - a) * x + 0.5 * (a + b)).ravel(), (0.5 * (b - a) * w).ravel()
    outside = float(exact.cdf(edges[0]) + exact.cdf(np.inf) - exact.cdf(edges[-1]))
    l1 = float(np.sum(wq * np.abs(r.pdf(q) - exact.pdf(q)))) + outside
    grid = np.concatenate((q, edges))
    mismatch = r.cdf(grid) - r.zero_weight - exact.cdf(grid)
    return l1, float(np.max(r.pdf(grid)) / np.max(exact.pdf(grid))), float(np.ptp(mismatch))


@pytest.mark.parametrize("name", list(PROBLEMS))
@pytest.mark.parametrize("rtol", [1e-4, 1e-6, 1e-8])
def test_native_pdf_and_estimate_meet_the_bars(name, rtol):
    p0, V, f, exact = PROBLEMS[name]
    r = dp.propagate(p0, V, diffusivity=f, rtol=rtol, backend="native")
    l1, peak, interval = distances(r, exact, None)
    assert r.success and l1 <= 10 * rtol and 0.1 <= l1 / r.error_estimate <= 10, (l1, r.error_estimate)
    assert abs(peak - 1.0) <= 0.01 and interval <= rtol
    assert abs(r.zero_weight - (1.0 - float(exact.cdf(np.inf)))) <= rtol


@pytest.mark.parametrize("name", list(PROBLEMS))
def test_closed_form_pdf_is_exact(name):
    p0, V, f, exact = PROBLEMS[name]
    r = dp.propagate(p0, V, diffusivity=f if name == "feller" else None, backend="closed_form")
    l1, peak, interval = distances(r, exact, p0 + 20 * np.sqrt(V))
    assert l1 < 1e-12 and abs(peak - 1.0) < 1e-6 and interval < 1e-12


@pytest.mark.parametrize("kind, p0, tau", [("mirror", 0.3, 0.25), ("feller", 1.0, 0.5), ("feller", 0.01, 2.0)])
def test_closed_form_cdf_is_the_integral_of_its_pdf(kind, p0, tau):
    """Marcum's Q for Feller, Gaussian cdfs for the mirror, against scipy's quad of the exact densities."""
    law = ExactSolution(kind, p0, tau, 1.0)
    density = (lambda p: mirror_gaussian_density(p, p0, 2 * tau)) if kind == "mirror" else (
        lambda p: feller_density(p, p0, tau, 1.0))
    for x in (1e-3 * p0, 0.5 * p0, p0, 3 * p0 + 2 * tau):
        integral = quad(density, 0.0, x, epsabs=1e-15, epsrel=1e-13, limit=200)[0]
        assert float(law.cdf(x)) == pytest.approx(integral, abs=1e-13)


def test_feller_density_near_the_wall():
    """f = p from p0 = 1 at tau = 1/2: the density at p = 1e-3 is 0.5413 (it was 0 left of the first node)."""
    expect = float(feller_density(1e-3, 1.0, 0.5, 1.0))
    assert expect == pytest.approx(0.54134, abs=1e-5)
    for backend in ("closed_form", "native"):
        r = dp.propagate(1.0, 1.0, diffusivity=ProportionalDiffusivity(1.0), backend=backend, rtol=1e-6)
        assert float(r.pdf(1e-3)) == pytest.approx(expect, rel=1e-4)


def test_the_pdf_holds_the_contact_mass_of_a_start_at_the_wall():
    """p0 = 1e-6, V = 1: all but 8e-7 is absorbed.  The pdf integrates to that mass (it once gave 3.4e-5, a spike
    in the cells near p0); its L1 error is within rtol (the shape of so small a part is not resolved at rtol 1e-4:
    its peak is 1.7x the exact one)."""
    r = dp.propagate(1e-6, 1.0, rtol=1e-4, backend="native")
    contact = 1.0 - persson_zero_weight(1e-6, 1.0)
    exact = ExactSolution("mirror", 1e-6, 0.5, 1.0)
    l1, _, _ = distances(r, exact, None)
    x, w = np.polynomial.legendre.leggauss(16)
    a, b = r.edges[:-1, None], r.edges[1:, None]
    integral = float(np.sum((0.5 * (b - a) * w) * r.pdf(0.5 * (b - a) * x + 0.5 * (a + b))))
    assert integral == pytest.approx(contact, rel=1e-3) and l1 <= 1e-4


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["pypde", "fipy"])
@pytest.mark.parametrize("name", ["mirror", "feller"])
def test_other_backends_pdf_and_estimate_meet_the_bars(backend, name):
    pytest.importorskip({"pypde": "pde", "fipy": "fipy"}[backend])
    p0, V, f, exact = PROBLEMS[name]
    r = dp.propagate(p0, V, diffusivity=f, rtol=1e-4, backend=backend)
    l1, peak, interval = distances(r, exact, None)
    assert r.success and l1 <= 1e-3 and 0.1 <= l1 / r.error_estimate <= 10, (l1, r.error_estimate)
    assert abs(peak - 1.0) <= 0.01 and interval <= 1e-4
