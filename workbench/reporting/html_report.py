"""Self-contained HTML versions of the project's Markdown reports.

A report written here opens from disk, mailed or copied alone: its figures are embedded as base64 data URIs,
its style sheet is inline, and nothing (CDN, external CSS, JS, image file) is referenced. Only the Markdown subset
the reports use is understood:

* ATX headings ``#`` .. ``####``, each with a unique ``id`` slug;
* paragraphs (consecutive non-blank lines), horizontal rules (``---``);
* pipe tables (header line, ``|---|:--:|`` separator line, body rows; ``\\|`` is a literal ``|`` in a cell);
* bullet (``-`` / ``*``) and numbered (``1.``) lists, nested by indenting 2 or more spaces;
* fenced code blocks (```` ``` ````);
* inline ``**bold**``, ``*italic*`` / ``_italic_`` (only at word boundaries, so ``snake_case`` survives),
  ```code```, ``[text](url)`` and ``![alt](file.png)`` (PNG, JPEG or SVG, read from ``base_dir``).

:func:`check_html_report` reads a written file back the way a reader (browser) sees it and verifies that every
figure decodes and every table is rectangular.
"""
from __future__ import annotations

import base64
import binascii
import html
import io
import re
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path

from labio.atomic import atomic_write_text

__all__ = ["markdown_to_html", "write_html_report", "check_html_report"]

_MIME = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".svg": "image/svg+xml"}
_FORMAT = {"image/png": "png", "image/jpeg": "jpeg", "image/svg+xml": "svg"}

_HEADING = re.compile(r"^(#{1,4})\s+(.*?)(?:\s+#+)?\s*$")
_FENCE = re.compile(r"^\s*```")
_RULE = re.compile(r"^\s{0,3}([-*_])(?:\s*\1){2,}\s*$")
_ITEM = re.compile(r"^(\s*)(?:([-*])|(\d+)[.)])\s+(.*)$")
_SEPARATOR = re.compile(r"^\s*\|?\s*:?-+:?\s*(?:\|\s*:?-+:?\s*)*\|?\s*$")
_CELL_SPLIT = re.compile(r"(?<!\\)\|")

# Placeholders keep finished HTML (code spans, images, links) out of reach of the emphasis rules; NUL never
# occurs in a report, and is stripped from the input to be sure.
_TOKEN = "\x00{}\x00"
_TOKEN_RE = re.compile("\x00(\\d+)\x00")
_CODE_SPAN = re.compile(r"(`+)(.+?)\1")
_BACKSLASH = re.compile(r"\\([\\`*_{}\[\]()#+\-.!|])")
_IMAGE = re.compile(r"!\[([^\]]*)\]\(\s*([^)\s]+)(?:\s+&quot;[^)]*&quot;)?\s*\)")
_LINK = re.compile(r"\[([^\]]+)\]\(\s*([^)\s]+)(?:\s+&quot;[^)]*&quot;)?\s*\)")
# Emphasis only where the marker is not inside a word: ``snake_case_name`` and ``a*b*c`` stay as they are.
_BOLD = re.compile(r"(?<![\w*])\*\*(?=\S)(.+?)(?<=\S)\*\*(?![\w*])|(?<![\w_])__(?=\S)(.+?)(?<=\S)__(?![\w_])")
_ITALIC = re.compile(r"(?<![\w*])\*(?=[^\s*])(.+?)(?<=[^\s*])\*(?![\w*])|(?<![\w_])_(?=[^\s_])(.+?)(?<=[^\s_])_(?![\w_])")

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; line-height: 1.5;
       max-width: 60rem; margin: 2rem auto; padding: 0 1rem; color: #222; }
h1, h2, h3, h4 { line-height: 1.25; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.92em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; vertical-align: top; }
th { background: #e8e8e8; }
tbody tr:nth-child(even) { background: #f5f5f5; }
td.pass { color: #0a6b0a; background: #dff3df; font-weight: 600; }
td.fail { color: #a10d0d; background: #f8dddd; font-weight: 600; }
img { max-width: 100%; height: auto; }
pre { background: #f4f4f4; padding: 0.6em 0.8em; overflow-x: auto; }
code { font-family: ui-monospace, Menlo, Consolas, monospace; font-size: 0.92em; }
nav.toc { border: 1px solid #ddd; padding: 0.4em 1em; margin: 1em 0; }
nav.toc p { margin: 0.3em 0; font-weight: 600; }
""".strip()


# --------------------------------------------------------------------------------------------------------------
# Inline markup
# --------------------------------------------------------------------------------------------------------------

def _embed_image(alt: str, target: str, base_dir: Path, line_no: int) -> str:
    """``<img>`` with the file at ``base_dir / target`` as a base64 data URI (``alt`` is already escaped)."""
    target = html.unescape(target)
    if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith("//"):
        # An external (or already data:) src would break "opens from disk alone".
        raise ValueError(f"line {line_no}: image {target!r} is not a local file and cannot be embedded")
    path = Path(base_dir) / target
    mime = _MIME.get(path.suffix.lower())
    if mime is None:
        raise ValueError(f"line {line_no}: image {target!r}: unsupported format {path.suffix!r} "
                         f"(expected one of {', '.join(sorted(_MIME))})")
    if not path.is_file():
        raise FileNotFoundError(f"line {line_no}: image file {target!r} not found (looked for {path})")
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img alt="{alt}" src="data:{mime};base64,{data}">'


def _inline(lines: list[tuple[int, str]], base_dir: Path) -> str:
    """Inline markup of one block given as ``(line number, raw text)`` pairs; lines are joined by newlines."""
    tokens: list[str] = []

    def keep(fragment: str) -> str:
        tokens.append(fragment)
        return _TOKEN.format(len(tokens) - 1)

    out = []
    for line_no, raw in lines:
        # Escape first, so that nothing in the report's text can become markup.
        text = html.escape(raw.replace("\x00", ""), quote=True)
        text = _CODE_SPAN.sub(lambda m: keep(f"<code>{m.group(2).strip()}</code>"), text)
        text = _BACKSLASH.sub(lambda m: keep(m.group(1)), text)
        text = _IMAGE.sub(lambda m: keep(_embed_image(m.group(1), m.group(2), base_dir, line_no)), text)
        text = _LINK.sub(lambda m: keep(f'<a href="{m.group(2)}">{_emphasis(m.group(1))}</a>'), text)
        out.append(text)
    text = _emphasis("\n".join(out))
    # Tokens may hold tokens (a link's text with code in it): substitute until none is left.
    while _TOKEN_RE.search(text):
        text = _TOKEN_RE.sub(lambda m: tokens[int(m.group(1))], text)
    return text


def _emphasis(text: str) -> str:
    """``**bold**`` / ``__bold__`` then ``*italic*`` / ``_italic_``, at word boundaries only."""
    text = _BOLD.sub(lambda m: f"<strong>{m.group(1) or m.group(2)}</strong>", text)
    return _ITALIC.sub(lambda m: f"<em>{m.group(1) or m.group(2)}</em>", text)


def _plain(fragment: str) -> str:
    """The text a reader sees in an HTML fragment (tags dropped, entities decoded)."""
    return html.unescape(re.sub(r"<[^>]*>", "", fragment))


def _slug(text: str, used: set[str]) -> str:
    """A unique anchor id from a heading's text: lower case, words joined by ``-``."""
    base = re.sub(r"[^\w\s-]", "", text.lower()).strip()
    base = re.sub(r"[\s-]+", "-", base) or "section"
    slug, n = base, 1
    while slug in used:
        n += 1
        slug = f"{base}-{n}"
    used.add(slug)
    return slug


# --------------------------------------------------------------------------------------------------------------
# Blocks
# --------------------------------------------------------------------------------------------------------------

def _split_row(line: str) -> list[str]:
    """Cells of a pipe-table line; ``\\|`` is a literal ``|`` inside a cell."""
    line = line.strip()
    if line.startswith("|"):
        line = line[1:]
    if line.endswith("|") and not line.endswith("\\|"):
        line = line[:-1]
    return [cell.strip().replace("\\|", "|") for cell in _CELL_SPLIT.split(line)]


def _is_table_start(lines: list[str], i: int) -> bool:
    return (lines[i].lstrip().startswith("|") and i + 1 < len(lines)
            and "-" in lines[i + 1] and bool(_SEPARATOR.match(lines[i + 1])))


def _starts_block(lines: list[str], i: int) -> bool:
    """Whether line ``i`` begins something other than paragraph text (which ends a paragraph)."""
    line = lines[i]
    return bool(_HEADING.match(line) or _FENCE.match(line) or _RULE.match(line) or _ITEM.match(line)
                or _is_table_start(lines, i))


def _table(lines: list[str], i: int, base_dir: Path) -> tuple[str, int]:
    """The pipe table starting at line index ``i``; returns its HTML and the index after it."""
    header = _split_row(lines[i])
    spec = _split_row(lines[i + 1])
    if len(spec) != len(header):
        raise ValueError(f"line {i + 2}: table separator has {len(spec)} columns, its header {len(header)}")
    align = []
    for s in spec:
        left, right = s.startswith(":"), s.endswith(":")
        align.append("center" if left and right else "right" if right else "left" if left else None)

    def cell(tag: str, text: str, col: int, line_no: int) -> str:
        attrs = f' style="text-align:{align[col]}"' if align[col] else ""
        if tag == "td" and text in ("pass", "fail"):
            attrs += f' class="{text}"'
        return f"<{tag}{attrs}>{_inline([(line_no, text)], base_dir)}</{tag}>"

    out = ["<table>", "<thead>", "<tr>" + "".join(cell("th", h, c, i + 1) for c, h in enumerate(header)) + "</tr>",
           "</thead>", "<tbody>"]
    j = i + 2
    while j < len(lines) and lines[j].lstrip().startswith("|"):
        row = _split_row(lines[j])
        if len(row) > len(header):
            # Markdown would drop the extra cells; a report losing data silently is worse than an error.
            raise ValueError(f"line {j + 1}: table row has {len(row)} cells, its header {len(header)}")
        row += [""] * (len(header) - len(row))  # short rows are padded, as in GitHub Markdown
        out.append("<tr>" + "".join(cell("td", t, c, j + 1) for c, t in enumerate(row)) + "</tr>")
        j += 1
    out += ["</tbody>", "</table>"]
    return "\n".join(out), j


def _list(lines: list[str], i: int, base_dir: Path) -> tuple[str, int]:
    """The (possibly nested) list starting at line index ``i``; returns its HTML and the index after it."""
    items: list[tuple[int, str, str | None, list[tuple[int, str]]]] = []  # indent, tag, start, lines
    j = i
    while j < len(lines):
        m = _ITEM.match(lines[j])
        if m:
            tag = "ul" if m.group(2) else "ol"
            items.append((len(m.group(1).expandtabs(4)), tag, m.group(3), [(j + 1, m.group(4))]))
        elif lines[j].strip() and not _starts_block(lines, j):
            items[-1][3].append((j + 1, lines[j].strip()))  # lazy continuation of the last item
        elif not lines[j].strip() and j + 1 < len(lines) and _ITEM.match(lines[j + 1]):
            pass  # a blank line between items keeps the list going
        else:
            break
        j += 1

    out: list[str] = []
    stack: list[tuple[int, str]] = []  # (indent, tag) of the open lists, outermost first

    def open_list(indent: int, tag: str, start: str | None) -> None:
        out.append(f'<ol start="{int(start)}">' if tag == "ol" and start and int(start) != 1 else f"<{tag}>")
        stack.append((indent, tag))

    for indent, tag, start, text in items:
        if not stack:
            open_list(indent, tag, start)
        elif indent >= stack[-1][0] + 2:
            open_list(indent, tag, start)  # nested inside the still-open <li>
        else:
            while len(stack) > 1 and indent < stack[-1][0]:
                out.append(f"</li></{stack.pop()[1]}>")
            out.append("</li>")
            if tag != stack[-1][1]:
                out.append(f"</{stack.pop()[1]}>")
                open_list(indent, tag, start)
        out.append("<li>" + _inline(text, base_dir))
    while stack:
        out.append(f"</li></{stack.pop()[1]}>")
    return "\n".join(out), j


def _convert(text: str, base_dir: Path) -> tuple[str, list[tuple[int, str, str]]]:
    """HTML fragment and the headings as ``(level, inner HTML, id)``."""
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    out: list[str] = []
    headings: list[tuple[int, str, str]] = []
    used: set[str] = set()
    i = 0
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            i += 1
        elif _FENCE.match(line):
            lang = line.strip()[3:].strip()
            j = i + 1
            while j < len(lines) and not _FENCE.match(lines[j]):
                j += 1
            if j == len(lines):
                raise ValueError(f"line {i + 1}: code block is not closed")
            cls = f' class="language-{html.escape(lang)}"' if lang else ""
            out.append(f"<pre><code{cls}>" + html.escape("\n".join(lines[i + 1:j])) + "</code></pre>")
            i = j + 1
        elif m := _HEADING.match(line):
            level, inner = len(m.group(1)), _inline([(i + 1, m.group(2))], base_dir)
            slug = _slug(_plain(inner), used)
            headings.append((level, inner, slug))
            out.append(f'<h{level} id="{slug}">{inner}</h{level}>')
            i += 1
        elif _RULE.match(line):
            out.append("<hr>")
            i += 1
        elif _is_table_start(lines, i):
            fragment, i = _table(lines, i, base_dir)
            out.append(fragment)
        elif _ITEM.match(line):
            fragment, i = _list(lines, i, base_dir)
            out.append(fragment)
        else:
            block = [(i + 1, line.strip())]
            i += 1
            while i < len(lines) and lines[i].strip() and not _starts_block(lines, i):
                block.append((i + 1, lines[i].strip()))
                i += 1
            out.append(f"<p>{_inline(block, base_dir)}</p>")
    return "\n".join(out) + "\n", headings


def markdown_to_html(text: str, base_dir: Path) -> str:
    """Convert a report's Markdown to an HTML fragment, embedding its images.

    Parameters
    ----------
    text : str
        Markdown (the subset described in the module docstring).
    base_dir : Path
        Folder that relative image paths are read from (normally the Markdown file's folder).

    Returns
    -------
    str
        The HTML fragment; every text is HTML-escaped, Unicode is kept as it is.

    Raises
    ------
    FileNotFoundError
        Naming the file and the Markdown line of an image that does not exist.
    ValueError
        Naming the line of an image that is not a local PNG/JPEG/SVG file, of a table row with more cells than
        its header, or of a code block that is not closed.
    """
    return _convert(text, Path(base_dir))[0]


def write_html_report(path: Path, title: str, markdown_text: str, base_dir: Path, *, toc: bool = True) -> Path:
    """Write a complete, self-contained HTML document for a Markdown report (atomically).

    Parameters
    ----------
    path : Path
        The HTML file to write; its folder is created if missing.
    title : str
        The document's ``<title>``; also shown as ``<h1>`` when the Markdown does not begin with a level-1
        heading.
    markdown_text : str
        The report's Markdown.
    base_dir : Path
        Folder that relative image paths are read from.
    toc : bool
        Add a table of contents linking the level-2 headings (when there are any).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    FileNotFoundError, ValueError
        As :func:`markdown_to_html`; nothing is written then.
    """
    body, headings = _convert(markdown_text, Path(base_dir))
    parts = ["<!doctype html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             f"<title>{html.escape(title)}</title>", f"<style>\n{_CSS}\n</style>", "</head>", "<body>"]
    # The contents go under the report's title: the Markdown's leading <h1>, else one made from ``title``.
    if body.startswith("<h1"):
        head, body = body.split("</h1>\n", 1)
        parts.append(head + "</h1>")
    else:
        parts.append(f"<h1>{html.escape(title)}</h1>")
    sections = [(inner, slug) for level, inner, slug in headings if level == 2]
    if toc and sections:
        # A <p> rather than a heading, so the contents box is not itself a section of the report.
        links = "\n".join(f'<li><a href="#{slug}">{inner}</a></li>' for inner, slug in sections)
        parts.append(f'<nav class="toc">\n<p>Contents</p>\n<ul>\n{links}\n</ul>\n</nav>')
    parts += [body.rstrip("\n"), "</body>", "</html>", ""]
    atomic_write_text(path, "\n".join(parts))
    return Path(path)


# --------------------------------------------------------------------------------------------------------------
# Reading a report back
# --------------------------------------------------------------------------------------------------------------

class _ReportReader(HTMLParser):
    """Collects headings, images and table shapes as a browser would lay them out (entities decoded)."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.headings: list[str] = []
        self.images: list[dict] = []
        self.tables: list[dict] = []
        self._heading: list[str] | None = None
        self._caption: list[str] | None = None
        self._table: dict | None = None
        self._section = "tbody"
        self._row: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag in ("h1", "h2", "h3", "h4", "h5", "h6"):
            self._heading = []
        elif tag == "img":
            self.images.append({"alt": attrs.get("alt") or "", "src": attrs.get("src") or ""})
        elif tag == "table":
            heading = self.headings[-1] if self.headings else None
            self._table = {"heading": heading, "caption": None, "header": None, "rows": []}
        elif self._table is None:
            return
        elif tag == "caption":
            self._caption = []
        elif tag in ("thead", "tbody", "tfoot"):
            self._section = tag
        elif tag == "tr":
            self._row = []
        elif tag in ("td", "th") and self._row is not None:
            self._row.append("")

    def handle_endtag(self, tag):
        if tag in ("h1", "h2", "h3", "h4", "h5", "h6") and self._heading is not None:
            self.headings.append(" ".join("".join(self._heading).split()))
            self._heading = None
        elif self._table is None:
            return
        elif tag == "caption" and self._caption is not None:
            self._table["caption"] = " ".join("".join(self._caption).split())
            self._caption = None
        elif tag == "tr" and self._row is not None:
            # The header is the thead row, or else the first row when the table has no thead.
            if self._section == "thead":
                self._table["header"] = self._row
            else:
                self._table["rows"].append(self._row)
            self._row = None
        elif tag == "table":
            if self._table["header"] is None and self._table["rows"]:
                self._table["header"] = self._table["rows"].pop(0)
            self.tables.append(self._table)
            self._table, self._section = None, "tbody"

    def handle_data(self, data):
        if self._heading is not None:
            self._heading.append(data)
        if self._caption is not None:
            self._caption.append(data)
        if self._row:
            self._row[-1] += data


def _figure(index: int, alt: str, src: str) -> dict:
    """Decode and open one embedded figure; ``ValueError`` names it when it cannot be read."""
    name = f"figure {index} ({alt!r})"
    m = re.match(r"^data:([\w.+/-]+)((?:;[\w.+-]+=[^;,]*)*);base64,(.*)$", src.strip(), re.S)
    if not m:
        raise ValueError(f"{name}: src is not a base64 data URI ({src[:60]!r})")
    mime, payload = m.group(1).lower(), re.sub(r"\s+", "", m.group(3))
    fmt = _FORMAT.get(mime)
    if fmt is None:
        raise ValueError(f"{name}: unsupported image type {mime!r}")
    try:
        data = base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError) as err:
        raise ValueError(f"{name}: base64 data do not decode ({err})") from None
    if not data:
        raise ValueError(f"{name}: embedded image is empty")
    try:
        if fmt == "svg":
            width, height = _svg_size(ET.fromstring(data))
        else:
            # The signature first: a truncated or mislabelled file must not pass as the declared type.
            magic = b"\x89PNG\r\n\x1a\n" if fmt == "png" else b"\xff\xd8\xff"
            if not data.startswith(magic):
                raise ValueError(f"data are not a {fmt.upper()} file")
            import matplotlib.image

            pixels = matplotlib.image.imread(io.BytesIO(data), format=fmt)
            height, width = int(pixels.shape[0]), int(pixels.shape[1])
    except Exception as err:  # noqa: BLE001 - whatever the decoder raises, the figure is unreadable
        raise ValueError(f"{name}: embedded {fmt.upper()} cannot be read ({type(err).__name__}: {err})") from None
    return {"alt": alt, "format": fmt, "width": width, "height": height}


def _svg_size(root: ET.Element) -> tuple[float | None, float | None]:
    """An SVG's width and height (``px`` or unitless attributes, else its viewBox); None where unknown."""
    if not root.tag.endswith("svg"):
        raise ValueError(f"root element is <{root.tag}>, not <svg>")

    def number(value: str | None) -> float | None:
        m = re.fullmatch(r"\s*([0-9.]+)\s*(px|pt)?\s*", value or "")
        return None if not m else float(m.group(1)) * (4 / 3 if m.group(2) == "pt" else 1)

    width, height = number(root.get("width")), number(root.get("height"))
    box = (root.get("viewBox") or "").replace(",", " ").split()
    if (width is None or height is None) and len(box) == 4:
        width = float(box[2]) if width is None else width
        height = float(box[3]) if height is None else height
    return width, height


def check_html_report(path: Path) -> dict:
    """Read a written report back and verify its figures and tables.

    Parameters
    ----------
    path : Path
        An HTML file (as written by :func:`write_html_report`).

    Returns
    -------
    dict
        ``figures``: ``{"alt", "format" ("png", "jpeg" or "svg"), "width", "height"}`` per ``<img>`` (pixels,
        decoded from the embedded data); ``tables``: ``{"caption_or_heading", "columns", "rows"}`` per table
        (its caption, else the text of the nearest preceding heading; header columns; body rows);
        ``headings``: the text of every heading, in order.

    Raises
    ------
    ValueError
        Naming the figure (index and alt text) whose src is not a base64 data URI, does not decode, is empty or
        is not a readable image; naming the table (index and heading) that has no header, no body rows, or a row
        whose number of cells differs from the header's.
    """
    reader = _ReportReader()
    reader.feed(Path(path).read_text(encoding="utf-8"))
    reader.close()
    figures = [_figure(k, img["alt"], img["src"]) for k, img in enumerate(reader.images)]
    tables = []
    for k, table in enumerate(reader.tables):
        label = table["caption"] or table["heading"]
        name = f"table {k} (under {label!r})"
        if not table["header"]:
            raise ValueError(f"{name}: no header row")
        if not table["rows"]:
            raise ValueError(f"{name}: no body rows")
        for r, row in enumerate(table["rows"]):
            if len(row) != len(table["header"]):
                raise ValueError(f"{name}: body row {r} has {len(row)} cells, the header {len(table['header'])}")
        tables.append({"caption_or_heading": label, "columns": len(table["header"]), "rows": len(table["rows"])})
    return {"figures": figures, "tables": tables, "headings": reader.headings}


def main(argv: list[str] | None = None) -> int:
    """``python -m workbench.reporting.html_report REPORT.html ...``: check reports as a reader sees them (exit 1 if not)."""
    import sys

    paths = sys.argv[1:] if argv is None else argv
    if not paths:
        print("usage: python -m workbench.reporting.html_report REPORT.html ...", file=sys.stderr)
        return 2
    status = 0
    for p in paths:
        try:
            found = check_html_report(Path(p))
        except (OSError, ValueError) as exc:
            print(f"{p}: {exc}", file=sys.stderr)
            status = 1
            continue
        print(f"{p}: {len(found['figures'])} figures decode, {len(found['tables'])} tables with "
              f"{sum(t['rows'] for t in found['tables'])} rows, {len(found['headings'])} headings")
    return status


if __name__ == "__main__":
    raise SystemExit(main())
