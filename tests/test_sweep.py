"""Studies on Dask: a real LocalCluster, a killed sweep resumed, a separately started scheduler and worker.

The physics check is Pan et al. 2008: the random error of 2-D subset DIC with Gaussian noise sigma in both
images is sqrt(2) sigma / sqrt(sum f_x^2 over the subset); the floor is computed from the exact image gradient,
independently of the DIC engine.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from workbench.store import DatasetStore
from workbench.studies.study import load_study
from workbench.studies.report import gather, write_study_outputs
from workbench.studies.sweep import run_sweep

WORKBENCH = [sys.executable, "-m", "workbench.cli"]

NOISE_SUBSET = """
[study]
name = "noise x subset (test)"
repeats = 3
[scenario]
experiment = "dic2d"
[scenario.render]
bit_depth = 0
[scenario.image2d]
size_px = 512
[instrument]
step_px = 7
shape_order = 1
[[axis]]
name = "noise_grey"
parameter = "scenario.render.read_noise_grey"
values = [1.0, 3.0]
[[axis]]
name = "subset_px"
parameter = "instrument.subset_px"
values = [21, 41]
"""


def _study(tmp_path, text=NOISE_SUBSET, name="study.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_study(path)


def test_noise_by_subset_study_on_a_local_cluster_follows_the_pan_2008_floor_within_10_percent(tmp_path):
    """2 x 2 grid (noise 1 and 3 grey x subset 21 and 41 px), 3 seeds, on a LocalCluster of 2 process workers:
    at every grid point the random error (pooled over the seeds) is within 10 % of sqrt(2) sigma / sqrt(SSSIG)."""
    study = _study(tmp_path)
    summary = run_sweep(study, tmp_path / "out", store=DatasetStore(tmp_path / "store"), workers=2, progress=False)
    assert (summary.total, summary.computed, summary.failed) == (12, 12, 0)
    assert len({r["pid"] for r in summary.records}) == 2            # both worker processes took cases
    ds = gather(study, summary.records)
    assert dict(ds["random_error_px"].sizes) == {"noise_grey": 2, "subset_px": 2, "repeat": 3}
    rms = lambda da: np.sqrt((da ** 2).mean("repeat"))              # noqa: E731 - pooled over the seeds
    ratio = rms(ds["random_error_px"]) / rms(ds["predicted_error_px"])
    assert np.all(np.abs(ratio.values - 1.0) <= 0.10), ratio.values
    # the floor scales with sigma and shrinks with the subset, as the formula says
    floor = ds["predicted_error_px"].mean("repeat")
    assert floor.sel(noise_grey=3.0).values == pytest.approx(3.0 * floor.sel(noise_grey=1.0).values, rel=1e-9)
    assert np.all(floor.sel(subset_px=41).values < floor.sel(subset_px=21).values)
    # per-point files beside the records: u, v, the exact shift, status; the case's figures follow from them
    for record in summary.records:
        rows = (tmp_path / "out" / "cases" / record["points_file"]).read_text().splitlines()
        header = rows[0].split(",")
        table = np.array([r.split(",") for r in rows[1:]])
        col = lambda name: table[:, header.index(name)]  # noqa: E731
        shift = record["scenario"]["image2d"].get("shift_x_px", 0.25)
        np.testing.assert_allclose(col("u_true").astype(float), shift, rtol=0, atol=1e-12)
        error = col("u").astype(float) - shift
        ok = np.isfinite(error)
        assert ok.sum() == record["metrics"]["points"] and set(col("status_name")[ok]) == {"converged"}
        assert np.mean(error[ok]) == pytest.approx(record["metrics"]["bias_px"], abs=1e-8)
        independent = ok & (col("independent") == "1")
        assert np.std(error[independent]) == pytest.approx(record["metrics"]["random_error_px"], rel=1e-6)
    paths = write_study_outputs(study, tmp_path / "out", summary.records, ["test"], {})
    import xarray as xr
    back = xr.open_dataset(paths["netcdf"], engine="scipy")
    assert np.allclose(back["random_error_px"].values, ds["random_error_px"].values, equal_nan=True)
    assert back.attrs["study_text"] == study.source_text
    html = paths["html"].read_text()
    assert html.count("data:image/png;base64,") >= 5 and "noise x subset (test)" in html


SMALL = """
[study]
name = "small"
repeats = 2
[scenario]
experiment = "dic2d"
[scenario.image2d]
size_px = 128
[instrument]
step_px = 8
subset_px = 21
"""


def test_workers_start_and_compile_with_a_progress_line_and_every_case_runs_on_a_warmed_worker(tmp_path):
    """A first case took > 20 s (Dask start-up + numba compilation) with no word on stdout. The sweep says when the
    workers are up and when their kernels are compiled, before any case; every case ran on a worker that was
    warmed (its pid among the warmed ones, recorded in sweep-log.json). --no-points writes no per-point file, and
    a rerun that wants them runs those cases again."""
    study = tmp_path / "small.toml"
    study.write_text(SMALL)
    out = tmp_path / "out"
    proc = subprocess.run([*WORKBENCH, "sweep", str(study), "--workers", "2", "--store", str(tmp_path / "store"),
                           "--no-points", "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    ready = next(i for i, line in enumerate(lines) if "2 Dask worker(s) ready in" in line)
    warmed = next(i for i, line in enumerate(lines) if "kernels ready on 2 worker(s)" in line)
    assert ready < warmed
    log = json.loads((out / "sweep-log.json").read_text())
    startup = log["workers_startup"]
    records = [json.loads(p.read_text()) for p in (out / "cases").glob("*.json")]
    assert len(records) == 2 and not list((out / "cases").glob("*.points.csv"))
    assert all("points_file" not in r for r in records)
    assert len(startup["warm_per_worker_s"]) == 2
    assert {r["pid"] for r in records} <= set(startup["warm_pids"])
    again = subprocess.run([*WORKBENCH, "sweep", str(study), "--workers", "2", "--store", str(tmp_path / "store"),
                            "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "2 cases, 0 already done, 2 to run" in again.stdout
    assert len(list((out / "cases").glob("*.points.csv"))) == 2


def test_renders_are_stored_once_by_content_and_reused_across_instrument_settings(tmp_path):
    """The subset axis does not change the images: 2 noise levels x 3 seeds = 6 datasets for 12 cases."""
    study = _study(tmp_path)
    store = DatasetStore(tmp_path / "store")
    summary = run_sweep(study, tmp_path / "out", store=store, workers=1, progress=False)
    datasets = sorted(p.name for p in store.root.iterdir() if not p.name.startswith("."))
    assert len(datasets) == 6
    assert sum(r["reused"]["images"] for r in summary.records) == 6
    assert {r["datasets"]["images"] for r in summary.records} == {d.split("-", 1)[1] for d in datasets}
    again = run_sweep(study, tmp_path / "out", store=store, workers=1, progress=False)
    assert (again.already_done, again.computed) == (12, 0)
    log = json.loads((tmp_path / "out" / "sweep-log.json").read_text())
    assert [(r["computed"], r["already_done"]) for r in log["runs"]] == [(12, 0), (0, 12)]    # both runs kept


def test_a_partial_dataset_is_never_read_and_a_dead_process_partial_is_cleared(tmp_path):
    store = DatasetStore(tmp_path / "store")
    calls = []

    def render(folder):
        from workbench.manifest import complete_folder
        (folder / "a.txt").write_text("x")
        complete_folder(folder, "demo", ["a.txt"])
        calls.append(folder)

    # a folder under the hash without a manifest (an interrupted write) is not a dataset
    (store.path("demo", "abc")).mkdir(parents=True)
    (store.path("demo", "abc") / "a.txt").write_text("half")
    assert store.find("demo", "abc") is None
    folder, reused = store.ensure("demo", "abc", {"k": 1}, render)
    assert (reused, len(calls), (folder / "a.txt").read_text()) == (False, 1, "x")
    assert store.ensure("demo", "abc", {"k": 1}, render) == (folder, True) and len(calls) == 1
    import socket
    host = socket.gethostname()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (store.root / ".partial" / f"demo-def@{host}-{dead.pid}").mkdir(parents=True)
    (store.root / ".partial" / f"demo-ghi@{host}-{os.getpid()}").mkdir(parents=True)      # alive: kept
    (store.root / ".partial" / f"demo-jkl@elsewhere-{dead.pid}").mkdir(parents=True)     # another host's: kept
    removed = store.clear_partials()
    assert [p.name for p in removed] == [f"demo-def@{host}-{dead.pid}"]


def _run_cli(args, **kw):
    return subprocess.run(WORKBENCH + args, capture_output=True, text=True, **kw)


def test_a_killed_sweep_resumes_with_every_case_once_and_none_recomputed(tmp_path):
    """SIGTERM to the client and its workers halfway; the same command then finishes the rest only."""
    study_path = tmp_path / "study.toml"
    study_path.write_text(NOISE_SUBSET.replace("values = [21, 41]", "values = [21, 31, 41]")
                          .replace("values = [1.0, 3.0]", "values = [1.0, 2.0, 3.0]"))
    out, store = tmp_path / "out", tmp_path / "store"
    args = ["sweep", str(study_path), "--workers", "2", "--store", str(store), "--quiet", "--out", str(out)]
    proc = subprocess.Popen(WORKBENCH + args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    cases = out / "cases"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and len(list(cases.glob("*.json"))) < 6 and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGTERM)               # the client and every worker process of its session
    proc.wait(timeout=60)
    time.sleep(1.0)
    before = {p.name: (p.stat().st_mtime_ns, json.loads(p.read_text())["run_id"]) for p in cases.glob("*.json")}
    assert 6 <= len(before) < 27, f"the kill did not land halfway: {len(before)} of 27 cases done"
    again = _run_cli(args, timeout=600)
    assert again.returncode == 0, again.stdout + again.stderr
    after = {p.name: (p.stat().st_mtime_ns, json.loads(p.read_text())["run_id"]) for p in cases.glob("*.json")}
    assert len(after) == 27                            # every case present, once (one record per case hash)
    assert all(after[name] == before[name] for name in before)      # none recomputed, none rewritten
    log = json.loads((out / "sweep-log.json").read_text())
    assert (log["already_done"], log["computed"], log["failed"]) == (len(before), 27 - len(before), 0)
    assert len({run for _, run in after.values()}) == 2
    assert f"{len(before)} already done" in again.stdout


def test_sweep_runs_on_a_separately_started_dask_scheduler_and_worker(tmp_path):
    """``dask scheduler`` and ``dask worker`` as their own processes on localhost; ``--scheduler`` uses them."""
    scheduler_file = tmp_path / "scheduler.json"
    dask_cli = Path(sys.executable).with_name("dask")
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    scheduler = subprocess.Popen([str(dask_cli), "scheduler", "--host", "127.0.0.1", "--port", "0",
                                  "--no-dashboard", "--scheduler-file", str(scheduler_file)],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    worker = None
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        worker = subprocess.Popen([str(dask_cli), "worker", address, "--nworkers", "1", "--nthreads", "1",
                                   "--no-dashboard", "--name", "test-worker"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
        study_path = tmp_path / "study.toml"
        study_path.write_text(NOISE_SUBSET.replace("repeats = 3", "repeats = 1").replace("size_px = 512", "size_px = 256"))
        result = _run_cli(["sweep", str(study_path), "--scheduler", address, "--store", str(tmp_path / "store"),
                           "--quiet", "--out", str(tmp_path / "out")], timeout=300)
        assert result.returncode == 0, result.stdout + result.stderr
        log = json.loads((tmp_path / "out" / "sweep-log.json").read_text())
        assert (log["computed"], log["scheduler"]) == (4, address)
        records = [json.loads(p.read_text()) for p in (tmp_path / "out" / "cases").glob("*.json")]
        # the cases ran in the worker's process, not in the client's
        assert len(records) == 4 and all(r["pid"] not in (os.getpid(),) for r in records)
        assert len({r["pid"] for r in records}) == 1
    finally:
        for proc in (worker, scheduler):
            if proc is not None:
                proc.terminate()
        for proc in (worker, scheduler):
            if proc is not None:
                proc.wait(timeout=30)
    assert scheduler.returncode is not None and (worker is None or worker.returncode is not None)


def test_a_bad_study_file_is_refused_before_any_work_naming_the_file_and_key(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(NOISE_SUBSET.replace("scenario.render.read_noise_grey", "scenario.render.noise_grey"))
    result = _run_cli(["sweep", str(path), "--out", str(tmp_path / "out"), "--store", str(tmp_path / "store")])
    assert result.returncode == 2
    assert "bad.toml: axis[0] (noise_grey): scenario.render.noise_grey: no such parameter" in result.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "store").exists()
    result = _run_cli(["sweep", str(path), "--scheduler", "tcp://127.0.0.1:1", "--out", str(tmp_path / "out")])
    assert result.returncode == 2 and "bad.toml" in result.stderr


BUDGET = """
[study]
name = "2-D noise budget (test)"
seeds = [0, 1]
[scenario]
experiment = "dic2d"
[scenario.render]
bit_depth = 0
read_noise_grey = 0.0
[scenario.image2d]
size_px = 384
[instrument]
subset_px = 25
step_px = 9
shape_order = 1
[[budget.source]]
name = "read noise 2 grey"
set = { "scenario.render.read_noise_grey" = 2.0 }
[[budget.source]]
name = "shot noise 40 e-/grey"
set = { "scenario.render.electrons_per_grey" = 40.0 }
"""


def test_budget_of_two_independent_noise_sources_adds_in_quadrature_within_10_percent(tmp_path):
    """Read noise (2 grey) and shot noise (mean 128 grey at 40 e-/grey: 1.8 grey) are independent: the random
    error with both is the quadrature sum of each alone (10 %), and clearly not their linear sum."""
    path = tmp_path / "budget.toml"
    path.write_text(BUDGET)
    result = _run_cli(["budget", str(path), "--metric", "random_error_px", "--workers", "2", "--quiet",
                       "--store", str(tmp_path / "store"), "--out", str(tmp_path / "out")], timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    budget = json.loads((tmp_path / "out" / "budget.json").read_text())
    check = budget["check"]
    assert [r["case"] for r in budget["rows"]] == ["baseline", "read noise 2 grey", "shot noise 40 e-/grey",
                                                   "all sources"]
    assert check["baseline"] < 0.02 * check["all_together"]          # noise-free: only interpolation bias spread
    assert abs(check["quadrature_sum_vs_all"] - 1.0) <= 0.10
    assert check["linear_sum_vs_all"] > 1.25
    assert check["dominant_source"] == "read noise 2 grey"
    assert "data:image/png;base64," in (tmp_path / "out" / "report.html").read_text()


def test_budget_refuses_a_metric_or_source_that_does_not_exist_before_any_work(tmp_path):
    path = tmp_path / "budget.toml"
    path.write_text(BUDGET)
    result = _run_cli(["budget", str(path), "--metric", "random_error", "--out", str(tmp_path / "out")])
    assert result.returncode == 2 and "--metric random_error: not a metric of the dic2d experiment" in result.stderr
    path.write_text(BUDGET.replace("scenario.render.electrons_per_grey", "scenario.render.electrons"))
    result = _run_cli(["budget", str(path), "--metric", "random_error_px", "--out", str(tmp_path / "out")])
    assert result.returncode == 2
    assert "budget.toml: budget.source[1] (shot noise 40 e-/grey): scenario.render.electrons: no such parameter" \
        in result.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("scheduler, expected, wrong", [
    ("tcp://10.0.0.7:8786", "  connecting to the Dask scheduler at tcp://10.0.0.7:8786 ...", "starting"),
    (None, "  starting 3 local Dask worker processes ...", "connecting")])
def test_the_sweep_says_it_connects_to_a_given_scheduler_and_starts_only_its_own(tmp_path, monkeypatch, capsys,
                                                                                  scheduler, expected, wrong):
    """With --scheduler the sweep uses the user's scheduler: it must not claim to start one. The line comes from
    run_sweep itself, just before it asks start_client for the client (stopped there: no cluster is needed)."""
    import workbench.studies.sweep as sweep

    def no_client(address, workers):
        raise ConnectionError(f"stopped before connecting ({address}, {workers})")

    monkeypatch.setattr(sweep, "start_client", no_client)
    with pytest.raises(ConnectionError, match=r"stopped before connecting"):
        run_sweep(_study(tmp_path), tmp_path / "out", store=DatasetStore(tmp_path / "store"), scheduler=scheduler,
                  workers=3)
    out = capsys.readouterr().out
    assert expected in out.splitlines()
    assert wrong not in out


def test_a_local_cluster_leaves_this_process_environment_as_it_was(monkeypatch):
    """The workers get one thread per library (WORKER_ENV), but this process keeps its own environment: the Dask
    nanny wrote NUMBA_NUM_THREADS=1 into it, after which numba refused to compile anything here ("Cannot set
    NUMBA_NUM_THREADS to a different value"; the docs gallery's twin example after the error-budget one)."""
    from workbench.studies.sweep import WORKER_ENV, start_client

    for key in WORKER_ENV:
        monkeypatch.delenv(key, raising=False)
    client, cluster = start_client(None, 1)
    try:
        assert all(os.environ.get(key) is None for key in WORKER_ENV), {k: os.environ.get(k) for k in WORKER_ENV}
        seen = client.run(lambda: (os.environ.get("NUMBA_NUM_THREADS"), os.environ.get("OMP_NUM_THREADS")))
        assert list(seen.values()) == [("1", "1")]
    finally:
        client.close()
        cluster.close()


def test_dry_run_counts_the_cases_and_estimates_from_one_timed_case_that_the_sweep_keeps(tmp_path, capsys):
    """--dry-run on a fresh folder: 12 cases (2 x 2 axes x 3 seeds), one of them run here to time it (the only record
    in cases/), the estimate = that case's seconds x the 11 left / 2 workers as printed; a second dry run estimates
    from the finished record without running anything; the sweep afterwards computes 11 cases, not 12."""
    from workbench.cli import main
    from workbench.studies.sweep import plan_sweep

    path = tmp_path / "study.toml"
    path.write_text(NOISE_SUBSET)
    out, store = tmp_path / "out", tmp_path / "store"
    base = ["sweep", str(path), "--workers", "2", "--store", str(store), "--out", str(out)]
    assert main(base + ["--dry-run"]) == 0
    text = capsys.readouterr().out
    records = list((out / "cases").glob("*.json"))
    assert len(records) == 1
    seconds = json.loads(records[0].read_text())["seconds"]
    assert "12 cases (2 axes: noise_grey, subset_px; 3 seeds each), 1 already done" in text
    assert f"11 cases x {seconds:.1f} s (median of 1 finished) / 2 workers" in text
    plan = plan_sweep(load_study(path), out, store=DatasetStore(store), workers=2)
    assert plan["timed_here"] is None and plan["todo"] == 11
    assert plan["estimate_s"] == pytest.approx(seconds * 11 / 2)
    assert len(list((out / "cases").glob("*.json"))) == 1            # the second plan ran nothing
    assert main(base + ["--quiet"]) == 0
    log = json.loads((out / "sweep-log.json").read_text())
    assert (log["already_done"], log["computed"]) == (1, 11)
