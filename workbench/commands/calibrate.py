"""``workbench calibrate``: the stepwise Scheimpflug stereo calibration from board image pairs."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from workbench.commands.options import (draws_arg, glob_files, output_file, paired_globs, pattern_arg,
                                        positive_float_arg, positive_int_arg, read_image_for, seed_arg, size_text,
                                        tilt_pair_arg)


def add_parser(sub) -> None:
    """The ``calibrate`` subcommand."""
    cal = sub.add_parser("calibrate", help="stepwise Scheimpflug stereo calibration from checkerboard image pairs "
                                           "(or one camera's images with --camera)")
    cal.add_argument("--left", default=None, help="glob of left images, e.g. 'views/left_*.png' (sorted)")
    cal.add_argument("--right", default=None, help="glob of right images (sorted; paired with the left ones)")
    cal.add_argument("--camera", default=None, metavar="GLOB",
                     help="single-camera calibration of these images instead of a stereo pair (--left/--right); "
                          "writes a camera JSON (and an OpenCV YAML beside it)")
    cal.add_argument("--square-mm", type=positive_float_arg, default=5.0)
    cal.add_argument("--pattern", type=pattern_arg, default=(11, 8),
                     help="inner corners, COLSxROWS (default 11x8); with --target dots: the dots, COLSxROWS")
    cal.add_argument("--target", choices=("checkerboard", "charuco", "dots"), default="checkerboard",
                     help="calibration target: checkerboard (default), charuco (--squares, --marker-mm, --dictionary; "
                          "--square-mm the square) or dots (a symmetric dot grid: --pattern, --square-mm the pitch, "
                          "--dot-mm)")
    cal.add_argument("--squares", type=pattern_arg, default=None, help="ChArUco board squares, COLSxROWS")
    cal.add_argument("--marker-mm", type=positive_float_arg, default=None, help="ChArUco marker side, mm")
    cal.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco ArUco dictionary (default DICT_4X4_50)")
    cal.add_argument("--dot-mm", type=positive_float_arg, default=None, help="dot diameter, mm (--target dots)")
    cal.add_argument("--white-dots", action="store_true", help="light dots on a dark ground (--target dots)")
    cal.add_argument("--model", choices=("rmm", "opencv-tilt", "pinhole", "auto"), default="rmm",
                     help="camera model (default rmm, the paper's); auto: pinhole or rmm, whichever is the simplest "
                          "that held-out views support (and each candidate's tilt / sigma is printed)")
    cal.add_argument("--tilt-guess-deg", type=tilt_pair_arg, default=(0.0, 0.0),
                     help="datasheet tilt (alpha,beta) of the left camera for step 1")
    cal.add_argument("--tilt-guess-right-deg", type=tilt_pair_arg, default=None,
                     help="right camera's (alpha,beta); default mirrors the left one: (alpha,-beta)")
    cal.add_argument("--no-joint", action="store_true", help="skip the final joint refinement")
    cal.add_argument("--refine-corners", action="store_true", help="saddle-fit refinement of OpenCV's corners")
    from measurement.calibration.stepwise import LENS_ALIASES, LENSES
    cal.add_argument("--lens", choices=tuple(LENS_ALIASES) + LENSES + ("auto",), default="brown4",
                     help="lens distortion: k1k2p1p2 = brown4 (the paper, default), k1k2k3p1p2 = brown5 (also the r^6 "
                          "term k3; then both are fitted and the output says whether k3 is worth it), full (also the "
                          "thin prism s1-s4 and the skew), or auto (the simplest the held-out views support)")
    cal.add_argument("--folds", type=positive_int_arg, default=8,
                     help="most folds of the held-out-view test of --model/--lens auto (default 8)")
    cal.add_argument("--covariance", choices=("linear", "bootstrap"), default="linear",
                     help="parameter covariance stored with the calibration (propagated to the points' calibration "
                          "uncertainty): linear (default: s^2 (J^T J)^-1 of the least squares; a lower bound beyond "
                          "~0.02 px of corner noise on narrow fields) or bootstrap (--bootstrap-draws recalibrations "
                          "of synthetic corners at the fit's own residual noise; costs that many calibrations; says "
                          "how often the procedure stops in a worse minimum, but does not cure the under-statement "
                          "at 0.05 px: see measurement.calibration.bootstrap)")
    cal.add_argument("--bootstrap-draws", type=draws_arg, default=40,
                     help="calibrations of the --covariance bootstrap (default 40: each sigma to ~11 %%)")
    cal.add_argument("--bootstrap-seed", type=seed_arg, default=0, help="seed of the bootstrap's noise (default 0)")
    cal.add_argument("--bootstrap-workers", type=positive_int_arg, default=1,
                     help="processes the bootstrap's calibrations are spread over (default 1)")
    cal.add_argument("--out", type=Path, required=True, help="calibration JSON (a .yaml OpenCV export is written beside)")


def _calibration_texts(cal, pairs, extra: dict | None = None) -> tuple[str, str]:
    """The calibration JSON and its OpenCV YAML export as texts, built before either file is written."""
    import tempfile

    from measurement.calibration.io import export_opencv_yaml, save_calibration

    with tempfile.TemporaryDirectory(prefix="workbench-calibrate-") as tmp:
        json_path, yaml_path = Path(tmp) / "calibration.json", Path(tmp) / "calibration.yaml"
        try:
            save_calibration(cal, json_path, extra={"images": {"left": pairs.left_files, "right": pairs.right_files,
                                                               "dropped": pairs.dropped}, **(extra or {})})
            export_opencv_yaml(cal, yaml_path)
            return json_path.read_text(encoding="utf-8"), yaml_path.read_text(encoding="utf-8")
        except OSError as err:
            raise OSError(f"cannot build the calibration files in {tmp}: {err.strerror or err}") from None


def _auto_candidates(model: str, lens: str) -> list[tuple[str, str]]:
    """The (model, lens) candidates of ``--model auto`` / ``--lens auto`` (the other option fixed if not auto)."""
    from measurement.calibration.stepwise import LENSES, canonical_lens

    models = ("pinhole", "rmm") if model == "auto" else (model,)
    lenses = LENSES if lens == "auto" else (canonical_lens(lens),)
    return [(m, ln) for m in models for ln in lenses]


def _parameter_names(lens: str) -> tuple[str, ...]:
    from measurement.calibration.stepwise import LENS_TERMS

    terms = LENS_TERMS[lens]
    return (("fx", "fy") + (("skew",) if "skew" in terms else ()) + ("cx", "cy", "alpha_deg", "beta_deg", "k1", "k2")
            + (("k3",) if "k3" in terms else ()) + ("p1", "p2") + tuple(t for t in terms if t.startswith("s")))


def _calibration_target(args):
    """The target spec of ``calibrate``'s options (None: the checkerboard of --pattern), checked."""
    from measurement.calibration.targets import CharucoSpec, DotGridSpec

    if args.target != "charuco" and (args.squares or args.marker_mm):
        raise ValueError("--squares and --marker-mm describe a ChArUco board: add --target charuco")
    if args.target != "dots" and (args.dot_mm or args.white_dots):
        raise ValueError("--dot-mm and --white-dots describe a dot grid: add --target dots")
    if args.target != "checkerboard" and args.refine_corners:
        raise ValueError("--refine-corners refines checkerboard corners; it does not apply to --target "
                         f"{args.target}")
    if args.target == "charuco":
        if args.squares is None or args.marker_mm is None:
            raise ValueError("--target charuco needs --squares COLSxROWS and --marker-mm (and --square-mm)")
        return CharucoSpec(squares=args.squares, square_mm=args.square_mm, marker_mm=args.marker_mm,
                           dictionary=args.dictionary)
    if args.target == "dots":
        if args.dot_mm is None:
            raise ValueError("--target dots needs --dot-mm (and --pattern COLSxROWS dots, --square-mm the pitch)")
        return DotGridSpec(pattern_size=args.pattern, pitch_mm=args.square_mm, diameter_mm=args.dot_mm,
                           dark_dots=not args.white_dots)
    return None


def _calibration_check(args) -> tuple[str, str]:
    """Options of ``calibrate`` checked before any board is detected; returns the (model, lens) as asked."""
    if args.camera is not None and (args.left is not None or args.right is not None):
        raise ValueError("--camera calibrates one camera: give its images with --camera only, not --left/--right")
    if args.camera is None and (args.left is None or args.right is None):
        raise ValueError("give --left and --right (a stereo pair) or --camera (one camera)")
    if args.camera is not None and args.covariance == "bootstrap":
        raise ValueError("--covariance bootstrap is for a stereo calibration (--left/--right): a single camera's "
                         "file stores no parameter covariance")
    if args.out.suffix.lower() in (".yaml", ".yml", ".xml"):
        raise ValueError(f"--out {args.out} names the YAML export; give the calibration JSON (e.g. "
                         f"{args.out.with_suffix('.json')}): the .yaml is written beside it")
    _calibration_target(args)
    return args.model, args.lens


def _bootstrap(cal, pairs, board, settings: dict, args):
    """``cal`` with the bootstrap covariance of ``--covariance bootstrap``, and the record written beside it."""
    import time

    from measurement.calibration.bootstrap import with_bootstrap_covariance

    print(f"  bootstrap covariance: {args.bootstrap_draws} calibrations of synthetic corners "
          f"({args.bootstrap_workers} process{'es' if args.bootstrap_workers > 1 else ''})", flush=True)
    start = time.perf_counter()
    cal, boot = with_bootstrap_covariance(cal, pairs.points_left, pairs.points_right, board, pairs.image_size,
                                          draws=args.bootstrap_draws, seed=args.bootstrap_seed,
                                          workers=args.bootstrap_workers, **settings)
    seconds = time.perf_counter() - start
    print(f"    corner noise drawn {boot.corner_sigma_px['left']:.4f} / {boot.corner_sigma_px['right']:.4f} px "
          f"(left / right); {boot.draws} draws kept, {boot.failed} refused, {boot.not_converged} not converged, "
          f"{boot.wrong_minimum} in a worse minimum; "
          f"{seconds:.0f} s")
    return cal, {"draws": boot.draws, "refused": boot.failed, "not_converged": boot.not_converged,
                 "wrong_minimum": boot.wrong_minimum,
                 "seed": boot.seed, "corner_sigma_px": boot.corner_sigma_px, "seconds": round(seconds, 1)}


def _print_significance(cal, model: str | None = None) -> None:
    """Each optional term's value / sigma on stdout; the terms the data do not determine as warnings on stderr."""
    from measurement.calibration.model_selection import significance_lines

    lines, warns = significance_lines(cal, model=model)
    if lines:
        print("  terms beyond the pinhole camera with k1 k2 p1 p2 (value ± sigma, z = |value| / sigma):")
        print("\n".join(lines))
    for w in warns:
        print(f"warning: {w}", file=sys.stderr)


def _calibrate_one_camera(args) -> int:
    """``workbench calibrate --camera GLOB``: steps 1-4 (and the final refinement) of one camera."""
    import warnings

    from measurement.calibration.images import MIN_VIEWS, detect_views, target_points_mm
    from measurement.calibration.io import opencv_camera_yaml_text, save_camera_calibration
    from measurement.calibration.model_selection import select_camera_model, term_significance
    from measurement.calibration.stepwise import calibrate_camera
    from workbench.manifest import write_texts_together

    files = glob_files(args.camera, "--camera")
    if len(files) < MIN_VIEWS:
        raise ValueError(f"calibration needs at least {MIN_VIEWS} images; --camera {args.camera!r} matches {len(files)}")
    yaml_out = args.out.with_suffix(".yaml")
    output_file(args.out)
    output_file(yaml_out, "the YAML export beside --out")
    target = _calibration_target(args)
    views = detect_views(files, args.pattern, refine=args.refine_corners, target=target)
    board = target_points_mm(target, args.pattern, args.square_mm)
    candidates = _auto_candidates(args.model, args.lens)
    rows = []
    if len(candidates) > 1:
        (model, lens), rows = select_camera_model(views.points, board, views.image_size, candidates=candidates,
                                                  folds=args.folds, tilt_guess_deg=args.tilt_guess_deg)
        print(f"  model selection over {len(rows)} candidates ({min(args.folds, len(views.files))}-fold held-out "
              "views; simplest within one standard error of the best):")
        for r in rows:
            print(f"    {r['model']:<8} {r['lens']:<7} held-out MSE {r['held_out_mse_px2']:.5f} ± {r['se_px2']:.5f} "
                  f"px²{'  <- chosen' if r['chosen'] else ''}")
    else:
        model, lens = candidates[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cal = calibrate_camera(views.points, board, views.image_size, model=model, tilt_guess_deg=args.tilt_guess_deg,
                               lens=lens)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    extra = {"images": {"files": views.files, "dropped": views.dropped},
             "significance": term_significance(cal, model)["camera"],
             **({"model_selection": {"rule": "simplest candidate within one standard error of the lowest held-out "
                                              "MSE", "candidates": rows}} if rows else {})}
    import tempfile

    with tempfile.TemporaryDirectory(prefix="workbench-calibrate-") as tmp:     # validated text, then both files
        json_path = Path(tmp) / "camera.json"
        save_camera_calibration(cal, json_path, model=model, extra=extra)
        json_text = json_path.read_text(encoding="utf-8")
    write_texts_together({args.out: json_text, yaml_out: opencv_camera_yaml_text(cal, yaml_out)})
    print(f"calibrated one camera ({model}, lens {lens}) from {len(views.files)} images ({len(views.dropped)} dropped)")
    params = ", ".join(f"{n}={getattr(cal.camera, n):.5g}±{cal.sigma.get(n, 0.0):.2g}" for n in _parameter_names(lens)
                       if not (model == "pinhole" and n in ("alpha_deg", "beta_deg")))
    print(f"  reprojection RMS {cal.rms_px:.4f} px; {params}")
    _print_significance(cal, model)
    print(f"  wrote {args.out} and {yaml_out}")
    return 0


def calibrate_command(args) -> int:
    from measurement.calibration.images import MIN_VIEWS, calibrate_from_files
    from workbench.manifest import write_texts_together

    # Options and inputs are checked before any board is detected.
    model, lens = _calibration_check(args)
    if args.camera is not None:
        return _calibrate_one_camera(args)
    output_file(args.out)
    yaml_out = args.out.with_suffix(".yaml")
    output_file(yaml_out, "the YAML export beside --out")
    left, right = paired_globs(args.left, args.right)
    if len(left) < MIN_VIEWS:
        raise ValueError(f"calibration needs at least {MIN_VIEWS} stereo pairs; --left {args.left!r} matches "
                         f"{len(left)}")
    first = None
    for f in left + right:
        image = read_image_for(f, "image")
        if first is None:
            first = (image.shape, f)
        elif image.shape != first[0]:
            raise ValueError(f"image {f} is {size_text(image)} but {first[1]} is {first[0][1]} x {first[0][0]} px: all "
                             "images must have one size")
    guess_r = args.tilt_guess_right_deg or (args.tilt_guess_deg[0], -args.tilt_guess_deg[1])
    from measurement.calibration.images import target_points_mm
    from measurement.calibration.stepwise import calibrate_stereo, canonical_lens

    target = _calibration_target(args)
    board = target_points_mm(target, args.pattern, args.square_mm)
    settings = dict(tilt_guess_left_deg=args.tilt_guess_deg, tilt_guess_right_deg=guess_r, joint=not args.no_joint)
    comparison = selection = None
    extra = {}
    if "auto" in (model, lens):
        from measurement.calibration import images
        from measurement.calibration.model_selection import select_model

        pairs = images.detect_pairs(left, right, args.pattern, refine=args.refine_corners, target=target)
        selection = select_model(pairs.points_left, pairs.points_right, board, pairs.image_size,
                                 candidates=_auto_candidates(model, lens), folds=args.folds,
                                 progress=lambda text: print(f"  fitting {text}", flush=True), **settings)
        cal = selection.calibration
        extra["model_selection"] = selection.to_dict()
    else:
        lens = canonical_lens(lens)
        cal, pairs = calibrate_from_files(left, right, square_mm=args.square_mm, pattern_size=args.pattern,
                                          model=model, refine_corners=args.refine_corners, target=target,
                                          lens="brown4" if lens == "brown5" else lens, **settings)
        if lens == "brown5":
            # the four-term fit above is the reference of the comparison; the five-term one is what is written
            from measurement.calibration.stepwise import compare_lens_models

            brown5 = calibrate_stereo(pairs.points_left, pairs.points_right, board, pairs.image_size, lens="brown5",
                                      model=model, **settings)
            comparison = compare_lens_models(pairs.points_left, pairs.points_right, board, pairs.image_size,
                                             brown4=cal, brown5=brown5, model=model, **settings)
            cal = brown5
            extra["lens_comparison"] = comparison
    if args.covariance == "bootstrap":
        cal, extra["covariance_bootstrap"] = _bootstrap(cal, pairs, board, settings, args)
    from measurement.calibration.model_selection import term_significance

    extra["significance"] = {"rule": "z = |value| / sigma of each term beyond the pinhole camera with k1 k2 p1 p2; "
                                     "z < 3: not determined by the data", **term_significance(cal)}
    json_text, yaml_text = _calibration_texts(cal, pairs, extra)
    write_texts_together({args.out: json_text, yaml_out: yaml_text})       # both files or neither
    lens_text = "" if cal.lens == "brown4" else f" (lens {cal.lens})"
    print(f"calibrated {cal.model}{lens_text} from {len(pairs.left_files)} stereo views ({len(pairs.dropped)} images "
          f"dropped)")
    for side in ("left", "right"):
        c = getattr(cal, side)
        params = ", ".join(f"{n}={getattr(c.camera, n):.5g}±{c.sigma.get(n, 0.0):.2g}" for n in _parameter_names(cal.lens))
        print(f"  {side}: reprojection RMS {c.rms_px:.4f} px; {params}")
    if selection is not None:
        print("\n".join(selection.lines()))
    if comparison is not None:
        from measurement.calibration.stepwise import lens_comparison_lines
        print("\n".join(lens_comparison_lines(comparison)))
    _print_significance(cal)
    print(f"  stereo T = {np.round(cal.T_right_from_left_mm, 4).tolist()} mm; wrote {args.out} and {yaml_out}")
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("calibrate", None): calibrate_command}
