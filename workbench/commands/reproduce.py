"""``workbench reproduce WHAT``: the paper's checks, each writing a report.

WHAT: agreement, calibration, rigid-motion, bending, fig6-causes, paper, dic-accuracy, depth-of-field, star, catalog,
uncertainty.
"""
from __future__ import annotations

from pathlib import Path

from workbench.commands.options import (angle_deg_arg, draws_arg, integer_arg, non_negative_float_arg, output_folder,
                                        positive_float_arg, positive_int_arg, scale_arg, seed_arg, subset_arg,
                                        views_arg)
from workbench.commands.sweep import run_study


def add_speckle_renderer_option(parser) -> None:
    """``--renderer auto|mitsuba`` of the experiments that render speckle states."""
    parser.add_argument("--renderer", choices=("auto", "mitsuba"), default="auto",
                        help="speckle states: auto renders without Monte Carlo where a view allows it (pinhole: exact "
                             "coverage, Gauss-Legendre quadrature of the speckle), Mitsuba elsewhere; mitsuba: always "
                             "Monte Carlo at --spp")


def add_parser(sub) -> None:
    """The ``reproduce`` subcommand."""
    rep = sub.add_parser("reproduce", help="run one of the paper's checks and write a report")
    repsub = rep.add_subparsers(dest="what", required=True)
    ag = repsub.add_parser("agreement", help="render <-> camera-model agreement at checkerboard corners")
    ag.add_argument("--rig", default="paper")
    ag.add_argument("--views", type=views_arg, default=2)
    ag.add_argument("--seed", type=seed_arg, default=0)
    ag.add_argument("--scale", type=scale_arg, default=1.0)
    ag.add_argument("--spp", type=positive_int_arg, default=256)
    ag.add_argument("--mc-target-grey", type=positive_float_arg, default=None,
                    help="render with the adaptive renderer at this Monte-Carlo noise (grey RMS) instead of --spp")
    ag.add_argument("--renderer", choices=("mitsuba", "exact"), default="mitsuba",
                    help="whose agreement with the camera model: Mitsuba's sensor plugin (default) or the exact "
                         "polygon renderer")
    ag.add_argument("--out", type=Path, required=True)
    rc = repsub.add_parser("calibration", help="the paper's calibration protocol on rendered views (Table 1, Fig 5)")
    rc.add_argument("--scale", type=scale_arg, default=1.0)
    rc.add_argument("--seed", type=seed_arg, default=0)
    rc.add_argument("--spp", type=positive_int_arg, default=64)
    rc.add_argument("--renderer", choices=("auto", "mitsuba"), default="auto",
                    help="board views: exact box-filtered polygons where possible (auto) or Monte Carlo (mitsuba)")
    rc.add_argument("--noise-grey", type=non_negative_float_arg, default=1.0)
    rc.add_argument("--calibration-views", type=views_arg, default=30)
    rc.add_argument("--validation-views", type=views_arg, default=20)
    rc.add_argument("--refine-corners", action="store_true", help="saddle-fit refinement of OpenCV's corners")
    rc.add_argument("--covariance", choices=("linear", "bootstrap"), default="linear",
                    help="parameter covariance stored with each calibration: linear (default) or bootstrap "
                         "(--bootstrap-draws recalibrations of synthetic corners; see `workbench calibrate`)")
    rc.add_argument("--bootstrap-draws", type=draws_arg, default=40,
                    help="calibrations of the --covariance bootstrap (default 40)")
    rc.add_argument("--store", type=Path, default=None,
                    help="dataset store: renders kept by content hash and reused (default $WORKBENCH_STORE or "
                         "~/.cache/scheimpflug-dic-workbench/datasets)")
    rc.add_argument("--out", type=Path, required=True)
    rm = repsub.add_parser("rigid-motion", help="the paper's rigid-motion test (Fig 6) on rendered states, scored")
    rm.add_argument("--scale", type=scale_arg, default=1.0)
    rm.add_argument("--calib", default="rendered",
                    help="'rendered' (reproduced from rendered boards, default), 'true' (the true rig) or a file")
    rm.add_argument("--lens", choices=("thin", "pinhole"), default="pinhole",
                    help="pinhole (default) or thin lens at f/8 with the rig's tilted sensors (its focus plane misses the face)")
    rm.add_argument("--seed", type=seed_arg, default=0)
    rm.add_argument("--spp", type=positive_int_arg, default=64)
    add_speckle_renderer_option(rm)
    rm.add_argument("--f-number", type=positive_float_arg, default=8.0,
                    help="the lens' aperture for its diffraction on the speckle states (default 8)")
    rm.add_argument("--ideal-optics", action="store_true", help="no diffraction (the images as rendered)")
    rm.add_argument("--subset", type=subset_arg, default=65)
    rm.add_argument("--step", type=positive_int_arg, default=5)
    rm.add_argument("--store", type=Path, default=None,
                    help="dataset store: renders kept by content hash and reused (default $WORKBENCH_STORE or "
                         "~/.cache/scheimpflug-dic-workbench/datasets)")
    rm.add_argument("--out", type=Path, required=True)
    bd = repsub.add_parser("bending", help="the paper's three-point bending test (Figs 7-8): FE truth, strain, scored")
    bd.add_argument("--scale", type=scale_arg, default=1.0)
    bd.add_argument("--rig", choices=("scheimpflug", "paper"), default="scheimpflug",
                    help="scheimpflug (tilts from the Scheimpflug condition, default) or paper (Table 1 as printed)")
    bd.add_argument("--lens", choices=("thin", "pinhole"), default="thin")
    bd.add_argument("--calib", default="rendered",
                    help="'rendered' (reproduced from rendered boards, default), 'true' (the true rig) or a file")
    bd.add_argument("--seed", type=seed_arg, default=0)
    bd.add_argument("--spp", type=positive_int_arg, default=64)
    add_speckle_renderer_option(bd)
    bd.add_argument("--f-number", type=positive_float_arg, default=8.0,
                    help="the lens' aperture for its diffraction on the speckle states (default 8)")
    bd.add_argument("--ideal-optics", action="store_true", help="no diffraction (the images as rendered)")
    bd.add_argument("--noise-grey", type=non_negative_float_arg, default=1.0)
    bd.add_argument("--subset", type=subset_arg, default=65)
    bd.add_argument("--step", type=positive_int_arg, default=5)
    bd.add_argument("--window", type=integer_arg, default=15,
                    help="strain window (points per side, odd >= 3); 0 = per-triangle Cosserat strain, no window")
    bd.add_argument("--store", type=Path, default=None,
                    help="dataset store: renders kept by content hash and reused (default $WORKBENCH_STORE or "
                         "~/.cache/scheimpflug-dic-workbench/datasets)")
    bd.add_argument("--out", type=Path, required=True)
    ct = repsub.add_parser("catalog", help="the specimen catalog (plate with a hole, notched coupon, pressurised tube, "
                                           "beam): FE files, stereo renders with exact truth, measured and scored")
    ct.add_argument("--names", nargs="+", default=None,
                    choices=("plate_with_hole", "notched_coupon", "pressurised_cylinder", "beam"),
                    help="which specimens (default: all)")
    ct.add_argument("--scale", type=scale_arg, default=0.25)
    ct.add_argument("--subset", type=subset_arg, default=33)
    ct.add_argument("--step", type=positive_int_arg, default=8)
    ct.add_argument("--window", type=positive_int_arg, default=9, help="strain window, points per side (odd)")
    ct.add_argument("--store", type=Path, default=None,
                    help="dataset store (default $WORKBENCH_STORE or ~/.cache/scheimpflug-dic-workbench/datasets)")
    ct.add_argument("--out", type=Path, required=True)
    un = repsub.add_parser("uncertainty", help="is the per-point sigma honest? coverage of the instrument's "
                                               "uncertainty over noise draws of planar and stereo scenes (issue 36)")
    un.add_argument("--quick", action="store_true", help="fewer draws and one specimen (CI scale)")
    un.add_argument("--planar-only", action="store_true", help="only the planar (2-D) classes: no rendering, no "
                                                                "calibrations")
    un.add_argument("--calibrations", type=positive_int_arg, default=None,
                    help="independent calibrations of the calibration class (default 20; 6 with --quick)")
    un.add_argument("--draws", type=positive_int_arg, default=None,
                    help="noise draws per class (default 12 planar / 6 stereo; 6 / 3 with --quick)")
    un.add_argument("--real-data", type=Path, default=None,
                    help="folder of real static pairs from scripts/fetch_twin_data.sh (default data/twin when present)")
    un.add_argument("--store", type=Path, default=None,
                    help="dataset store (default $WORKBENCH_STORE or ~/.cache/scheimpflug-dic-workbench/datasets)")
    un.add_argument("--out", type=Path, required=True)
    f6 = repsub.add_parser("fig6-causes", help="which simulated error sources explain the paper's Fig 6 error growth "
                                                "(a study on Dask, resumable)")
    f6.add_argument("--study", type=Path, default=None, help="study file (default studies/fig6_causes.toml)")
    f6.add_argument("--compare", type=Path, default=None, metavar="DIR",
                    help="the output folder of the same study at another resolution (its fig6_causes.json and "
                         "study.toml): the report says whether the explanation changes")
    f6.add_argument("--scheduler", default=None, help="address of a running Dask scheduler; default a LocalCluster")
    f6.add_argument("--workers", type=positive_int_arg, default=2, help="LocalCluster process workers, default 2")
    f6.add_argument("--store", type=Path, default=None,
                    help="dataset store (renders by scenario hash); default $WORKBENCH_STORE or ~/.cache/...")
    f6.add_argument("--quiet", action="store_true", help="no progress bar")
    f6.add_argument("--out", type=Path, required=True)
    pp = repsub.add_parser("paper", help="the whole paper: calibration, rigid motion, bending, depth of field; one "
                                         "report (report.html, report.md) with every goal figure; resumable")
    pp.add_argument("--quick", action="store_true", help="quarter scale, same protocol (CI and the README)")
    pp.add_argument("--scale", type=scale_arg, default=None, help="image scale (default 1, or 0.25 with --quick)")
    pp.add_argument("--mc-target-grey", type=positive_float_arg, default=None,
                    help="Monte-Carlo noise target of the adaptive renders, grey RMS (default 0.3)")
    pp.add_argument("--seed", type=seed_arg, default=0)
    pp.add_argument("--strict", action="store_true", help="exit 1 when a goal figure is not met")
    pp.add_argument("--ideal-optics", action="store_true",
                    help="render the speckle states without the lens' diffraction (default: f/8, 550 nm)")
    pp.add_argument("--store", type=Path, default=None,
                    help="dataset store (renders by content hash); default $WORKBENCH_STORE or ~/.cache/...")
    pp.add_argument("--out", type=Path, required=True)
    da = repsub.add_parser("dic-accuracy", help="DIC bias vs sub-pixel shift, noise floor, shape functions")
    da.add_argument("--out", type=Path, required=True)
    from workbench.experiments.dic2d.star import add_star_parser
    add_star_parser(repsub)
    dof = repsub.add_parser("depth-of-field", help="MIG of an oblique speckled plate: Scheimpflug vs untilted")
    dof.add_argument("--scale", type=scale_arg, default=1.0)
    dof.add_argument("--object-tilt-deg", type=angle_deg_arg, default=38.0)
    dof.add_argument("--f-number", type=positive_float_arg, default=4.0)
    dof.add_argument("--spp", type=positive_int_arg, default=64)
    dof.add_argument("--seed", type=seed_arg, default=0)
    dof.add_argument("--out", type=Path, required=True)


def reproduce_catalog_command(args) -> int:
    from workbench.experiments.specimen.run import reproduce_catalog

    output_folder(args.out)
    result = reproduce_catalog(args.out, args.names, scale=args.scale, subset_size=args.subset, step=args.step,
                               window=args.window, store=args.store)
    for m in result["specimens"]:
        v = m["verdicts"]
        print(f"{m['name']}: noise floor {m['noise_floor_um']:.3g} µm; " + "; ".join(
            f"{k} {'met' if x['met'] else 'MISSED'}" for k, x in v.items()))
    print(f"report: {args.out / 'report.md'}")
    return 0


def reproduce_uncertainty_command(args) -> int:
    from workbench.experiments.uncertainty.run import run

    output_folder(args.out)
    if args.draws is not None and args.draws < 2:
        raise ValueError(f"--draws {args.draws}: at least 2 noise draws are needed")
    real = args.real_data
    if real is None:
        default = Path(__file__).resolve().parents[2] / "data" / "twin"
        real = default if default.is_dir() else None
    elif not real.is_dir():
        raise ValueError(f"--real-data {real}: no such folder (run scripts/fetch_twin_data.sh)")
    if args.calibrations is not None and args.calibrations < 2:
        raise ValueError(f"--calibrations {args.calibrations}: at least 2 calibrations are needed")
    result = run(args.out, quick=args.quick, draws_planar=args.draws, draws_stereo=args.draws, store=args.store,
                 stereo=not args.planar_only, real_data=real, calibration=not args.planar_only,
                 calibrations=args.calibrations)
    for r in result["classes"]:
        v = r["verdict"]
        figures = ", ".join(f"{n} std(z) {f['std_z']:.3f} cov95 {f['coverage_95']:.3f}"
                            for n, f in r["components"].items())
        print(f"{r['class']}: {figures}; flagged {r['flagged_fraction']:.3f}; "
              + ", ".join(f"{k} {'met' if ok else 'MISSED'}" for k, ok in v.items()))
    for cal in result.get("calibration") or []:
        print(f"{cal['class']}: observed / predicted sigma "
              + ", ".join(f"{n} {c['ratio']:.2f}" for n, c in cal["components"].items())
              + f"; {'met' if cal['verdict']['within_20_percent'] else 'MISSED'} (goal within 20 %)")
    print(f"report: {args.out / 'report.html'}")
    return 0


def _rig_option(calib: str) -> None:
    """``--calib rendered|true|FILE``: a file must exist (checked before any rendering)."""
    if calib not in ("rendered", "true"):
        path = Path(calib)
        if path.is_dir():
            raise ValueError(f"--calib {calib} is a directory, not a calibration file")
        if not path.is_file():
            raise ValueError(f"calibration file not found: {calib} (--calib takes 'true', 'rendered' or a "
                             "calibration file)")


def reproduce_rigid_motion_command(args) -> int:
    from workbench.experiments.rigid_motion.run import reproduce_rigid_motion

    _rig_option(args.calib)
    output_folder(args.out)
    m = reproduce_rigid_motion(args.out, scale=args.scale, calib=args.calib, lens=args.lens, seed=args.seed,
                               spp=args.spp, subset_size=args.subset, step=args.step, store=args.store,
                               renderer=args.renderer, f_number=None if args.ideal_optics else args.f_number)
    e = m["reference_3d_error_um"]
    print(f"{m['calibration']}: reference 3D error {e['aligned_rms']:.3f} um aligned ({e['unaligned_rms']:.1f} um "
          f"unaligned), {m['points']} points")
    for r in m["states"]:
        if "error" in r:
            print(f"  {r['imposed_mm']:5.1f} mm: skipped ({r['error']})")
            continue
        paper = "" if r["paper_mean_um"] is None else f"; paper {r['paper_mean_um']:.1f} / {r['paper_std_um']:.1f} um"
        print(f"  {r['imposed_mm']:5.1f} mm: mean error {r['mean_error_um']:+.3f} um, std {r['std_um']:.3f} um "
              f"({r['points']} points){paper}")
    print(f"wrote {args.out / 'report.md'}")
    return 0 if any("error" not in r for r in m["states"]) else 1


def reproduce_bending_command(args) -> int:
    from workbench.experiments.bending.run import reproduce_bending

    if args.window != 0 and (args.window < 3 or args.window % 2 == 0):
        raise ValueError(f"--window must be 0 (per-triangle strain) or an odd number >= 3, got {args.window}")
    _rig_option(args.calib)
    output_folder(args.out)
    m = reproduce_bending(args.out, scale=args.scale, rig_name=args.rig, lens=args.lens, calib=args.calib,
                          seed=args.seed, spp=args.spp, noise_grey=args.noise_grey, subset_size=args.subset,
                          step=args.step, window=args.window or None, store=args.store, renderer=args.renderer,
                          f_number=None if args.ideal_optics else args.f_number)
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


def reproduce_paper_command(args) -> int:
    from workbench.experiments.paper.run import PaperSettings, reproduce_paper

    settings = PaperSettings.for_mode(args.quick, args.scale, args.mc_target_grey, args.seed, args.ideal_optics)
    summary = reproduce_paper(args.out, settings, store=args.store)
    failed = [g for g in summary["goals"] if g["met"] is False]
    return 1 if (args.strict and failed) else 0


def reproduce_dic_accuracy_command(args) -> int:
    from workbench.experiments.dic2d.accuracy import reproduce_dic_accuracy

    output_folder(args.out)
    metrics = reproduce_dic_accuracy(args.out)
    for curve in metrics["bias"]:
        print(f"bias {curve['label']}: max {curve['max_abs_px']:.5f} px")
    print(f"noise ratio std(u)/theory: {metrics['noise']['all']['ratio']:.3f}; wrote {args.out / 'report.md'}")
    return 0


def reproduce_calibration_command(args) -> int:
    from workbench.experiments.calibration.run import reproduce_calibration

    output_folder(args.out)
    m = reproduce_calibration(args.out, scale=args.scale, seed=args.seed, spp=args.spp, noise_grey=args.noise_grey,
                              n_calibration=args.calibration_views, n_validation=args.validation_views,
                              refine_corners=args.refine_corners, store=args.store, renderer=args.renderer,
                              covariance=args.covariance, bootstrap_draws=args.bootstrap_draws)
    for model, r in m["models"].items():
        v, pf = r["validation_exact"], r["validation_plane_fit"]
        print(f"{model:8s}: reprojection RMS {r['reprojection_rms_px']['left']:.4f} / "
              f"{r['reprojection_rms_px']['right']:.4f} px; 3D RMS {v['rms_3d_aligned_um']:.3f} um aligned "
              f"({v['rms_3d_unaligned_um']:.1f} um unaligned); projection {v['projection_rms_px']:.4f} px; plane fit "
              f"RMSE {pf['rmse_um']:.2f} um, max {pf['max_abs_um']:.2f} um; calibration {r['calibration_s']} s")
    print(f"report: {args.out / 'report.md'}")
    return 0


def reproduce_agreement_command(args) -> int:
    from workbench.experiments.calibration.agreement import measure_agreement, summary_lines, write_agreement_report
    from workbench.rigs import get_rig

    output_folder(args.out)
    rig = get_rig(args.rig, args.scale)
    spp = args.spp if args.mc_target_grey is None else f"adaptive:{args.mc_target_grey:g}"
    summary = measure_agreement(rig, n_views=args.views, seed=args.seed, spp=spp, renderer=args.renderer)
    write_agreement_report(summary, args.out)
    print("\n".join(summary_lines(summary)))
    print(f"report: {args.out / 'report.md'}")
    return 0 if all(e["meets_goal"] for e in summary["cameras"].values()) else 1


def reproduce_depth_of_field_command(args) -> int:
    from workbench.experiments.depth_of_field.run import reproduce_depth_of_field

    output_folder(args.out)
    m = reproduce_depth_of_field(args.out, scale=args.scale, object_tilt_deg=args.object_tilt_deg,
                                 f_number=args.f_number, spp=args.spp, seed=args.seed)
    for name, c in m["cameras"].items():
        print(f"{name:13s}: MIG {c['mig']:.2f}, blur median {c['blur_px']['median']:.2f} px (max {c['blur_px']['max']:.2f}), "
              f"noise floor {c['noise_floor_px']['u']:.4f} / {c['noise_floor_px']['v']:.4f} px, "
              f"displacement error RMS {c['displacement_error_px']['rms']:.4f} px")
    print(f"MIG ratio {m['mig_ratio']:.2f} (paper {m['paper_mig_scheimpflug'] / m['paper_mig_conventional']:.2f}); "
          f"wrote {args.out / 'report.md'}")
    return 0


def reproduce_star_command(args) -> int:
    from workbench.experiments.dic2d.star import star_command
    return star_command(args)


def fig6_causes_command(args) -> int:
    from workbench.studies.fig6_causes import write_fig6_report
    from workbench.studies.study import load_study
    from workbench.studies.report import write_study_outputs

    path = args.study or FIG6_STUDY
    if path == FIG6_STUDY and FIG6_STUDY.is_relative_to(Path.cwd()):
        path = FIG6_STUDY.relative_to(Path.cwd())      # the report names the file as the user would
    study = load_study(path)
    if study.scenario.experiment != "rigid_motion" or study.mode != "cases" or \
            "perfect world" not in [c.name for c in study.cases]:
        raise ValueError(f"{path}: the Fig 6 study needs experiment = \"rigid_motion\", mode = \"cases\" and a "
                         "case named \"perfect world\" (the baseline)")
    compare = None
    if getattr(args, "compare", None) is not None:       # read before the (long) study: a bad folder fails now
        import json
        for name in ("fig6_causes.json", "study.toml"):
            if not (args.compare / name).is_file():
                raise ValueError(f"--compare {args.compare}: no {name} there (the output folder of a fig6-causes run)")
        compare = (json.loads((args.compare / "fig6_causes.json").read_text()),
                   float(load_study(args.compare / "study.toml").scenario.rig.scale))
    summary, lines, versions = run_study(args, study)
    outputs = write_study_outputs(study, args.out, summary.records, lines, versions, html=False)
    result = write_fig6_report(study, args.out, summary.records, versions, outputs["figures"],
                               lines + outputs["summary"], compare=compare)
    print("\n".join(lines))
    for v in result["single_causes"]:
        print(f"  {v['case']}: {v['verdict']}")
    print(f"best explanation: {', '.join(result['best'][:3])}")
    print(f"report: {args.out / 'fig6_causes.md'}")
    return 1 if summary.failed else 0


#: The study shipped with the repository that explains the paper's Fig 6.
FIG6_STUDY = Path(__file__).resolve().parents[2] / "studies" / "fig6_causes.toml"


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {
    ("reproduce", "agreement"): reproduce_agreement_command,
    ("reproduce", "depth-of-field"): reproduce_depth_of_field_command,
    ("reproduce", "calibration"): reproduce_calibration_command,
    ("reproduce", "dic-accuracy"): reproduce_dic_accuracy_command,
    ("reproduce", "paper"): reproduce_paper_command,
    ("reproduce", "rigid-motion"): reproduce_rigid_motion_command,
    ("reproduce", "bending"): reproduce_bending_command,
    ("reproduce", "fig6-causes"): fig6_causes_command,
    ("reproduce", "star"): reproduce_star_command,
    ("reproduce", "catalog"): reproduce_catalog_command,
    ("reproduce", "uncertainty"): reproduce_uncertainty_command,
}
