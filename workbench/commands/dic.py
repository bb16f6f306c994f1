"""``workbench dic``: 2-D subset DIC between a reference and a deformed image."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from workbench.commands.options import (add_auto_roi_options, auto_roi_settings, non_negative_float_arg, output_file,
                                        pair_arg, poi_grid, positive_float_arg, positive_int_arg, read_image_for,
                                        roi_arg, size_text, subset_arg, zncc_arg)


def add_parser(sub) -> None:
    """The ``dic`` subcommand."""
    dic = sub.add_parser("dic", help="2-D subset DIC between a reference and a deformed image (any 8/16-bit grey files)")
    dic.add_argument("reference", type=Path, help="reference image file")
    dic.add_argument("deformed", type=Path, help="deformed image file")
    dic.add_argument("--roi", type=roi_arg, default=None, help="rectangle of points of interest X0,Y0,X1,Y1 (px)")
    dic.add_argument("--mask", type=Path, default=None, help="image whose non-zero pixels may hold points of interest")
    dic.add_argument("--subset", type=subset_arg, default=33, help="subset size 2M+1 (odd, px), default 33")
    dic.add_argument("--step", type=positive_int_arg, default=8, help="grid step (px), default 8")
    dic.add_argument("--order", type=int, choices=(1, 2), default=1, help="shape function order, default 1")
    dic.add_argument("--interp", choices=("biquintic", "bicubic"), default="biquintic")
    dic.add_argument("--seed-point", type=pair_arg, action="append", default=None,
                     help="preferred seed X,Y (px); may be repeated")
    dic.add_argument("--seed-guess", type=pair_arg, default=(0.0, 0.0),
                     help="displacement U,V (px) at which the seed search is centred, default 0,0")
    dic.add_argument("--search-radius", type=positive_int_arg, default=32, help="seed search half-width (px)")
    dic.add_argument("--min-zncc", type=zncc_arg, default=0.8, help="points below this ZNCC are rejected")
    dic.add_argument("--tolerance", type=positive_float_arg, default=1e-3,
                     help="IC-GN convergence threshold (px at the subset edge)")
    dic.add_argument("--lowpass-sigma", type=non_negative_float_arg, default=0.0,
                     help="Gaussian pre-filter sigma (px), default off")
    dic.add_argument("--threads", type=positive_int_arg, default=None, help="worker threads (default: all cores)")
    dic.add_argument("--auto-roi", action="store_true",
                     help="automatic ROI: points whose reference subset lacks texture are flagged low_texture and not "
                          "correlated; converged points that disagree with their neighbours are flagged inconsistent")
    add_auto_roi_options(dic)
    dic.add_argument("--static", type=Path, default=None,
                     help="a second exposure of the unmoved reference scene: the camera's noise for the sigma columns "
                          "is measured from it (default: fitted to the match's residuals)")
    dic.add_argument("--out", type=Path, required=True, help="CSV of the points (x,y,u,v,zncc,iterations,status,...)")


def dic_command(args) -> int:
    import numba

    from measurement.dic import DICSettings, Status, correlate

    reference = read_image_for(args.reference, "reference image")
    deformed = read_image_for(args.deformed, "deformed image")
    if reference.shape != deformed.shape:
        raise ValueError(f"{args.reference} is {reference.shape[1]} x {reference.shape[0]} px but {args.deformed} is "
                         f"{deformed.shape[1]} x {deformed.shape[0]} px: the images must have the same size")
    static = None
    if args.static is not None:
        static = read_image_for(args.static, "--static")
        if static.shape != reference.shape:
            raise ValueError(f"--static {args.static} is {size_text(static)} but the reference is {size_text(reference)}")
    output_file(args.out)
    mask = None
    if args.mask is not None:
        mask_image = read_image_for(args.mask, "--mask")
        if mask_image.shape != reference.shape:
            raise ValueError(f"--mask {args.mask} is {size_text(mask_image)} but the images are {size_text(reference)}")
        mask = mask_image != 0
    h, w = reference.shape
    for x, y in args.seed_point or ():
        if not (0 <= x <= w - 1 and 0 <= y <= h - 1):
            raise ValueError(f"--seed-point {x:g},{y:g} is outside the {size_text(reference)} image "
                             f"(0 <= X <= {w - 1}, 0 <= Y <= {h - 1})")
    u, v = args.seed_guess
    if abs(u) >= w or abs(v) >= h:
        raise ValueError(f"--seed-guess {u:g},{v:g} moves the seed search outside the {size_text(reference)} image")
    grid = poi_grid(reference, args, mask)
    auto_roi = auto_roi_settings(args)
    settings = DICSettings(subset_size=args.subset, step=args.step, order=args.order, interpolation=args.interp,
                           search_radius_px=args.search_radius, min_zncc=args.min_zncc,
                           tolerance_px=args.tolerance, lowpass_sigma_px=args.lowpass_sigma)
    if args.threads:
        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    report = None
    try:
        if auto_roi is None:
            result = correlate(reference, deformed, settings, grid=grid, seed_points_xy=args.seed_point,
                               seed_guess_px=args.seed_guess)
        else:
            from measurement.dic.roi import correlate_auto_roi

            result, report = correlate_auto_roi(reference, deformed, settings, grid=grid, auto_roi=auto_roi,
                                                seed_points_xy=args.seed_point, seed_guess_px=args.seed_guess)
    except ValueError as err:
        if str(err).startswith("seed point"):
            raise ValueError(f"--seed-point: {err}") from None
        raise
    noise = None
    if static is not None:
        from measurement.uncertainty.noise import static_pair_noise_2d

        repeat = correlate(reference, static, settings, grid=grid, seed_points_xy=args.seed_point)
        noise = static_pair_noise_2d(reference, static, repeat, what=f"--static {args.static}")
    if result.converged.sum() >= 20:
        from measurement.uncertainty.match import dic_uncertainty

        # without a static pair the noise is fitted to the match's own residuals (stated in the output)
        result.uncertainty = dic_uncertainty(reference, result, noise, target=deformed, bias=True)
    result.to_csv(args.out)
    ok = result.converged
    counts = ", ".join(f"{name.lower()} {n}" for name, n in result.status_counts().items())
    print(f"{result.x.size} points ({counts}) in {result.timings_s['total']:.2f} s; wrote {args.out}")
    if report is not None:
        print(report.summary())
    if result.uncertainty is not None:
        summary = result.uncertainty.summary()
        print(f"  uncertainty: median sigma u {summary['median_sigma_u_px']:.4f} px, v {summary['median_sigma_v_px']:.4f} "
              f"px (noise from the {summary['noise_source']}: {result.uncertainty.noise_reference.sigma_grey:.3g} grey); "
              f"{100 * summary['flagged_fraction']:.1f} % of the points flagged (residual above the noise)")
    if ok.any():
        print(f"  u {np.nanmin(result.u):.4f} .. {np.nanmax(result.u):.4f} px, v {np.nanmin(result.v):.4f} .. "
              f"{np.nanmax(result.v):.4f} px, median ZNCC {np.median(result.zncc[ok]):.4f}, "
              f"mean iterations {result.iterations[ok].mean():.2f}")
    else:
        print(f"workbench dic: error: no point converged (statuses: "
              f"{', '.join(Status(s).name for s in np.unique(result.status))})", file=sys.stderr)
        return 1
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("dic", None): dic_command}
