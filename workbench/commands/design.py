"""``workbench design``: design a Scheimpflug stereo rig before buying it, verified by rendering the design.

    workbench design design.toml --out design/ [--no-verify] [--compare paper,scheimpflug]

The design file (TOML; every key: ``workbench parameters``, prefix ``design.``) names the specimen (a catalog
name, a mesh/FE file or a plane), the cameras, lenses and Scheimpflug adapter on offer, the lighting and where the
cameras may stand. Writes report.html (self-contained), report.md, design.json, candidates.csv and the chosen and
best untilted rigs as calibration files (project JSON with their optics, OpenCV YAML) into --out; prints the
chosen rig, the best untilted one and, with verification, predicted against measured noise.
"""
from __future__ import annotations

from pathlib import Path

from workbench.commands.options import input_file, output_folder


def _names(text: str) -> tuple[str, ...]:
    return tuple(n.strip() for n in text.split(",") if n.strip())


def add_parser(sub) -> None:
    de = sub.add_parser("design", help="design a stereo rig for your specimen and parts list: tilt or not, stereo "
                                       "angle, distance, aperture; predicted noise of U, V, W and strain, the best "
                                       "untilted rig beside it, both verified by rendering")
    de.add_argument("design", type=Path, help="the design file (TOML or JSON; keys: workbench parameters)")
    de.add_argument("--out", type=Path, required=True, help="output folder")
    de.add_argument("--no-verify", action="store_true", help="prediction only: do not render and measure the rigs")
    de.add_argument("--compare", type=_names, default=(),
                    help="named rigs to predict beside the design, comma separated: paper, scheimpflug")


def design_command(args) -> int:
    import time

    from workbench.design.run import run_design

    input_file(args.design, "design file")
    output_folder(args.out)
    start = time.perf_counter()

    def progress(message: str) -> None:
        print(f"[{time.perf_counter() - start:6.1f} s] {message}", flush=True)

    dr = run_design(args.design, args.out, verify_rigs=False if args.no_verify else None, compare_with=args.compare,
                    progress=progress)
    best, best_u = dr.search.best, dr.search.best_untilted
    s = best.summary
    print(f"chosen: {best.candidate.rig.name}: sigma U, V, W {s['sigma_U_um']:.3g}, {s['sigma_V_um']:.3g}, "
          f"{s['sigma_W_um']:.3g} µm (static pair, RMS over the ROI), in focus {s['in_focus_fraction']:.2f}")
    if best_u is not None and best_u is not best:
        u = best_u.summary
        print(f"best untilted: {best_u.candidate.rig.name}: sigma U, V, W {u['sigma_U_um']:.3g}, "
              f"{u['sigma_V_um']:.3g}, {u['sigma_W_um']:.3g} µm, in focus {u['in_focus_fraction']:.2f}; "
              f"{u['objective'] / s['objective']:.2f}x the chosen rig's {dr.design.specimen.quantity} noise")
    for key, v in dr.verification.items():
        st = v["static"]
        print(f"verified ({key}): predicted / measured U, V, W " + ", ".join(f"{r:.2f}" for r in st["ratio"]))
    print(f"wrote {Path(args.out) / 'report.html'} ({time.perf_counter() - start:.0f} s)")
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("design", None): design_command}
