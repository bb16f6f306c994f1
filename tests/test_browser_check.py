"""The browser check (issue 37): a report read in headless Chromium at 1280 px fails on a figure cut off past the
window, an image that does not load, or a plotted axis without a label; a report that has none of these passes.

The reference is Chromium's own layout (the page's scroll width, each image's decoded size), not our HTML writer.
"""
from __future__ import annotations

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from workbench.reporting.browser_check import check_in_browser, chromium_path  # noqa: E402
from labio.figures import png_bytes, read_axes_record  # noqa: E402
from workbench.reporting.html_report import write_html_report  # noqa: E402

needs_chromium = pytest.mark.skipif(chromium_path() is None, reason="no Chromium (scripts/bootstrap.sh installs "
                                                                  "Debian's package as root)")


def _figure(label_y: bool = True, colorbar_label: bool = True) -> bytes:
    fig, ax = plt.subplots(figsize=(6, 3))
    im = ax.imshow(np.arange(12.0).reshape(3, 4))
    ax.set_xlabel("x (px)")
    if label_y:
        ax.set_ylabel("y (px)")
    bar = fig.colorbar(im, ax=ax)
    if colorbar_label:
        bar.set_label("error (µm)")
    return png_bytes(fig, dpi=80)


def test_figures_record_their_axes():
    """The PNG carries, per axes, its labels and whether it has tick labels; a colour bar its label; a PNG from
    elsewhere carries nothing."""
    record = read_axes_record(_figure(label_y=False))
    axes = [a for a in record if a["kind"] == "axes"]
    bars = [a for a in record if a["kind"] == "colorbar"]
    assert len(axes) == 1 and axes[0]["xlabel"] == "x (px)" and axes[0]["ylabel"] == ""
    assert axes[0]["xticks"] and axes[0]["yticks"]
    assert len(bars) == 1 and bars[0]["label"] == "error (µm)"
    fig, _ = plt.subplots()
    import io

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    plt.close(fig)
    assert read_axes_record(buffer.getvalue()) is None


@needs_chromium
def test_a_good_report_passes_and_each_defect_fails(tmp_path):
    """A report of one labelled figure and a table passes (the page is exactly the window's width); the same report
    with its figure in a 1 600 px wide block fails naming the block; an image that does not decode, a
    y axis without a label and a colour bar without a label fail, each named."""
    (tmp_path / "good.png").write_bytes(_figure())
    (tmp_path / "nolabel.png").write_bytes(_figure(label_y=False, colorbar_label=False))
    text = "# A report\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\n![the map](good.png)\n"
    good = write_html_report(tmp_path / "good.html", "good", text, tmp_path)
    result = check_in_browser(good, screenshot=tmp_path / "good_shot.png")
    assert result["ok"], result["problems"]
    assert result["layout"]["scrollWidth"] == 1280 and result["figures"] == 1
    assert (tmp_path / "good_shot.png").stat().st_size > 1000

    html = good.read_text()
    wide = tmp_path / "wide.html"
    wide.write_text(html.replace("<img ", '<div id="cutoff" style="width:1600px"><img style="max-width:none;'
                                          'width:1600px" ', 1).replace("</p>\n</body>", "</p></div>\n</body>"))
    cut = check_in_browser(wide)
    assert not cut["ok"]
    assert cut["layout"]["scrollWidth"] > 1600
    assert any("horizontal overflow" in p and "<div> 'cutoff' reaches" in p for p in cut["problems"]), cut["problems"]

    broken = tmp_path / "broken.html"
    broken.write_text(html.replace('src="data:image/png;base64,', 'src="data:image/png;base64,AAAA', 1))
    assert any("image 1 ('the map') does not load" in p for p in check_in_browser(broken)["problems"])

    unlabelled = write_html_report(tmp_path / "nolabel.html", "n", text.replace("good.png", "nolabel.png"), tmp_path)
    problems = check_in_browser(unlabelled)["problems"]
    assert any("y axis has ticks but no label" in p for p in problems), problems
    assert any("a colour bar without a label" in p for p in problems), problems


@needs_chromium
def test_a_figure_written_elsewhere_fails_the_check(tmp_path):
    """A PNG that does not carry the record of its axes cannot show they are labelled: the check names it."""
    import io

    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=60)
    plt.close(fig)
    (tmp_path / "plain.png").write_bytes(buffer.getvalue())
    report = write_html_report(tmp_path / "r.html", "r", "# r\n\n![plain figure](plain.png)\n", tmp_path)
    problems = check_in_browser(report)["problems"]
    assert problems == ["figure 1 ('plain figure'): no record of its axes (not written through "
                        "labio.figures)"]
