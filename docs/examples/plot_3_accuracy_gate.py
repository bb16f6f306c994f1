"""
An accuracy gate for CI
=======================

A gate file names quick checks, the metrics each must keep, their thresholds and the tolerance against a committed
baseline. ``workbench gate`` runs them, prints a table, writes ``gate.md`` and JUnit XML (one test case per metric,
so CI shows which figure regressed) and exits 1 on any regression. This project's own gate
(``gates/gates.toml``) runs in its CI after the tests.

Here a two-check gate (the bias of 2-D DIC over sub-pixel shifts, and its noise floor against Pan et al. 2008) is
run twice. The first run, with the instrument as configured (biquintic interpolation), writes the baseline
(``--update-baseline``). The second, with a degraded instrument (bicubic interpolation), still meets the absolute
bias threshold of 0.002 px, but is worse than the baseline by more than the tolerance it allows: the gate fails.
"""
import tempfile
from pathlib import Path

from workbench.scoring.gate import load_gate, run_gate, table_lines, write_junit

work = Path(tempfile.mkdtemp(prefix="gate-"))
gate_text = '''
[gate]
name = "2-D DIC"
baseline = "baseline.json"

[instrument]
subset_px = 33
step_px = 8
shape_order = 1
interpolation = "{interpolation}"

[[check]]
name = "bias_curve"
kind = "dic2d_bias"
[check.metrics.max_abs_bias_px]
max = 0.002
rel_tol = 0.5
abs_tol = 0.0002

[[check]]
name = "noise_floor"
kind = "dic2d_noise"
[check.metrics.ratio_to_pan_floor]
max = 1.25
rel_tol = 0.1
'''
for interpolation, update_baseline in (("biquintic", True), ("bicubic", False)):
    path = work / f"gate_{interpolation}.toml"         # both files share work/baseline.json
    path.write_text(gate_text.replace("{interpolation}", interpolation))
    record = run_gate(load_gate(path), work / interpolation, update_baseline=update_baseline, log=lambda *a: None)
    write_junit(record, work / interpolation / "gate-junit.xml")
    what = "wrote the baseline" if update_baseline else ("PASSED" if record["passed"] else "FAILED")
    print(f"interpolation = {interpolation}: {what}")
    print("\n".join(table_lines(record)))
    print()

# %%
# In CI, the command is one line; its exit code fails the job::
#
#     workbench gate gates/gates.toml --junit gate-junit.xml --out gate/
#
# ``--engine 'mytool {ref} {def} {out} ...'`` (or ``module:function``) gates your own DIC code instead of this
# project's; ``--update-baseline`` rewrites the baseline when a change is meant to move a figure.
