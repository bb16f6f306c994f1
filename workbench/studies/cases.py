"""One study case, run anywhere (a Dask worker or this process): the experiment registry.

:func:`run_case` is a pure function of its scenario and instrument (and the dataset store it renders into
or reuses): a killed study resumes by skipping the cases whose records exist.
"""
from __future__ import annotations

import os
import time
import traceback
from pathlib import Path

from workbench.scenario import Instrument, Scenario, dataset_parts
from workbench.store import DatasetStore


def _dic2d():
    from workbench.experiments.dic2d import case as dic2d_case
    return dic2d_case


def _rigid_motion():
    from workbench.experiments.rigid_motion import case as rigid_motion_case
    return rigid_motion_case


def _specimen():
    from workbench.experiments.specimen import case as specimen_case
    return specimen_case


#: experiment name -> loader of its module (each has KIND, METRICS, FLOORS and run(scenario, instrument, store))
EXPERIMENT_MODULES = {"dic2d": _dic2d, "rigid_motion": _rigid_motion, "specimen": _specimen}


def experiment_module(name: str):
    if name not in EXPERIMENT_MODULES:
        raise ValueError(f"unknown experiment {name!r} (known: {', '.join(EXPERIMENT_MODULES)})")
    return EXPERIMENT_MODULES[name]()


def experiment_metrics(name: str) -> list[str]:
    """The metric names an experiment returns."""
    return list(experiment_module(name).METRICS)


def writes_points(experiment: str) -> bool:
    """Whether an experiment writes a per-point file for each case (its ``run`` takes ``points_path``)."""
    import inspect

    return "points_path" in inspect.signature(experiment_module(experiment).run).parameters


def run_case(scenario: Scenario, instrument: Instrument, store: DatasetStore, points_path: Path | None = None) -> dict:
    """Render (or reuse) the scenario's datasets, measure, score: ``{"metrics", "dims", "coords", "datasets"}``.

    ``metrics`` maps a name to a float or a list (a list has the dimensions ``dims[name]`` with coordinates
    ``coords[dim]``). ``points_path``: where an experiment that writes per-point files (:func:`writes_points`)
    writes this case's (``points_file`` in the output names it).
    """
    module = experiment_module(scenario.experiment)
    if points_path is not None and writes_points(scenario.experiment):
        return module.run(scenario, instrument, store, points_path=points_path)
    return module.run(scenario, instrument, store)


def run_case_record(payload: dict) -> dict:
    """Worker entry point: run one case from its JSON payload and write its record atomically.

    ``payload``: ``scenario``, ``instrument`` (mappings), ``hash``, ``labels``, ``seed``, ``store`` (folder),
    ``cases_dir`` (where the record ``<hash>.json`` goes), ``run_id``, ``points`` (also write the per-point file
    ``<hash>.points.csv`` where the experiment has one). A case that raises is recorded with
    ``status = "failed"`` and its error (and retried by the next run); it never stops the study.
    """
    import json

    from labio.atomic import atomic_write_text
    from workbench.config import from_dict

    scenario = from_dict(Scenario, payload["scenario"], "scenario")
    instrument = from_dict(Instrument, payload["instrument"], "instrument")
    store = DatasetStore(payload["store"])
    start = time.perf_counter()
    record = {"hash": payload["hash"], "labels": payload["labels"], "seed": payload["seed"],
              "scenario": payload["scenario"], "instrument": payload["instrument"], "run_id": payload["run_id"],
              "pid": os.getpid(), "datasets": {p: h for p, (h, _) in dataset_parts(scenario).items()}}
    points_path = Path(payload["cases_dir"]) / f"{payload['hash']}.points.csv" if payload.get("points") else None
    try:
        out = run_case(scenario, instrument, store, points_path)
        record.update(status="ok", metrics=out["metrics"], dims=out.get("dims", {}), coords=out.get("coords", {}),
                      reused=out.get("reused", {}))
        if out.get("points_file"):
            record["points_file"] = out["points_file"]     # beside the record, written before it
    except Exception as err:  # noqa: BLE001 - a failed case is recorded with its cause, the study goes on
        record.update(status="failed", error=f"{type(err).__name__}: {err}",
                      traceback=traceback.format_exc(limit=8))
    record["seconds"] = round(time.perf_counter() - start, 3)
    record["finished_at"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    name = f"{payload['hash']}.json" if record["status"] == "ok" else f"{payload['hash']}.failed.json"
    atomic_write_text(Path(payload["cases_dir"]) / name, json.dumps(record, indent=1, allow_nan=True))
    return record
