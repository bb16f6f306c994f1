"""Rendered datasets as other tools see them: images per state and camera, the true rig, and the truth at any point.

A dataset is a folder of the render store (:mod:`workbench.store`) or any folder a render command wrote
(``manifest.json`` names its kind): ``dic2d`` (a 2-D reference/deformed pair), ``rigid-motion`` and
``bending`` (stereo sequences: state 0 is the reference). :func:`open_dataset` also takes a scenario file
(TOML/JSON, :mod:`workbench.scenario`) and renders its dataset through the store first.

The truth of a point is defined, as everywhere in this project, at a pixel of the **left reference image**:
its chief ray meets the specimen at a material point; :func:`point_truth` gives that point's position in
every state (left camera frame, mm), where it appears in the left and right images of every state (px) and
so the 2-D displacement a tool tracking it in the left images must find. Pixel convention as OpenCV: x =
column, y = row, pixel centres at integer coordinates.
"""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from workbench.manifest import read_manifest

#: Dataset kinds another tool can be run on, and whether they are stereo.
KINDS = {"dic2d": False, "rigid-motion": True, "bending": True, "specimen": True}


class DatasetError(ValueError):
    """A folder that is not a usable dataset (the message names the folder and what is wrong)."""


@dataclass(frozen=True)
class Dataset:
    """A rendered dataset.

    Attributes
    ----------
    folder : Path
    kind : str, one of :data:`KINDS`
    images : tuple of dicts, one per state, ``{"left": Path[, "right": Path]}``; state 0 is the reference
    image_size_px : (width, height)
    labels : tuple of str, what each state is (``"reference"``, ``"stage 2 mm"``, ``"1800 N"``)
    """

    folder: Path
    kind: str
    images: tuple
    image_size_px: tuple
    labels: tuple

    @property
    def stereo(self) -> bool:
        return KINDS[self.kind]

    @property
    def n_states(self) -> int:
        return len(self.images)


@dataclass(frozen=True)
class PointTruth:
    """The truth of points defined at pixels of the left reference image.

    Attributes
    ----------
    x_px, y_px : (N,) float, the points in the left reference image
    valid : (N,) bool, the pixel sees the specimen (the truth of the others is NaN)
    uv_left_px : (S, N, 2) float, px, where the material point is in the left image of state s minus where it is
        in the reference image (what 2-D DIC on the left images measures); zero for state 0
    X_left_mm : (S, N, 3) float or None, mm, its position in state s, left camera frame (stereo only)
    xy_right_px : (S, N, 2) float or None, px, where it appears in the right image of state s (stereo only)
    strain_left : (S, N, 3, 3) float or None, the exact surface Green-Lagrange strain of state s relative to state 0
        at the material point (dimensionless, tensor shear), as a tensor of the left camera frame tangent to the
        reference surface (``E = Q E_2 Q^T`` for the 2 x 2 strain ``E_2`` in an orthonormal tangent basis ``Q``);
        its component along unit tangents ``a, b`` is ``a @ E @ b`` (:func:`strain_components`). Stereo datasets,
        with ``point_truth(..., strain=True)``; zero in a rigid-motion dataset.
    """

    x_px: np.ndarray
    y_px: np.ndarray
    valid: np.ndarray
    uv_left_px: np.ndarray
    X_left_mm: np.ndarray | None = None
    xy_right_px: np.ndarray | None = None
    strain_left: np.ndarray | None = None

    @property
    def displacement_left_mm(self) -> np.ndarray | None:
        """(S, N, 3) displacement from the reference state, left camera frame, mm (stereo only)."""
        return None if self.X_left_mm is None else self.X_left_mm - self.X_left_mm[0]


def _image_size(path: Path) -> tuple[int, int]:
    from measurement.image_io import read_grey

    image = read_grey(path)
    return int(image.shape[1]), int(image.shape[0])


def open_dataset(source: str | Path, store=None) -> Dataset:
    """The dataset in folder ``source``, or the one the scenario file ``source`` renders (through the store).

    Raises :class:`DatasetError` naming the folder when it is not a complete dataset of a known kind.
    """
    source = Path(source)
    if source.is_file() and source.suffix.lower() in (".toml", ".json") and source.name != "manifest.json":
        return open_dataset(render_scenario_dataset(source, store))
    if not source.is_dir():
        raise DatasetError(f"{source}: no such dataset folder or scenario file")
    manifest = read_manifest(source)
    if manifest is None or manifest.get("complete") is not True:
        raise DatasetError(f"{source}: not a complete dataset (no complete manifest.json); render it first")
    kind = manifest["kind"]
    if kind not in KINDS:
        raise DatasetError(f"{source}: a {kind!r} dataset; another tool can be run on {', '.join(KINDS)}")
    truth = json.loads((source / "truth.json").read_text())
    if kind == "dic2d":
        files = truth["files"]
        images = ({"left": source / files["reference"]}, {"left": source / files["deformed"]})
        labels = ("reference", "shift {:g}, {:g} px".format(*truth["shift_xy_px"]))
    else:
        images = tuple({side: source / s["files"][side] for side in ("left", "right")} for s in truth["states"])
        if kind == "rigid-motion":
            labels = tuple(f"stage {s['stage_mm']:g} mm" for s in truth["states"])
        elif kind == "specimen":
            labels = tuple(str(s["label"]) for s in truth["states"])
        else:
            labels = tuple(f"{s['load_N']:g} N" for s in truth["states"])
    missing = [str(p) for state in images for p in state.values() if not p.is_file()]
    if missing:
        raise DatasetError(f"{source}: images missing: {', '.join(missing[:3])}")
    return Dataset(source, kind, images, _image_size(images[0]["left"]), labels)


def image_sha256(dataset: Dataset) -> list[dict[str, str]]:
    """:func:`workbench.results.pixels_sha256` of every state's images, ``[{"left": hash[, "right": hash]}, ...]``."""
    return [{side: _pixels_sha256_of_file(path) for side, path in state.items()} for state in dataset.images]


@functools.lru_cache(maxsize=512)
def _pixels_sha256_cached(path: str, mtime_ns: int, size: int) -> str:
    from measurement.image_io import read_grey
    from workbench.results import pixels_sha256

    return pixels_sha256(read_grey(path))


def _pixels_sha256_of_file(path: Path) -> str:
    stat = Path(path).stat()
    return _pixels_sha256_cached(str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size)


def state_of_images(dataset: Dataset, measured) -> int:
    """The dataset state whose images a result measured (:class:`workbench.results.MeasuredImages`), by content.

    The images are compared by their grey levels (:func:`workbench.results.pixels_sha256`), not by name or place:
    an exported copy (PNG or re-encoded TIFF) is the same image.

    Raises
    ------
    DatasetError
        The result's reference pair is not the dataset's reference, or its state pair is no state's pair of the
        dataset (the message names the result's images and the dataset's).
    """
    hashes = image_sha256(dataset)
    sides = tuple(hashes[0])

    def pair(names: dict) -> str:
        return " + ".join(Path(str(names[s])).name for s in sides)

    ours = [pair({s: dataset.images[k][s] for s in sides}) for k in range(dataset.n_states)]
    shown = ", ".join(f"state {k}: {n}" for k, n in enumerate(ours[:4])) + (" ..." if len(ours) > 4 else "")
    if any(measured.reference_sha256.get(s) != hashes[0][s] for s in sides):
        raise DatasetError(f"{measured.record}: the result's reference images ({pair(measured.reference)}) are not the "
                           f"reference of dataset {dataset.folder} ({ours[0]}): it was measured on other images")
    for k, state in enumerate(hashes):
        if all(measured.state_sha256.get(s) == state[s] for s in sides):
            return k
    raise DatasetError(f"{measured.record}: the result measured {pair(measured.state)}, which are the images of no "
                       f"state of dataset {dataset.folder} ({shown})")


def render_scenario_dataset(path: Path, store=None) -> Path:
    """Render (or find in the store) the images a scenario file describes; returns the dataset folder."""
    from workbench.studies.cases import experiment_module
    from workbench.config import load_config, read_mapping
    from workbench.scenario import Scenario, dataset_parts, with_specimen_paths
    from workbench.store import DatasetStore

    # a scenario file, or a study-style file whose [scenario] table is the scenario
    scenario = load_config(Scenario, path, "scenario" if "scenario" in read_mapping(path) else None)
    scenario = with_specimen_paths(scenario, Path(path).resolve().parent)
    store = store if isinstance(store, DatasetStore) else DatasetStore(store)
    module = experiment_module(scenario.experiment)
    module.check(scenario)
    parts = dataset_parts(scenario)
    if scenario.experiment == "dic2d":
        key, content = parts["images"]
        folder, _ = store.ensure("dic2d", key, content, lambda f: module.render_dataset(scenario, f))
    elif scenario.experiment == "specimen":
        key, content = parts["states"]
        folder, _ = store.ensure("specimen", key, content, lambda f: module.render_states(scenario, f))
    else:
        key, content = parts["states"]
        folder, _ = store.ensure("rigid-motion", key, content, lambda f: module.render_states(scenario, f))
    return folder


def _stereo_truth(dataset: Dataset):
    if dataset.kind == "specimen":
        from workbench.experiments.specimen.scenes import load_specimen_truth
        return load_specimen_truth(dataset.folder)
    if dataset.kind == "rigid-motion":
        from workbench.experiments.rigid_motion.scenes import load_truth
        return load_truth(dataset.folder)
    from workbench.experiments.bending.scenes import load_bending_truth
    return load_bending_truth(dataset.folder)


def strain_components(strain_left: np.ndarray, e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    """Components E11, E22, E12 (..., 3) of strain tensors (..., 3, 3) along the unit tangents ``e1``, ``e2`` (..., 3)."""
    E11 = np.einsum("...i,...ij,...j->...", e1, strain_left, e1)
    E22 = np.einsum("...i,...ij,...j->...", e2, strain_left, e2)
    E12 = np.einsum("...i,...ij,...j->...", e1, strain_left, e2)
    return np.stack([E11, E22, E12], axis=-1)


def _strain_truth(dataset: Dataset, t, pixels: np.ndarray, X_specimen: np.ndarray | None, valid: np.ndarray,
                  n_states: int) -> np.ndarray:
    """(S, N, 3, 3) exact surface strain of every state at the points (:class:`PointTruth`), NaN where not valid."""
    out = np.full((n_states, len(pixels), 3, 3), np.nan)
    if dataset.kind == "rigid-motion":
        out[:, valid] = 0.0                 # a rigid motion strains nothing
        return out
    if dataset.kind == "specimen":          # every state at once: the pixels' material points found once
        E, Q = t.strain_truths(pixels)
        out[:] = np.einsum("nia,snab,njb->snij", Q, E, Q)
    else:
        for k in range(n_states):           # bending: at the face's material points
            E, Q, _ = t.strain_truth(X_specimen, k)
            out[k] = np.einsum("nia,nab,njb->nij", Q, E, Q)
    out[:, ~valid] = np.nan
    return out


def point_truth(dataset: Dataset, x_px, y_px, *, strain: bool = False) -> PointTruth:
    """The truth of the points ``(x_px, y_px)`` of the left reference image in every state of ``dataset``
    (``strain=True``: also the exact surface strain, stereo datasets only)."""
    x = np.asarray(x_px, float).ravel()
    y = np.asarray(y_px, float).ravel()
    if x.shape != y.shape:
        raise ValueError(f"x_px and y_px must have the same length, got {x.size} and {y.size}")
    w, h = dataset.image_size_px
    inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5)
    if strain and not dataset.stereo:
        raise ValueError(f"{dataset.folder}: a 2-D dataset has no surface strain truth (its 2-D strain: "
                         "workbench.scoring.metrics.truth_strain_2d)")
    if dataset.kind == "dic2d":
        truth = json.loads((dataset.folder / "truth.json").read_text())
        uv = np.zeros((2, x.size, 2))
        uv[1] = truth["shift_xy_px"]
        uv[:, ~inside] = np.nan
        return PointTruth(x, y, inside, uv)
    t = _stereo_truth(dataset)
    pixels = np.column_stack([x, y])
    X_specimen, X_world = t.points_of_interest(pixels)          # world = left camera frame
    valid = inside & np.all(np.isfinite(X_world[0]), axis=1)
    X_world[:, ~valid] = np.nan
    S, N = X_world.shape[:2]
    left = t.project("left", X_world.reshape(-1, 3)).reshape(S, N, 2)
    right = t.project("right", X_world.reshape(-1, 3)).reshape(S, N, 2)
    E = _strain_truth(dataset, t, pixels, X_specimen, valid, S) if strain else None
    return PointTruth(x, y, valid, left - left[0], X_world, right, E)


def true_rig(dataset: Dataset):
    """The cameras the dataset was rendered with, as the instrument's :class:`CalibratedRig` (left = world).

    Returns ``(rig, notes)``: ``notes`` lists what the instrument's camera model cannot hold (true-lens terms
    k3, s1..s4 or a thin lens' defocus are not calibration parameters).
    """
    from measurement.calibration.io import CalibratedRig
    from measurement.camera import INTRINSIC_NAMES, ScheimpflugCamera

    if not dataset.stereo:
        raise DatasetError(f"{dataset.folder}: a 2-D dataset has no stereo calibration")
    t = _stereo_truth(dataset)
    notes = []
    cams = {}
    for side in ("left", "right"):
        spec = t.specs[side]
        cams[side] = ScheimpflugCamera(**{n: float(getattr(spec, n)) for n in INTRINSIC_NAMES},
                                       width=int(spec.width), height=int(spec.height))
        extra = {n: getattr(spec, n, 0.0) for n in ("k3", "s1", "s2", "s3", "s4")}
        if any(extra.values()):
            notes.append(f"{side}: true-lens terms {', '.join(f'{k}={v:g}' for k, v in extra.items() if v)} are not in "
                         "the calibration (an error source of the scenario)")
        if getattr(spec, "lens", "pinhole") == "thin":
            notes.append(f"{side}: rendered through a thin lens (defocus); the calibration is its chief-ray camera")
    R_l, t_l = t.camera_poses["left"]
    if not (np.allclose(R_l, np.eye(3)) and np.allclose(t_l, 0.0)):
        raise DatasetError(f"{dataset.folder}: the world frame is not the left camera frame")
    R, T = t.camera_poses["right"]
    return CalibratedRig("rmm", cams["left"], cams["right"], np.asarray(R, float), np.asarray(T, float)), notes


def dense_truth(dataset: Dataset, step_px: int = 1, *, progress: bool = False) -> dict:
    """Per-pixel truth of the left reference image on every ``step_px``-th pixel, as float32 arrays.

    Returns ``{"x_px": (W',), "y_px": (H',), "valid": (H', W') bool, "uv_left_px": (S, H', W', 2)`` and for
    stereo ``"X_left_mm": (S, H', W', 3), "xy_right_px": (S, H', W', 2)}``.
    """
    if int(step_px) != step_px or step_px < 1:
        raise ValueError(f"the truth step must be a positive integer number of pixels, got {step_px!r}")
    w, h = dataset.image_size_px
    xs, ys = np.arange(0, w, step_px), np.arange(0, h, step_px)
    S = dataset.n_states
    out = {"x_px": xs.astype(np.int32), "y_px": ys.astype(np.int32), "valid": np.zeros((ys.size, xs.size), bool),
           "uv_left_px": np.full((S, ys.size, xs.size, 2), np.nan, np.float32)}
    if dataset.stereo:
        out["X_left_mm"] = np.full((S, ys.size, xs.size, 3), np.nan, np.float32)
        out["xy_right_px"] = np.full((S, ys.size, xs.size, 2), np.nan, np.float32)
    rows = max(1, 100_000 // xs.size)                   # blocks of rows: float64 work arrays stay ~100 MB
    from tqdm import tqdm

    for r0 in tqdm(range(0, ys.size, rows), desc=f"truth of every {step_px} px", unit="block", disable=not progress):
        r1 = min(ys.size, r0 + rows)
        X, Y = np.meshgrid(xs, ys[r0:r1])
        pt = point_truth(dataset, X.ravel(), Y.ravel())
        shape = X.shape
        out["valid"][r0:r1] = pt.valid.reshape(shape)
        out["uv_left_px"][:, r0:r1] = pt.uv_left_px.reshape((S,) + shape + (2,))
        if dataset.stereo:
            out["X_left_mm"][:, r0:r1] = pt.X_left_mm.reshape((S,) + shape + (3,))
            out["xy_right_px"][:, r0:r1] = pt.xy_right_px.reshape((S,) + shape + (2,))
    return out


#: The keys of the two dense truth files (:func:`read_dense_truth`).
EXPORT_TRUTH_KEYS = ("x_px", "y_px", "valid", "uv_left_px")
SPECIMEN_TRUTH_KEYS = ("x_px", "y_px", "displacement_world_mm", "xy_left_px", "xy_right_px", "strain_E11_E22_E12",
                       "strain_basis_world")


def read_dense_truth(path) -> dict:
    """Read a dense truth file into arrays with documented keys (the formats page describes both files).

    * ``truth/truth_reference.npz`` of ``workbench export`` (:func:`dense_truth` on every ``truth_step_px``-th
      pixel of the left reference image): ``x_px`` (W',), ``y_px`` (H',), ``valid`` (H', W'), ``uv_left_px``
      (S, H', W', 2) and for stereo ``X_left_mm`` (S, H', W', 3), ``xy_right_px`` (S, H', W', 2), ``labels`` (S,);
    * ``truth_states.npz`` of a specimen dataset (``workbench render specimen``): ``x_px``, ``y_px``,
      ``displacement_left_mm`` (S, H', W', 3: the world frame is the left camera's), ``xy_left_px``,
      ``xy_right_px`` (S, H', W', 2: where the material point is in each image of each state), ``strain_left``
      (S, H', W', 3, 3: the exact surface Green-Lagrange strain tensor, left camera frame, from the file's
      ``strain_E11_E22_E12`` in its ``strain_basis_world``), ``valid`` (H', W': the pixel sees the specimen).

    Every array is float32 (float64 for ``strain_left``), NaN where the pixel does not see the specimen.
    ``kind`` says which file it was: ``"export"`` or ``"specimen"``.

    Raises
    ------
    DatasetError
        A file that is neither, naming its keys and the keys each kind has.
    """
    path = Path(path)
    with np.load(path, allow_pickle=False) as z:
        keys = set(z.files)
        if all(k in keys for k in EXPORT_TRUTH_KEYS):
            out = {k: z[k] for k in z.files}
            out["kind"] = "export"
            return out
        if all(k in keys for k in SPECIMEN_TRUTH_KEYS):
            E = z["strain_E11_E22_E12"].astype(float)
            Q = z["strain_basis_world"].astype(float)
            E2 = np.stack([np.stack([E[..., 0], E[..., 2]], -1), np.stack([E[..., 2], E[..., 1]], -1)], -2)
            strain = np.einsum("hwia,shwab,hwjb->shwij", Q, E2, Q)
            D = z["displacement_world_mm"]
            return {"kind": "specimen", "x_px": z["x_px"], "y_px": z["y_px"], "displacement_left_mm": D,
                    "xy_left_px": z["xy_left_px"], "xy_right_px": z["xy_right_px"], "strain_left": strain,
                    "valid": np.all(np.isfinite(D[0]), axis=-1)}
    raise DatasetError(f"{path}: not a dense truth file (keys {', '.join(sorted(keys))}); an export's "
                       f"truth_reference.npz has {', '.join(EXPORT_TRUTH_KEYS)}, ..., a specimen dataset's "
                       f"truth_states.npz {', '.join(SPECIMEN_TRUTH_KEYS)}")


def _eroded(valid: np.ndarray, step: int, margin_px: int) -> np.ndarray:
    import cv2

    r = max(1, int(np.ceil(margin_px / step)))
    return cv2.erode(valid.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8), borderValue=0)


def roi_polygons_px(valid: np.ndarray, x_px: np.ndarray, y_px: np.ndarray,
                    margin_px: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """The region of interest where the truth is valid, shrunk by ``margin_px``: its outer polygon (M, 2) px and the
    polygons of the holes inside it (a plate's hole, grown by the margin), each (K, 2) px.

    ``valid`` is the (H', W') mask of :func:`workbench.scoring.datasets.dense_truth` on the pixels ``x_px`` x ``y_px``.
    The largest connected region is kept, eroded so that subsets centred inside it (and outside its holes) see only
    the specimen.
    """
    import cv2

    step = int(x_px[1] - x_px[0]) if len(x_px) > 1 else 1
    mask = _eroded(valid, step, margin_px)
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    outer = [i for i in range(len(contours)) if hierarchy[0][i][3] < 0]
    if not outer:
        raise ValueError(f"no region of the reference image sees the specimen {margin_px} px from its edge")
    best = max(outer, key=lambda i: cv2.contourArea(contours[i]))

    def polygon(contour):
        poly = cv2.approxPolyDP(contour, 1.0, True).reshape(-1, 2).astype(float)
        return np.column_stack([x_px[0] + poly[:, 0] * step, y_px[0] + poly[:, 1] * step])

    holes = [polygon(contours[i]) for i in range(len(contours)) if hierarchy[0][i][3] == best
             and cv2.contourArea(contours[i]) > 0]
    return polygon(contours[best]), holes


def roi_polygon_px(valid: np.ndarray, x_px: np.ndarray, y_px: np.ndarray, margin_px: int) -> np.ndarray:
    """The outer polygon (M, 2) px of :func:`roi_polygons_px` (the region's holes are not in it)."""
    return roi_polygons_px(valid, x_px, y_px, margin_px)[0]


def poi_mask(valid: np.ndarray, x_px: np.ndarray, y_px: np.ndarray, image_size_px: tuple[int, int],
             margin_px: int) -> np.ndarray:
    """(H, W) bool over the left reference image: the pixels whose ``margin_px`` neighbourhood sees only the specimen
    (a point of interest there has a subset of up to ``2 margin_px - 1`` px on the specimen): the mask a DIC tool is
    given (a VIC-3D or MatchID mask image, ``workbench stereo --mask``). ``valid`` on the pixels ``x_px`` x ``y_px``
    (:func:`dense_truth`) is taken to every pixel by its nearest sample."""
    w, h = image_size_px
    step = int(x_px[1] - x_px[0]) if len(x_px) > 1 else 1
    inside = _eroded(valid, step, margin_px).astype(bool)
    rows = np.clip(np.rint((np.arange(h) - y_px[0]) / step).astype(int), 0, inside.shape[0] - 1)
    cols = np.clip(np.rint((np.arange(w) - x_px[0]) / step).astype(int), 0, inside.shape[1] - 1)
    return inside[np.ix_(rows, cols)]


def subset_roi_xyxy_px(dataset: Dataset, subset_px: int) -> tuple[int, int, int, int]:
    """Inclusive bounds (x0, y0, x1, y1) of subset centres whose subsets of ``subset_px`` see the specimen (and,
    with the deformed subset's interpolation stencil, stay inside the image): the ROI an engine is given."""
    w, h = dataset.image_size_px
    margin = subset_px // 2 + 8
    if not dataset.stereo:
        return margin, margin, w - 1 - margin, h - 1 - margin
    dense = dense_truth(dataset, 4)
    poly = roi_polygon_px(dense["valid"], dense["x_px"], dense["y_px"], margin + 4)
    x0, y0 = np.ceil(poly.min(0)).astype(int)
    x1, y1 = np.floor(poly.max(0)).astype(int)
    return int(x0), int(y0), int(x1), int(y1)
