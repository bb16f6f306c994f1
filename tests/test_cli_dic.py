"""``workbench dic`` driven from the command line (``workbench.cli.main``): a synthetic pair with a known shift.

The pair is an exact Fourier-shifted speckle pattern (4 px speckles, shift (2.3, -1.7) px) written as 16-bit
PNGs, so the engine's interpolation bias (<= 0.5e-3 px for biquintic, reports/dic_accuracy) and the 16-bit
quantisation (~1e-5 of the grey range) are the only errors.
"""
import csv
import errno
import os

import cv2
import numpy as np
import pytest

from measurement.dic import PARAMETER_NAMES
from scenes.image_pairs.fourier_shift import fourier_shifted_pair
from workbench.cli import main

SHIFT_PX = (2.3, -1.7)
ROI = "30,30,170,130"
COLUMNS = ["x", "y", "u", "v", "zncc", "iterations", "status", "status_name",
           *PARAMETER_NAMES[1:6], *PARAMETER_NAMES[7:], "sigma_u_px", "sigma_v_px", "residual_ratio", "sigma_flag",
           "bias_bound_u_px", "bias_bound_v_px", "misfit_bias_u_px", "misfit_bias_v_px"]


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("dic_pair")
    reference, deformed = fourier_shifted_pair((160, 200), 4.0, SHIFT_PX, seed=2)
    low, high = min(reference.min(), deformed.min()), max(reference.max(), deformed.max())
    for name, image in (("ref.png", reference), ("def.png", deformed)):
        assert cv2.imwrite(str(folder / name), np.rint((image - low) / (high - low) * 60000 + 2000).astype(np.uint16))
    return folder / "ref.png", folder / "def.png"


def _rows(path):
    with open(path, newline="") as handle:
        reader = csv.reader(handle)
        return next(reader), list(reader)


def _last_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err.strip().splitlines()[-1]


def test_dic_measures_the_imposed_shift(pair, tmp_path, capsys):
    ref, dfm = pair
    out = tmp_path / "points.csv"
    assert main(["dic", str(ref), str(dfm), "--roi", ROI, "--subset", "33", "--step", "10", "--out", str(out)]) == 0
    header, rows = _rows(out)
    assert header == COLUMNS
    assert len(rows) == 14 * 10                      # the ROI's grid: x 30..160, y 30..120 at step 10
    converged = [r for r in rows if r[7] == "converged"]
    assert len(converged) == len(rows)              # every subset of this ROI lies inside the image
    u = np.array([float(r[2]) for r in converged])
    v = np.array([float(r[3]) for r in converged])
    assert np.abs(u - SHIFT_PX[0]).max() < 1e-3 and np.abs(v - SHIFT_PX[1]).max() < 1e-3
    assert abs(u.mean() - SHIFT_PX[0]) < 5e-4 and abs(v.mean() - SHIFT_PX[1]) < 5e-4
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed and "converged 140" in printed
    # every converged point has a positive sigma, and the output says where the noise came from
    sigma = np.array([[float(r[COLUMNS.index(c)]) for c in ("sigma_u_px", "sigma_v_px")] for r in converged])
    assert np.all(np.isfinite(sigma)) and np.all(sigma > 0)
    assert "noise from the match residuals" in printed
    # on this (nearly noise-free) exact shift the error is the interpolation bias: its bound plus 3 sigma covers it
    bound = np.array([[float(r[COLUMNS.index(c)]) for c in ("bias_bound_u_px", "bias_bound_v_px")] for r in converged])
    error = np.abs(np.column_stack([u - SHIFT_PX[0], v - SHIFT_PX[1]]))
    assert np.mean(error <= bound + 3 * sigma) >= 0.95, (error.max(axis=0), bound.max(axis=0))


def test_a_negative_seed_guess_is_an_option_value(pair, tmp_path):
    """``--seed-guess -3,2`` used to be taken for an unknown option ("expected one argument")."""
    ref, dfm = pair
    out = tmp_path / "points.csv"
    assert main(["dic", str(ref), str(dfm), "--roi", ROI, "--step", "20", "--seed-guess", "-3,2",
                 "--seed-point", "100,80", "--out", str(out)]) == 0
    _, rows = _rows(out)
    u = np.array([float(r[2]) for r in rows if r[7] == "converged"])
    assert u.size == len(rows) and np.abs(u - SHIFT_PX[0]).max() < 1e-3


@pytest.mark.parametrize("args, option, message", [
    (["--roi", "inf,0,10,10"], "--roi", "finite"),                     # was an OverflowError traceback
    (["--roi", "nan,0,10,10"], "--roi", "finite"),
    (["--roi", "1,2,3"], "--roi", "four numbers"),
    (["--roi", "10,10,5,50"], "--roi", "X0 < X1"),
    (["--roi", "-5,0,50,50"], "--roi", "0 <= X0"),
    (["--roi", "0,0,9999,50"], "--roi", "reaches outside the 200 x 160 px image"),
    (["--seed-guess", "inf,0"], "--seed-guess", "finite"),             # was an OverflowError traceback
    (["--seed-guess", "1e300,0"], "--seed-guess", "outside the 200 x 160 px image"),
    (["--seed-point", "nan,5"], "--seed-point", "finite"),             # was silently ignored
    (["--seed-point", "999,5"], "--seed-point", "outside the 200 x 160 px image"),   # was silently ignored
    (["--seed-point", "-1,5"], "--seed-point", "outside the 200 x 160 px image"),
    (["--roi", "20,20,60,60", "--seed-point", "150,100"], "--seed-point", "not near any point of interest"),
    (["--subset", "4"], "--subset", "odd and >= 5"),
    (["--subset", "34"], "--subset", "odd and >= 5"),
    (["--subset", "9999"], "--subset", "does not fit the 200 x 160 px image"),   # was "roi (4999, ...) ..."
    (["--step", "0"], "--step", ">= 1"),
    (["--order", "3"], "--order", "invalid choice"),
    (["--min-zncc", "2"], "--min-zncc", "[-1, 1]"),
    (["--min-zncc", "nan"], "--min-zncc", "finite"),
    (["--tolerance", "0"], "--tolerance", "> 0"),
    (["--tolerance", "inf"], "--tolerance", "finite"),
    (["--lowpass-sigma", "-1"], "--lowpass-sigma", ">= 0"),
    (["--search-radius", "0"], "--search-radius", ">= 1"),
    (["--threads", "0"], "--threads", ">= 1"),
])
def test_bad_option_exits_2_with_one_line_naming_it(pair, tmp_path, capsys, args, option, message):
    ref, dfm = pair
    out = tmp_path / "points.csv"
    assert main(["dic", str(ref), str(dfm), "--out", str(out)] + args) == 2
    line = _last_error_line(capsys)
    assert line.startswith("workbench dic: error:") and option in line and message in line, line
    assert not out.exists()


def test_a_directory_given_as_an_image_says_so(pair, tmp_path, capsys):
    ref, _ = pair
    assert main(["dic", str(ref), str(tmp_path), "--out", str(tmp_path / "p.csv")]) == 2
    assert f"deformed image {tmp_path} is a directory" in _last_error_line(capsys)
    assert main(["dic", str(ref), str(ref), "--mask", str(tmp_path), "--out", str(tmp_path / "p.csv")]) == 2
    assert f"--mask {tmp_path} is a directory" in _last_error_line(capsys)
    assert main(["dic", str(ref), str(ref), "--out", str(tmp_path)]) == 2
    assert f"--out {tmp_path} is a directory" in _last_error_line(capsys)


def test_a_frame_stack_is_refused_before_any_output(pair, tmp_path, capsys):
    """A 3-frame stack saved by tifffile (one planar 'RGB' page) used to be read as a grey mix of the frames and
    the DIC exited 0; it exits 2 naming the file and the frame count, and writes nothing."""
    import warnings

    import tifffile

    ref, dfm = pair
    frames = np.stack([cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in (ref, dfm, ref)])
    stack = tmp_path / "frames.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tifffile.imwrite(stack, frames)
    out = tmp_path / "points.csv"
    assert main(["dic", str(stack), str(dfm), "--roi", ROI, "--step", "20", "--out", str(out)]) == 2
    assert f"{stack} holds 3 pages" in _last_error_line(capsys)
    assert not out.exists()


def test_a_full_disk_leaves_no_partial_csv(pair, tmp_path, capsys, monkeypatch):
    """ENOSPC while the CSV is flushed: exit 2, the message names the file, the earlier file is untouched and
    no temporary file is left (the CSV used to be left cut mid-row)."""
    ref, dfm = pair
    out = tmp_path / "points.csv"
    out.write_text("earlier results\n")

    def full_disk(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full_disk)
    assert main(["dic", str(ref), str(dfm), "--roi", ROI, "--step", "20", "--out", str(out)]) == 2
    line = _last_error_line(capsys)
    assert str(out) in line and "No space left on device" in line
    assert out.read_text() == "earlier results\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["points.csv"]


def test_dic_static_pair_gives_the_noise(tmp_path, capsys):
    """`workbench dic --static`: the noise measured on the static pair is within 5 % of the 8-bit images' true
    noise (2 grey read + quantisation); a "static" image shifted by 0.8 px is refused, naming --static."""
    from scenes.sensor.noise import SensorNoise

    reference, deformed = fourier_shifted_pair((200, 240), 4.0, SHIFT_PX, seed=5, mean_grey=128.0, std_grey=30.0)
    noise = SensorNoise(read_noise_grey=2.0, bit_depth=8)
    files = {}
    for k, (name, image) in enumerate((("ref", reference), ("def", deformed), ("static", reference))):
        files[name] = tmp_path / f"{name}.png"
        assert cv2.imwrite(str(files[name]), noise.apply(image, seed=k).astype(np.uint8))
    out = tmp_path / "points.csv"
    assert main(["dic", str(files["ref"]), str(files["def"]), "--roi", ROI, "--static", str(files["static"]),
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    grey = float(printed.split("noise from the static pair: ")[1].split(" grey")[0])
    assert abs(grey / np.hypot(2.0, 12 ** -0.5) - 1.0) < 0.05, printed
    _, moved = fourier_shifted_pair((200, 240), 4.0, (0.8, 0.0), seed=5, mean_grey=128.0, std_grey=30.0)
    assert cv2.imwrite(str(tmp_path / "moved.png"), noise.apply(moved, seed=9).astype(np.uint8))
    assert main(["dic", str(files["ref"]), str(files["def"]), "--roi", ROI, "--static", str(tmp_path / "moved.png"),
                 "--out", str(tmp_path / "x.csv")]) == 2
    assert "--static" in capsys.readouterr().err and not (tmp_path / "x.csv").exists()
