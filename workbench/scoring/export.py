"""``workbench export``: a rendered dataset written the way another DIC tool reads it, with its truth.

Layouts (``FORMATS``):

* ``native``: the images under their own names, ``calibration.json`` (this project's format);
* ``dice``: ``images/img_0000_0.tif`` (left) / ``img_0000_1.tif`` (right) — a 2-D pair ``img_0000.tif`` /
  ``img_0001.tif`` — and DICe's ``input.xml`` (image lists, ``subset_size``, ``step_size``,
  ``camera_system_file``), ``params.xml`` (ZNSSD-type gradient-based subset DIC, Keys 4th-order interpolation)
  and ``subset_defs.txt`` (the region of interest as a polygon, DICe's ``begin region_of_interest`` block),
  ``cal.xml`` (DICe camera-system XML);
* ``vic3d``: ``images/dataset-0000_0.tif`` / ``_1.tif`` (VIC-3D's camera suffixes), ``calibration.cal``;
* ``matchid``: ``images/dataset_0000_0.tif`` / ``_1.tif``, ``calibration.caldat``;
* ``opencv``: ``left/left_0000.png``, ``right/right_0000.png`` and ``stereo.yaml`` (cv2.FileStorage: K1, D1, K2,
  D2, R, T).

Every layout also holds ``truth/``: ``truth_reference.npz`` (the per-pixel truth of the left reference image,
:func:`workbench.scoring.datasets.dense_truth`, float32, NaN off the specimen), ``points.csv`` (the truth of every point
of a grid over the region of interest, every state) and ``export.json`` (what was written, the calibration's
conversion cost, every note). Where a format cannot express the true cameras (the two-axis Scheimpflug tilt,
true-lens terms) the nearest model of the format is written and its projection cost over the image (px, mean
and max) is printed and logged — never silently. The whole folder is written under a temporary name and
renamed when complete.
"""
from __future__ import annotations

import csv
import io
import json
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_bytes, atomic_write_text, atomic_writer
from workbench.scoring.datasets import Dataset, dense_truth, poi_mask, point_truth, roi_polygons_px, true_rig

FORMATS = ("native", "dice", "vic3d", "matchid", "opencv")
#: The components of a symmetric strain tensor written to ``truth/points.csv`` (``Exx_left`` ...).
STRAIN_TENSOR_COMPONENTS = ("xx", "yy", "zz", "yz", "xz", "xy")
#: Calibration file name per format.
CALIBRATION_NAME = {"native": "calibration.json", "dice": "cal.xml", "vic3d": "calibration.cal",
                    "matchid": "calibration.caldat", "opencv": "stereo.yaml"}


@dataclass(frozen=True)
class ExportSettings:
    """What the exported analysis files ask of the tool and what truth comes with them.

    ``subset_px``/``step_px`` go into the tool's input files (DICe); ``grid_step_px`` is the spacing of the
    truth grid in ``points.csv``; ``truth_step_px`` that of the per-pixel truth array (1 = every pixel).
    """

    subset_px: int = 33
    step_px: int = 8
    grid_step_px: int = 8
    truth_step_px: int = 1


def image_names(fmt: str, dataset: Dataset) -> list[dict[str, str]]:
    """The file name (relative to the export folder) of every state's images in ``fmt``."""
    out = []
    for k, state in enumerate(dataset.images):
        ext = state["left"].suffix if fmt == "native" else (".png" if fmt == "opencv" else ".tif")
        names = {}
        for cam, side in enumerate(("left", "right")):
            if side not in state:
                continue
            if fmt == "native":
                names[side] = state[side].name
            elif fmt == "opencv":
                names[side] = f"{side}/{side}_{k:04d}{ext}"
            elif not dataset.stereo:
                names[side] = f"images/img_{k:04d}{ext}" if fmt == "dice" else f"images/dataset_{k:04d}{ext}"
            elif fmt == "dice":
                names[side] = f"images/img_{k:04d}_{cam}{ext}"
            elif fmt == "vic3d":
                names[side] = f"images/dataset-{k:04d}_{cam}{ext}"
            else:
                names[side] = f"images/dataset_{k:04d}_{cam}{ext}"
        out.append(names)
    return out


def _write_image(src: Path, dst: Path) -> None:
    """Copy an image, re-encoded as a TIFF of the same dtype when the target is .tif (values unchanged)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.suffix == src.suffix:
        atomic_write_bytes(dst, src.read_bytes())
        return
    from measurement.image_io import read_grey

    image = read_grey(src)
    if dst.suffix == ".tif":
        import tifffile

        buffer = io.BytesIO()
        tifffile.imwrite(buffer, np.ascontiguousarray(image))
        atomic_write_bytes(dst, buffer.getvalue())
    else:
        from labio.atomic import atomic_write_image
        atomic_write_image(dst, image)


def _inside(poly: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    import matplotlib.path

    return matplotlib.path.Path(poly).contains_points(np.column_stack([x, y]))


def truth_grid(dataset: Dataset, poly: np.ndarray, step_px: int):
    """The points of a ``step_px`` grid inside ``poly`` and their truth (:func:`point_truth`, with the surface strain
    for a stereo dataset)."""
    w, h = dataset.image_size_px
    X, Y = np.meshgrid(np.arange(0, w, step_px), np.arange(0, h, step_px))
    keep = _inside(poly, X.ravel(), Y.ravel())
    return point_truth(dataset, X.ravel()[keep], Y.ravel()[keep], strain=dataset.stereo)


def _points_csv(path: Path, dataset: Dataset, pt) -> None:
    stereo = pt.X_left_mm is not None
    header = ["state", "label", "x_px", "y_px", "valid", "u_px", "v_px"]
    if stereo:
        header += ["X_mm", "Y_mm", "Z_mm", "U_mm", "V_mm", "W_mm", "x_right_px", "y_right_px"]
    strain = pt.strain_left is not None
    if strain:                  # the exact surface strain tensor, left camera frame (workbench.scoring.datasets)
        header += [f"E{a}{b}_left" for a, b in STRAIN_TENSOR_COMPONENTS]
    fmt = lambda v: "nan" if not np.isfinite(v) else f"{v:.9g}"  # noqa: E731
    with atomic_writer(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        D = pt.displacement_left_mm
        for s in range(dataset.n_states):
            for i in range(pt.x_px.size):
                row = [s, dataset.labels[s], f"{pt.x_px[i]:g}", f"{pt.y_px[i]:g}", int(pt.valid[i]),
                       fmt(pt.uv_left_px[s, i, 0]), fmt(pt.uv_left_px[s, i, 1])]
                if stereo:
                    row += [fmt(v) for v in (*pt.X_left_mm[s, i], *D[s, i], *pt.xy_right_px[s, i])]
                if strain:
                    row += [fmt(pt.strain_left[s, i, "xyz".index(a), "xyz".index(b)])
                            for a, b in STRAIN_TENSOR_COMPONENTS]
                writer.writerow(row)


def _dice_polygon(poly: np.ndarray, indent: str) -> list[str]:
    return [f"{indent}begin polygon", f"{indent}  begin vertices", *(f"{indent}    {x:.0f} {y:.0f}" for x, y in poly),
            f"{indent}  end vertices", f"{indent}end polygon"]


def _dice_files(dataset: Dataset, names, poly: np.ndarray, settings: ExportSettings,
                holes: list | None = None) -> dict[str, str]:
    """DICe's input.xml, params.xml and subset_defs.txt (paths relative to the export folder)."""
    p = lambda name, typ, value: f'<Parameter name="{name}" type="{typ}" value="{value}" />'  # noqa: E731
    lines = ["<!-- written by workbench export (scheimpflug-dic-workbench) -->", "<ParameterList>",
             p("output_folder", "string", "results/"), p("correlation_parameters_file", "string", "params.xml"),
             p("subset_file", "string", "subset_defs.txt"), p("subset_size", "int", settings.subset_px),
             p("step_size", "int", settings.step_px), p("separate_output_file_for_each_subset", "bool", "false"),
             p("create_separate_run_info_file", "bool", "true"), p("image_folder", "string", ""),
             p("reference_image", "string", names[0]["left"]), '<ParameterList name="deformed_images">',
             *(p(n["left"], "bool", "true") for n in names[1:]), "</ParameterList>"]
    if dataset.stereo:
        lines += [p("camera_system_file", "string", CALIBRATION_NAME["dice"]),
                  p("stereo_reference_image", "string", names[0]["right"]),
                  '<ParameterList name="stereo_deformed_images">',
                  *(p(n["right"], "bool", "true") for n in names[1:]), "</ParameterList>"]
    lines.append("</ParameterList>")
    params = ["<!-- written by workbench export: subset DIC as close to this project's instrument as DICe allows -->",
              "<ParameterList>", p("interpolation_method", "string", "KEYS_FOURTH"),
              p("optimization_method", "string", "GRADIENT_BASED"),
              p("initialization_method", "string", "USE_FIELD_VALUES"),
              p("enable_translation", "bool", "true"), p("enable_rotation", "bool", "true"),
              p("enable_normal_strain", "bool", "true"), p("enable_shear_strain", "bool", "true"),
              p("output_delimiter", "string", ","), "</ParameterList>"]
    roi = ["# region of interest: where the left reference image sees the specimen (workbench export); excluded: its "
           "holes, grown by half a subset", "begin region_of_interest", "  begin boundary", *_dice_polygon(poly, "    "),
           "  end boundary"]
    if holes:
        roi += ["  begin excluded", *(line for h in holes for line in _dice_polygon(h, "    ")), "  end excluded"]
    roi.append("end region_of_interest")
    return {"input.xml": "\n".join(lines) + "\n", "params.xml": "\n".join(params) + "\n",
            "subset_defs.txt": "\n".join(roi) + "\n"}


def opencv_kd_cost_px(cam, n: int = 41) -> tuple[float, float]:
    """Mean and max distance (px) over an ``n x n`` grid of the image between ``cam`` and what a tool reading only
    K and D (``cv2.projectPoints``) makes of the K/D our OpenCV YAML holds for it."""
    import cv2

    from measurement.calibration.io import opencv_distortion

    u, v = np.meshgrid(np.linspace(0, cam.width - 1, n), np.linspace(0, cam.height - 1, n))
    rays = cam.rays(np.column_stack([u.ravel(), v.ravel()]))
    rays = rays / rays[:, 2:3]
    ours = cam.project(rays)
    theirs = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), cam.K, opencv_distortion(cam))[0].reshape(-1, 2)
    d = np.linalg.norm(ours - theirs, axis=1)
    return float(d.mean()), float(d.max())


_RUN = {"dice": "cd into this folder and run `dice -i input.xml` (results in `results/DICe_solution_*.txt`); then\n"
               "`workbench score {dataset} results/DICe_solution_*.txt --format dice --out score`",
        "native": "`workbench stereo --calib calibration.json ...` or `workbench dic ...`; then `workbench score {dataset} "
                  "RESULT.csv --out score`",
        "opencv": "run your tool on left/ and right/ with stereo.yaml; then `workbench score {dataset} RESULT_*.csv "
                  "--format csv --columns x=..,y=..,u=..,v=.. --out score`",
        "vic3d": "open the images and calibration.cal in VIC-3D; export its results as CSV and score them with "
                 "`workbench score {dataset} RESULT_*.csv --format csv --columns ... --out score`",
        "matchid": "load the images and calibration.caldat in MatchID; export its results as CSV and score them with "
                   "`workbench score {dataset} RESULT_*.csv --format csv --columns ... --out score`"}


def _readme(dataset: Dataset, fmt: str, record: dict) -> str:
    """What is in the export folder and how to run and score the tool on it."""
    lines = [f"# {dataset.folder.name} exported for {fmt}", "",
             f"{dataset.n_states} states ({', '.join(dataset.labels)}); state 0 is the reference. "
             f"Written by `workbench export` ({record['convention']}).", "",
             "Run: " + _RUN[fmt].format(dataset=dataset.folder), "",
             "Truth: `truth/truth_reference.npz` (per pixel of the left reference image: `valid`, `uv_left_px` "
             "(state, row, column, 2), and for stereo `X_left_mm`, `xy_right_px`; NaN off the specimen), "
             "`truth/points.csv` (a grid over the ROI, every state), `truth/roi_polygon_px.csv` (its outer "
             "boundary; `export.json` lists the holes excluded from it) and, for stereo, `truth/roi_mask_left.png` (the "
             "same region as a mask image, 255 inside: VIC-3D's or MatchID's ROI import, `workbench stereo --mask`).",
             ""]
    if record["calibration"]:
        lines.append(f"Calibration: `{record['calibration']['file']}`:")
        lines += [f"- {c['camera']}: {c['model']}, {c['mean_px']:.3g} px mean / {c['max_px']:.3g} px max from the "
                  "true camera over the image" for c in record["calibration"]["cameras"]]
    lines += [f"- note: {n}" for n in record["notes"]]
    return "\n".join(lines) + "\n"


def _save_calibration(fmt: str, rig, path: Path, frame_rotation: bool = False) -> list[dict]:
    """Write the rig in ``fmt``; returns per camera ``{"camera", "model", "mean_px", "max_px", "notes"}``.

    ``opencv``: our YAML holds every parameter as named scalars (exact for this project's loader) and K/D for
    OpenCV; the cost reported is what a tool reading only K and D loses.
    """
    from measurement.calibration.formats import save_calibration_as

    report = save_calibration_as(rig, path, "json" if fmt == "native" else fmt, frame_rotation=frame_rotation)
    out = [{"camera": c.side, "model": c.model, "mean_px": float(c.mean_px), "max_px": float(c.max_px),
            "notes": list(c.notes)} for c in report.cameras]
    if fmt == "opencv":
        for c in out:
            c["mean_px"], c["max_px"] = opencv_kd_cost_px(getattr(rig, c["camera"]))
            c["model"] = "OpenCV K, D (CALIB_TILTED_MODEL, tau = alpha, beta)"
            if c["max_px"] > 1e-6:
                c["notes"].append("a tool reading only K/D gets OpenCV's tilt order, not the paper's two-axis RMM tilt")
    return out + [{"camera": "file", "notes": list(report.notes)}] if report.notes else out


def export_dataset(dataset: Dataset, fmt: str, out: Path, settings: ExportSettings = ExportSettings(),
                   log=print, frame_rotation: bool = False) -> dict:
    """Write ``dataset`` in ``fmt`` into the new folder ``out``; returns the export log (also ``export.json``)."""
    if fmt not in FORMATS:
        raise ValueError(f"--format {fmt!r}: choose one of {', '.join(FORMATS)}")
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"{out}: the export folder exists and is not empty; choose a new folder")
    start = time.perf_counter()
    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        record = _export_into(dataset, fmt, tmp, settings, log, frame_rotation)
        record["seconds"] = round(time.perf_counter() - start, 2)
        atomic_write_text(tmp / "export.json", json.dumps(record, indent=1))
        if out.exists():
            out.rmdir()
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return record


def _export_into(dataset: Dataset, fmt: str, folder: Path, settings: ExportSettings, log,
                 frame_rotation: bool = False) -> dict:
    names = image_names(fmt, dataset)
    for state, name in zip(dataset.images, names):
        for side, rel in name.items():
            _write_image(state[side], folder / rel)
    log(f"{dataset.n_states} states{' x 2 cameras' if dataset.stereo else ''} of {dataset.folder.name} written "
        f"as {fmt}")
    record = {"format": fmt, "dataset": str(dataset.folder), "kind": dataset.kind, "states": list(dataset.labels),
              "images": names, "settings": settings.__dict__, "notes": [], "calibration": None,
              "convention": "pixels as OpenCV (x = column, y = row, pixel centres at integer coordinates); "
                            "3-D in the left camera frame (x right, y down, z forward), mm; displacement = "
                            "position in state s minus position in state 0"}
    if dataset.stereo:
        rig, notes = true_rig(dataset)
        record["notes"] += notes
        cams = _save_calibration(fmt, rig, folder / CALIBRATION_NAME[fmt], frame_rotation)
        file_notes = [n for c in cams if c["camera"] == "file" for n in c["notes"]]
        cams = [c for c in cams if c["camera"] != "file"]
        record["calibration"] = {"file": CALIBRATION_NAME[fmt], "cameras": cams, "frame_rotation": frame_rotation,
                                 "notes": file_notes}
        record["notes"] += file_notes
        for n in file_notes:
            log(f"  calibration: {n}")
        for c in cams:
            log(f"  {c['camera']} camera: written as {c['model']}; it projects within {c['mean_px']:.3g} px (mean), "
                f"{c['max_px']:.3g} px (max) of the true camera over the image")
            for n in c["notes"]:
                log(f"    - {n}")
            record["notes"] += [f"{c['camera']}: {n}" for n in c["notes"]]
        for n in notes:
            log(f"  note: {n}")
    dense = dense_truth(dataset, settings.truth_step_px, progress=log is print)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **dense, labels=np.array(dataset.labels))
    (folder / "truth").mkdir()
    atomic_write_bytes(folder / "truth" / "truth_reference.npz", buffer.getvalue())
    margin = settings.subset_px // 2 + 1
    holes = []
    if dataset.stereo:
        poly, holes = roi_polygons_px(dense["valid"], dense["x_px"], dense["y_px"], margin)
        # the same region as an image (255: a point of interest there has its subset on the specimen), for tools
        # that take a mask image (VIC-3D's and MatchID's ROI import, workbench stereo --mask)
        from labio.atomic import atomic_write_image

        mask = poi_mask(dense["valid"], dense["x_px"], dense["y_px"], dataset.image_size_px, margin)
        atomic_write_image(folder / "truth" / "roi_mask_left.png", np.where(mask, 255, 0).astype(np.uint8))
        record["roi_mask"] = {"file": "truth/roi_mask_left.png", "pixels": int(mask.sum()), "margin_px": margin}
    else:
        w, h = dataset.image_size_px
        poly = np.array([[margin, margin], [w - 1 - margin, margin], [w - 1 - margin, h - 1 - margin],
                         [margin, h - 1 - margin]], float)
    pt = truth_grid(dataset, poly, settings.grid_step_px)
    _points_csv(folder / "truth" / "points.csv", dataset, pt)
    atomic_write_text(folder / "truth" / "roi_polygon_px.csv",
                      "x_px,y_px\n" + "".join(f"{x:.0f},{y:.0f}\n" for x, y in poly))
    record["roi_polygon_px"] = poly.tolist()
    record["roi_excluded_polygons_px"] = [h.tolist() for h in holes]
    record["truth_points"] = int(pt.x_px.size)
    if fmt == "dice":
        for name, text in _dice_files(dataset, names, poly, settings, holes).items():
            atomic_write_text(folder / name, text)
    atomic_write_text(folder / "README.md", _readme(dataset, fmt, record))
    log(f"  truth: truth/truth_reference.npz (every {settings.truth_step_px} px), truth/points.csv "
        f"({pt.x_px.size} points x {dataset.n_states} states)")
    return record
