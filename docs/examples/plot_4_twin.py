"""
What will my rig measure? A twin of a real camera
=================================================

Two exposures of an unmoved speckled coupon from a real camera (DICe's "StaticB", camera 0, a 480 x 240 px excerpt
shipped with the tests). The twin reads the pattern and the camera's noise from them, renders the pattern with that
noise, runs the instrument with our settings on the twin, and predicts the static noise; the same instrument on the
real pair says how close the prediction is. The what-if table then ranks what to change.

The same from the command line::

    workbench twin --left staticb_cam0_0.png --static-left staticb_cam0_1.png --subset 27 --step 8 --out twin/
"""
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import workbench
from workbench.twin import TwinSettings, run_twin

data = Path(workbench.__file__).resolve().parents[1] / "tests" / "data" / "twin"     # the repository's excerpt
result = run_twin(data / "staticb_cam0_0.png", static_left=data / "staticb_cam0_1.png", repeats=2, bias=False,
                  resolution=False, settings=TwinSettings(subset_px=27, step_px=8, order=2, strain_window=5))
for key, c in result.comparison.items():
    if not key.endswith("_ue"):
        print(f"{key}: predicted {c['predicted']:.4f} px (instrument's sigma {c['instrument_sigma']:.4f} px), "
              f"measured {c['measured']:.4f} px, ratio {c['ratio']:.2f} ({c['instrument_ratio']:.2f})")
model = result.noise_models["left"]
print(f"camera noise {model.sigma_grey:.2f} grey (read {model.read_noise_grey:.2f} grey, "
      f"gain {model.electrons_per_grey:.0f} e-/grey), speckle {result.speckle['left']['speckle_size_px']:.2f} px")

# %%
# The what-if table: each of our settings changed alone, on the same twin noise draws; beside each bar the
# instrument's own predicted sigma (measurement.uncertainty); l10 (theory) says what a change costs in spatial
# resolution.
rows = [r for r in result.whatif if "displacement_noise" in r]
fig, ax = plt.subplots(figsize=(7, 3.2))
y = np.arange(len(rows))
ax.barh(y, [r["displacement_noise"] for r in rows], color=["C2" if r.get("rank") == 1 else "C0" for r in rows])
ax.plot([r["instrument_sigma_figure"] for r in rows], y, "k|", ms=14, label="instrument's sigma")
ax.set_yticks(y, [f"{r['label']} (l10 {r['l10_theory_px']:.0f} px)" for r in rows], fontsize=7)
ax.invert_yaxis()
ax.set_xlabel("predicted static noise, RMS of u and v (px)")
ax.legend(fontsize=7)
fig.tight_layout()
w = result.whatif_real
print(f"lowest-noise change '{w['label']}': measured on the real pair {w['measured_before']:.4f} -> "
      f"{w['measured_after']:.4f} px ({100 * w['measured_change']:+.0f} %), predicted {100 * w['predicted_change']:+.0f} %")
