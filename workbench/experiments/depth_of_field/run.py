"""Depth of field: a Scheimpflug-tilted sensor keeps an oblique specimen sharp; an untilted one does not.

The paper (§4.1, Fig 4) compares the MIG of speckle images from the Scheimpflug camera (16.88) and from the
same camera without tilt (8.78). Here both cameras share the lens (focal length F, f-number N) and the image
distance ``v = fx * pixel_pitch``; the plate is rotated about the camera Y axis by ``object_tilt_deg`` around
the on-axis point in focus. The tilted camera's sensor angle comes from the thin-lens focus condition
(:func:`scheimpflug_sensor_tilt_deg`), not from the renderer.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy.optimize import brentq

from labio.atomic import atomic_write_image, atomic_write_text
from measurement.image_quality import mean_intensity_gradient
from scenes.optics.camera import SensorSpec
from scenes.sensor.noise import SensorNoise, to_image_dtype
from scenes.rendering.render import render_views
from scenes.specimens.plate import SpeckledPlate
from scenes.optics.projection import defocus_blur_px, intersect_front_face, pixel_rays, project_points


def _focus_slope(beta_rad: float, image_distance_mm: float, focal_length_mm: float, ds: float = 1e-3) -> float:
    """dZ/dX of the in-focus object line in the camera XZ plane for a sensor tilted by beta about Y."""
    pts = []
    for s in (-ds, ds):
        px, pz = s * np.cos(beta_rad), 1.0 - s * np.sin(beta_rad)   # tilted sensor point, units of v
        z_image = image_distance_mm * pz
        z_object = 1.0 / (1.0 / focal_length_mm - 1.0 / z_image)
        pts.append((px / pz * z_object, z_object))
    (x0, z0), (x1, z1) = pts
    return (z1 - z0) / (x1 - x0)


def scheimpflug_sensor_tilt_deg(object_tilt_deg: float, image_distance_mm: float, focal_length_mm: float) -> float:
    """Sensor tilt beta (about Y) that puts the plane of sharp focus on a plane rotated by ``object_tilt_deg``.

    A plane rotated about the camera Y axis by theta has dZ/dX = -tan(theta) in the camera frame.
    """
    target = -np.tan(np.deg2rad(object_tilt_deg))
    f = lambda b: _focus_slope(b, image_distance_mm, focal_length_mm) - target  # noqa: E731
    return float(np.rad2deg(brentq(f, -np.deg2rad(30), np.deg2rad(30), xtol=1e-12)))


@dataclass
class DepthOfFieldResult:
    sensor_tilt_deg: float
    mig_scheimpflug: float
    mig_conventional: float
    image_scheimpflug: np.ndarray
    image_conventional: np.ndarray

    @property
    def mig_ratio(self) -> float:
        return self.mig_scheimpflug / self.mig_conventional


@dataclass(frozen=True)
class DepthOfFieldScene:
    """The oblique plate and the two cameras (same lens, tilted and untilted sensor), world = camera frame."""

    plate: SpeckledPlate
    R_world_from_plate: np.ndarray
    t_world_from_plate_mm: np.ndarray
    specs: dict            # {"scheimpflug": SensorSpec, "conventional": SensorSpec}
    sensor_tilt_deg: float


def depth_of_field_scene(fx: float = 10912.0, width: int = 2456, height: int = 2058, scale: float = 1.0,
                         pixel_pitch_mm: float = 0.00345, distance_mm: float = 376.0, object_tilt_deg: float = 35.0,
                         f_number: float = 4.0, speckle_px: float = 5.0, texels_per_px: float = 2.5,
                         seed: int = 0) -> DepthOfFieldScene:
    """Set up the plate and the cameras of :func:`run_depth_of_field` (no rendering)."""
    fx_s, w, h, pitch = fx * scale, int(round(width * scale)), int(round(height * scale)), pixel_pitch_mm / scale
    v = fx_s * pitch
    F = 1.0 / (1.0 / v + 1.0 / distance_mm)         # on-axis focus at the plate's centre
    beta = scheimpflug_sensor_tilt_deg(object_tilt_deg, v, F)
    px_mm = distance_mm / fx_s                          # pixel footprint at the plate centre
    theta = np.deg2rad(object_tilt_deg)
    plate_w = 1.3 * w * px_mm / np.cos(theta)
    plate = SpeckledPlate(width_mm=plate_w, height_mm=1.3 * h * px_mm, texel_mm=px_mm / texels_per_px,
                          speckle_mm=speckle_px * px_mm, seed=seed)
    R_plate = np.array([[np.cos(theta), 0, np.sin(theta)], [0, 1, 0], [-np.sin(theta), 0, np.cos(theta)]])
    specs = {name: SensorSpec(fx=fx_s, fy=fx_s, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h, beta_deg=tilt,
                              lens="thin", focal_length_mm=F, f_number=f_number, pixel_pitch_mm=pitch)
             for name, tilt in (("scheimpflug", beta), ("conventional", 0.0))}
    return DepthOfFieldScene(plate, R_plate, np.array([0.0, 0.0, distance_mm]), specs, beta)


def _central_mask(h: int, w: int) -> np.ndarray:
    mask = np.zeros((h, w), bool)
    mask[int(0.1 * h):int(0.9 * h), int(0.1 * w):int(0.9 * w)] = True
    return mask


def run_depth_of_field(fx: float = 10912.0, width: int = 2456, height: int = 2058, scale: float = 1.0,
                       pixel_pitch_mm: float = 0.00345, distance_mm: float = 376.0, object_tilt_deg: float = 35.0,
                       f_number: float = 4.0, speckle_px: float = 5.0, texels_per_px: float = 2.5, spp: int = 64,
                       seed: int = 0) -> DepthOfFieldResult:
    """Render an oblique speckled plate through a Scheimpflug and an untilted thin-lens camera; compare MIG.

    ``scale`` shrinks the image and fx together and grows the pixel pitch (same optics, coarser sensor).
    The MIG is taken over the central 80 % of each image (the plate fills the view).
    """
    scene = depth_of_field_scene(fx, width, height, scale, pixel_pitch_mm, distance_mm, object_tilt_deg, f_number,
                                 speckle_px, texels_per_px, seed)
    texture = scene.plate.texture()
    surface = scene.plate.surface(scene.R_world_from_plate, scene.t_world_from_plate_mm, texture)
    names = list(scene.specs)
    made = render_views([(scene.specs[n], (np.eye(3), np.zeros(3))) for n in names], [surface], renderer="mitsuba",
                        spp=spp, view_seeds=[seed + 1] * len(names))
    images = {n: r.image_grey for n, r in zip(names, made)}
    mask = _central_mask(*images["scheimpflug"].shape)
    return DepthOfFieldResult(scene.sensor_tilt_deg, mean_intensity_gradient(images["scheimpflug"], mask),
                              mean_intensity_gradient(images["conventional"], mask),
                              images["scheimpflug"], images["conventional"])


def _plate_points(scene: DepthOfFieldScene, spec, pixels_xy) -> np.ndarray:
    """Material points (plate frame, z = 0) seen along the chief rays of pixels; NaN off the plate."""
    size = SimpleNamespace(length_mm=scene.plate.width_mm, height_mm=scene.plate.height_mm)
    # the plate's painted face looks along -z of the plate frame, like the beam's front face
    o, d = pixel_rays(spec, np.eye(3), np.zeros(3), pixels_xy)
    return intersect_front_face(o, d, size, scene.R_world_from_plate, scene.t_world_from_plate_mm)[1]


def depth_of_field_dic(scene: DepthOfFieldScene, image_static: dict, image_moved: dict, shift_plate_mm,
                       noise_grey: float = 1.0, subset_size: int = 33, step: int = 16, seed: int = 0) -> dict:
    """What the Scheimpflug adapter buys in the instrument's terms, per camera.

    For each camera (tilted / untilted sensor, same lens and f-number), over the central 80 % of the image:

    * circle of confusion: the thin lens' blur-circle diameter (px) of the plate point each POI sees;
    * DIC noise floor: two independent sensor-noise draws of the same (noise-free) render correlated
      against each other: the std of u and v (px) is the noise floor of a static pair;
    * displacement error: the plate moved in its own plane by ``shift_plate_mm``; the DIC displacement of
      every POI against the true pixel motion of its material point (chief-ray projection).

    ``image_static`` / ``image_moved``: ``{camera name: noise-free render}`` of the plate before and after the
    move. Returns a dict of figures per camera plus per-POI arrays under ``"maps"``.
    """
    from measurement.dic import DICSettings, correlate

    noise = SensorNoise(read_noise_grey=noise_grey, bit_depth=8)
    settings = DICSettings(subset_size=subset_size, step=step, order=1)
    out = {}
    for c, (name, spec) in enumerate(scene.specs.items()):
        h, w = image_static[name].shape
        roi = (int(0.1 * w), int(0.1 * h), int(0.9 * w), int(0.9 * h))
        draw = [to_image_dtype(noise.apply(image_static[name], seed=seed * 1000 + 10 * c + i), 8).astype(float)
                for i in range(2)]
        moved = to_image_dtype(noise.apply(image_moved[name], seed=seed * 1000 + 10 * c + 2), 8).astype(float)
        static = correlate(draw[0], draw[1], settings, roi=roi)
        motion = correlate(draw[0], moved, settings, roi=roi)
        pixels = np.column_stack([static.x, static.y]).astype(float)
        X_plate = _plate_points(scene, spec, pixels)
        X0 = X_plate @ scene.R_world_from_plate.T + scene.t_world_from_plate_mm
        X1 = (X_plate + np.asarray(shift_plate_mm, float)) @ scene.R_world_from_plate.T + scene.t_world_from_plate_mm
        blur = defocus_blur_px(spec, np.eye(3), np.zeros(3), X0)
        true_uv = project_points(spec, np.eye(3), np.zeros(3), X1) - pixels
        err = np.column_stack([motion.u, motion.v]) - true_uv
        ok_s, ok_m = static.converged, motion.converged & np.all(np.isfinite(true_uv), axis=1)
        out[name] = {"sensor_tilt_deg": spec.beta_deg,
                     "blur_px": {"median": float(np.nanmedian(blur)), "max": float(np.nanmax(blur))},
                     "noise_floor_px": {"u": float(np.std(static.u[ok_s])), "v": float(np.std(static.v[ok_s]))},
                     "displacement_error_px": {"rms": float(np.sqrt(np.mean(np.sum(err[ok_m] ** 2, axis=1)))),
                                               "max": float(np.max(np.linalg.norm(err[ok_m], axis=1))),
                                               "mean_u": float(np.mean(err[ok_m, 0])),
                                               "mean_v": float(np.mean(err[ok_m, 1]))},
                     "points": int(static.x.size), "converged_static": int(ok_s.sum()),
                     "converged_moved": int(ok_m.sum()),
                     "maps": {"x": static.x, "y": static.y, "blur_px": blur, "error_px": np.linalg.norm(err, axis=1),
                              "noise_u_px": np.where(ok_s, static.u, np.nan)}}
    return out


def run_depth_of_field_study(scale: float = 0.5, object_tilt_deg: float = 38.0, f_number: float = 4.0,
                             spp: int = 64, seed: int = 0, shift_px: float = 0.4, noise_grey: float = 1.0,
                             subset_size: int = 33, step: int = 16,
                             mc_target_grey: float | None = None) -> tuple[DepthOfFieldScene, dict, dict]:
    """MIG, blur, DIC noise floor and displacement error of the tilted and untilted sensor at one f-number.

    The plate moves by ``shift_px`` pixels' worth (at its centre) along its own x axis between the two renders.
    ``mc_target_grey``: both cameras from one scene with :func:`scenes.rendering.render.render_views` (the pixels in
    focus and the blurred plate without Monte Carlo, anything left adaptive at that Monte-Carlo noise; ``spp``
    unused); the
    measured noise, renderer and share of pixels made without Monte Carlo per image are in
    ``figures[camera]["render_mc"]``.
    Returns ``(scene, images {"static"|"moved": {camera: image}}, figures per camera)``.
    """
    scene = depth_of_field_scene(scale=scale, object_tilt_deg=object_tilt_deg, f_number=f_number, seed=seed)
    texture = scene.plate.texture()
    px_mm = float(scene.t_world_from_plate_mm[2]) / scene.specs["scheimpflug"].fx
    shift = np.array([shift_px * px_mm, 0.0, 0.0])
    images, mc = {}, {}
    for key, offset in (("static", np.zeros(3)), ("moved", shift)):
        surface = scene.plate.surface(scene.R_world_from_plate,
                                      scene.t_world_from_plate_mm + scene.R_world_from_plate @ offset, texture)
        names = list(scene.specs)
        views = [(scene.specs[n], (np.eye(3), np.zeros(3))) for n in names]
        if mc_target_grey is None:
            rendered = render_views(views, [surface], renderer="mitsuba", spp=spp,
                                    view_seeds=[seed + 1 + (key == "moved")] * len(names))
            images[key] = {n: r.image_grey for n, r in zip(names, rendered)}
        else:
            rendered = render_views(views, [surface], seed=10 * (seed + 1 + (key == "moved")),
                                    mc_target_grey=mc_target_grey)
            images[key] = {n: r.image_grey for n, r in zip(names, rendered)}
            # no Monte Carlo at all (every pixel in focus): 0 noise, target met
            mc[key] = {n: {**(r.mc or {"mc_rms_grey": 0.0, "target_met": True}), "renderer": r.renderer,
                           "known_fraction": r.known_fraction, "defocus_error_grey": r.defocus_error_grey}
                       for n, r in zip(names, rendered)}
    figures = depth_of_field_dic(scene, images["static"], images["moved"], shift, noise_grey=noise_grey,
                                 subset_size=subset_size, step=step, seed=seed)
    for name in scene.specs:
        mask = _central_mask(*images["static"][name].shape)
        figures[name]["mig"] = mean_intensity_gradient(images["static"][name], mask)
        if mc:
            figures[name]["render_mc"] = {key: mc[key][name] for key in mc}
    return scene, images, figures


def _render_text(metrics: dict) -> str:
    if metrics.get("spp") != "adaptive":
        return f"{metrics['spp']} spp"
    rms = [r["mc_rms_grey"] for c in metrics["cameras"].values() for r in c.get("render_mc", {}).values()]
    shares = {name: min(r.get("known_fraction", 0.0) for r in c.get("render_mc", {}).values())
              for name, c in metrics["cameras"].items()}
    quadrature = [r.get("defocus_error_grey") for c in metrics["cameras"].values()
                  for r in c.get("render_mc", {}).values() if r.get("defocus_error_grey") is not None]
    if all(v >= 1.0 for v in shares.values()):
        return ("every pixel without Monte Carlo: in focus (blur circle <= 0.1 px) by quadrature over the pixel"
                + (f", blurred by quadrature over the pixel and the aperture (each blur's rule within "
                   f"{max(quadrature):.3f} grey RMS of a rule 4-5x denser, scenes.rendering.defocus_quadrature)"
                   if quadrature else ""))
    text = ("the pixels in focus (blur circle <= 0.1 px) and the blurred plate's without Monte Carlo "
            "(at least " + ", ".join(f"{100 * v:.0f} % of the {k} camera's" for k, v in shares.items())
            + f"), the rest (edges) by adaptive sampling (Monte-Carlo noise target {metrics['mc_target_grey']:g} "
            f"grey, measured {max(rms):.3f} grey RMS at most over the sampled pixels)")
    # a camera whose renders missed the target says so: its noise floor and MIG carry the extra render noise
    missed = {name: max(r["mc_rms_grey"] for r in c["render_mc"].values())
              for name, c in metrics["cameras"].items()
              if any(r.get("target_met") is False for r in c.get("render_mc", {}).values())}
    for name, worst in missed.items():
        text += (f"; the {name} camera's renders MISSED the target ({worst:.2f} grey RMS: its defocus blur needs "
                 "more samples per pixel than the adaptive budget, scenes.rendering.adaptive.AdaptiveSettings.sides, allows), "
                 "so its static noise floor and MIG include that render noise")
    return text


def reproduce_depth_of_field(out_dir, *, scale: float = 1.0, object_tilt_deg: float = 38.0, f_number: float = 4.0,
                             spp: int = 64, seed: int = 0, noise_grey: float = 1.0,
                             mc_target_grey: float | None = None, shift_px: float = 0.4) -> dict:
    """Write ``metrics.json``, ``report.md``, ``side_by_side.png`` and ``dic_maps.png`` (tilted vs untilted).

    ``mc_target_grey``: renders without Monte Carlo where in focus or on the blurred plate, adaptive at that
    Monte-Carlo noise elsewhere (:func:`scenes.rendering.adaptive.render_views_auto`) instead of ``spp``. ``shift_px``: the in-plane move of the plate
    between the two renders, pixels at its centre (recorded in the metrics for the report)."""
    import json
    from pathlib import Path

    import cv2
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from workbench.manifest import save_figure
    from workbench.rigs import paper_values

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    subset = max(21, int(round(33 * scale)) | 1)
    step = max(8, int(round(16 * scale)))
    scene, images, fig = run_depth_of_field_study(scale=scale, object_tilt_deg=object_tilt_deg, f_number=f_number,
                                                  spp=spp, seed=seed, noise_grey=noise_grey, subset_size=subset,
                                                  step=step, mc_target_grey=mc_target_grey, shift_px=shift_px)
    paper = paper_values()["speckle_quality"]
    st, cv = images["static"]["scheimpflug"], images["static"]["conventional"]
    for name, img in (("scheimpflug", st), ("conventional", cv)):
        atomic_write_image(out_dir / f"{name}.png", np.clip(np.rint(img), 0, 255).astype(np.uint8))
    h, w = st.shape
    side = np.hstack([st, np.full((h, max(4, w // 100)), 255.0), cv])
    f = min(1.0, 1400 / side.shape[1])
    from labio.atomic import atomic_write_bytes
    from labio.figures import picture_png

    atomic_write_bytes(out_dir / "side_by_side.png", picture_png(
        cv2.resize(np.clip(side, 0, 255).astype(np.uint8), None, fx=f, fy=f, interpolation=cv2.INTER_AREA)))
    figure, axes = plt.subplots(2, 2, figsize=(11, 7))
    for r, (key, label) in enumerate((("blur_px", "blur-circle diameter (px)"),
                                      ("error_px", "|displacement error| (px)"))):
        # one colour scale for both cameras' maps of a quantity, from both (a Scheimpflug blur map that is ~0 everywhere
        # is shown as ~0 on the untilted camera's scale, not as its rounding noise)
        both = np.concatenate([np.ravel(fig[name]["maps"][key]) for name in ("scheimpflug", "conventional")])
        both = both[np.isfinite(both)]
        high = float(np.percentile(both, 99)) if both.size else 1.0
        for c, name in enumerate(("scheimpflug", "conventional")):
            m = fig[name]["maps"]
            sc = axes[r, c].scatter(m["x"], m["y"], c=m[key], s=4, cmap="magma", vmin=0.0,
                                    vmax=high if high > 0 else 1.0)
            axes[r, c].invert_yaxis()
            axes[r, c].set_aspect("equal")
            axes[r, c].set_title(f"{name}: {label}", fontsize=9)
            axes[r, c].set_xlabel("x (px)", fontsize=8)
            axes[r, c].set_ylabel("y (px)", fontsize=8)
            figure.colorbar(sc, ax=axes[r, c], fraction=0.035).set_label(label, fontsize=8)
    figure.suptitle(f"Plate at {object_tilt_deg}°, f/{f_number}: tilted vs untilted sensor, same lens", fontsize=9)
    figure.tight_layout()
    save_figure(figure, out_dir / "dic_maps.png", dpi=110)
    plt.close(figure)
    from workbench.experiments.calibration.run import render_content
    metrics = {"object_tilt_deg": object_tilt_deg, "f_number": f_number, "scale": scale,
               **render_content(spp, mc_target_grey),
               "noise_grey": noise_grey, "subset_px": subset, "step_px": step, "shift_px": shift_px,
               "paper_mig_scheimpflug": paper["MIG_scheimpflug"], "paper_mig_conventional": paper["MIG_conventional"],
               "cameras": {name: {k: v for k, v in d.items() if k != "maps"} for name, d in fig.items()}}
    metrics["mig_ratio"] = fig["scheimpflug"]["mig"] / fig["conventional"]["mig"]
    atomic_write_text(out_dir / "metrics.json", json.dumps(metrics, indent=1))
    s, c = metrics["cameras"]["scheimpflug"], metrics["cameras"]["conventional"]
    row = lambda label, a, b, fmt: f"| {label} | {fmt.format(a)} | {fmt.format(b)} |"  # noqa: E731
    atomic_write_text(out_dir / "report.md", "\n".join([
        "# Depth of field: Scheimpflug vs untilted sensor, in the instrument's terms", "",
        f"An oblique speckled plate ({object_tilt_deg}° about the camera Y axis, centre at 376 mm) through the same "
        f"thin lens at f/{f_number}, scale {scale} ({w} x {h} px), {_render_text(metrics)}. The tilted sensor "
        f"({s['sensor_tilt_deg']:.2f}° from the thin-lens focus condition) keeps the whole plate in focus; the "
        "untilted one only its middle. Over the central 80 % of the image: MIG, the blur circle of the plate point "
        "each POI sees, the DIC noise floor of a static pair (two sensor-noise draws, σ = "
        f"{noise_grey} grey, subset {subset} px, first order) and the error of a {shift_px:g} px in-plane move of the "
        "plate against the true pixel motion of each material point.", "",
        "| | Scheimpflug (tilted) | untilted |", "|---|---|---|",
        row("MIG", s["mig"], c["mig"], "{:.2f}"),
        f"| MIG, paper | {paper['MIG_scheimpflug']:.2f} | {paper['MIG_conventional']:.2f} |",
        row("blur circle, median (px)", s["blur_px"]["median"], c["blur_px"]["median"], "{:.3f}"),
        row("blur circle, max (px)", s["blur_px"]["max"], c["blur_px"]["max"], "{:.3f}"),
        row("DIC noise floor σu (px)", s["noise_floor_px"]["u"], c["noise_floor_px"]["u"], "{:.4f}"),
        row("DIC noise floor σv (px)", s["noise_floor_px"]["v"], c["noise_floor_px"]["v"], "{:.4f}"),
        row("displacement error RMS (px)", s["displacement_error_px"]["rms"], c["displacement_error_px"]["rms"], "{:.4f}"),
        row("displacement error max (px)", s["displacement_error_px"]["max"], c["displacement_error_px"]["max"], "{:.4f}"),
        f"| converged points (static / moved) | {s['converged_static']} / {s['converged_moved']} of {s['points']} | "
        f"{c['converged_static']} / {c['converged_moved']} of {c['points']} |", "",
        f"MIG ratio {metrics['mig_ratio']:.2f} (paper {paper['MIG_scheimpflug'] / paper['MIG_conventional']:.2f}). "
        "Absolute MIG depends on speckle size and contrast (not given in the paper); compare the ratio.", "",
        "![maps](dic_maps.png)", "", "Left: Scheimpflug; right: untilted.", "", "![side by side](side_by_side.png)", ""]))
    from workbench.reporting.experiment_idics import append_idics
    append_idics(out_dir, "depth_of_field", metrics)
    return metrics
