"""Property-based fuzzing (hypothesis) of every structured-file loader, and the truth.json schema.

Loaders: the calibration JSON (:func:`measurement.calibration.io.load_calibration`), the OpenCV YAML
(:func:`~measurement.calibration.io.load_opencv_yaml`) and ``truth.json`` of both experiments
(:func:`workbench.experiments.rigid_motion.scenes.load_truth`,
:func:`workbench.experiments.bending.scenes.load_bending_truth`).

The property: whatever the bytes, a loader returns a valid object or raises
:class:`labio.schema.FileFormatError` naming the file -- never another exception (KeyError, TypeError,
AttributeError, SystemError, OverflowError, a cv2.error ...). Inputs, per loader:

* random JSON/YAML structures (recursive dicts/lists/scalars, top-level keys drawn from the real ones too);
* mutations of a valid file: drop a key or list entry, replace a value with a random structure or an extreme
  scalar (NaN, +-inf, 1e300, 10**400, a numeric string, a boolean, null), wrap a value in a list;
* text damage of a valid file: truncated at a random byte, random bytes overwritten, a slice cut out, lines
  dropped / duplicated / given a random value (YAML), up to 60 000 nested brackets inserted (OpenCV's YAML
  parser overflows its stack beyond ~20 000);
* random bytes.

The default run is deterministic (``derandomize=True``) and sized to ~40 s for the four loaders together on
2 cores (:data:`DEFAULT_EXAMPLES` each); ``pytest -m fuzz_long`` runs 10 000 cases per loader.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from measurement.calibration.io import (CalibratedRig, _read_opencv_yaml, calibration_to_dict, export_opencv_yaml,
                                        load_calibration, load_opencv_yaml)
from measurement.calibration.stepwise import CameraCalibration, StereoCalibration
from labio.schema import FileFormatError

#: Cases per loader in the default run (4 loaders: ~40 s in all on 2 cores) and under ``-m fuzz_long``.
DEFAULT_EXAMPLES = 300
LONG_EXAMPLES = 10_000

_COMMON = dict(deadline=None, derandomize=True, database=None, print_blob=True,
               suppress_health_check=list(HealthCheck))
DEFAULT_SETTINGS = settings(max_examples=DEFAULT_EXAMPLES, **_COMMON)
LONG_SETTINGS = settings(max_examples=LONG_EXAMPLES, **_COMMON)


# ------------------------------------------------------------------------------------------------------------
# Valid files to start from (built once; no rendering)
# ------------------------------------------------------------------------------------------------------------
def _stereo_calibration() -> StereoCalibration:
    from workbench.rigs import paper_rig

    rig = paper_rig(0.5)
    sigma = {n: 0.01 for n in ("fx", "fy", "cx", "cy", "alpha_deg", "beta_deg", "k1", "k2", "p1", "p2")}

    def cam(c):
        return CameraCalibration(c, np.zeros((2, 3)), np.ones((2, 3)), 0.03, np.array([0.03, 0.03]), dict(sigma),
                                 [("intrinsics", ("fx", "fy"), 0.05)])

    return StereoCalibration("rmm", cam(rig.left), cam(rig.right), rig.R_right_from_left, rig.T_right_from_left_mm,
                             {"rvec": [1e-4] * 3, "T_mm": [0.01] * 3}, {"left": 0.03, "right": 0.03},
                             {"left": [0.03], "right": [0.03]}, [("stereo", ("R", "T"), 0.03)])


@functools.cache
def valid_calibration_json() -> str:
    return json.dumps(calibration_to_dict(_stereo_calibration()), indent=1)


@functools.cache
def valid_opencv_yaml() -> str:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "calib.yaml"
        export_opencv_yaml(_stereo_calibration(), path)
        return path.read_text()


def _as_rendered(truth, rig, scale):
    """The truth as ``render_*`` leaves it before writing truth.json: image names and render/rig info."""
    digits = 2
    n = len(getattr(truth, "poses", None) or truth.loads_N)
    truth.files = [{side: f"{side}_{k:0{digits}d}.png" for side in ("left", "right")} for k in range(n)]
    truth.info.update(render={"spp": 4, "seed": 0, "bit_depth": 8, "read_noise_grey": 1.0, "exposure_grey": 128.0},
                      rig={"name": rig.name, "scale": scale,
                           "R_right_from_left": np.asarray(rig.R_right_from_left).tolist(),
                           "T_right_from_left_mm": np.asarray(rig.T_right_from_left_mm).tolist(),
                           "pixel_pitch_mm": rig.pixel_pitch_mm,
                           "intrinsics": {side: rig.camera(side).to_dict() for side in ("left", "right")}})
    return truth


@functools.cache
def rigid_truth():
    from workbench.experiments.rigid_motion.scenes import rigid_motion_truth
    from workbench.rigs import get_rig

    rig = get_rig("paper", 0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = rigid_motion_truth(rig, lens="thin", states_mm=[0.0, 1.0, 2.0])
    return _as_rendered(truth, rig, 0.1)


@functools.cache
def bending_truth_():
    from workbench.experiments.bending.scenes import bending_truth
    from workbench.rigs import get_rig

    rig = get_rig("scheimpflug", 0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = bending_truth(rig, lens="thin", loads_N=[20.0, 200.0, 400.0])
    return _as_rendered(truth, rig, 0.1)


@functools.cache
def valid_rigid_truth_json() -> str:
    from workbench.experiments.rigid_motion.scenes import _truth_to_json

    return json.dumps(_truth_to_json(rigid_truth()), indent=1)


@functools.cache
def valid_bending_truth_json() -> str:
    from workbench.experiments.bending.scenes import _truth_to_json

    return json.dumps(_truth_to_json(bending_truth_()), indent=1)


# ------------------------------------------------------------------------------------------------------------
# Strategies
# ------------------------------------------------------------------------------------------------------------
EXTREMES = [0, -1, 1, 0.0, -0.0, 1e300, -1e300, 1e-320, math.nan, math.inf, -math.inf, 10 ** 400, -(10 ** 400),
            2 ** 63, True, False, None, "", "1.0", "nan", "abc", [], {}, [1.0, 2.0, 3.0], {"rows": 3}]
#: Text without lone surrogates (those cannot be UTF-8 encoded; invalid UTF-8 comes from the byte damage).
TEXT = st.text(st.characters(blacklist_categories=("Cs",)), max_size=12)
SCALARS = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), TEXT, st.sampled_from(EXTREMES))


def _keys(doc) -> list[str]:
    """Every mapping key anywhere in a document (random structures are built from the real names too)."""
    out = set()
    if isinstance(doc, dict):
        out |= set(doc)
        for v in doc.values():
            out |= set(_keys(v))
    elif isinstance(doc, list):
        for v in doc:
            out |= set(_keys(v))
    return sorted(out)


def json_values(keys=TEXT):
    return st.recursive(SCALARS, lambda children: st.one_of(st.lists(children, max_size=5),
                                                            st.dictionaries(keys, children, max_size=5)),
                        max_leaves=25)


def _paths(doc, prefix=()):
    """Every path (tuple of keys / indices) in a JSON-like document, the root included."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, prefix + (i,))
    return out


@st.composite
def mutated(draw, valid_doc):
    """A valid document with 1-3 random structural mutations."""
    doc = json.loads(json.dumps(valid_doc))
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        path = draw(st.sampled_from(paths))
        op = draw(st.sampled_from(["drop", "replace", "extreme", "wrap"]))
        if not path:
            if op in ("replace", "extreme"):
                doc = draw(json_values() if op == "replace" else st.sampled_from(EXTREMES))
            elif op == "wrap":
                doc = [doc]
            continue
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        last = path[-1]
        if op == "drop":
            del parent[last]
        elif op == "replace":
            parent[last] = draw(json_values())
        elif op == "extreme":
            parent[last] = draw(st.sampled_from(EXTREMES))
        else:
            parent[last] = [parent[last]]
    return doc


@st.composite
def damaged_text(draw, text: str):
    """The bytes of a valid file, truncated / overwritten / cut."""
    data = bytearray(text.encode())
    op = draw(st.sampled_from(["truncate", "overwrite", "cut"]))
    if op == "truncate":
        return bytes(data[:draw(st.integers(0, len(data)))])
    if op == "overwrite":
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, len(data) - 1))
            data[i] = draw(st.integers(0, 255))
        return bytes(data)
    i = draw(st.integers(0, len(data)))
    j = draw(st.integers(i, min(len(data), i + 200)))
    return bytes(data[:i] + data[j:])


def json_bytes(doc) -> st.SearchStrategy:
    return st.tuples(st.just(doc), st.booleans()).map(
        lambda t: json.dumps(t[0], ensure_ascii=t[1]).encode("utf-8", "surrogatepass"))


@st.composite
def deeply_nested(draw, valid_text: str):
    """The valid text with a value replaced by up to 60 000 nested brackets (parsers that recurse crash)."""
    depth = draw(st.integers(1, 60_000))
    opener = draw(st.sampled_from(["[", "{", "- ", '{"a": ']))
    i = draw(st.integers(0, len(valid_text)))
    return (valid_text[:i] + opener * depth + valid_text[i:]).encode()


@st.composite
def json_file(draw, valid_text: str):
    valid = json.loads(valid_text)
    kind = draw(st.sampled_from(["random", "random-keyed", "mutated", "damaged", "deep", "bytes"]))
    if kind == "random":
        return draw(json_values().flatmap(json_bytes))
    if kind == "random-keyed":
        keys = st.one_of(st.sampled_from(_keys(valid)), TEXT)
        return draw(st.dictionaries(keys, json_values(keys), max_size=8).flatmap(json_bytes))
    if kind == "mutated":
        return draw(mutated(valid).flatmap(json_bytes))
    if kind == "damaged":
        return draw(damaged_text(valid_text))
    if kind == "deep":
        return draw(deeply_nested(valid_text))
    return draw(st.binary(max_size=300))


# --- OpenCV YAML -------------------------------------------------------------------------------------------
_PLAIN_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _yaml_scalar(v) -> str:
    if isinstance(v, bool) or v is None:
        return json.dumps(v)
    if isinstance(v, float):
        return ".nan" if math.isnan(v) else (".Inf" if v == math.inf else "-.Inf" if v == -math.inf else repr(v))
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[ " + ", ".join(_yaml_scalar(x) for x in v) + " ]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_yaml_key(k)}: {_yaml_scalar(x)}" for k, x in v.items()) + " }"
    return repr(v)


def _yaml_key(k) -> str:
    return k if isinstance(k, str) and _PLAIN_KEY.match(k) else json.dumps(str(k))


def to_opencv_yaml(doc) -> str:
    """Emit a document as OpenCV FileStorage YAML (matrices as ``!!opencv-matrix`` blocks)."""
    lines = ["%YAML:1.0", "---"]
    if not isinstance(doc, dict):
        return "\n".join(lines + [_yaml_scalar(doc)]) + "\n"
    for k, v in doc.items():
        if isinstance(v, dict) and {"rows", "cols", "dt", "data"} <= set(v):
            lines.append(f"{_yaml_key(k)}: !!opencv-matrix")
            lines += [f"   {_yaml_key(mk)}: {_yaml_scalar(mv)}" for mk, mv in v.items()]
        else:
            lines.append(f"{_yaml_key(k)}: {_yaml_scalar(v)}")
    return "\n".join(lines) + "\n"


@st.composite
def damaged_lines(draw, text: str):
    lines = text.splitlines()
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["drop", "duplicate", "value"]))
        if op == "drop":
            del lines[i]
        elif op == "duplicate":
            lines.insert(i, lines[i])
        else:
            head = lines[i].split(":", 1)[0]
            token = draw(st.one_of(st.sampled_from([".nan", ".Inf", "1e300", "-1e300", "abc", "", "[", "{", "]",
                                                    "!!opencv-matrix", "0", "-0", "1.8e308", "'x'", '"y"']),
                                   TEXT))
            lines[i] = f"{head}: {token}"
        if not lines:
            break
    return ("\n".join(lines) + "\n").encode("utf-8", "surrogatepass")


@st.composite
def yaml_file(draw, valid_text: str):
    valid = _read_opencv_yaml(valid_text, "valid.yaml").value
    kind = draw(st.sampled_from(["random", "random-keyed", "mutated", "damaged", "lines", "deep", "bytes"]))
    if kind == "random":
        doc = draw(json_values())
    elif kind == "random-keyed":
        keys = st.one_of(st.sampled_from(_keys(valid)), TEXT)
        doc = draw(st.dictionaries(keys, json_values(keys), max_size=12))
    elif kind == "mutated":
        doc = draw(mutated(valid))
    elif kind == "damaged":
        return draw(damaged_text(valid_text))
    elif kind == "lines":
        return draw(damaged_lines(valid_text))
    elif kind == "deep":
        return draw(deeply_nested(valid_text))
    else:
        return draw(st.binary(max_size=300))
    return to_opencv_yaml(doc).encode("utf-8", "surrogatepass")


# ------------------------------------------------------------------------------------------------------------
# The property
# ------------------------------------------------------------------------------------------------------------
def _check_rig(rig: CalibratedRig):
    for cam in (rig.left, rig.right):
        assert 0 < cam.fx < 1e6 and 0 < cam.fy < 1e6 and cam.width >= 1 and cam.height >= 1
        assert all(math.isfinite(v) for v in cam.intrinsics().values())
    R = rig.R_right_from_left
    assert np.max(np.abs(R.T @ R - np.eye(3))) <= 1e-6 and np.linalg.det(R) > 0
    assert 0 < np.linalg.norm(rig.T_right_from_left_mm) < 1e6


def _check_truth(truth):
    for R, t in truth.camera_poses.values():
        assert np.max(np.abs(R.T @ R - np.eye(3))) <= 1e-6 and np.all(np.isfinite(t))
    assert all(isinstance(f["left"], str) and isinstance(f["right"], str) for f in truth.files)


def _load_truth(folder: Path, loader):
    from workbench.experiments.bending.scenes import load_bending_truth
    from workbench.experiments.rigid_motion.scenes import load_truth

    return {"rigid": load_truth, "bending": load_bending_truth}[loader](folder)


LOADERS = {
    "calibration-json": (lambda: json_file(valid_calibration_json()), "calib.json", lambda p: load_calibration(p),
                         _check_rig),
    "opencv-yaml": (lambda: yaml_file(valid_opencv_yaml()), "calib.yaml", lambda p: load_opencv_yaml(p), _check_rig),
    "rigid-truth": (lambda: json_file(valid_rigid_truth_json()), "truth.json",
                    lambda p: _load_truth(p.parent, "rigid"), _check_truth),
    "bending-truth": (lambda: json_file(valid_bending_truth_json()), "truth.json",
                      lambda p: _load_truth(p.parent, "bending"), _check_truth),
}


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def _fuzz_one(name: str, folder: Path, data) -> None:
    make, filename, load, check = LOADERS[name]
    content = data.draw(make(), label="file content")
    path = folder / name / filename
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(content)
    try:
        result = load(path)
    except FileFormatError as err:
        assert str(path) in str(err) or str(path.parent) in str(err), f"the error does not name the file: {err}"
        return
    check(result)


@pytest.mark.parametrize("name", list(LOADERS))
@DEFAULT_SETTINGS
@given(data=st.data())
def test_loader_raises_only_its_own_error(workdir, name, data):
    _fuzz_one(name, workdir, data)


@pytest.mark.fuzz_long
@pytest.mark.parametrize("name", list(LOADERS))
@LONG_SETTINGS
@given(data=st.data())
def test_loader_raises_only_its_own_error_long(workdir, name, data):
    _fuzz_one(name, workdir, data)


@pytest.mark.parametrize("name", list(LOADERS))
def test_fuzzing_starts_from_files_that_load(workdir, name):
    """The mutation strategies start from valid files (else every mutation would be refused trivially)."""
    _, filename, load, check = LOADERS[name]
    text = {"calibration-json": valid_calibration_json, "opencv-yaml": valid_opencv_yaml,
            "rigid-truth": valid_rigid_truth_json, "bending-truth": valid_bending_truth_json}[name]()
    path = workdir / f"valid-{name}" / filename
    path.parent.mkdir(exist_ok=True)
    path.write_text(text)
    original = load(path)
    check(original)
    # and the YAML emitter of the structural mutations writes files the loader reads like the originals
    if name == "opencv-yaml":
        path.write_text(to_opencv_yaml(_read_opencv_yaml(text, path).value))
        emitted = load(path)
        assert (emitted.model, emitted.left, emitted.right) == (original.model, original.left, original.right)
        assert np.array_equal(emitted.R_right_from_left, original.R_right_from_left)
        assert np.array_equal(emitted.T_right_from_left_mm, original.T_right_from_left_mm)


# ------------------------------------------------------------------------------------------------------------
# truth.json: round trip and rejection of each kind of defect
# ------------------------------------------------------------------------------------------------------------
TRUTHS = {"rigid": (rigid_truth, valid_rigid_truth_json), "bending": (bending_truth_, valid_bending_truth_json)}


def _arrays_equal(a, b) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("kind", list(TRUTHS))
def test_truth_round_trip_gives_identical_truth(tmp_path, kind):
    truth_of, text_of = TRUTHS[kind]
    truth = truth_of()
    (tmp_path / "truth.json").write_text(text_of())
    loaded = _load_truth(tmp_path, kind)
    assert loaded.specimen == truth.specimen and loaded.specs == truth.specs
    for side in ("left", "right"):
        assert _arrays_equal(loaded.camera_poses[side], truth.camera_poses[side])
    assert loaded.files == truth.files
    assert json.loads(json.dumps(loaded.info)) == json.loads(json.dumps(truth.info))
    if kind == "rigid":
        assert np.array_equal(loaded.states_mm, truth.states_mm)
        assert np.array_equal(loaded.stage_direction_world, truth.stage_direction_world)
        assert all(_arrays_equal(a, b) for a, b in zip(loaded.poses, truth.poses, strict=True))
    else:
        assert loaded.beam == truth.beam and _arrays_equal(loaded.pose, truth.pose)
        assert np.array_equal(loaded.loads_N, truth.loads_N)
    px = np.array([[30.0, 20.0], [60.0, 50.0]])
    np.testing.assert_array_equal(loaded.points_of_interest(px)[1], truth.points_of_interest(px)[1])


def _edited(text: str, key: str, value=...) -> str:
    d = json.loads(text)
    *parents, last = key.split(".")
    node = d
    for k in parents:
        node = node[int(k)] if isinstance(node, list) else node[k]
    if value is ...:
        del node[int(last) if isinstance(node, list) else last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return json.dumps(d)


TRUTH_DEFECTS = [
    # (experiment, key, new value (... = removed), the message after "<file>: ")
    ("rigid", "specimen", ..., r"key 'specimen': required key is missing"),
    ("rigid", "specimen.texel_mm", ..., r"key 'specimen.texel_mm': required key is missing"),
    ("rigid", "specimen.speckle_mm", "0.2", r"key 'specimen.speckle_mm': must be a number, got a string"),
    ("rigid", "specimen.height_mm", 1e300, r"key 'specimen.height_mm': must be in \(0, 10000\)"),
    ("rigid", "specimen.colour", "red", r"key 'specimen': unknown key\(s\) 'colour'"),
    ("rigid", "specimen.type", "Plate", r"key 'specimen.type': must be one of 'BendingSpecimen'"),
    ("rigid", "specimen.speckle_mm", 0.001, r"key 'specimen': invalid BendingSpecimen: speckle_mm=0.001 is under 2"),
    ("rigid", "specimen.seed", 1.5, r"key 'specimen.seed': must be an integer"),
    ("rigid", "cameras.left", ..., r"key 'cameras.left': required key is missing"),
    ("rigid", "cameras.right.sensor_spec.fx", float("nan"), r"key 'cameras.right.sensor_spec.fx': must be a finite number"),
    ("rigid", "cameras.right.sensor_spec.width", 0, r"key 'cameras.right.sensor_spec.width': must be an integer in \[1, "),
    ("rigid", "cameras.left.sensor_spec.lens", "fisheye", r"key 'cameras.left.sensor_spec': invalid SensorSpec: lens must"),
    ("rigid", "cameras.left.R_cam_from_world", [[1, 0, 0], [0, 1, 0], [0, 0, -1]],
     r"key 'cameras.left.R_cam_from_world': must be a proper rotation"),
    ("rigid", "cameras.right.t_cam_from_world_mm", [1, 2], r"key 'cameras.right.t_cam_from_world_mm': must be a list of 3"),
    ("rigid", "stage_direction_world", [0, -2, 0], r"key 'stage_direction_world': its length must be in"),
    ("rigid", "states", [], r"key 'states': must be a list of at least 1 entries, got 0"),
    ("rigid", "states", None, r"key 'states': must be a list, got null"),
    ("rigid", "states.1.stage_mm", "1 mm", r"key 'states\[1\].stage_mm': must be a number, got a string"),
    ("rigid", "states.1.index", 7, r"key 'states\[1\].index': must be 1"),
    ("rigid", "states.2.R_world_from_specimen", [[1, 0, 0], [0, 1, 0], [0, 0, 1.1]],
     r"key 'states\[2\].R_world_from_specimen': must be a rotation matrix"),
    ("rigid", "states.0.files", None, r"key 'states\[0\].files': it must be a mapping .*got null"),
    ("rigid", "states.0.files.left", 3, r"key 'states\[0\].files.left': must be a string, got a number"),
    ("rigid", "states.0.files.right", "../../etc/passwd", r"key 'states\[0\].files.right': must be a file name inside"),
    ("rigid", "lens", ..., r"key 'lens': required key is missing"),
    ("rigid", "rig", [1], r"key 'rig': it must be a mapping"),
    ("bending", "beam", ..., r"key 'beam': required key is missing"),
    ("bending", "beam.poisson_ratio", 0.7, r"key 'beam.poisson_ratio': must be in \(-1, 0.5\)"),
    ("bending", "beam.span_mm", 200.0, r"key 'beam': invalid ThreePointBending: the support strips"),
    ("bending", "beam.element_mm", 1e-9, r"key 'beam.element_mm': must be in \(0.001, 10000\)"),
    ("bending", "R_world_from_specimen", "identity", r"key 'R_world_from_specimen': must be a list, got a string"),
    ("bending", "t_world_from_specimen_mm.2", math.inf, r"key 't_world_from_specimen_mm\[2\]': must be a finite number"),
    ("bending", "states.1.load_N", ..., r"key 'states\[1\].load_N': required key is missing"),
    ("bending", "states.1.load_N", True, r"key 'states\[1\].load_N': must be a number, got a boolean"),
    ("bending", "cameras.left.sensor_spec.focal_length_mm", -5.0,
     r"key 'cameras.left.sensor_spec.focal_length_mm': must be in \[0, 10000\)"),
]


@pytest.mark.parametrize("kind, key, value, message", TRUTH_DEFECTS,
                         ids=[f"{k}-{key}-{'removed' if v is ... else 'edited'}" for k, key, v, _ in TRUTH_DEFECTS])
def test_truth_defects_are_refused_naming_file_and_key(tmp_path, kind, key, value, message):
    (tmp_path / "truth.json").write_text(_edited(TRUTHS[kind][1](), key, value))
    with pytest.raises(FileFormatError, match=re.escape(str(tmp_path / "truth.json")) + ": " + message):
        _load_truth(tmp_path, kind)


@pytest.mark.parametrize("kind", list(TRUTHS))
@pytest.mark.parametrize("content, message", [
    ("[]", r"the file's top level must be a mapping .*got a list of 0"),
    ("null", r"the file's top level must be a mapping .*got null"),
    ("", r"truth file is empty"),
    ('{"specimen": ', r"is not valid JSON"),
])
def test_truth_files_that_are_not_a_json_object_are_refused(tmp_path, kind, content, message):
    (tmp_path / "truth.json").write_text(content)
    with pytest.raises(FileFormatError, match=re.escape(str(tmp_path / "truth.json")) + ": " + message):
        _load_truth(tmp_path, kind)


def test_missing_truth_is_still_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="no truth.json in"):
        _load_truth(tmp_path, "rigid")
    with pytest.raises(FileNotFoundError, match="no truth.json in"):
        _load_truth(tmp_path, "bending")


def test_calibration_error_is_a_value_error_for_the_cli():
    """The CLI prints one line for a ValueError; the loaders' error must be one (and keep file and key)."""
    err = FileFormatError("calib.yaml", "left_k1", "required key is missing")
    assert isinstance(err, ValueError)
    assert str(err) == "calib.yaml: key 'left_k1': required key is missing"
    assert (err.file, err.key) == ("calib.yaml", "left_k1")
    import pickle

    again = pickle.loads(pickle.dumps(err))
    assert str(again) == str(err) and type(again) is FileFormatError
    assert dataclasses.is_dataclass(CalibratedRig)
