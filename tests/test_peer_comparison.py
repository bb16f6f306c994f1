"""pyvale beside this project's engine through ``workbench score --engine`` on one rendered pair.

The pair: a 256 x 256 px dic2d scenario (4 px speckle, exact Fourier shift of 0.3 px along x, 2 grey read
noise in both images, 8-bit PNG, seed 0), subset 33 px, step 8 px. Claims, from what was measured (pyvale
2026.10.2, the adapter's defaults: prefilter off, cubic B-spline, forward-additive Levenberg-Marquardt):

* ours (IC-GN, biquintic): |bias u| < 0.002 px and RMS u < 0.008 px (measured +0.0000 and 0.0049 px);
* pyvale: bias u between +0.003 and +0.010 px and RMS u < 0.012 px (measured +0.0064 and 0.0081 px): its
  forward-additive iteration adds a noise-induced bias towards the half pixel, predicted
  -sigma^2 S'(t) / (2 <f_x^2>) = +0.0045 px here, on top of its cubic spline's own +0.0017 px (module
  docstring of ``workbench.peers.pyvale_engine``; ``reports/peer_pyvale/``);
* both: v unbiased (|bias v| < 0.002 px), and results for the same ROI: the same grid points, each engine
  valid on more than 90 % of them (measured 100 %).

Run with ``python -m pytest -m peers tests/test_peer_comparison.py`` where ``pip install '.[peers]'`` is.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

_HAD_STRAY_LOG = Path("plotter_log.log").exists()
pytest.importorskip("pyvale")

from workbench.peers import pyvale_engine  # noqa: E402
from workbench.results import read_result  # noqa: E402

pyvale_engine.remove_stray_log(_HAD_STRAY_LOG)

pytestmark = pytest.mark.peers

ROOT = Path(__file__).resolve().parents[1]
SHIFT_PX = 0.3
SCENARIO = f"""experiment = "dic2d"
seed = 0
[render]
read_noise_grey = 2.0
bit_depth = 8
[image2d]
size_px = 256
shift_x_px = {SHIFT_PX}
"""
ENGINES = {"ours": "workbench.engines:ours", "pyvale": "workbench.peers.pyvale_engine:run"}


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    """Run ``workbench score --engine`` for both engines on the same scenario and store; their metrics and
    result files."""
    tmp = tmp_path_factory.mktemp("peer_comparison")
    scenario = tmp / "pair.toml"
    scenario.write_text(SCENARIO)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    out = {}
    for name, spec in ENGINES.items():
        folder = tmp / name
        proc = subprocess.run([sys.executable, "-m", "workbench.cli", "score", str(scenario), "--engine", spec,
                               "--subset", "33", "--step", "8", "--store", str(tmp / "store"), "--out", str(folder)],
                              capture_output=True, text=True, cwd=tmp, env=env, timeout=300)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        doc = json.loads((folder / "metrics.json").read_text())
        fmt = "pyvale" if name == "pyvale" else "native"
        out[name] = {"doc": doc, "metrics": doc["states"][0],
                     "result": read_result(folder / "engine" / "result_01.csv", fmt)}
    return out


def test_both_scored_the_same_dataset(scored):
    assert scored["ours"]["doc"]["dataset"] == scored["pyvale"]["doc"]["dataset"]
    assert scored["pyvale"]["doc"]["tool"].startswith("pyvale ")


def test_ours_is_unbiased(scored):
    m = scored["ours"]["metrics"]
    assert abs(m["bias_u_px"]) < 0.002, m
    assert m["rms_u_px"] < 0.008, m
    assert abs(m["bias_v_px"]) < 0.002, m


def test_pyvale_has_its_noise_induced_bias_and_stays_within_0p012_px_rms(scored):
    m = scored["pyvale"]["metrics"]
    assert 0.003 < m["bias_u_px"] < 0.010, m
    assert m["rms_u_px"] < 0.012, m
    assert abs(m["bias_v_px"]) < 0.002, m
    # the noise-induced part is pyvale's, not the pair's: the same pair costs ours nothing
    assert m["bias_u_px"] - scored["ours"]["metrics"]["bias_u_px"] > 0.003


def test_both_report_the_same_roi(scored):
    a, b = scored["ours"]["result"], scored["pyvale"]["result"]
    key = lambda r: sorted(zip(np.asarray(r.x_px, float).tolist(), np.asarray(r.y_px, float).tolist()))  # noqa: E731
    assert a.x_px.size > 600 and key(a) == key(b)
    for name in ENGINES:
        m = scored[name]["metrics"]
        assert m["valid_fraction"] > 0.9, (name, m)
        assert m["outside_points"] == 0, (name, m)


def test_hermite_interpolation_is_refused_not_a_crash(tmp_path):
    # pyvale 2026.10.2's HERMITE interpolator segfaults the process; the adapter refuses it before pyvale runs.
    if pyvale_engine._version_tuple(pyvale_engine._pyvale_version()) > pyvale_engine._HERMITE_CRASHES_UP_TO:
        pytest.skip("a pyvale newer than the one whose HERMITE interpolator is known to crash")
    with pytest.raises(ValueError, match="HERMITE"):
        pyvale_engine.run(tmp_path / "a.tiff", tmp_path / "b.tiff", tmp_path / "o.csv",
                          interpolation_routine="HERMITE")
