"""pyvale as a peer DIC engine (workbench.peers.pyvale_engine): exact pairs pin its displacement sign and
coordinate convention to ours. Run with ``python -m pytest -m peers tests/test_peer_pyvale.py`` in an
environment with ``pip install '.[peers]'``."""
import importlib.metadata
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile

_HAD_STRAY_LOG = Path("plotter_log.log").exists()
pyvale = pytest.importorskip("pyvale")

from labio.atomic import atomic_write_image  # noqa: E402
from scenes.image_pairs import gaussian_speckle as si
from workbench.peers import pyvale_engine  # noqa: E402

# ``import pyvale`` leaves an empty plotter_log.log in the current folder (the checkout): take it away again.
pyvale_engine.remove_stray_log(_HAD_STRAY_LOG)

pytestmark = pytest.mark.peers

SHAPE = (256, 256)
SHIFT_XY_PX = (0.37, -0.21)
ROI_XYXY_PX = (40, 44, 215, 211)


def _write(path, image):
    """Float images as float32 TIFF (no quantisation), integer ones through the project's writer."""
    if image.dtype.kind == "f":
        tifffile.imwrite(path, image.astype(np.float32))
    else:
        atomic_write_image(path, image)
    return path


@pytest.mark.parametrize("kind", ["float32 tiff", "uint8 png"])
def test_shifted_pair_gives_the_shift_inside_the_roi(tmp_path, kind):
    ref, shifted = si.fourier_shifted_pair(SHAPE, 4.0, SHIFT_XY_PX, seed=11)
    if kind == "uint8 png":
        # 8-bit quantisation of the same pair; pyvale cannot read PNG, so this also checks the array hand-over.
        ref, shifted = (np.clip(np.rint(im), 0, 255).astype(np.uint8) for im in (ref, shifted))
    ext = ".tiff" if kind.endswith("tiff") else ".png"
    out = pyvale_engine.run(_write(tmp_path / f"ref{ext}", ref), _write(tmp_path / f"def{ext}", shifted),
                            tmp_path / "result" / "pyvale.csv", subset_px=33, step_px=8,
                            roi_xyxy_px=ROI_XYXY_PX, order=1, threads=1)
    r = pyvale_engine.read_result(out)

    assert r["tool"] == f"pyvale {importlib.metadata.version('pyvale')}"
    x0, y0, x1, y1 = ROI_XYXY_PX
    assert r["x_px"].size > 300
    assert np.all((r["x_px"] >= x0) & (r["x_px"] <= x1) & (r["y_px"] >= y0) & (r["y_px"] <= y1))
    error = np.hypot(r["u_px"] - SHIFT_XY_PX[0], r["v_px"] - SHIFT_XY_PX[1])
    assert np.mean(r["valid"] & (error < 0.02)) >= 0.95
    assert np.all(np.isnan(r["u_px"][~r["valid"]]))


@pytest.mark.parametrize("order", [1, 2])
def test_linear_strain_pins_the_coordinate_origin(tmp_path, order):
    # u = 0.01 (x - 100), v = -0.008 (y - 140): a coordinate offset d shows up as 0.01 d in u and 0.008 d in v.
    field = si.HomogeneousStrain(exx=0.01, eyy=-0.008, centre_xy_px=(100.0, 140.0))
    pattern = si.gaussian_speckle(si.extent_for_shape(SHAPE, margin_px=8.0), si.radius_for_speckle_size(4.0),
                                  seed=5)
    ref_path = _write(tmp_path / "ref.tiff", pattern.render_reference(SHAPE))
    def_path = _write(tmp_path / "def.tiff", pattern.render_deformed(SHAPE, field))
    r = pyvale_engine.read_result(pyvale_engine.run(ref_path, def_path, tmp_path / "pyvale.csv", subset_px=33,
                                                    step_px=8, roi_xyxy_px=ROI_XYXY_PX, order=order, threads=1))

    ok = r["valid"]
    assert ok.mean() >= 0.95
    true_u, true_v = field(r["x_px"][ok], r["y_px"][ok])
    error_u, error_v = r["u_px"][ok] - true_u, r["v_px"][ok] - true_v
    assert np.sqrt(np.mean(error_u**2)) < 0.01
    assert np.sqrt(np.mean(error_v**2)) < 0.01
    # The rms bound alone lets a 0.5 px offset through (it costs 0.005 px rms here); the least-squares
    # offset does not: measured -0.01 px in x and +0.02 px in y, against 0.5 for a half-pixel convention.
    assert abs(np.mean(error_u) / field.exx) < 0.1
    assert abs(np.mean(error_v) / field.eyy) < 0.1


def test_missing_column_names_the_file_and_the_column(tmp_path):
    path = tmp_path / "no_v.csv"
    path.write_text('"subset_x","subset_y","disp_u","disp_mag","converged",\n'
                    "16.0,16.0,0.5,0.5,1\n")
    with pytest.raises(ValueError, match=r"no_v\.csv.*'disp_v'"):
        pyvale_engine.read_result(path)


def test_reads_pyvale_nan_rows_as_invalid(tmp_path):
    path = tmp_path / "nan.csv"
    path.write_text('"subset_x","subset_y","disp_u","disp_v","disp_mag","converged","cost_zncc","ftol","xtol",'
                    '"num_iter",\n'
                    "16.00000000,24.00000000,0.25000000,-0.50000000,0.55901699,1,0.999,0.0,0.0,2\n"
                    "24.00000000,24.00000000,-nan,-nan,-nan,0,-nan,-nan,-nan,40\n"
                    "32.00000000,24.00000000,0.30000000,-0.40000000,0.50000000,0,0.95,0.1,0.1,40\n")
    r = pyvale_engine.read_result(path)
    np.testing.assert_array_equal(r["x_px"], [16.0, 24.0, 32.0])
    np.testing.assert_array_equal(r["y_px"], [24.0, 24.0, 24.0])
    np.testing.assert_array_equal(r["valid"], [True, False, False])
    assert r["u_px"][0] == 0.25 and r["v_px"][0] == -0.5
    assert np.isnan(r["u_px"][1:]).all() and np.isnan(r["v_px"][1:]).all()


def test_refuses_options_the_engine_sets(tmp_path):
    with pytest.raises(TypeError, match="output_basepath"):
        pyvale_engine.run(tmp_path / "a.tiff", tmp_path / "b.tiff", tmp_path / "o.csv", output_basepath="/tmp")


def test_without_pyvale_says_how_to_install(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "pyvale.dic", None)
    with pytest.raises(ModuleNotFoundError, match=r"pip install '\.\[peers\]'"):
        pyvale_engine.run(tmp_path / "a.tiff", tmp_path / "b.tiff", tmp_path / "o.csv")


def test_ctrl_c_reaches_python_after_a_run(tmp_path):
    # pyvale's engine installs a C SIGINT handler that only sets a flag; run() must give SIGINT back.
    ref, shifted = si.fourier_shifted_pair((128, 128), 4.0, SHIFT_XY_PX, seed=2)
    pyvale_engine.run(_write(tmp_path / "ref.tiff", ref), _write(tmp_path / "def.tiff", shifted),
                      tmp_path / "o.csv", subset_px=21, step_px=16, threads=1)
    assert not (Path.cwd() / "plotter_log.log").exists() or _HAD_STRAY_LOG
    with pytest.raises(KeyboardInterrupt, match=r"^$"):      # Python's default handler: no message
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.5)
