"""Render stereo views of the paper's checkerboard with their ground truth (``workbench render checkerboard``)."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from labio.atomic import atomic_write_image, atomic_write_text

from scenes.optics.camera import SensorSpec
from scenes.sensor.noise import SensorNoise, to_image_dtype
from scenes.surfaces.checkerboard import Checkerboard
from workbench.manifest import complete_folder, prepare_folder
from workbench.poses import check_in_view, random_board_poses
from workbench.rigs import StereoRig

EXPOSURE_GREY = {8: 255.0, 16: 65535.0}


@dataclass
class BoardView:
    """One camera's rendered view of the board and its truth."""

    view: int
    camera: str
    image_grey: np.ndarray            # (H, W) noise-free grey levels
    R_cam_from_board: np.ndarray      # (3, 3)
    t_cam_from_board_mm: np.ndarray   # (3,)
    points_cam_mm: np.ndarray         # (N, 3) inner corners in this camera's frame
    pixels: np.ndarray                # (N, 2) their true projections (scenes.optics.projection), OpenCV convention
    extra: dict = field(default_factory=dict)


def board_outline_mm(board: Checkerboard) -> np.ndarray:
    """Outer corners of the checkered area (without the white margin), board frame, (4, 3); a target with its
    own ``outline_board_mm()`` (e.g. :class:`scenes.surfaces.dot_grid.DotGrid`) gives that."""
    if hasattr(board, "outline_board_mm"):
        return np.asarray(board.outline_board_mm(), dtype=float)
    x0, x1, y0, y1 = board.extent_board_mm()
    m = board.margin_squares * board.square_mm
    return np.array([[x0 + m, y0 + m, 0], [x1 - m, y0 + m, 0], [x1 - m, y1 - m, 0], [x0 + m, y1 - m, 0]])


def camera_to_sensor_spec(camera, pixel_pitch_mm: float = 0.00345, **lens) -> SensorSpec:
    """The renderer's description of a camera (a rig's ``ScheimpflugCamera`` parameters, read as numbers: same Table 1 names, and the camera's k3 and thin prism s1-s4 unless
    ``lens`` gives them); the renderer builds the paper's RMM and has no skew, so a camera with one is refused."""
    if camera.tilt_model != "rmm":
        raise ValueError(f"the renderer implements the paper's RMM tilt, not {camera.tilt_model!r}")
    if camera.skew != 0.0:
        raise ValueError(f"the renderer has no skew term; this camera has skew = {camera.skew:g} px")
    terms = {n: float(getattr(camera, n)) for n in ("k3", "s1", "s2", "s3", "s4") if getattr(camera, n) != 0.0}
    return SensorSpec(**camera.intrinsics(), width=camera.width, height=camera.height,
                      pixel_pitch_mm=pixel_pitch_mm, **{**terms, **lens})


def sensor_spec_for(rig: StereoRig, side: str, **lens) -> SensorSpec:
    """The renderer's description of one of the rig's cameras."""
    return camera_to_sensor_spec(rig.camera(side), rig.pixel_pitch_mm, **lens)


#: Renderers of board views: "auto" (exact where the view allows it, else Mitsuba), "exact" (refuse otherwise),
#: "mitsuba" (Monte Carlo: fixed spp or adaptive).
BOARD_RENDERERS = ("auto", "exact", "mitsuba")


def render_board_views(rig: StereoRig, board: Checkerboard, poses, *, spp: int = 64, seed: int = 0,
                       bit_depth: int = 8, progress: bool = True, lens_terms: dict | None = None,
                       mc_target_grey: float | None = None, renderer: str = "auto"):
    """Render every pose in both cameras; yields :class:`BoardView` (noise-free images).

    ``poses``: list of ``(R_world_from_board, t_world_from_board_mm)``. A pose whose board leaves an image
    raises :class:`workbench.poses.BoardOutOfViewError` naming the view and camera. The truth of a view is
    where the corners really are (:meth:`scenes.surfaces.checkerboard.Checkerboard.true_corners_board_mm`: an imperfect
    board's corners are not the nominal ones the instrument is told). ``lens_terms``: distortion terms of the
    true lenses that the rig's model lacks (``k3``, ``s1``-``s4``). The truth pixels are always projected by the
    truth side's camera (:func:`scenes.optics.projection.project_points`), never by the instrument's model. ``mc_target_grey``: render both cameras of a view
    from one scene with :mod:`scenes.rendering.adaptive` at that Monte-Carlo noise (``spp`` is then unused); the measured
    noise and sample counts are in ``BoardView.extra["mc"]``. ``renderer`` (:data:`BOARD_RENDERERS`): ``"auto"``
    renders each view exactly (:mod:`scenes.rendering.exact`: the box-filtered pixel of the printed polygons, no
    Monte-Carlo noise) where it can and with Mitsuba otherwise (a bowed board that occludes itself, ...), through
    the one render entry :func:`scenes.rendering.render.render_views` (with ``mc_target_grey`` an occluding board
    is made exactly but at its occluding edges, which Mitsuba traces);
    ``BoardView.extra["renderer"]`` says which made the image, ``extra["fallback"]`` why Mitsuba did.
    """
    from scenes.optics.projection import project_points
    from scenes.rendering.exact import NotExactError
    from scenes.rendering.render import render_views

    if renderer not in BOARD_RENDERERS:
        raise ValueError(f"board renderer {renderer!r}: choose one of {', '.join(BOARD_RENDERERS)}")
    corners_board = board.true_corners_board_mm()
    for view, (R_wb, t_wb) in enumerate(tqdm(poses, desc="rendering board views", disable=not progress)):
        check_in_view(board_outline_mm(board) @ np.asarray(R_wb).T + t_wb, rig, what=f"board of view {view}")
        surface = board.surface(R_wb, t_wb)
        specs = {side: sensor_spec_for(rig, side, **(lens_terms or {})) for side in ("left", "right")}
        try:
            made = render_views([(specs[side], rig.pose(side)) for side in ("left", "right")], [surface],
                                renderer=renderer, spp=spp, seed=seed * 100003 + 2 * view,
                                exposure_grey=EXPOSURE_GREY[bit_depth], mc_target_grey=mc_target_grey)
        except NotExactError as err:
            side = ("left", "right")[err.view_index]
            raise ValueError(f"view {view}, {side} camera: the exact renderer cannot render it: {err}") from None
        for k, side in enumerate(("left", "right")):
            R_cw, t_cw = rig.pose(side)
            R_cb, t_cb = R_cw @ R_wb, R_cw @ t_wb + t_cw
            spec = specs[side]
            image, extra = made[k].image_grey, {"renderer": made[k].renderer}
            if made[k].mc is not None:
                extra = {"mc": made[k].mc, **extra}
            if made[k].reason is not None:
                failed = made[k].reason_view
                extra["fallback"] = (made[k].reason if failed is None
                                     else f"{('left', 'right')[failed]} camera: {made[k].reason}")
            points = corners_board @ R_cb.T + t_cb
            pixels = project_points(spec, np.eye(3), np.zeros(3), points)     # truth side, never the instrument
            yield BoardView(view, side, image, R_cb, t_cb, points, pixels, extra)


def write_checkerboard_dataset(rig: StereoRig, out_dir: Path, n_views: int, seed: int, *, spp: int = 64,
                               board: Checkerboard | None = None, noise: SensorNoise | None = None,
                               image_format: str = "png", progress: bool = True, poses=None,
                               overwrite: bool = False, lens_terms: dict | None = None,
                               mc_target_grey: float | None = None, renderer: str = "auto") -> dict:
    """Render ``n_views`` random stereo poses (or the given ``poses``) and write images, ``truth.json`` and
    ``manifest.json`` (:mod:`workbench.manifest`; truth and manifest last: a folder with a manifest is complete).

    A folder holding an earlier dataset is refused (:class:`workbench.manifest.DatasetFolderError`) unless
    ``overwrite``, which first deletes exactly the files of that dataset.
    """
    board = board or Checkerboard()
    noise = noise or SensorNoise(read_noise_grey=0.0, electrons_per_grey=None, bit_depth=8)
    if image_format not in ("png", "tiff"):
        raise ValueError(f"image format must be png or tiff, got {image_format!r}")
    out_dir = Path(out_dir)
    if poses is None:
        poses = random_board_poses(rig, board_outline_mm(board), n_views, seed)
    extension = "png" if image_format == "png" else "tif"
    names = [f"{side}_{view:03d}.{extension}" for view in range(len(poses)) for side in ("left", "right")]
    prepare_folder(out_dir, "checkerboard", names + ["truth.json"], overwrite=overwrite)
    images = []
    for bv in render_board_views(rig, board, poses, spp=spp, seed=seed, bit_depth=noise.bit_depth or 8,
                                 progress=progress, lens_terms=lens_terms, mc_target_grey=mc_target_grey,
                                 renderer=renderer):
        name = f"{bv.camera}_{bv.view:03d}.{extension}"
        noisy = noise.apply(bv.image_grey, seed=seed * 100003 + 2 * bv.view + (bv.camera == "right"))
        atomic_write_image(out_dir / name, to_image_dtype(noisy, noise.bit_depth or 8))
        images.append({
            "file": name, "camera": bv.camera, "view": bv.view,
            "intrinsics": rig.camera(bv.camera).to_dict(),
            "R_cam_from_board": bv.R_cam_from_board.tolist(),
            "t_cam_from_board_mm": bv.t_cam_from_board_mm.tolist(),
            "points_cam_mm": bv.points_cam_mm.tolist(),
            "pixels": bv.pixels.tolist(),
            **({"mc": bv.extra["mc"]} if "mc" in bv.extra else {}),
            "renderer": bv.extra.get("renderer", "mitsuba"),
            **({"renderer_fallback": bv.extra["fallback"]} if "fallback" in bv.extra else {}),
        })
    truth = {
        "about": "Ground truth of rendered checkerboard views. Pixels follow OpenCV (pixel centres at integer "
                 "coordinates) and are computed by the truth side (scenes.optics.projection.project_points) from points_cam_mm. Poses: "
                 "X_cam = R_cam_from_board @ X_board + t_cam_from_board_mm; stereo: X_right = R @ X_left + T.",
        "rig": {"name": rig.name, "R_right_from_left": np.asarray(rig.R_right_from_left).tolist(),
                "T_right_from_left_mm": np.asarray(rig.T_right_from_left_mm).tolist(),
                "pixel_pitch_mm": rig.pixel_pitch_mm},
        "board": {"squares": list(board.squares), "inner_corners": list(board.inner_corners),
                  "square_mm": board.square_mm, "corners_board_mm": board.corners_board_mm().tolist(),
                  **({} if board.is_perfect else {
                      "imperfections": {"print_scale_error": board.print_scale_error, "bow_sag_mm": board.bow_sag_mm,
                                        "bow_axis": board.bow_axis, "corner_noise_mm": board.corner_noise_mm,
                                        "corner_noise_seed": board.corner_noise_seed},
                      "true_corners_board_mm": board.true_corners_board_mm().tolist()})},
        **({"true_lens_terms": {k: float(v) for k, v in lens_terms.items()}} if lens_terms else {}),
        "render": {"renderer": renderer,
                   "renderers": {name: sum(im["renderer"] == name for im in images)
                                 for name in sorted({im["renderer"] for im in images})},
                   "spp": "adaptive" if mc_target_grey is not None else spp,
                   **({"mc_target_grey": float(mc_target_grey)} if mc_target_grey is not None else {}),
                   "seed": seed, "bit_depth": noise.bit_depth,
                   "read_noise_grey": noise.read_noise_grey, "electrons_per_grey": noise.electrons_per_grey},
        "images": images,
    }
    atomic_write_text(out_dir / "truth.json", json.dumps(truth, indent=1))
    complete_folder(out_dir, "checkerboard", [im["file"] for im in images] + ["truth.json"],
                    {"rig": rig.name, "image_size_px": [rig.left.width, rig.left.height], "views": len(poses),
                     **truth["render"], "format": image_format})
    return truth
