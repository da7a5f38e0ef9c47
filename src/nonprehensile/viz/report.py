"""A self-contained HTML report: sections of text, tables and figures with images embedded.

The report is one file (``index.html``) that opens anywhere, with no network and no other
file: every figure is a PNG embedded as a ``data:`` URI. A small script marks the page once
every image has loaded (``<body data-images-loaded="N/M">``), so a headless browser can check
that the page renders completely.
"""

from __future__ import annotations

import base64
import html
import math
import struct
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np
    from matplotlib.figure import Figure
    from matplotlib.text import Text
    from numpy.typing import NDArray

__all__ = ["MIN_TEXT_PX", "PAGE_WIDTH_PX", "Cell", "HtmlFigure", "Section", "figure_pixels",
           "figure_to_png", "png_bytes", "readable", "render_report", "write_report"]

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 2em auto;
       max-width: 1200px; color: #222; line-height: 1.45; padding: 0 1em; }
h1 { border-bottom: 2px solid #444; padding-bottom: .2em; }
h2 { margin-top: 2em; border-bottom: 1px solid #bbb; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: .9em; color: #555; }
table { border-collapse: collapse; margin: .8em 0; font-size: .9em; }
th, td { border: 1px solid #ccc; padding: .25em .6em; text-align: left; vertical-align: top; }
th { background: #f0f0f0; }
code { background: #f4f4f4; padding: 0 .2em; }
.note { color: #555; font-size: .9em; }
td[title], th[title] { text-decoration: underline dotted #888; cursor: help; }
table.meta { font-size: .85em; } table.meta th { font-weight: normal; color: #555; }
table.matrix { font-size: .75em; margin: 0; }
table.matrix th, table.matrix td { padding: 0 .2em; border: 1px solid #e4e4e4; }
table.matrix th { background: none; font-weight: normal; white-space: nowrap; }
table.matrix thead th { vertical-align: bottom; }
table.matrix thead th span { writing-mode: vertical-rl; transform: rotate(180deg); }
table.matrix td { width: 1.1em; min-width: 1.1em; height: 1.1em; padding: 0; }
table.matrix td.shown, p.legend i.shown { outline: 2px solid #000; outline-offset: -2px; }
p.legend { font-size: .85em; } p.legend span { margin-right: 1.2em; white-space: nowrap; }
p.legend i { display: inline-block; width: 1em; height: 1em; margin-right: .35em;
             vertical-align: -.15em; }
"""

_SCRIPT = """
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.setAttribute("data-images-loaded", ok + "/" + imgs.length);
});
"""


@dataclass(frozen=True)
class HtmlFigure:
    """A figure the page lays out itself (a table of coloured cells, say), not an image.

    ``markup`` goes into the page as it is: it must come from this package's own functions,
    every text in it escaped (:func:`html.escape`). Text-heavy figures cost matplotlib half a
    millisecond a text and a millisecond a tick; as HTML they cost the report nearly nothing
    (issue 16).
    """

    markup: str


@dataclass(frozen=True)
class Cell:
    """A table cell with a tooltip: ``text`` shown, ``title`` when the pointer rests on it
    (both plain text, escaped when rendered). Cells with a tooltip are underlined dotted."""

    text: str
    title: str


@dataclass
class Section:
    """One section of the report.

    Attributes
    ----------
    title : str
    paragraphs : list of str
        Plain text (escaped when rendered).
    figures : list of (bytes or HtmlFigure, str)
        PNG data (or a figure in HTML) and a caption.
    tables : list of (list of str or Cell, list of list of str or Cell)
        Header and rows, plain text (a :class:`Cell` adds a tooltip).
    notes : list of str
        Plain text shown small under the tables (what a column means, say).
    """

    title: str
    paragraphs: list[str] = field(default_factory=list)
    figures: list[tuple[bytes | HtmlFigure, str]] = field(default_factory=list)
    tables: list[tuple[Sequence[str | Cell], Sequence[Sequence[str | Cell]]]] = field(
        default_factory=list)
    notes: list[str] = field(default_factory=list)


#: Width of the page's content, px: a wider image is shown scaled down to it.
PAGE_WIDTH_PX = 1150
#: Smallest text in a figure as shown at 100 % zoom, px.
MIN_TEXT_PX = 10.5
#: zlib level of the report's PNG images: 1, the fastest (figures are flat colours, which
#: compress about as well at 1 as at matplotlib's 6).
PNG_COMPRESS_LEVEL = 1
#: FreeType hinting of the figures' text while the report draws them: none (matplotlib
#: renders every glyph anew at each draw, and unhinted glyphs take 40 % less time).
TEXT_HINTING = "no_hinting"


def _axes_drawn(ax: Any) -> bool:
    """Whether ``ax`` draws its axes' ticks and labels (2-D ``axison``; a 3-D axes keeps its
    own switch)."""
    return bool(getattr(ax, "_axis3don", ax.axison))


def _axes_of(ax: Any) -> list[Any]:
    return [a for a in (ax.xaxis, ax.yaxis, getattr(ax, "zaxis", None)) if a is not None]


def _shown_texts(artist: Any) -> Iterator[Text]:
    """Every visible text under ``artist``, not looking inside invisible artists.

    Unlike ``Figure.findobj`` this does not ask an invisible axis for its children, which
    would make its ticks (about a millisecond each, none of them drawn: issue 16).
    """
    from matplotlib.text import Text

    for child in artist.get_children():
        if not child.get_visible():
            continue
        if isinstance(child, Text):
            yield child
        yield from _shown_texts(child)


def readable(fig: Figure, dpi: float, *, min_px: float = MIN_TEXT_PX,
             page_px: float = PAGE_WIDTH_PX) -> float:
    """Raise every text of ``fig`` to at least ``min_px`` pixels as the page shows it.

    A figure wider than the page is shown scaled down, so its text must be larger in points;
    returns the smallest font size (points) the figure now has. An axes switched off
    (``set_axis_off``) gets its axes hidden: they draw nothing, and hidden they make no ticks
    for this function or for the title's placement (a tick costs about a millisecond).
    """
    import matplotlib as mpl

    shown = min(1.0, page_px / (fig.get_figwidth() * dpi))
    min_pt = min_px * 72.0 / dpi / shown
    smallest = math.inf
    # tick labels are made at draw time: raise the size the axis gives them
    default = mpl.font_manager.FontProperties(size=mpl.rcParams["xtick.labelsize"]).get_size()
    for ax in fig.axes:
        drawn = _axes_drawn(ax)
        for axis in _axes_of(ax):
            if not drawn:
                axis.set_visible(False)
            if not axis.get_visible():
                continue
            made = [float(t.get_fontsize()) for t in axis.get_ticklabels(which="both")]
            if min(made, default=float(default)) < min_pt:
                axis.set_tick_params(which="both", labelsize=min_pt)
    for t in _shown_texts(fig):
        if not t.get_text():
            continue
        size = float(t.get_fontsize())
        if size < min_pt:
            t.set_fontsize(min_pt)
            size = min_pt
        smallest = min(smallest, size)
    return smallest


def figure_to_png(fig: Figure, dpi: int = 80) -> bytes:
    """A matplotlib figure as PNG bytes, every text readable on the page (:func:`readable`).

    The figure's layout engine, if any, runs once here and is then switched off, so that the
    figure is drawn once (a constrained layout otherwise costs a second full draw). Text is
    laid out and drawn unhinted (:data:`TEXT_HINTING`), and an opaque figure is written as
    RGB by :func:`png_bytes` (issue 16).

    The figure is drawn as the report shows it and keeps what that changed: its texts raised
    to the page's smallest size, its dpi set to ``dpi``, the axes of axes switched off hidden
    for good (no ticks made for them), and its layout engine off. ``savefig``'s own settings
    (``facecolor``, ``transparent``) do not apply: draw a copy for other uses.
    """
    return png_bytes(figure_pixels(fig, dpi))


def figure_pixels(fig: Figure, dpi: int = 80) -> NDArray[np.uint8]:
    """The pixels :func:`figure_to_png` writes: shape (height, width, 3), or 4 where the
    figure is not opaque; a fresh array the caller may write into."""
    import matplotlib as mpl
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    readable(fig, dpi)
    fig.set_dpi(dpi)
    canvas: Any = FigureCanvasAgg(fig)  # its draw() has no type hints
    with mpl.rc_context({"text.hinting": TEXT_HINTING}):
        engine = fig.get_layout_engine()
        if engine is not None:
            engine.execute(fig)
            fig.set_layout_engine("none")
        canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    # the page is opaque: RGB without the alpha channel
    return np.array(rgba[..., :3] if rgba[..., 3].min() == 255 else rgba)


def png_bytes(pixels: NDArray[np.uint8], level: int = PNG_COMPRESS_LEVEL) -> bytes:
    """An RGB or RGBA image (shape (height, width, 3 or 4), uint8) as PNG bytes.

    Rows unfiltered (PNG filter 0), deflated at zlib's ``level``. Pillow (what matplotlib
    writes with) tries every PNG filter on every row to pick one, which costs more than the
    deflate itself and, on the report's flat-coloured figures, gives larger files: unfiltered
    rows at level 1 take half the time and are 10 % smaller (issue 16). Any PNG reader reads
    them (the format's own chunks: signature, IHDR, IDAT, IEND).
    """
    import numpy as np

    height, width, channels = pixels.shape
    if pixels.dtype != np.uint8 or channels not in (3, 4):
        raise ValueError(f"expected uint8 pixels of shape (h, w, 3 or 4), got {pixels.dtype} "
                         f"{pixels.shape}")
    rows = np.zeros((height, 1 + width * channels), dtype=np.uint8)  # filter byte 0: none
    rows[:, 1:] = pixels.reshape(height, width * channels)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data)))

    color_type = 2 if channels == 3 else 6  # truecolour, truecolour with alpha
    header = struct.pack(">IIBBBBB", width, height, 8, color_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(rows.tobytes(), level)) + chunk(b"IEND", b""))


def _cell(tag: str, c: str | Cell) -> str:
    if isinstance(c, Cell):
        return (f'<{tag} title="{html.escape(c.title, quote=True)}">{html.escape(c.text)}'
                f"</{tag}>")
    return f"<{tag}>{html.escape(c)}</{tag}>"


def _table(header: Sequence[str | Cell], rows: Sequence[Sequence[str | Cell]]) -> str:
    head = "".join(_cell("th", h) for h in header)
    body = "".join("<tr>" + "".join(_cell("td", c) for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def render_report(title: str, intro: str, sections: Sequence[Section],
                  meta: Sequence[tuple[str, str]] = ()) -> str:
    """The report as one HTML document; ``meta`` (name, value) pairs, such as the version,
    seed and command that made it, are listed under the title."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>",
        f"<style>{_STYLE}</style><script>{_SCRIPT}</script></head>",
        f'<body data-images-loaded="pending"><h1>{html.escape(title)}</h1>',
        f"<p>{html.escape(intro)}</p>",
    ]
    if meta:
        parts.append('<table class="meta">' + "".join(
            f"<tr><th>{html.escape(k)}</th><td><code>{html.escape(v)}</code></td></tr>"
            for k, v in meta) + "</table>")
    for sec in sections:
        parts.append(f"<h2>{html.escape(sec.title)}</h2>")
        parts += [f"<p>{html.escape(p)}</p>" for p in sec.paragraphs]
        for header, rows in sec.tables:
            parts.append(_table(header, rows))
        parts += [f'<p class="note">{html.escape(n)}</p>' for n in sec.notes]
        for png, caption in sec.figures:
            if isinstance(png, HtmlFigure):
                parts.append(f"<figure>{png.markup}<figcaption>{html.escape(caption)}"
                             "</figcaption></figure>")
                continue
            data = base64.b64encode(png).decode("ascii")
            parts.append(
                f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
            )
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(path: str | Path, title: str, intro: str, sections: Sequence[Section],
                 *, meta: Sequence[tuple[str, str]] = ()) -> Path:
    """Write the report (``path`` is a folder: ``index.html`` goes in it)."""
    folder = Path(path)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / "index.html"
    from nonprehensile.io import write_text_file

    return write_text_file(out, render_report(title, intro, sections, meta))
