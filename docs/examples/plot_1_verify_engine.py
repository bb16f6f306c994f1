"""
Verify a DIC engine on exact truth
==================================

A 2-D pair whose truth is exact: a band-limited speckle and its Fourier translation by 0.25 px, with 2 grey levels
of sensor noise in both images. The scenario is six lines of TOML; the workbench renders it through its store,
runs an engine on it (here this project's instrument, ``workbench.engines:ours``; your own tool is a command line
``'mytool {ref} {def} {out}'`` or a Python function ``module:function``) and scores every point against the truth.

The same three steps are the ``workbench score`` command::

    workbench score pair.toml --engine workbench.engines:ours --out score/
"""
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from workbench.engines import parse_engine, run_engine
from workbench.results import read_result
from workbench.scoring.datasets import open_dataset, point_truth, subset_roi_xyxy_px
from workbench.scoring.metrics import score_state

work = Path(tempfile.mkdtemp(prefix="verify-"))
scenario = work / "pair.toml"
scenario.write_text('experiment = "dic2d"\n'
                    '[render]\nread_noise_grey = 2.0\nbit_depth = 0\n'
                    '[image2d]\nsize_px = 256\nshift_x_px = 0.25\n')
dataset = open_dataset(scenario)                      # rendered once, then reused from the store
print(f"{dataset.kind}: {dataset.image_size_px[0]} x {dataset.image_size_px[1]} px, {dataset.n_states} states")

# %%
# Run the engine on the reference and the deformed image, inside the ROI where its subsets see the specimen.
engine = parse_engine("workbench.engines:ours")
roi = subset_roi_xyxy_px(dataset, 33)
out = work / "result_01.csv"
info = run_engine(engine, dataset.images[0]["left"], dataset.images[1]["left"], out,
                  subset_px=33, step_px=8, roi_xyxy_px=roi)
print(f"engine ran in {info['seconds']:.1f} s")

# %%
# Score: the exact truth is evaluated at every point the engine reports. The random error of first-order subset
# DIC on this image is bounded below by Pan et al. (2008); the bias of a biquintic interpolant at 0.25 px is a few
# thousandths of a pixel.
result = read_result(out, "native")
score = score_state(dataset, 1, result)
for key, value in score.metrics.items():
    if key.endswith("_px") and isinstance(value, float):
        print(f"{key:>24s} = {value:.5f}")

# %%
# The error of every point, against the exact 0.25 px shift.
truth = point_truth(dataset, result.x_px, result.y_px)
error = result.u_px - truth.uv_left_px[1, :, 0]       # the same as score.error_uv_px[:, 0]
fig, ax = plt.subplots(figsize=(6, 4.5))
sc = ax.scatter(result.x_px, result.y_px, c=error, cmap="RdBu_r", vmin=-0.03, vmax=0.03, s=18)
ax.set_aspect("equal")
ax.invert_yaxis()
ax.set_xlabel("x (px)")
ax.set_ylabel("y (px)")
ax.set_title(f"u error (px): mean {np.nanmean(error):+.4f}, std {np.nanstd(error):.4f}")
fig.colorbar(sc, ax=ax)
plt.show()
