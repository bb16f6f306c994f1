"""Error budgets: every error source of a study switched on alone, then all together, drawn as a waterfall.

A budget file is a study file with a ``[budget]`` table instead of axes::

    [study]
    name = "rigid-motion budget"
    repeats = 2
    [scenario]
    experiment = "rigid_motion"
    [[budget.source]]
    name = "print scale -0.5 %"
    set = { "scenario.target.print_scale_error" = -0.005 }
    [[budget.source]]
    name = "bowed board 0.5 mm"
    set = { "scenario.target.bow_sag_mm" = 0.5 }

The cases are ``baseline`` (the scenario as given: sources off), each source alone, and ``all sources``.
Two sums tell how far the sources add: **linear** (``baseline + sum of (alone - baseline)``; the rule for
signed, systematic metrics such as a mean error) and **in quadrature** (``sqrt(baseline^2 + sum of
(alone^2 - baseline^2))``; the rule for independent random errors such as a standard deviation). Both are
reported against the all-sources case.
"""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from labio.atomic import atomic_write_text
from workbench.config import ConfigError
from workbench.studies.study import CaseSpec, Study, apply_assignments

BASELINE = "baseline"
ALL = "all sources"


def budget_study(base: Study, metric: str) -> Study:
    """The cases-mode study of a budget file's sources (see the module doc); errors name the file and key."""
    from workbench.studies.cases import experiment_metrics

    where = base.source
    table = base.extra.get("budget")
    if table is None:
        raise ConfigError(f"{where}: budget: a budget needs a [budget] table with [[budget.source]] entries")
    if base.axes or base.cases:
        raise ConfigError(f"{where}: a budget file has [[budget.source]] entries, not [[axis]] or [[case]] tables")
    if not isinstance(table, dict) or set(table) - {"source"}:
        bad = sorted(set(table) - {"source"}) if isinstance(table, dict) else ["(not a table)"]
        raise ConfigError(f"{where}: budget.{bad[0]}: unknown key (known: source)")
    raw = table.get("source", [])
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{where}: budget.source: expected at least one [[budget.source]] table")
    known = experiment_metrics(base.scenario.experiment)
    if metric not in known:
        raise ConfigError(f"--metric {metric}: not a metric of the {base.scenario.experiment} experiment "
                          f"(its metrics: {', '.join(known)})")
    sources, union = [], {}
    for i, entry in enumerate(raw):
        key = f"budget.source[{i}]"
        if not isinstance(entry, dict) or set(entry) - {"name", "set"}:
            bad = sorted(set(entry) - {"name", "set"}) if isinstance(entry, dict) else ["(not a table)"]
            raise ConfigError(f"{where}: {key}.{bad[0]}: unknown key (known: name, set)")
        name, assignments = entry.get("name"), entry.get("set")
        if not isinstance(name, str) or not name or name in (BASELINE, ALL):
            raise ConfigError(f"{where}: {key}.name: expected a source name (not {BASELINE!r} or {ALL!r}), got {name!r}")
        if not isinstance(assignments, dict) or not assignments:
            raise ConfigError(f"{where}: {key}.set: expected a table of the parameters the source sets")
        apply_assignments(base.scenario, base.instrument, list(assignments.items()), f"{where}: {key} ({name})")
        for path, value in assignments.items():
            if path in union and union[path] != value:
                raise ConfigError(f"{where}: {key}.set: {path} is set to {union[path]!r} by another source")
            union[path] = value
        sources.append(CaseSpec(name, tuple(assignments.items())))
    names = [s.name for s in sources]
    if len(set(names)) != len(names):
        raise ConfigError(f"{where}: budget.source: source names must differ")
    cases = (CaseSpec(BASELINE, ()),) + tuple(sources) + (CaseSpec(ALL, tuple(union.items())),)
    return dataclasses.replace(base, mode="cases", cases=cases, metrics=(metric,))


def parse_at(text: str | None) -> tuple[str, float] | None:
    """``--at DIM=VALUE`` as ``(dim, value)``."""
    if text is None:
        return None
    dim, sep, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not dim or not math.isfinite(number):
        raise ValueError(f"--at {text}: expected DIM=VALUE with a number, e.g. stage_mm=10")
    return dim.strip(), number


def budget_rows(ds, metric: str, at: tuple[str, float] | None) -> tuple[list[dict], dict]:
    """Per case: mean and std over the repeats, contribution (alone - baseline); and the two sum checks."""
    da = ds[metric]
    own = [d for d in da.dims if d not in ("case", "repeat")]
    if own:
        if at is None or at[0] not in own:
            raise ValueError(f"metric {metric} is a function of {own[0]} (values {ds[own[0]].values.tolist()}): "
                             f"choose one with --at {own[0]}=VALUE")
        values = ds[at[0]].values
        index = int(np.argmin(np.abs(values - at[1])))
        if not np.isclose(values[index], at[1], rtol=1e-9, atol=1e-9):
            raise ValueError(f"--at {at[0]}={at[1]:g}: no such {at[0]} (values {values.tolist()})")
        da = da.isel({at[0]: index})
    elif at is not None:
        raise ValueError(f"--at {at[0]}: metric {metric} has no dimension {at[0]}")
    mean = da.mean("repeat", skipna=True).values
    std = da.std("repeat", skipna=True).values
    names = [str(c) for c in ds["case"].values]
    base = mean[names.index(BASELINE)]
    rows = [{"case": n, "mean": float(m), "std": float(s), "contribution": float(m - base)}
            for n, m, s in zip(names, mean, std)]
    sources = [r for r in rows if r["case"] not in (BASELINE, ALL)]
    together = rows[names.index(ALL)]["mean"]
    linear = base + sum(r["contribution"] for r in sources)
    quad_sq = base ** 2 + sum(r["mean"] ** 2 - base ** 2 for r in sources)
    quadrature = math.copysign(math.sqrt(abs(quad_sq)), quad_sq)
    check = {"baseline": float(base), "all_together": float(together), "linear_sum": float(linear),
             "quadrature_sum": float(quadrature),
             "linear_sum_vs_all": float(linear / together) if together else float("nan"),
             "quadrature_sum_vs_all": float(quadrature / together) if together else float("nan"),
             "dominant_source": max(sources, key=lambda r: abs(r["contribution"]))["case"]}
    return rows, check


def waterfall_png(rows: list[dict], check: dict, metric: str, label: str) -> str:
    """The waterfall: baseline, each source's contribution stacked, the linear sum, and all together."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from workbench.studies.report import png_base64

    sources = [r for r in rows if r["case"] not in (BASELINE, ALL)]
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * (len(sources) + 3)), 4.4))
    level = check["baseline"]
    ax.bar(0, level, color="0.6", label="baseline")
    for i, r in enumerate(sources, start=1):
        c = r["contribution"]
        ax.bar(i, c, bottom=level, color="C3" if c > 0 else "C2", yerr=r["std"], capsize=3)
        ax.plot([i - 1.4, i + 0.4], [level, level], color="0.3", lw=0.6)
        level += c
    n = len(sources) + 1
    ax.bar(n, check["linear_sum"], color="white", edgecolor="k", hatch="//", label="linear sum")
    ax.plot([n - 0.4, n + 0.4], [check["quadrature_sum"]] * 2, "b-", lw=2, label="quadrature sum")
    together = next(r for r in rows if r["case"] == ALL)
    ax.bar(n + 1, together["mean"], yerr=together["std"], capsize=3, color="C0", label="all sources together")
    ax.set_xticks(range(n + 2))
    ax.set_xticklabels([BASELINE] + [r["case"] for r in sources] + ["sum", ALL], rotation=25, ha="right", fontsize=8)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("error source (switched on alone), their sum, all together")
    ax.set_ylabel(label)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=7)
    ax.set_title(f"Error budget of {metric}", fontsize=10)
    fig.tight_layout()
    png = png_base64(fig)
    plt.close(fig)
    return png


def write_budget(study: Study, out_dir, records: list[dict], metric: str, at, summary_lines: list[str],
                 versions: dict) -> dict:
    """``budget.json``, ``results.nc``, ``results.csv`` and ``report.html`` with the waterfall."""
    from workbench.studies.cases import experiment_module
    from workbench.studies.report import gather, html_table, save_csv, save_netcdf, write_html

    ds = gather(study, records, versions)
    save_netcdf(ds, out_dir / "results.nc")
    save_csv(ds, out_dir / "results.csv")
    rows, check = budget_rows(ds, metric, at)
    description = experiment_module(study.scenario.experiment).METRICS.get(metric, metric)
    label = f"{metric}" + (f" at {at[0]} = {at[1]:g}" if at else "")
    png = waterfall_png(rows, check, metric, label)
    check_text = (f"baseline {check['baseline']:.4g}; all sources together {check['all_together']:.4g}; linear sum "
                  f"{check['linear_sum']:.4g} ({check['linear_sum_vs_all']:.3f}x), quadrature sum "
                  f"{check['quadrature_sum']:.4g} ({check['quadrature_sum_vs_all']:.3f}x); dominant source: "
                  f"{check['dominant_source']}")
    table = html_table(["case", f"{label} (mean over repeats)", "std over repeats", "contribution vs baseline"],
                       [[r["case"], r["mean"], r["std"], r["contribution"]] for r in rows])
    lines = summary_lines + [f"metric: {label}: {description}", check_text]
    html_path = write_html(out_dir / "report.html", study, ds, [(f"waterfall: {label}", png)], lines, [table])
    result = {"metric": metric, "at": list(at) if at else None, "rows": rows, "check": check}
    atomic_write_text(out_dir / "budget.json", json.dumps(result, indent=1))
    return {**result, "check": check_text, "html": html_path}


__all__ = ["ALL", "BASELINE", "budget_rows", "budget_study", "parse_at", "waterfall_png", "write_budget"]
