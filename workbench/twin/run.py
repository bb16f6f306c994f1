"""A digital twin of the user's rig, end to end: :func:`run_twin`.

1. Inputs (:mod:`.inputs`): the rig from the calibration file, the images checked against it.
2. The real pair: with a right image, the instrument's reference shape of the user's own pair (the plane the
   twin paints on, the right camera's region); with a static pair, the instrument's noise on it (the figure the
   prediction is checked against) and its mean motion (refused above the image noise's motion equivalent, see
   :func:`static_motion_limit_px`).
3. The speckle (:mod:`measurement.speckle_quality`): grey statistics, speckle size, SSSIG and MIG per subset,
   each camera's noise model (measured from the static pair, motion and illumination drift undone; else
   estimated from one image), the subset advice (too fine / too coarse are refused, with the subset it needs).
4. The twin (:mod:`.scene`): the pattern on the plane, rendered through the rig; its static pairs measured by the
   instrument (:mod:`.predict`): the noise floor of U, V, W (µm) and strain (µε) per point and pooled, beside it
   the instrument's own predicted sigma of a static repeat (:mod:`measurement.uncertainty`, with the cameras' noise
   models), the interpolation bias on the pattern, l10 on the pattern.
5. The what-if table (:mod:`.whatif`; with the lens stated, f-number and focus rows from :mod:`.optics`); with a
   static pair, the top settings recommendation is also applied to the real pair and measured.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from measurement.dic import DICSettings
from measurement.dic.roi import texture_mask
from measurement.speckle_quality import (grey_statistics, noise_from_image, noise_from_static_pair, speckle_size_px,
                                         subset_advice, subset_sssig)
from measurement.stereo_dic import reference_shape

from .inputs import TwinInputs, load_inputs
from .measure import static_noise_2d, static_noise_stereo
from .predict import interpolation_bias_px, spatial_resolution, twin_static_noise
from .scene import TwinScene, build_stereo_scene, default_plane, plane_through_points, twin_rig
from .whatif import (displacement_figure, rank, strain_figure, strain_only, theory_l10, variants, vsg_px)


class NotStaticError(ValueError):
    """The "static" pair moved by more than its noise can hide."""


@dataclass(frozen=True)
class TwinSettings:
    """The user's instrument settings the twin predicts for.

    Attributes
    ----------
    subset_px : int
        Odd subset width, px.
    step_px : int or None
        Grid step, px (None: a quarter of the subset, at least 2).
    order : {1, 2}
    interpolation : {"biquintic", "bicubic"}
    strain_window : int or None
        Strain window in grid points (odd >= 3); None: Cosserat triangles.
    """

    subset_px: int = 33
    step_px: int | None = None
    order: int = 2
    interpolation: str = "biquintic"
    strain_window: int | None = 5

    def dic(self) -> DICSettings:
        step = self.step_px if self.step_px is not None else max(2, self.subset_px // 4)
        return DICSettings(subset_size=int(self.subset_px), step=int(step), order=int(self.order),
                           interpolation=self.interpolation)


@dataclass
class TwinResult:
    """Everything the twin found and predicted (see :func:`run_twin`); ``summary()`` is JSON-ready."""

    inputs: TwinInputs = field(repr=False)
    settings: TwinSettings
    speckle: dict
    noise_models: dict = field(repr=False)
    prediction: dict = field(default_factory=dict)
    measured: dict | None = None
    comparison: dict | None = None
    whatif: list = field(default_factory=list)
    whatif_real: dict | None = None
    maps: dict = field(default_factory=dict, repr=False)
    scene: TwinScene | None = field(default=None, repr=False)
    timings_s: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    #: The mask of points of interest the instrument used (the user's, and the automatic ROI's), or None.
    mask: np.ndarray | None = field(default=None, repr=False)
    #: The region the instrument measured, in words (rectangle, mask, automatic ROI and what it kept).
    roi_used: str = "whole image"

    @property
    def unit(self) -> str:
        return "um" if self.inputs.stereo else "px"

    def summary(self) -> dict:
        return _json({"kind": "stereo" if self.inputs.stereo else "2d", "unit": self.unit,
                      "settings": self.settings.__dict__, "dic_step_px": self.settings.dic().step,
                      "inputs": {k: str(v.path) for k, v in self.inputs.infos.items()},
                      "calibration": str(self.inputs.calibration) if self.inputs.calibration else None,
                      "bit_depth": self.inputs.bit_depth, "roi": self.inputs.roi, "roi_used": self.roi_used,
                      "speckle": self.speckle,
                      "noise_models": {k: _noise_dict(m) for k, m in self.noise_models.items()},
                      "prediction": self.prediction, "measured": self.measured, "comparison": self.comparison,
                      "whatif": self.whatif, "whatif_real": self.whatif_real, "timings_s": self.timings_s,
                      "notes": self.inputs.notes + self.notes})


def _noise_dict(model) -> dict:
    return {"sigma_grey": model.sigma_grey, "read_noise_grey": model.read_noise_grey,
            "electrons_per_grey": model.electrons_per_grey, "source": model.source}


def _json(value):
    if isinstance(value, dict):
        return {str(k): _json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.ndarray):
        return _json(value.tolist())
    return value


def describe_roi(roi, mask, shape) -> str:
    """The user's region in words: ``"whole image"``, ``"rectangle X0,Y0,X1,Y1"``, with a mask's pixel count."""
    text = "whole image" if roi is None else "rectangle {},{},{},{} px".format(*roi)
    if mask is not None:
        text += f" and your mask ({int(np.count_nonzero(mask))} of {shape[0] * shape[1]} px)"
    return text


def static_motion_limit_px(image: np.ndarray, region: np.ndarray, sigma_grey: float) -> float:
    """The motion whose grey-level change equals the image noise: ``sigma / RMS |grad I|`` over the region, px.

    Below it a "static" pair's motion hides in the noise (and is undone before the noise is read); above it the
    pair shows motion, not noise, and is refused."""
    gy, gx = np.gradient(np.asarray(image, dtype=np.float64))
    g2 = (gx * gx + gy * gy)[region]
    return float(sigma_grey / math.sqrt(np.mean(g2))) if g2.size and np.mean(g2) > 0 else math.inf


def right_region_of(shape, x_px, y_px, subset: int, step: int) -> np.ndarray:
    """The right image's pixels the matched subsets cover: each matched point's neighbourhood (the step, at least
    half a subset), so the right camera's statistics are those of the specimen it sees, not of the background."""
    region = np.zeros(shape, dtype=bool)
    x = np.rint(np.asarray(x_px)).astype(np.int64)
    y = np.rint(np.asarray(y_px)).astype(np.int64)
    ok = (x >= 0) & (y >= 0) & (x < shape[1]) & (y < shape[0])
    if not ok.any():
        region[:] = True
        return region
    region[y[ok], x[ok]] = True
    reach = max(int(step), int(subset) // 2)
    return ndimage.binary_dilation(region, np.ones((2 * reach + 1, 2 * reach + 1), dtype=bool))


def _speckle_figures(image, region, bit_depth, noise, settings: DICSettings) -> dict:
    stats = grey_statistics(image, region, bit_depth)
    size = speckle_size_px(image, region)
    half = settings.subset_size // 2
    rows, cols = np.nonzero(region)
    ys = np.arange(rows.min() + half, rows.max() - half + 1, settings.step)
    xs = np.arange(cols.min() + half, cols.max() - half + 1, settings.step)
    X, Y = np.meshgrid(xs, ys)
    keep = region[Y, X]
    x, y = X[keep], Y[keep]
    x = np.asarray(x, dtype=np.int64)
    y = np.asarray(y, dtype=np.int64)
    inside = (x >= half) & (y >= half) & (x < image.shape[1] - half) & (y < image.shape[0] - half)
    x, y = x[inside], y[inside]
    sx, sy, mig = subset_sssig(image, x, y, settings.subset_size, noise.sigma_grey)
    advice = subset_advice(image, x[:: max(1, x.size // 400)], y[:: max(1, y.size // 400)], noise.sigma_grey, size)
    return {"mean_grey": stats.mean_grey, "std_grey": stats.std_grey, "contrast": stats.contrast,
            "p1_grey": stats.p1_grey, "p99_grey": stats.p99_grey, "saturated_fraction": stats.saturated_fraction,
            "zero_fraction": stats.zero_fraction, "histogram": stats.histogram.tolist(),
            "bin_edges": stats.bin_edges.tolist(), "speckle_size_px": size, "autocorrelation_radius_px": size / 2,
            "mig_grey_per_px": float(np.mean(mig)) if mig.size else math.nan,
            "sssig_median_grey2": float(np.median(np.minimum(sx, sy))) if sx.size else math.nan,
            "noise_sigma_grey": noise.sigma_grey, "noise_source": noise.source,
            "advice": {"subset_px": advice.subset_px, "needed_px": advice.needed_px, "verdict": advice.verdict,
                       "message": advice.message},
            "_points": (x, y, sx, sy, mig)}


def _points_sssig(image, x_px, y_px, subset: int, sigma: float) -> np.ndarray:
    """SSSIG x, y (grey^2) and MIG (grey/px) of the user's left subsets at the points, (N, 3); NaN off the image."""
    x = np.rint(np.asarray(x_px)).astype(np.int64)
    y = np.rint(np.asarray(y_px)).astype(np.int64)
    half = subset // 2
    ok = (x >= half) & (y >= half) & (x < image.shape[1] - half) & (y < image.shape[0] - half)
    out = np.full((x.size, 3), np.nan)
    if ok.any():
        out[ok] = np.column_stack(subset_sssig(image, x[ok], y[ok], subset, sigma))
    return out


def generated_pattern(shape, figures: dict, seed: int) -> np.ndarray:
    """A Gaussian speckle of ``shape`` with the measured speckle size, mean and standard deviation (the truth side's
    analytic pattern, point-sampled)."""
    from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle, radius_for_speckle_size

    size = max(float(figures["speckle_size_px"]), 1.6)
    pattern = gaussian_speckle(extent_for_shape(shape, 8.0), radius_for_speckle_size(size), 0.5, int(seed) + 17,
                               mean_grey=float(figures["mean_grey"]), std_grey=float(figures["std_grey"]))
    return pattern.render_reference(shape)


def optics_rows(scene, lens, regions, noise_models, inputs, dic, window, roi, mask, seed, say) -> list[dict]:
    """What-if rows of a thin-lens rig: one stop up and down, the focus 5 % of the distance nearer and farther."""
    from .optics import changed_scene

    distance = float(np.linalg.norm(scene.plane.point_mm))
    shift = round(0.05 * distance, 1)
    N0 = lens.f_number
    changes = [(f"f-number {N0:g} -> {N0 * math.sqrt(2):.2g}", {"f_number": N0 * math.sqrt(2)}),
               (f"f-number {N0:g} -> {N0 / math.sqrt(2):.2g}", {"f_number": N0 / math.sqrt(2)}),
               (f"focus {shift:g} mm nearer", {"focus_shift_mm": -shift}),
               (f"focus {shift:g} mm farther", {"focus_shift_mm": shift})]
    rows = []
    for label, change in changes:
        say(f"what-if: {label}")
        changed, info = changed_scene(scene, lens, regions, ceiling=2 ** inputs.bit_depth - 1, **change)
        p = twin_static_noise(changed, noise_models, inputs.bit_depth, dic, roi=roi, mask=mask, strain_window=window,
                              repeats=1, seed=seed)
        r0 = p.runs[0]
        left = info["left"]
        note = (f"blur sigma {left['sigma_now_px']:.2f} -> {left['sigma_new_px']:.2f} px, light x "
                f"{left['light_factor']:.2f}" + (" (sharper than your image: the twin cannot sharpen, only the light "
                                                  "changes)" if left["sharper"] else ""))
        rows.append({"label": label, "subset_px": dic.subset_size, "step_px": dic.step, "order": dic.order,
                     "strain_window": window, "noise": r0.noise, "strain_ue": r0.strain_ue, "points": r0.points,
                     "instrument_sigma": r0.instrument_sigma, "displacement_noise": displacement_figure(r0.noise),
                     "strain_noise_ue": strain_figure(r0.strain_ue),
                     "instrument_sigma_figure": displacement_figure(r0.instrument_sigma),
                     "l10_theory_px": theory_l10(dic), "vsg_px": vsg_px(dic, window), "optics": {**change, **info},
                     "note": note, "applies_to_real": False})
    return rows


def run_twin(left, right=None, static_left=None, static_right=None, *, calibration=None, roi=None, mask=None,
             auto_roi: bool = False, settings: TwinSettings | None = None, bit_depth: int | None = None,
             repeats: int = 2, seed: int = 0, whatif: bool = True, objective: str = "displacement",
             bias: bool = True, resolution: bool = True, apply_top_to_real: bool = True,
             allow_coarse: bool = False, lens=None, texture: str = "photo", progress=None) -> TwinResult:
    """The digital twin of a rig from its calibration and images (module notes).

    Parameters
    ----------
    left, right, static_left, static_right : path
        The left (and right) reference images; a second exposure of each of the unmoved scene (optional).
    calibration : path, optional
        The rig's calibration (needed for a stereo twin; a one-camera twin without it works in px).
    roi : (x0, y0, x1, y1) or str, optional
    mask : path or ndarray of bool, optional
    auto_roi : bool
        Measure only subsets with enough texture (:func:`measurement.dic.roi.texture_mask`).
    settings : TwinSettings
        The user's subset, step, order, interpolation and strain window.
    bit_depth : int, optional
        The data's bit depth, if stated (checked against the files).
    repeats : int
        Twin static pairs for the prediction (>= 1; 2 gives per-point maps).
    seed : int
        Seed of every noise draw.
    whatif : bool
        Build the what-if table.
    objective : {"displacement", "strain"}
        What the table ranks by.
    bias, resolution : bool
        Predict the interpolation bias / l10 on the pattern.
    apply_top_to_real : bool
        With a static pair, measure the real pair again with the lowest-noise change.
    allow_coarse : bool
        Go on when the speckle is too coarse or too fine for any subset (the advice is still reported).
    texture : {"photo", "generated"}
        The twin's pattern: your photograph itself (default), or a generated Gaussian speckle with its measured
        speckle size, mean grey and contrast (for a pattern you have not applied yet, or to see what the
        photograph's particulars are worth).
    lens : :class:`workbench.twin.optics.Lens`, optional
        The f-number and pixel pitch of a stereo rig's lenses: adds the f-number and focus rows to the what-if table.
    progress : callable, optional
        ``progress(message)`` for long steps.

    Raises
    ------
    ValueError
        Bad inputs (:mod:`.inputs`), a speckle too fine or too coarse (unless ``allow_coarse``);
        :class:`NotStaticError` for a static pair that moved.
    """
    say = progress or (lambda message: None)
    settings = settings or TwinSettings()
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    if texture not in ("photo", "generated"):
        raise ValueError(f"texture must be 'photo' or 'generated', got {texture!r}")
    times = {}
    start = time.perf_counter()
    inputs = load_inputs(left, right, static_left, static_right, calibration=calibration, roi=roi, mask=mask,
                         bit_depth=bit_depth)
    dic = settings.dic()
    images = inputs.images
    region = inputs.region
    notes: list[str] = []
    times["inputs"] = time.perf_counter() - start

    # 2. the real pair
    t = time.perf_counter()
    rig = inputs.rig
    measured = None
    real_shape = None
    roi_rect, mask_arr = inputs.roi, inputs.mask
    roi_used = describe_roi(roi_rect, mask_arr, images["left"].shape)
    if auto_roi:
        auto = texture_mask(images["left"], dic.subset_size)      # noise estimated from the image, as `stereo` does
        before = int(region.sum())
        mask_arr = auto if mask_arr is None else (mask_arr & auto)
        region = region & auto
        if not region.any():
            raise ValueError("--auto-roi: no subset of the left reference has enough texture")
        roi_used += (f", then the automatic ROI (--auto-roi: subsets of {dic.subset_size} px with enough texture): "
                     f"{int(region.sum())} of its {before} px kept ({100 * region.sum() / before:.0f} %)")
    if inputs.stereo:
        say("instrument: reference shape of your pair")
        real_shape = reference_shape(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm,
                                     images["left"], images["right"], dic, roi=roi_rect, mask=mask_arr)
    if inputs.has_static:
        say("instrument: your static pair")
        if inputs.stereo:
            measured = static_noise_stereo(rig, images["left"], images["right"], images["static_left"],
                                           images["static_right"], dic, roi=roi_rect, mask=mask_arr,
                                           strain_window=settings.strain_window, shape=real_shape)
        else:
            measured = static_noise_2d(images["left"], images["static_left"], dic, roi=roi_rect, mask=mask_arr,
                                       strain_window=settings.strain_window)
    times["real_pair"] = time.perf_counter() - t

    # 3. speckle and noise
    t = time.perf_counter()
    right_region = None
    if inputs.stereo:
        rm = real_shape.right_match
        ok = real_shape.valid
        xr, yr = (rm.x + rm.u)[ok], (rm.y + rm.v)[ok]
        right_region = right_region_of(images["right"].shape, xr, yr, dic.subset_size, dic.step)
    noise_models = {}
    for side, reg in (("left", region), ("right", right_region)):
        if side not in images:
            continue
        if inputs.has_static:
            motion = measured.mean_motion_uv_px if side == "left" else measured.right_motion_uv_px
            noise_models[side] = noise_from_static_pair(images[side], images[f"static_{side}"], reg,
                                                        motion_xy_px=motion)
        else:
            noise_models[side] = noise_from_image(images[side])
            notes.append(f"{side} camera noise estimated from one image ({noise_models[side].sigma_grey:.3g} grey): "
                         "give a static pair (--static-left/--static-right) to measure it")
    speckle = {}
    for side, reg in (("left", region), ("right", right_region)):
        if side in images:
            speckle[side] = _speckle_figures(images[side], reg, inputs.bit_depth, noise_models[side], dic)
    advice = speckle["left"]["advice"]
    if advice["verdict"] != "ok" and not allow_coarse:
        raise ValueError(f"speckle {advice['verdict']}: {advice['message']} (--allow-coarse to go on anyway)")
    if inputs.has_static:
        limit = static_motion_limit_px(images["left"], region, noise_models["left"].sigma_grey)
        if measured.mean_motion_px > limit:
            paths = inputs.infos
            raise NotStaticError(
                f"the static pair {paths['left'].path.name} -> {paths['static_left'].path.name} is not static: its "
                f"mean motion is ({measured.mean_motion_uv_px[0]:+.4f}, {measured.mean_motion_uv_px[1]:+.4f}) px, "
                f"above the {limit:.4f} px that the image noise ({noise_models['left'].sigma_grey:.3g} grey) can "
                "hide; record two exposures without touching the rig")
        speckle["left"]["static_motion_limit_px"] = limit
    times["speckle"] = time.perf_counter() - t

    # 4. the twin
    t = time.perf_counter()
    pattern = images["left"] if not inputs.has_static else 0.5 * (images["left"] + images["static_left"])
    if texture == "generated":
        pattern = generated_pattern(pattern.shape, speckle["left"], seed)
        notes.append(f"twin pattern: a generated Gaussian speckle with your measured statistics (speckle "
                     f"{speckle['left']['speckle_size_px']:.2f} px, mean {speckle['left']['mean_grey']:.1f} grey, std "
                     f"{speckle['left']['std_grey']:.1f} grey), not your photograph")
    scene = None
    mm_per_px = None
    if inputs.stereo:
        trig, skews = twin_rig(rig)
        if any(skews.values()):
            notes.append("the renderer has no skew: the twin's cameras drop the calibration's skew "
                         f"({skews['left']:+.3g}, {skews['right']:+.3g} px) and measure with the same cameras")
        try:
            point, normal = plane_through_points(real_shape.X_mm[real_shape.valid])
            plane_note = "the plane fitted through your pair's measured reference points"
        except ValueError:
            point, normal = default_plane(trig)
            plane_note = "the plane where the optical axes meet"
        say("twin: rendering both cameras")
        scene = build_stereo_scene(trig, pattern, point, normal, right_target=images["right"],
                                   right_region=right_region)
        notes.append(f"twin scene: your left image painted on {plane_note} (distance {np.linalg.norm(point):.1f} mm),"
                     " point-sampled through both cameras; the right view scaled to your right image's mean and "
                     "contrast; both cameras' optics taken equal")
        Z = real_shape.X_mm[real_shape.valid][:, 2]
        mm_per_px = float(np.median(Z) / rig.left.fx)
    else:
        scene = TwinScene(None, {"left": pattern}, {"left": np.ones(pattern.shape, bool)}, {}, None)
    times["twin_render"] = time.perf_counter() - t

    t = time.perf_counter()
    say(f"twin: {repeats} static pair(s) through the instrument")
    pooled = twin_static_noise(scene, noise_models, inputs.bit_depth, dic, roi=roi_rect, mask=mask_arr,
                               strain_window=settings.strain_window, repeats=repeats, seed=seed, progress=say)
    times["twin_static"] = time.perf_counter() - t
    base_run = pooled.runs[0]
    prediction = {"noise": pooled.noise, "noise_detrended": pooled.detrended, "strain_ue": pooled.strain_ue,
                  "instrument_sigma": pooled.instrument_sigma, "instrument_sigma_source": "measurement.uncertainty",
                  "repeats": repeats, "points": base_run.points,
                  "mm_per_px": mm_per_px, "vsg_px": vsg_px(dic, settings.strain_window),
                  "l10_theory_px": theory_l10(dic)}
    t = time.perf_counter()
    if bias:
        say("twin: interpolation bias on your pattern")
        b = interpolation_bias_px(pattern, region, dic)
        prediction["bias"] = b
        if mm_per_px:
            prediction["bias"]["max_abs_um"] = b["max_abs_px"] * mm_per_px * 1e3
    times["bias"] = time.perf_counter() - t
    t = time.perf_counter()
    if resolution:
        say("twin: spatial resolution (Star field on your pattern)")
        r = spatial_resolution(pattern, region, dic, noise_models["left"], inputs.bit_depth, seed=seed)
        prediction["resolution"] = r
        if mm_per_px and np.isfinite(r.get("l10_px", math.nan)):
            r["l10_mm"] = r["l10_px"] * mm_per_px
    times["resolution"] = time.perf_counter() - t

    comparison = None
    if measured is not None:
        comparison = {}
        for key, predicted in pooled.noise.items():
            real = measured.noise.get(key, math.nan)
            sigma = pooled.instrument_sigma.get(key, math.nan)
            # the measured static noise (over the points, mean removed) is what the instrument's sigma predicts
            comparison[key] = {"predicted": predicted, "measured": real,
                               "ratio": predicted / real if real else math.nan,
                               "instrument_sigma": sigma,
                               "instrument_ratio": sigma / real if real else math.nan,
                               "measured_detrended": measured.detrended.get(key, math.nan)}
        for key, predicted in pooled.strain_ue.items():
            real = measured.strain_ue.get(key, math.nan)
            comparison[f"{key}_ue"] = {"predicted": predicted, "measured": real,
                                       "ratio": predicted / real if real else math.nan}

    # 5. what-if
    rows, whatif_real = [], None
    t = time.perf_counter()
    if whatif:
        max_subset = min(images["left"].shape) // 2 * 2 - 1
        for label, s, window in variants(dic, settings.strain_window, base_run.points, max_subset):
            run = base_run
            if label.startswith("baseline"):
                run_noise, run_strain = base_run.noise, base_run.strain_ue
            elif s is dic:           # a strain-only change
                run_noise, run_strain = base_run.noise, strain_only(base_run, window)
            else:
                say(f"what-if: {label}")
                p = twin_static_noise(scene, noise_models, inputs.bit_depth, s, roi=roi_rect, mask=mask_arr,
                                      strain_window=window, repeats=1, seed=seed)
                run = p.runs[0]
                run_noise, run_strain = run.noise, run.strain_ue
            rows.append({"label": label, "subset_px": s.subset_size, "step_px": s.step, "order": s.order,
                         "strain_window": window, "noise": run_noise, "strain_ue": run_strain, "points": run.points,
                         "instrument_sigma": run.instrument_sigma, "displacement_noise": displacement_figure(run_noise),
                         "strain_noise_ue": strain_figure(run_strain),
                         "instrument_sigma_figure": displacement_figure(run.instrument_sigma),
                         "l10_theory_px": theory_l10(s),
                         "vsg_px": vsg_px(s, window)})
        if lens is not None and inputs.stereo:
            rows += optics_rows(scene, lens, {"left": region, "right": right_region}, noise_models, inputs, dic,
                                settings.strain_window, roi_rect, mask_arr, seed, say)
        rows = rank(rows, objective)
        if lens is None or not inputs.stereo:
            reason = ("a one-camera twin without a calibration has no geometry for the lens" if not inputs.stereo else
                      "a calibration describes a pinhole camera: give the lens's f-number and the pixel pitch "
                      "(--f-number, --pixel-pitch-um) for these rows")
            for lens_row in ("f-number", "focus distance"):
                rows.append({"label": f"{lens_row}: not applicable", "rank": None, "reason": reason})
        top = next((r for r in rows if r.get("rank") == 1), None)
        applicable = next((r for r in rows if r.get("rank") and r.get("applies_to_real", True)), None)
        if top is not None and top is not applicable:
            notes.append(f"the lowest-noise change ({top['label']}) changes the optics, which a recorded pair cannot "
                         "show; the best settings change was applied to your pair instead")
        top = applicable
        if top is not None and measured is not None and apply_top_to_real:
            say(f"instrument: your static pair with the lowest-noise change ({top['label']})")
            s = DICSettings(subset_size=top["subset_px"], step=top["step_px"], order=top["order"],
                            interpolation=dic.interpolation)
            if inputs.stereo:
                after = static_noise_stereo(rig, images["left"], images["right"], images["static_left"],
                                            images["static_right"], s, roi=roi_rect, mask=mask_arr,
                                            strain_window=top["strain_window"])
            else:
                after = static_noise_2d(images["left"], images["static_left"], s, roi=roi_rect, mask=mask_arr,
                                        strain_window=top["strain_window"])
            key = "displacement_noise" if objective == "displacement" else "strain_noise_ue"
            before_fig = displacement_figure(measured.noise) if key == "displacement_noise" else \
                strain_figure(measured.strain_ue)
            after_fig = displacement_figure(after.noise) if key == "displacement_noise" else \
                strain_figure(after.strain_ue)
            whatif_real = {"label": top["label"], "objective": objective, "measured_before": before_fig,
                           "measured_after": after_fig, "predicted_before": rows[0][key], "predicted_after": top[key],
                           "measured_change": after_fig / before_fig - 1.0 if before_fig else math.nan,
                           "predicted_change": top["change"], "noise_before": measured.noise,
                           "noise_after": after.noise, "strain_before_ue": measured.strain_ue,
                           "strain_after_ue": after.strain_ue}
    times["whatif"] = time.perf_counter() - t
    times["total"] = time.perf_counter() - start

    for side in speckle:
        speckle[side].pop("_points", None)
    maps = {"x_px": base_run.x_px, "y_px": base_run.y_px, "per_point": pooled.per_point,
            "instrument_sigma": pooled.sigma_map,
            "measured": None if measured is None else measured.values,
            "sssig": _points_sssig(images["left"], base_run.x_px, base_run.y_px, dic.subset_size,
                                   noise_models["left"].sigma_grey)}
    return TwinResult(inputs, settings, speckle, noise_models, prediction, None if measured is None else
                      measured.summary(), comparison, rows, whatif_real, maps, scene, times, notes, mask_arr,
                      roi_used)
