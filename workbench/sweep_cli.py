"""``workbench sweep``, ``workbench budget`` and ``workbench parameters``: the command-line side of studies."""
from __future__ import annotations

import dataclasses
import signal
import typing
from pathlib import Path

from workbench.config import parameter_paths


def _terminate_cleanly() -> None:
    """SIGTERM unwinds like Ctrl-C, so the LocalCluster is closed (finished case records are already on disk)."""
    def handler(signum, frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, handler)


def _prepare_out(out: Path, study) -> None:
    from measurement.files import atomic_write_text

    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    suffix = Path(study.source).suffix or ".toml"
    copy = out / f"study{suffix}"
    if copy.is_file() and copy.read_text(encoding="utf-8") != study.source_text:
        print(f"note: {out} held another study file; finished cases of identical content are reused, the study "
              f"file copy is replaced")
    atomic_write_text(copy, study.source_text)


def _summary_lines(study, summary, scheduler, workers) -> list[str]:
    engine = f"Dask scheduler {scheduler}" if scheduler else f"Dask LocalCluster, {workers} process workers"
    return [f"{summary.total} cases ({len(study.seeds)} seeds each): {summary.already_done} already done, "
            f"{summary.computed} computed now, {summary.failed} failed; {summary.seconds:.1f} s on {engine}",
            f"dimensions: {', '.join(study.dims)}; experiment {study.scenario.experiment}",
            "results: results.nc (xarray / NetCDF), results.csv, cases/<hash>.json"]


def sweep_command(args) -> int:
    from workbench.store import DatasetStore
    from workbench.study import load_study
    from workbench.study_report import write_study_outputs
    from workbench.sweep import environment_versions, run_sweep

    study = load_study(args.study)                   # every error before any work
    _prepare_out(args.out, study)
    _terminate_cleanly()
    summary = run_sweep(study, args.out, store=DatasetStore(args.store), scheduler=args.scheduler,
                        workers=args.workers, progress=not args.quiet)
    lines = _summary_lines(study, summary, args.scheduler, args.workers)
    paths = write_study_outputs(study, args.out, summary.records, lines, environment_versions())
    print("\n".join(lines))
    print(f"report: {paths['html']}")
    return 1 if summary.failed else 0


def budget_command(args) -> int:
    from workbench.budget import budget_study, parse_at, write_budget
    from workbench.store import DatasetStore
    from workbench.study import load_study
    from workbench.sweep import environment_versions, run_sweep

    base = load_study(args.study)
    study = budget_study(base, args.metric)          # checks the [budget] table and the metric
    at = parse_at(args.at, base, args.metric)
    _prepare_out(args.out, base)
    _terminate_cleanly()
    summary = run_sweep(study, args.out, store=DatasetStore(args.store), scheduler=args.scheduler,
                        workers=args.workers, progress=not args.quiet)
    lines = _summary_lines(study, summary, args.scheduler, args.workers)
    result = write_budget(study, args.out, summary.records, args.metric, at, lines, environment_versions())
    print("\n".join(lines))
    for row in result["rows"]:
        print(f"  {row['case']:<32s} {row['mean']:+.4g} ± {row['std']:.2g}   contribution {row['contribution']:+.4g}")
    print(f"  {result['check']}")
    print(f"report: {result['html']}")
    return 1 if summary.failed else 0


def parameters_command(args) -> int:
    from workbench.scenario import Instrument, Scenario

    for root, cls in (("scenario", Scenario), ("instrument", Instrument)):
        for path in parameter_paths(cls):
            obj, owner = cls(), cls
            parts = path.split(".")
            for name in parts[:-1]:
                obj = getattr(obj, name)
                owner = type(obj)
            f = {x.name: x for x in dataclasses.fields(owner)}[parts[-1]]
            hint = typing.get_type_hints(owner)[parts[-1]]
            meta = dict(f.metadata)
            extra = [f"one of {', '.join(map(str, meta['choices']))}" if "choices" in meta else "",
                     f">= {meta['min']}" if meta.get("min") is not None and "choices" not in meta else "",
                     f"<= {meta['max']}" if meta.get("max") is not None and "choices" not in meta else ""]
            bounds = "; ".join(e for e in extra if e)
            print(f"{root}.{path} = {getattr(obj, parts[-1])!r}  [{getattr(hint, '__name__', str(hint))}"
                  f"{'; ' + bounds if bounds else ''}]  {meta.get('doc', '')}")
    return 0
