"""The iDICs Good Practices tables and render figures that close each experiment's ``report.md``.

One function per experiment kind (``idics_for``), reached by the experiments (``append_idics``) and by the paper
report, so no experiment imports the paper back.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_text
from workbench.poses import common_view_centre_mm
from workbench.reporting import idics
from workbench.rigs import get_rig


def idics_for(stage: str, m: dict, level: int = 2) -> list[str]:
    """The iDICs hardware and analysis tables of one experiment's metrics (``stage``: calibration, rigid_motion,
    bending or depth_of_field), as Markdown lines under a heading of ``level``."""
    mc = (m.get("render_mc") or {}).get("mc_rms_grey", {}).get("median")
    if stage == "calibration":
        rig = get_rig(m.get("rig", "paper"), m["scale"])
        hw = idics.hardware_rows(rig, lens="pinhole", f_number=None, focal_length_mm=None,
                                 stand_off_mm=float(np.linalg.norm(common_view_centre_mm(rig))),
                                 read_noise_grey=m["noise_grey"], mc_rms_grey=mc, pattern="checkerboard (rendered)",
                                 feature_px=None,
                                 target=f"12 × 9-square checkerboard, 5 mm squares; {m['calibration_views']} calibration "
                                        f"+ {m['validation_views']} validation views")
        refined = m.get("corner_refinement") not in (None, "none")
        an = [("calibration software", idics.software_version() + ", `measurement/calibration/`"),
              ("image filtering", "none"),
              ("corner detection", "OpenCV findChessboardCornersSB" + (" + saddle refinement" if refined else "")),
              ("camera model", "the paper's RMM (eqs 1-7): fx, fy, cx, cy, α, β, k1, k2, p1, p2"),
              ("calibration", "the paper's five-step stepwise calibration, then joint refinement"),
              ("reprojection RMS", " / ".join(f"{v:.4f}" for v in m["models"]["rmm"]["reprojection_rms_px"].values())
               + " px (left / right)")]
        return idics.idics_section(hw, an, level=level)
    truth = idics.truth_of(m.get("images", ""))
    rig_name = m.get("rig", "paper")
    rig = get_rig(rig_name, m["scale"])
    speckle_px = None
    spec = truth.get("specimen", {})
    if spec.get("speckle_mm") and rig is not None:
        footprint = float(np.linalg.norm(common_view_centre_mm(rig))) / rig.left.fx
        speckle_px = spec["speckle_mm"] / footprint
    if stage == "depth_of_field":
        cams = m["cameras"]
        hw = [("camera", "one rendered camera, tilted (Scheimpflug) vs untilted sensor, same thin lens"),
              ("aperture", f"f/{m['f_number']:g}"), ("object", f"speckled plate at {m['object_tilt_deg']}° to the "
                                                                "image plane, 376 mm"),
              ("image noise", f"σ = {m['noise_grey']:g} grey read noise")]
        # each camera is correlated on its own (workbench.experiments.depth_of_field.run.depth_of_field_dic): there
        # is no stereo pair to describe
        shift = f"{m['shift_px']:g} px" if m.get("shift_px") is not None else "a sub-pixel step"
        matching = ("2-D matching (each camera alone, no stereo)",
                    "per camera (tilted and untilted sensor): the static render's first sensor-noise draw → its second "
                    f"(noise floor) and → the render of the plate moved {shift} in its own plane (error against the "
                    "true pixel motion of each material point); no triangulation between the cameras")
        an = idics.analysis_rows(subset_px=m["subset_px"], step_px=m["step_px"], order=1, strain_window="—",
                                 vsg_px=None, strain_formulation="—",
                                 noise_floor=f"tilted {cams['scheimpflug']['noise_floor_px']['u']:.4f} px, untilted "
                                             f"{cams['conventional']['noise_floor_px']['u']:.4f} px (σu, static pair)",
                                 strain_noise_floor="—", matching=matching)
        return idics.idics_section(hw, an, level=level)
    lens = m.get("lens", "pinhole")
    thin = m.get("thin_lens", {}) if stage == "bending" else {}
    # where the specimen really is: the experiment's own pixel footprint (rigid motion: at its face)
    footprint = m.get("pixel_footprint_mm") or m.get("dic_noise_floor", {}).get("pixel_footprint_mm")
    stand_off = footprint * rig.left.fx if footprint else float(np.linalg.norm(common_view_centre_mm(rig)))
    if footprint and spec.get("speckle_mm"):
        speckle_px = spec["speckle_mm"] / footprint
    hw = idics.hardware_rows(rig, lens=lens, f_number=thin.get("f_number"), focal_length_mm=thin.get("focal_length_mm"),
                             stand_off_mm=stand_off, read_noise_grey=m.get("noise_grey", 1.0), mc_rms_grey=mc,
                             pattern="rendered speckle texture (band-limited random speckle, seeded)",
                             feature_px=speckle_px, target=m["calibration"], footprint_mm=footprint)
    if stage == "rigid_motion":
        nf = m["dic_noise_floor"]
        an = idics.analysis_rows(subset_px=m["subset_px"], step_px=m["step_px"], order=2, strain_window="—",
                                 vsg_px=None, strain_formulation="—",
                                 noise_floor=f"{nf['median_sigma_px']:.4f} px per match (Pan 2008 bound at σ = "
                                             f"{nf['read_noise_grey']:g} grey), {nf['in_plane_um']:.3f} µm in-plane",
                                 strain_noise_floor="—")
    else:
        first = next((r for r in m["states"] if "error" not in r), None)
        an = idics.analysis_rows(subset_px=m["subset_px"], step_px=m["step_px"], order=2,
                                 strain_window=f"{m['strain_window']} points" if isinstance(m["strain_window"], int)
                                 else str(m["strain_window"]), vsg_px=m.get("vsg_px"),
                                 strain_formulation="Green–Lagrange, local surface frame (Cosserat point elements / "
                                                    "windowed least squares)",
                                 noise_floor=f"reference shape {m['reference_3d_error_um']['aligned_rms']:.3f} µm RMS "
                                             "after one rigid alignment",
                                 strain_noise_floor="—" if first is None else
                                 f"{first['strain_magnitude_rmse_vs_filtered_ue']:.1f} µε RMSE vs the windowed truth at "
                                 f"{first['load_N']:g} N")
    return idics.idics_section(hw, an, level=level)



IDICS_HEADING = "iDICs Good Practices: hardware and analysis"


def append_idics(out_dir: str | Path, stage: str, metrics: dict) -> None:
    """Append the render figures and the iDICs Good Practices tables to an experiment's ``report.md``
    (``stage``: calibration, rigid_motion, bending or depth_of_field); a report that has them is left alone."""
    path = Path(out_dir) / "report.md"
    text = path.read_text()
    if IDICS_HEADING in text:
        return
    atomic_write_text(path, text.rstrip("\n") + "\n\n" + "\n".join(render_lines(metrics) + idics_for(stage, metrics)))


#: How each speckle renderer is named in reports.
SPECKLE_RENDERER_TEXT = {
    "polygon-quadrature": "without Monte Carlo (exact coverage of the specimen's faces, Gauss-Legendre quadrature of "
                          "the speckle, 6 x 6 nodes per pixel; scenes.rendering.exact)",
    "in-focus-quadrature+mitsuba-adaptive": "through thin lenses: the pixels in focus (blur circle <= 0.1 px) "
                                            "without Monte Carlo as above, the blurred rest (end faces, "
                                            "silhouette) by Mitsuba, adaptive (scenes.rendering.adaptive.render_views_auto)",
    "in-focus-quadrature+defocus-quadrature": "through thin lenses without Monte Carlo: the pixels in focus as "
                                              "above, the blurred flat faces by quadrature over the pixel and the "
                                              "aperture (scenes.rendering.defocus_quadrature)",
    "in-focus-quadrature+defocus-quadrature+mitsuba-adaptive": "through thin lenses: the pixels in focus and the "
                                                               "blurred flat faces without Monte Carlo (quadrature "
                                                               "over the pixel and the aperture), the rest "
                                                               "(silhouettes, faces that are not flat) by Mitsuba, "
                                                               "adaptive (scenes.rendering.adaptive.render_views_auto)",
    "mitsuba-adaptive": "by Mitsuba, adaptive (scenes.rendering.adaptive)",
    "mitsuba": "by Mitsuba at a fixed spp",
}


def render_lines(m: dict) -> list[str]:
    """The sentence on how an experiment's images were rendered: the deterministic renderer's share, and the
    adaptive Monte-Carlo renders' measured noise and cost (nothing for metrics without either)."""
    lines = []
    made = m.get("speckle_renderers") or {}
    for hybrid in ("in-focus-quadrature+mitsuba-adaptive", "in-focus-quadrature+defocus-quadrature+mitsuba-adaptive",
                   "in-focus-quadrature+defocus-quadrature"):
        if made.get(hybrid):
            shares = m.get("speckle_known_fraction")
            lines.append(f"Renders: {made[hybrid]} images {SPECKLE_RENDERER_TEXT[hybrid]}"
                         + (f"; {100 * shares[0]:.1f}-{100 * shares[1]:.1f} % of each image's lit pixels without "
                            "Monte Carlo" if shares else "") + ".")
    if made.get("polygon-quadrature"):
        lines.append(f"Renders: {made['polygon-quadrature']} images {SPECKLE_RENDERER_TEXT['polygon-quadrature']}"
                     + (f"; {sum(v for k, v in made.items() if k != 'polygon-quadrature')} by Mitsuba where a view "
                        "needed it." if len(made) > 1 else "."))
    r = m.get("render_mc")
    if r:
        lines.append(f"Renders: {r['images']} adaptive images, Monte-Carlo noise measured "
                     f"{r['mc_rms_grey']['median']:.3f} grey RMS median ({r['mc_rms_grey']['max']:.3f} max; target "
                     f"{r['target_grey']:g}), {r['sensor_spp']['median']:.1f} samples per sensor pixel median, crop "
                     f"{100 * r['crop_fraction']:.0f} % of the sensor, {r['seconds_per_image']:.1f} s per image.")
    return [line for text in lines for line in (text, "")]


__all__ = ["IDICS_HEADING", "SPECKLE_RENDERER_TEXT", "append_idics", "idics_for", "render_lines"]
