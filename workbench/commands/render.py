"""``workbench render checkerboard``: random stereo views of a board with their truth."""
from __future__ import annotations

from pathlib import Path

from workbench.commands.options import (non_negative_float_arg, output_folder, positive_int_arg, scale_arg, seed_arg,
                                        views_arg)


def add_parser(sub) -> None:
    """The ``render`` subcommand."""
    render = sub.add_parser("render", help="render images with ground truth")
    rsub = render.add_subparsers(dest="what", required=True)
    cb = rsub.add_parser("checkerboard", help="random stereo views of the 12 x 9 checkerboard + truth.json")
    cb.add_argument("--rig", default="paper")
    cb.add_argument("--views", type=views_arg, default=10)
    cb.add_argument("--seed", type=seed_arg, default=0)
    cb.add_argument("--scale", type=scale_arg, default=1.0, help="shrink image size and K together (fast runs)")
    cb.add_argument("--spp", type=positive_int_arg, default=64, help="samples per pixel (Mitsuba renders)")
    cb.add_argument("--renderer", choices=("auto", "exact", "mitsuba"), default="auto",
                    help="auto: the exact box-filtered polygons wherever a view allows it (no Monte-Carlo noise), "
                         "Mitsuba elsewhere; exact: refuse a view it cannot make; mitsuba: Monte Carlo at --spp")
    cb.add_argument("--noise-grey", type=non_negative_float_arg, default=0.0, help="Gaussian read noise, grey levels")
    cb.add_argument("--bit-depth", type=int, choices=(8, 16), default=8)
    cb.add_argument("--format", choices=("png", "tiff"), default="png")
    cb.add_argument("--overwrite", action="store_true",
                    help="replace an earlier dataset in --out (deletes exactly the files its manifest.json lists)")
    cb.add_argument("--out", type=Path, required=True)
    sp = rsub.add_parser("specimen", help="a specimen of one's own (mesh or FE file in a scenario's [specimen]): "
                                          "stereo images of every state + per-pixel truth")
    sp.add_argument("scenario", type=Path, help="scenario TOML/JSON with experiment = \"specimen\" and a [specimen] "
                                                 "table (a study file's [scenario] table also works)")
    sp.add_argument("--overwrite", action="store_true",
                    help="replace an earlier dataset in --out (deletes exactly the files its manifest.json lists)")
    sp.add_argument("--out", type=Path, required=True)


def render_checkerboard_command(args) -> int:
    from scenes.sensor.noise import SensorNoise
    from workbench.experiments.calibration.views import write_checkerboard_dataset
    from workbench.rigs import get_rig

    output_folder(args.out)
    rig = get_rig(args.rig, args.scale)
    noise = SensorNoise(read_noise_grey=args.noise_grey, bit_depth=args.bit_depth)
    truth = write_checkerboard_dataset(rig, args.out, args.views, args.seed, spp=args.spp, noise=noise,
                                       image_format=args.format, overwrite=args.overwrite, renderer=args.renderer)
    made = ", ".join(f"{n} by {name}" for name, n in truth["render"]["renderers"].items())
    print(f"wrote {len(truth['images'])} images ({made}), truth.json and manifest.json to {args.out}")
    return 0


def load_specimen_scenario(path: Path):
    """A ``specimen`` scenario from its file, the specimen file made absolute relative to the scenario's folder."""
    from workbench.config import load_config, read_mapping
    from workbench.scenario import Scenario, with_specimen_paths

    scenario = load_config(Scenario, path, "scenario" if "scenario" in read_mapping(path) else None)
    if scenario.experiment != "specimen":
        raise ValueError(f"{path}: experiment = {scenario.experiment!r}; render specimen needs experiment = \"specimen\"")
    return with_specimen_paths(scenario, Path(path).resolve().parent)


def render_specimen_command(args) -> int:
    from workbench.experiments.specimen.scenes import SIDES, render_specimen

    output_folder(args.out)
    scenario = load_specimen_scenario(args.scenario)
    truth = render_specimen(scenario, args.out, overwrite=args.overwrite)
    masks = truth.info["masks"]
    for side in SIDES:
        m = masks[side]
        lost = ", ".join(f"{k} {v}" for k, v in m.items() if k != "measurable" and v)
        print(f"{side} reference: {m['measurable']} measurable pixels" + (f" (masked: {lost})" if lost else ""))
    layout = truth.info["paint_layout"]
    if layout.get("stretch_max") and layout["stretch_max"] > 1.05:
        print(f"paint: speckles stretched up to {layout['stretch_max']:.2f}x on sloped faces (mean "
              f"{layout['stretch_mean']:.2f}x)")
    made = ", ".join(f"{n} by {name}" for name, n in truth.info["render"].get("renderers", {}).items())
    print(f"wrote {2 * len(truth.files)} images ({made}) of {len(truth.files)} states, truth.json, truth_*.npz and "
          f"manifest.json to {args.out}")
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("render", "checkerboard"): render_checkerboard_command, ("render", "specimen"): render_specimen_command}
