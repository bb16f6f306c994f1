"""Read a report the way its reader does: in a real browser (headless Chromium), at a laptop's width.

:func:`check_in_browser` opens an HTML report in Debian's Chromium (``chromium --headless``) at 1280 px wide and
fails it when

* the page is wider than the window (horizontal overflow: a figure or table cut off behind a scrollbar), naming
  the widest elements that stick out;
* an image does not load or decode (``naturalWidth == 0``);
* a figure has a plotted axis without a label: every figure the project writes carries, in its PNG, the labels of
  its axes (:func:`labio.figures.png_bytes`); an axis with ticks and no label, a colour bar without
  one, or a figure with no such record fails (a PNG from elsewhere cannot show its axes were labelled).

Optionally it writes a screenshot of the report's first screens (for a human reader, e.g. a closing note).

The layout is measured by a script added to a temporary copy of the report (the report itself has no script), read
back from Chromium's ``--dump-dom``. Chromium is found as ``chromium`` (Debian's package) or ``$WORKBENCH_CHROMIUM``.
"""
from __future__ import annotations

import base64
import json
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

__all__ = ["chromium_path", "check_in_browser", "BrowserCheckError"]

#: The reader's window: a laptop screen.
WIDTH_PX = 1280
HEIGHT_PX = 900

_PROBE = """
<script>
window.addEventListener("load", function () {
  var doc = document.documentElement, width = window.innerWidth;
  var out = {innerWidth: width, scrollWidth: doc.scrollWidth, overflowing: [], images: []};
  var all = document.body.getElementsByTagName("*");
  for (var i = 0; i < all.length; i++) {
    var r = all[i].getBoundingClientRect();
    if (r.right > width + 1) {
      var e = all[i];
      out.overflowing.push({tag: e.tagName.toLowerCase(), right: Math.round(r.right), width: Math.round(r.width),
                            what: (e.getAttribute("alt") || e.id || (e.textContent || "").slice(0, 60)).trim()});
    }
  }
  var imgs = document.images;
  for (var k = 0; k < imgs.length; k++) {
    var im = imgs[k];
    out.images.push({alt: im.getAttribute("alt") || "", complete: im.complete, naturalWidth: im.naturalWidth,
                     shownWidth: Math.round(im.getBoundingClientRect().width)});
  }
  var pre = document.createElement("pre");
  pre.id = "__browser_check__";
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>
"""
_RESULT = re.compile(r'<pre id="__browser_check__">(.*?)</pre>', re.S)


class BrowserCheckError(RuntimeError):
    """Chromium could not be found or run (the message says how to get it)."""


def chromium_path() -> str | None:
    """The Chromium executable: ``$WORKBENCH_CHROMIUM``, else ``chromium`` / ``chromium-browser`` on the PATH."""
    env = os.environ.get("WORKBENCH_CHROMIUM")
    if env:
        return env
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return None


def _run_chromium(args: list[str], timeout_s: float) -> subprocess.CompletedProcess:
    exe = chromium_path()
    if exe is None:
        raise BrowserCheckError("no Chromium: install Debian's package (apt-get install chromium; scripts/bootstrap.sh "
                                "does as root) or set WORKBENCH_CHROMIUM to its executable")
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--hide-scrollbars",
             "--disable-background-networking", "--disable-extensions", "--no-first-run", "--mute-audio",
             f"--window-size={WIDTH_PX},{HEIGHT_PX}"]
    with tempfile.TemporaryDirectory(prefix="workbench-chromium-") as profile:
        return subprocess.run([exe, *flags, f"--user-data-dir={profile}", *args], capture_output=True, text=True,
                              timeout=timeout_s)


def png_axes_records(html_text: str) -> list[dict]:
    """For each ``<img>`` of a report, in page order: ``{"alt", "axes"}`` with ``axes`` the figure's record of its axes
    (a list, :func:`labio.figures.png_bytes`), or None where the image carries none (not an embedded
    PNG, or a PNG written another way)."""
    from html.parser import HTMLParser

    from labio.figures import read_axes_record

    images = []

    class Images(HTMLParser):
        def handle_starttag(self, tag, attrs):
            if tag == "img":
                images.append(dict(attrs))

    Images(convert_charrefs=True).feed(html_text)
    out = []
    for attrs in images:
        src = attrs.get("src") or ""
        record = None
        if src.startswith("data:image/png;base64,"):
            try:
                record = read_axes_record(base64.b64decode(src.split(",", 1)[1]))
            except (ValueError, TypeError):
                record = None
        out.append({"alt": attrs.get("alt") or "", "axes": record})
    return out


def unlabelled_axes(records: list[dict]) -> list[str]:
    """One sentence per figure axis that is plotted but carries no label (or per figure with no record)."""
    problems = []
    for k, rec in enumerate(records, 1):
        name = f"figure {k} ({rec['alt'][:60]!r})"
        if rec["axes"] is None:
            problems.append(f"{name}: no record of its axes (not written through labio.figures)")
            continue
        for a in rec["axes"]:
            where = f"{name}, panel {a.get('title') or a['index']!r}"
            if a["kind"] == "colorbar":
                if not a.get("label"):
                    problems.append(f"{where}: a colour bar without a label")
                continue
            if a.get("xticks") and not a.get("xlabel"):
                problems.append(f"{where}: x axis has ticks but no label")
            if a.get("yticks") and not a.get("ylabel"):
                problems.append(f"{where}: y axis has ticks but no label")
    return problems


def check_in_browser(path: str | Path, *, screenshot: str | Path | None = None, timeout_s: float = 120.0) -> dict:
    """Open the report ``path`` in headless Chromium at :data:`WIDTH_PX` and check it (module notes).

    Returns ``{"ok": bool, "problems": [sentences], "layout": what the page measured, "figures": n}``; writes a
    screenshot of the first 2 400 px of the page to ``screenshot`` when given. Raises :class:`BrowserCheckError` when
    Chromium is missing or fails, FileNotFoundError for a missing report.
    """
    path = Path(path).resolve()
    text = path.read_text(encoding="utf-8")
    probe = text.replace("</body>", _PROBE + "</body>") if "</body>" in text else text + _PROBE
    # the probe goes into a copy in a private temporary folder (deleted with it): the report itself is never written
    with tempfile.TemporaryDirectory(prefix="workbench-browser-check-") as tmp:
        copy = Path(tmp) / path.name
        copy.write_text(probe, encoding="utf-8")
        done = _run_chromium(["--virtual-time-budget=20000", "--run-all-compositor-stages-before-draw", "--dump-dom",
                              copy.as_uri()], timeout_s)
    m = _RESULT.search(done.stdout)
    if m is None:
        raise BrowserCheckError(f"{path}: Chromium returned no layout (exit {done.returncode}): "
                                f"{done.stderr.strip()[-400:]}")
    import html as _html

    layout = json.loads(_html.unescape(m.group(1)))
    problems = []
    if layout["scrollWidth"] > layout["innerWidth"] + 1:
        sticking = sorted(layout["overflowing"], key=lambda e: -e["right"])[:3]
        problems.append(f"the page is {layout['scrollWidth']} px wide in a {layout['innerWidth']} px window "
                        "(horizontal overflow): " + "; ".join(f"<{e['tag']}> {e['what']!r} reaches {e['right']} px"
                                                               for e in sticking))
    for k, im in enumerate(layout["images"], 1):
        if not im["complete"] or im["naturalWidth"] == 0:
            problems.append(f"image {k} ({im['alt'][:60]!r}) does not load")
    records = png_axes_records(text)
    problems += unlabelled_axes(records)
    if screenshot is not None:
        shot = Path(screenshot).resolve()
        shot.parent.mkdir(parents=True, exist_ok=True)
        _run_chromium([f"--window-size={WIDTH_PX},2400", f"--screenshot={shot}", path.as_uri()], timeout_s)
    return {"ok": not problems, "problems": problems, "layout": layout, "figures": len(records)}


def main(argv: list[str] | None = None) -> int:
    """``python -m workbench.reporting.browser_check REPORT.html ... [--screenshots DIR]``: exit 1 when a report
    fails, naming every problem."""
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", type=Path, nargs="+")
    parser.add_argument("--screenshots", type=Path, default=None,
                        help="folder for one screenshot per report (JPEG, the first 2 400 px of the page)")
    args = parser.parse_args(argv)
    failed = 0
    for k, report in enumerate(args.reports):
        shot = None
        if args.screenshots is not None:       # JPEG: a few screens of a report, small enough to keep
            shot = args.screenshots / (re.sub(r"[^A-Za-z0-9_.-]+", "_", str(report.parent)).strip("_") + ".jpg")
        result = check_in_browser(report, screenshot=shot)
        status = "ok" if result["ok"] else "FAILED"
        print(f"{status}: {report} ({result['figures']} figures, {result['layout']['scrollWidth']} px wide)")
        for p in result["problems"]:
            print(f"  - {p}")
        failed += not result["ok"]
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
