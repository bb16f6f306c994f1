"""``workbench stereo``: stereo-DIC of an image sequence with a calibration file."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from workbench.commands.options import (add_auto_roi_options, auto_roi_settings, fraction_arg, input_file,
                                        output_folder, paired_globs, poi_grid, positive_float_arg, positive_int_arg,
                                        read_image_for, resolved, roi_arg, size_text, strain_window_arg, subset_arg,
                                        zncc_arg)


def add_parser(sub) -> None:
    """The ``stereo`` subcommand."""
    from measurement.stereo_dic import MAX_MEDIAN_RESIDUAL_PX, MIN_MEASURED_FRACTION

    st = sub.add_parser("stereo", help="stereo-DIC of an image sequence with a calibration file (real or rendered)")
    st.add_argument("--calib", type=Path, required=True, help="calibration JSON (workbench calibrate) or OpenCV YAML")
    st.add_argument("--left-ref", type=Path, required=True, help="left reference image")
    st.add_argument("--right-ref", type=Path, required=True, help="right reference image")
    st.add_argument("--left", required=True, help="glob of left deformed images (sorted; paired with --right)")
    st.add_argument("--right", required=True, help="glob of right deformed images")
    st.add_argument("--roi", type=roi_arg, default=None, help="rectangle of points on the left reference X0,Y0,X1,Y1")
    st.add_argument("--mask", type=Path, default=None,
                    help="image (the left reference's size) whose non-zero pixels may hold points of interest")
    st.add_argument("--subset", type=subset_arg, default=65, help="subset size (odd, px), default 65")
    st.add_argument("--step", type=positive_int_arg, default=5, help="grid step (px), default 5")
    st.add_argument("--order", type=int, choices=(1, 2), default=2)
    st.add_argument("--min-zncc", type=zncc_arg, default=0.8)
    st.add_argument("--max-residual-px", type=positive_float_arg, default=MAX_MEDIAN_RESIDUAL_PX,
                    help="refuse the reference or a state whose median triangulation residual is above this "
                         f"(px), default {MAX_MEDIAN_RESIDUAL_PX:g}")
    st.add_argument("--min-measured-fraction", type=fraction_arg, default=MIN_MEASURED_FRACTION,
                    help="refuse the reference (of its points) or a state (of the reference's points) measuring less "
                         f"than this fraction, default {MIN_MEASURED_FRACTION:g}")
    st.add_argument("--auto-roi", action="store_true",
                    help="automatic ROI: points whose left-reference subset lacks texture are flagged low_texture "
                         "and not matched; matches that disagree with their neighbours are flagged inconsistent")
    add_auto_roi_options(st)
    st.add_argument("--strain-window", type=strain_window_arg, default=9, metavar="K|triangles|none",
                    help="surface strain of every state (Green-Lagrange, columns exx..e2 and their sigma): a window of "
                         "K x K grid points (odd, >= 3; the virtual strain gauge is (K - 1) x step + subset px, printed "
                         "in mm too), 'triangles' (the paper's Cosserat elements, no sigma) or 'none'; default 9")
    st.add_argument("--strain-fit", choices=("linear", "quadratic"), default="linear",
                    help="order of the strain window's displacement fit, default linear")
    st.add_argument("--static-left", type=Path, default=None,
                    help="a second exposure of the unmoved reference scene, left camera (with --static-right): each "
                         "camera's noise for the uncertainty columns is measured from it; without, the noise is "
                         "fitted to the stereo match's residuals")
    st.add_argument("--static-right", type=Path, default=None, help="the static pair's right image")
    st.add_argument("--overwrite", action="store_true",
                    help="replace earlier results in --out (deletes exactly the files its manifest.json lists)")
    st.add_argument("--out", type=Path, required=True,
                    help="output folder (CSV + VTK per state, summary.csv, manifest.json); exit 1 if a state failed")


def load_rig(path: Path, image_size_px: tuple[int, int] | None = None):
    """Any calibration file the instrument reads (JSON, OpenCV YAML/XML, DICe, VIC-3D, MatchID: detected from the
    content); ``image_size_px`` for a format that holds none (MatchID)."""
    from measurement.calibration.formats import load_any_calibration

    if path.is_dir():
        raise ValueError(f"--calib {path} is a directory, not a calibration file")
    if not path.is_file():
        raise ValueError(f"calibration file not found: {path}")
    return load_any_calibration(path, image_size_px=image_size_px)


def _check_against_calibration(image: np.ndarray, camera, what: str) -> None:
    if image.shape != (camera.height, camera.width):
        raise ValueError(f"{what} is {size_text(image)} but the calibration is for {camera.width} x {camera.height} px")


def _image_record(state: int, result_file: str, left, right, left_image, right_image) -> dict:
    """The manifest's record of one result file: its state number, the images it measured (absolute paths) and
    their :func:`workbench.results.pixels_sha256`."""
    from workbench.results import pixels_sha256

    return {"state": state, "file": result_file, "left": str(resolved(Path(left))),
            "right": str(resolved(Path(right))), "left_pixels_sha256": pixels_sha256(left_image),
            "right_pixels_sha256": pixels_sha256(right_image)}


def stereo_command(args) -> int:
    from measurement.dic import DICSettings
    from measurement.stereo_dic import StereoMatchError, StereoQualityError, measure_state, reference_shape
    from measurement.stereo_io import write_state_csv, write_state_summary, write_state_vtk
    from workbench.manifest import complete_folder, prepare_folder

    # Everything is checked before the first match and the first write.
    input_file(args.left_ref, "--left-ref")
    left_ref = read_image_for(args.left_ref, "--left-ref")     # its size is what a MatchID file lacks
    rig = load_rig(args.calib, (left_ref.shape[1], left_ref.shape[0]))
    input_file(args.right_ref, "--right-ref")
    if resolved(args.left_ref) == resolved(args.right_ref):
        raise ValueError(f"--left-ref and --right-ref are the same file ({args.left_ref})")
    left_files, right_files = paired_globs(args.left, args.right)
    output_folder(args.out)
    right_ref = read_image_for(args.right_ref, "--right-ref")
    _check_against_calibration(left_ref, rig.left, f"--left-ref {args.left_ref}")
    _check_against_calibration(right_ref, rig.right, f"--right-ref {args.right_ref}")
    for fl, fr in zip(left_files, right_files):
        _check_against_calibration(read_image_for(fl, "left image"), rig.left, f"left image {fl}")
        _check_against_calibration(read_image_for(fr, "right image"), rig.right, f"right image {fr}")
    if (args.static_left is None) != (args.static_right is None):
        raise ValueError("--static-left and --static-right go together (a static pair of both cameras)")
    static = None
    if args.static_left is not None:
        input_file(args.static_left, "--static-left")
        input_file(args.static_right, "--static-right")
        static = (read_image_for(args.static_left, "--static-left"), read_image_for(args.static_right, "--static-right"))
        _check_against_calibration(static[0], rig.left, f"--static-left {args.static_left}")
        _check_against_calibration(static[1], rig.right, f"--static-right {args.static_right}")
    mask = None
    if args.mask is not None:
        mask_image = read_image_for(args.mask, "--mask")
        if mask_image.shape[:2] != left_ref.shape[:2]:
            raise ValueError(f"--mask {args.mask} is {size_text(mask_image)} but the left reference is {size_text(left_ref)}")
        mask = mask_image != 0 if mask_image.ndim == 2 else np.any(mask_image != 0, axis=-1)
    poi_grid(left_ref, args, mask, what="left reference image")
    auto_roi = auto_roi_settings(args)
    settings = DICSettings(subset_size=args.subset, step=args.step, order=args.order, min_zncc=args.min_zncc)
    strain_settings = None
    if args.strain_window is not None:
        from measurement.stereo_strain import StrainSettings

        window = None if args.strain_window == "triangles" else args.strain_window
        if window is None and args.strain_fit != "linear":
            raise ValueError("--strain-fit quadratic needs a strain window (--strain-window K), not triangles")
        strain_settings = StrainSettings(window, args.strain_fit)
    # One numbering everywhere: the reference is state 0, the k-th deformed pair state k (as in a dataset).
    names = [f"state_{k:03d}" for k in range(1, len(left_files) + 1)]
    planned = ["reference.csv", "reference.vtk", "summary.csv"] + [f"{n}.{e}" for n in names for e in ("csv", "vtk")]
    prepare_folder(args.out, "stereo", planned, overwrite=args.overwrite, dry_run=True)
    thresholds = dict(max_median_residual_px=args.max_residual_px, min_measured_fraction=args.min_measured_fraction)
    hint = (f" (calibration {args.calib}; thresholds: --max-residual-px {args.max_residual_px:g}, "
            f"--min-measured-fraction {args.min_measured_fraction:g})")

    try:
        shape = reference_shape(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, left_ref,
                                right_ref, settings, roi=args.roi, mask=mask, auto_roi=auto_roi, **thresholds)
    except StereoQualityError as err:
        raise ValueError(f"{err}{hint}") from None
    if static is not None:
        from measurement.stereo_dic import shape_uncertainty
        from measurement.uncertainty.noise import static_pair_noise_stereo

        what = f"the static pair ({args.static_left}, {args.static_right})"
        try:
            repeat = measure_state(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, shape,
                                   left_ref, *static, settings, name=what, **thresholds)
        except StereoMatchError as err:
            raise ValueError(f"{what}: {err}") from None
        noise = static_pair_noise_stereo(shape, repeat, left_ref, right_ref, *static)
        shape_uncertainty(shape, rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, settings, noise)
    from measurement.stereo_dic import calibration_uncertainty

    calibration_uncertainty(shape, None, rig)       # NaN, with a warning, for a calibration without covariance
    strains = None
    if strain_settings is not None:
        from measurement.stereo_strain import SequenceStrain

        cameras = (rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm)
        try:
            strains = SequenceStrain(shape, cameras, strain_settings)
        except ValueError as err:
            raise ValueError(f"--strain-window: {err}") from None
    prepare_folder(args.out, "stereo", planned, overwrite=args.overwrite)
    reference_strain = strains.reference() if strains is not None else None
    written = [write_state_csv(args.out / "reference.csv", shape, strain=reference_strain).name,
               write_state_vtk(args.out / "reference.vtk", shape, strain=reference_strain).name]
    q = shape.quality
    print(f"reference: {q.measured}/{shape.x.size} points triangulated, median residual {q.median_residual_px:.4f} px, "
          f"95th percentile {q.p95_residual_px:.4f} px")
    if shape.noise is not None:
        print(f"uncertainty: camera noise from the {shape.noise['left'].source} (left {shape.noise['left'].sigma_grey:.3g}"
              f" grey, right {shape.noise['right'].sigma_grey:.3g} grey)")
    if shape.auto_roi_report is not None:
        print(f"reference {shape.auto_roi_report.summary()}")
    if strains is not None:
        what = ("triangles (Cosserat elements)" if strain_settings.window is None else
                f"window {strain_settings.window} x {strain_settings.window} points, {strain_settings.fit} fit")
        no_sigma = "" if strains.has_sigma else (" (no strain sigma: the triangles have no windowed fit)"
                                                 if strain_settings.window is None else " (no strain sigma)")
        print(f"strain: Green-Lagrange, {what}; virtual strain gauge {strains.gauge_px:g} px = {strains.gauge_mm:.3g} mm "
              f"on the specimen{no_sigma}")
    from measurement.stereo_io import sigma_summary, strain_summary

    rows = [{"state": "reference", "left": str(args.left_ref), "right": str(args.right_ref), "quality": q,
             **sigma_summary(shape)}]
    # What each result file measured (by the images' grey levels): `workbench score` identifies its state by them.
    images = [_image_record(0, "reference.csv", args.left_ref, args.right_ref, left_ref, right_ref)]
    from tqdm import tqdm

    from measurement.image_io import read_grey
    skipped = []
    previous = None     # each state seeds the next (measure_state's warm start)
    for i, (fl, fr) in enumerate(tqdm(list(zip(left_files, right_files)), desc="stereo states")):
        k = i + 1
        what = f"state {k} ({fl}, {fr})"
        left_def, right_def = read_grey(fl), read_grey(fr)
        try:
            state = measure_state(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, shape,
                                  left_ref, left_def, right_def, settings, name=what, previous=previous,
                                  **thresholds)
        except StereoMatchError as err:
            message = f"{err}{hint}" if isinstance(err, StereoQualityError) else f"{what}: {err}"
            tqdm.write(f"workbench stereo: state {k} skipped: {message}", file=sys.stderr)
            skipped.append(k)
            rows.append({"state": names[i], "left": fl, "right": fr, "quality": getattr(err, "quality", None),
                         "error": message})
            continue
        previous = state
        calibration_uncertainty(shape, state, rig)
        strain = strains.state(state) if strains is not None else None
        written += [write_state_csv(args.out / f"{names[i]}.csv", shape, state, strain).name,
                    write_state_vtk(args.out / f"{names[i]}.vtk", shape, state, strain).name]
        images.append(_image_record(k, f"{names[i]}.csv", fl, fr, left_def, right_def))
        q = state.quality
        rows.append({"state": names[i], "left": fl, "right": fr, "quality": q,
                     "mean_D_mm": float(np.nanmean(state.D_mm[state.valid])), **sigma_summary(shape, state),
                     **(strain_summary(shape, strain) if strain is not None else {})})
        tqdm.write(f"state {k} ({Path(fl).name}, {Path(fr).name}): {q.measured}/{q.points} points, median residual "
                   f"{q.median_residual_px:.4f} px, 95th percentile {q.p95_residual_px:.4f} px, mean D "
                   f"{rows[-1]['mean_D_mm']:.4f} mm; median sigma U, V, W {rows[-1]['median_sigma_U_um']:.3g}, "
                   f"{rows[-1]['median_sigma_V_um']:.3g}, {rows[-1]['median_sigma_W_um']:.3g} µm, "
                   f"{100 * rows[-1]['sigma_flagged_fraction']:.1f} % flagged")
        if strain is not None and "max_e1" in rows[-1]:
            r = rows[-1]
            tqdm.write(f"state {k} strain: largest e1 {1e6 * r['max_e1']:.0f} µε at ({r['max_e1_x_px']:g}, "
                       f"{r['max_e1_y_px']:g}) px, smallest e2 {1e6 * r['min_e2']:.0f} µε"
                       + (f", median sigma exx {1e6 * r['median_sigma_exx']:.3g} µε" if "median_sigma_exx" in r else ""))
        if state.auto_roi_report is not None:
            tqdm.write(f"state {k} {state.auto_roi_report.summary()}")
    written.append(write_state_summary(args.out / "summary.csv", rows).name)
    complete_folder(args.out, "stereo", written,
                    {"calib": str(args.calib), "left_ref": str(args.left_ref), "right_ref": str(args.right_ref),
                     "left": args.left, "right": args.right, "roi": args.roi,
                     "mask": None if args.mask is None else str(args.mask), "subset": args.subset,
                     "step": args.step, "order": args.order, "min_zncc": args.min_zncc, **thresholds,
                     "auto_roi": None if auto_roi is None else vars(auto_roi) | {"noise_sigma_used_grey":
                                                                                  shape.noise_sigma_grey},
                     "skipped_states": skipped, "images": images,
                     "strain": None if strains is None else strains.description(),
                     "static_left": None if args.static_left is None else str(args.static_left),
                     "static_right": None if args.static_right is None else str(args.static_right),
                     "noise": {side: {"source": m.source, "sigma_grey": m.sigma_grey,
                                      "read_noise_grey": m.read_noise_grey, "electrons_per_grey": m.electrons_per_grey}
                               for side, m in (shape.noise or {}).items()}})
    print(f"wrote {args.out} ({len(left_files) - len(skipped)} of {len(left_files)} states; summary.csv)")
    if skipped:
        print(f"workbench stereo: error: {len(skipped)} of {len(left_files)} states could not be measured (states "
              f"{', '.join(map(str, skipped))}; see the messages above and {args.out / 'summary.csv'})",
              file=sys.stderr)
        return 1
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("stereo", None): stereo_command}
