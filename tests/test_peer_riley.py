"""riley (pyvale's rasteriser, ``riley-raster``) beside our renderer: benchmarks/render_peer_riley.py at a tiny
size. Both render the same speckled plate in both cameras of ``paper_rig(0.1)``; each image is checked against
the speckle texture itself (numpy), not against the other renderer. Run with
``python -m pytest -m peers tests/test_peer_riley.py`` in an environment with ``pip install '.[peers]'``."""
import math
import sys
from pathlib import Path

import numpy as np
import pytest

riley = pytest.importorskip("riley")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import render_peer_riley as bench  # noqa: E402

pytestmark = pytest.mark.peers

SCALE = 0.1
SPP = 16            # riley: 4 x 4 sub-pixel grid


@pytest.fixture(scope="module")
def result():
    return bench.render_pair_both(SCALE, SPP, repeat=1)


def _window_mean_sigma(texture: np.ndarray, window: tuple[int, int], n: int = 2000) -> float:
    """Standard deviation of the texture's mean over randomly placed windows (periodic texture, wrapped)."""
    tex = np.asarray(texture, float)
    r, c = tex.shape
    wr, wc = min(r, window[0]), min(c, window[1])
    sat = np.pad(np.pad(tex, ((0, wr), (0, wc)), mode="wrap").cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    rng = np.random.default_rng(0)
    i, j = rng.integers(0, r, n), rng.integers(0, c, n)
    means = (sat[i + wr, j + wc] - sat[i, j + wc] - sat[i + wr, j] + sat[i, j]) / (wr * wc)
    return float(means.std())


def test_both_renderers_image_the_same_texture(result):
    scene = result["scene"]
    tex = scene.texture
    h, w = scene.rig.left.height, scene.rig.left.width
    assert (h, w) == (scene.rig.right.height, scene.rig.right.width)
    lo, hi = float(tex.min()) * bench.EXPOSURE_GREY, float(tex.max()) * bench.EXPOSURE_GREY
    tex_mean_grey = float(np.mean(tex, dtype=np.float64)) * bench.EXPOSURE_GREY
    # Tolerance on an image's mean grey level: a view sees only part of the plate (about w*h*2.5^2 texels:
    # 2.5 texels per pixel at the plate), so its mean differs from the whole texture's mean by the spread of
    # window means of the speckle field, measured here with numpy: 4 sigma of that, plus 0.1 grey for the rest
    # (ours: 16-sample MC noise averaged over ~5e4 pixels, < 0.05 grey; the view is oblique, not a window).
    sigma = _window_mean_sigma(tex, (round(h * 2.5), round(w * 2.5))) * bench.EXPOSURE_GREY
    tol = 4 * sigma + 0.1
    assert 0.5 < tol < 6, tol        # the derivation itself: speckle windows of this size vary by ~1 grey

    names = [r["renderer"] for r in result["rows"]]
    assert names[0].startswith("ours") and names[1].startswith("riley")
    for row in result["rows"]:
        assert row["width"] == w and row["height"] == h
        assert row["spp"] == SPP
        assert len(row["images"]) == 2
        for side, image in zip(bench.SIDES, row["images"]):
            what = f"{row['renderer']}, {side}"
            assert image.shape == (h, w), what
            assert np.all(np.isfinite(image)), what
            # Bilinear lookups and box averages are convex combinations of texels: every pixel that sees only
            # the plate lies in [min, max] of the texture. A miss gives 0 (ours) or a hugely negative value
            # (riley's background) in that pixel, so this also says the plate covers the whole view.
            assert image.min() >= lo - 1e-3 and image.max() <= hi + 1e-3, (what, image.min(), image.max())
            assert abs(float(image.mean()) - tex_mean_grey) <= tol, (what, image.mean(), tex_mean_grey, tol)
            # A speckle image, not a flat field: the pixel box (2.5 texels) barely blurs 5 px speckles.
            assert image.std() > 0.5 * float(tex.std()) * bench.EXPOSURE_GREY, what
        assert row["seconds"] > 0 and math.isfinite(row["seconds"])
        expected = w * h * row["spp"] * 2 / row["seconds"] / 1e6
        assert math.isfinite(row["msamples_per_s"]) and row["msamples_per_s"] > 0
        assert row["msamples_per_s"] == pytest.approx(expected)


def test_ours_sees_the_plate_over_every_pixel(result):
    """Our partial-coverage pixels would still lie in the texture's range: check coverage itself."""
    from scenes.rendering.mitsuba import render_view

    scene = result["scene"]
    for side in bench.SIDES:
        r = render_view(scene.specs[side], *scene.poses[side], [scene.surface], spp=4, truth=True)
        assert r.coverage.shape == scene.shape
        assert float(r.coverage.min()) == pytest.approx(1.0, abs=1e-6), side


def test_riley_sub_sample_is_a_square_grid():
    assert [bench.riley_sub_sample(s) for s in (1, 4, 16, 64, 100)] == [1, 2, 4, 8, 10]
    assert bench.riley_sub_sample(50) ** 2 == 49
    with pytest.raises(ValueError, match="spp must be >= 1, got 0"):
        bench.riley_sub_sample(0)


def test_table_lists_both_renderers_and_the_machine(result):
    table = bench.format_table(result, SPP, 1)
    assert "ours (Mitsuba" in table and "riley (rasteriser)" in table
    assert "os.cpu_count()" in table and "riley-raster" in table
    assert "4 x 4 sub-pixel grid" in table
