"""The design's report: ``report.md`` and the self-contained ``report.html`` with its figures.

Figures: the two rigs drawn from above and from the side (cameras, optical axes, the plane of sharp focus of each
camera and its depth-of-field wedge -- where the blur circle stays within ``search.in_focus_blur_px`` -- over the
face); maps of the predicted W noise and of the blur over the ROI for both rigs on one colour scale each; the best
candidate per f-number, tilted and untilted (the aperture trade-off: light against depth of field); the
verification, predicted against measured per component.
"""
from __future__ import annotations

import collections
import math
from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_text, atomic_writer

from ..reporting.html_report import write_html_report
from .geometry import SIDES

COLOURS = {"chosen": "tab:blue", "untilted": "tab:orange"}


def _fmt(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return f"{v:.{digits}g}"


def _png(fig, path: Path) -> str:
    from labio.figures import png_bytes

    data = png_bytes(fig, dpi=100, bbox_inches="tight")
    with atomic_writer(path, "wb") as f:
        f.write(data)
    return path.name


def _to_spec(cand, X_world: np.ndarray) -> np.ndarray:
    return (np.asarray(X_world) - cand.t_world_from_spec_mm) @ cand.R_world_from_spec


def _focus_lines(cand, blur_px: float, row: bool):
    """Per camera: the in-focus points and the near/far limits along the middle row (or column) of pixels, in the
    specimen frame."""
    from scenes.optics.projection import in_focus_points_world_mm

    out = {}
    for side in SIDES:
        spec = cand.specs[side]
        R, t = cand.rig.pose(side)
        n = 41
        if row:
            pix = np.column_stack([np.linspace(0, spec.width - 1, n), np.full(n, (spec.height - 1) / 2)])
        else:
            pix = np.column_stack([np.full(n, (spec.width - 1) / 2), np.linspace(0, spec.height - 1, n)])
        focus = in_focus_points_world_mm(spec, R, t, pix)
        centre = -R.T @ t
        # depth of field along each chief ray: blur c = (F/N) fx |e| / z_o at Z = z_o / (1 + e)
        z_o = (focus - centre) @ (R.T @ np.array([0.0, 0.0, 1.0]))
        e = blur_px * z_o / ((spec.focal_length_mm / spec.f_number) * spec.fx)
        e = np.clip(e, 0, 0.95)
        near = centre + (focus - centre) / (1 + e)[:, None]
        far = centre + (focus - centre) / (1 - e)[:, None]
        out[side] = (_to_spec(cand, focus), _to_spec(cand, near), _to_spec(cand, far), _to_spec(cand, centre[None])[0])
    return out


def rig_figure(rigs: dict, surface, blur_px: float, path: Path) -> str:
    """The rigs from above (x-z) and from the side (y-z), specimen frame (module notes)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(rigs), 2, figsize=(11, 4.2 * len(rigs)), squeeze=False)
    P = surface.points_mm
    for r, (key, pred) in enumerate(rigs.items()):
        cand = pred.candidate
        for c, (row, (i, name)) in enumerate(((True, (0, "x")), (False, (1, "y")))):
            ax = axes[r, c]
            lines = _focus_lines(cand, blur_px, row)
            for side in SIDES:
                focus, near, far, centre = lines[side]
                colour = "tab:blue" if side == "left" else "tab:red"
                wedge = np.vstack([near[:, [i, 2]], far[::-1][:, [i, 2]]])
                ax.fill(wedge[:, 0], wedge[:, 1], color=colour, alpha=0.12, lw=0,
                        label=f"{side}: in focus (blur <= {blur_px:g} px)")
                ax.plot(focus[:, i], focus[:, 2], color=colour, lw=1.5, label=f"{side}: plane of sharp focus")
                ax.plot([centre[i], 0.0], [centre[2], 0.0], color=colour, lw=0.8, ls="--")
                ax.plot(centre[i], centre[2], "s", color=colour, ms=7)
            ax.plot(P[:, i], P[:, 2], ".", color="k", ms=3, label="face (ROI samples)")
            span = max(np.ptp(P[:, i]), 10.0)
            ax.set_xlim(-1.2 * span if c == 0 else -0.8 * span, 1.2 * span if c == 0 else 0.8 * span)
            zs = P[:, 2]
            ax.set_ylim(zs.max() + 0.4 * span, zs.min() - 0.4 * span)
            ax.set_xlabel(f"specimen {name} (mm)")
            ax.set_ylabel("specimen z, towards the cameras is up (mm)")
            tilt = ", ".join(f"{s} alpha {cand.rig.camera(s).alpha_deg:+.2f} beta {cand.rig.camera(s).beta_deg:+.2f} deg"
                             for s in SIDES)
            ax.set_title(f"{key}: {'from above' if c == 0 else 'from the side'}\n{tilt}", fontsize=9)
            ax.set_aspect("auto")
            if r == 0 and c == 0:
                ax.legend(fontsize=7, loc="lower left")
    fig.suptitle("The rigs near the face: planes of sharp focus and depth-of-field wedges (cameras off the plot: "
                 "dashed lines lead to them)", fontsize=10)
    fig.tight_layout()
    return _png(fig, path)


def overview_figure(rigs: dict, path: Path) -> str:
    """Both rigs to scale, from above: where the cameras stand."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 5))
    for key, pred in rigs.items():
        cand = pred.candidate
        for side in SIDES:
            c = cand.placement.centre_mm(side)
            ax.plot([c[0], 0], [c[2], 0], color=COLOURS.get(key, "k"), lw=1)
            ax.plot(c[0], c[2], "s", color=COLOURS.get(key, "k"), ms=8,
                    label=f"{key}: D {cand.placement.distance_mm:.0f} mm, {cand.placement.stereo_angle_deg:.1f} deg"
                    if side == "left" else None)
    ax.axhline(0, color="k", lw=2)
    ax.set_xlabel("specimen x (mm)")
    ax.set_ylabel("specimen z (mm; the cameras stand at negative z)")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    ax.set_title("Camera positions (to scale, from above)", fontsize=10)
    return _png(fig, path)


def _grid(surface, values):
    g = np.full(surface.grid_shape, np.nan)
    g[surface.grid_index[:, 1], surface.grid_index[:, 0]] = values
    return g


def maps_figure(rigs: dict, surface, path: Path) -> str:
    """Predicted W noise and the worst blur over the ROI, both rigs on one colour scale per quantity."""
    import matplotlib.pyplot as plt

    x0, y0, x1, y1 = surface.roi_mm
    extent = (x0, x1, y1, y0)
    keys = list(rigs)
    w = np.concatenate([rigs[k].sigma_U_um[:, 2] for k in keys])
    b = np.concatenate([rigs[k].blur_px.max(axis=1) for k in keys])
    fig, axes = plt.subplots(2, len(keys), figsize=(5.4 * len(keys), 7.4), squeeze=False)
    for c, k in enumerate(keys):
        p = rigs[k]
        for r, (vals, lim, label, cmap) in enumerate((
                (p.sigma_U_um[:, 2], (np.nanmin(w), np.nanmax(w)), "predicted sigma W (µm), static pair", "viridis"),
                (p.blur_px.max(axis=1), (0.0, max(np.nanmax(b), 1e-3)), "defocus blur circle, worse camera (px)",
                 "magma"))):
            ax = axes[r, c]
            im = ax.imshow(_grid(surface, vals), extent=extent, vmin=lim[0], vmax=lim[1], cmap=cmap,
                           interpolation="nearest", aspect="equal")
            fig.colorbar(im, ax=ax, shrink=0.85, label=label)
            ax.set_xlabel("specimen x (mm)")
            ax.set_ylabel("specimen y (mm)")
            ax.set_title(f"{k}: {p.candidate.rig.name}", fontsize=8)
    fig.tight_layout()
    return _png(fig, path)


def aperture_figure(result, objective_label: str, path: Path) -> str:
    """The best candidate per f-number, tilted and untilted."""
    import matplotlib.pyplot as plt

    best = {}
    for p in result.ranked:
        key = (p.candidate.tilted, p.candidate.f_number)
        if key not in best:
            best[key] = p.summary["objective"]
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for tilted, colour in ((True, COLOURS["chosen"]), (False, COLOURS["untilted"])):
        pts = sorted((N, v) for (t, N), v in best.items() if t == tilted)
        if pts:
            ax.plot(*zip(*pts), "o-", color=colour, label="tilted (hinge rule)" if tilted else "untilted")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("f-number N")
    ax.set_ylabel(objective_label)
    ax.set_title("Best candidate per aperture: light (small N) against depth of field (large N)", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _png(fig, path)


def verification_figure(verification: dict, path: Path) -> str:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    width = 0.2
    for i, (key, v) in enumerate(verification.items()):
        st = v["static"]
        xs = np.arange(3) + (i - 0.5) * 2 * width
        ax.bar(xs - width / 2, st["predicted_um"], width, color=COLOURS.get(key), alpha=0.5,
               label=f"{key}: predicted")
        ax.bar(xs + width / 2, st["measured_um"], width, color=COLOURS.get(key), label=f"{key}: measured")
    ax.set_xticks(range(3), ["U (face x)", "V (face y)", "W (normal)"])
    ax.set_xlabel("displacement component, specimen face frame")
    ax.set_ylabel("static-pair noise, 1 sigma (µm)")
    ax.set_title("Verification: rendered and measured by the instrument", fontsize=9)
    ax.legend(fontsize=8)
    return _png(fig, path)


def images_figure(verification: dict, path: Path) -> str:
    """The rendered left reference images of the verified rigs (the camera's exposure applied, no noise)."""
    import matplotlib.pyplot as plt

    from measurement.image_io import read_grey

    fig, axes = plt.subplots(1, len(verification), figsize=(5.6 * len(verification), 4.4), squeeze=False)
    for ax, (key, v) in zip(axes[0], verification.items()):
        image = read_grey(Path(v["images"]) / "left_00.png").astype(float) * v["exposure_grey"] / 255.0
        step = max(1, image.shape[1] // 700)
        im = ax.imshow(image[::step, ::step], cmap="gray", vmin=0, vmax=float(np.percentile(image, 99.9)),
                       extent=(0, image.shape[1], image.shape[0], 0))
        fig.colorbar(im, ax=ax, shrink=0.8, label="grey level")
        ax.set_xlabel("x (px)")
        ax.set_ylabel("y (px)")
        ax.set_title(f"{key}: left reference image", fontsize=9)
    fig.tight_layout()
    return _png(fig, path)


def _summary_rows(rigs: dict) -> list[str]:
    keys = list(rigs)
    lines = ["| | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]

    def row(name, fn):
        lines.append(f"| {name} | " + " | ".join(fn(rigs[k]) for k in keys) + " |")

    row("camera / lens", lambda p: f"{p.candidate.camera_name} / {p.candidate.lens_name}")
    row("working distance (mm)", lambda p: _fmt(p.candidate.placement.distance_mm, 4))
    row("stereo angle (deg)", lambda p: _fmt(p.candidate.placement.stereo_angle_deg, 3))
    row("f-number", lambda p: _fmt(p.candidate.f_number))
    for s in SIDES:
        row(f"{s} sensor tilt alpha, beta (deg)",
            lambda p, s=s: f"{p.candidate.rig.camera(s).alpha_deg:+.3f}, {p.candidate.rig.camera(s).beta_deg:+.3f}"
            + (" (adapter limit)" if p.candidate.tilt_clamped else ""))
    row("image distance v (mm)", lambda p: _fmt(p.candidate.rig.left.fx * p.candidate.rig.pixel_pitch_mm, 4))
    sm = lambda key, d=3: (lambda p: _fmt(p.summary[key], d))  # noqa: E731
    row("predicted sigma U, V, W (µm, RMS over the ROI)",
        lambda p: f"{_fmt(p.summary['sigma_U_um'])}, {_fmt(p.summary['sigma_V_um'])}, {_fmt(p.summary['sigma_W_um'])}")
    row("worst point sigma W (µm)", sm("max_sigma_W_um"))
    row("predicted strain noise exx, eyy (µε)",
        lambda p: f"{_fmt(p.summary['sigma_exx_ue'])}, {_fmt(p.summary['sigma_eyy_ue'])}")
    row("in focus (fraction of ROI x depth samples)", sm("in_focus_fraction"))
    row("largest defocus blur circle (px)", sm("max_blur_px"))
    row("diffraction (Gaussian sigma, px)", sm("diffraction_sigma_px"))
    row("MIG (grey/px)", sm("mig_grey_per_px"))
    row("mean grey, noise (grey)", lambda p: f"{_fmt(p.summary['mean_grey'])}, {_fmt(p.summary['noise_grey'])}"
        + (" (exposure cut: no saturation)" if p.summary["light_cut"] else ""))
    row("speckle (mm; px over the ROI)", lambda p: f"{_fmt(p.summary['speckle_mm'])}; "
        f"{p.summary['speckle_px'][0]:.2f}-{p.summary['speckle_px'][1]:.2f}")
    row("subset footprint (mm), virtual strain gauge (mm)",
        lambda p: f"{_fmt(p.summary['subset_mm'])}, {_fmt(p.summary['vsg_mm'])}")
    return lines


def write_report(dr) -> Path:
    """Write report.md, report.html and the figures into ``dr.out_dir``."""
    out = Path(dr.out_dir)
    design, result, surface = dr.design, dr.search, dr.surface
    s = design.specimen
    what = (f"{s.quantity} {s.component}" if s.quantity == "displacement" else f"{s.component} strain")
    objective_label = {"displacement out-of-plane": "RMS predicted sigma W (µm)",
                       "displacement in-plane": "RMS predicted in-plane sigma (µm)"}.get(
        what, "RMS predicted strain noise (µε)")
    rigs = {"chosen": result.best}
    if result.best_untilted is not None and result.best_untilted is not result.best:
        rigs["untilted"] = result.best_untilted
    best = result.best
    lines = ["# Rig design", "",
             f"Specimen: **{surface.label}**, ROI {[round(v, 2) for v in surface.roi_mm]} mm "
             f"({len(surface.points_mm)} samples), depth travel {s.depth_range_mm:g} mm; what matters: **{what}**. "
             f"{result.tried} candidate rigs tried, {len(result.ranked)} feasible, ranked in {result.seconds:.1f} s "
             f"(analytic: no rendering).", ""]
    if "untilted" in rigs:
        ratio = rigs["untilted"].summary["objective"] / best.summary["objective"]
        mig = best.summary["mig_grey_per_px"] / rigs["untilted"].summary["mig_grey_per_px"]
        lines += [f"**Chosen: {best.candidate.rig.name}.** The best untilted rig under the same constraints "
                  f"({rigs['untilted'].candidate.rig.name}) is predicted **{ratio:.2f}x** noisier in {what}; MIG "
                  f"ratio chosen / untilted {mig:.2f}.", ""]
    else:
        lines += [f"**Chosen: {best.candidate.rig.name}.**", ""]
    lines += ["## The rigs", ""] + _summary_rows(rigs) + [""]
    lines += [f"![rigs to scale]({overview_figure(rigs, out / 'rig_positions.png')})", "",
              f"![rigs near the face]({rig_figure(rigs, surface, design.search.in_focus_blur_px, out / 'rig_focus.png')})",
              "", "## Predicted noise and blur over the ROI", "",
              "Static-pair noise (1 sigma) from the instrument's own estimator on the paint, for the design's "
              "camera noise and exposure; worst over the depth travel.", "",
              f"![maps]({maps_figure(rigs, surface, out / 'maps.png')})", "",
              f"![aperture]({aperture_figure(result, objective_label, out / 'aperture.png')})", ""]
    if dr.verification:
        lines += ["## Verification: the rigs rendered and measured", "",
                  "Each rig rendered with the specimen (thin lens, the design's speckle), the camera's noise and "
                  "exposure applied, measured by the instrument: static pairs (noise) and one deformed state "
                  "against the truth. U, V, W along the face's x, y and normal; the prediction where the measurement is "
                  "(each measured point takes its nearest ROI sample's sigma, on a grid 4 times denser than the "
                  "search's).", "",
                  "| rig | component | predicted (µm) | measured (µm) | predicted / measured | instrument's own "
                  "sigma, deformed state (µm) | deformed state: measured random error (µm) |",
                  "|---|---|---|---|---|---|---|"]
        for key, v in dr.verification.items():
            st, de = v["static"], v["deformed"]
            for k, comp in enumerate("UVW"):
                inst = de["instrument_sigma_um"][k] if de.get("instrument_sigma_um") else None
                lines.append(f"| {key} | {comp} | {_fmt(st['predicted_um'][k])} | {_fmt(st['measured_um'][k])} | "
                             f"{_fmt(st['ratio'][k])} | {_fmt(inst)} | {_fmt(de['measured_um'][k])} |")
        for key, v in dr.verification.items():
            cov = v["static"].get("roi_samples_covered")
            if cov and cov[0] < cov[1]:
                whole = v["static"]["predicted_whole_roi_um"]
                lines += ["", f"{key}: the match failed at {cov[1] - cov[0]} of {cov[1]} ROI samples (no measured point "
                          f"within a grid step); over the whole ROI the prediction is U, V, W "
                          + ", ".join(_fmt(w) for w in whole) + " µm."]
        if "untilted" in dr.verification and "chosen" in dr.verification:
            pr = [u / c for u, c in zip(dr.verification["untilted"]["static"]["predicted_um"],
                                        dr.verification["chosen"]["static"]["predicted_um"])]
            me = [u / c for u, c in zip(dr.verification["untilted"]["static"]["measured_um"],
                                        dr.verification["chosen"]["static"]["measured_um"])]
            lines += ["", "Untilted over chosen, U, V, W: predicted " + ", ".join(f"{v:.2f}" for v in pr)
                      + "; measured on the renders " + ", ".join(f"{v:.2f}" for v in me) + "."]
        lines += ["", f"![verification]({verification_figure(dr.verification, out / 'verification.png')})", "",
                  f"![renders]({images_figure(dr.verification, out / 'renders.png')})", "",
                  "Static strain noise: " + "; ".join(
                      f"{k}: predicted exx {_fmt(v['static']['strain_predicted_ue'][0])} µε, measured E11 "
                      f"{_fmt(v['static']['strain_measured_ue'].get('E11'))} µε"
                      for k, v in dr.verification.items()) + ".", ""]
    if dr.hinge_check:
        h = dr.hinge_check
        lines += ["## The hinge rule, checked", "",
                  "The chosen tilts against an independent solver (:func:`workbench.rigs.scheimpflug_tilt_for_plane`: "
                  "the lens' F solved for the designed sensor distance): largest difference "
                  f"**{h['max_difference_deg']:.2g} deg**" + ("" if h["applies"] else
                                                               " (a tilt reached the adapter's limit: not comparable)")
                  + ".", "",
                  "| camera | design alpha, beta (deg) | hinge rule alpha, beta (deg) | its F (mm) vs the lens' |",
                  "|---|---|---|---|"]
        for side in SIDES:
            r = h[side]
            lines.append(f"| {side} | {r['design_alpha_deg']:+.4f}, {r['design_beta_deg']:+.4f} | "
                         f"{r['hinge_rule_alpha_deg']:+.4f}, {r['hinge_rule_beta_deg']:+.4f} | "
                         f"{r['hinge_rule_focal_length_mm']:.3f} vs {r['lens_focal_length_mm']:.3f} |")
        lines.append("")
    if dr.comparisons:
        lines += ["## Compared with named rigs", "",
                  "Each named rig with the design's camera noise and lighting, at the chosen f-number, looking at "
                  "the same face (placed where its optical axes meet, facing the cameras' bisector).", "",
                  "| rig | D (mm) | stereo angle (deg) | tilts beta L, R (deg) | sigma U, V, W (µm) | in focus | "
                  "max blur (px) | MIG |", "|---|---|---|---|---|---|---|---|"]
        for name, v in dr.comparisons.items():
            if "error" in v:
                lines.append(f"| {name} | {v['error']} | | | | | | |")
                continue
            p = v["prediction"]
            sm = p.summary
            lines.append(f"| {name} | {v['working_distance_mm']:.0f} | {v['stereo_angle_deg']:.2f} | "
                         f"{v['tilts_deg']['left'][1]:+.2f}, {v['tilts_deg']['right'][1]:+.2f} | "
                         f"{_fmt(sm['sigma_U_um'])}, {_fmt(sm['sigma_V_um'])}, {_fmt(sm['sigma_W_um'])} | "
                         f"{_fmt(sm['in_focus_fraction'])} | {_fmt(sm['max_blur_px'])} | {_fmt(sm['mig_grey_per_px'])} |")
        lines.append("")
        for name, v in dr.comparisons.items():
            d = v.get("designer_tilts_deg")
            if d:
                lines += [f"The designer's hinge rule for the **{name}** rig's own geometry and lenses (its poses, "
                          f"image distances and F; principal point at the image centre, no distortion): left beta "
                          f"{d['left']['designer_beta_deg']:+.3f} deg (the rig's {d['left']['rig_beta_deg']:+.3f}), "
                          f"right {d['right']['designer_beta_deg']:+.3f} deg (the rig's "
                          f"{d['right']['rig_beta_deg']:+.3f}): largest difference {d['max_difference_deg']:.3f} deg "
                          "(the rig's solver keeps Table 1's principal points and distortion).", ""]
    lines += ["## Ranked candidates (top 12)", "", "| # | rig | " + objective_label + " | sigma U, V, W (µm) | in focus | "
              "max blur (px) | MIG |", "|---|---|---|---|---|---|---|"]
    for i, p in enumerate(result.ranked[:12], 1):
        sm = p.summary
        lines.append(f"| {i} | {p.candidate.rig.name} | {_fmt(sm['objective'])} | {_fmt(sm['sigma_U_um'])}, "
                     f"{_fmt(sm['sigma_V_um'])}, {_fmt(sm['sigma_W_um'])} | {_fmt(sm['in_focus_fraction'])} | "
                     f"{_fmt(sm['max_blur_px'])} | {_fmt(sm['mig_grey_per_px'])} |")
    reasons = collections.Counter(r["reason"].split(":")[0].split(" (")[0][:80] for r in result.rejected)
    if reasons:
        lines += ["", "Rejected candidates, by reason: " + "; ".join(f"{n} x {why}" for why, n in
                                                                     reasons.most_common(6)) + "."]
    lines += ["", "Every candidate with its figures: `candidates.csv`; the rigs as calibration files: "
              "`rig_chosen/rig.json` (with its optics: `workbench render` and `twin` use it) and "
              "`rig_chosen/rig_opencv.yaml`" + (", likewise `rig_untilted/`" if "untilted" in rigs else "") + ".", ""]
    text = "\n".join(lines)
    atomic_write_text(out / "report.md", text)
    return write_html_report(out / "report.html", "Rig design", text, out)
