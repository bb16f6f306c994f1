"""The accuracy gate: passes on this project's settings, fails with a clear JUnit failure when degraded.

Claims: a gate file's mistakes are named (file, check, key); a metric fails on its threshold and on its
baseline tolerance in the stated direction; a small 2-D gate written as its own baseline passes, and the same
gate with bicubic interpolation (biquintic in the baseline) or a smaller subset (higher noise floor) fails,
with one JUnit test case per metric and the measured / threshold / baseline values in the failure message.
"""
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from workbench.gate import GateError, MetricRule, load_gate, verdict

SMALL = """
[gate]
name = "small"
baseline = "baseline.json"
[instrument]
subset_px = {subset}
step_px = 8
shape_order = 1
interpolation = "{interp}"
[[check]]
name = "bias"
kind = "dic2d_bias"
[check.params]
shifts_px = [0.0, 0.2, 0.4]
[check.scenario.image2d]
size_px = 160
[check.metrics.max_abs_bias_px]
max = 0.01
rel_tol = 0.5
abs_tol = 0.0002
[[check]]
name = "noise"
kind = "dic2d_noise"
[check.scenario.image2d]
size_px = 256
[check.metrics.random_error_px]
max = 0.05
rel_tol = 0.1
[check.metrics.ratio_to_pan_floor]
max = 1.3
"""


def _gate(folder, subset=33, interp="biquintic"):
    path = folder / "gate.toml"
    path.write_text(SMALL.format(subset=subset, interp=interp))
    return path


def _run(path, out, *extra):
    return subprocess.run([sys.executable, "-m", "workbench.cli", "gate", str(path), "--out", str(out), *extra],
                          capture_output=True, text=True)


def test_verdicts_follow_threshold_baseline_and_direction():
    rule = MetricRule("e", max=1.0, rel_tol=0.1, abs_tol=0.01)
    assert verdict(rule, 0.5, 0.5)[0]
    assert verdict(rule, 0.5 + 0.05 + 0.0099, 0.5)[0]             # within 10 % + abs_tol
    ok, msg = verdict(rule, 0.5 + 0.05 + 0.0101, 0.5)
    assert not ok and "worse than the baseline 0.5" in msg
    ok, msg = verdict(rule, 1.2, None)
    assert not ok and msg.startswith("measured 1.2 > threshold 1")
    higher = MetricRule("f", min=0.9, rel_tol=0.01, better="higher")
    assert verdict(higher, 0.999, 0.99)[0]                          # better than the baseline: passes
    assert not verdict(higher, 0.97, 0.99)[0]
    assert not verdict(higher, float("nan"), 0.99)[0]


@pytest.mark.parametrize("text, message", [
    ('[[check]]\nname = "a"\nkind = "nope"\n[check.metrics.x]\nmax = 1\n', r"check\[0\]\.kind: 'nope' is not one of"),
    ('[[check]]\nname = "a"\nkind = "dic2d_bias"\n[check.metrics.x]\nmax = "1"\n', r"metrics\.x\.max: '1' is not a finite"),
    ('[[check]]\nname = "a"\nkind = "dic2d_bias"\n[check.metrics.x]\nmaxx = 1\n', r"metrics\.x\.maxx: unknown key"),
    ('[instrument]\nsubset_pxx = 3\n[[check]]\nname = "a"\nkind = "dic2d_bias"\n[check.metrics.x]\nmax = 1\n',
     r"instrument\.subset_pxx"),
    ('[[check]]\nname = "a"\nkind = "dic2d_bias"\n[check.scenario.render]\nnoise = 1\n[check.metrics.x]\nmax = 1\n',
     r"check 'a': scenario: render\.noise: no such parameter"),
    ('[[check]]\nname = "a"\nkind = "dic2d_bias"\n', r"check\[0\]\.metrics: a check needs at least one metric"),
])
def test_gate_file_mistakes_are_named(tmp_path, text, message):
    path = tmp_path / "g.toml"
    path.write_text(text)
    with pytest.raises(GateError, match=message):
        load_gate(path)


def test_gate_passes_on_its_baseline_and_fails_when_degraded(tmp_path):
    path = _gate(tmp_path)
    first = _run(path, tmp_path / "base", "--update-baseline")
    assert first.returncode == 0, first.stderr
    assert (tmp_path / "baseline.json").is_file()
    again = _run(path, tmp_path / "again", "--junit", str(tmp_path / "again.xml"))
    assert again.returncode == 0, again.stdout + again.stderr
    suite = ET.parse(tmp_path / "again.xml").getroot()
    assert suite.get("tests") == "3" and suite.get("failures") == "0"

    bicubic = _run(_gate(tmp_path, interp="bicubic"), tmp_path / "bicubic", "--junit", str(tmp_path / "bicubic.xml"))
    assert bicubic.returncode == 1
    failed = {c.get("name"): c.find("failure") for c in ET.parse(tmp_path / "bicubic.xml").getroot()
              if c.find("failure") is not None}
    assert "max_abs_bias_px" in failed
    assert "worse than the baseline" in failed["max_abs_bias_px"].get("message")

    small = _run(_gate(tmp_path, subset=17), tmp_path / "small", "--junit", str(tmp_path / "small.xml"))
    assert small.returncode == 1
    failed = {c.get("name") for c in ET.parse(tmp_path / "small.xml").getroot() if c.find("failure") is not None}
    assert "random_error_px" in failed                  # a 17 px subset roughly doubles the noise floor
    assert "FAIL" in (tmp_path / "small" / "gate.md").read_text()
