"""``workbench twin``: a digital twin of the user's own rig, what it will measure before the test (issue 24).

    workbench twin --calib cal.xml --left L0.tif --right R0.tif [--static-left L1.tif --static-right R1.tif] \\
        [--roi X0,Y0,X1,Y1 | --mask M.png | --auto-roi] [--subset 33] [--step 8] [--order 2] \\
        [--strain-window 5] [--bit-depth 12] [--repeats 2] [--objective displacement|strain] --out twin/
    workbench twin --left ref.tif --static-left ref2.tif --out twin2d/      (one camera, no calibration: px)

Writes report.html (self-contained), report.md, twin.json, twin_points.csv and the figures into --out; prints
the predicted noise floor (beside the measured one with a static pair) and the top what-if recommendation.
"""
from __future__ import annotations

from pathlib import Path

from workbench.commands.options import (input_file, output_folder, positive_float_arg, positive_int_arg, roi_arg,
                                        seed_arg, subset_arg)


def _window_arg(text: str) -> int | None:
    if text.lower() in ("none", "triangles"):
        return None
    value = positive_int_arg(text)
    if value < 3 or value % 2 == 0:
        import argparse
        raise argparse.ArgumentTypeError(f"the strain window must be an odd number of grid points >= 3, got {text}")
    return value


def _order_arg(text: str) -> int:
    if text not in ("1", "2"):
        import argparse
        raise argparse.ArgumentTypeError(f"order must be 1 or 2, got {text!r}")
    return int(text)


def add_parser(sub) -> None:
    tw = sub.add_parser("twin", help="a digital twin of your rig from its calibration and images: predicted noise "
                                     "floor (U, V, W in µm, strain in µε), bias, l10 and a what-if table; checked "
                                     "against your static pair when given")
    tw.add_argument("--calib", type=Path, help="the rig's calibration (project JSON, OpenCV YAML/XML, DICe cal.xml, "
                                               "VIC-3D XML, MATLAB); without it a one-camera twin in px")
    tw.add_argument("--left", type=Path, required=True, help="left (or only) camera's reference image")
    tw.add_argument("--right", type=Path, help="right camera's reference image (stereo)")
    tw.add_argument("--static-left", type=Path, help="a second exposure of the unmoved scene, left camera")
    tw.add_argument("--static-right", type=Path, help="a second exposure of the unmoved scene, right camera")
    region = tw.add_mutually_exclusive_group()
    region.add_argument("--roi", type=roi_arg, help="X0,Y0,X1,Y1 on the left image, px")
    region.add_argument("--mask", type=Path, help="mask image of the left image's size (non-zero = measure)")
    region.add_argument("--auto-roi", action="store_true", help="measure only subsets with enough texture")
    tw.add_argument("--subset", type=subset_arg, default=33, help="subset size (odd, px), default 33")
    tw.add_argument("--step", type=positive_int_arg, help="grid step (px), default a quarter of the subset")
    tw.add_argument("--order", type=_order_arg, default=2, help="shape function order 1 or 2 (default 2)")
    tw.add_argument("--interp", choices=("biquintic", "bicubic"), default="biquintic")
    tw.add_argument("--strain-window", type=_window_arg, default=5,
                    help="strain window in grid points (odd >= 3), or 'triangles'; default 5")
    tw.add_argument("--bit-depth", type=int, choices=(8, 10, 12, 14, 16),
                    help="the bits of the image data, if you know them (checked against the files)")
    tw.add_argument("--repeats", type=positive_int_arg, default=2, help="twin static pairs (default 2)")
    tw.add_argument("--objective", choices=("displacement", "strain"), default="displacement",
                    help="what the what-if table ranks by")
    tw.add_argument("--no-whatif", action="store_true", help="skip the what-if table")
    tw.add_argument("--allow-coarse", action="store_true",
                    help="go on when the speckle is too fine or too coarse for any subset")
    tw.add_argument("--texture", choices=("photo", "generated"), default="photo",
                    help="the twin's pattern: your photograph (default) or a generated speckle with its statistics")
    tw.add_argument("--f-number", type=positive_float_arg,
                    help="the lenses' f-number (with --pixel-pitch-um: adds f-number and focus rows to the what-if)")
    tw.add_argument("--pixel-pitch-um", type=positive_float_arg, help="the sensor's pixel pitch, µm")
    tw.add_argument("--wavelength-nm", type=positive_float_arg, default=550.0,
                    help="light wavelength for diffraction, nm (default 550)")
    tw.add_argument("--seed", type=seed_arg, default=0)
    tw.add_argument("--out", type=Path, required=True, help="output folder")


def twin_command(args) -> int:
    import time

    from workbench.twin import TwinSettings, run_twin, write_twin_report
    from workbench.twin.whatif import advice

    for option in ("calib", "left", "right", "static_left", "static_right", "mask"):
        value = getattr(args, option)
        if value is not None:
            input_file(value, f"--{option.replace('_', '-')}")
    output_folder(args.out)
    if (args.f_number is None) != (args.pixel_pitch_um is None):
        raise ValueError("--f-number and --pixel-pitch-um go together (the lens rows need both)")
    lens = None
    if args.f_number is not None:
        from workbench.twin.optics import Lens

        lens = Lens(args.f_number, args.pixel_pitch_um, args.wavelength_nm)
    start = time.perf_counter()

    def progress(message: str) -> None:
        print(f"[{time.perf_counter() - start:6.1f} s] {message}", flush=True)

    result = run_twin(args.left, args.right, args.static_left, args.static_right, calibration=args.calib,
                      roi=args.roi, mask=args.mask, auto_roi=args.auto_roi,
                      settings=TwinSettings(args.subset, args.step, args.order, args.interp, args.strain_window),
                      bit_depth=args.bit_depth, repeats=args.repeats, seed=args.seed, whatif=not args.no_whatif,
                      objective=args.objective, allow_coarse=args.allow_coarse, lens=lens, texture=args.texture,
                      progress=progress)
    html = write_twin_report(result, args.out)
    unit = result.unit
    print("predicted static noise (1 sigma): " + ", ".join(
        f"{k.split('_')[0]} {v:.3g} {unit}" for k, v in result.prediction["noise"].items()) + "; strain " + ", ".join(
        f"{k} {v:.3g} µε" for k, v in result.prediction["strain_ue"].items()))
    if result.prediction.get("instrument_sigma"):
        print("instrument's sigma (measurement.uncertainty): " + ", ".join(
            f"{k.split('_')[0]} {v:.3g} {unit}" for k, v in result.prediction["instrument_sigma"].items()))
    if result.comparison:
        print("measured on your static pair: " + ", ".join(
            f"{k.split('_')[0]} {c['measured']:.3g} (predicted/measured {c['ratio']:.2f}, instrument's sigma/measured "
            f"{c['instrument_ratio']:.2f})" for k, c in result.comparison.items() if not k.endswith("_ue")))
    if result.whatif:
        for line in advice(result.whatif)["lines"]:       # the report's verdict, word for word
            print(line)
    print(f"wrote {html} ({time.perf_counter() - start:.0f} s)")
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("twin", None): twin_command}
