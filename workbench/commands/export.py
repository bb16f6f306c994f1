"""``workbench export``: a rendered dataset as another DIC tool reads it."""
from __future__ import annotations

from pathlib import Path

from workbench.commands.options import positive_int_arg


def add_parser(sub) -> None:
    """The ``export`` subcommand."""
    from workbench.scoring.export import FORMATS

    ex = sub.add_parser("export", help="write a rendered dataset as another DIC tool reads it (images, calibration, "
                                       "truth)")
    ex.add_argument("dataset", type=Path, help="a dataset folder (render store, render command) or a scenario "
                                               "file (.toml/.json), rendered through the store first")
    ex.add_argument("--format", choices=FORMATS, default="native")
    ex.add_argument("--subset", type=positive_int_arg, default=33, help="subset size written into the tool's input, px")
    ex.add_argument("--step", type=positive_int_arg, default=8, help="step written into the tool's input, px")
    ex.add_argument("--grid-step", type=positive_int_arg, default=8, help="spacing of the truth grid of points.csv, px")
    ex.add_argument("--truth-step", type=positive_int_arg, default=1, help="spacing of the per-pixel truth array, px")
    ex.add_argument("--frame-rotation", action="store_true",
                    help="let the calibration absorb a Scheimpflug tilt the format lacks in a rotation of the camera "
                         "frames (exact for DICe's OpenCV tilt); the extrinsics carry it")
    ex.add_argument("--store", type=Path, default=None, help="render store (default $WORKBENCH_STORE)")
    ex.add_argument("--out", type=Path, required=True, help="a new folder")



def export_command(args) -> int:
    from workbench.scoring.datasets import open_dataset
    from workbench.scoring.export import ExportSettings, export_dataset

    dataset = open_dataset(args.dataset, args.store)
    settings = ExportSettings(subset_px=args.subset, step_px=args.step, grid_step_px=args.grid_step,
                              truth_step_px=args.truth_step)
    record = export_dataset(dataset, args.format, args.out, settings, frame_rotation=args.frame_rotation)
    print(f"wrote {args.out} ({record['seconds']:.1f} s): see {args.out / 'export.json'}")
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("export", None): export_command}
