"""Run a study on Dask: one task per case, records written atomically, a killed sweep resumes.

* The engine is ``dask.distributed``: a :class:`distributed.LocalCluster` of process workers by default (one
  thread each: Dr.Jit and numba keep per-process state, and a case already uses a core), or an existing
  cluster when a scheduler address is given (``dask scheduler`` / ``dask worker`` started elsewhere; the
  workers must see the same store and output folders, e.g. on one machine or a shared file system).
* Each case is keyed by the hash of its scenario and instrument. Its record ``<out>/cases/<hash>.json`` is
  written by the worker, atomically, as soon as the case finishes; a rerun of the same study skips every case
  whose record exists, so a killed sweep (client, workers or both) loses nothing that finished and recomputes
  nothing. A failed case is recorded as ``<hash>.failed.json`` with its error and retried by the next run.
* Renders go to the dataset store (:mod:`workbench.store`), shared by all cases and studies.
"""
from __future__ import annotations

import json
import logging
import os
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_text
from workbench.config import to_dict
from workbench.store import DatasetStore
from workbench.studies.study import Case, Study

#: Environment of LocalCluster workers: one thread per library, since each worker process is one case at a time.
WORKER_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
              "NUMBA_NUM_THREADS": "1", "WORKBENCH_RENDER_THREADS": "1", "MALLOC_TRIM_THRESHOLD_": "65536"}


@dataclass
class SweepSummary:
    """What a sweep run did."""

    total: int
    already_done: int
    computed: int
    failed: int
    seconds: float
    out_dir: Path
    records: list
    points: bool = False        # the cases wrote per-point files (cases/<hash>.points.csv)


def case_payload(case: Case, store: DatasetStore, cases_dir: Path, run_id: str, points: bool = True) -> dict:
    return {"scenario": to_dict(case.scenario), "instrument": to_dict(case.instrument), "hash": case.hash,
            "labels": case.labels, "seed": case.seed, "store": str(store.root), "cases_dir": str(cases_dir),
            "run_id": run_id, "points": bool(points)}


def warm_worker() -> dict:
    """Run on each worker before its first case: compile (or load) the DIC kernels once, so no case's timing
    carries numba's compilation; returns the worker's process id and the seconds it took."""
    from measurement.dic.warm import warm_up_kernels

    return {"pid": os.getpid(), "seconds": warm_up_kernels()}


def prepare_workers(client, expected: int | None, log=print) -> dict:
    """Wait for the workers (``expected`` of them, or those the scheduler has), then warm every one of them,
    with a progress line for each wait; returns ``{"workers", "start_s", "warm_s", "warm_per_worker_s"}``."""
    start = time.perf_counter()
    if expected:
        client.wait_for_workers(expected, timeout=300)
    workers = len(client.scheduler_info()["workers"])
    start_s = time.perf_counter() - start
    log(f"  {workers} Dask worker(s) ready in {start_s:.1f} s; compiling the DIC kernels on each (numba, once per "
        "worker: up to ~30 s with an empty cache) ...")
    start = time.perf_counter()
    warm = client.run(warm_worker)
    warm_s = time.perf_counter() - start
    per = {addr: round(r["seconds"], 2) for addr, r in warm.items()}
    log(f"  kernels ready on {len(per)} worker(s) in {warm_s:.1f} s (slowest {max(per.values(), default=0):.1f} s)")
    return {"workers": workers, "start_s": round(start_s, 2), "warm_s": round(warm_s, 2), "warm_per_worker_s": per,
            "warm_pids": sorted(int(r["pid"]) for r in warm.values())}


def read_record(path: Path) -> dict | None:
    """A case record, or None if it cannot be read (then the case is computed again)."""
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return record if isinstance(record, dict) and record.get("status") == "ok" else None


def finished_records(cases_dir: Path, hashes) -> dict[str, dict]:
    """Records of the finished cases among ``hashes``."""
    out = {}
    for h in hashes:
        record = read_record(cases_dir / f"{h}.json")
        if record is not None:
            out[h] = record
    return out


def client_start_text(scheduler: str | None, workers: int) -> str:
    """What :func:`start_client` is about to do, in words: a given scheduler is the user's, only connected to.

    Parameters
    ----------
    scheduler : str or None
        Address of a running Dask scheduler, or None for a new LocalCluster.
    workers : int
        Process workers of the LocalCluster (unused with ``scheduler``).

    Returns
    -------
    str
        ``"connecting to the Dask scheduler at ADDRESS"`` or ``"starting N local Dask worker processes"``.
    """
    if scheduler:
        return f"connecting to the Dask scheduler at {scheduler}"
    return f"starting {workers} local Dask worker processes"


def start_client(scheduler: str | None, workers: int):
    """A ``distributed.Client``: on ``scheduler`` (an address) or on a new LocalCluster of ``workers`` processes."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as err:
            raise ConnectionError(f"--scheduler {scheduler}: no Dask scheduler answers there ({err})") from None
    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    environ.update(WORKER_ENV)
    # the nanny writes pre-spawn-environ into this process's os.environ too; left there, NUMBA_NUM_THREADS=1 makes
    # numba refuse every later compilation in this process ("Cannot set NUMBA_NUM_THREADS to a different value")
    saved = {key: os.environ.get(key) for key in environ}
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ,
                              "distributed.worker.daemon": False}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR)
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
    return Client(cluster), cluster


def plan_sweep(study: Study, out_dir: str | Path, *, store: DatasetStore | None = None, workers: int = 2,
               time_one: bool = True, points: bool = True) -> dict:
    """What ``workbench sweep`` would do: the case count, how many are already done in ``out_dir``, and a time estimate.

    The estimate is the median duration of this study's finished cases times the cases left, divided by
    ``workers`` (the cases run in parallel; the one-time kernel compilation per worker is not counted). With no
    finished case and ``time_one``, one case is run here to time it (its record is kept: the sweep does not run it
    again); its duration includes rendering its dataset unless the store held it.
    """
    from workbench.studies.cases import writes_points

    out_dir = Path(out_dir)
    cases_dir = out_dir / "cases"
    cases = study.expand()
    done = finished_records(cases_dir, [c.hash for c in cases]) if cases_dir.is_dir() else {}
    todo = [c for c in cases if c.hash not in done]
    seconds = [float(r["seconds"]) for r in done.values() if isinstance(r.get("seconds"), (int, float))]
    timed = None
    if not seconds and todo and time_one:
        store = store or DatasetStore()
        store.root.mkdir(parents=True, exist_ok=True)
        cases_dir.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        record = _run_payload(case_payload(todo[0], store, cases_dir, "dry-run-" + uuid.uuid4().hex[:8],
                                           bool(points and writes_points(study.scenario.experiment))))
        if record.get("status") == "ok":
            seconds = [float(record.get("seconds") or time.perf_counter() - start)]
            timed = {"labels": todo[0].labels, "seconds": seconds[0]}
            todo = todo[1:]
            done[record["hash"]] = record
    per_case = float(np.median(seconds)) if seconds else None
    estimate = None if per_case is None else per_case * len(todo) / max(1, int(workers))
    return {"cases": len(cases), "seeds": len(study.seeds), "done": len(done), "todo": len(todo),
            "per_case_s": per_case, "estimate_s": estimate, "workers": int(workers), "timed_here": timed,
            "from_cases": len(seconds)}


def run_sweep(study: Study, out_dir: str | Path, *, store: DatasetStore | None = None, scheduler: str | None = None,
              workers: int = 2, progress: bool = True, client=None, points: bool = True) -> SweepSummary:
    """Run every case of ``study`` not yet recorded in ``out_dir/cases`` and return the summary.

    ``client``: an existing ``distributed.Client`` to use (then ``scheduler``/``workers`` are ignored).
    ``points``: each case of an experiment that has per-point files writes ``cases/<hash>.points.csv`` (a finished
    case without one is run again). Before the first case every worker compiles the DIC kernels once, with a
    progress line (:func:`prepare_workers`).
    """
    from distributed import as_completed
    from tqdm import tqdm

    from workbench.studies.cases import writes_points

    out_dir = Path(out_dir)
    cases_dir = out_dir / "cases"
    cases_dir.mkdir(parents=True, exist_ok=True)
    store = store or DatasetStore()
    store.root.mkdir(parents=True, exist_ok=True)
    store.clear_partials()
    cases = study.expand()
    hashes = [c.hash for c in cases]
    if len(set(hashes)) != len(hashes):
        raise ValueError(f"{study.source}: two cases of the study are identical (same scenario and instrument); "
                         "check the axes and seeds")
    done = finished_records(cases_dir, hashes)
    points = bool(points and writes_points(study.scenario.experiment))
    if points:
        # a case finished without its per-point file (an earlier run with --no-points) is run again
        done = {h: r for h, r in done.items() if (cases_dir / str(r.get("points_file", ""))).is_file()
                and r.get("points_file")}
    todo = [c for c in cases if c.hash not in done]
    run_id = uuid.uuid4().hex[:12]
    start = time.perf_counter()
    records, failed = list(done.values()), 0
    if progress:
        print(f"{study.name}: {len(cases)} cases, {len(done)} already done, {len(todo)} to run", flush=True)
    if todo:
        own = client is None
        cluster = None
        log = (lambda text: print(text, flush=True)) if progress else (lambda text: None)
        if own:
            log(f"  {client_start_text(scheduler, workers)} ...")
            client, cluster = start_client(scheduler, workers)
        try:
            startup = prepare_workers(client, workers if own and not scheduler else None, log)
            futures = [client.submit(_run_payload, case_payload(c, store, cases_dir, run_id, points),
                                     key=f"case-{c.hash}-{run_id}", pure=False, retries=0) for c in todo]
            bar = tqdm(total=len(todo), desc=f"sweep {study.name}", unit="case", disable=not progress)
            for future in as_completed(futures):
                try:
                    record = future.result()
                except Exception as err:  # noqa: BLE001 - a worker lost mid-case: that case is simply not done
                    record = {"status": "failed", "error": f"{type(err).__name__}: {err}"}
                if record.get("status") == "ok":
                    records.append(record)
                else:
                    failed += 1
                    if progress:
                        tqdm.write(f"case {record.get('labels')} failed: {record.get('error')}")
                bar.update(1)
            bar.close()
        finally:
            if own:
                client.close()
                if cluster is not None:
                    cluster.close()
    summary = SweepSummary(len(cases), len(done), len(todo) - failed, failed, time.perf_counter() - start, out_dir,
                           records, points)
    run = {"study": study.name, "source": study.source, "cases": len(cases), "already_done": len(done),
           "computed": summary.computed, "failed": failed, "seconds": round(summary.seconds, 2), "run_id": run_id,
           "workers_startup": startup if todo else None,
           "scheduler": scheduler or f"LocalCluster({workers} process workers)",
           "store": str(store.root), "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    write_sweep_log(out_dir / "sweep-log.json", run)
    return summary


def write_sweep_log(path: Path, run: dict) -> None:
    """Append this run to ``sweep-log.json`` (every run of the study into this folder, newest last); the newest
    run's figures are also at the top level."""
    runs = []
    try:
        earlier = json.loads(path.read_text(encoding="utf-8"))
        runs = earlier.get("runs", [earlier]) if isinstance(earlier, dict) else []
        runs = [r for r in runs if isinstance(r, dict) and "run_id" in r]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        pass
    atomic_write_text(path, json.dumps({**run, "runs": runs + [run]}, indent=1))


def _run_payload(payload: dict) -> dict:
    from workbench.studies.cases import run_case_record
    return run_case_record(payload)


def environment_versions() -> dict:
    """Versions recorded with every study result."""
    import platform

    import numpy

    versions = {"python": platform.python_version(), "numpy": numpy.__version__, "machine": platform.machine(),
                "cpus": os.cpu_count()}
    for name in ("dask", "distributed", "xarray", "scipy", "numba", "mitsuba", "drjit"):
        try:
            module = __import__(name)
            versions[name] = getattr(module, "__version__", "?")
        except ImportError:
            versions[name] = None
    try:
        from importlib.metadata import version
        versions["workbench"] = version("scheimpflug-dic-workbench")
    except Exception:  # noqa: BLE001 - not installed as a package
        versions["workbench"] = None
    return versions
