"""The score report: what ``workbench score`` writes for a reader (report.md, report.html, metrics.json, CSVs, PNGs).

Per state: the errors as maps over the left reference speckle image; where the result carries strain, the strain
measured beside the truth through the tool's window, the concentration's peak (measured, window-filtered truth,
exact truth) and where it is; line profiles along the user's lines; virtual extensometers between the user's
points. Every figure's axes carry their quantity and unit; colour scales come from the data of their own panel (a
measured map and its truth share one, chosen from both).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from workbench.scoring.datasets import Dataset

#: The summary tables' columns (shown where any state has them): (header, metric keys joined in one cell).
DISPLACEMENT_COLUMNS = (("measured fraction", ("valid_fraction",)), ("u, v error RMS px", ("rms_px",)),
                        ("3-D error RMS µm", ("rms_um",)), ("3-D error max µm", ("max_um",)),
                        ("bias U, V, W µm", ("bias_U_um", "bias_V_um", "bias_W_um")),
                        ("position error RMS µm", ("position_rms_um",)),
                        ("σ coverage u, v", ("sigma_coverage_95_u", "sigma_coverage_95_v")),
                        ("σ coverage U, V, W", ("sigma_coverage_95_U", "sigma_coverage_95_V", "sigma_coverage_95_W")))
STRAIN_COLUMNS = (("e1 error RMS µε (vs windowed truth)", ("strain_rms_e1_vs_windowed_microstrain",)),
                  ("exx, eyy, exy error RMS µε", ("strain_rms_exx_vs_windowed_microstrain",
                                                   "strain_rms_eyy_vs_windowed_microstrain",
                                                   "strain_rms_exy_vs_windowed_microstrain")),
                  ("peak e1 µε: measured / windowed / exact", ("strain_peak_e1_measured_microstrain",
                                                              "strain_peak_e1_windowed_microstrain",
                                                              "strain_peak_e1_exact_microstrain")),
                  ("peak error %", ("strain_peak_e1_error_percent",)),
                  ("strain σ coverage exx, eyy, exy", ("strain_sigma_coverage_95_exx", "strain_sigma_coverage_95_eyy",
                                                       "strain_sigma_coverage_95_exy")))


def _table(scores, columns, with_points: bool) -> list[str]:
    shown = [(h, keys) for h, keys in columns if any(k in s.metrics for s in scores for k in keys)]
    if not shown:
        return []
    head = ["state", "label"] + (["points"] if with_points else []) + [h for h, _ in shown]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in scores:
        cells = [str(s.state), s.label] + ([f"{s.metrics['valid_points']}/{s.metrics['truth_points']}"]
                                           if with_points else [])
        for h, keys in shown:
            cells.append((" / " if " / " in h else ", ").join(_fmt(s.metrics.get(k)) for k in keys))
        lines.append("| " + " | ".join(cells) + " |")
    return lines + [""]


def _fmt(v) -> str:
    if isinstance(v, bool) or v is None:
        return "—" if v is None else str(v)
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, float):
        return "—" if not np.isfinite(v) else f"{v:.4g}"
    return str(v)


def _png(fig) -> bytes:
    from labio.figures import png_bytes

    return png_bytes(fig, dpi=100)


def _speckle(dataset: Dataset):
    from measurement.image_io import read_grey

    return read_grey(dataset.images[0]["left"])


def _limits(*arrays, symmetric: bool = False) -> tuple[float, float]:
    """Colour limits from the 1st-99th percentile of the finite values of ``arrays`` (the data shown)."""
    values = np.concatenate([np.asarray(a, float).ravel() for a in arrays])
    values = values[np.isfinite(values)]
    if not values.size:
        return -1.0, 1.0
    if symmetric:
        m = float(np.percentile(np.abs(values), 99)) or 1e-12
        return -m, m
    lo, hi = (float(v) for v in np.percentile(values, [1, 99]))
    if hi - lo < 1e-9 * max(1.0, abs(hi)):
        pad = max(abs(hi) * 1e-3, 1e-9)
        lo, hi = lo - pad, hi + pad
    return lo, hi


#: The speckle image behind the maps is shown at most this wide (px): the maps' context, not their data (a 5 MP
#: speckle image at full size would make every PNG megabytes of noise).
BACKGROUND_WIDTH_PX = 240


def _background(speckle: np.ndarray) -> np.ndarray:
    import cv2

    h, w = speckle.shape[:2]
    f = min(1.0, BACKGROUND_WIDTH_PX / w)
    return cv2.resize(np.asarray(speckle, np.float32), None, fx=f, fy=f, interpolation=cv2.INTER_AREA) if f < 1 \
        else speckle


def _map_panel(fig, ax, speckle, x, y, values, title, unit, lims, cmap, marks=()):
    from workbench.scoring.strain import grid_layout

    ok = np.isfinite(values)
    h, w = speckle.shape[:2]
    ax.imshow(_background(speckle), cmap="gray", interpolation="bilinear", extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    try:                                   # a grid result: one cell per point, over the speckle it measured
        layout = grid_layout(x, y)
        (x0, y0), h = layout.origin_px, layout.step_px / 2
        rows, cols = layout.shape
        sc = ax.imshow(layout.on_grid(np.where(ok, values, np.nan)), cmap=cmap, vmin=lims[0], vmax=lims[1],
                       interpolation="nearest",
                       extent=(x0 - h, x0 + (cols - 1) * 2 * h + h, y0 + (rows - 1) * 2 * h + h, y0 - h))
        ax.set_xlim(-0.5, speckle.shape[1] - 0.5)
        ax.set_ylim(speckle.shape[0] - 0.5, -0.5)
    except ValueError:                     # scattered points
        sc = ax.scatter(x[ok], y[ok], c=values[ok], s=5, cmap=cmap, vmin=lims[0], vmax=lims[1], marker="s",
                        linewidths=0, alpha=0.85)
    for mx, my, style, label in marks:
        ax.plot(mx, my, style, ms=9, mfc="none", mew=1.6, label=label)
    if marks:
        ax.legend(fontsize=7, loc="lower right", framealpha=0.8)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x (px)", fontsize=8)
    ax.set_ylabel("y (px)", fontsize=8)
    ax.tick_params(labelsize=7)
    bar = fig.colorbar(sc, ax=ax, shrink=0.85)
    bar.set_label(unit, fontsize=8)
    bar.ax.tick_params(labelsize=7)


def state_figure(dataset: Dataset, score, tool: str, speckle) -> bytes:
    """Maps of one state over the left reference image: the 3-D (or 2-D) error, and with strain e1 measured, e1
    through the window (one colour scale for the two) and their difference."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = []
    if score.error_U_um is not None:
        norm = np.linalg.norm(score.error_U_um, axis=1)
        panels.append(("3-D displacement error |ΔU|", "µm", norm, _limits(norm), "viridis", ()))
    elif score.error_uv_px is not None:
        norm = np.linalg.norm(score.error_uv_px, axis=1)
        panels.append(("2-D displacement error |Δ(u, v)|", "px", norm, _limits(norm), "viridis", ()))
    st = score.strain
    if st is not None:
        measured, windowed = 1e6 * st.measured[:, 3], 1e6 * st.windowed[:, 3]
        lims = _limits(measured, windowed)
        peaks = score.metrics.get("strain_peaks", {})
        marks = [(p["x_px"], p["y_px"], style, label) for key, style, label in
                 (("measured", "wo", "peak measured"), ("windowed_truth", "c^", "peak windowed truth"))
                 if (p := peaks.get(key))]
        panels += [("e1 measured", "µε", measured, lims, "magma", marks),
                   ("e1 truth through the tool's window", "µε", windowed, lims, "magma", marks),
                   ("e1 measured − windowed truth", "µε", measured - windowed,
                    _limits(measured - windowed, symmetric=True), "coolwarm", ())]
    cols = min(2, len(panels))
    rows = int(np.ceil(len(panels) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.6 * cols, 4.3 * rows), squeeze=False)
    for ax, (title, unit, values, lims, cmap, marks) in zip(axes.ravel(), panels):
        _map_panel(fig, ax, speckle, score.x_px, score.y_px, values, title, unit, lims, cmap, marks)
    for ax in axes.ravel()[len(panels):]:
        ax.axis("off")
    fig.suptitle(f"{tool}: {score.label} (state {score.state})", fontsize=10)
    fig.tight_layout()
    return _png(fig)


def concentration_figure(scores, tool: str) -> bytes | None:
    """The largest principal strain e1 per state: measured, through the tool's window, exact."""
    import matplotlib.pyplot as plt

    rows = [(s.state, s.metrics) for s in scores if "strain_peak_e1_windowed_microstrain" in s.metrics]
    if not rows:
        return None
    states = np.array([k for k, _ in rows])
    fig, ax = plt.subplots(figsize=(7.5, 3.8))
    for key, label, style in (("strain_peak_e1_exact_microstrain", "exact truth", "k:s"),
                              ("strain_peak_e1_windowed_microstrain", "truth through the window", "c--^"),
                              ("strain_peak_e1_measured_microstrain", f"measured ({tool})", "r-o")):
        ax.plot(states, [m.get(key, np.nan) for _, m in rows], style, label=label)
    ax.set_xlabel("state")
    ax.set_ylabel("peak of e1 (µε)")
    ax.set_xticks(states)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    ax.set_title("strain concentration: largest principal strain per state", fontsize=10)
    fig.tight_layout()
    return _png(fig)


def profile_figure(profile, label: str, state_label: str) -> bytes:
    """Strain along a line: exx and e1 measured, through the window and exact, against the distance along it."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10.5, 3.8))
    for ax, (j, name) in zip(axes, ((0, "exx"), (3, "e1"))):
        for data, style, what in ((profile.exact, "k:", "exact truth"), (profile.windowed, "c--", "truth through "
                                  "the window"), (profile.measured, "r-o", "measured")):
            ax.plot(profile.s_px, 1e6 * data[:, j], style, ms=3, label=what)
        ax.set_xlabel(f"distance along the line from ({profile.segment[0]:g}, {profile.segment[1]:g}) (px)")
        ax.set_ylabel(f"{name} (µε)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"line {label}: {state_label}", fontsize=10)
    fig.tight_layout()
    return _png(fig)


def extensometer_figure(rows: list[dict], label: str) -> bytes:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    states = [r["state"] for r in rows]
    ax.plot(states, [r["true_strain_microstrain"] for r in rows], "k:s", label="truth")
    ax.plot(states, [r["strain_microstrain"] for r in rows], "r-o", label="measured")
    ax.set_xlabel("state")
    ax.set_ylabel("gauge strain ΔL / L0 (µε)")
    ax.set_xticks(states)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"virtual extensometer {label}", fontsize=10)
    fig.tight_layout()
    return _png(fig)


def _profile_csv(profiles: list[tuple[int, str, object]]) -> str:
    rows = ["line,state,s_px,x_px,y_px," + ",".join(f"{w}_{c}" for w in ("measured", "windowed", "exact")
                                                      for c in ("exx", "eyy", "exy", "e1", "e2"))]
    for k, (state, label, p) in enumerate(profiles):
        for i in range(p.s_px.size):
            vals = [*p.measured[i], *p.windowed[i], *p.exact[i]]
            rows.append(",".join([label, str(state), f"{p.s_px[i]:g}", _fmt(float(p.x_px[i])), _fmt(float(p.y_px[i])),
                                  *("nan" if not np.isfinite(v) else f"{v:.6g}" for v in vals)]))
    return "\n".join(rows) + "\n"


def write_score_report(out: Path, dataset: Dataset, scores: list, tool: str, sources: list[Path],
                       notes: list[str] | None = None, *, lines=(), extensometers=None, mask: str | None = None,
                       progress=None) -> dict:
    """metrics.json, report.md, report.html, errors.csv, one PNG of maps per state and, where asked, line profiles
    (profiles.csv) and extensometers, into ``out``.

    ``lines``: segments (x0, y0, x1, y1) px; ``extensometers``: ``{segment: [row per state]}``
    (:func:`workbench.scoring.probes.extensometer`).
    """
    from labio.atomic import atomic_write_bytes, atomic_write_text
    from workbench.reporting.html_report import write_html_report
    from workbench.scoring.probes import line_profile

    out.mkdir(parents=True, exist_ok=True)
    extensometers = extensometers or {}
    doc = {"dataset": str(dataset.folder), "kind": dataset.kind, "tool": tool, "results": [str(s) for s in sources],
           "notes": notes or [], "mask": mask, "states": [s.metrics for s in scores],
           "extensometers": [{"segment_px": list(seg), "states": rows} for seg, rows in extensometers.items()]}
    md = [f"# {tool} scored against the truth of `{dataset.folder.name}`", "",
          f"Dataset: `{dataset.folder}` ({dataset.kind}, {dataset.n_states} states). Result files: "
          + ", ".join(f"`{s}`" for s in sources) + ".", "",
          "How to read it: the truth is evaluated exactly at each reported reference position (left reference image, "
          "px as OpenCV: integer pixel centres); 3-D errors are in the left camera frame, µm. Points the tool reports "
          "as NaN or failed on the specimen are *not measured* and left out of the errors (the measured fraction "
          "counts them). A strain is Green-Lagrange (tensor shear) in the surface frame of the left image's x axis; "
          "it is compared with the truth **through the tool's own strain window** (the exact positions of its own "
          "points put through the same window: what a perfect instrument with that gauge would measure) and with the "
          "exact truth (the difference is the gauge's spatial resolution, not an error). σ coverage: the fraction "
          "of the errors inside ±1.96 σ of the tool's own uncertainty (95 % for an honest σ).", ""]
    if mask:
        md += [f"Scored inside the user's mask `{mask}` only.", ""]
    md += ["## Summary", "", "### Displacement", ""] + _table(scores, DISPLACEMENT_COLUMNS, True)
    strain_table = _table(scores, STRAIN_COLUMNS, False)
    if strain_table:
        md += ["### Strain", ""] + strain_table
    md += [f"- {n}" for n in notes or []]
    md.append("")
    figure = concentration_figure(scores, tool)
    if figure is not None:
        atomic_write_bytes(out / "concentration.png", figure)
        md += ["## Strain concentration", "",
               "| state | peak e1 measured µε (at x, y px) | windowed truth µε (at x, y px) | exact µε (at x, y px) | "
               "measured at the truth's peak µε | peak error % |", "|---|---|---|---|---|---|"]
        for s in scores:
            p = s.metrics.get("strain_peaks") or {}
            cell = lambda d: "—" if not d else f"{d['microstrain']:.0f} ({d['x_px']:g}, {d['y_px']:g})"  # noqa: E731
            w = p.get("windowed_truth")
            md.append(f"| {s.state} | {cell(p.get('measured'))} | {cell(w)} | {cell(p.get('exact_truth'))} | "
                      f"{_fmt(w.get('measured_here_microstrain')) if w else '—'} | "
                      f"{_fmt(s.metrics.get('strain_peak_e1_error_percent'))} |")
        md += ["", "![peak of e1 per state: measured, truth through the window, exact](concentration.png)", ""]
    speckle = _speckle(dataset)
    md += ["## Maps per state", ""]
    for s in scores:
        name = f"errors_state_{s.state:02d}.png"
        atomic_write_bytes(out / name, state_figure(dataset, s, tool, speckle))
        md += [f"### State {s.state}: {s.label}", "", f"![maps of state {s.state}]({name})", ""]
        if progress:
            progress(f"  report: maps of state {s.state}")
    profiles = []
    strained = [s for s in scores if s.strain is not None]
    if lines and strained:
        md += ["## Line profiles", "", "Each sample is the tool's grid point nearest the line (none where that point "
               "is missing). All states are in `profiles.csv`; the figure shows the state with the largest windowed "
               "peak.", ""]
        shown = max(strained, key=lambda s: s.metrics.get("strain_peak_e1_windowed_microstrain", -np.inf))
        for n, seg in enumerate(lines, 1):
            label = f"L{n} ({seg[0]:g}, {seg[1]:g}) → ({seg[2]:g}, {seg[3]:g}) px"
            for s in strained:
                p = line_profile(s.x_px, s.y_px, s.strain.measured, s.strain.windowed, s.strain.exact, seg)
                profiles.append((s.state, f"L{n}", p))
                if s is shown:
                    atomic_write_bytes(out / f"profile_L{n}.png", profile_figure(p, label, f"{s.label} (state {s.state})"))
            md += [f"![strain along {label}](profile_L{n}.png)", ""]
        atomic_write_text(out / "profiles.csv", _profile_csv(profiles))
    elif lines:
        md += ["## Line profiles", "", "No line profile: the results carry no strain.", ""]
    if extensometers:
        md += ["## Virtual extensometers", "", "The distance between the two material points at the ends, from the "
               "tool's 3-D positions (bilinear between its four nearest grid points) and from the exact truth at the "
               "same pixels; gauge strain = L / L0 − 1.", ""]
        for n, (seg, rows) in enumerate(extensometers.items(), 1):
            label = f"E{n} ({seg[0]:g}, {seg[1]:g}) → ({seg[2]:g}, {seg[3]:g}) px"
            md += [f"### {label}", "", "| state | L0 mm (truth) | ΔL µm measured | ΔL µm truth | strain µε measured | "
                   "strain µε truth | error µε |", "|---|---|---|---|---|---|---|"]
            for r in rows:
                md.append(f"| {r['state']} | {_fmt(r['length_mm'])} ({_fmt(r['true_length_mm'])}) | "
                          f"{_fmt(r['change_um'])} | {_fmt(r['true_change_um'])} | {_fmt(r['strain_microstrain'])} | "
                          f"{_fmt(r['true_strain_microstrain'])} | {_fmt(r['error_microstrain'])} |")
            atomic_write_bytes(out / f"extensometer_E{n}.png", extensometer_figure(rows, label))
            md += ["", f"![virtual extensometer {label}](extensometer_E{n}.png)", ""]
    text = "\n".join(md) + "\n"
    atomic_write_text(out / "metrics.json", json.dumps(doc, indent=1))
    atomic_write_text(out / "report.md", text)
    write_html_report(out / "report.html", f"{tool} scored against the truth", text, out)
    atomic_write_text(out / "errors.csv", _errors_csv(scores))
    return doc


def _errors_csv(scores) -> str:
    header = ["state", "x_px", "y_px", "error_u_px", "error_v_px", "error_U_um", "error_V_um", "error_W_um"]
    with_strain = any(s.strain is not None for s in scores)
    if with_strain:
        header += [f"{w}_{c}" for w in ("measured", "windowed", "exact") for c in ("exx", "eyy", "exy", "e1", "e2")]
    rows = [",".join(header)]
    for s in scores:
        n = s.x_px.size
        e2 = s.error_uv_px if s.error_uv_px is not None else np.full((n, 2), np.nan)
        e3 = s.error_U_um if s.error_U_um is not None else np.full((n, 3), np.nan)
        parts = [e2, e3]
        if with_strain:
            st = s.strain
            parts += [st.measured, st.windowed, st.exact] if st is not None else [np.full((n, 5), np.nan)] * 3
        table = np.column_stack(parts)
        for i in range(n):
            rows.append(",".join([str(s.state), f"{s.x_px[i]:g}", f"{s.y_px[i]:g}",
                                  *("nan" if not np.isfinite(v) else f"{v:.6g}" for v in table[i])]))
    return "\n".join(rows) + "\n"
