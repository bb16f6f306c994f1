"""Gather a study's case records into an xarray Dataset (NetCDF), a CSV and a self-contained HTML report.

Dimensions: the study's axes (factorial) or ``case`` (listed cases), then ``repeat`` (coordinate ``seed``),
then any dimension of a vector metric (e.g. ``stage_mm`` of the rigid-motion test). Variables: the metrics;
attributes: the study file, its name, the software versions and the sweep's figures. A case that has no
record (failed, or not run) is NaN.
"""
from __future__ import annotations

import base64
import html
import io
import json
import math
import time
from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_bytes, atomic_write_text
from workbench.studies.study import Study


def _coord(values) -> np.ndarray:
    values = list(values)
    if all(isinstance(v, bool) for v in values):
        return np.array([str(v).lower() for v in values])
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return np.array(values, dtype=float if any(isinstance(v, float) for v in values) else int)
    return np.array([str(v) for v in values])


def gather(study: Study, records: list[dict], versions: dict | None = None):
    """The xarray Dataset of a study's metrics (see the module doc)."""
    import xarray as xr

    dims = list(study.dims)
    if study.mode == "factorial":
        coords = {a.name: _coord(a.values) for a in study.axes}
        label_index = [{_key(v): i for i, v in enumerate(a.values)} for a in study.axes]
    else:
        coords = {"case": np.array([c.name for c in study.cases])}
        label_index = [{_key(c.name): i for i, c in enumerate(study.cases)}]
    coords["repeat"] = np.arange(len(study.seeds))
    shape = [len(coords[d]) for d in dims]
    ok = [r for r in records if r.get("status") == "ok"]
    names = list(study.metrics) or sorted({m for r in ok for m in r["metrics"]})
    extra_dims, extra_coords = {}, {}
    for r in ok:
        for m, mdims in r.get("dims", {}).items():
            extra_dims.setdefault(m, tuple(mdims))
        for d, values in r.get("coords", {}).items():
            extra_coords.setdefault(d, values)
    data = {}
    for m in names:
        mdims = extra_dims.get(m, ())
        mshape = shape + [len(extra_coords[d]) for d in mdims]
        data[m] = np.full(mshape, np.nan)
    done = np.zeros(shape, dtype=bool)
    for r in ok:
        labels = r["labels"]
        index = [label_index[i][_key(labels[d])] for i, d in enumerate(dims[:-1])] + [labels["repeat"]]
        done[tuple(index)] = True
        for m in names:
            value = r["metrics"].get(m)
            if value is None:
                continue
            arr = np.asarray(value, dtype=float)
            target = data[m][tuple(index)]
            if np.shape(target) != arr.shape:
                raise ValueError(f"case {r['hash']}: metric {m} has shape {arr.shape}, expected {np.shape(target)}")
            data[m][tuple(index)] = arr
    variables = {m: (dims + list(extra_dims.get(m, ())), v) for m, v in data.items()}
    variables["case_done"] = (dims, done.astype(np.int8))
    all_coords = {**coords, **{d: np.asarray(v, dtype=float) for d, v in extra_coords.items()}}
    all_coords["seed"] = ("repeat", np.array(study.seeds))
    ds = xr.Dataset(variables, coords=all_coords)
    ds.attrs.update({"study": study.name, "description": study.description, "study_file": study.source,
                     "study_text": study.source_text, "study_mode": study.mode,
                     "axes": json.dumps([{"name": a.name, "parameter": a.parameter} for a in study.axes]),
                     "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                     "versions": json.dumps(versions or {}), "experiment": study.scenario.experiment})
    return ds


def _key(value):
    return json.dumps(value, sort_keys=True)


def save_netcdf(ds, path: Path) -> Path:
    """NetCDF-3 through SciPy (no compiled NetCDF library needed), written whole or not at all."""
    import os
    import tempfile

    handle, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    os.close(handle)
    try:
        ds.to_netcdf(tmp, engine="scipy")
        data = Path(tmp).read_bytes()
    finally:
        os.unlink(tmp)
    return atomic_write_bytes(path, data)


def save_csv(ds, path: Path) -> Path:
    """Long-format CSV: one row per case and metric element."""
    frame = ds.drop_vars("case_done").to_dataframe().reset_index()
    buffer = io.StringIO()
    frame.to_csv(buffer, index=False)
    return atomic_write_text(path, buffer.getvalue())


# ------------------------------------------------------------------------------------------------------------
def png_base64(fig) -> str:
    """A matplotlib figure as base64 PNG text (110 dpi), for an ``<img src="data:image/png;base64,...">``."""
    from labio.figures import png_bytes

    return base64.b64encode(png_bytes(fig, dpi=110, close=False)).decode()


def metric_figures(ds, study: Study, floors: dict, descriptions: dict) -> list[tuple[str, str]]:
    """One (title, base64 PNG) per metric: lines over the first axis (one per value of the second), a heat map
    for two axes, bars for listed cases, lines over a metric's own dimension; mean over repeats with the
    standard deviation as error bars, the theoretical floor dashed where one exists."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from labio.figures import quantity_label

    out = []
    floor_names = {f for f, _ in floors.values()}
    for m in ds.data_vars:
        if m == "case_done" or (m in floor_names and m not in study.metrics and study.metrics):
            continue
        da = ds[m]
        mean, std = da.mean("repeat", skipna=True), da.std("repeat", skipna=True)
        floor = ds[floors[m][0]].mean("repeat", skipna=True) if m in floors and floors[m][0] in ds else None
        own = [d for d in da.dims if d not in study.dims]
        axes_dims = [d for d in study.dims if d != "repeat"]
        averaged = axes_dims[2:] if not own else axes_dims[1:]
        if averaged:               # more axes than a plot shows: the rest are averaged (said in the title)
            mean, std = mean.mean(averaged), std.mean(averaged)
            floor = floor.mean(averaged) if floor is not None else None
            axes_dims = [d for d in axes_dims if d not in averaged]
        panels = 2 if (len(axes_dims) == 2 and not own) else 1
        fig, axs = plt.subplots(1, panels, figsize=(6.2 * panels, 4.2), squeeze=False)
        ax = axs[0, 0]
        if own:                                   # a vector metric: lines over its own dimension
            x = ds[own[0]].values
            flat = mean.stack(_c=axes_dims) if axes_dims else mean.expand_dims(_c=[0])
            sflat = std.stack(_c=axes_dims) if axes_dims else std.expand_dims(_c=[0])
            for i in range(flat.sizes["_c"]):
                label = ", ".join(f"{v}" for v in np.atleast_1d(flat["_c"].values[i])) if axes_dims else m
                ax.errorbar(x, flat.isel(_c=i).values, yerr=sflat.isel(_c=i).values, marker="o", ms=3, capsize=2,
                            label=str(label))
            ax.set_xlabel(quantity_label(own[0]))
        elif study.mode == "cases":
            labels = [str(v) for v in ds["case"].values]
            ax.bar(range(len(labels)), mean.values, yerr=std.values, capsize=3, color="C0")
            if floor is not None:
                ax.plot(range(len(labels)), floor.values, "k_", ms=20, label=floors[m][1])
            ax.set_xticks(range(len(labels)))
            ax.set_xticklabels(labels, rotation=30, ha="right", fontsize=7)
            ax.set_xlabel("case")
        elif not axes_dims:                       # repeats only: one value, mean ± std over the seeds
            ax.bar([0], [float(mean.values)], yerr=[float(std.values)], capsize=3, color="C0", label="measured")
            if floor is not None:
                ax.plot([0], [float(floor.values)], "k_", ms=30, label=floors[m][1])
            ax.set_xticks([0])
            ax.set_xticklabels([f"{ds.sizes.get('repeat', 1)} seeds"])
            ax.set_xlabel("all cases (mean ± std over the seeds)")
        else:
            first = axes_dims[0]
            x = ds[first].values
            if len(axes_dims) == 1:
                ax.errorbar(x, mean.values, yerr=std.values, marker="o", capsize=3, label="measured")
                if floor is not None:
                    ax.plot(x, floor.values, "k--", label=floors[m][1])
            else:
                second = axes_dims[1]
                for j, value in enumerate(ds[second].values):
                    color = f"C{j % 10}"
                    ax.errorbar(x, mean.isel({second: j}).values, yerr=std.isel({second: j}).values, marker="o",
                                ms=3, capsize=2, color=color,
                                label=f"{quantity_label(second)} = {value}")
                    if floor is not None:
                        ax.plot(x, floor.isel({second: j}).values, "--", color=color, lw=1)
                if floor is not None:
                    ax.plot([], [], "k--", lw=1, label=f"floor: {floors[m][1]}")
                hm = axs[0, 1].imshow(mean.transpose(second, first).values, origin="lower", aspect="auto",
                                      cmap="viridis")
                axs[0, 1].set_xticks(range(len(x)))
                axs[0, 1].set_xticklabels([f"{v:g}" if isinstance(v, (int, float, np.number)) else str(v) for v in x])
                axs[0, 1].set_yticks(range(ds.sizes[second]))
                axs[0, 1].set_yticklabels([str(v) for v in ds[second].values])
                axs[0, 1].set_xlabel(quantity_label(first))
                axs[0, 1].set_ylabel(quantity_label(second))
                fig.colorbar(hm, ax=axs[0, 1], label=quantity_label(m))
                if m in floors and floors[m][0] in ds:
                    ratio = (mean / floor).transpose(second, first).values
                    for (i, j), r in np.ndenumerate(ratio):
                        if math.isfinite(r):
                            axs[0, 1].text(j, i, f"{r:.2f}×", ha="center", va="center", fontsize=7, color="w")
                    axs[0, 1].set_title("mean; numbers: measured / floor", fontsize=8)
            ax.set_xlabel(quantity_label(first))
        ax.set_ylabel(quantity_label(m))
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
        title = descriptions.get(m, m) + (f" (mean over {', '.join(averaged)})" if averaged else "")
        fig.suptitle(f"{m}: {title}", fontsize=9)
        fig.tight_layout()
        out.append((m, png_base64(fig)))
        plt.close(fig)
    return out


def write_html(path: Path, study: Study, ds, figures, summary_lines: list[str], tables: list[str] = ()) -> Path:
    """A self-contained HTML report (figures embedded), written atomically."""
    parts = ["<!doctype html><html><head><meta charset='utf-8'>",
             f"<title>{html.escape(study.name)}</title>",
             "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;line-height:1.4}"
             "img{max-width:100%;height:auto}"
             "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 6px;font-size:13px}"
             "pre{background:#f6f6f6;padding:8px;overflow:auto;font-size:12px}</style></head><body>",
             f"<h1>Study: {html.escape(study.name)}</h1>",
             f"<p>{html.escape(study.description)}</p>" if study.description else "",
             "<ul>" + "".join(f"<li>{html.escape(s)}</li>" for s in summary_lines) + "</ul>"]
    parts += list(tables)
    for name, png in figures:
        parts.append(f"<h2>{html.escape(name)}</h2><img alt='{html.escape(name)}' src='data:image/png;base64,{png}'>")
    parts.append("<h2>Study file</h2><pre>" + html.escape(study.source_text or "(none)") + "</pre>")
    parts.append("<h2>Versions</h2><pre>" + html.escape(ds.attrs.get("versions", "")) + "</pre></body></html>")
    return atomic_write_text(path, "\n".join(parts))


def html_table(header: list[str], rows: list[list]) -> str:
    def cell(v):
        return f"{v:.4g}" if isinstance(v, float) else html.escape(str(v))
    return ("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"
            + "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows) + "</table>")


def write_study_outputs(study: Study, out_dir: Path, records: list[dict], summary_lines: list[str],
                        versions: dict, *, html: bool = True) -> dict:
    """``results.nc``, ``results.csv`` and ``report.html`` of a study; returns their paths, and under ``figures``
    the report's (title, base64 PNG) figures. ``html=False``: no ``report.html`` (a study with its own report,
    such as the Fig 6 causes study, puts the figures in it)."""
    from workbench.studies.cases import experiment_module

    module = experiment_module(study.scenario.experiment)
    ds = gather(study, records, versions)
    out = {"netcdf": save_netcdf(ds, out_dir / "results.nc"), "csv": save_csv(ds, out_dir / "results.csv")}
    figures = metric_figures(ds, study, getattr(module, "FLOORS", {}), getattr(module, "METRICS", {}))
    verdict = module.summary_lines(ds) if hasattr(module, "summary_lines") else []
    if html:
        out["html"] = write_html(out_dir / "report.html", study, ds, figures, summary_lines + verdict)
    out["summary"] = verdict
    out["figures"] = figures
    return out


__all__ = ["gather", "html_table", "metric_figures", "save_csv", "save_netcdf", "write_html", "write_study_outputs"]
