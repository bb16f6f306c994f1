"""Stereo-DIC (measurement/stereo_dic.py) on renders of a speckled plate through the paper rig (test scale).

The plate sits where the optical axes meet, facing the bisector of the two cameras; the true rig is used, so
the figures measure matching + triangulation alone. Truth: the plate plane, and its rigid translation.
"""
import numpy as np
import pytest

from measurement.dic import DICSettings, Status
from measurement.stereo_dic import StereoMatchError, match_features, measure_state, reference_shape
from scenes.sensor.noise import SensorNoise
from scenes.rendering.mitsuba import render_view
from scenes.specimens.plate import SpeckledPlate
from workbench.experiments.calibration.views import sensor_spec_for
from workbench.rigs import paper_rig

SCALE = 0.25
RIG = paper_rig(SCALE)
NOISE = SensorNoise(read_noise_grey=1.0, bit_depth=8)
MM_PER_PX = 85.0 / RIG.left.width
SETTINGS = DICSettings(subset_size=33, step=10, order=2)
MOVE_MM = np.array([0.0, -1.0, 0.0])


def _plate_pose():
    axis_left = np.array([0.0, 0.0, 1.0])
    axis_right = RIG.R_right_from_left.T @ axis_left
    z = axis_left + axis_right
    z /= np.linalg.norm(z)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z]), RIG.optical_axes_meeting_point_mm()


@pytest.fixture(scope="module")
def renders():
    plate = SpeckledPlate(width_mm=70.0, height_mm=55.0, texel_mm=MM_PER_PX / 4, speckle_mm=4 * MM_PER_PX, seed=3)
    texture = plate.texture()
    R_world_from_plate, centre_mm = _plate_pose()
    images = {}
    for state, offset in (("ref", np.zeros(3)), ("def", MOVE_MM)):
        surface = plate.surface(R_world_from_plate, centre_mm + offset, texture)
        for k, side in enumerate(("left", "right")):
            R_cw, t_cw = RIG.pose(side)
            image = render_view(sensor_spec_for(RIG, side), R_cw, t_cw, [surface], spp=64,
                                seed=10 * k + (state == "def")).image_grey
            images[f"{side}_{state}"] = NOISE.apply(image, seed=100 + 10 * k + (state == "def"))
    return images, R_world_from_plate, centre_mm


def _roi():
    w, h = RIG.left.width, RIG.left.height
    return (int(0.3 * w), int(0.3 * h), int(0.7 * w), int(0.7 * h))


def test_reference_shape_lies_on_the_plate(renders):
    images, R_world_from_plate, centre_mm = renders
    shape = reference_shape(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm,
                            images["left_ref"], images["right_ref"], SETTINGS, roi=_roi())
    assert shape.valid.mean() > 0.95, shape.right_match.status_counts()
    normal = R_world_from_plate[:, 2]
    distance_um = 1e3 * (shape.X_mm[shape.valid] - centre_mm) @ normal
    print(f"reference shape: {shape.valid.sum()} points, plane distance RMS {np.sqrt(np.mean(distance_um ** 2)):.2f} "
          f"um, max {np.abs(distance_um).max():.2f} um; residual median {np.median(shape.residual_px[shape.valid]):.4f} px")
    # 1 px ~ 0.14 mm at this scale; 0.01 px of matching noise is ~3 um in depth through the 23 deg stereo angle
    assert np.sqrt(np.mean(distance_um ** 2)) < 10.0
    assert np.median(shape.residual_px[shape.valid]) < 0.05


def test_rigid_translation_is_measured(measured):
    _, _, state = measured
    ok = state.valid
    assert ok.mean() > 0.95, {s: int((state.status == s).sum()) for s in np.unique(state.status)}
    error_um = 1e3 * (state.U_mm[ok] - MOVE_MM)
    print(f"translation 1 mm: mean error {error_um.mean(axis=0).round(2)} um, std {error_um.std(axis=0).round(2)} um; "
          f"D mean {state.D_mm[ok].mean():.5f} mm")
    assert np.abs(error_um.mean(axis=0)).max() < 5.0
    assert error_um.std(axis=0).max() < 10.0
    assert abs(state.D_mm[ok].mean() - 1.0) < 0.005
    assert np.all(state.status[~ok] != Status.CONVERGED)
    assert np.isnan(state.U_mm[~ok]).all()


def test_images_with_no_overlap_are_refused(renders):
    images, _, _ = renders
    flat = np.full_like(images["right_ref"], 128)
    with pytest.raises(StereoMatchError, match="right reference"):
        match_features(images["left_ref"], flat, name="right reference")


def test_image_size_must_match_the_calibration(renders):
    images, _, _ = renders
    with pytest.raises(ValueError, match="calibration is for"):
        reference_shape(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm,
                        images["left_ref"][:-2], images["right_ref"][:-2], SETTINGS)


def test_workbench_stereo_cli(renders, tmp_path, capsys):
    import csv

    import cv2

    from measurement.calibration.io import CalibratedRig, export_opencv_yaml
    from workbench.cli import main

    images, _, _ = renders
    for name, image in images.items():
        cv2.imwrite(str(tmp_path / f"{name}.png"), np.clip(np.rint(image), 0, 255).astype(np.uint8))
    export_opencv_yaml(CalibratedRig("rmm", RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm),
                       tmp_path / "rig.yaml")
    x0, y0, x1, y1 = _roi()
    args = ["stereo", "--calib", str(tmp_path / "rig.yaml"), "--left-ref", str(tmp_path / "left_ref.png"),
            "--right-ref", str(tmp_path / "right_ref.png"), "--left", str(tmp_path / "left_def.png"),
            "--right", str(tmp_path / "right_def.png"), "--roi", f"{x0},{y0},{x1},{y1}", "--subset", "33",
            "--step", "20", "--out", str(tmp_path / "out")]
    assert main(args) == 0
    rows = list(csv.DictReader((tmp_path / "out" / "state_001.csv").open()))
    assert rows and set(rows[0]) >= {"x", "y", "X", "Y", "Z", "U", "V", "W", "zncc", "residual", "status"}
    V = np.array([float(r["V"]) for r in rows if r["status_name"] == "converged"])
    assert V.size > 0.9 * len(rows) and abs(V.mean() + 1.0) < 0.01
    vtk = (tmp_path / "out" / "state_001.vtk").read_text()
    assert vtk.startswith("# vtk DataFile") and "VECTORS displacement_mm" in vtk
    # missing calibration file: one clear line, exit code 2
    assert main(args[:2] + [str(tmp_path / "none.json")] + args[3:]) == 2
    assert "calibration file not found" in capsys.readouterr().err


# --- the reference side computed once per sequence, warm starts, fast per-point files (issue 39) ---------------

@pytest.fixture(scope="module")
def measured(renders):
    images, _, _ = renders
    shape = reference_shape(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm,
                            images["left_ref"], images["right_ref"], SETTINGS, roi=_roi())
    state = measure_state(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm, shape,
                          images["left_ref"], images["left_def"], images["right_def"], SETTINGS)
    return images, shape, state


def _seeds_of(result, count=8):
    from measurement.dic import Seed

    ok = np.flatnonzero(result.converged)
    return [Seed(int(result.x[k]), int(result.y[k]), result.parameters[k]) for k in ok[:: ok.size // count][:count]]


def test_a_match_reading_the_reference_cache_equals_one_that_prepares_every_subset_again(measured):
    """Same seeds, same images: the cached Hessians, means and norms give the same numbers to 1e-12 px."""
    from measurement.dic import correlate

    images, shape, state = measured
    cache = shape.reference_cache
    assert cache.filled_fraction > 0.9      # the stereo match filled it: the states read it
    seeds = _seeds_of(state.left_match)
    fresh = correlate(shape.reference, images["left_def"], SETTINGS, grid=shape.grid, seeds=seeds)
    cached = correlate(shape.reference, images["left_def"], SETTINGS, grid=shape.grid, seeds=seeds,
                       reference_cache=cache)
    assert np.array_equal(fresh.status, cached.status)
    ok = fresh.converged
    assert ok.mean() > 0.95
    assert np.max(np.abs(fresh.u[ok] - cached.u[ok])) <= 1e-12
    assert np.max(np.abs(fresh.v[ok] - cached.v[ok])) <= 1e-12
    assert np.max(np.abs(fresh.zncc[ok] - cached.zncc[ok])) <= 1e-12


def test_a_cached_reference_status_says_why_unreached_nodes_are_unusable_as_a_fresh_match_does(measured):
    """Nodes no propagation reaches take their reference-only status (here: untextured) from the cache's one
    integral-image pass: the same statuses as a match without the cache, twice over (the second reads the kept
    array), and each untextured node's subset really has a grey-level std under the threshold (direct numpy)."""
    from measurement.dic import ReferenceCache, Status, correlate
    from measurement.dic.correlate import prepare_image, subset_min_std

    images, shape, state = measured
    flat = images["left_ref"].copy()
    x0, y0, x1, y1 = _roi()
    cx, cy, size = (x0 + x1) // 2, (y0 + y1) // 2, SETTINGS.subset_size + 4 * SETTINGS.step
    flat[cy - size // 2:cy + size // 2, cx - size // 2:cx + size // 2] = 128.0
    prepared = prepare_image(flat, SETTINGS.interpolation, True, "flat patch")
    min_std = subset_min_std(SETTINGS, prepared.values)
    cache = ReferenceCache.for_grid(prepared.values, shape.grid, SETTINGS, min_std)
    seeds = _seeds_of(state.left_match)
    fresh = correlate(prepared, images["left_def"], SETTINGS, grid=shape.grid, seeds=seeds)
    first = correlate(prepared, images["left_def"], SETTINGS, grid=shape.grid, seeds=seeds, reference_cache=cache)
    second = correlate(prepared, images["left_def"], SETTINGS, grid=shape.grid, seeds=seeds, reference_cache=cache)
    untextured = fresh.status == int(Status.LOW_TEXTURE)
    assert untextured.sum() >= 4
    assert np.array_equal(fresh.status, first.status) and np.array_equal(fresh.status, second.status)
    half = SETTINGS.subset_size // 2
    for x, y in zip(fresh.x[untextured], fresh.y[untextured]):
        assert flat[y - half:y + half + 1, x - half:x + half + 1].std() < min_std


def test_a_reference_cache_is_refused_for_another_reference_grid_or_setting(measured):
    from dataclasses import replace

    from measurement.dic import correlate, poi_grid

    images, shape, state = measured
    cache = shape.reference_cache
    with pytest.raises(ValueError, match="reference_cache was made for another match: .*the reference image"):
        correlate(images["right_ref"], images["left_def"], SETTINGS, grid=shape.grid, reference_cache=cache)
    other_grid = poi_grid(images["left_ref"].shape, SETTINGS.subset_size, SETTINGS.step + 2, roi=_roi())
    with pytest.raises(ValueError, match="the grid of points of interest"):
        correlate(shape.reference, images["left_def"], SETTINGS, grid=other_grid, reference_cache=cache)
    with pytest.raises(ValueError, match=r"order \(1, the cache has 2\)"):
        correlate(shape.reference, images["left_def"], replace(SETTINGS, order=1), grid=shape.grid,
                  reference_cache=cache)


def test_a_cache_of_another_reference_would_move_the_matches(measured):
    """Why the refusal matters: the left reference's cached Hessians, means and norms used for a reference shifted
    by 1 px (the check bypassed by hand) move the matches by more than 0.01 px (ten times IC-GN's tolerance; a
    median ~0.06 px measured) or fail them. So the 1e-12 px equality test above can fail."""
    from measurement.dic import ReferenceCache, correlate
    from measurement.dic.correlate import prepare_image, subset_min_std
    from measurement.dic.reference_cache import _fingerprint

    images, shape, state = measured
    shifted = np.roll(images["left_ref"], 1, axis=1)
    prepared = prepare_image(shifted, SETTINGS.interpolation, True, "shifted")
    seeds = _seeds_of(state.left_match)
    fresh = correlate(prepared, images["left_def"], SETTINGS, grid=shape.grid, seeds=seeds)
    wrong = ReferenceCache.for_grid(shape.reference.values, shape.grid, SETTINGS,
                                    subset_min_std(SETTINGS, prepared.values))
    correlate(shape.reference, images["left_def"], SETTINGS, grid=shape.grid, seeds=seeds, reference_cache=wrong)
    wrong._values, wrong.fingerprint = prepared.values, _fingerprint(prepared.values)     # the bypass
    reused = correlate(prepared, images["left_def"], SETTINGS, grid=shape.grid, seeds=seeds, reference_cache=wrong)
    both = fresh.converged & reused.converged
    lost = np.mean(fresh.converged & ~reused.converged)
    error = np.abs(reused.u[both] - fresh.u[both])
    assert lost > 0.5 or np.median(error) > 0.01, (lost, np.median(error))


def test_a_state_warm_started_from_the_previous_one_measures_what_feature_seeds_measure(measured):
    """The warm start replaces feature matching; the matches agree to 1e-4 px (a tenth of the IC-GN tolerance),
    and a previous state the seeds cannot follow (every point 200 px off) falls back to feature seeds."""
    from copy import deepcopy

    images, shape, state = measured
    warm = measure_state(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm, shape,
                         images["left_ref"], images["left_def"], images["right_def"], SETTINGS, previous=state)
    assert warm.seeded_by == {"left": "previous state", "right": "previous state"}
    assert state.seeded_by == {"left": "features", "right": "features"}
    assert np.array_equal(warm.valid, state.valid)
    ok = warm.valid
    for side in ("left_match", "right_match"):
        a, b = getattr(warm, side), getattr(state, side)
        assert np.max(np.abs(a.u[ok] - b.u[ok])) < 1e-4 and np.max(np.abs(a.v[ok] - b.v[ok])) < 1e-4
    far = deepcopy(state)
    for match in (far.left_match, far.right_match):
        match.parameters[:, 0] += 200.0
    jumped = measure_state(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm, shape,
                           images["left_ref"], images["left_def"], images["right_def"], SETTINGS, previous=far)
    assert jumped.seeded_by == {"left": "features", "right": "features"}
    assert np.array_equal(jumped.valid, state.valid)
    assert np.nanmax(np.abs(jumped.U_mm - state.U_mm)) < 1e-5


def _sequence_seeds_by_dict(reference, target, grid, previous, settings, per_region=2, tries_per_region=6,
                            min_zncc=0.5):
    """The warm-start seeds found through a dict of positions (the implementation the array lookup replaced)."""
    from measurement.dic import Seed, Status
    from measurement.dic.guide import band_regions
    from measurement.dic.initial import zncc_search

    ok = previous.status == Status.CONVERGED
    lookup = {(int(x), int(y)): k for k, (x, y) in enumerate(zip(previous.x[ok], previous.y[ok]))}
    params = previous.parameters[ok]
    region = band_regions(grid.shape, settings.regions)
    seeds = []
    for region_id in range(int(region.max()) + 1):
        rows, cols = np.nonzero(grid.active & (region == region_id))
        known = [(int(grid.x[r, c]), int(grid.y[r, c])) for r, c in zip(rows, cols)]
        known = [xy for xy in known if xy in lookup]
        if not known:
            continue
        xy = np.array(known, dtype=np.float64)
        order = np.argsort(np.sum((xy - xy.mean(axis=0)) ** 2, axis=1), kind="stable")
        found = 0
        for k in order[:: max(1, order.size // 64)][:tries_per_region]:
            x, y = known[k]
            p = params[lookup[(x, y)]].copy()
            seed = zncc_search(reference, target, x, y, grid.half, int(settings.search_radius_px), (p[0], p[6]))
            if seed is None or not seed.zncc >= min_zncc:
                continue
            p[0], p[6] = seed.parameters[0], seed.parameters[6]
            seeds.append(Seed(x, y, p, seed.zncc))
            found += 1
            if found >= per_region:
                break
    return seeds


def test_warm_start_seeds_are_those_a_dict_of_positions_gives(measured):
    """sequence_seeds finds the previous match's nodes by sorted position keys: the same seeds (node, parameters,
    score) as a dict lookup, also when most previous points failed (only every third one kept)."""
    from copy import deepcopy

    from measurement.dic import Status
    from measurement.stereo_dic import sequence_seeds

    images, shape, state = measured
    sparse = deepcopy(state.right_match)
    sparse.status[np.arange(sparse.status.size) % 3 != 0] = int(Status.LOW_CORRELATION)
    for previous in (state.right_match, sparse):
        fast = sequence_seeds(shape.reference.values, images["right_def"], shape.grid, previous, SETTINGS)
        slow = _sequence_seeds_by_dict(shape.reference.values, images["right_def"], shape.grid, previous, SETTINGS)
        assert len(fast) == len(slow) >= SETTINGS.regions
        for a, b in zip(fast, slow):
            assert (a.x, a.y, a.zncc) == (b.x, b.y, b.zncc) and np.array_equal(a.parameters, b.parameters)


def _csv_reference(header, rows):
    """The per-value writer the fast one replaced (csv module, one value at a time): the independent reference."""
    import csv
    import io

    def fmt(value):
        return "nan" if not np.isfinite(value) else f"{value:.9g}"

    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    writer.writerow(header)
    for row in rows:
        writer.writerow([fmt(v) if isinstance(v, float) else str(v) for v in row])
    return buffer.getvalue()


def test_per_point_files_hold_the_text_a_value_by_value_writer_gives(measured, tmp_path):
    """write_state_csv / write_points_with_truth / write_state_vtk, byte for byte against value-by-value
    formatting, with NaN, +-inf, -0 and extreme magnitudes in the columns."""
    from copy import deepcopy

    from measurement.stereo_io import CSV_COLUMNS, state_sigmas, write_state_csv, write_state_vtk
    from workbench.points_with_truth import TRUTH_COLUMNS, Alignment, write_points_with_truth

    images, shape, state = measured
    state = deepcopy(state)
    n = shape.x.size
    state.X_mm[0] = [np.inf, -np.inf, -0.0]
    state.X_mm[1] = [1.23456789012e-300, -9.87654321e+250, 1e-5]
    state.zncc[2] = np.nan
    write_state_csv(tmp_path / "state.csv", shape, state)
    D = np.linalg.norm(state.U_mm, axis=1)
    sig = state_sigmas(shape, state)
    flag = sig.pop("sigma_flag")
    from measurement.dic import Status

    rows = [[int(shape.x[k]), int(shape.y[k]), *map(float, state.X_mm[k]), *map(float, state.U_mm[k]), float(D[k]),
             float(state.zncc[k]), float(state.residual_px[k]), int(state.status[k]),
             Status(int(state.status[k])).name.lower(), *(float(v[k]) for v in sig.values()),
             "" if flag[k] < 0 else int(flag[k])] for k in range(n)]
    assert (tmp_path / "state.csv").read_bytes().decode() == _csv_reference(CSV_COLUMNS, rows)

    rng = np.random.default_rng(0)
    X_true_ref, X_true = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    X_true[3] = np.nan
    on = rng.random(n) > 0.2
    R, t = np.eye(3)[[1, 0, 2]], np.array([0.5, -1.0, 2.0])
    write_points_with_truth(tmp_path / "truth.csv", shape, state, X_true_ref, X_true, on, Alignment(R, t, 5),
                            extra={"bonus": np.arange(n) * 0.1})
    X_al, U_al, U_true = state.X_mm @ R.T + t, state.U_mm @ R.T, X_true - X_true_ref
    truth_rows = [row + [*map(float, (*X_al[k], *U_al[k], *X_true[k], *U_true[k], np.linalg.norm(U_true[k]))),
                         int(on[k]), float(k * 0.1)] for k, row in enumerate(rows)]
    expected = _csv_reference([*CSV_COLUMNS, *TRUTH_COLUMNS, "bonus"], truth_rows)
    assert (tmp_path / "truth.csv").read_bytes().decode() == expected

    write_state_vtk(tmp_path / "state.vtk", shape, state)
    ok = state.valid
    text = (tmp_path / "state.vtk").read_text().splitlines()
    m = int(ok.sum())
    assert text[4] == f"POINTS {m} double"
    assert text[5:5 + m] == [" ".join(f"{float(v):.9g}" for v in X) for X in state.X_mm[ok]]
    zncc_at = text.index("SCALARS zncc double 1")
    assert text[zncc_at + 2:zncc_at + 2 + m] == [f"{float(v):.9g}" for v in state.zncc[ok]]
