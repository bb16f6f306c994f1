"""workbench.reporting.html_report: self-contained HTML reports, checked against an independent reading of the HTML."""
import base64
import io
import re
from html.parser import HTMLParser

import matplotlib.image
import numpy as np
import pytest
from matplotlib.figure import Figure

from workbench.reporting.html_report import check_html_report, markdown_to_html, write_html_report


class _Reader(HTMLParser):
    """The test's own reading of the HTML: tables (cell texts and classes), images, links, list items, tags."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.tables, self.images, self.tags, self.ids, self.hrefs = [], [], [], [], []
        self.strong, self.em, self.code_blocks, self.items = [], [], [], []
        self._cell = self._row = None
        self._capture = []  # open (kind, buffer) captures for strong/em/pre/li
        self._lists = 0
        self._nav = False  # the contents box's links are not the report's lists

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.tags.append((tag, attrs))
        if "id" in attrs:
            self.ids.append(attrs["id"])
        if tag == "a":
            self.hrefs.append(attrs.get("href"))
        if tag == "img":
            self.images.append(attrs)
        elif tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self._row = []
            self.tables[-1].append(self._row)
        elif tag in ("td", "th"):
            self._cell = {"text": "", "class": attrs.get("class"), "tag": tag}
            self._row.append(self._cell)
        elif tag in ("ul", "ol"):
            self._lists += 1
        elif tag == "nav":
            self._nav = True
        elif tag in ("strong", "em", "pre", "li") and not self._nav:
            if tag == "li":  # items in document order, filled in when they close
                self.items.append(None)
            self._capture.append((tag, [], (self._lists, len(self.items) - 1)))

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self._cell = None
        elif tag in ("ul", "ol"):
            self._lists -= 1
        elif tag == "nav":
            self._nav = False
        elif tag in ("strong", "em", "pre", "li") and not self._nav:
            kind, buffer, (depth, slot) = self._capture.pop()
            assert kind == tag, f"<{kind}> closed by </{tag}>"
            text = "".join(buffer)
            if tag == "li":
                self.items[slot] = (text.split("\n")[0].strip(), depth)
            else:
                {"strong": self.strong, "em": self.em, "pre": self.code_blocks}[tag].append(text)

    def handle_data(self, data):
        if self._cell is not None:
            self._cell["text"] += data
        for _, buffer, _ in self._capture:
            buffer.append(data)


def _read(path):
    reader = _Reader()
    reader.feed(path.read_text(encoding="utf-8"))
    reader.close()
    return reader


def _png(path, width, height, seed):
    """A PNG of exactly ``width`` x ``height`` pixels (figsize x dpi, no tight bounding box)."""
    fig = Figure(figsize=(width / 100, height / 100), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.imshow(np.random.default_rng(seed).random((8, 12)), aspect="auto")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


CELLS = [
    ["quantity", "value", "unit", "status"],
    ["bias u", "+0.0012 ± 0.0003", "µm", "pass"],
    ["strain ε", "≤ 5 × 10⁻³", "µm/m", "fail"],
    ["a | b", "90", "°", "passed"],
]

MARKDOWN = """# Test report

Intro with **bold**, snake_case_name, a_b_c, `code_span` and a [link](https://example.org/page).
Second line of the same paragraph.

## Results

| quantity | value | unit | status |
|---|:---:|---:|---|
| bias u | +0.0012 ± 0.0003 | µm | pass |
| strain ε | ≤ 5 × 10⁻³ | µm/m | fail |
| a \\| b | 90 | ° | passed |

- level one
  - level two *italic* here
    - level three
- back to one

1. first
2. second

```python
x_y = 1 * 2 * 3  # <not a tag>
```

## Figures

![first figure](fig_a.png)

![second figure](sub/fig_b.png)
"""


@pytest.fixture
def report(tmp_path):
    fig_a = _png(tmp_path / "fig_a.png", 300, 200, seed=1)
    fig_b = _png(tmp_path / "sub" / "fig_b.png", 120, 80, seed=2)
    out = write_html_report(tmp_path / "out" / "report.html", "Test report", MARKDOWN, tmp_path)
    return out, fig_a, fig_b


def test_report_figures_tables_headings(report):
    out, fig_a, fig_b = report
    # The sizes the figures were made with, read independently from the original files.
    sizes = [matplotlib.image.imread(f).shape[:2] for f in (fig_a, fig_b)]
    assert sizes == [(200, 300), (80, 120)]

    result = check_html_report(out)
    assert [(f["alt"], f["format"], f["width"], f["height"]) for f in result["figures"]] == [
        ("first figure", "png", 300, 200), ("second figure", "png", 120, 80)]
    assert result["tables"] == [{"caption_or_heading": "Results", "columns": 4, "rows": 3}]
    assert result["headings"] == ["Test report", "Results", "Figures"]


def test_report_reads_as_the_markdown_says(report):
    out, _, _ = report
    text = out.read_text(encoding="utf-8")
    assert text.lower().startswith("<!doctype html>")
    assert '<meta charset="utf-8">' in text and "<title>Test report</title>" in text
    # Unicode passes through as characters, not entities.
    for char in "µ±≤°×ε⁻":
        assert char in text
    reader = _read(out)

    (table,) = reader.tables
    assert [[c["text"] for c in row] for row in table] == CELLS
    assert [c["tag"] for c in table[0]] == ["th"] * 4
    # Exactly "pass"/"fail" cells are marked; "passed" and the other cells are not.
    assert [[c["class"] for c in row] for row in table[1:]] == [
        [None, None, None, "pass"], [None, None, None, "fail"], [None, None, None, None]]

    assert reader.items == [("level one", 1), ("level two italic here", 2), ("level three", 3),
                            ("back to one", 1), ("first", 1), ("second", 1)]
    assert reader.code_blocks == ["x_y = 1 * 2 * 3  # <not a tag>"]
    assert reader.strong == ["bold"] and reader.em == ["italic"]
    assert "snake_case_name, a_b_c," in text

    # The contents link every h2, and every anchor points at an id that exists.
    assert "#results" in reader.hrefs and "#figures" in reader.hrefs
    for href in reader.hrefs:
        assert not href.startswith("#") or href[1:] in reader.ids

    # Nothing is loaded from outside: no <link>/<script>, every image a PNG data URI, no file name left.
    assert not [t for t, _ in reader.tags if t in ("link", "script", "iframe", "object")]
    assert len(reader.images) == 2
    for attrs in reader.images:
        assert attrs["src"].startswith("data:image/png;base64,")
    assert "fig_a.png" not in text and "fig_b.png" not in text
    # "http" only in the one navigation link of the Markdown.
    assert text.count("http") == 1 and reader.hrefs.count("https://example.org/page") == 1


def test_embedded_pixels_equal_the_original(report):
    out, fig_a, fig_b = report
    reader = _read(out)
    for attrs, original in zip(reader.images, (fig_a, fig_b)):
        data = base64.b64decode(attrs["src"].split(",", 1)[1])
        assert data == original.read_bytes()
        embedded = matplotlib.image.imread(io.BytesIO(data), format="png")
        assert np.array_equal(embedded, matplotlib.image.imread(original))


def test_jpeg_and_svg_figures(tmp_path):
    fig = Figure(figsize=(1.2, 0.8), dpi=100)
    fig.add_axes([0, 0, 1, 1]).plot([0, 1], [1, 0])
    fig.savefig(tmp_path / "plot.jpg", dpi=100)
    (tmp_path / "box.svg").write_text('<svg xmlns="http://www.w3.org/2000/svg" width="40" height="30">'
                                      '<rect width="40" height="30" fill="red"/></svg>', encoding="utf-8")
    out = write_html_report(tmp_path / "r.html", "T", "![jpeg](plot.jpg)\n\n![vector](box.svg)\n", tmp_path)
    reader = _read(out)
    assert [a["src"].split(";")[0] for a in reader.images] == ["data:image/jpeg", "data:image/svg+xml"]
    jpeg_shape = matplotlib.image.imread(tmp_path / "plot.jpg").shape[:2]
    result = check_html_report(out)
    assert [(f["format"], f["width"], f["height"]) for f in result["figures"]] == [
        ("jpeg", jpeg_shape[1], jpeg_shape[0]), ("svg", 40, 30)]
    assert jpeg_shape == (80, 120)


def test_missing_image_names_file_and_line(tmp_path):
    text = "# T\n\nsee below\n![gone](plots/missing.png)\n"
    with pytest.raises(FileNotFoundError, match=r"line 4.*plots/missing\.png"):
        markdown_to_html(text, tmp_path)
    with pytest.raises(FileNotFoundError, match=r"missing\.png"):
        write_html_report(tmp_path / "r.html", "T", text, tmp_path)
    assert not (tmp_path / "r.html").exists()


def test_external_image_in_markdown_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"line 1.*not a local file"):
        markdown_to_html("![web](https://example.org/a.png)", tmp_path)


def test_ragged_table_row_is_refused(report):
    out, _, _ = report
    text = out.read_text(encoding="utf-8")
    # Drop one cell of the second body row.
    edited = re.sub(r"<td[^>]*>µm/m</td>", "", text, count=1)
    assert edited != text
    out.write_text(edited, encoding="utf-8")
    with pytest.raises(ValueError, match=r"table 0 \(under 'Results'\).*row 1 has 3 cells.*header 4"):
        check_html_report(out)


def test_table_without_body_rows_is_refused(tmp_path):
    out = write_html_report(tmp_path / "r.html", "T", "## Empty\n\n| a | b |\n|---|---|\n", tmp_path)
    with pytest.raises(ValueError, match=r"table 0 \(under 'Empty'\): no body rows"):
        check_html_report(out)


def test_too_many_cells_in_markdown_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"line 3: table row has 3 cells, its header 2"):
        markdown_to_html("| a | b |\n|---|---|\n| 1 | 2 | 3 |\n", tmp_path)


def _edit_src(path, index, new_src):
    text = path.read_text(encoding="utf-8")
    srcs = re.findall(r'src="([^"]*)"', text)
    path.write_text(text.replace(srcs[index], new_src, 1), encoding="utf-8")


def test_corrupted_base64_is_refused(report):
    out, _, _ = report
    _edit_src(out, 0, "data:image/png;base64,iVBORw0K!!!!")
    with pytest.raises(ValueError, match=r"figure 0 \('first figure'\): base64 data do not decode"):
        check_html_report(out)


def test_truncated_png_is_refused(report):
    out, fig_a, _ = report
    truncated = base64.b64encode(fig_a.read_bytes()[:100]).decode()
    _edit_src(out, 0, "data:image/png;base64," + truncated)
    with pytest.raises(ValueError, match=r"figure 0 \('first figure'\): embedded PNG cannot be read"):
        check_html_report(out)


def test_empty_image_is_refused(report):
    out, _, _ = report
    _edit_src(out, 1, "data:image/png;base64,")
    with pytest.raises(ValueError, match=r"figure 1 \('second figure'\): embedded image is empty"):
        check_html_report(out)


def test_external_src_is_refused(report):
    out, _, _ = report
    _edit_src(out, 1, "https://example.org/fig_b.png")
    with pytest.raises(ValueError, match=r"figure 1 \('second figure'\): src is not a base64 data URI"):
        check_html_report(out)


def test_emphasis_only_at_word_boundaries(tmp_path):
    fragment = markdown_to_html(
        "snake_case_name and a_b_c, 2*3*4, **bold** text, _it one_ and *it two*, x * y * z", tmp_path)
    out = tmp_path / "f.html"
    out.write_text(fragment, encoding="utf-8")
    reader = _read(out)
    assert reader.strong == ["bold"]
    assert reader.em == ["it one", "it two"]
    assert "snake_case_name and a_b_c, 2*3*4," in fragment and "x * y * z" in fragment


def test_escaping_and_unique_anchors(tmp_path):
    fragment = markdown_to_html("## A & <b>\n\n## A & <b>\n\n<script>alert(1)</script> ±1 µm\n", tmp_path)
    out = tmp_path / "f.html"
    out.write_text(fragment, encoding="utf-8")
    reader = _read(out)
    assert [t for t, _ in reader.tags] == ["h2", "h2", "p"]  # no <b>, no <script>: all text
    assert len(set(reader.ids)) == 2
    assert "&lt;script&gt;alert(1)&lt;/script&gt; ±1 µm" in fragment


def test_toc_can_be_left_out(tmp_path):
    text = "# T\n\n## One\n\n## Two\n"
    with_toc = _read(write_html_report(tmp_path / "a.html", "T", text, tmp_path))
    without = _read(write_html_report(tmp_path / "b.html", "T", text, tmp_path, toc=False))
    assert [h for h in with_toc.hrefs] == ["#one", "#two"]
    assert without.hrefs == [] and not [t for t, _ in without.tags if t == "nav"]
