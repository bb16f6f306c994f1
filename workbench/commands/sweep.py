"""``workbench sweep``: a study file (axes x repeats) on Dask."""
from __future__ import annotations

import signal
from pathlib import Path

from workbench.commands.options import positive_int_arg


def add_study_arguments(parser) -> None:
    """The options ``sweep`` and ``budget`` share: the study file, where it runs, the store, the output folder."""
    parser.add_argument("study", type=Path, help="study file (.toml or .json)")
    parser.add_argument("--scheduler", default=None,
                        help="address of a running Dask scheduler (tcp://host:8786); default: a LocalCluster")
    parser.add_argument("--workers", type=positive_int_arg, default=2, help="LocalCluster process workers, default 2")
    parser.add_argument("--store", type=Path, default=None,
                        help="dataset store (renders by scenario hash); default $WORKBENCH_STORE or ~/.cache/...")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--no-points", dest="points", action="store_false",
                        help="no per-point file per case (cases/<hash>.points.csv: u, v, truth, status of every "
                             "point, for experiments that have one); default: written")
    parser.add_argument("--out", type=Path, required=True,
                        help="output folder (cases/<hash>.json, results.nc, results.csv, report.html); rerun the "
                             "same command to resume")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the case count, the cases already done in --out and a time estimate, and stop: "
                             "the estimate comes from the finished cases, else from one case run here to time it "
                             "(its result is kept)")


def add_parser(sub) -> None:
    """The ``sweep`` subcommand."""
    add_study_arguments(sub.add_parser(
        "sweep", help="run a study file (axes x repeats) on Dask: results.nc, results.csv, report.html"))


def _terminate_cleanly() -> None:
    """SIGTERM unwinds like Ctrl-C, so the LocalCluster is closed (finished case records are already on disk)."""
    def handler(signum, frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, handler)


def _prepare_out(out: Path, study) -> None:
    from labio.atomic import atomic_write_text

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


def run_study(args, study, copy_of=None):
    """Prepare ``--out``, run the study's missing cases on Dask; returns ``(summary, summary lines, versions)``."""
    from workbench.store import DatasetStore
    from workbench.studies.sweep import environment_versions, run_sweep

    _prepare_out(args.out, copy_of or study)
    _terminate_cleanly()
    summary = run_sweep(study, args.out, store=DatasetStore(args.store), scheduler=args.scheduler,
                        workers=args.workers, progress=not args.quiet, points=getattr(args, "points", True))
    return summary, _summary_lines(study, summary, args.scheduler, args.workers), environment_versions()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}" if seconds >= 3600 else \
        f"{seconds // 60}:{seconds % 60:02d}"


def dry_run(args, study) -> int:
    """``--dry-run``: the plan of the study (:func:`workbench.studies.sweep.plan_sweep`) in words."""
    from workbench.store import DatasetStore
    from workbench.studies.sweep import plan_sweep

    if args.out.exists() and not args.out.is_dir():
        raise ValueError(f"--out {args.out} is a file, not a folder")
    cases_dir = args.out / "cases"
    if not (cases_dir.is_dir() and any(cases_dir.glob("*.json"))):
        print(f"{study.name}: timing one case here (no finished case in {args.out} to estimate from) ...", flush=True)
    plan = plan_sweep(study, args.out, store=DatasetStore(args.store), workers=args.workers,
                      points=getattr(args, "points", True))
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else f"{args.workers} process workers"
    axes = [d for d in study.dims if d != "repeat"]
    print(f"{study.name}: {plan['cases']} cases ({len(axes)} axes: {', '.join(axes) or 'none'}; "
          f"{plan['seeds']} seeds each), {plan['done']} already done in {args.out}, {plan['todo']} to run")
    if plan["timed_here"]:
        labels = ", ".join(f"{k} = {v}" for k, v in plan["timed_here"]["labels"].items())
        print(f"  one case ({labels}) took {plan['timed_here']['seconds']:.1f} s here "
              "(its dataset's rendering included unless the store held it); its result is kept")
    if plan["estimate_s"] is None:
        print("  no time estimate: no case finished" + (" (the timed case failed)" if plan["todo"] else ""))
    else:
        print(f"  estimate: {plan['todo']} cases x {plan['per_case_s']:.1f} s (median of {plan['from_cases']} "
              f"finished) / {plan['workers']} workers = {_duration(plan['estimate_s'])} on {where}, plus about a "
              "minute per worker to compile the DIC kernels")
    return 0


def sweep_command(args) -> int:
    from workbench.studies.study import load_study
    from workbench.studies.report import write_study_outputs

    study = load_study(args.study)                   # every error before any work
    if getattr(args, "dry_run", False):
        return dry_run(args, study)
    summary, lines, versions = run_study(args, study)
    paths = write_study_outputs(study, args.out, summary.records, lines, versions)
    print("\n".join(lines + paths["summary"]))
    print(f"report: {paths['html']}")
    return 1 if summary.failed else 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("sweep", None): sweep_command}
