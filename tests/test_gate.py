"""The accuracy gate: passes on this project's settings, fails with a clear JUnit failure when degraded.

Claims: a gate file's mistakes are named (file, check, key); a metric fails on its threshold and on its
baseline tolerance in the stated direction; a small 2-D gate written as its own baseline passes, and the same
gate with bicubic interpolation (biquintic in the baseline) or a smaller subset (higher noise floor) fails,
with one JUnit test case per metric and the measured / threshold / baseline values in the failure message.
"""
import json
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from workbench.scoring.gate import GateError, MetricRule, load_gate, verdict

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
    assert suite.get("tests") == "4" and suite.get("failures") == "0"     # 3 metrics and the baseline's own case

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
    from workbench.reporting.html_report import check_html_report

    page = check_html_report(tmp_path / "small" / "report.html")      # the same table, as a page a reader opens
    assert any(t["columns"] > 3 for t in page["tables"])
    assert "FAIL" in (tmp_path / "small" / "report.html").read_text()


def test_a_stale_baseline_is_said_and_fails_the_gate_when_required(tmp_path):
    """Issue 35: the committed baseline was not what a fresh clone measures and nothing said so. A baseline records
    the hashes of the sources that measured it; one whose source has changed since (here: its recorded hash of
    measurement/dic/icgn.py no longer matches the file), or that records none, is named stale with the file; with
    --require-current-baseline the gate fails on it (exit 1, a JUnit failure), without it the gate only says so."""
    path = _gate(tmp_path)
    assert _run(path, tmp_path / "base", "--update-baseline").returncode == 0
    doc = json.loads((tmp_path / "baseline.json").read_text())
    sources = doc["measured_with"]["sources"]
    assert "measurement/dic/icgn.py" in sources                      # the code that measured the figures
    assert all(len(h) == 64 for h in sources.values()) and "workbench/scoring/gate.py" in sources
    current = _run(path, tmp_path / "current", "--require-current-baseline")
    assert current.returncode == 0 and "baseline.json is current" in current.stdout, current.stdout

    sources["measurement/dic/icgn.py"] = "0" * 64                    # the IC-GN code changed after the baseline
    (tmp_path / "baseline.json").write_text(json.dumps(doc))
    said = _run(path, tmp_path / "said")
    assert said.returncode == 0 and "is STALE" in said.stdout and "measurement/dic/icgn.py" in said.stdout
    failed = _run(path, tmp_path / "failed", "--require-current-baseline", "--junit", str(tmp_path / "stale.xml"))
    assert failed.returncode == 1 and "FAILED (the baseline is stale)" in failed.stdout
    case = next(c for c in ET.parse(tmp_path / "stale.xml").getroot() if c.get("classname") == "gate.baseline")
    assert "measurement/dic/icgn.py" in case.find("failure").text

    del doc["measured_with"]                                         # an old baseline: nothing says which code
    (tmp_path / "baseline.json").write_text(json.dumps(doc))
    old = _run(path, tmp_path / "old", "--require-current-baseline")
    assert old.returncode == 1 and "records no source fingerprint" in old.stdout


def test_the_committed_gate_baseline_was_measured_by_this_code():
    """gates/baseline.json is what this checkout measures: every source file that measured it hashes as recorded
    (regenerate with `workbench gate gates/gates.toml --update-baseline --out DIR` after changing one)."""
    from pathlib import Path

    from workbench.scoring.gate import DEFAULT_ENGINE, baseline_staleness

    doc = json.loads((Path(__file__).parents[1] / "gates" / "baseline.json").read_text())
    status = baseline_staleness(doc, DEFAULT_ENGINE)
    assert not status["stale"], status["reasons"]
    assert len(doc["measured_with"]["sources"]) > 20


ONE_CHECK = """
[gate]
name = "settings"
[instrument]
subset_px = 25
step_px = 10
shape_order = {order}
interpolation = "{interp}"
[[check]]
name = "bias"
kind = "dic2d_bias"
[check.params]
shifts_px = [0.3]
[check.scenario.image2d]
size_px = 96
[check.metrics.max_abs_bias_px]
max = 0.05
"""

RECORDING_ENGINE = '''
import json
from pathlib import Path

from workbench.engines import ours


def run(ref, deformed, out, **settings):
    """Writes what it was given beside its result, then measures with this project's instrument."""
    Path(out).with_suffix(".settings.json").write_text(json.dumps(settings))
    return ours(ref, deformed, out, **settings)


def no_order(ref, deformed, out, *, subset_px, step_px, roi_xyxy_px):
    return ours(ref, deformed, out, subset_px=subset_px, step_px=step_px, roi_xyxy_px=roi_xyxy_px)
'''


def _run_env(path, out, *extra, pythonpath):
    import os

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(pythonpath), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "workbench.cli", "gate", str(path), "--out", str(out), *extra],
                          capture_output=True, text=True, env=env)


def test_a_gate_passes_its_settings_to_a_user_engine_and_names_them_in_junit(tmp_path):
    """`workbench gate --engine MODULE:FUNCTION` ran the user's engine without the gate's shape-function order
    and interpolant (it got neither and nothing said so). The engine now receives both as the gate file states
    them (order 2, bicubic: not the engine's defaults 1 and biquintic), and every JUnit case names them."""
    (tmp_path / "recording_engine.py").write_text(RECORDING_ENGINE)
    gate = tmp_path / "gate.toml"
    gate.write_text(ONE_CHECK.format(order=2, interp="bicubic"))
    proc = _run_env(gate, tmp_path / "out", "--engine", "recording_engine:run", "--junit", str(tmp_path / "j.xml"),
                    pythonpath=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    given = [json.loads(p.read_text()) for p in (tmp_path / "out" / "engine").glob("*.settings.json")]
    assert given and all(g["order"] == 2 and g["interpolation"] == "bicubic" for g in given), given
    assert all(g["subset_px"] == 25 and g["step_px"] == 10 for g in given), given
    case = ET.parse(tmp_path / "j.xml").getroot().find("testcase")
    props = {p.get("name"): p.get("value") for p in case.find("properties")}
    assert props == {"engine": "recording_engine:run", "subset_px": "25", "step_px": "10", "order": "2",
                     "interpolation": "bicubic"}
    assert "ran with engine = recording_engine:run, subset_px = 25, step_px = 10, order = 2, interpolation = bicubic" \
        in case.find("system-out").text


@pytest.mark.parametrize("engine, message", [
    ("recording_engine:no_order", r"measures with order = 1, but no_order\(\) takes no 'order' keyword"),
    (f"{sys.executable} -m workbench.cli dic {{ref}} {{def}} --out {{out}}",
     r"measures with order = 1, but the template has no \{order\} placeholder"),
    ("workbench.peers.pyvale_engine:run", r"measures with interpolation = 'biquintic', which the engine does not offer"),
])
def test_an_engine_that_cannot_take_a_setting_is_refused_before_anything_runs(tmp_path, engine, message):
    (tmp_path / "recording_engine.py").write_text(RECORDING_ENGINE)
    gate = tmp_path / "gate.toml"
    gate.write_text(ONE_CHECK.format(order=1, interp="biquintic"))
    proc = _run_env(gate, tmp_path / "out", "--engine", engine, "--store", str(tmp_path / "store"),
                    pythonpath=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert re.search(message, proc.stderr), proc.stderr
    assert not (tmp_path / "store").exists() and not (tmp_path / "out" / "gate.json").exists()


def test_a_command_engine_gets_the_settings_through_its_placeholders(tmp_path):
    """The same gate through a command template with {order} and {interpolation}: the command (a recorder in
    front of our own CLI as 'another tool') is called with the gate's order 2 and bicubic."""
    (tmp_path / "recorder.py").write_text(
        "import json, sys\nfrom pathlib import Path\nfrom workbench.cli import main\n"
        "out = sys.argv[sys.argv.index('--out') + 1]\n"
        "Path(out).with_suffix('.argv.json').write_text(json.dumps(sys.argv[1:]))\n"
        "sys.exit(main(['dic', *sys.argv[1:]]))\n")
    gate = tmp_path / "gate.toml"
    gate.write_text(ONE_CHECK.format(order=2, interp="bicubic"))
    template = (f"{sys.executable} {tmp_path / 'recorder.py'} {{ref}} {{def}} --subset {{subset}} --step {{step}} "
                f"--roi {{roi}} --order {{order}} --interp {{interpolation}} --out {{out}}")
    proc = _run_env(gate, tmp_path / "out", "--engine", template, pythonpath=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    argv = json.loads(next(iter((tmp_path / "out" / "engine").glob("*.argv.json"))).read_text())
    assert argv[argv.index("--order") + 1] == "2" and argv[argv.index("--interp") + 1] == "bicubic", argv
    assert argv[argv.index("--subset") + 1] == "25" and argv[argv.index("--step") + 1] == "10", argv
