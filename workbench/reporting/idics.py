"""The iDICs Good Practices Guide's reporting tables (hardware and analysis), filled from a run.

The guide (International DIC Society, *A Good Practices Guide for Digital Image Correlation*, 2018, §"DIC
reporting") asks every DIC result to state its hardware and its analysis parameters, each with units. Here the
"hardware" is the rendered rig: every entry comes from the true rig, the rendered dataset's ``truth.json`` and
the experiment's ``metrics.json``, never typed in.
"""
from __future__ import annotations

import json
import platform
from pathlib import Path

import numpy as np


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("scheimpflug-dic-workbench")
    except metadata.PackageNotFoundError:
        return "unknown"


def _commit() -> str:
    import subprocess

    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def software_version() -> str:
    """``scheimpflug-dic-workbench <version> (git <commit>)``."""
    return f"scheimpflug-dic-workbench {_version()} (git {_commit()})"


def _rotation_deg(R) -> float:
    R = np.asarray(R, dtype=float)
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def _table(rows: list[tuple[str, str]]) -> list[str]:
    return ["| item | value |", "|---|---|"] + [f"| {k} | {v} |" for k, v in rows]


def hardware_rows(rig, *, lens: str, f_number: float | None, focal_length_mm: dict | None, stand_off_mm: float,
                  read_noise_grey: float, mc_rms_grey: float | None, pattern: str, feature_px: float | None,
                  target: str, bit_depth: int = 8, footprint_mm: float | None = None) -> list[tuple[str, str]]:
    """Hardware rows of the guide for a rendered stereo rig (``rig``: :class:`workbench.rigs.StereoRig`).

    ``footprint_mm``: the object-side size of a left pixel where the specimen is (default stand-off / fx)."""
    left, right = rig.left, rig.right
    footprint_mm = footprint_mm or stand_off_mm / left.fx
    fov = (left.width * footprint_mm, left.height * footprint_mm)
    image_distance = {s: rig.camera(s).fx * rig.pixel_pitch_mm for s in ("left", "right")}
    if lens == "thin":
        lens_text = "thin lens (rendered, aperture sampled), tilted sensor (Scheimpflug)"
        focal = ", ".join(f"{s} F = {focal_length_mm[s]:.2f} mm" for s in ("left", "right")) if focal_length_mm else "—"
        aperture = f"f/{f_number:g}" if f_number else "—"
    else:
        lens_text = "pinhole (rendered; infinite depth of field), tilted sensor (Scheimpflug)"
        focal = "—"
        aperture = "pinhole"
    noise = f"σ = {read_noise_grey:g} grey read noise ({bit_depth}-bit)"
    if mc_rms_grey is not None:
        noise += f"; Monte-Carlo render noise {mc_rms_grey:.3f} grey RMS (measured)"
    tilt = (f"left α, β = {left.alpha_deg:+.3f}°, {left.beta_deg:+.3f}°; right {right.alpha_deg:+.3f}°, "
            f"{right.beta_deg:+.3f}°")
    return [
        ("camera", f"rendered Scheimpflug camera pair, rig `{rig.name}`, {1e3 * rig.pixel_pitch_mm:.2f} µm pixels; "
                   f"sensor tilt {tilt}"),
        ("image resolution", f"{left.width} × {left.height} px"),
        ("lens", lens_text),
        ("focal length", f"image distance fx·pitch: left {image_distance['left']:.2f} mm, right "
                         f"{image_distance['right']:.2f} mm; {focal}"),
        ("aperture", aperture),
        ("field of view", f"{fov[0]:.1f} × {fov[1]:.1f} mm at the stand-off distance"),
        ("image scale", f"{1e3 * footprint_mm:.2f} µm/px ({1 / footprint_mm:.1f} px/mm)"),
        ("stereo angle", f"{_rotation_deg(rig.R_right_from_left):.2f}° (angle between the cameras' frames)"),
        ("stand-off distance", f"{stand_off_mm:.1f} mm (left camera to the specimen, along the left optical axis)"),
        ("image noise", noise),
        ("patterning technique", pattern),
        ("feature size", "—" if feature_px is None else f"{feature_px:.1f} px ({feature_px * footprint_mm:.3f} mm)"),
        ("calibration target", target),
    ]


#: The matching row of a stereo experiment (left and right images matched, points triangulated).
STEREO_MATCHING = ("stereo matching", "left reference → right reference and → every deformed left/right image "
                                      "(2-D DIC), triangulation with tilt and distortion")


def analysis_rows(*, subset_px: int | None, step_px: int | None, order: int | None, strain_window: str,
                  vsg_px: float | str | None, strain_formulation: str, noise_floor: str, strain_noise_floor: str,
                  lowpass_sigma_px: float = 0.0,
                  matching: tuple[str, str] = STEREO_MATCHING) -> list[tuple[str, str]]:
    """Analysis rows of the guide for this project's instrument.

    ``matching``: the (item, value) row saying which images are matched; the stereo experiments' by default, an
    experiment that correlates each camera alone passes its own (it has no stereo matching to report).
    """
    shape = {1: "first order (affine)", 2: "second order (quadratic)"}.get(order, "—")
    return [
        ("DIC software", f"{software_version()}, `measurement/` (numba)"),
        ("image filtering", "none" if not lowpass_sigma_px else f"Gaussian low-pass σ = {lowpass_sigma_px:g} px"),
        ("subset size", "—" if subset_px is None else f"{subset_px} px"),
        ("step size", "—" if step_px is None else f"{step_px} px"),
        ("subset shape function", shape),
        ("matching criterion", "ZNSSD, inverse-compositional Gauss–Newton; ZNCC seeds, reliability-guided"),
        ("interpolant", "biquintic B-spline"),
        matching,
        ("strain window", strain_window),
        ("virtual strain gauge size", "—" if vsg_px is None else f"{vsg_px} px"),
        ("strain formulation", strain_formulation),
        ("post-filtering of displacements", "none"),
        ("displacement noise floor", noise_floor),
        ("strain noise floor", strain_noise_floor),
    ]


def idics_section(hardware: list[tuple[str, str]], analysis: list[tuple[str, str]], level: int = 2) -> list[str]:
    """Markdown lines: the two tables under one heading."""
    h = "#" * level
    return [f"{h} iDICs Good Practices: hardware and analysis", "",
            "As the iDICs *Good Practices Guide for DIC* (2018) asks every result to report; the hardware is the "
            "rendered rig, each entry taken from the run.", "", "**Hardware**", ""] + _table(hardware) + [
            "", "**Analysis**", ""] + _table(analysis) + [""]


def machine_text() -> str:
    """One line: OS, CPU count, Python."""
    import os

    return (f"{platform.system()} {platform.release()}, {platform.machine()}, {os.cpu_count()} CPUs, "
            f"Python {platform.python_version()}")


def truth_of(images_folder: str | Path) -> dict:
    """The rendered dataset's ``truth.json`` (empty when the folder is gone, e.g. another machine's store)."""
    path = Path(images_folder) / "truth.json"
    return json.loads(path.read_text()) if path.is_file() else {}


__all__ = ["analysis_rows", "hardware_rows", "idics_section", "machine_text", "software_version", "truth_of"]
