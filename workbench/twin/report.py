"""The twin's report: ``report.html`` (self-contained), ``report.md``, ``twin.json``, ``twin_points.csv``, figures.

What a user looks at first: the predicted noise floor -- the twin's repeats and, beside them, the instrument's own
predicted sigma of a static repeat (:mod:`measurement.uncertainty`) -- and, with a static pair, what the instrument
measured on it; the what-if table with the top recommendation, maps of the predicted noise over the ROI, the
speckle-quality figures (image, histogram, noise model), and the Star curve on their pattern.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_text, atomic_writer

from ..reporting.html_report import write_html_report
from .whatif import advice


def _fmt(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return f"{value:.{digits}g}"


def _png(fig, path: Path) -> str:
    from labio.figures import png_bytes

    data = png_bytes(fig, dpi=110, bbox_inches="tight")
    with atomic_writer(path, "wb") as f:
        f.write(data)
    return path.name


def _grid(x, y, v):
    xs, ix = np.unique(x, return_inverse=True)
    ys, iy = np.unique(y, return_inverse=True)
    out = np.full((ys.size, xs.size), np.nan)
    out[iy, ix] = v
    return out, (xs.min(), xs.max(), ys.max(), ys.min())


def _local_rms(grid: np.ndarray, size: int = 5) -> np.ndarray:
    """RMS over the finite values of each ``size`` x ``size`` neighbourhood (NaN where the point is NaN)."""
    from scipy import ndimage

    ok = np.isfinite(grid)
    total = ndimage.uniform_filter(np.where(ok, grid ** 2, 0.0), size, mode="constant")
    count = ndimage.uniform_filter(ok.astype(float), size, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ok & (count > 0), np.sqrt(total / count), np.nan)


def _maps_figure(result, out: Path) -> str | None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    maps = result.maps
    per_point = maps.get("per_point")
    names = ["U", "V", "W"] if result.inputs.stereo else ["u", "v"]
    unit = "µm" if result.inputs.stereo else "px"
    rows = []
    if per_point is not None and np.isfinite(per_point).any():     # needs two twin repeats or more
        rows.append(("twin repeats: 1σ (local RMS, 5 x 5 points)", per_point))
    if maps.get("instrument_sigma") is not None:
        rows.append(("instrument's 1σ (measurement.uncertainty)", maps["instrument_sigma"]))
    if maps.get("measured") is not None:
        rows.append(("your static pair: measured value (mean removed)", maps["measured"]))
    if not rows:
        return None
    fig, axes = plt.subplots(len(rows), len(names), figsize=(4.2 * len(names), 2.9 * len(rows)), squeeze=False)
    grids = [[_grid(maps["x_px"], maps["y_px"], values[:, c]) for c in range(len(names))] for _, values in rows]
    for r, (title, _) in enumerate(rows):
        if title.startswith("twin"):          # a per-point spread from a few repeats is itself noisy
            grids[r] = [(_local_rms(g), extent) for g, extent in grids[r]]
    for r, (title, values) in enumerate(rows):
        for c, name in enumerate(names):
            grid, extent = grids[r][c]
            ax = axes[r, c]
            finite = grid[np.isfinite(grid)]
            if "measured" in title:
                lim = np.percentile(np.abs(finite), 99) if finite.size else 1
                im = ax.imshow(grid, extent=extent, cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="equal")
            else:
                # the twin's and the instrument's sigma on one scale, so that the maps compare
                both = np.concatenate([grids[k][c][0].ravel() for k, (t, _) in enumerate(rows) if "measured" not in t])
                both = both[np.isfinite(both)]
                hi = np.percentile(both, 99) if both.size else 1
                im = ax.imshow(grid, extent=extent, cmap="viridis", vmin=0, vmax=hi, aspect="equal")
            ax.set_title(f"{name}: {title}", fontsize=8)
            ax.set_xlabel("x (px, left image)", fontsize=7)
            ax.set_ylabel("y (px, left image)", fontsize=7)
            ax.tick_params(labelsize=6)
            fig.colorbar(im, ax=ax, label=unit, shrink=0.8)
    return _png(fig, out / "noise_maps.png")


def _speckle_figure(result, out: Path) -> str:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sides = list(result.speckle)
    fig, axes = plt.subplots(len(sides), 3, figsize=(13, 3.3 * len(sides)), squeeze=False)
    region = result.inputs.region
    for r, side in enumerate(sides):
        sp = result.speckle[side]
        image = result.inputs.images[side]
        ax = axes[r, 0]
        if side == "left":
            ys, xs = np.nonzero(region)
            y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        else:
            y0, y1, x0, x1 = 0, image.shape[0], 0, image.shape[1]
        cy, cx = (y0 + y1) // 2, (x0 + x1) // 2
        crop = image[max(y0, cy - 100):min(y1, cy + 100), max(x0, cx - 150):min(x1, cx + 150)]
        ax.imshow(crop, cmap="grey", interpolation="nearest")
        ax.set_title(f"{side}: pattern (centre of the ROI, 1:1 px), speckle {sp['speckle_size_px']:.2f} px",
                     fontsize=8)
        ax.axis("off")
        ax = axes[r, 1]
        edges = np.asarray(sp["bin_edges"])
        ax.bar(edges[:-1], sp["histogram"], width=np.diff(edges), align="edge", color="0.4")
        ax.axvline(sp["mean_grey"], color="C1", label=f"mean {sp['mean_grey']:.1f}")
        ax.set_xlabel("grey level", fontsize=8)
        ax.set_ylabel("pixels", fontsize=8)
        ax.set_title(f"histogram: contrast (std/mean) {sp['contrast']:.2f}, saturated "
                     f"{100 * sp['saturated_fraction']:.2f} %", fontsize=8)
        ax.legend(fontsize=7)
        ax = axes[r, 2]
        model = result.noise_models[side]
        if model.bin_grey.size:
            ax.plot(model.bin_grey, np.sqrt(model.bin_variance), "o", ms=3, label="static pair, per grey bin")
        g = np.linspace(0, max(float(edges[-1]), 1.0), 100)
        ax.plot(g, model.sigma_at(g), "-", label=f"model ({model.source})")
        ax.set_xlabel("grey level", fontsize=8)
        ax.set_ylabel("noise σ (grey)", fontsize=8)
        ax.set_title(f"sensor noise: σ = {model.sigma_grey:.3g} grey", fontsize=8)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return _png(fig, out / "speckle.png")


def _whatif_figure(result, out: Path) -> str | None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in result.whatif if "displacement_noise" in r]
    if not rows:
        return None
    fig, axes = plt.subplots(1, 2, figsize=(12, 0.45 * len(rows) + 1.2))
    labels = [r["label"] for r in rows][::-1]
    y = np.arange(len(rows))
    unit = "µm" if result.inputs.stereo else "px"
    disp = [r["displacement_noise"] for r in rows][::-1]
    sigma = [r.get("instrument_sigma_figure", math.nan) for r in rows][::-1]
    axes[0].barh(y, disp, color=["C2" if r.get("rank") == 1 else "C0" for r in rows][::-1], label="twin repeats")
    axes[0].plot(sigma, y, "k|", ms=14, label="instrument's sigma (measurement.uncertainty)")
    axes[0].set_yticks(y, labels, fontsize=7)
    axes[0].set_ylabel("what if", fontsize=8)
    axes[0].set_xlabel(f"displacement noise, RMS of components ({unit})", fontsize=8)
    axes[0].legend(fontsize=7)
    axes[1].barh(y, [r["strain_noise_ue"] for r in rows][::-1], color="C3")
    axes[1].set_yticks(y, [""] * len(rows))
    axes[1].set_xlabel("strain noise, RMS of E11, E22 (µε)", fontsize=8)
    fig.tight_layout()
    return _png(fig, out / "whatif.png")


def _star_figure(result, out: Path) -> str | None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = result.prediction.get("resolution")
    if not res or not res.get("curve_period_px"):
        return None
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.plot(res["curve_period_px"], res["curve_ratio"], "-", lw=1)
    ax.axhline(0.9, color="0.5", ls="--", lw=0.8)
    if res.get("l10_px") and math.isfinite(res["l10_px"]):
        ax.axvline(res["l10_px"], color="C3", lw=0.8, label=f"l10 = {res['l10_px']:.1f} px")
        ax.legend(fontsize=8)
    ax.set_xscale("log")
    # plain numbers at round periods: the log axis' own minor labels (2x10^1, 3x10^1, ...) overlapped
    from matplotlib.ticker import NullFormatter

    periods = np.asarray(res["curve_period_px"], float)
    ticks = [t for t in (2, 5, 10, 20, 30, 50, 100, 200, 300, 500, 1000) if periods.min() <= t <= periods.max()]
    ax.set_xticks(ticks)
    ax.set_xticklabels([f"{t:g}" for t in ticks])
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("Star period (px)", fontsize=8)
    ax.set_ylabel("measured / imposed amplitude", fontsize=8)
    ax.set_title("spatial resolution on your pattern (DIC Challenge 2.0 Star)", fontsize=9)
    return _png(fig, out / "star.png")


def report_markdown(result, figures: dict) -> str:
    s = result.summary()
    stereo = result.inputs.stereo
    unit = "µm" if stereo else "px"
    names = ["U_um", "V_um", "W_um"] if stereo else ["u_px", "v_px"]
    p = result.prediction
    lines = ["# Digital twin of your rig", ""]
    kind = "stereo rig" if stereo else "one camera (2-D DIC)"
    lines += [f"- **rig**: {kind}" + (f" from `{result.inputs.calibration}`" if result.inputs.calibration else ""),
              "- **images**: " + ", ".join(f"{k} `{Path(v).name}`" for k, v in s["inputs"].items()),
              f"- **bit depth**: {result.inputs.bit_depth}; **ROI**: {result.roi_used}",
              f"- **settings**: subset {result.settings.subset_px} px, step {s['dic_step_px']} px, order "
              f"{result.settings.order}, {result.settings.interpolation}, strain window "
              f"{result.settings.strain_window} points (virtual strain gauge {_fmt(p.get('vsg_px'))} px)",
              f"- twin repeats: {p.get('repeats')} static pair(s), {p.get('points')} points", ""]
    lines += ["## Predicted noise floor", "",
              "Static noise (1σ over the ROI, mean removed) of the instrument with your settings on the twin's "
              "static pairs; beside it the instrument's own predicted sigma of a static repeat "
              "(measurement.uncertainty: each subset's Hessian and your noise model"
              + (", carried through both cameras' triangulation" if stereo else "") +
              "; RMS over the same points), the figure the instrument reports with every measurement.", "",
              "| quantity | twin repeats | instrument's sigma |" +
              (" your static pair (measured) | twin / measured | instrument / measured |" if result.comparison
               else ""),
              "|---|---|---|" + ("---|---|---|" if result.comparison else "")]
    for n in names:
        row = f"| {n.replace('_um', ' (µm)').replace('_px', ' (px)')} | {_fmt(p['noise'].get(n))} | " \
              f"{_fmt(p['instrument_sigma'].get(n))} |"
        if result.comparison:
            c = result.comparison[n]
            row += f" {_fmt(c['measured'])} | {_fmt(c['ratio'])} | {_fmt(c.get('instrument_ratio'))} |"
        lines.append(row)
    for n in ("E11", "E22", "E12"):
        if n in p["strain_ue"]:
            row = f"| {n} (µε) | {_fmt(p['strain_ue'][n])} | - |"
            if result.comparison and f"{n}_ue" in result.comparison:
                c = result.comparison[f"{n}_ue"]
                row += f" {_fmt(c['measured'])} | {_fmt(c['ratio'])} | - |"
            lines.append(row)
    lines.append("")
    if "bias" in p:
        b = p["bias"]
        lines.append(f"- **interpolation bias** on your pattern (noise-free sub-pixel shifts 0.1-0.5 px): max "
                     f"{_fmt(b['max_abs_px'])} px" + (f" = {_fmt(b.get('max_abs_um'))} µm" if b.get("max_abs_um")
                                                       else ""))
    if "resolution" in p:
        r = p["resolution"]
        lines.append(f"- **spatial resolution** l10 on your pattern: {_fmt(r.get('l10_px'))} px"
                     + (f" = {_fmt(r.get('l10_mm'))} mm" if r.get("l10_mm") else "")
                     + f" (theory for the subset and order: {_fmt(p.get('l10_theory_px'))} px)")
    if p.get("mm_per_px"):
        lines.append(f"- scale at the specimen: {p['mm_per_px'] * 1e3:.2f} µm per pixel")
    lines.append("")
    if figures.get("maps"):
        lines += ["## Maps over the ROI", "", f"![predicted noise maps]({figures['maps']})", ""]
    lines += ["## What if", "",
              "Each row changes one setting of yours, measured on the same twin noise draws; ranked by the predicted "
              f"change of the {result.whatif[0].get('objective', 'displacement') if result.whatif else ''} "
              "noise. l10 (theory) and the virtual strain gauge say what each costs in spatial resolution.", ""]
    if result.whatif:
        lines += [f"| rank | change | displacement noise ({unit}) | vs yours | instrument's sigma ({unit}) | "
                  "strain noise (µε) | l10 theory (px) | VSG (px) |", "|---|---|---|---|---|---|---|---|"]
        for r in result.whatif:
            if "displacement_noise" not in r:
                lines.append(f"| - | {r['label']} | {r.get('reason', '')} | | | | | |")
                continue
            change = "-" if r["label"].startswith("baseline") else (
                f"{100 * r['change']:+.0f} %" if r.get("change") is not None and math.isfinite(r["change"]) else "-")
            label = r["label"] + (f" ({r['note']})" if r.get("note") else "")
            lines.append(f"| {r.get('rank') or ''} | {label} | {_fmt(r['displacement_noise'])} | {change} | "
                         f"{_fmt(r.get('instrument_sigma_figure'))} | {_fmt(r['strain_noise_ue'])} | "
                         f"{_fmt(r['l10_theory_px'])} | {_fmt(r['vsg_px'])} |")
        lines.append("")
        if figures.get("whatif"):
            lines += [f"![what-if]({figures['whatif']})", ""]
    if result.whatif:
        # the same verdict the terminal prints (one function says it)
        for k, line in enumerate(advice(result.whatif)["lines"]):
            text = f"{line[0].upper()}{line[1:]}."
            lines += [f"**{text}**" if k == 0 else text, ""]
    if result.whatif_real:
        w = result.whatif_real
        lines += [f"**The lowest-noise change applied to your static pair** ({w['label']}): measured "
                  f"{_fmt(w['measured_before'])} -> {_fmt(w['measured_after'])} "
                  f"({100 * w['measured_change']:+.0f} %); the twin predicted {_fmt(w['predicted_before'])} -> "
                  f"{_fmt(w['predicted_after'])} ({100 * w['predicted_change']:+.0f} %).", ""]
    lines += ["## Speckle quality", ""]
    for side, sp in result.speckle.items():
        model = result.noise_models[side]
        lines.append(f"- **{side}**: speckle size {sp['speckle_size_px']:.2f} px (autocorrelation radius "
                     f"{sp['autocorrelation_radius_px']:.2f} px), mean grey {sp['mean_grey']:.1f}, contrast "
                     f"{sp['contrast']:.2f}, 1-99 % {sp['p1_grey']:.0f}-{sp['p99_grey']:.0f}, MIG "
                     f"{sp['mig_grey_per_px']:.2f} grey/px, median SSSIG {sp['sssig_median_grey2']:.3g} grey², "
                     f"saturated {100 * sp['saturated_fraction']:.2f} %; noise σ {model.sigma_grey:.3g} grey "
                     f"({model.source}; read {model.read_noise_grey:.3g} grey"
                     + (f", gain {model.electrons_per_grey:.3g} e-/grey" if model.electrons_per_grey else "")
                     + (f"; illumination change between the exposures {model.smooth_change_grey:.2f} grey, not "
                        "counted as noise" if model.smooth_change_grey else "") + ")")
        lines.append(f"  - subset advice: {sp['advice']['message']}")
    lines += ["", f"![speckle quality]({figures['speckle']})", ""]
    if figures.get("star"):
        lines += [f"![Star curve]({figures['star']})", ""]
    notes = s["notes"]
    if notes:
        lines += ["## How the twin was made", ""] + [f"- {n}" for n in notes] + [""]
    lines += ["## Timings", "", ", ".join(f"{k} {v:.1f} s" for k, v in result.timings_s.items()), ""]
    return "\n".join(lines)


def write_points_csv(result, path: Path) -> None:
    maps = result.maps
    names = ["U_um", "V_um", "W_um"] if result.inputs.stereo else ["u_px", "v_px"]
    header = ["x_px", "y_px"] + [f"predicted_sigma_{n}" for n in names] + \
        [f"instrument_sigma_{n}" for n in names] + \
        [f"measured_{n}" for n in names] + ["sssig_x_grey2", "sssig_y_grey2", "mig_grey_per_px"]
    n = len(maps["x_px"])
    empty = np.full((n, len(names)), np.nan)
    cols = [maps["x_px"], maps["y_px"], *maps["per_point"].T,
            *(maps["instrument_sigma"] if maps.get("instrument_sigma") is not None else empty).T,
            *(maps["measured"] if maps.get("measured") is not None else empty).T,
            *(maps["sssig"] if maps.get("sssig") is not None else np.full((n, 3), np.nan)).T]
    with atomic_writer(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in zip(*cols):
            w.writerow(["" if not np.isfinite(v) else f"{v:.6g}" for v in row])


def write_twin_report(result, out_dir) -> Path:
    """Write the twin's report into ``out_dir`` (created); returns the report.html path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures = {"speckle": _speckle_figure(result, out), "maps": _maps_figure(result, out),
               "whatif": _whatif_figure(result, out), "star": _star_figure(result, out)}
    atomic_write_text(out / "twin.json", json.dumps(result.summary(), indent=1))
    write_points_csv(result, out / "twin_points.csv")
    text = report_markdown(result, figures)
    atomic_write_text(out / "report.md", text)
    return write_html_report(out / "report.html", "Digital twin of your rig", text, out)
