"""``workbench budget``: the error budget of a study file (each source alone, then all together)."""
from __future__ import annotations

from workbench.commands.sweep import add_study_arguments, dry_run, run_study


def add_parser(sub) -> None:
    """The ``budget`` subcommand."""
    sw = sub.add_parser("budget", help="error budget: each error source of a study file alone, then all together")
    add_study_arguments(sw)
    sw.add_argument("--metric", required=True, help="the metric whose budget is drawn")
    sw.add_argument("--at", default=None,
                    help="for a metric over a dimension (e.g. stage_mm), the value to take: DIM=VALUE")


def budget_command(args) -> int:
    from workbench.studies.budget import budget_study, parse_at, write_budget
    from workbench.studies.study import load_study

    base = load_study(args.study)
    study = budget_study(base, args.metric)          # checks the [budget] table and the metric
    at = parse_at(args.at)
    if args.dry_run:
        return dry_run(args, study)
    summary, lines, versions = run_study(args, study, copy_of=base)
    result = write_budget(study, args.out, summary.records, args.metric, at, lines, versions)
    print("\n".join(lines))
    for row in result["rows"]:
        print(f"  {row['case']:<32s} {row['mean']:+.4g} ± {row['std']:.2g}   contribution {row['contribution']:+.4g}")
    print(f"  {result['check']}")
    print(f"report: {result['html']}")
    return 1 if summary.failed else 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("budget", None): budget_command}
