"""The one way a report's figure becomes a PNG: :func:`png_bytes` renders a matplotlib figure and records in the PNG
(a ``tEXt`` chunk, ``workbench:axes``) what each of its axes shows: its title, x and y labels, whether it has tick
labels, and each colour bar's label. :mod:`workbench.reporting.browser_check` reads that record back from the page a
reader sees and fails a figure with a plotted axis left unlabelled.
"""
from __future__ import annotations

import io
import json

KEY = "workbench:axes"


#: Unit suffixes of the project's names (``noise_grey``, ``bias_px``) and how a label writes them.
UNITS = {"px": "px", "grey": "grey", "mm": "mm", "um": "µm", "deg": "°", "percent": "%", "s": "s", "ue": "µε",
         "microstrain": "µε", "n": "N", "mpa": "MPa", "nm": "nm"}


def quantity_label(name: str) -> str:
    """An axis label from a parameter or metric name: ``"noise_grey"`` -> ``"noise (grey)"``,
    ``"scenario.render.read_noise_grey"`` -> ``"render read noise (grey)"``, ``"bias_px"`` -> ``"bias (px)"``."""
    parts = str(name).split(".")
    if parts[0] in ("scenario", "instrument", "design") and len(parts) > 1:
        parts = parts[1:]
    words = " ".join(parts).split("_")
    unit = UNITS.get(words[-1].lower()) if len(words) > 1 else None
    text = " ".join(words[:-1] if unit else words).strip()
    return f"{text} ({unit})" if unit else text


def axes_record(fig) -> list[dict]:
    """What each visible axes of ``fig`` shows (after a draw, so tick labels are known)."""
    out = []
    for index, ax in enumerate(fig.axes):
        if not ax.get_visible() or not ax.axison:
            continue
        if ax.get_label() == "<colorbar>":
            out.append({"index": index, "kind": "colorbar",
                        "label": (ax.get_ylabel() or ax.get_xlabel()).strip()})
            continue
        has = lambda axis: axis.get_visible() and any(t.get_visible() and t.get_text().strip()  # noqa: E731
                                                      for t in axis.get_ticklabels())
        out.append({"index": index, "kind": "axes", "title": ax.get_title().strip(),
                    "xlabel": ax.get_xlabel().strip(), "ylabel": ax.get_ylabel().strip(),
                    "xticks": bool(has(ax.xaxis)), "yticks": bool(has(ax.yaxis))})
    return out


def png_bytes(fig, *, dpi: float = 110, close: bool = True, **savefig_kwargs) -> bytes:
    """``fig`` as PNG bytes carrying its :func:`axes_record`; closes the figure unless ``close=False``."""
    import matplotlib.pyplot as plt

    fig.canvas.draw()
    record = axes_record(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, metadata={KEY: json.dumps(record)}, **savefig_kwargs)
    if close:
        plt.close(fig)
    return buffer.getvalue()


def read_axes_record(png: bytes) -> list[dict] | None:
    """The :func:`axes_record` a PNG carries, or None (a PNG not written by :func:`png_bytes`)."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(png)) as image:
            text = getattr(image, "text", {}) or {}
    except OSError:
        return None
    return json.loads(text[KEY]) if KEY in text else None


def picture_png(image) -> bytes:
    """A picture (an image array shown as it is, no plotted axes: a rendered view, a speckle image) as PNG bytes
    whose record says it has no axes, so the browser check does not ask for labels it cannot have."""
    import numpy as np
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    info.add_text(KEY, "[]")
    buffer = io.BytesIO()
    Image.fromarray(np.asarray(image)).save(buffer, format="PNG", pnginfo=info)
    return buffer.getvalue()
