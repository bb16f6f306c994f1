"""
An error budget: which source dominates?
========================================

A budget file is a study file with a list of error sources instead of axes. The workbench runs the baseline
(every source off), each source alone, then all together, on Dask (a ``LocalCluster`` here; a scheduler address
for a cluster), and says how far the sources add: linearly (signed, systematic metrics) or in quadrature
(independent random errors).

This budget is of the random error of 2-D subset DIC on a 256 px pair: sensor read noise, shot noise and 8-bit
quantisation. The same file through the command line::

    workbench budget budget.toml --metric random_error_px --out budget/
"""
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from workbench.store import DatasetStore
from workbench.studies.budget import budget_study, write_budget
from workbench.studies.study import load_study
from workbench.studies.sweep import environment_versions, run_sweep

work = Path(tempfile.mkdtemp(prefix="budget-"))
budget_file = work / "budget.toml"
budget_file.write_text('''
[study]
name = "2-D DIC random error budget"
repeats = 2

[scenario]
experiment = "dic2d"
[scenario.render]
bit_depth = 0                 # float images: no quantisation in the baseline
read_noise_grey = 0.5
[scenario.image2d]
size_px = 256
shift_x_px = 0.25

[instrument]
subset_px = 31
step_px = 8
shape_order = 1

[[budget.source]]
name = "read noise 2 grey"
set = { "scenario.render.read_noise_grey" = 2.0 }
[[budget.source]]
name = "shot noise, 4 e-/grey"
set = { "scenario.render.electrons_per_grey" = 4.0 }
[[budget.source]]
name = "8-bit quantisation"
set = { "scenario.render.bit_depth" = 8 }
''')
study = budget_study(load_study(budget_file), "random_error_px")
print(f"{len(study.expand())} cases: " + ", ".join(c.name for c in study.cases))

# %%
# Run the cases on a one-worker ``LocalCluster`` (finished cases are records on disk: a rerun computes only what is
# missing), then write the budget's report.
summary = run_sweep(study, work / "out", store=DatasetStore(), workers=1, progress=False)
result = write_budget(study, work / "out", summary.records, "random_error_px", None,
                      [f"{summary.total} cases in {summary.seconds:.0f} s"], environment_versions())
for row in result["rows"]:
    print(f"{row['case']:<24s} {row['mean']:.5f} px   contribution {row['contribution']:+.5f}")
print(result["check"])

# %%
# The waterfall: each source's contribution on top of the baseline, and the all-sources case beside the sums.
rows = result["rows"]
fig, ax = plt.subplots(figsize=(7, 4))
ax.bar([r["case"] for r in rows], [r["mean"] for r in rows], yerr=[r["std"] for r in rows], color="#4878a8")
ax.set_ylabel("random error of u (px)")
ax.tick_params(axis="x", rotation=20)
ax.set_title("2-D DIC random error: each source alone, then all together")
fig.tight_layout()
plt.show()
