"""Real images: MultiDIC's sample data (a speckled cylinder, radius 57.0 mm, cameras 201 and 202) measured with our
instrument.

Data: ``scripts/fetch_multidic.sh`` (default folder ``data/multidic``; MultiDIC, https://github.com/MultiDIC/MultiDIC,
Apache License 2.0). Nothing here is MultiDIC's code; only its images and its 2-D/3-D calibration-object coordinates.

Steps (each prints its progress and time):

1. Intrinsics of each camera from its own 25 checkerboard images (not simultaneous pairs): corners by
   :func:`measurement.calibration.detection.detect_checkerboard`, which searches a copy shrunk to
   ``--detect-max-side`` px (8 MP at full size takes ~8 s an image) and refines the corners at full size (saddle
   points); cached in
   ``corners_<cam>.npz`` in the output folder. Then :func:`measurement.calibration.stepwise.calibrate_camera` (model
   ``pinhole``, lens ``brown5`` by default: MultiDIC's STEP0 default is 3 radial + 2 tangential terms + skew).
   Our corners are compared with MultiDIC's own (``cameraCBparameters_cam_<cam>.mat``: ``imagePoints``, MATLAB
   1-based, so 0-based = MATLAB - 1), and our intrinsics with those MultiDIC prints in
   ``figures/params_cam<cam>.fig`` (the only readable copy: the ``cameraParameters`` in the .mat are opaque MATLAB
   objects; the figure saved by STEP0 is the one "after distortion correction", i.e. a re-calibration on
   undistorted images, whose f and c equal the original's to within their uncertainty).
2. Extrinsics of each camera from the cylindrical calibration object: MultiDIC's target centroids
   (``DLTstruct_cam_<cam>.mat``: ``imageCentroids``, found by STEP1 on the image enlarged 3x by ``imresize`` and
   divided by 3, 1-based: a pixel-centre 0-based coordinate is ``C - 2/3``, see :data:`CENTROID_OFFSET_PX`) against
   the targets' true 3-D coordinates (``C3Dtrue(:, columns, :)``, MATLAB column-major order), by ``cv2.solvePnP``
   refined with our own projection model; the stereo pose right-from-left follows. The centroid convention is
   checked against centroids we measure on the image (binary blob centroids, as MultiDIC's ``regionprops``).
   Written as ``calibration.json`` (our format, :func:`measurement.calibration.io.save_rig`) and its OpenCV YAML.
3. Stereo DIC of the reference pair (201_1 / 202_1) with :func:`measurement.stereo_dic.reference_shape` and
   MultiDIC's ROI mask (``ROIMask_C_201_C_202.mat``, left image = camera 201) as POI mask. Counted: points whose
   left->right match converged, of those how many are triangulated, the reasons of the others.
4. A cylinder (axis direction, axis point, radius) fitted by nonlinear least squares to the triangulated points;
   radius, RMS of the radial residuals and the relative radius error against 57.0 mm (the nominal radius; it is also
   the radius of the targets in MultiDIC's ``calibrationObjectCoordinates.mat``, so the speckled sleeve is taken to
   be on the same 57.0 mm cylinder: its thickness is not accounted for).
5. (default, ``--no-checks`` skips it) sensitivity: the same 2-D matches re-triangulated with the other lens model,
   the plain 1-based reading of the centroids (C - 1) and our own blob centroids.
6. (``--states``) the deformed states 2-5 through :func:`measurement.stereo_dic.measure_state`: counts, radius.
7. (``--cli``) the reference and states through ``workbench stereo --mask`` (the ROI mask as a PNG), in a
   temporary folder.

    scripts/fetch_multidic.sh --mirror /work/.mirror/MultiDIC+MultiDIC/repo      # or without --mirror: download
    .venv/bin/python benchmarks/real_multidic.py --data data/multidic --out reports/real_multidic --states --cli
"""
from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from measurement.calibration.detection import DETECT_MAX_SIDE_PX  # noqa: E402  (after the path set-up)

CAMERAS = ("201", "202")               # left, right (MultiDIC's pair C_201_C_202)
PATTERN = (19, 14)                     # inner corners (columns, rows): MultiDIC's boardSize [15 20] squares
SQUARE_MM = 10.0                       # MultiDIC's squareSize
RADIUS_MM = 57.0                       # the speckled cylinder's nominal radius
#: MultiDIC's STEP1 finds the calibration-object centroids on ``imresize(IM, 3)`` (1-based) and divides by 3: HR
#: pixel h (1-based) lies at original 1-based (h + 1) / 3, so C/3 is 1/3 px short of the 1-based coordinate; 0-based
#: = 1-based - 1 gives C - 2/3. (Checked against our own blob centroids in :func:`centroid_check`.)
CENTROID_OFFSET_PX = -2.0 / 3.0
MATLAB_OFFSET_PX = -1.0                # MATLAB 1-based pixel centres -> ours (0-based)
GOAL_TRIANGULATED = 0.98
GOAL_RADIUS_REL = 0.005


def log(msg: str) -> None:
    print(msg, flush=True)


def loadmat(path: Path):
    from scipy.io import loadmat as _loadmat

    return _loadmat(path, squeeze_me=True, struct_as_record=False)


def source_line(data: Path) -> str:
    """The data folder's SOURCE.txt 'Source:' line (written by scripts/fetch_multidic.sh), or the folder."""
    src = data / "SOURCE.txt"
    if src.is_file():
        for line in src.read_text().splitlines():
            if line.startswith("Source:"):
                return line.split(":", 1)[1].strip()
    return f"folder {data}"


# --------------------------------------------------------------------------------------------------------
# Step 1: intrinsics
# --------------------------------------------------------------------------------------------------------
def _save_npz(path: Path, **arrays) -> None:
    """np.savez through the atomic writer: an interrupted run leaves no truncated cache behind."""
    from labio.atomic import atomic_write_bytes

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def detect_corners(path: Path, max_side_px: int) -> np.ndarray | None:
    """Ordered inner corners of one checkerboard image, (N, 2) px (0-based pixel centres), or ``None``: the
    instrument's own :func:`~measurement.calibration.detection.detect_checkerboard`, which searches a copy shrunk to
    ``max_side_px`` and refines the corners at full size (saddle points)."""
    from measurement.calibration.detection import detect_checkerboard
    from measurement.image_io import read_grey

    return detect_checkerboard(read_grey(path), PATTERN, max_side_px=max_side_px)


def corners_for_camera(data: Path, out: Path, cam: str, max_side_px: int):
    """Corners of every checkerboard image of ``cam``: (names, (V, N, 2) px, image size), cached in the out folder."""
    cache = out / f"corners_{cam}.npz"
    files = sorted((data / "BAcheckerboardImages" / cam).glob("*.jpg"))
    if not files:
        raise SystemExit(f"{data}: no BAcheckerboardImages/{cam}/*.jpg (run scripts/fetch_multidic.sh)")
    names = [f.name for f in files]
    if cache.is_file():
        z = np.load(cache, allow_pickle=False)
        if list(z["names"]) == names and "max_side_px" in z and int(z["max_side_px"]) == max_side_px:
            log(f"  camera {cam}: corners from cache {cache.name} ({int(z['found'].sum())}/{len(names)} boards)")
            return [n for n, f in zip(names, z["found"]) if f], z["points"], tuple(int(s) for s in z["size"])
    pts, found = [], []
    size = None
    for f in files:
        t = time.time()
        c = detect_corners(f, max_side_px)
        if size is None:
            h, w = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE).shape
            size = (w, h)
        found.append(c is not None)
        if c is not None:
            pts.append(c)
        log(f"  camera {cam}: {f.name} {'found' if c is not None else 'NOT found'} ({time.time() - t:.1f} s)")
    points = np.array(pts)
    _save_npz(cache, names=np.array(names), found=np.array(found), points=points, size=np.array(size),
              max_side_px=max_side_px)
    return [n for n, f in zip(names, found) if f], points, size


def multidic_corner_check(data: Path, cam: str, names: list[str], points: np.ndarray) -> str:
    """Our corners vs MultiDIC's ``imagePoints`` (MATLAB detectCheckerboardPoints, 1-based), nearest-neighbour
    matched per image (the two orders differ)."""
    from scipy.spatial import cKDTree

    path = data / "BAcheckerboardImages" / f"cameraCBparameters_cam_{cam}.mat"
    if not path.is_file():
        return "no MultiDIC corners to compare"
    s = loadmat(path)["cameraCBparameters"]
    theirs = np.asarray(s.imagePoints, float)                      # (N, 2, V)
    files = [Path(str(p).replace("\\", "/")).name for p in np.atleast_1d(s.imagesInfo.imageFileNames)]
    used = np.atleast_1d(s.imagesUsed).astype(int)
    diffs = []
    for k, idx in enumerate(used):
        name = files[idx - 1] if idx <= len(files) else None
        if name not in names:
            continue
        ours = points[names.index(name)]
        th = theirs[:, :, k] + MATLAB_OFFSET_PX
        d, j = cKDTree(th).query(ours)
        if np.all(d < 3):
            diffs.append(ours - th[j])
    n_used = used.size
    if not diffs:
        return "no common images with MultiDIC's corners"
    d = np.concatenate(diffs)
    return (f"MultiDIC kept {n_used} of its images; ours - MultiDIC (MATLAB - 1) over the {len(diffs)} common "
            f"images, {d.shape[0]} corners: mean "
            f"({d[:, 0].mean():+.3f}, {d[:, 1].mean():+.3f}) px, RMS {np.sqrt((d ** 2).sum(1).mean()):.3f} px")


def multidic_intrinsics(data: Path, cam: str) -> dict | None:
    """f, c (0-based), k, p, skew and mean error as printed in MultiDIC's ``figures/params_cam<cam>.fig``
    (the "after distortion correction" figure: a re-calibration on the undistorted images), or ``None``."""
    import re

    path = data / "BAcheckerboardImages" / "figures" / f"params_cam{cam}.fig"
    if not path.is_file():
        return None
    m = loadmat(path)
    texts = []

    def walk(o, depth=0):
        if depth > 60:
            return
        if isinstance(o, str):
            texts.append(o)
        elif isinstance(o, np.ndarray) and o.dtype == object:
            for e in o.ravel():
                walk(e, depth + 1)
        elif hasattr(o, "_fieldnames"):
            for f in o._fieldnames:
                walk(getattr(o, f), depth + 1)

    for k, v in m.items():
        if not k.startswith("__"):
            walk(v)
    num = r"([-+]?\d+\.?\d*(?:e[-+]?\d+)?)"
    pairs = [t for t in texts if re.match(r"\\rm\[", t)]
    vals = [[float(x) for x in re.findall(num + r" \\pm", t)] for t in pairs]
    out = {"title": next((t for t in texts if t.startswith("Camera ")), "")}
    for v in vals:
        if len(v) == 2 and "fx" not in out and v[0] > 100:
            out["fx"], out["fy"] = v
        elif len(v) == 2 and "cx" not in out and v[0] > 100:
            out["cx"], out["cy"] = v[0] + MATLAB_OFFSET_PX, v[1] + MATLAB_OFFSET_PX
        elif len(v) == 3:
            out["k1"], out["k2"], out["k3"] = v
        elif len(v) == 2 and "p1" not in out:
            out["p1"], out["p2"] = v
    err = [t for t in texts if t.startswith("Overall Mean Error")]
    if err:
        out["mean_error_px"] = float(re.findall(num, err[0])[0])
    return out


def intrinsics(data: Path, out: Path, max_side_px: int, lens: str):
    """Step 1 for both cameras: {cam: CameraCalibration}, report lines."""
    from measurement.calibration.detection import board_points_mm
    from measurement.calibration.stepwise import calibrate_camera

    board = board_points_mm(PATTERN, SQUARE_MM)
    cals, lines = {}, []
    for cam in CAMERAS:
        t = time.time()
        names, pts, size = corners_for_camera(data, out, cam, max_side_px)
        t_det = time.time() - t
        t = time.time()
        cal = calibrate_camera(pts, board, size, model="pinhole", lens=lens, name=f"camera {cam}")
        t_cal = time.time() - t
        c = cal.camera
        sg = cal.sigma
        start = len(lines)
        lines.append(f"camera {cam}: {len(names)}/25 boards ({PATTERN[0]} x {PATTERN[1]} inner corners, "
                     f"{SQUARE_MM:g} mm), "
                     f"image {size[0]} x {size[1]} px; detection {t_det:.0f} s, calibration {t_cal:.1f} s")
        lines.append(f"  ours ({lens}): fx {c.fx:.2f} +- {sg['fx']:.2f}, fy {c.fy:.2f} +- {sg['fy']:.2f}, "
                     f"cx {c.cx:.2f} +- {sg['cx']:.2f}, cy {c.cy:.2f} +- {sg['cy']:.2f} px; "
                     f"k1 {c.k1:+.5f} k2 {c.k2:+.5f} "
                     f"k3 {c.k3:+.5f} p1 {c.p1:+.6f} p2 {c.p2:+.6f}; reprojection RMS {cal.rms_px:.3f} px "
                     f"(per view max {np.max(cal.per_view_rms_px):.3f})")
        md = multidic_intrinsics(data, cam)
        if md:
            md = {k: md.get(k, np.nan) for k in ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "p1", "p2",
                                                 "mean_error_px")} | {"title": md.get("title", "")}
            lines.append(f"  MultiDIC (params_cam{cam}.fig, '{md.get('title', '')}', c converted to 0-based): "
                         f"fx {md['fx']:.1f}, fy {md['fy']:.1f}, cx {md['cx']:.1f}, cy {md['cy']:.1f} px; "
                         f"k1 {md['k1']:+.5f} k2 {md['k2']:+.5f} k3 {md['k3']:+.5f} "
                         f"p1 {md['p1']:+.6f} p2 {md['p2']:+.6f} "
                         f"(after MultiDIC's own undistortion, so ~0); overall mean error "
                         f"{md['mean_error_px']:.2f} px (mean |e|, not RMS)")
            lines.append(f"  ours - MultiDIC: dfx {c.fx - md['fx']:+.1f}, dfy {c.fy - md['fy']:+.1f}, "
                         f"dcx {c.cx - md['cx']:+.1f}, dcy {c.cy - md['cy']:+.1f} px")
        lines.append("  corners: " + multidic_corner_check(data, cam, names, pts))
        err = np.linalg.norm(cal_residuals(cal, board, pts), axis=-1)
        lines.append(f"  our mean |reprojection error| {err.mean():.3f} px (the figure MultiDIC prints)")
        for line in lines[start:]:
            log(line)
        cals[cam] = cal
    return cals, lines


def cal_residuals(cal, board, pts) -> np.ndarray:
    from measurement.calibration.stepwise import project_views

    return project_views(cal.camera, cal.rvecs, cal.tvecs_mm, board) - pts


# --------------------------------------------------------------------------------------------------------
# Step 2: extrinsics from the calibration object
# --------------------------------------------------------------------------------------------------------
def calibration_object(data: Path, cam: str) -> tuple[np.ndarray, np.ndarray]:
    """MultiDIC's target centroids (MATLAB convention as stored) and their true 3-D coordinates (mm)."""
    s = loadmat(data / "calibrationObjectImages" / f"DLTstruct_cam_{cam}.mat")["DLTstructCam"]
    cols = np.atleast_1d(s.columns).astype(int) - 1
    C3D = np.asarray(s.C3Dtrue, float)[:, cols, :]                  # (rows, columns, 3)
    X = C3D.reshape(-1, 3, order="F")                                # MATLAB reshape(C3Dtemp, Np, 3)
    uv = np.asarray(s.imageCentroids, float)
    if uv.shape[0] != X.shape[0]:
        raise SystemExit(f"camera {cam}: {uv.shape[0]} centroids for {X.shape[0]} targets")
    return uv, X


def blob_centroids(grey: np.ndarray, guess_px: np.ndarray) -> np.ndarray:
    """Binary centroids (Otsu threshold, the dark blob under the guess) of the dark targets, 0-based px; NaN rows
    where no blob is found."""
    d = np.linalg.norm(guess_px[:, None] - guess_px[None], axis=2)
    d[d == 0] = np.inf
    half = int(0.45 * np.median(d.min(1)))
    out = np.full_like(guess_px, np.nan)
    for i, (u, v) in enumerate(np.round(guess_px).astype(int)):
        if not (half <= u < grey.shape[1] - half and half <= v < grey.shape[0] - half):
            continue
        win = grey[v - half:v + half + 1, u - half:u + half + 1]
        _, bw = cv2.threshold(win, 0, 1, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)
        n, lab, stats, cents = cv2.connectedComponentsWithStats(bw.astype(np.uint8))
        if n < 2:
            continue
        k = lab[half, half] if lab[half, half] > 0 else 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        x0, y0, w, h = stats[k, :4]
        if x0 == 0 or y0 == 0 or x0 + w >= win.shape[1] or y0 + h >= win.shape[0]:
            continue                                                  # blob cut by the window
        out[i] = cents[k] + [u - half, v - half]
    return out


def solve_pose(camera, X_mm: np.ndarray, uv_px: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pose ``X_cam = R X_obj + t`` by cv2.solvePnP (OpenCV's k1 k2 p1 p2 k3 = ours for an untilted camera), refined
    by least squares with our projection (:meth:`ScheimpflugCamera.project`). Returns (rvec, t_mm, residuals (N, 2)
    px)."""
    from scipy.optimize import least_squares

    dist = np.array([camera.k1, camera.k2, camera.p1, camera.p2, camera.k3])     # OpenCV's order
    ok, rvec, tvec = cv2.solvePnP(X_mm, uv_px, camera.K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise SystemExit("solvePnP failed")

    def res(p):
        R = cv2.Rodrigues(p[:3])[0]
        return (camera.project(X_mm @ R.T + p[3:]) - uv_px).ravel()

    sol = least_squares(res, np.r_[rvec.ravel(), tvec.ravel()], method="lm", xtol=1e-14, ftol=1e-14)
    return sol.x[:3], sol.x[3:], sol.fun.reshape(-1, 2)


def rig_variant(data: Path, cameras: dict, centroids: str = "multidic"):
    """A rig from ``cameras`` ({cam: ScheimpflugCamera}) and PnP on the calibration object, without the report:
    ``centroids`` = ``multidic`` (C - 2/3), ``multidic-1`` (C - 1) or ``blobs`` (ours). For the sensitivity checks."""
    from measurement.calibration.io import CalibratedRig
    from measurement.image_io import read_grey

    poses = {}
    for cam in CAMERAS:
        uv_m, X = calibration_object(data, cam)
        if centroids == "blobs":
            uv = blob_centroids(read_grey(data / "calibrationObjectImages" / f"{cam}.jpg"), uv_m + CENTROID_OFFSET_PX)
            ok = np.all(np.isfinite(uv), 1)
            uv, X = uv[ok], X[ok]
        else:
            uv = uv_m + (CENTROID_OFFSET_PX if centroids == "multidic" else MATLAB_OFFSET_PX)
        rvec, t, _ = solve_pose(cameras[cam], X, uv)
        poses[cam] = (cv2.Rodrigues(rvec)[0], t)
    (R1, t1), (R2, t2) = poses[CAMERAS[0]], poses[CAMERAS[1]]
    R = R2 @ R1.T
    return CalibratedRig(model="pinhole", left=cameras[CAMERAS[0]], right=cameras[CAMERAS[1]], R_right_from_left=R,
                         T_right_from_left_mm=t2 - R @ t1)


def extrinsics(data: Path, out: Path, cals: dict, lens: str):
    """Step 2: the rig (CalibratedRig) and report lines; writes calibration.json."""
    from measurement.calibration.io import CalibratedRig, load_calibration, save_rig
    from measurement.image_io import read_grey

    lines, poses = [], {}
    for cam in CAMERAS:
        camera = cals[cam].camera
        start = len(lines)
        uv_m, X = calibration_object(data, cam)
        uv = uv_m + CENTROID_OFFSET_PX
        grey = read_grey(data / "calibrationObjectImages" / f"{cam}.jpg")
        ours = blob_centroids(grey, uv)
        ok = np.all(np.isfinite(ours), 1)
        dd = uv_m[ok] - ours[ok]
        dlt_struct = loadmat(data / "calibrationObjectImages" / f"DLTstruct_cam_{cam}.mat")["DLTstructCam"]
        columns = np.atleast_1d(dlt_struct.columns).tolist()
        lines.append(f"camera {cam}: {X.shape[0]} targets (object columns {columns}, 1-based); "
                     f"MultiDIC centroid (as stored) - our blob centroid (0-based), {ok.sum()} blobs: mean "
                     f"({dd[:, 0].mean():+.3f}, {dd[:, 1].mean():+.3f}) px, std ({dd[:, 0].std():.3f}, "
                     f"{dd[:, 1].std():.3f}) px "
                     f"-> offset used {CENTROID_OFFSET_PX:+.3f} px")
        L = np.asarray(dlt_struct.DLTparams, float)
        w = X @ L[8:11] + 1.0
        dlt = np.column_stack([(X @ L[0:3] + L[3]) / w, (X @ L[4:7] + L[7]) / w]) - uv_m
        lines.append(f"  MultiDIC's own DLT (11 parameters, no distortion) on its centroids: reprojection RMS "
                     f"{np.sqrt((dlt ** 2).sum(1).mean()):.3f} px (max {np.linalg.norm(dlt, axis=1).max():.3f})")
        for label, pts in (("MultiDIC centroids - 2/3", uv), ("MultiDIC centroids - 1", uv_m + MATLAB_OFFSET_PX),
                           ("our blob centroids", ours[ok])):
            Xs = X if pts is not ours[ok] else X[ok]
            rvec, t, r = solve_pose(camera, Xs, pts)
            # the same with the distortion switched off: tells whether the centroids came from undistorted images
            _, _, r0 = solve_pose(type(camera)(fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy,
                                               width=camera.width, height=camera.height), Xs, pts)
            lines.append(f"  PnP on {label}: reprojection RMS {np.sqrt((r ** 2).sum(1).mean()):.3f} px "
                         f"(max {np.linalg.norm(r, axis=1).max():.3f}); with zero distortion "
                         f"{np.sqrt((r0 ** 2).sum(1).mean()):.3f} px")
            if label.startswith("MultiDIC centroids - 2/3"):
                poses[cam] = (cv2.Rodrigues(rvec)[0], t)
                lines.append(f"    pose (object -> camera {cam}): rvec {np.round(rvec, 5).tolist()}, "
                             f"t {np.round(t, 3).tolist()} mm, |t| {np.linalg.norm(t):.1f} mm")
        for line in lines[start:]:
            log(line)
    (R1, t1), (R2, t2) = poses[CAMERAS[0]], poses[CAMERAS[1]]
    R = R2 @ R1.T
    T = t2 - R @ t1
    ang = np.degrees(np.linalg.norm(cv2.Rodrigues(R)[0]))
    lines.append(f"stereo (X_{CAMERAS[1]} = R X_{CAMERAS[0]} + T): rotation {ang:.3f} deg, "
                 f"T {np.round(T, 3).tolist()} mm, |T| {np.linalg.norm(T):.2f} mm")
    log(lines[-1])
    rig = CalibratedRig(model="pinhole", left=cals[CAMERAS[0]].camera, right=cals[CAMERAS[1]].camera,
                        R_right_from_left=R, T_right_from_left_mm=T)
    path = out / "calibration.json"
    save_rig(rig, path, extra={"source": "benchmarks/real_multidic.py: intrinsics from each camera's checkerboards "
                                         f"(pinhole, {lens}), poses by PnP on MultiDIC's calibration object",
                               "cameras": {"left": CAMERAS[0], "right": CAMERAS[1]},
                               "object_to_left": {"R": R1.tolist(), "t_mm": t1.tolist()}})
    rig = load_calibration(path)
    save_rig(rig, path.with_suffix(".yaml"))              # the OpenCV YAML twin, as workbench calibrate writes
    lines.append(f"wrote {path} and {path.with_suffix('.yaml').name}")
    return rig, (R1, t1), lines


# --------------------------------------------------------------------------------------------------------
# Step 3: stereo DIC; step 4: cylinder
# --------------------------------------------------------------------------------------------------------
def roi_mask(data: Path) -> np.ndarray:
    m = loadmat(data / "speckledObjectImages" / f"ROIMask_C_{CAMERAS[0]}_C_{CAMERAS[1]}.mat")["ROImask"]
    return np.asarray(m).astype(bool)


def stereo_reference(data: Path, rig, subset: int, step: int, order: int, min_zncc: float):
    """Step 3: (shape, counts dict, report lines)."""
    from measurement.dic import DICSettings, Status
    from measurement.image_io import read_grey
    from measurement.stereo_dic import reference_shape

    left = read_grey(data / "speckledObjectImages" / CAMERAS[0] / f"{CAMERAS[0]}_1.jpg")
    right = read_grey(data / "speckledObjectImages" / CAMERAS[1] / f"{CAMERAS[1]}_1.jpg")
    mask = roi_mask(data)
    if mask.shape != left.shape:
        raise SystemExit(f"ROI mask is {mask.shape}, left image {left.shape}")
    ys, xs = np.nonzero(mask)
    roi = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    settings = DICSettings(subset_size=subset, step=step, order=order, min_zncc=min_zncc)
    t = time.time()
    shape = reference_shape(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, left, right,
                            settings, roi=roi, mask=mask, max_median_residual_px=None, min_measured_fraction=None)
    dt = time.time() - t
    m = shape.right_match
    conv = m.status == Status.CONVERGED
    tri = shape.valid
    counts = {"points": int(shape.x.size), "converged": int(conv.sum()), "triangulated": int((conv & tri).sum())}
    reasons = {Status(s).name: int((m.status == s).sum()) for s in np.unique(m.status) if s != Status.CONVERGED}
    res = shape.residual_px[tri]
    lines = [f"POIs: MultiDIC's ROI mask ({mask.sum()} px, bounding box x {roi[0]}..{roi[2] - 1}, "
             f"y {roi[1]}..{roi[3] - 1}) "
             f"as POI mask; subset {subset} px, step {step} px, order {order}, min ZNCC {min_zncc}; {dt:.0f} s",
             f"points {counts['points']}; left->right match converged {counts['converged']} "
             f"({counts['converged'] / max(counts['points'], 1):.1%}); not converged: {reasons or 'none'}",
             f"(a) triangulated / converged: {counts['triangulated']} / {counts['converged']} = "
             f"{counts['triangulated'] / max(counts['converged'], 1):.2%} (goal >= {GOAL_TRIANGULATED:.0%})",
             f"triangulation residual (RMS of both images): median {np.median(res):.3f} px, 95th percentile "
             f"{np.percentile(res, 95):.3f} px, max {res.max():.3f} px"]
    if counts["triangulated"] < counts["converged"]:
        lines.append(f"converged but not triangulated: {counts['converged'] - counts['triangulated']} points")
    for line in lines:
        log(line)
    return shape, counts, lines


def _axis_frame(d: np.ndarray) -> np.ndarray:
    """Rows e1, e2, d: an orthonormal frame whose third axis is ``d``."""
    d = d / np.linalg.norm(d)
    a = np.eye(3)[np.argmin(np.abs(d))]
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return np.array([e1, np.cross(d, e1), d])


def fit_cylinder(X_mm: np.ndarray) -> dict:
    """Least-squares cylinder through points, (N, 3) mm.

    Each principal direction of the points is tried as the initial axis (circle by Kasa's algebraic fit in the
    plane across it); the parameters (two tilt angles of the axis, the axis point across it, the radius) are refined
    by ``scipy.optimize.least_squares`` on the radial residuals ``|(X - p) x d| - r``; the lowest cost wins.

    Returns
    -------
    dict with ``axis`` (unit), ``point_mm`` (on the axis, nearest the points' centroid), ``radius_mm``,
    ``residual_mm`` (N,), ``rms_mm``
    """
    from scipy.optimize import least_squares

    c0 = X_mm.mean(0)
    _, _, Vt = np.linalg.svd(X_mm - c0, full_matrices=False)
    best = None
    for d0 in Vt:
        F = _axis_frame(d0)

        def geometry(p, F=F):                   # F bound now (the loop rebinds it)
            a, b, px, py, _ = p
            d = F.T @ np.array([a, b, 1.0])
            d /= np.linalg.norm(d)
            return d, c0 + F.T @ np.array([px, py, 0.0])

        def residual(p, geometry=geometry):
            d, q = geometry(p)
            return np.linalg.norm(np.cross(X_mm - q, d), axis=1) - p[4]

        Y = (X_mm - c0) @ F.T
        A = np.column_stack([Y[:, 0], Y[:, 1], np.ones(len(Y))])
        sol, *_ = np.linalg.lstsq(A, (Y[:, :2] ** 2).sum(1), rcond=None)
        cx, cy = sol[0] / 2, sol[1] / 2
        r0 = np.sqrt(max(sol[2] + cx ** 2 + cy ** 2, 1e-6))
        fit = least_squares(residual, [0.0, 0.0, cx, cy, r0], x_scale="jac", xtol=1e-12, ftol=1e-12)
        if best is None or fit.cost < best[0].cost:
            best = (fit, geometry)
    fit, geometry = best
    d, q = geometry(fit.x)
    q = q + d * np.dot(c0 - q, d)
    r = fit.fun
    return {"axis": d, "point_mm": q, "radius_mm": float(fit.x[4]), "residual_mm": r,
            "rms_mm": float(np.sqrt(np.mean(r ** 2)))}


def cylinder_lines(cyl: dict, n: int) -> list[str]:
    rel = cyl["radius_mm"] / RADIUS_MM - 1
    return [f"cylinder fit to {n} triangulated reference points: radius {cyl['radius_mm']:.3f} mm, axis "
            f"{np.round(cyl['axis'], 4).tolist()} (left camera frame), point "
            f"{np.round(cyl['point_mm'], 2).tolist()} mm",
            f"(b) radius error vs {RADIUS_MM} mm: {cyl['radius_mm'] - RADIUS_MM:+.3f} mm = {rel:+.3%} "
            f"(goal within +-{GOAL_RADIUS_REL:.1%})",
            f"radial residuals: RMS {cyl['rms_mm'] * 1e3:.1f} um, "
            f"max |r| {np.abs(cyl['residual_mm']).max() * 1e3:.1f} um, "
            f"5-95th percentile {np.percentile(cyl['residual_mm'], 5) * 1e3:.1f} .. "
            f"{np.percentile(cyl['residual_mm'], 95) * 1e3:.1f} um"]


def residual_png(path: Path, x, y, r_mm, title: str, size) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from labio.atomic import atomic_write_bytes

    r = r_mm * 1e3
    lim = max(float(np.percentile(np.abs(r), 98)), 1e-3)
    fig, ax = plt.subplots(figsize=(4.0, 6.4), dpi=100)
    sc = ax.scatter(x, y, c=np.clip(r, -lim, lim), cmap="RdBu_r", vmin=-lim, vmax=lim, s=4, marker="s")
    pad = 150
    ax.set_xlim(max(0, x.min() - pad), min(size[0], x.max() + pad))
    ax.set_ylim(min(size[1], y.max() + pad), max(0, y.min() - pad))
    ax.set_aspect("equal")
    ax.set_xlabel("x (px, left reference 201_1)")
    ax.set_ylabel("y (px)")
    ax.set_title(title, fontsize=8)
    fig.colorbar(sc, ax=ax, shrink=0.8, label="radial residual (um)")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def sensitivity(data: Path, out: Path, shape, rig, max_side_px: int, lens: str) -> list[str]:
    """The reference's 2-D matches re-triangulated with other calibrations: the other lens model, the other reading
    of MultiDIC's centroids, our own blob centroids. Radius and the fraction triangulated of each."""
    from measurement.calibration.detection import board_points_mm
    from measurement.calibration.stepwise import calibrate_camera
    from measurement.stereo import triangulate

    m = shape.right_match
    conv = m.converged
    pl = np.column_stack([m.x, m.y]).astype(float)[conv]
    pr = pl + np.column_stack([m.u, m.v])[conv]
    other = "brown4" if lens == "brown5" else "brown5"
    board = board_points_mm(PATTERN, SQUARE_MM)
    cams_other = {}
    for cam in CAMERAS:
        names, pts, size = corners_for_camera(data, out, cam, max_side_px)
        cams_other[cam] = calibrate_camera(pts, board, size, model="pinhole", lens=other, name=f"camera {cam}").camera
    ours = {CAMERAS[0]: rig.left, CAMERAS[1]: rig.right}
    variants = [(f"as above ({lens}, MultiDIC centroids - 2/3)", ours, "multidic"),
                (f"lens {other}", cams_other, "multidic"),
                ("MultiDIC centroids - 1 (plain 1-based reading)", ours, "multidic-1"),
                ("our blob centroids on 201.jpg / 202.jpg", ours, "blobs")]
    lines = []
    for label, cams, cen in variants:
        r = rig_variant(data, cams, cen)
        tri = triangulate(r.left, r.right, r.R_right_from_left, r.T_right_from_left_mm, pl, pr)
        cyl = fit_cylinder(tri.X_left_mm[tri.valid])
        lines.append(f"{label}: triangulated {tri.valid.sum()}/{conv.sum()}, median residual "
                     f"{np.nanmedian(tri.reprojection_error_px):.3f} px, radius {cyl['radius_mm']:.3f} mm "
                     f"({cyl['radius_mm'] / RADIUS_MM - 1:+.3%}), RMS {cyl['rms_mm'] * 1e3:.1f} um, |T| "
                     f"{np.linalg.norm(r.T_right_from_left_mm):.2f} mm")
        log("  " + lines[-1])
    return lines


def deformed_states(data: Path, rig, shape, settings_kw: dict) -> list[str]:
    """States 2-5 (201_k / 202_k) against the reference: counts and the cylinder radius of each deformed shape."""
    from measurement.dic import DICSettings
    from measurement.image_io import read_grey
    from measurement.stereo_dic import measure_state

    settings = DICSettings(**settings_kw)
    left_ref = read_grey(data / "speckledObjectImages" / CAMERAS[0] / f"{CAMERAS[0]}_1.jpg")
    lines = []
    for k in range(2, 6):
        t = time.time()
        fl = data / "speckledObjectImages" / CAMERAS[0] / f"{CAMERAS[0]}_{k}.jpg"
        fr = data / "speckledObjectImages" / CAMERAS[1] / f"{CAMERAS[1]}_{k}.jpg"
        try:
            st = measure_state(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, shape, left_ref,
                               read_grey(fl), read_grey(fr), settings, max_median_residual_px=None,
                               min_measured_fraction=None, name=f"state {k}")
        except ValueError as err:
            lines.append(f"state {k}: failed: {err}")
            log("  " + lines[-1])
            continue
        both = st.left_match.converged & st.right_match.converged & shape.right_match.converged
        ok = st.valid
        cyl = fit_cylinder(st.X_mm[ok]) if ok.sum() > 10 else None
        D = st.D_mm[ok]
        lines.append(f"state {k} ({fl.name} / {fr.name}): all three matches converged {both.sum()}/{shape.x.size}; "
                     f"triangulated {ok.sum()}/{both.sum()} = {ok.sum() / max(both.sum(), 1):.2%}; median residual "
                     f"{np.nanmedian(st.residual_px):.3f} px; |U| median {np.median(D):.3f} mm"
                     + (f"; cylinder radius {cyl['radius_mm']:.3f} mm ({cyl['radius_mm'] / RADIUS_MM - 1:+.3%}), "
                        f"RMS {cyl['rms_mm'] * 1e3:.1f} um" if cyl else "") + f"; {time.time() - t:.0f} s")
        log("  " + lines[-1])
    return lines


def read_state_csv(path: Path) -> dict:
    """A ``workbench stereo`` per-state CSV as arrays (x, y px; X (N, 3) mm; status; status_name)."""
    import csv

    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {"x": np.array([int(r["x"]) for r in rows]), "y": np.array([int(r["y"]) for r in rows]),
            "X": np.array([[float(r[c]) for c in "XYZ"] for r in rows]),
            "status": np.array([int(r["status"]) for r in rows]), "name": np.array([r["status_name"] for r in rows])}


def cli_check(data: Path, out: Path, subset: int, step: int, order: int, min_zncc: float) -> list[str]:
    """The same measurement through the CLI (``workbench stereo``, our calibration.json, MultiDIC's ROI mask written
    as a PNG for ``--mask``). Its output folder is temporary (only the counts are reported)."""
    mask = roi_mask(data)
    import tempfile

    sp = data / "speckledObjectImages"
    tmp = tempfile.TemporaryDirectory(prefix="real_multidic_cli_")      # ~14 MB of CSV/VTK at step 10: not kept
    folder = Path(tmp.name) / "cli"
    mask_png = Path(tmp.name) / "roi_mask.png"
    cv2.imwrite(str(mask_png), mask.astype(np.uint8) * 255)
    cmd = [sys.executable, "-m", "workbench.cli", "stereo", "--calib", str(out / "calibration.json"),
           "--left-ref", str(sp / CAMERAS[0] / f"{CAMERAS[0]}_1.jpg"),
           "--right-ref", str(sp / CAMERAS[1] / f"{CAMERAS[1]}_1.jpg"),
           "--left", str(sp / CAMERAS[0] / f"{CAMERAS[0]}_[2-5].jpg"),
           "--right", str(sp / CAMERAS[1] / f"{CAMERAS[1]}_[2-5].jpg"),
           "--mask", str(mask_png), "--subset", str(subset), "--step", str(step), "--order", str(order),
           "--min-zncc", str(min_zncc), "--out", str(folder), "--overwrite"]
    shown = " ".join(f"'{c}'" if "[" in c else c for c in ["workbench"] + cmd[3:-3] + ["--out", "OUT"]).replace(
        str(mask_png), "roi_mask.png")
    log(f"  run: {shown}")
    t = time.time()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    lines = [f"command: {shown}", f"exit {r.returncode} after {time.time() - t:.0f} s; "
             + "; ".join(x.strip() for x in (r.stdout + r.stderr).splitlines()
                         if x.strip() and "stereo states" not in x and "%|" not in x)[:600]]
    for name in ["reference"] + [f"state_{k:03d}" for k in range(4)]:
        f = folder / f"{name}.csv"
        if not f.is_file():
            lines.append(f"{name}: no CSV")
            continue
        c = read_state_csv(f)
        inside = mask[c["y"], c["x"]]
        ok = inside & (c["status"] == 0)
        names, n = np.unique(c["name"][inside & (c["status"] != 0)], return_counts=True)
        bn, bc = np.unique(c["name"][c["status"] != 0], return_counts=True)
        cyl = fit_cylinder(c["X"][ok]) if ok.sum() > 10 else None
        box_failed = dict(zip(bn.tolist(), bc.tolist())) or "none"
        lines.append(f"{name}: {c['x'].size} points (not measured: {box_failed}), "
                     f"{inside.sum()} inside the mask; converged and "
                     f"triangulated {ok.sum()} ({ok.sum() / max(inside.sum(), 1):.2%}); others "
                     f"{dict(zip(names.tolist(), n.tolist())) or 'none'}"
                     + (f"; cylinder radius {cyl['radius_mm']:.3f} mm ({cyl['radius_mm'] / RADIUS_MM - 1:+.3%}), "
                        f"RMS {cyl['rms_mm'] * 1e3:.1f} um" if cyl else ""))
    tmp.cleanup()
    for line in lines[1:]:
        log("  " + line)
    return lines


def measure(data: Path, out: Path, *, step: int = 10, subset: int = 41, order: int = 2, min_zncc: float = 0.8,
            detect_max_side_px: int = DETECT_MAX_SIDE_PX, lens: str = "brown5", states: bool = False, checks: bool = True,
            cli: bool = False) -> dict:
    """Run steps 1-4; returns the figures (and the report lines under ``lines``)."""
    out.mkdir(parents=True, exist_ok=True)
    times, lines = {}, []
    t = time.time()
    log("step 1: intrinsics from each camera's checkerboards")
    cals, l1 = intrinsics(data, out, detect_max_side_px, lens)
    times["1 intrinsics"] = time.time() - t
    t = time.time()
    log("step 2: extrinsics from the calibration object")
    rig, _, l2 = extrinsics(data, out, cals, lens)
    times["2 extrinsics"] = time.time() - t
    t = time.time()
    log("step 3: stereo DIC of the reference pair")
    shape, counts, l3 = stereo_reference(data, rig, subset, step, order, min_zncc)
    times["3 stereo DIC"] = time.time() - t
    t = time.time()
    log("step 4: cylinder fit")
    ok = shape.valid
    cyl = fit_cylinder(shape.X_mm[ok])
    l4 = cylinder_lines(cyl, int(ok.sum()))
    for line in l4:
        log(line)
    times["4 cylinder"] = time.time() - t
    png = out / "radial_residuals.png"
    residual_png(png, shape.x[ok], shape.y[ok], cyl["residual_mm"],
                 f"MultiDIC sample, reference pair: cylinder fit radial residual\nR = {cyl['radius_mm']:.3f} mm "
                 f"(nominal {RADIUS_MM}), RMS {cyl['rms_mm'] * 1e3:.1f} um", (rig.left.width, rig.left.height))
    lines = {}
    if checks:
        t = time.time()
        log("step 5: sensitivity of the radius to the calibration (same 2-D matches, re-triangulated)")
        lines["step 5 sensitivity"] = sensitivity(data, out, shape, rig, detect_max_side_px, lens)
        times["5 sensitivity"] = time.time() - t
    if states:
        t = time.time()
        log("step 6: deformed states 2-5")
        lines["step 6 deformed states"] = deformed_states(data, rig, shape, dict(subset_size=subset, step=step,
                                                                                 order=order, min_zncc=min_zncc))
        times["6 states"] = time.time() - t
    if cli:
        t = time.time()
        log("step 7: the same through the CLI (workbench stereo)")
        lines["step 7 CLI cross-check"] = cli_check(data, out, subset, step, order, min_zncc)
        times["7 CLI"] = time.time() - t
    _save_npz(out / "reference_points.npz", x_px=shape.x, y_px=shape.y, X_mm=shape.X_mm, valid=shape.valid,
              residual_px=shape.residual_px, status=shape.right_match.status)
    lines = {"step 1 intrinsics": l1, "step 2 extrinsics": l2, "step 3 stereo DIC": l3, "step 4 cylinder": l4,
             **lines}
    return {"counts": counts, "fraction": counts["triangulated"] / max(counts["converged"], 1),
            "radius_mm": cyl["radius_mm"], "rms_mm": cyl["rms_mm"],
            "rel_radius_error": cyl["radius_mm"] / RADIUS_MM - 1,
            "times_s": times, "lines": lines, "png": png}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT / "data" / "multidic",
                    help="folder from scripts/fetch_multidic.sh (default data/multidic)")
    ap.add_argument("--out", type=Path, default=ROOT / "reports" / "real_multidic")
    ap.add_argument("--step", type=int, default=10, help="POI grid step, px (default 10)")
    ap.add_argument("--subset", type=int, default=41, help="subset size, px (odd, default 41)")
    ap.add_argument("--order", type=int, choices=(1, 2), default=2)
    ap.add_argument("--min-zncc", type=float, default=0.8)
    ap.add_argument("--detect-max-side", type=int, default=DETECT_MAX_SIDE_PX,
                    help="checkerboard search on a copy shrunk to this long side, refined at full size (default "
                         f"{DETECT_MAX_SIDE_PX}, the instrument's)")
    ap.add_argument("--lens", choices=("brown4", "brown5"), default="brown5")
    ap.add_argument("--states", action="store_true", help="also measure the deformed states 2-5")
    ap.add_argument("--cli", action="store_true",
                    help="also run the reference and states through `workbench stereo --mask`")
    ap.add_argument("--no-checks", action="store_true", help="skip the calibration sensitivity checks (step 5)")
    args = ap.parse_args(argv)
    if not (args.data / "speckledObjectImages").is_dir():
        raise SystemExit(f"{args.data}: not a MultiDIC sample-data folder (run scripts/fetch_multidic.sh)")
    t0 = time.time()
    r = measure(args.data, args.out, step=args.step, subset=args.subset, order=args.order, min_zncc=args.min_zncc,
                detect_max_side_px=args.detect_max_side, lens=args.lens, states=args.states, checks=not args.no_checks,
                cli=args.cli)
    total = time.time() - t0
    try:
        ours = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True).stdout.strip()
    except OSError:
        ours = "?"
    cmd = " ".join([".venv/bin/python", "benchmarks/real_multidic.py"] + (argv if argv is not None else sys.argv[1:]))
    text = [
        "MultiDIC sample data measured with our instrument (benchmarks/real_multidic.py)",
        "",
        f"data: MultiDIC sample_data ({source_line(args.data)}); https://github.com/MultiDIC/MultiDIC, "
        "Apache License 2.0 (LICENSE.txt in the data folder); images and calibration-object coordinates only.",
        f"our code: commit {ours} with uncommitted changes of the working tree",
        f"command: {cmd}",
        "data: scripts/fetch_multidic.sh --mirror /work/.mirror/MultiDIC+MultiDIC/repo (or without --mirror: download)",
        "",
        "RESULT",
        f"  (a) triangulated / converged 2-D matches: {r['counts']['triangulated']} / {r['counts']['converged']} = "
        f"{r['fraction']:.2%}  (goal >= {GOAL_TRIANGULATED:.0%}: "
        f"{'met' if r['fraction'] >= GOAL_TRIANGULATED else 'MISSED'})",
        f"  (b) cylinder radius {r['radius_mm']:.3f} mm vs {RADIUS_MM} mm: {r['rel_radius_error']:+.3%}  (goal within "
        f"+-{GOAL_RADIUS_REL:.1%}: {'met' if abs(r['rel_radius_error']) <= GOAL_RADIUS_REL else 'MISSED'}); "
        f"radial residual RMS {r['rms_mm'] * 1e3:.1f} um",
        "",
    ]
    for name, ls in r["lines"].items():
        text += [name.upper()] + [f"  {x}" for x in ls] + [""]
    text += ["TIME (s): " + ", ".join(f"{k} {v:.0f}" for k, v in r["times_s"].items()) + f", total {total:.0f}",
             f"plot: {r['png'].name}; points: reference_points.npz; calibration: calibration.json; corner cache: "
             "corners_201.npz, corners_202.npz"]
    from labio.atomic import atomic_write_text

    atomic_write_text(args.out / "benchmark.txt", "\n".join(text) + "\n")
    atomic_write_text(args.out / "figures.json", json.dumps(
        {"triangulated": r["counts"]["triangulated"], "converged": r["counts"]["converged"],
         "points": r["counts"]["points"], "fraction": r["fraction"], "radius_mm": r["radius_mm"],
         "rms_mm": r["rms_mm"], "rel_radius_error": r["rel_radius_error"], "times_s": r["times_s"]}, indent=1))
    log(f"wrote {args.out / 'benchmark.txt'} ({total:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
