"""Benchmark of ``diffusion_pr.cumulants.stress_variance`` (and V(eta), D(eta)).

Target (issue 3): 100 values of ``zeta`` for a continuum spectrum in under
10 ms. Prints a table of median wall times (``time.perf_counter``, many
repeats after one warm-up call) and, for the continuum, the accuracy of the
fixed Gauss-Legendre rule against adaptive ``scipy.integrate.quad``.

Run: ``python benchmarks/bench_variance.py``
"""
from __future__ import annotations

import math
import statistics
import time

import numpy as np
from scipy.integrate import quad

from diffusion_pr.cumulants import diffusivity_vs_magnification, stress_variance, variance_vs_magnification
from diffusion_pr.spectra import DiscreteSpectrum, SelfAffineSpectrum

E_STAR, P0 = 8.0 / 3.0, 0.004


def median_time(fn, repeats: int = 50) -> float:
    fn()  # warm-up (caches the quadrature rule)
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def surface(n: int, length: float, spec: SelfAffineSpectrum, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = np.fft.fft2(rng.standard_normal((n, n))) / n
    k = np.fft.fftfreq(n, d=1.0 / n)
    q = 2 * np.pi / length * np.hypot(k[:, None], k[None, :])
    ht = noise * np.sqrt(spec.psd(q)) * (2 * np.pi / length)
    ht[0, 0] = 0
    return np.fft.ifft2(ht * n * n).real


def quad_ref(s: SelfAffineSpectrum, z: float) -> float:
    def f(t):
        q = math.exp(t)
        g = 1 / (1 + z * q * E_STAR / (2 * P0))
        return (E_STAR / 2) ** 2 * 2 * math.pi * q**4 * float(s.psd(q)) * g * g

    out = 0.0
    for lo, hi in ((s.q_min, s.q_roll), (s.q_roll, s.q_max)):
        if hi > lo:
            out += quad(f, math.log(lo), math.log(hi), epsabs=0, epsrel=1e-13, limit=500)[0]
    return out


def main() -> None:
    zetas = np.geomspace(1e-4, 10.0, 100)
    fig1 = SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    wide = SelfAffineSpectrum(0.8, 1e-4, 1.0, rms_slope=0.1, q_roll=1e-3)
    rows = []
    for name, s in (("continuum Fig.1 (mag 32)", fig1), ("continuum mag 1e4, roll-off", wide)):
        n_nodes = s.quadrature()[0].size
        t = median_time(lambda s=s: stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=zetas))
        v = stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=zetas)
        sub = zetas[::11]
        err = max(abs(v[::11][i] / quad_ref(s, z) - 1) for i, z in enumerate(sub))
        rows.append((f"stress_variance, 100 zeta, {name}", n_nodes, t, err))
    for n in (256, 1024):
        d = DiscreteSpectrum.from_heights(surface(n, float(n), fig1), float(n))
        t = median_time(lambda d=d: stress_variance(d, E_star=E_STAR, mean_pressure=P0, zeta=zetas), repeats=20)
        rows.append((f"stress_variance, 100 zeta, discrete {n}x{n} (Fig.1 band)", d.q.size, t, float("nan")))
    dw = DiscreteSpectrum.from_heights(np.random.default_rng(2).standard_normal((1024, 1024)), 1024.0)
    t = median_time(lambda: stress_variance(dw, E_star=E_STAR, mean_pressure=P0, zeta=zetas), repeats=5)
    rows.append(("stress_variance, 100 zeta, discrete 1024x1024 white noise", dw.q.size, t, float("nan")))
    cold = []
    for _ in range(20):
        s = SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
        t0 = time.perf_counter()
        stress_variance(s, E_star=E_STAR, mean_pressure=P0, zeta=zetas)
        cold.append(time.perf_counter() - t0)
    rows.insert(1, ("  same, cold (new spectrum: builds the rule)", fig1.quadrature()[0].size, statistics.median(cold), float("nan")))
    h = surface(1024, 1024.0, fig1)
    t = median_time(lambda: DiscreteSpectrum.from_heights(h, 1024.0), repeats=5)
    rows.append(("DiscreteSpectrum.from_heights 1024x1024", 1024 * 1024, t, float("nan")))
    eta = np.linspace(1, 32, 1000)
    t = median_time(lambda: variance_vs_magnification(fig1, eta, E_star=E_STAR, mean_pressure=P0, zeta=0.25))
    rows.append(("variance_vs_magnification, 1000 eta, continuum", fig1.quadrature()[0].size, t, float("nan")))
    t = median_time(lambda: diffusivity_vs_magnification(fig1, eta, E_star=E_STAR, mean_pressure=P0, zeta=0.25))
    rows.append(("diffusivity_vs_magnification, 1000 eta, continuum", 0, t, float("nan")))

    print(f"{'case':<58} {'nodes/shells':>12} {'median':>11} {'max rel err vs quad':>20}")
    for name, n_nodes, t, err in rows:
        err_s = "" if math.isnan(err) else f"{err:.1e}"
        print(f"{name:<58} {n_nodes:>12d} {t * 1e3:>8.3f} ms {err_s:>20}")
    target = rows[0][2]
    print(f"\ntarget: 100 zeta (continuum) < 10 ms -> {'PASS' if target < 10e-3 else 'FAIL'} ({target * 1e3:.3f} ms)")


if __name__ == "__main__":
    main()
