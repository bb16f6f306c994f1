"""``workbench reproduce paper``: the paper's four experiments in one run, one report.

Stages, each its own command too: the stepwise calibration (Table 1, Fig 5 plane fit) of the paper rig, the
rigid-motion test (Fig 6) measured with that calibration, the three-point bending test (Figs 7-8, the
Scheimpflug rig calibrated from its own rendered boards) and the depth-of-field comparison (Fig 4, MIG). Speckle
renders are adaptive (:mod:`scenes.rendering.adaptive`, one Monte-Carlo noise target), board views exact where possible
(:mod:`scenes.rendering.exact`); all go through the one render store, so an identical scenario is never rendered
twice.

Resume: a stage is complete when ``<out>/<stage>/stage.json`` exists for the same settings; it is written last,
atomically, after the stage's own files (which are atomic too). Interrupted (Ctrl-C) and run again, the command
skips complete stages and repeats only the interrupted one, reusing whatever renders the store completed.

The report: ``report.md`` and a self-contained ``report.html`` (figures embedded): a summary of every goal
figure with pass/fail, each experiment's own report beside the paper's figures and the truth, the iDICs Good
Practices tables of each experiment, the settings, software versions, machine and timings.
"""
from __future__ import annotations

import json
import re
import time
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path


from labio.atomic import atomic_write_text
from workbench.reporting import experiment_idics, idics

#: Stages in run order: (folder, title, share of the run's time at full resolution, for the estimate).
STAGES = (("calibration", "Calibration (Table 1, Fig 5)", 0.35),
          ("rigid_motion", "Rigid-motion test (Fig 6)", 0.25),
          ("bending", "Three-point bending test (Figs 7-8)", 0.32),
          ("depth_of_field", "Depth of field (Fig 4, MIG)", 0.08))

#: Default Monte-Carlo noise target of the renders, grey levels: its variance is under 10 % of the 1-grey read
#: noise's, about what a fixed 64 spp gave at full resolution (0.3-0.4 grey RMS).
MC_TARGET_GREY = 0.3
#: ``--quick``'s target: its variance is a quarter of the read noise's.
QUICK_MC_TARGET_GREY = 0.5


@dataclass(frozen=True)
class PaperSettings:
    """What a ``reproduce paper`` run does; its hash decides which stages a rerun can keep."""

    scale: float = 1.0
    dof_scale: float = 1.0
    seed: int = 0
    mc_target_grey: float = MC_TARGET_GREY
    calibration_views: int = 30
    validation_views: int = 20
    quick: bool = False
    #: the lens' aperture of the speckle renders, for its diffraction (None: ideal optics)
    f_number: float | None = 8.0

    @classmethod
    def for_mode(cls, quick: bool, scale: float | None = None, mc_target_grey: float | None = None,
                 seed: int = 0, ideal_optics: bool = False) -> "PaperSettings":
        """Full resolution, or ``quick``: quarter scale (16x fewer pixels) and renders at 0.5 grey Monte-Carlo
        noise instead of 0.3, the paper's protocol otherwise (with 15 + 10 board views instead of 30 + 20 the
        stepwise calibration's tilt and principal point drift by many sigma: the views are kept). The speckle
        states are recorded through the diffraction of an f/8 lens, or ``ideal_optics``."""
        s = scale if scale is not None else (0.25 if quick else 1.0)
        if not 0 < s <= 1:
            raise ValueError(f"--scale must be in (0, 1], got {s}")
        target = mc_target_grey if mc_target_grey is not None else (QUICK_MC_TARGET_GREY if quick else MC_TARGET_GREY)
        return cls(scale=s, dof_scale=s, seed=seed, quick=quick, mc_target_grey=float(target),
                   f_number=None if ideal_optics else 8.0)

    def stage_settings(self, stage: str) -> dict:
        return {"stage": stage, **asdict(self)}


def _hash(d: dict) -> str:
    from workbench.config import hash_of

    return hash_of(d)


def _clock(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    return f"{m // 60}:{m % 60:02d}:{s:02d}" if m >= 60 else f"{m}:{s:02d}"


def stage_done(out_dir: Path, stage: str, settings: PaperSettings) -> dict | None:
    """The completion record of ``stage`` if it was finished with these settings, else None."""
    path = out_dir / stage / "stage.json"
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if record.get("settings_hash") != _hash(settings.stage_settings(stage)):
        return None
    if not (out_dir / stage / "metrics.json").is_file():
        return None
    return record


def _run_stage(stage: str, folder: Path, s: PaperSettings, store, progress: bool) -> dict:
    if stage == "calibration":
        from workbench.experiments.calibration.run import reproduce_calibration
        return reproduce_calibration(folder, scale=s.scale, seed=s.seed, n_calibration=s.calibration_views,
                                     n_validation=s.validation_views, refine_corners=s.scale >= 0.75,
                                     progress=progress, store=store, mc_target_grey=s.mc_target_grey)
    if stage == "rigid_motion":
        from workbench.experiments.rigid_motion.run import reproduce_rigid_motion
        calib = folder.parent / "calibration" / "calibration.json"       # the paper rig's, from stage 1
        return reproduce_rigid_motion(folder, scale=s.scale, calib=str(calib), seed=s.seed, progress=progress,
                                      store=store, mc_target_grey=s.mc_target_grey, f_number=s.f_number)
    if stage == "bending":
        from workbench.experiments.bending.run import reproduce_bending
        return reproduce_bending(folder, scale=s.scale, calib="rendered", seed=s.seed, progress=progress,
                                 store=store, mc_target_grey=s.mc_target_grey,
                                 calibration_views=(s.calibration_views, s.validation_views), f_number=s.f_number)
    if stage == "depth_of_field":
        from workbench.experiments.depth_of_field.run import reproduce_depth_of_field
        return reproduce_depth_of_field(folder, scale=s.dof_scale, seed=s.seed, mc_target_grey=s.mc_target_grey)
    raise ValueError(f"unknown stage {stage!r}")


def reproduce_paper(out_dir: str | Path, settings: PaperSettings, *, store=None, progress: bool = True,
                    log=print) -> dict:
    """Run every stage that is not complete, then write ``report.md`` and ``report.html``. Returns the summary."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    timings = {}
    warm = _warm_dic_kernels_beside(out_dir, settings)
    try:
        _run_stages(out_dir, settings, store, progress, log, start, timings)
    finally:
        if warm is not None and warm.poll() is None:
            warm.kill()
            warm.wait()
    total = time.perf_counter() - start
    summary = write_paper_report(out_dir, settings, timings, total)
    failed = [g for g in summary["goals"] if g["met"] is False]
    log(f"{len(summary['goals']) - len(failed)} of {len(summary['goals'])} goal figures met"
        + ("" if not failed else "; not met: " + ", ".join(f"{g['experiment']}: {g['figure']}" for g in failed)))
    log(f"report: {out_dir / 'report.html'} and {out_dir / 'report.md'} (this run {_clock(total)})")
    return summary


def _warm_dic_kernels_beside(out_dir: Path, settings: PaperSettings):
    """Compile the DIC kernels and the speckle renderer's quadrature kernel in a separate process while the
    calibration stage (which uses neither) runs, so a first run on a fresh install finds numba's disk cache filled
    when the rigid-motion stage needs them (~30 s + ~4 s on 2 cores). None when the calibration stage is already
    complete (nothing to overlap with)."""
    import subprocess
    import sys

    if stage_done(out_dir, "calibration", settings) is not None:
        return None
    code = ("import runpy; runpy.run_module('measurement.dic.warm', run_name='__main__'); "
            "runpy.run_module('scenes.rendering.quadrature_raster', run_name='__main__')")
    try:
        return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        return None


def _run_stages(out_dir: Path, settings: PaperSettings, store, progress: bool, log, start: float,
                timings: dict) -> None:
    """Every stage that is not complete, in order; ``timings`` gets each stage's seconds."""
    done_share, run_seconds = 0.0, 0.0
    for k, (stage, title, share) in enumerate(STAGES, 1):
        record = stage_done(out_dir, stage, settings)
        if record is not None:
            timings[stage] = {"seconds": record["seconds"], "this_run": "kept (complete from an earlier run)"}
            log(f"[{k}/{len(STAGES)}] {title}: complete from an earlier run ({_clock(record['seconds'])}), kept")
            continue
        elapsed = time.perf_counter() - start
        left = sum(sh for st, _, sh in STAGES[k - 1:] if stage_done(out_dir, st, settings) is None)
        estimate = f", about {_clock(run_seconds / done_share * left)} left" if done_share > 0 else ""
        log(f"[{k}/{len(STAGES)}] {title}: running (elapsed {_clock(elapsed)}{estimate})")
        t0 = time.perf_counter()
        _run_stage(stage, out_dir / stage, settings, store, progress)
        seconds = time.perf_counter() - t0
        run_seconds += seconds
        done_share += share
        timings[stage] = {"seconds": seconds, "this_run": "ran"}
        atomic_write_text(out_dir / stage / "stage.json", json.dumps({
            "stage": stage, "settings": settings.stage_settings(stage),
            "settings_hash": _hash(settings.stage_settings(stage)), "seconds": seconds,
            "finished_utc": datetime.now(timezone.utc).isoformat(timespec="seconds")}, indent=1))
        log(f"[{k}/{len(STAGES)}] {title}: done in {_clock(seconds)}")


def _board_render_text(out_dir: Path) -> str:
    """Which renderer made the board views of the run's calibrations (from their metrics)."""
    counts: dict[str, int] = {}
    for path in (out_dir / "calibration" / "metrics.json", out_dir / "bending" / "calibration" / "metrics.json"):
        try:
            renderers = json.loads(path.read_text()).get("renderers") or {}
        except (OSError, ValueError):
            continue
        for name, n in renderers.items():
            counts[name] = counts.get(name, 0) + int(n)
    if not counts:
        return "as each stage's report says"
    names = {"exact-polygon": "exact box-filtered polygons (scenes.rendering.exact, no Monte Carlo)",
             "mitsuba": "Mitsuba at fixed spp", "mitsuba-adaptive": "Mitsuba adaptive"}
    return "; ".join(f"{names.get(k, k)}: {v} images" for k, v in sorted(counts.items()))


def _optics_text(settings: PaperSettings) -> str:
    """The lens' diffraction the speckle states were recorded through (scenes.optics.mtf), at full-scale pixels."""
    if settings.f_number is None:
        return "ideal (no diffraction: --ideal-optics)"
    from scenes.optics.mtf import airy_radius_px
    from workbench.rigs import DEFAULT_PIXEL_PITCH_MM

    pitch = DEFAULT_PIXEL_PITCH_MM / settings.scale
    return (f"the lens' diffraction at f/{settings.f_number:g}, 550 nm, {1e3 * pitch:.2f} µm pixels: Airy radius "
            f"{airy_radius_px(settings.f_number, 550.0, pitch):.2f} px (scenes.optics.mtf)")


def _speckle_render_text(out_dir: Path, settings: PaperSettings) -> str:
    """Which renderer made the speckle states of the run (from the rigid-motion and bending metrics)."""
    counts: dict[str, int] = {}
    for stage in ("rigid_motion", "bending"):
        for name, n in ((_metrics(out_dir, stage) or {}).get("speckle_renderers") or {}).items():
            counts[name] = counts.get(name, 0) + int(n)
    adaptive = (f"adaptive, Monte-Carlo noise target {settings.mc_target_grey:g} grey RMS (scenes.rendering.adaptive)")
    if not counts:
        return adaptive
    names = {**experiment_idics.SPECKLE_RENDERER_TEXT, "mitsuba-adaptive": f"Mitsuba {adaptive}"}
    return "; ".join(f"{names.get(k, k)}: {v} images" for k, v in sorted(counts.items(), reverse=True))


# ------------------------------------------------------------------------------------------------------------
# Goals
def _goal(experiment, figure, paper, goal, ours, met, unit="") -> dict:
    return {"experiment": experiment, "figure": figure, "paper": paper, "goal": goal, "ours": ours,
            "met": None if met is None else bool(met), "unit": unit}


def goal_rows(out_dir: Path, settings: PaperSettings) -> list[dict]:
    """Every goal figure of the run: the paper's value, the goal, ours, met or not.

    Goals in µm scale with the pixel footprint (1 / scale): a quarter-scale run sees 4x larger pixels. The strain
    goal (% of the sampled peak) follows its own scale law (:func:`workbench.experiments.bending.run.
    strain_goal_scale_law`). The rigid-motion and bending goals, their texts and pass/fail come from the
    experiments' own goal functions, the ones their reports use, so the summary and the experiment tables agree.
    """
    from workbench.experiments.bending.report import GOALS as BENDING_GOALS
    from workbench.experiments.bending.report import goal_check as bending_goal_check
    from workbench.experiments.bending.report import goal_texts as bending_goal_texts
    from workbench.experiments.rigid_motion.run import state_goal
    from workbench.reporting.goals import scaled_note, um_goal_text
    from workbench.rigs import paper_values

    p = paper_values()
    scale = settings.scale
    per_um = 1.0 / scale
    rows = []
    m = _metrics(out_dir, "calibration")
    if m:
        r = m["models"]["rmm"]
        t1 = p["table1_calibration"]
        for side in ("left", "right"):
            ours = r["reprojection_rms_px"][side]
            paper = t1[side]["reprojection_error_px"]
            rows.append(_goal("calibration", f"reprojection RMS, {side} (px)", f"{paper:.4f}", f"≤ {paper:.4f}",
                              f"{ours:.4f}", ours <= paper))
        z = max(abs((r["estimate"][s][n] - m["truth"][s][n]) / r["sigma"][s][n])
                for s in ("left", "right") for n in r["estimate"][s] if r["sigma"][s].get(n))
        rows.append(_goal("calibration", "Table 1: largest |estimate − truth| / σ", "—", "≤ 3", f"{z:.2f}", z <= 3))
        pf = r["validation_plane_fit"]
        proto = p["calibration_protocol"]
        for key, paper_mm, name in (("rmse_um", proto["plane_fit_rmse_mm"], "plane-fit RMSE (µm)"),
                                    ("max_abs_um", proto["plane_fit_max_deviation_mm"], "plane-fit max (µm)")):
            goal = 1e3 * paper_mm * per_um
            rows.append(_goal("calibration", f"Fig 5 {name}", f"{1e3 * paper_mm:.1f}",
                              um_goal_text(goal, scale, digits=1), f"{pf[key]:.2f}", pf[key] <= goal))
    m = _metrics(out_dir, "rigid_motion")
    if m:
        states = [s for s in m["states"] if "error" not in s and s.get("paper_mean_um") is not None]
        skipped = [s for s in m["states"] if "error" in s]
        # the run's scale, as the rigid-motion report itself states the goals (the same as settings.scale)
        rm_scale = m.get("scale", scale)
        ok = [state_goal(s, rm_scale)[2] for s in states]
        worst = max(states, key=lambda s: abs(s["mean_error_um"]) / s["paper_mean_um"]) if states else None
        note = scaled_note(rm_scale)
        rows.append(_goal("rigid motion", "states within paper/10 (mean) and paper/3 (std) of D error"
                          + (f", {note}" if note else ""), "—",
                          f"all {len(states) + len(skipped)}", f"{sum(ok)}", bool(states) and all(ok) and not skipped))
        if worst is not None:
            goal_mean, _, _ = state_goal(worst, rm_scale)
            rows.append(_goal("rigid motion", f"mean error of D at {worst['imposed_mm']:g} mm (µm), worst state",
                              f"{worst['paper_mean_um']:.1f}", um_goal_text(goal_mean, rm_scale, "abs ≤"),
                              f"{worst['mean_error_um']:+.3f}", abs(worst["mean_error_um"]) <= goal_mean))
        ten = next((s for s in states if s["imposed_mm"] == 10), None)
        if ten is not None:
            _, goal_std, _ = state_goal(ten, rm_scale)
            rows.append(_goal("rigid motion", "std of D at 10 mm (µm)", f"{ten['paper_std_um']:.1f}",
                              um_goal_text(goal_std, rm_scale), f"{ten['std_um']:.3f}", ten["std_um"] <= goal_std))
    m = _metrics(out_dir, "bending")
    if m:
        # recomputed from the states with the bending report's own goal functions (not read from m["goals"]), so
        # the summary and the bending table state the same goal and verdict
        g = bending_goal_check(m)
        if not g.get("state_found"):
            rows.append(_goal("bending", f"state at {BENDING_GOALS['load_N']:g} N measured", "—", "yes", "no", False))
        else:
            text = bending_goal_texts(m)
            for key, name in (("U_um", "U"), ("V_um", "V"), ("W_um", "W")):
                value, met = g[key]
                rows.append(_goal("bending", f"{name} RMSE vs FE truth at {BENDING_GOALS['load_N']:g} N (µm)", "—",
                                  text[key], f"{value:.3f}", met))
            value, met = g["strain_percent_of_peak"]
            rows.append(_goal("bending", "strain magnitude RMSE vs windowed truth (% of peak)", "—",
                              text["strain_percent_of_peak"], f"{value:.2f}", met))
            na, met = g["neutral_axis_mm"]
            rows.append(_goal("bending", "neutral axis position error (mm)", "—", text["neutral_axis_mm"],
                              "—" if na is None else f"{na:.3f}", met))
            top, bottom = g["area_change_top_compressed_bottom_stretched"][0]
            rows.append(_goal("bending", "Fig 8: area change, top compressed / bottom stretched", "top < 0 < bottom",
                              "top < 0 < bottom", f"{top:+.2e} / {bottom:+.2e}", top < 0 < bottom))
    m = _metrics(out_dir, "depth_of_field")
    if m:
        paper_ratio = m["paper_mig_scheimpflug"] / m["paper_mig_conventional"]
        rows.append(_goal("depth of field", "MIG ratio tilted / untilted", f"{paper_ratio:.2f}", "> 1",
                          f"{m['mig_ratio']:.2f}", m["mig_ratio"] > 1))
        blur = m["cameras"]["scheimpflug"]["blur_px"]["max"]
        rows.append(_goal("depth of field", "Scheimpflug blur circle over the plate, max (px)", "—", "≤ 1",
                          f"{blur:.3f}", blur <= 1))
    return rows


def _metrics(out_dir: Path, stage: str) -> dict | None:
    path = out_dir / stage / "metrics.json"
    return json.loads(path.read_text()) if path.is_file() else None


# ------------------------------------------------------------------------------------------------------------
# Report
def _demote(md: str, stage: str) -> str:
    """An experiment's report.md inside the paper report: headings one level down, links into its folder."""
    out = []
    for line in md.splitlines():
        if line.startswith("#"):
            line = "##" + line          # under the stage's own h2, out of the table of contents
        line = re.sub(r"!\[([^\]]*)\]\((?!https?:|data:|/)([^)]+)\)", lambda mm: f"![{mm.group(1)}]({stage}/{mm.group(2)})",
                      line)
        out.append(line)
    return "\n".join(out)


def _versions() -> list[tuple[str, str]]:
    from importlib import metadata

    names = ("numpy", "scipy", "numba", "opencv-python-headless", "mitsuba", "drjit", "scikit-fem", "trimesh",
             "matplotlib", "dask", "xarray")
    rows = [("scheimpflug-dic-workbench", idics.software_version())]
    for n in names:
        try:
            rows.append((n, metadata.version(n)))
        except metadata.PackageNotFoundError:
            rows.append((n, "not installed"))
    try:
        from scenes.optics.backend import VARIANT
        rows.append(("Mitsuba variant", VARIANT))
    except Exception as exc:  # noqa: BLE001 - the report must still be written
        rows.append(("Mitsuba variant", f"unavailable ({exc})"))
    return rows


def write_paper_report(out_dir: Path, settings: PaperSettings, timings: dict, total_s: float) -> dict:
    """``report.md`` and self-contained ``report.html`` from the stages' outputs; returns the summary."""
    from workbench.reporting.html_report import write_html_report

    goals = goal_rows(out_dir, settings)
    met = sum(1 for g in goals if g["met"])
    mode = "quick (reduced scale)" if settings.quick else "full resolution"
    lines = ["# The paper, reproduced on rendered images with exact truth", "",
             f"*Scheimpflug Camera-Based Stereo-Digital Image Correlation for Full-Field 3D Deformation Measurement*: "
             f"its calibration, rigid-motion, three-point bending and depth-of-field experiments, run by "
             f"`workbench reproduce paper` ({mode}, scale {settings.scale:g}). Every image is rendered through the "
             "true rig, so every measured figure is compared with the truth as well as with the paper.", "",
             "## Summary of the goal figures", "",
             f"**{met} of {len(goals)} goal figures met.** Goals in µm scale with the pixel footprint (×{1 / settings.scale:g} "
             "at this scale); the paper's values are from real images.", "",
             "| experiment | figure | paper | goal | ours | result |", "|---|---|---|---|---|---|"]
    for g in goals:
        result = "—" if g["met"] is None else ("pass" if g["met"] else "fail")
        cells = [g["experiment"], g["figure"], g["paper"], g["goal"], g["ours"], result]
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |")
    lines += ["", "## Run", "", "| item | value |", "|---|---|",
              f"| mode | {mode} |", f"| image scale | {settings.scale:g} (depth of field {settings.dof_scale:g}) |",
              f"| seed | {settings.seed} |",
              f"| rendering | speckled specimens: {_speckle_render_text(out_dir, settings)}; calibration boards: "
              f"{_board_render_text(out_dir)} |",
              f"| optics of the rigid-motion and bending states | {_optics_text(settings)} |",
              f"| calibration views | {settings.calibration_views} + {settings.validation_views} validation |",
              f"| machine | {idics.machine_text()} |",
              f"| finished | {datetime.now(timezone.utc).isoformat(timespec='seconds')} |",
              f"| this run | {_clock(total_s)} |",
              f"| all stages (their own times, kept or run) | {_clock(sum(t['seconds'] for t in timings.values()))} |",
              ""]
    timed = [(title, timings[stage]) for stage, title, _ in STAGES if stage in timings]
    if timed:
        lines += ["| stage | time | this run |", "|---|---|---|"] + [
            f"| {title} | {_clock(t['seconds'])} | {t['this_run']} |" for title, t in timed]
    lines += ["", "| software | version |", "|---|---|"] + [f"| {n} | {v} |" for n, v in _versions()] + [""]
    for stage, title, _ in STAGES:
        report = out_dir / stage / "report.md"
        m = _metrics(out_dir, stage)
        lines += [f"## {title}", ""]
        if not report.is_file() or m is None:
            lines += ["Not run (the stage did not complete).", ""]
            continue
        text = report.read_text()
        if experiment_idics.IDICS_HEADING not in text:                 # a report written before the section existed
            text += "\n" + "\n".join(experiment_idics.render_lines(m) + experiment_idics.idics_for(stage, m))
        lines += [_demote(text, stage), ""]
    md = "\n".join(lines) + "\n"
    atomic_write_text(out_dir / "report.md", md)
    write_html_report(out_dir / "report.html", "The paper, reproduced", md, out_dir)
    summary = {"settings": asdict(settings), "goals": goals, "timings": timings, "total_s": total_s}
    atomic_write_text(out_dir / "summary.json", json.dumps(summary, indent=1))
    return summary


__all__ = ["PaperSettings", "STAGES", "goal_rows", "reproduce_paper", "stage_done", "write_paper_report"]
