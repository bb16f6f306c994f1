"""``workbench gate``: a fixed, quick accuracy suite whose figures fail a build when they get worse.

A gate file (TOML) names the instrument settings the suite measures with and a list of checks; each check
yields metrics, and each metric has an absolute threshold (``max`` or ``min``) and a relative tolerance
against a committed baseline (``rel_tol``, plus ``abs_tol`` for metrics whose baseline is near zero)::

    [gate]
    name = "my DIC code"
    baseline = "gates-baseline.json"        # relative to the gate file; --baseline overrides
    [instrument]                            # workbench.scenario.Instrument: subset_px, step_px, shape_order, ...
    subset_px = 33
    [[check]]
    name = "bias"
    kind = "dic2d_bias"                     # see CHECKS
    [check.metrics.max_abs_bias_px]
    max = 0.002
    rel_tol = 0.5

A metric fails when it is worse than its threshold, or worse than its baseline by more than
``rel_tol * |baseline| + abs_tol`` (worse = higher unless ``better = "higher"``). The run prints a table,
writes ``gate.md``, ``gate.json`` and JUnit XML (one test case per metric; a failure message with measured,
threshold and baseline) and exits non-zero on any failure. ``--update-baseline`` writes the measured values
as the new baseline instead of comparing (commit it when a change is meant to move a figure).

2-D checks run any engine through :mod:`workbench.engines` (``--engine``; default this project's instrument)
with the gate's settings: subset, step, shape-function order and interpolant (and the pre-filter when set) reach
the engine as keywords or template placeholders, and an engine that cannot take one is refused before anything
runs, naming it; every JUnit case lists the settings it ran with. Stereo checks (``rigid_motion``, ``calibration``) measure with this project's
stereo pipeline. Every check renders through the store, so a rerun only measures.
"""
from __future__ import annotations

import json
import math
import time
import tomllib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_text
from workbench.config import ConfigError, from_dict, with_value
from workbench.scenario import Instrument, Scenario

DEFAULT_ENGINE = "workbench.engines:ours"


class GateError(ValueError):
    """A gate file that cannot be run (the message names the file and the key)."""


@dataclass(frozen=True)
class MetricRule:
    name: str
    max: float | None = None
    min: float | None = None
    rel_tol: float | None = None
    abs_tol: float = 0.0
    better: str = "lower"


@dataclass(frozen=True)
class Check:
    name: str
    kind: str
    params: dict
    scenario: dict
    metrics: tuple


@dataclass(frozen=True)
class Gate:
    path: Path
    name: str
    baseline: Path | None
    instrument: Instrument
    checks: tuple = field(default_factory=tuple)


# ------------------------------------------------------------------------------------------------------------
# checks: each returns {metric: value}
# ------------------------------------------------------------------------------------------------------------
def _pair_dataset(scenario: Scenario, store):
    from workbench.scoring.datasets import open_dataset
    from workbench.experiments.dic2d import case as dic2d_case
    from workbench.scenario import dataset_parts

    key, content = dataset_parts(scenario)["images"]
    folder, _ = store.ensure(dic2d_case.KIND, key, content, lambda f: dic2d_case.render_dataset(scenario, f))
    return open_dataset(folder)


def _engine_result(engine, dataset, instrument: Instrument, workdir: Path, options: dict):
    from workbench.engines import run_engine
    from workbench.results import read_result
    from workbench.scoring.datasets import subset_roi_xyxy_px

    out = workdir / f"{dataset.folder.name}.csv"
    roi = subset_roi_xyxy_px(dataset, instrument.subset_px)
    run_engine(engine, dataset.images[0]["left"], dataset.images[1]["left"], out, subset_px=instrument.subset_px,
               step_px=instrument.step_px, roi_xyxy_px=roi, options=options)
    return read_result(out, engine.result_format or "native")


def _independent(x: np.ndarray, y: np.ndarray, subset_px: int) -> np.ndarray:
    """Points of a grid whose subsets do not overlap (every k-th column and row, k = ceil(subset / step))."""
    keep = np.ones(x.size, bool)
    for c in (x, y):
        values = np.unique(c)
        step = np.median(np.diff(values)) if values.size > 1 else subset_px
        stride = max(1, math.ceil(subset_px / step))
        keep &= np.isin(c, values[::stride])
    return keep


def check_dic2d_bias(check: Check, instrument: Instrument, engine, store, workdir: Path, options: dict) -> dict:
    """Bias of u vs sub-pixel shift on noise-free float pairs (Schreier 2000's interpolation bias curve)."""
    from workbench.scoring.metrics import score_state

    shifts = check.params.get("shifts_px", [0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    base = _scenario(check, {"experiment": "dic2d", "render.read_noise_grey": 0.0, "render.bit_depth": 0})
    biases, fractions = [], []
    for s in shifts:
        dataset = _pair_dataset(with_value(base, "image2d.shift_x_px", float(s)), store)
        m = score_state(dataset, 1, _engine_result(engine, dataset, instrument, workdir, options)).metrics
        biases.append(m["bias_u_px"])
        fractions.append(m["valid_fraction"])
    b = np.abs(np.array(biases))
    return {"max_abs_bias_px": float(b.max()), "rms_bias_px": float(np.sqrt(np.mean(b ** 2))),
            "valid_fraction": float(min(fractions))}


def check_dic2d_noise(check: Check, instrument: Instrument, engine, store, workdir: Path, options: dict) -> dict:
    """Random error of u on a noisy exactly shifted pair, and its ratio to Pan 2008's floor."""
    from measurement.image_io import read_grey
    from workbench.experiments.dic2d.case import image_noise_sigma_grey, pan_floor_px
    from workbench.scoring.metrics import score_state

    scenario = _scenario(check, {"experiment": "dic2d", "render.read_noise_grey": 2.0, "render.bit_depth": 0})
    dataset = _pair_dataset(scenario, store)
    result = _engine_result(engine, dataset, instrument, workdir, options)
    score = score_state(dataset, 1, result)
    sel = _independent(result.x_px, result.y_px, instrument.subset_px) & np.isfinite(score.error_uv_px[:, 0])
    random = float(np.std(score.error_uv_px[sel, 0]))
    clean = read_grey(dataset.folder / "clean_reference.tif")
    xs, ys = np.rint(result.x_px[sel]).astype(int), np.rint(result.y_px[sel]).astype(int)
    floor = float(np.sqrt(np.mean(pan_floor_px(clean, xs, ys, instrument.subset_px,
                                               image_noise_sigma_grey(scenario, clean)) ** 2)))
    return {"random_error_px": random, "ratio_to_pan_floor": random / floor, "pan_floor_px": floor,
            "abs_bias_px": abs(score.metrics["bias_u_px"]), "valid_fraction": score.metrics["valid_fraction"]}


def check_rigid_motion(check: Check, instrument: Instrument, engine, store, workdir: Path, options: dict) -> dict:
    """The paper's rigid-motion test at reduced scale: calibrate from rendered boards, measure, score."""
    from workbench.experiments.rigid_motion import case as rigid_motion_case

    scenario = _scenario(check, {"experiment": "rigid_motion", "motion.max_mm": 1.0, "motion.step_mm": 1.0,
                                 "target.calibration_views": 20, "render.spp": 16})
    rigid_motion_case.check(scenario, instrument)
    out = rigid_motion_case.run(scenario, instrument, store)["metrics"]
    last = -1
    return {"abs_mean_error_um": abs(out["mean_error_um"][last]), "std_um": out["std_um"][last],
            "abs_mean_error_truth_um": abs(out["mean_error_truth_um"][last]),
            "reference_rms_um": out["reference_rms_um"], "points_fraction": out["points_fraction"][last],
            "calibration_rms_px": out["calibration_rms_px"]}


def check_calibration(check: Check, instrument: Instrument, engine, store, workdir: Path, options: dict) -> dict:
    """Stepwise calibration from rendered boards: reprojection RMS and the error of the stereo baseline length.

    Not the cameras' projections against the true ones: with planar targets the tilt trades against the
    principal point and the camera frame's orientation (DESIGN §3), so a good calibration may project a
    fixed camera-frame point 100 px elsewhere; 3-D accuracy is judged by the rigid-motion check.
    """
    from workbench.experiments.rigid_motion import case as rigid_motion_case
    from workbench.rigs import get_rig
    from workbench.scenario import dataset_parts

    scenario = _scenario(check, {"experiment": "rigid_motion", "target.calibration_views": 20, "render.spp": 16})
    inst = with_value(instrument, "calibration", "rendered")
    key, content = dataset_parts(scenario)["calibration"]
    views, _ = store.ensure("checkerboard", key, content,
                            lambda f: rigid_motion_case.render_calibration_views(scenario, f))
    rig, rms = rigid_motion_case.calibrate(scenario, inst, views, store)
    true = get_rig(scenario.rig.name, scenario.rig.scale)
    length_error_mm = float(np.linalg.norm(rig.T_right_from_left_mm) - np.linalg.norm(true.T_right_from_left_mm))
    return {"reprojection_rms_px": rms, "baseline_length_error_um": abs(length_error_mm) * 1e3}


def check_star(check: Check, instrument: Instrument, engine, store, workdir: Path, options: dict) -> dict:
    """DIC Challenge 2.0 Star at reduced size: spatial resolution l10 (vs the subset's theory), noise floor, MEI."""
    from scenes.image_pairs.star import star_images
    from workbench.engines import array_engine
    from workbench.experiments.dic2d.star import run_star

    rows, cols = check.params.get("shape", [251, 2000])
    step = int(check.params.get("step_px", 3))
    images = star_images((int(rows), int(cols)), seed=int(check.params.get("seed", 0)))
    m = run_star(instrument.subset_px, instrument.shape_order, images=images, step_px=step,
                 engine=array_engine(engine, workdir, options))
    return {k: float(m[k]) for k in ("l10_px", "l10_theory_px", "noise_floor_px", "mei_px2")
            if k in m} | {"l10_over_theory": float(m["l10_px"] / m["l10_theory_px"])}


CHECKS = {"dic2d_bias": check_dic2d_bias, "dic2d_noise": check_dic2d_noise, "rigid_motion": check_rigid_motion,
          "calibration": check_calibration, "star": check_star}
#: Checks that run the --engine (the others use this project's stereo pipeline).
ENGINE_CHECKS = ("dic2d_bias", "dic2d_noise", "star")


def _scenario(check: Check, defaults: dict) -> Scenario:
    """The check's scenario: its defaults, then the gate file's ``[check.scenario]`` values (dotted keys)."""
    scenario = Scenario()
    for path, value in {**defaults, **check.scenario}.items():
        scenario = with_value(scenario, path, value, where=f"check {check.name!r}: scenario")
    return scenario


# ------------------------------------------------------------------------------------------------------------
# gate file
# ------------------------------------------------------------------------------------------------------------
def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def load_gate(path: str | Path) -> Gate:
    """Parse and check a gate file; every problem is a :class:`GateError` naming the file and the key."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise GateError(f"gate file not found: {path}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise GateError(f"{path}: not valid TOML: {err}") from None
    unknown = set(doc) - {"gate", "instrument", "check"}
    if unknown:
        raise GateError(f"{path}: unknown table(s) {', '.join(sorted(unknown))} (gate, instrument, check)")
    head = doc.get("gate", {})
    bad = set(head) - {"name", "baseline", "description"}
    if bad:
        raise GateError(f"{path}: gate.{sorted(bad)[0]}: unknown key (name, baseline, description)")
    try:
        instrument = from_dict(Instrument, doc.get("instrument", {}), "instrument")
    except ConfigError as err:
        raise GateError(f"{path}: {err}") from None
    checks, names = [], set()
    raw_checks = doc.get("check", [])
    if not isinstance(raw_checks, list) or not raw_checks:
        raise GateError(f"{path}: no [[check]] tables")
    for i, c in enumerate(raw_checks):
        where = f"{path}: check[{i}]"
        extra = set(c) - {"name", "kind", "params", "scenario", "metrics"}
        if extra:
            raise GateError(f"{where}.{sorted(extra)[0]}: unknown key (name, kind, params, scenario, metrics)")
        name, kind = c.get("name"), c.get("kind")
        if not isinstance(name, str) or not name:
            raise GateError(f"{where}.name: missing or not a string")
        if name in names:
            raise GateError(f"{where}.name: {name!r} is used twice")
        names.add(name)
        if kind not in CHECKS:
            raise GateError(f"{where}.kind: {kind!r} is not one of {', '.join(CHECKS)}")
        scenario = _flatten(c.get("scenario", {}))
        try:
            s = Scenario()
            for key, value in scenario.items():
                s = with_value(s, key, value, where=f"check {name!r}: scenario")
        except ConfigError as err:
            raise GateError(f"{path}: {err}") from None
        rules = []
        metrics = c.get("metrics", {})
        if not metrics:
            raise GateError(f"{where}.metrics: a check needs at least one metric rule")
        for mname, rule in metrics.items():
            mwhere = f"{where}.metrics.{mname}"
            if not isinstance(rule, dict):
                raise GateError(f"{mwhere}: a table of max/min/rel_tol/abs_tol/better")
            extra = set(rule) - {"max", "min", "rel_tol", "abs_tol", "better"}
            if extra:
                raise GateError(f"{mwhere}.{sorted(extra)[0]}: unknown key (max, min, rel_tol, abs_tol, better)")
            for k in ("max", "min", "rel_tol", "abs_tol"):
                if k in rule and (isinstance(rule[k], bool) or not isinstance(rule[k], (int, float))
                                  or not math.isfinite(rule[k])):
                    raise GateError(f"{mwhere}.{k}: {rule[k]!r} is not a finite number")
            if rule.get("better", "lower") not in ("lower", "higher"):
                raise GateError(f"{mwhere}.better: {rule['better']!r} is not 'lower' or 'higher'")
            if "max" not in rule and "min" not in rule and "rel_tol" not in rule:
                raise GateError(f"{mwhere}: give a threshold (max or min) or a baseline tolerance (rel_tol)")
            rules.append(MetricRule(mname, rule.get("max"), rule.get("min"), rule.get("rel_tol"),
                                    float(rule.get("abs_tol", 0.0)), rule.get("better", "lower")))
        checks.append(Check(name, kind, dict(c.get("params", {})), scenario, tuple(rules)))
    baseline = head.get("baseline")
    return Gate(path, head.get("name", path.stem), (path.parent / baseline) if baseline else None, instrument,
                tuple(checks))


# ------------------------------------------------------------------------------------------------------------
# verdicts
# ------------------------------------------------------------------------------------------------------------
def verdict(rule: MetricRule, value: float | None, baseline: float | None) -> tuple[bool, str]:
    """(passed, message) of one metric against its threshold and baseline."""
    if value is None or not math.isfinite(value):
        return False, f"measured {value!r}: the check did not produce this metric"
    problems = []
    if rule.max is not None and value > rule.max:
        problems.append(f"measured {value:.6g} > threshold {rule.max:.6g}")
    if rule.min is not None and value < rule.min:
        problems.append(f"measured {value:.6g} < threshold {rule.min:.6g}")
    if rule.rel_tol is not None and baseline is not None and math.isfinite(baseline):
        allowed = rule.rel_tol * abs(baseline) + rule.abs_tol
        worse = value - baseline if rule.better == "lower" else baseline - value
        if worse > allowed:
            problems.append(f"measured {value:.6g} is worse than the baseline {baseline:.6g} by {worse:.3g} "
                            f"(allowed {allowed:.3g}: rel_tol {rule.rel_tol:g}, abs_tol {rule.abs_tol:g})")
    if problems:
        return False, "; ".join(problems)
    ref = f", baseline {baseline:.6g}" if baseline is not None else ""
    return True, f"measured {value:.6g}{ref}"


#: The project's packages whose code, when it ran during a gate, decides the gate's figures ...
FINGERPRINT_PACKAGES = ("scenes", "measurement", "labio", "workbench")
#: ... but for the rooms that only parse options, write reports or run other commands (loaded with the CLI).
NOT_FINGERPRINTED = ("workbench.cli", "workbench.__main__", "workbench.commands", "workbench.reporting",
                     "workbench.twin", "workbench.studies")
#: Versions a baseline is compared on: a difference is said (it may move a figure), never failed.
COMPARED_VERSIONS = ("python", "numpy", "scipy", "numba", "mitsuba", "drjit", "machine")


def _project_root() -> Path:
    return Path(__file__).resolve().parents[2]


def _file_sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def source_fingerprint(gate_path: Path | None = None) -> dict:
    """What the figures just measured were measured with: ``{"commit", "dirty", "sources"}``.

    ``sources`` maps every module of the project loaded in this process (the code that ran the checks), and the
    gate file itself, to its SHA-256: a baseline whose sources still hash the same was measured by this code.
    ``commit`` is git's HEAD where the checkout has one (for a reader; the hashes decide).
    """
    import subprocess
    import sys

    root = _project_root()
    files = set()
    for name, module in list(sys.modules.items()):
        path = getattr(module, "__file__", None)
        if path and name.split(".")[0] in FINGERPRINT_PACKAGES and not any(
                name == n or name.startswith(n + ".") for n in NOT_FINGERPRINTED):
            resolved_path = Path(path).resolve()
            if resolved_path.is_relative_to(root) and resolved_path.suffix == ".py":
                files.add(resolved_path)
    if gate_path is not None and Path(gate_path).resolve().is_relative_to(root):
        files.add(Path(gate_path).resolve())
    sources = {p.relative_to(root).as_posix(): _file_sha256(p) for p in sorted(files)}
    commit, dirty = None, None
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                                timeout=10, check=True).stdout.strip() or None
        dirty = bool(subprocess.run(["git", "status", "--porcelain", "--", *sources], cwd=root, capture_output=True,
                                    text=True, timeout=10, check=True).stdout.strip())
    except (OSError, subprocess.SubprocessError):
        pass
    return {"commit": commit, "dirty": dirty, "sources": sources}


def baseline_staleness(baseline_doc: dict, engine_spec: str) -> dict:
    """Whether a baseline was measured by this checkout's code: ``{"stale": bool, "reasons": [...],
    "notes": [...]}``.

    Stale (a reason each): the baseline records no sources (written before they were recorded), a recorded source
    file that now hashes otherwise or is gone, another engine. Notes: package versions that differ (a figure may
    move with them; the code is what a baseline is pinned to).
    """
    reasons, notes = [], []
    recorded = baseline_doc.get("measured_with")
    if baseline_doc.get("engine") not in (None, engine_spec):
        reasons.append(f"it was measured with the engine {baseline_doc.get('engine')}, this run uses {engine_spec}")
    if not isinstance(recorded, dict) or not isinstance(recorded.get("sources"), dict):
        reasons.append("it records no source fingerprint (written by an older workbench), so nothing says which "
                       "code measured it")
    else:
        root = _project_root()
        changed = []
        for rel, digest in recorded["sources"].items():
            path = root / rel
            if not path.is_file():
                changed.append(f"{rel} (gone)")
            elif _file_sha256(path) != digest:
                changed.append(rel)
        if changed:
            shown = ", ".join(changed[:5]) + (f" and {len(changed) - 5} more" if len(changed) > 5 else "")
            commit = recorded.get("commit")
            reasons.append(f"{len(changed)} of the {len(recorded['sources'])} source files that measured it changed "
                           f"since{f' commit {commit[:10]}' if commit else ''}: {shown}")
    from workbench.studies.sweep import environment_versions

    now = environment_versions()
    then = baseline_doc.get("versions", {}) or {}
    for key in COMPARED_VERSIONS:
        if key in then and then.get(key) != now.get(key):
            notes.append(f"{key} {then.get(key)} when the baseline was measured, {now.get(key)} now")
    return {"stale": bool(reasons), "reasons": reasons, "notes": notes}


def run_gate(gate: Gate, out: Path, engine_spec: str | None = None, baseline_path: Path | None = None,
             store=None, update_baseline: bool = False, log=print, require_current_baseline: bool = False) -> dict:
    """Run every check, judge every metric; returns the record written to ``gate.json``.

    The baseline's staleness (:func:`baseline_staleness`) is said in the log and the record
    (``baseline_status``); with ``require_current_baseline`` a stale baseline fails the gate.
    """
    from workbench.engines import check_settings, instrument_settings, parse_engine
    from workbench.store import DatasetStore

    store = store if isinstance(store, DatasetStore) else DatasetStore(store)
    engine = parse_engine(engine_spec or DEFAULT_ENGINE)
    inst = gate.instrument
    # Every setting the gate judges reaches the engine, or the engine is refused before anything runs.
    options = instrument_settings(inst.shape_order, inst.interpolation, inst.prefilter_sigma_px)
    if any(c.kind in ENGINE_CHECKS for c in gate.checks):
        try:
            check_settings(engine, options, who=f"the gate {gate.path.name}")
        except ValueError as err:
            raise GateError(str(err)) from None
    ran_with = {"engine": engine.spec, "subset_px": inst.subset_px, "step_px": inst.step_px, **options}
    baseline_path = baseline_path or gate.baseline
    baseline, status = {}, None
    if baseline_path is not None and baseline_path.is_file() and not update_baseline:
        try:
            baseline_doc = json.loads(baseline_path.read_text())
            baseline = baseline_doc["metrics"]
        except (json.JSONDecodeError, KeyError, TypeError) as err:
            raise GateError(f"{baseline_path}: not a gate baseline ({err})") from None
        status = baseline_staleness(baseline_doc, engine.spec) | {"file": str(baseline_path)}
    elif baseline_path is not None and not update_baseline:
        log(f"no baseline {baseline_path}: thresholds only (write one with --update-baseline)")
    out.mkdir(parents=True, exist_ok=True)
    workdir = out / "engine"
    workdir.mkdir(exist_ok=True)
    rows, timings = [], {}
    for check in gate.checks:
        start = time.perf_counter()
        log(f"check {check.name} ({check.kind}) ...")
        try:
            values = CHECKS[check.kind](check, inst, engine, store, workdir, options)
            error = None
        except (ValueError, RuntimeError, OSError) as err:
            values, error = {}, f"{type(err).__name__}: {err}"
        timings[check.name] = round(time.perf_counter() - start, 2)
        for rule in check.metrics:
            key = f"{check.name}.{rule.name}"
            value = values.get(rule.name)
            if error is not None:
                passed, message = False, f"the check failed: {error}"
            elif update_baseline:
                passed, message = verdict(MetricRule(rule.name, rule.max, rule.min), value, None)
            else:
                passed, message = verdict(rule, value, baseline.get(key))
            rows.append({"check": check.name, "metric": rule.name, "value": value, "baseline": baseline.get(key),
                         "max": rule.max, "min": rule.min, "rel_tol": rule.rel_tol, "passed": passed,
                         "message": message, "seconds": timings[check.name], "settings": _ran_with(check, inst,
                                                                                                   ran_with)})
        log(f"  {timings[check.name]:.1f} s: " + ", ".join(f"{k} {v:.4g}" for k, v in values.items()
                                                          if isinstance(v, float)) if values else f"  {error}")
    if status is not None:
        for line in status_lines(status, require_current_baseline):
            log(line)
    record = {"gate": gate.name, "file": str(gate.path), "engine": engine.spec,
              "instrument": {k: getattr(inst, k) for k in inst.__dataclass_fields__},
              "passed": all(r["passed"] for r in rows) and not (require_current_baseline and status is not None
                                                                 and status["stale"]),
              "metrics": rows, "timings_s": timings, "total_s": round(sum(timings.values()), 2),
              "baseline_status": status, "require_current_baseline": require_current_baseline}
    atomic_write_text(out / "gate.json", json.dumps(record, indent=1))
    if update_baseline:
        if baseline_path is None:
            raise GateError(f"{gate.path}: --update-baseline needs gate.baseline or --baseline")
        from workbench.studies.sweep import environment_versions

        atomic_write_text(baseline_path, json.dumps(
            {"about": f"baseline of {gate.path.name}, written by workbench gate --update-baseline",
             "engine": engine.spec, "versions": environment_versions(),
             "measured_with": source_fingerprint(gate.path),
             "metrics": {f"{r['check']}.{r['metric']}": r["value"] for r in rows}}, indent=1))
        log(f"wrote the baseline {baseline_path}")
    return record


def _ran_with(check: Check, inst: Instrument, engine_settings: dict) -> dict:
    """The settings a check measured with: the engine and its settings for the 2-D checks, this project's
    stereo pipeline and the whole instrument for the others."""
    if check.kind == "star":
        return {**engine_settings, "step_px": int(check.params.get("step_px", 3))}
    if check.kind in ENGINE_CHECKS:
        return dict(engine_settings)
    return {"engine": "this project's stereo pipeline", **{k: getattr(inst, k) for k in inst.__dataclass_fields__}}


def status_lines(status: dict, required: bool = False) -> list[str]:
    """The baseline's staleness in words (empty reasons: current)."""
    if not status["stale"]:
        lines = [f"baseline {status['file']} is current: measured by this checkout's code"]
    else:
        lines = [f"baseline {status['file']} is STALE{' (the gate fails: --require-current-baseline)' if required else ''}"
                 f": {'; '.join(status['reasons'])}. Its figures are not what this checkout measures; measure them "
                 "again with `workbench gate GATE_FILE --update-baseline --out DIR` and commit the baseline"]
    return lines + [f"note: {n}" for n in status["notes"]]


def _settings_text(settings: dict) -> str:
    return ", ".join(f"{k} = {v}" for k, v in settings.items())


def table_lines(record: dict) -> list[str]:
    """The verdicts as a Markdown table."""
    fmt = lambda v: "" if v is None else (f"{v:.4g}" if isinstance(v, float) else str(v))  # noqa: E731
    lines = ["| check | metric | measured | baseline | threshold | verdict |", "|---|---|---|---|---|---|"]
    for r in record["metrics"]:
        thr = " ".join(filter(None, (f"≤ {fmt(r['max'])}" if r["max"] is not None else "",
                                     f"≥ {fmt(r['min'])}" if r["min"] is not None else "")))
        lines.append(f"| {r['check']} | {r['metric']} | {fmt(r['value'])} | {fmt(r['baseline'])} | {thr} | "
                     f"{'pass' if r['passed'] else 'FAIL: ' + r['message']} |")
    return lines


def write_junit(record: dict, path: Path) -> None:
    """JUnit XML: one test case per metric (classname = check), a <failure> with the verdict's message."""
    failures = sum(not r["passed"] for r in record["metrics"])
    suite = ET.Element("testsuite", name=f"workbench gate: {record['gate']}", tests=str(len(record["metrics"])),
                       failures=str(failures), errors="0", time=f"{record['total_s']:.2f}")
    for r in record["metrics"]:
        case = ET.SubElement(suite, "testcase", classname=f"gate.{r['check']}", name=r["metric"],
                             time=f"{r['seconds']:.2f}")
        settings = r.get("settings", {})
        # the settings the case ran with, as JUnit properties (shown by CI test reports) and in its text
        props = ET.SubElement(case, "properties")
        for k, v in settings.items():
            ET.SubElement(props, "property", name=k, value=str(v))
        ran = f" (ran with {_settings_text(settings)})" if settings else ""
        if not r["passed"]:
            ET.SubElement(case, "failure", message=r["message"] + ran, type="AccuracyRegression").text = (
                f"{r['check']}.{r['metric']}: {r['message']}{ran}")
        else:
            ET.SubElement(case, "system-out").text = r["message"] + ran
    status = record.get("baseline_status")
    if status is not None:                 # the baseline's own case: current, or stale (a failure only when required)
        case = ET.SubElement(suite, "testcase", classname="gate.baseline", name="current", time="0")
        text = "\n".join(status_lines(status, record.get("require_current_baseline", False)))
        if status["stale"] and record.get("require_current_baseline"):
            ET.SubElement(case, "failure", message=text.splitlines()[0], type="StaleBaseline").text = text
            suite.set("failures", str(failures + 1))
        else:
            ET.SubElement(case, "system-out").text = text
        suite.set("tests", str(len(record["metrics"]) + 1))
    ET.indent(suite)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, ET.tostring(suite, encoding="unicode", xml_declaration=True) + "\n")


def gate_command(args) -> int:
    gate = load_gate(args.gate_file)
    record = run_gate(gate, args.out, args.engine, args.baseline, args.store, args.update_baseline,
                      require_current_baseline=args.require_current_baseline)
    lines = table_lines(record)
    status = record["baseline_status"]
    summary = [f"# Accuracy gate: {record['gate']}", "", f"Engine: `{record['engine']}`; instrument: "
               + ", ".join(f"{k} = {v}" for k, v in record["instrument"].items()) + ".", "",
               *lines, "", *([f"- {line}" for line in status_lines(status, record["require_current_baseline"])] + [""]
                            if status is not None else []),
               f"{'PASSED' if record['passed'] else 'FAILED'} in {record['total_s']:.1f} s "
               f"({', '.join(f'{k} {v:.1f} s' for k, v in record['timings_s'].items())})."]
    atomic_write_text(args.out / "gate.md", "\n".join(summary) + "\n")
    from workbench.reporting.html_report import write_html_report

    write_html_report(args.out / "report.html", f"Accuracy gate: {record['gate']}", "\n".join(summary) + "\n",
                      args.out)
    if args.junit is not None:
        write_junit(record, args.junit)
    print("\n".join(lines))
    n_fail = sum(not r["passed"] for r in record["metrics"])
    verdict_text = "passed" if record["passed"] else (f"FAILED ({n_fail} of {len(record['metrics'])} metrics)"
                                                      if n_fail else "FAILED (the baseline is stale)")
    print(f"gate {verdict_text} in {record['total_s']:.1f} s; wrote {args.out / 'gate.md'}, report.html"
          + (f" and {args.junit}" if args.junit else ""))
    return 0 if record["passed"] or args.update_baseline else 1
