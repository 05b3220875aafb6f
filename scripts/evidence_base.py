"""Evidence base beyond the Fig. 1 scene: GFMD ensembles over H, spectral breadth, load and wall.

One command regenerates everything (about 35 min on 2 cores)::

    python scripts/evidence_base.py all            # design, GFMD, resolution check, summary, dev table

Steps (each can be run alone): ``design`` writes ``data/evidence/design.json`` (the scene grid and its split into
development and held-out scenes, fixed before any GFMD number is looked at); ``run`` solves every case into the
store (``evidence_out/``, gitignored; resumable); ``resolution`` solves a few development scenes with the
shortest wavelength on twice the grid points; ``summarize`` writes ``data/evidence/summary.json`` (per scene and
seed: contact area at the solver's threshold, mean, and 129 pressure quantiles); ``measure`` compares the
package's theories with the DEVELOPMENT scenes only (the ``dev_table`` of the summary and a Markdown table);
``decide`` compares them with the HELD-OUT scenes by :data:`DECISION_RULE` (``held_out_table`` and ``decision``
in the summary).

Units: lengths in grid spacings (``L = n``), pressures in units of ``E* = 1``; the surfaces have rms slope 0.1,
so a load ``p0 / (E* gbar)`` is ``10 p0``.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data" / "evidence"
STORE = ROOT / "evidence_out"
E_STAR, RMS_SLOPE = 1.0, 0.1
HURSTS = (0.3, 0.5, 0.8)
GRID = {16: 256, 32: 256, 100: 800}          # breadth q_s/q_r -> grid n (lambda_s = n / breadth points)
LOADS = (5e-4, 1e-2, 0.25)                   # p0 / (E* gbar)
WALLS = (None, 1e-4, 4e-3, 0.125)            # hard, zeta / lambda_s
SEEDS = "1-16"
HELD_OUT = ((0.3, 32), (0.5, 100), (0.8, 16))  # (H, breadth): a Latin square, every H and breadth once
CUT = ((100, 0.25),)                         # (breadth, load) left out: ccg/newton stall at 800^2, pk 12 s a solve
RESOLUTION = dict(hurst=(0.5, 0.8), breadth=32, n_fine=512, seeds="1-8")
#: the hard wall at the smallest load on held-out scenes with lambda_s on 2x and 4x the grid points (GFMD only:
#: how far the area there is from converged; no theory is chosen on it)
RESOLUTION_HELD_OUT = dict(pairs=((0.8, 16), (0.3, 32)), n=(512, 1024), load=LOADS[0], seeds="1-16")
N_LEVELS = 129                               # quantile levels kept per seed in the summary
CLOSURES = ("second_order", "lognormal_gap", "local_g1", "local_g1_balanced", "local_g1_shell_balanced",
            "yang_persson", "wang_muser", "sum_rule")
#: fixed before any theory met a held-out scene (committed with the step that measures them)
DECISION_RULE = (
    "On the held-out scenes only: per closure, the contact-area error a_r(theory)/a_r(GFMD) - 1 at the hard wall "
    "(goal: within 3 %) and K/noise over p >= p0/20 at every wall (goal: K <= 2 noise). The default closure is the "
    "parameter-free closure (yang_persson and wang_muser carry fitted constants and are not candidates) with the "
    "smallest median K/noise over all held-out scene points (among those defined and solved at every point); ties "
    "(medians within 10 %) go to the cheaper closure.")
#: fixed after the rule above was applied and before sum_rule (built on development scenes only) met a held-out scene
HARD_WALL_RULE = (
    "At the hard wall (zeta = 0) the default is sum_rule instead of Persson's mirror Gaussian if, on the held-out "
    "hard-wall points, its median K/noise (p >= p0/20) and its median |a_r(theory)/a_r(GFMD) - 1| are both smaller "
    "than Persson's.")


def scenes() -> list:
    """Every scene point of the design: dict(hurst, breadth, n, load, p0, wall, zeta, split)."""
    out = []
    for H in HURSTS:
        for b, n in GRID.items():
            for load in LOADS:
                if (b, load) in CUT:
                    continue
                for w in WALLS:
                    out.append(dict(hurst=H, breadth=b, n=n, load=load, p0=load * E_STAR * RMS_SLOPE, wall=w,
                                    zeta=None if w is None else w * n / b,
                                    split="held_out" if (H, b) in HELD_OUT else "dev"))
    return out


def scene_id(s: dict) -> str:
    wall = "hard" if s["wall"] is None else f"z{s['wall']:g}"
    return f"H{s['hurst']:g}_b{s['breadth']}_n{s['n']}_load{s['load']:g}_{wall}"


def git_rev() -> str:
    out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--", "diffusion_pr", "gfmd_ref",
                            "scripts"], capture_output=True, text=True).stdout.strip()
    return out.stdout.strip() + ("+dirty" if dirty else "")


def write_design() -> dict:
    d = dict(units="lengths in grid spacings (L = n), pressures in units of E* = 1",
             E_star=E_STAR, rms_slope=RMS_SLOPE, hursts=HURSTS, breadth_to_grid=GRID,
             loads_p0_over_Estar_gbar=LOADS, walls_zeta_over_lambda_s=["hard" if w is None else w for w in WALLS],
             seeds=SEEDS, held_out_hurst_breadth=HELD_OUT, left_out_breadth_load=CUT, resolution_check=RESOLUTION,
             split_rule="held-out: the (H, breadth) pairs of held_out_hurst_breadth (one per H and per breadth); "
                        "development: the other six pairs. No theory is compared with a held-out scene here.",
             scenes=[dict(s, id=scene_id(s)) for s in scenes()])
    DATA.mkdir(parents=True, exist_ok=True)
    (DATA / "design.json").write_text(json.dumps(d, indent=1) + "\n")
    return d


def _surface(H: float, b: int):
    import gfmd_ref
    return gfmd_ref.EnsembleSurface(hurst=H, rms_slope=RMS_SLOPE, n_waves=b)


def _store(H: float, b: int, n: int) -> Path:
    return STORE / f"H{H:g}_b{b}_n{n}"


def run(workers: int = 2, seeds: str = SEEDS, only=None) -> None:
    """Solve every case of the design into the store (cases already there are skipped)."""
    import gfmd_ref
    cmd = "python scripts/evidence_base.py run"
    for H in HURSTS:
        for b, n in GRID.items():
            if only is not None and (H, b) not in only:
                continue
            loads = [x for x in LOADS if (b, x) not in CUT]
            walls = ["hard" if w is None else w * n / b for w in WALLS]
            t = time.time()
            gfmd_ref.run_ensemble(_store(H, b, n), n=n, seeds=seeds, walls=walls,
                                  mean_pressures=[x * E_STAR * RMS_SLOPE for x in loads], surface=_surface(H, b),
                                  E_star=E_STAR, workers=workers, threads_per_worker=1, progress=False,
                                  verbose=False, command=cmd)
            print(f"H={H} breadth={b} n={n}: {time.time() - t:.0f} s", flush=True)
    top_up(workers)


def top_up(workers: int = 2, spare: int = 8) -> None:
    """Scenes with fewer than 16 converged seeds (a stalled solve is kept in the store and excluded from the pool)
    get the next seeds, one at a time, up to ``spare`` more."""
    import gfmd_ref
    for s in scenes():
        for extra in range(17, 17 + spare):
            g = _group(s)
            if g.n_seeds >= 16:
                break
            gfmd_ref.run_ensemble(_store(s["hurst"], s["breadth"], s["n"]), n=s["n"], seeds=[extra],
                                  walls=["hard" if s["zeta"] is None else s["zeta"]], mean_pressures=[s["p0"]],
                                  surface=_surface(s["hurst"], s["breadth"]), E_star=E_STAR, serial=True,
                                  progress=False, verbose=False, command="python scripts/evidence_base.py run")


def resolution(workers: int = 2) -> None:
    """Development scenes of RESOLUTION at twice the grid points per shortest wavelength (8 seeds)."""
    import gfmd_ref
    b, n = RESOLUTION["breadth"], RESOLUTION["n_fine"]
    for H in RESOLUTION["hurst"]:
        gfmd_ref.run_ensemble(_store(H, b, n), n=n, seeds=RESOLUTION["seeds"],
                              walls=["hard" if w is None else w * n / b for w in WALLS[:3]],
                              mean_pressures=[x * E_STAR * RMS_SLOPE for x in LOADS], surface=_surface(H, b),
                              E_star=E_STAR, workers=workers, threads_per_worker=1, progress=False, verbose=False,
                              command="python scripts/evidence_base.py resolution")


def resolution_held_out(workers: int = 2) -> list:
    """RESOLUTION_HELD_OUT: solve it into the store and return one row per scene (contact area per grid)."""
    import gfmd_ref
    r, rows = RESOLUTION_HELD_OUT, []
    for H, b in r["pairs"]:
        s = dict(hurst=H, breadth=b, n=GRID[b], load=r["load"], p0=r["load"] * E_STAR * RMS_SLOPE, wall=None)
        for n in r["n"]:
            gfmd_ref.run_ensemble(_store(H, b, n), n=n, seeds=r["seeds"], walls=["hard"], mean_pressures=[s["p0"]],
                                  surface=_surface(H, b), E_star=E_STAR, workers=workers, threads_per_worker=1,
                                  progress=False, verbose=False, command="python scripts/evidence_base.py resolution")
        ar = {n: np.array([x.contact_fraction for x in _group(s, n).records]) for n in (GRID[b], *r["n"])}
        rows.append(dict(id=scene_id(s), points_per_lambda_s=[n / b for n in ar],
                         contact_area=[_sig(a.mean(), 5) for a in ar.values()],
                         contact_area_se=[_sig(a.std(ddof=1) / np.sqrt(a.size), 3) for a in ar.values()],
                         n_seeds=[int(a.size) for a in ar.values()]))
    return rows


def _group(s: dict, n: int = None):
    import gfmd_ref
    n = s["n"] if n is None else n
    ens = gfmd_ref.load_ensemble(_store(s["hurst"], s["breadth"], n))
    return ens.group(zeta=None if s["wall"] is None else s["wall"] * n / s["breadth"], mean_pressure=s["p0"], n=n)


def mean_spectrum(group):
    """Average power per lattice shell over the group's seeds: the expected spectrum of the pooled ensemble."""
    from diffusion_pr import DiscreteSpectrum
    recs = list(group.records)
    qs = np.unique(np.concatenate([np.asarray(r.spectrum_q, float) for r in recs]))
    power, mult = np.zeros(qs.size), np.ones(qs.size, dtype=np.int64)
    for r in recs:
        idx = np.searchsorted(qs, np.asarray(r.spectrum_q, float))
        power[idx] += np.asarray(r.spectrum_power, float)
        mult[idx] = np.maximum(mult[idx], np.asarray(r.spectrum_multiplicity))
    return DiscreteSpectrum(qs, power / len(recs), mult, float(recs[0].length))


def persson_variance(group) -> float:
    """Persson's full-contact stress variance ``V0 = (E*/2)^2 sum q^2 |h~|^2`` of the mean spectrum [E*^2]."""
    sp = mean_spectrum(group)
    return float((E_STAR / 2) ** 2 * np.sum(np.asarray(sp.q) ** 2 * np.asarray(sp.power)))


def _sig(x: float, d: int = 4) -> float:
    return float(f"{x:.{d}g}")


def summarize() -> dict:
    """Per scene: seeds (contact area, mean, sd, skewness), pooled quantiles of p/p0, noise; the resolution check."""
    from diffusion_pr.compare import compare_ensemble

    class _Zero:  # a CDF that is 0 everywhere: compare_ensemble's noise does not depend on the theory
        mean_pressure = 0.0

        @staticmethod
        def cdf(p):
            return np.zeros_like(np.asarray(p, dtype=float))

    levels = np.linspace(0.0, 1.0, N_LEVELS)
    out = []
    for s in scenes():
        g = _group(s)
        recs, p0 = list(g.records), s["p0"]
        pooled = np.quantile(np.concatenate([np.interp(np.linspace(0, 1, 4097), r.levels, r.quantiles)
                                             for r in recs]), levels) / p0
        noise = {k: compare_ensemble(_Zero, recs, p_min=pm, n_boot=200, n_split=2).noise_bootstrap
                 for k, pm in (("p0_20", p0 / 20), ("all", 0.0))}
        ar = np.array([r.contact_fraction for r in recs])
        out.append(dict(id=scene_id(s), **{k: s[k] for k in ("hurst", "breadth", "n", "load", "p0", "wall", "zeta",
                                                               "split")},
                        threshold=recs[0].contact_threshold, n_excluded=g.n_excluded,
                        contact_area=_sig(ar.mean(), 6), contact_area_se=_sig(ar.std(ddof=1) / np.sqrt(ar.size), 3),
                        V0=_sig(persson_variance(g), 8),
                        noise_bootstrap={k: _sig(v, 3) for k, v in noise.items()},
                        seeds=[dict(seed=r.seed, contact_area=_sig(r.contact_fraction, 6),
                                    mean_over_p0=_sig(r.mean / p0), sd_over_p0=_sig(r.sd / p0),
                                    skewness=_sig(r.skewness, 3)) for r in recs],
                        pooled_quantiles_over_p0=[_sig(v) for v in pooled]))
    res = []
    for H in RESOLUTION["hurst"]:
        for load in LOADS:
            for w in WALLS[:3]:
                s = dict(hurst=H, breadth=RESOLUTION["breadth"], n=GRID[RESOLUTION["breadth"]], load=load,
                         p0=load * E_STAR * RMS_SLOPE, wall=w)
                lo, hi = (int(x) for x in RESOLUTION["seeds"].split("-"))
                seeds = range(lo, hi + 1)
                ar = [float(np.mean([r.contact_fraction for r in _group(s, n).records if r.seed in seeds]))
                      for n in (s["n"], RESOLUTION["n_fine"])]
                res.append(dict(id=scene_id(s), n=[s["n"], RESOLUTION["n_fine"]],
                                points_per_lambda_s=[s["n"] / s["breadth"], RESOLUTION["n_fine"] / s["breadth"]],
                                contact_area_8_seeds=[_sig(a, 5) for a in ar],
                                relative_change=_sig(ar[1] / ar[0] - 1, 3)))
    res_held = resolution_held_out()
    summ = dict(provenance=dict(code=git_rev(), command="python scripts/evidence_base.py all",
                                created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())),
                design="data/evidence/design.json", levels=N_LEVELS, scenes=out, resolution=res,
                resolution_held_out=res_held)
    (DATA / "summary.json").write_text(json.dumps(summ, separators=(",", ":")) + "\n")
    return summ


def theories(s: dict, group) -> dict:
    """Every shipped closure for a scene (``None`` where a closure is not defined there)."""
    import warnings

    import diffusion_pr as dp
    sp = mean_spectrum(group)
    out = {}
    for cl in CLOSURES:
        if cl == "lognormal_gap" and s["wall"] is None or cl == "local_g1" and s["wall"] == WALLS[1]:
            out[cl] = None  # lognormal_gap: not defined at the hard wall; local_g1: minutes per solve there
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                out[cl] = dp.pressure_distribution(sp, E_star=E_STAR, mean_pressure=s["p0"],
                                                   zeta=0.0 if s["zeta"] is None else s["zeta"], closure=cl)
        except ValueError:
            out[cl] = None
    return out


def measure_scene(s: dict) -> dict:
    """One development scene: every closure's contact area and K (p >= p0/20 and all p) with the noise
    (cached in the store)."""
    from diffusion_pr.compare import compare_ensemble
    f = STORE / "theory" / f"{scene_id(s)}.json"
    if f.exists():
        return json.loads(f.read_text())
    g = _group(s)
    t0 = time.time()
    row = dict(id=scene_id(s), **{k: s[k] for k in ("hurst", "breadth", "n", "load", "p0", "wall", "zeta")},
               n_seeds=g.n_seeds, theory={})
    for cl, th in theories(s, g).items():
        if th is None:
            continue
        try:
            c = {k: compare_ensemble(th, g, p_min=pm, n_boot=200, n_split=20) for k, pm in
                 (("p0_20", s["p0"] / 20), ("all", 0.0))}
        except Exception as exc:  # a result whose CDF cannot be evaluated: recorded, not hidden
            row["theory"][cl] = dict(error=f"{type(exc).__name__}: {exc}")
            continue
        row["contact_area_gfmd"] = c["all"].contact_fraction_gfmd
        row["contact_area_se"] = c["all"].contact_fraction_gfmd_sd / np.sqrt(g.n_seeds)
        row["noise"] = {k: v.noise_bootstrap for k, v in c.items()}
        row["theory"][cl] = dict(contact_area=c["all"].contact_fraction_theory,
                                 K={k: v.kolmogorov for k, v in c.items()})
    row["seconds"] = time.time() - t0
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_text(json.dumps(row))
    print(row["id"], f"{row['seconds']:.0f} s", flush=True)
    return row


def measure(split: str = "dev") -> list:
    """Theory against GFMD on the scenes of ``split``; the table goes into the summary."""
    rows = [measure_scene(s) for s in scenes() if s["split"] == split]
    summ = json.loads((DATA / "summary.json").read_text())
    summ["dev_table" if split == "dev" else "held_out_table"] = [_round(r) for r in rows]
    if split == "held_out":
        summ["decision"] = decision(rows)
    (DATA / "summary.json").write_text(json.dumps(summ, separators=(",", ":")) + "\n")
    return rows


def decision(rows: list) -> dict:
    """:data:`DECISION_RULE` applied to held-out rows: per closure the median and maximum K/noise, the worst
    hard-wall contact-area error, and the chosen default."""
    out = {"rule": DECISION_RULE, "closures": {}}
    for cl in CLOSURES:
        ratios = [r["theory"][cl]["K"]["p0_20"] / r["noise"]["p0_20"] for r in rows if "K" in r["theory"].get(cl, {})]
        area = [r["theory"][cl]["contact_area"] / r["contact_area_gfmd"] - 1 for r in rows
                if r["wall"] is None and "K" in r["theory"].get(cl, {})]
        if ratios:
            out["closures"][cl] = dict(points=len(ratios), median_K_over_noise=_sig(float(np.median(ratios)), 3),
                                       max_K_over_noise=_sig(max(ratios), 3),
                                       within_2_noise=sum(x <= 2 for x in ratios),
                                       hard_wall_area_error=[_sig(a, 3) for a in area])
    cost = ("second_order", "lognormal_gap", "local_g1", "local_g1_balanced", "local_g1_shell_balanced")
    cand = {c: v["median_K_over_noise"] for c, v in out["closures"].items()
            if c not in ("yang_persson", "wang_muser") and v["points"] == len(rows)}
    best = min(cand.values())
    out["default"] = next(c for c in cost if c in cand and cand[c] <= 1.1 * best)
    hard = [r for r in rows if r["wall"] is None]

    def medians(c):
        return (np.median([r["theory"][c]["K"]["p0_20"] / r["noise"]["p0_20"] for r in hard]),
                np.median([abs(r["theory"][c]["contact_area"] / r["contact_area_gfmd"] - 1) for r in hard]))
    if "sum_rule" in out["closures"]:
        out["hard_wall_rule"] = HARD_WALL_RULE
        wins = all(a < b for a, b in zip(medians("sum_rule"), medians("second_order")))
        out["hard_wall_default"] = "sum_rule" if wins else "second_order"
    return out


def _round(r: dict) -> dict:
    def rnd(v):
        return {k: rnd(x) for k, x in v.items()} if isinstance(v, dict) else _sig(v, 7) if isinstance(v, float) else v
    return {k: rnd(v) for k, v in r.items() if k != "seconds"}


def markdown(rows: list) -> str:
    """The development tables: contact areas (GFMD +- se, theories) and K over p >= p0/20 with the noise beside
    it; for the hard wall also K over all p (where the contact area enters)."""
    def ar(t, c):
        return f"{t[c]['contact_area']:.3g}" if "K" in t.get(c, {}) else ("err" if c in t else "-")

    def K(t, c, k="p0_20"):
        return f"{t[c]['K'][k]:.3f}" if "K" in t.get(c, {}) else ("err" if c in t else "-")

    cls = ("second_order", "lognormal_gap", "local_g1", "local_g1_balanced", "local_g1_shell_balanced")
    lines = ["| H | q_s/q_r | load | wall | a_r GFMD | a_r: 2nd | bal | shell | noise | K: 2nd | logn | g1 | bal "
             "| shell |", "|" + "---|" * 14]
    for r in rows:
        t = r["theory"]
        wall = "hard" if r["wall"] is None else f"{r['wall']:g}"
        lines.append(f"| {r['hurst']} | {r['breadth']} | {r['load']:g} | {wall} | {r['contact_area_gfmd']:.3g} "
                     f"± {r['contact_area_se']:.1g} | " + " | ".join(ar(t, c) for c in cls[::2][:1] + cls[3:])
                     + f" | {r['noise']['p0_20']:.4f} | " + " | ".join(K(t, c) for c in cls) + " |")
    hard = ("second_order", "sum_rule", "yang_persson", "wang_muser")
    lines += ["", "| H | q_s/q_r | load | a_r GFMD | Persson | a_r error: Persson | sum_rule | yang_persson | "
              "wang_muser | noise (p0/20) | K: Persson | sum_rule | yang_persson | wang_muser |", "|" + "---|" * 14]
    for r in (r for r in rows if r["wall"] is None):
        a, t = r["contact_area_gfmd"], r["theory"]
        err = [f"{100 * (t[c]['contact_area'] / a - 1):+.1f} %" if "K" in t.get(c, {}) else "-" for c in hard]
        lines.append(f"| {r['hurst']} | {r['breadth']} | {r['load']:g} | {a:.4g} ± {r['contact_area_se']:.1g} | "
                     f"{t['second_order']['contact_area']:.4g} | " + " | ".join(err) +
                     f" | {r['noise']['p0_20']:.4f} | " + " | ".join(K(t, c, "p0_20") for c in hard) + " |")
    return "\n".join(lines)

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("step", choices=["design", "run", "resolution", "summarize", "measure", "decide", "all"])
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    if a.step in ("design", "all"):
        write_design()
    if a.step in ("run", "all"):
        run(a.workers)
    if a.step in ("resolution", "all"):
        resolution(a.workers)
        print(json.dumps(resolution_held_out(a.workers), indent=1))
    if a.step in ("summarize", "all"):
        summarize()
    if a.step in ("measure", "all"):
        print(markdown(measure()))
    if a.step in ("decide", "all"):
        print(markdown(measure("held_out")))
        print(json.dumps(json.loads((DATA / "summary.json").read_text())["decision"], indent=1))
