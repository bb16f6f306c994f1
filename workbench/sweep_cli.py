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
            "results: results.nc (xarray / NetCDF), results.csv, cases/<hash>.json"
            + (" and cases/<hash>.points.csv (per point: u, v, truth, status)" if getattr(summary, "points", False)
               else "")]


def _run(args, study, copy_of=None):
    """Prepare ``--out``, run the study's missing cases on Dask; returns ``(summary, summary lines, versions)``."""
    from workbench.store import DatasetStore
    from workbench.sweep import environment_versions, run_sweep

    _prepare_out(args.out, copy_of or study)
    _terminate_cleanly()
    summary = run_sweep(study, args.out, store=DatasetStore(args.store), scheduler=args.scheduler,
                        workers=args.workers, progress=not args.quiet, points=getattr(args, "points", True))
    return summary, _summary_lines(study, summary, args.scheduler, args.workers), environment_versions()


def sweep_command(args) -> int:
    from workbench.study import load_study
    from workbench.study_report import write_study_outputs

    study = load_study(args.study)                   # every error before any work
    summary, lines, versions = _run(args, study)
    paths = write_study_outputs(study, args.out, summary.records, lines, versions)
    print("\n".join(lines + paths["summary"]))
    print(f"report: {paths['html']}")
    return 1 if summary.failed else 0


#: The study shipped with the repository that explains the paper's Fig 6.
FIG6_STUDY = Path(__file__).resolve().parents[1] / "studies" / "fig6_causes.toml"


def fig6_causes_command(args) -> int:
    from workbench.experiments.fig6_causes import write_fig6_report
    from workbench.study import load_study
    from workbench.study_report import write_study_outputs

    path = args.study or FIG6_STUDY
    if path == FIG6_STUDY and FIG6_STUDY.is_relative_to(Path.cwd()):
        path = FIG6_STUDY.relative_to(Path.cwd())      # the report names the file as the user would
    study = load_study(path)
    if study.scenario.experiment != "rigid_motion" or study.mode != "cases" or \
            "perfect world" not in [c.name for c in study.cases]:
        raise ValueError(f"{path}: the Fig 6 study needs experiment = \"rigid_motion\", mode = \"cases\" and a "
                         "case named \"perfect world\" (the baseline)")
    summary, lines, versions = _run(args, study)
    write_study_outputs(study, args.out, summary.records, lines, versions)
    result = write_fig6_report(study, args.out, summary.records, versions)
    print("\n".join(lines))
    for v in result["single_causes"]:
        print(f"  {v['case']}: {v['verdict']}")
    print(f"best explanation: {', '.join(result['best'][:3])}")
    print(f"report: {args.out / 'fig6_causes.md'}")
    return 1 if summary.failed else 0


def budget_command(args) -> int:
    from workbench.budget import budget_study, parse_at, write_budget
    from workbench.study import load_study

    base = load_study(args.study)
    study = budget_study(base, args.metric)          # checks the [budget] table and the metric
    at = parse_at(args.at)
    summary, lines, versions = _run(args, study, copy_of=base)
    result = write_budget(study, args.out, summary.records, args.metric, at, lines, versions)
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
