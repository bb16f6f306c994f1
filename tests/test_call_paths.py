"""Call paths of the workbench's experiments and twin (issue 41): along any one call stack, no module of
``workbench/experiments`` or ``workbench/twin`` comes back after a lower room (the instrument, the truth side, the
workbench's core) more than once -- a settings object does not travel twin -> instrument -> twin -> instrument ->
twin; where a helper is the instrument's job it lives in ``measurement/``.

The stacks are recorded with ``sys.setprofile`` while the real code runs (a rendered specimen, the stereo twin
with its bias and what-if rows), so a callback handed down and called back counts as what it is. The counter is
checked on a deliberately built stack that goes back and forth twice.
"""
from __future__ import annotations

import sys

import numpy as np
import pytest

#: Packages whose modules may come back to the stack at most once after a lower room.
WATCHED = ("workbench.experiments.", "workbench.twin.")
#: Lower rooms, by package prefix.
LOWER = ("measurement", "scenes", "labio", "workbench.config", "workbench.scenario", "workbench.store",
         "workbench.manifest", "workbench.rigs", "workbench.poses", "workbench.engines", "workbench.results",
         "workbench.truth_schema", "workbench.points_with_truth", "workbench.agreement")
MOST_RETURNS = 1


def _project_module(name: str | None) -> str | None:
    if not name or name.split(".")[0] not in ("measurement", "scenes", "labio", "workbench"):
        return None
    return name


def worst_return(run) -> tuple[int, list[str]]:
    """Run ``run()`` and return the most times one watched module came back to a call stack after a lower room
    had been entered above it, with that stack (compressed: one entry per module change)."""
    stack: list[tuple[str, ...]] = []
    worst: list = [0, []]

    def returns(path: tuple[str, ...]) -> int:
        most = 0
        for module in set(path):
            if not module.startswith(WATCHED):
                continue
            seen, lower_since, n = False, False, 0
            for m in path:
                if m == module:
                    n += seen and lower_since
                    seen, lower_since = True, False
                elif seen and m.startswith(LOWER):
                    lower_since = True
            most = max(most, n)
        return most

    def profile(frame, event, arg):
        if event == "call":
            module = _project_module(frame.f_globals.get("__name__"))
            path = stack[-1] if stack else ()
            if module is not None and (not path or path[-1] != module):
                path = path + (module,)
                n = returns(path)
                if n > worst[0]:
                    worst[:] = [n, list(path)]
            stack.append(path)
        elif event == "return" and stack:
            stack.pop()

    sys.setprofile(profile)
    try:
        run()
    finally:
        sys.setprofile(None)
    return worst[0], worst[1]


def _fake(module: str, source: str, **names):
    """A function defined in a module named ``module`` (its frames carry that ``__name__``)."""
    scope = {"__name__": module, **names}
    exec(source, scope)
    return scope["f"]


def test_the_counter_catches_a_twin_that_goes_back_and_forth_twice():
    callback = _fake("workbench.twin.fake", "def f(g, depth):\n    return g(f, depth - 1) if depth else 0\n")
    instrument = _fake("measurement.fake", "def f(cb, depth):\n    return cb(f, depth)\n")
    assert worst_return(lambda: callback(instrument, 1))[0] == 1
    n, path = worst_return(lambda: callback(instrument, 2))
    assert n == 2 and path[:3] == ["workbench.twin.fake", "measurement.fake", "workbench.twin.fake"]


@pytest.fixture(scope="module")
def plate_dataset(tmp_path_factory):
    import skfem
    from skfem.io.meshio import to_meshio

    from scenes.specimens.fe_files import write_exodus

    tmp = tmp_path_factory.mktemp("plate")
    m = to_meshio(skfem.MeshTet.init_tensor(np.linspace(-30, 30, 7), np.linspace(-20, 20, 5), np.linspace(0, 3, 2)))
    write_exodus(tmp / "plate.e", m.points, {"tetra": m.cells[0].data}, np.zeros((1, *m.points.shape)), times=[0.0])
    (tmp / "plate.toml").write_text('experiment = "specimen"\nseed = 3\n[rig]\nname = "paper"\nscale = 0.2\n'
                                    '[render]\nread_noise_grey = 2.0\nelectrons_per_grey = 20.0\n'
                                    '[specimen]\nmesh = "plate.e"\nstatic_offset_px = [0.0, 0.0]\n')
    return tmp


def test_rendering_a_specimen_comes_back_at_most_once(plate_dataset, tmp_path):
    from workbench.commands.render import load_specimen_scenario
    from workbench.experiments.specimen.scenes import render_specimen

    scenario = load_specimen_scenario(plate_dataset / "plate.toml")
    n, path = worst_return(lambda: render_specimen(scenario, tmp_path / "data", progress=False))
    assert n <= MOST_RETURNS, path


def test_the_stereo_twin_comes_back_at_most_once(plate_dataset, tmp_path):
    from workbench.cli import main
    from workbench.twin import TwinSettings, run_twin

    assert main(["render", "specimen", str(plate_dataset / "plate.toml"), "--out", str(tmp_path / "data")]) == 0
    assert main(["export", str(tmp_path / "data"), "--format", "native", "--out", str(tmp_path / "ex")]) == 0
    ex = tmp_path / "ex"
    n, path = worst_return(lambda: run_twin(ex / "left_00.png", ex / "right_00.png", ex / "left_01.png",
                                            ex / "right_01.png", calibration=ex / "calibration.json",
                                            auto_roi=True, repeats=1, whatif=True, bias=True, resolution=False,
                                            settings=TwinSettings(subset_px=21, step_px=6)))
    assert n <= MOST_RETURNS, path
