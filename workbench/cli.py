"""The ``workbench`` command line.

    workbench render checkerboard --rig paper --views N --seed S [--scale F] [--spp N] --out DIR
    workbench reproduce agreement [--rig paper] [--views N] [--scale F] [--spp N] [--seed S] --out DIR
    workbench reproduce depth-of-field [--scale F] [--f-number N] [--spp N] --out DIR
    workbench reproduce calibration [--scale F] [--seed S] [--spp N] --out DIR
    workbench calibrate --left GLOB --right GLOB --square-mm 5 --pattern 11x8 [--model rmm]
                        [--tilt-guess-deg A,B] --out calib.json
    workbench reproduce dic-accuracy --out DIR
    workbench reproduce rigid-motion [--scale F] [--calib rendered|true|FILE] [--lens thin|pinhole] --out DIR
    workbench stereo --calib calib.json --left-ref L0 --right-ref R0 --left GLOB --right GLOB [--roi ...]
                     [--subset 65] [--step 5] --out DIR
    workbench dic REF DEF [--roi X0,Y0,X1,Y1] [--subset 33] [--step 8] [--order 1|2]
                  [--interp biquintic|bicubic] [--seed-point X,Y] --out points.csv
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _scale(text: str) -> float:
    value = float(text)
    if not 0 < value <= 4:
        raise argparse.ArgumentTypeError(f"scale must be in (0, 4], got {value}")
    return value


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="workbench", description="Scheimpflug stereo-DIC virtual lab.")
    sub = p.add_subparsers(dest="command", required=True)

    render = sub.add_parser("render", help="render images with ground truth")
    rsub = render.add_subparsers(dest="what", required=True)
    cb = rsub.add_parser("checkerboard", help="random stereo views of the 12 x 9 checkerboard + truth.json")
    cb.add_argument("--rig", default="paper")
    cb.add_argument("--views", type=_positive_int, default=10)
    cb.add_argument("--seed", type=int, default=0)
    cb.add_argument("--scale", type=_scale, default=1.0, help="shrink image size and K together (fast runs)")
    cb.add_argument("--spp", type=_positive_int, default=64, help="samples per pixel")
    cb.add_argument("--noise-grey", type=float, default=0.0, help="Gaussian read noise, grey levels")
    cb.add_argument("--bit-depth", type=int, choices=(8, 16), default=8)
    cb.add_argument("--format", choices=("png", "tiff"), default="png")
    cb.add_argument("--out", type=Path, required=True)

    rep = sub.add_parser("reproduce", help="run one of the paper's checks and write a report")
    repsub = rep.add_subparsers(dest="what", required=True)
    ag = repsub.add_parser("agreement", help="render <-> camera-model agreement at checkerboard corners")
    ag.add_argument("--rig", default="paper")
    ag.add_argument("--views", type=_positive_int, default=2)
    ag.add_argument("--seed", type=int, default=0)
    ag.add_argument("--scale", type=_scale, default=1.0)
    ag.add_argument("--spp", type=_positive_int, default=256)
    ag.add_argument("--out", type=Path, required=True)
    rc = repsub.add_parser("calibration", help="the paper's calibration protocol on rendered views (Table 1, Fig 5)")
    rc.add_argument("--scale", type=_scale, default=1.0)
    rc.add_argument("--seed", type=int, default=0)
    rc.add_argument("--spp", type=_positive_int, default=64)
    rc.add_argument("--noise-grey", type=float, default=1.0)
    rc.add_argument("--calibration-views", type=_positive_int, default=30)
    rc.add_argument("--validation-views", type=_positive_int, default=20)
    rc.add_argument("--refine-corners", action="store_true", help="saddle-fit refinement of OpenCV's corners")
    rc.add_argument("--out", type=Path, required=True)
    rm = repsub.add_parser("rigid-motion", help="the paper's rigid-motion test (Fig 6) on rendered states, scored")
    rm.add_argument("--scale", type=_scale, default=1.0)
    rm.add_argument("--calib", default="rendered",
                    help="'rendered' (reproduced from rendered boards, default), 'true' (the true rig) or a file")
    rm.add_argument("--lens", choices=("thin", "pinhole"), default="pinhole",
                    help="pinhole (default) or thin lens at f/8 with the rig's tilted sensors (its focus plane misses the face)")
    rm.add_argument("--seed", type=int, default=0)
    rm.add_argument("--spp", type=_positive_int, default=64)
    rm.add_argument("--subset", type=_positive_int, default=65)
    rm.add_argument("--step", type=_positive_int, default=5)
    rm.add_argument("--out", type=Path, required=True)
    bd = repsub.add_parser("bending", help="the paper's three-point bending test (Figs 7-8): FE truth, strain, scored")
    bd.add_argument("--scale", type=_scale, default=1.0)
    bd.add_argument("--rig", choices=("scheimpflug", "paper"), default="scheimpflug",
                    help="scheimpflug (tilts from the Scheimpflug condition, default) or paper (Table 1 as printed)")
    bd.add_argument("--lens", choices=("thin", "pinhole"), default="thin")
    bd.add_argument("--calib", default="rendered",
                    help="'rendered' (reproduced from rendered boards, default), 'true' (the true rig) or a file")
    bd.add_argument("--seed", type=int, default=0)
    bd.add_argument("--spp", type=_positive_int, default=64)
    bd.add_argument("--noise-grey", type=float, default=1.0)
    bd.add_argument("--subset", type=_positive_int, default=65)
    bd.add_argument("--step", type=_positive_int, default=5)
    bd.add_argument("--window", type=int, default=15,
                    help="strain window (points per side, odd >= 3); 0 = per-triangle Cosserat strain, no window")
    bd.add_argument("--out", type=Path, required=True)
    da = repsub.add_parser("dic-accuracy", help="DIC bias vs sub-pixel shift, noise floor, shape functions")
    da.add_argument("--out", type=Path, required=True)
    dof = repsub.add_parser("depth-of-field", help="MIG of an oblique speckled plate: Scheimpflug vs untilted")
    dof.add_argument("--scale", type=_scale, default=1.0)
    dof.add_argument("--object-tilt-deg", type=float, default=38.0)
    dof.add_argument("--f-number", type=float, default=4.0)
    dof.add_argument("--spp", type=_positive_int, default=64)
    dof.add_argument("--seed", type=int, default=0)
    dof.add_argument("--out", type=Path, required=True)
    cal = sub.add_parser("calibrate", help="stepwise Scheimpflug stereo calibration from checkerboard image pairs")
    cal.add_argument("--left", required=True, help="glob of left images, e.g. 'views/left_*.png' (sorted)")
    cal.add_argument("--right", required=True, help="glob of right images (sorted; paired with the left ones)")
    cal.add_argument("--square-mm", type=float, default=5.0)
    cal.add_argument("--pattern", type=_pattern, default=(11, 8), help="inner corners, COLSxROWS (default 11x8)")
    cal.add_argument("--model", choices=("rmm", "opencv-tilt", "pinhole"), default="rmm")
    cal.add_argument("--tilt-guess-deg", type=_pair, default=(0.0, 0.0),
                     help="datasheet tilt (alpha,beta) of the left camera for step 1")
    cal.add_argument("--tilt-guess-right-deg", type=_pair, default=None,
                     help="right camera's (alpha,beta); default mirrors the left one: (alpha,-beta)")
    cal.add_argument("--no-joint", action="store_true", help="skip the final joint refinement")
    cal.add_argument("--refine-corners", action="store_true", help="saddle-fit refinement of OpenCV's corners")
    cal.add_argument("--out", type=Path, required=True, help="calibration JSON (a .yaml OpenCV export is written beside)")

    st = sub.add_parser("stereo", help="stereo-DIC of an image sequence with a calibration file (real or rendered)")
    st.add_argument("--calib", type=Path, required=True, help="calibration JSON (workbench calibrate) or OpenCV YAML")
    st.add_argument("--left-ref", type=Path, required=True, help="left reference image")
    st.add_argument("--right-ref", type=Path, required=True, help="right reference image")
    st.add_argument("--left", required=True, help="glob of left deformed images (sorted; paired with --right)")
    st.add_argument("--right", required=True, help="glob of right deformed images")
    st.add_argument("--roi", type=_roi, default=None, help="rectangle of points on the left reference X0,Y0,X1,Y1")
    st.add_argument("--subset", type=_positive_int, default=65, help="subset size (odd, px), default 65")
    st.add_argument("--step", type=_positive_int, default=5, help="grid step (px), default 5")
    st.add_argument("--order", type=int, choices=(1, 2), default=2)
    st.add_argument("--min-zncc", type=float, default=0.8)
    st.add_argument("--out", type=Path, required=True, help="output folder (CSV + VTK per state)")

    dic = sub.add_parser("dic", help="2-D subset DIC between a reference and a deformed image (any 8/16-bit grey files)")
    dic.add_argument("reference", type=Path, help="reference image file")
    dic.add_argument("deformed", type=Path, help="deformed image file")
    dic.add_argument("--roi", type=_roi, default=None, help="rectangle of points of interest X0,Y0,X1,Y1 (px)")
    dic.add_argument("--mask", type=Path, default=None, help="image whose non-zero pixels may hold points of interest")
    dic.add_argument("--subset", type=_positive_int, default=33, help="subset size 2M+1 (odd, px), default 33")
    dic.add_argument("--step", type=_positive_int, default=8, help="grid step (px), default 8")
    dic.add_argument("--order", type=int, choices=(1, 2), default=1, help="shape function order, default 1")
    dic.add_argument("--interp", choices=("biquintic", "bicubic"), default="biquintic")
    dic.add_argument("--seed-point", type=_pair, action="append", default=None,
                     help="preferred seed X,Y (px); may be repeated")
    dic.add_argument("--seed-guess", type=_pair, default=(0.0, 0.0),
                     help="displacement U,V (px) at which the seed search is centred, default 0,0")
    dic.add_argument("--search-radius", type=_positive_int, default=32, help="seed search half-width (px)")
    dic.add_argument("--min-zncc", type=float, default=0.8, help="points below this ZNCC are rejected")
    dic.add_argument("--tolerance", type=float, default=1e-3, help="IC-GN convergence threshold (px at the subset edge)")
    dic.add_argument("--lowpass-sigma", type=float, default=0.0, help="Gaussian pre-filter sigma (px), default off")
    dic.add_argument("--threads", type=_positive_int, default=None, help="worker threads (default: all cores)")
    dic.add_argument("--out", type=Path, required=True, help="CSV of the points (x,y,u,v,zncc,iterations,status,...)")
    return p


def _roi(text: str) -> tuple[int, int, int, int]:
    try:
        values = tuple(int(round(float(v))) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"roi must be X0,Y0,X1,Y1, got {text!r}") from None
    if len(values) != 4:
        raise argparse.ArgumentTypeError(f"roi must be X0,Y0,X1,Y1, got {text!r}")
    return values


def _reproduce_rigid_motion(args) -> int:
    from workbench.experiments.rigid_motion import reproduce_rigid_motion

    m = reproduce_rigid_motion(args.out, scale=args.scale, calib=args.calib, lens=args.lens, seed=args.seed,
                               spp=args.spp, subset_size=args.subset, step=args.step)
    e = m["reference_3d_error_um"]
    print(f"{m['calibration']}: reference 3D error {e['aligned_rms']:.3f} um aligned ({e['unaligned_rms']:.1f} um "
          f"unaligned), {m['points']} points")
    for r in m["states"]:
        paper = "" if r["paper_mean_um"] is None else f"; paper {r['paper_mean_um']:.1f} / {r['paper_std_um']:.1f} um"
        print(f"  {r['imposed_mm']:5.1f} mm: mean error {r['mean_error_um']:+.3f} um, std {r['std_um']:.3f} um "
              f"({r['points']} points){paper}")
    print(f"wrote {args.out / 'report.md'}")
    return 0


def _reproduce_bending(args) -> int:
    from workbench.experiments.bending import reproduce_bending

    if args.window != 0 and (args.window < 3 or args.window % 2 == 0):
        raise ValueError(f"--window must be 0 (per-triangle strain) or an odd number >= 3, got {args.window}")
    m = reproduce_bending(args.out, scale=args.scale, rig_name=args.rig, lens=args.lens, calib=args.calib,
                          seed=args.seed, spp=args.spp, noise_grey=args.noise_grey, subset_size=args.subset,
                          step=args.step, window=args.window or None)
    print(f"{m['calibration']}: {m['points']} points, VSG {m['vsg_px']} px")
    for r in m["states"]:
        if "error" in r:
            print(f"  {r['load_N']:6.0f} N: skipped ({r['error']})")
            continue
        print(f"  {r['load_N']:6.0f} N: U/V/W RMSE " + " / ".join(f"{v:.3f}" for v in r["U_rmse_um"])
              + f" um; strain RMSE {r['strain_magnitude_rmse_vs_filtered_ue']:.1f} ue vs windowed truth "
              f"({r['strain_rmse_vs_filtered_percent_of_peak']:.1f} % of the {r['peak_truth_strain_ue']:.0f} ue peak)")
    print(f"wrote {args.out / 'report.md'}")
    measured = [r for r in m["states"] if "error" not in r]
    return 0 if measured else 1


def _reproduce_dic_accuracy(args) -> int:
    from workbench.experiments.dic_accuracy import reproduce_dic_accuracy

    metrics = reproduce_dic_accuracy(args.out)
    for curve in metrics["bias"]:
        print(f"bias {curve['label']}: max {curve['max_abs_px']:.5f} px")
    print(f"noise ratio std(u)/theory: {metrics['noise']['all']['ratio']:.3f}; wrote {args.out / 'report.md'}")
    return 0


def _stereo(args) -> int:
    import glob
    import warnings

    from measurement.calibration.io import load_calibration, load_opencv_yaml
    from measurement.dic import DICSettings
    from measurement.image_io import read_grey
    from measurement.stereo_dic import StereoMatchError, measure_state, reference_shape
    from measurement.stereo_io import write_state_csv, write_state_vtk

    if not args.calib.is_file():
        raise ValueError(f"calibration file not found: {args.calib}")
    rig = load_opencv_yaml(args.calib) if args.calib.suffix.lower() in (".yaml", ".yml") else load_calibration(args.calib)
    left_files, right_files = sorted(glob.glob(args.left)), sorted(glob.glob(args.right))
    if not left_files or not right_files:
        raise ValueError(f"no images match --left {args.left!r}" if not left_files
                         else f"no images match --right {args.right!r}")
    if len(left_files) != len(right_files):
        raise ValueError(f"{len(left_files)} left images but {len(right_files)} right images: they must pair up")
    settings = DICSettings(subset_size=args.subset, step=args.step, order=args.order, min_zncc=args.min_zncc)
    left_ref, right_ref = read_grey(args.left_ref), read_grey(args.right_ref)
    shape = reference_shape(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, left_ref, right_ref,
                            settings, roi=args.roi)
    args.out.mkdir(parents=True, exist_ok=True)
    write_state_csv(args.out / "reference.csv", shape)
    write_state_vtk(args.out / "reference.vtk", shape)
    print(f"reference: {int(shape.valid.sum())}/{shape.x.size} points triangulated, median residual "
          f"{np.nanmedian(shape.residual_px):.4f} px")
    from tqdm import tqdm
    for k, (fl, fr) in enumerate(tqdm(list(zip(left_files, right_files)), desc="stereo states")):
        try:
            state = measure_state(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, shape,
                                  left_ref, read_grey(fl), read_grey(fr), settings)
        except StereoMatchError as err:
            warnings.warn(f"state {k} ({fl}, {fr}) skipped: {err}", stacklevel=1)
            continue
        name = f"state_{k:03d}"
        write_state_csv(args.out / f"{name}.csv", shape, state)
        write_state_vtk(args.out / f"{name}.vtk", shape, state)
        ok = state.valid
        if ok.mean() < 0.5:
            warnings.warn(f"state {k} ({fl}, {fr}): only {ok.mean():.0%} of the points were measured", stacklevel=1)
        tqdm.write(f"state {k} ({Path(fl).name}, {Path(fr).name}): {int(ok.sum())}/{ok.size} points, mean D "
                   f"{np.nanmean(state.D_mm) if ok.any() else float('nan'):.4f} mm")
    print(f"wrote {args.out}")
    return 0


def _dic(args) -> int:
    import numba

    from measurement.dic import DICSettings, Status, correlate
    from measurement.image_io import read_grey

    if args.threads:
        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    reference = read_grey(args.reference)
    deformed = read_grey(args.deformed)
    if reference.shape != deformed.shape:
        raise ValueError(f"{args.reference} is {reference.shape[1]} x {reference.shape[0]} px but {args.deformed} is "
                         f"{deformed.shape[1]} x {deformed.shape[0]} px: the images must have the same size")
    mask = None
    if args.mask is not None:
        mask = read_grey(args.mask) != 0
    settings = DICSettings(subset_size=args.subset, step=args.step, order=args.order, interpolation=args.interp,
                           search_radius_px=args.search_radius, min_zncc=args.min_zncc,
                           tolerance_px=args.tolerance, lowpass_sigma_px=args.lowpass_sigma)
    result = correlate(reference, deformed, settings, roi=args.roi, mask=mask, seed_points_xy=args.seed_point,
                       seed_guess_px=args.seed_guess)
    result.to_csv(args.out)
    ok = result.converged
    counts = ", ".join(f"{name.lower()} {n}" for name, n in result.status_counts().items())
    print(f"{result.x.size} points ({counts}) in {result.timings_s['total']:.2f} s; wrote {args.out}")
    if ok.any():
        print(f"  u {np.nanmin(result.u):.4f} .. {np.nanmax(result.u):.4f} px, v {np.nanmin(result.v):.4f} .. "
              f"{np.nanmax(result.v):.4f} px, median ZNCC {np.median(result.zncc[ok]):.4f}, "
              f"mean iterations {result.iterations[ok].mean():.2f}")
    else:
        print(f"  no point converged (statuses: {', '.join(Status(s).name for s in np.unique(result.status))})",
              file=sys.stderr)
        return 1
    return 0


def _pattern(text: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"pattern must look like 11x8, got {text!r}") from None
    if a < 2 or b < 2:
        raise argparse.ArgumentTypeError(f"pattern needs at least 2x2 inner corners, got {text!r}")
    return a, b


def _pair(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two numbers 'A,B', got {text!r}") from None
    return a, b


def _calibrate(args) -> int:
    import glob

    from measurement.calibration.images import calibrate_from_files
    from measurement.calibration.io import export_opencv_yaml, save_calibration

    left, right = sorted(glob.glob(args.left)), sorted(glob.glob(args.right))
    if not left or not right:
        raise ValueError(f"no images match --left {args.left!r}" if not left else f"no images match --right {args.right!r}")
    guess_r = args.tilt_guess_right_deg or (args.tilt_guess_deg[0], -args.tilt_guess_deg[1])
    cal, pairs = calibrate_from_files(left, right, square_mm=args.square_mm, pattern_size=args.pattern,
                                      model=args.model, tilt_guess_left_deg=args.tilt_guess_deg,
                                      tilt_guess_right_deg=guess_r, joint=not args.no_joint,
                                      refine_corners=args.refine_corners)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(cal, args.out, extra={"images": {"left": pairs.left_files, "right": pairs.right_files,
                                                       "dropped": pairs.dropped}})
    export_opencv_yaml(cal, args.out.with_suffix(".yaml"))
    print(f"calibrated {args.model} from {len(pairs.left_files)} stereo views ({len(pairs.dropped)} images dropped)")
    for side in ("left", "right"):
        c = getattr(cal, side)
        params = ", ".join(f"{n}={getattr(c.camera, n):.5g}±{c.sigma[n]:.2g}" for n in ("fx", "fy", "cx", "cy",
                           "alpha_deg", "beta_deg", "k1", "k2", "p1", "p2"))
        print(f"  {side}: reprojection RMS {c.rms_px:.4f} px; {params}")
    print(f"  stereo T = {np.round(cal.T_right_from_left_mm, 4).tolist()} mm; wrote {args.out} and "
          f"{args.out.with_suffix('.yaml')}")
    return 0


def _reproduce_calibration(args) -> int:
    from workbench.experiments.calibration import reproduce_calibration

    m = reproduce_calibration(args.out, scale=args.scale, seed=args.seed, spp=args.spp, noise_grey=args.noise_grey,
                              n_calibration=args.calibration_views, n_validation=args.validation_views,
                              refine_corners=args.refine_corners)
    for model, r in m["models"].items():
        v, pf = r["validation_exact"], r["validation_plane_fit"]
        print(f"{model:8s}: reprojection RMS {r['reprojection_rms_px']['left']:.4f} / "
              f"{r['reprojection_rms_px']['right']:.4f} px; 3D RMS {v['rms_3d_aligned_um']:.3f} um aligned "
              f"({v['rms_3d_unaligned_um']:.1f} um unaligned); projection {v['projection_rms_px']:.4f} px; plane fit "
              f"RMSE {pf['rmse_um']:.2f} um, max {pf['max_abs_um']:.2f} um; calibration {r['calibration_s']} s")
    print(f"report: {args.out / 'report.md'}")
    return 0


def _render_checkerboard(args) -> int:
    from scenes.noise import SensorNoise
    from workbench.experiments.checkerboard_views import write_checkerboard_dataset
    from workbench.rigs import get_rig

    rig = get_rig(args.rig, args.scale)
    noise = SensorNoise(read_noise_grey=args.noise_grey, bit_depth=args.bit_depth)
    truth = write_checkerboard_dataset(rig, args.out, args.views, args.seed, spp=args.spp, noise=noise,
                                       image_format=args.format)
    print(f"wrote {len(truth['images'])} images and truth.json to {args.out}")
    return 0


def _reproduce_agreement(args) -> int:
    from workbench.experiments.render_agreement import measure_agreement, summary_lines, write_agreement_report
    from workbench.rigs import get_rig

    rig = get_rig(args.rig, args.scale)
    summary = measure_agreement(rig, n_views=args.views, seed=args.seed, spp=args.spp)
    write_agreement_report(summary, args.out)
    print("\n".join(summary_lines(summary)))
    print(f"report: {args.out / 'report.md'}")
    return 0 if all(e["meets_goal"] for e in summary["cameras"].values()) else 1


def _reproduce_depth_of_field(args) -> int:
    from workbench.experiments.depth_of_field import reproduce_depth_of_field

    m = reproduce_depth_of_field(args.out, scale=args.scale, object_tilt_deg=args.object_tilt_deg,
                                 f_number=args.f_number, spp=args.spp, seed=args.seed)
    for name, c in m["cameras"].items():
        print(f"{name:13s}: MIG {c['mig']:.2f}, blur median {c['blur_px']['median']:.2f} px (max {c['blur_px']['max']:.2f}), "
              f"noise floor {c['noise_floor_px']['u']:.4f} / {c['noise_floor_px']['v']:.4f} px, "
              f"displacement error RMS {c['displacement_error_px']['rms']:.4f} px")
    print(f"MIG ratio {m['mig_ratio']:.2f} (paper {m['paper_mig_scheimpflug'] / m['paper_mig_conventional']:.2f}); "
          f"wrote {args.out / 'report.md'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    handlers = {("render", "checkerboard"): _render_checkerboard,
                ("reproduce", "agreement"): _reproduce_agreement,
                ("reproduce", "depth-of-field"): _reproduce_depth_of_field,
                ("reproduce", "calibration"): _reproduce_calibration,
                ("calibrate", None): _calibrate,
                ("dic", None): _dic,
                ("stereo", None): _stereo,
                ("reproduce", "dic-accuracy"): _reproduce_dic_accuracy,
                ("reproduce", "rigid-motion"): _reproduce_rigid_motion,
                ("reproduce", "bending"): _reproduce_bending}
    try:
        return handlers[(args.command, getattr(args, "what", None))](args)
    except (ValueError, OSError, RuntimeError) as err:
        # Bad input and missing system pieces get one clear line, never a traceback.
        where = " ".join(filter(None, ("workbench", args.command, getattr(args, "what", None))))
        print(f"{where}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
