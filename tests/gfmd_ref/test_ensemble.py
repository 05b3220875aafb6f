"""Ensemble runner and store: records equal direct solves, on a cluster and serially;
resume after a killed run; a killed worker; bad parameters; non-convergence."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from gfmd_ref import ExponentialRepulsion, HardWall, fig1_surface, load_ensemble, run_ensemble, solve_contact
from gfmd_ref.ensemble.run import build_cases, case_surface
from gfmd_ref.ensemble.store import STORE_LEVELS, case_key, reduce_pressure_field, store_keys

ROOT = Path(__file__).resolve().parents[2]
N = 128
SEEDS = "1-3"
WALLS = "hard,0.25"


@pytest.fixture(scope="module")
def cluster():
    from gfmd_ref.ensemble.run import _local_cluster

    client, cl, _ = _local_cluster(2, 1)
    yield client
    client.close()
    cl.close()


@pytest.fixture(scope="module")
def direct():
    """Direct solve_contact of every case of the small ensemble (the oracle)."""
    out = {}
    for c in build_cases(n=N, seeds=SEEDS, walls=WALLS):
        h, L = fig1_surface(N, c["seed"])
        inter = HardWall() if c["zeta"] is None else ExponentialRepulsion(c["zeta"])
        res = solve_contact(h, length=L, E_star=8 / 3, mean_pressure=0.004, interaction=inter, tol=1e-6)
        out[case_key(c)] = (res, h)
    return out


def _assert_record_is(rec, res, h):
    np.testing.assert_array_equal(rec.quantiles, np.quantile(res.pressure, STORE_LEVELS))
    assert rec.contact_fraction == res.contact_fraction
    assert rec.provenance["iterations"] == res.iterations
    assert rec.provenance["converged"] and res.converged
    assert rec.mean == pytest.approx(float(res.pressure.mean()), rel=1e-14)
    # shell spectrum: Parseval, sum of shell powers = variance of the heights
    assert rec.spectrum_power.sum() == pytest.approx(float(h.var()), rel=1e-12)


def test_cluster_records_equal_direct_solves_and_serial(tmp_path, cluster, direct):
    run = run_ensemble(tmp_path / "dask", n=N, seeds=SEEDS, walls=WALLS, client=cluster, progress=False,
                       verbose=False)
    assert run.success and run.n_computed == 6
    ens = load_ensemble(tmp_path / "dask")
    assert len(ens) == 6
    pids = {r.provenance["pid"] for r in ens}
    assert os.getpid() not in pids  # solved on the workers
    for r in ens:
        _assert_record_is(r, *direct[r.key])
    ser = run_ensemble(tmp_path / "serial", n=N, seeds=SEEDS, walls=WALLS, serial=True, progress=False,
                       verbose=False)
    assert ser.success
    for a, b in zip(ens, load_ensemble(tmp_path / "serial")):
        assert a.key == b.key
        for f in ("quantiles", "hist_counts", "spectrum_power"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
        assert (a.mean, a.sd, a.skewness, a.contact_fraction) == (b.mean, b.sd, b.skewness, b.contact_fraction)


def test_worker_killed_mid_case_is_recovered(tmp_path, cluster):
    """Kill (SIGKILL) a worker process while it is solving a case: the scheduler
    reschedules the case, the store ends complete and equal to a serial run."""
    store = tmp_path / "kill"
    result = {}
    th = threading.Thread(target=lambda: result.setdefault(
        "run", run_ensemble(store, n=N, seeds="1-3", walls="0.01", client=cluster, progress=False, verbose=False)))
    th.start()
    pids = cluster.run(os.getpid)
    victim = None
    t0 = time.time()
    while victim is None and time.time() - t0 < 30:
        for addr, keys in cluster.processing().items():
            if keys and addr in pids:
                victim = (addr, pids[addr], list(keys))
                break
        time.sleep(0.01)
    assert victim is not None, "no case was ever in flight"
    os.kill(victim[1], signal.SIGKILL)
    th.join(120)
    run = result["run"]
    assert run.success and run.n_computed == 3
    ens = load_ensemble(store)
    assert len(ens) == 3 and len({r.key for r in ens}) == 3
    lost = {k.replace("gfmd-case-", "") for k in victim[2]}
    # the case that was in flight on the killed worker was solved again elsewhere
    for r in ens:
        if r.key in lost:
            assert r.provenance["pid"] != victim[1]
    ser = run_ensemble(tmp_path / "ser", n=N, seeds="1-3", walls="0.01", serial=True, progress=False, verbose=False)
    for a, b in zip(ens, load_ensemble(ser.store)):
        np.testing.assert_array_equal(a.quantiles, b.quantiles)


def test_killed_run_resumes_complete_and_duplicate_free(tmp_path):
    store = tmp_path / "resume"
    cmd = [sys.executable, "-m", "gfmd_ref.cli", "ensemble", "--n", str(N), "--seeds", "1-4",
           "--walls", "hard,0.25", "--store", str(store), "--serial", "--no-progress"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    t0 = time.time()
    while len(store_keys(store)) < 2 and time.time() - t0 < 60 and proc.poll() is None:
        time.sleep(0.02)
    proc.kill()
    proc.wait()
    done = len(store_keys(store))
    assert 2 <= done < 8, f"the run was not killed part-way ({done} of 8 finished)"
    # a partially written file is never a record
    (store / ".n128_hard_p0.004_s6__deadbeefdeadbeef.npz.123.tmp").write_bytes(b"partial")
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert f"{done} already in" in out.stdout and f"{8 - done} to run" in out.stdout
    ens = load_ensemble(store)
    expected = {case_key(c) for c in build_cases(n=N, seeds="1-4", walls="hard,0.25")}
    assert {r.key for r in ens} == expected and len(ens) == 8
    again = run_ensemble(store, n=N, seeds="1-4", walls="hard,0.25", serial=True, progress=False, verbose=False)
    assert again.n_skipped == 8 and again.n_computed == 0


@pytest.mark.parametrize("kw, name", [
    (dict(walls="hard,-1"), "walls"),
    (dict(walls="hard,nan"), "walls"),
    (dict(seeds="5-1"), "seeds"),
    (dict(seeds=[-1]), "seeds"),
    (dict(n=40), "n must be >= 2 n_waves"),
    (dict(mean_pressures=[0.004, 0.0]), "mean_pressures"),
    (dict(tol=2.0), "tol"),
    (dict(method="ccg", walls="hard,0.1"), "method"),
    (dict(method="pk", walls="hard,0.1"), "method"),
    (dict(workers=0), "workers"),
    (dict(max_iter=0), "max_iter"),
])
def test_bad_parameters_rejected_before_any_work(tmp_path, kw, name):
    args = dict(n=N, seeds="1", walls="hard")
    args.update(kw)
    with pytest.raises(ValueError, match=name):
        run_ensemble(tmp_path / "s", progress=False, verbose=False, **args)
    assert not (tmp_path / "s").exists()


def test_every_method_of_the_cli_builds_cases():
    """`gfmd-ref ensemble --method` offers what `gfmd-ref run` offers, pk included."""
    for method, walls in (("ccg", "hard"), ("pk", "hard"), ("newton", "0.25"), ("fire", "hard,0.25")):
        cases = build_cases(n=N, seeds="1", walls=walls, method=method)
        assert cases and all(c["method"] == method for c in cases)


def test_non_converged_case_recorded_excluded_and_counted(tmp_path, capsys):
    run = run_ensemble(tmp_path, n=N, seeds="1-2", walls="hard", max_iter=3, serial=True, progress=False)
    assert run.n_not_converged == 2
    ens = load_ensemble(tmp_path)
    assert ens.n_not_converged == 2 and not any(r.converged for r in ens)
    assert all(r.provenance["iterations"] == 3 and r.provenance["residual"] > 1e-6 for r in ens)
    run_ensemble(tmp_path, n=N, seeds="1-2", walls="hard", serial=True, progress=False, verbose=False)
    g = load_ensemble(tmp_path).group("hard")
    assert g.n_seeds == 2 and g.n_excluded == 2
    from gfmd_ref.cli import main

    assert main(["ensemble-summary", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "2 not converged" in out
    row = [ln for ln in out.splitlines() if "hard" in ln and ln.strip().startswith("128")][0]
    assert row.split()[3:5] == ["2", "2"]  # seeds used, not converged


def test_reduction_against_numpy_and_solver_definitions():
    rng = np.random.default_rng(3)
    p = np.where(rng.random((64, 64)) < 0.3, rng.exponential(0.01, (64, 64)), 0.0)
    red = reduce_pressure_field(p, mean_pressure=0.004, zeta=None)
    np.testing.assert_array_equal(red["quantiles"], np.quantile(p, STORE_LEVELS))
    assert red["contact_fraction"] == np.count_nonzero(p > 0) / p.size
    assert red["zero_weight"] == 1 - red["contact_fraction"]
    assert red["hist_counts"].sum() + red["hist_overflow"] + red["hist_zero"] == p.size
    c = p - p.mean()
    assert red["skewness"] == pytest.approx(np.mean(c**3) / np.std(p) ** 3, rel=1e-12)
    soft = reduce_pressure_field(p, mean_pressure=0.004, zeta=0.5)
    assert soft["contact_fraction"] == np.count_nonzero(p > 4e-5) / p.size
    with pytest.raises(ValueError, match="pressure must be >= 0"):
        reduce_pressure_field(-p - 1, mean_pressure=0.004, zeta=None)


def test_ingested_fields_give_the_live_records(tmp_path):
    """A saved field reduced by ``gfmd-ref ensemble-ingest`` equals the live run's record."""
    fields = tmp_path / "fields"
    fields.mkdir()
    cases = build_cases(n=N, seeds="2", walls="hard,0.25")
    for c in cases:
        h = case_surface(c)
        inter = HardWall() if c["zeta"] is None else ExponentialRepulsion(c["zeta"])
        r = solve_contact(h, length=c["length"], E_star=c["E_star"], mean_pressure=c["mean_pressure"],
                          interaction=inter, tol=c["tol"])
        meta = dict(n=N, seed=c["seed"], zeta=c["zeta"], length=c["length"], tol=c["tol"], method=r.method,
                    converged=r.converged, residual=r.residual, iterations=r.iterations, wall_time=r.wall_time,
                    code="test", E_star=c["E_star"], mean_pressure=c["mean_pressure"])
        np.savez_compressed(fields / f"f_{c['seed']}_{c['zeta']}.npz", pressure=r.pressure, meta=json.dumps(meta))
    from gfmd_ref.cli import main

    assert main(["ensemble-ingest", str(fields), "--store", str(tmp_path / "ing"), "--field-command", "test job",
                 "--no-progress"]) == 0
    live = run_ensemble(tmp_path / "live", n=N, seeds="2", walls="hard,0.25", serial=True, progress=False,
                        verbose=False)
    for a, b in zip(load_ensemble(tmp_path / "ing"), load_ensemble(live.store)):
        assert a.key == b.key
        assert a.provenance["source"] == "ingested" and a.provenance["field_command"] == "test job"
        np.testing.assert_array_equal(a.quantiles, b.quantiles)
        np.testing.assert_array_equal(a.spectrum_power, b.spectrum_power)
        assert a.contact_fraction == b.contact_fraction
    # the live run skips what was ingested
    again = run_ensemble(tmp_path / "ing", n=N, seeds="2", walls="hard,0.25", serial=True, progress=False,
                         verbose=False)
    assert again.n_skipped == 2 and again.n_computed == 0


def test_scheduler_address(tmp_path, cluster):
    """``scheduler=ADDRESS`` connects to a running cluster; same records as serial."""
    addr = cluster.scheduler.address
    run = run_ensemble(tmp_path / "addr", n=64, seeds="1-2", walls="hard", scheduler=addr, progress=False,
                       verbose=False)
    assert run.success and run.scheduler == f"scheduler {addr}"
    ser = run_ensemble(tmp_path / "ser", n=64, seeds="1-2", walls="hard", serial=True, progress=False, verbose=False)
    for a, b in zip(load_ensemble(tmp_path / "addr"), load_ensemble(ser.store)):
        np.testing.assert_array_equal(a.quantiles, b.quantiles)
        assert "run_ensemble" in a.provenance["command"]


@pytest.mark.slow
def test_cli_starts_and_closes_its_own_local_cluster(tmp_path, capsys):
    from gfmd_ref.cli import main

    assert main(["ensemble", "--n", "64", "--seeds", "1-2", "--walls", "hard", "--workers", "1",
                 "--store", str(tmp_path / "own"), "--no-progress"]) == 0
    assert "local cluster: 1 worker(s)" in capsys.readouterr().out
    ser = run_ensemble(tmp_path / "ser", n=64, seeds="1-2", walls="hard", serial=True, progress=False, verbose=False)
    for a, b in zip(load_ensemble(tmp_path / "own"), load_ensemble(ser.store)):
        np.testing.assert_array_equal(a.quantiles, b.quantiles)
        assert a.provenance["command"].startswith("gfmd-ref ensemble")


def test_bundle_is_the_store_subsampled(tmp_path):
    """write_bundle keeps every other store level (i/1024) as float32 and the
    float64 scalars and spectra exactly; a bundle refuses duplicate cases."""
    from gfmd_ref.ensemble.data import BUNDLE_LEVELS, _load_bundle, write_bundle

    run_ensemble(tmp_path / "s", n=64, seeds="1-2", walls="hard,0.5", serial=True, progress=False, verbose=False)
    path, size = write_bundle(tmp_path / "s", tmp_path / "b.npz", name="test", command="pytest")
    recs, info = _load_bundle(str(path))
    assert info["command"] == "pytest" and info["n_records"] == 4 and size == path.stat().st_size
    for a, b in zip(recs, load_ensemble(tmp_path / "s")):
        assert a.key == b.key and a.converged == b.converged
        np.testing.assert_array_equal(a.levels, BUNDLE_LEVELS)
        np.testing.assert_array_equal(a.quantiles, b.quantiles[::2].astype(np.float32).astype(np.float64))
        assert (a.contact_fraction, a.sd, a.skewness, a.zero_weight) == (b.contact_fraction, b.sd, b.skewness,
                                                                          b.zero_weight)
        np.testing.assert_array_equal(a.spectrum_power, b.spectrum_power)
    with pytest.raises(ValueError, match="twice"):
        write_bundle([tmp_path / "s", tmp_path / "s"], tmp_path / "c.npz", name="test")
