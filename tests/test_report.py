"""The self-contained HTML report, rendered in a real headless browser."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings, strategies as st

from nonprehensile.viz.report import Section, render_report, write_report

pytest.importorskip("matplotlib")

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def loaded_images(page: Path, profile: Path) -> str:
    """Open ``page`` in headless Chromium and read the count of loaded images it records."""
    dom = loaded_dom(page, profile)
    marker = 'data-images-loaded="'
    start = dom.index(marker) + len(marker)
    return dom[start:dom.index('"', start)]


def loaded_dom(page: Path, profile: Path) -> str:
    """The page's DOM after Chromium loaded it (scripts run)."""
    assert CHROMIUM is not None
    proc = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", f"--user-data-dir={profile}", "--virtual-time-budget=10000",
         "--dump-dom", page.resolve().as_uri()],
        capture_output=True, text=True, timeout=120, check=True,
    )
    return proc.stdout


def _png() -> bytes:
    from nonprehensile.geometry import cube
    from nonprehensile.viz import object_figure
    from nonprehensile.viz.report import figure_to_png

    return figure_to_png(object_figure(cube()))


def test_report_escapes_text_and_embeds_images(tmp_path: Path) -> None:
    png = _png()
    doc = render_report("T <1>", "a & b", [Section("S", ["<script>x</script>"], [(png, "c")],
                                                    [(["h"], [["<i>"]])])])
    assert "<script>x</script>" not in doc and "&lt;script&gt;" in doc
    assert doc.count("data:image/png;base64,") == 1
    assert "&lt;i&gt;" in doc


def test_html_figure_goes_in_as_markup_with_its_caption_escaped() -> None:
    """A figure the page lays out itself (issue 16: the transition matrix as a table) is put
    in as it is, in a figure with its caption, in the order of the section's figures."""
    from nonprehensile.viz.report import HtmlFigure

    png = _png()
    doc = render_report("T", "i", [Section("S", figures=[
        (png, "first"), (HtmlFigure('<table class="matrix"><tr><td></td></tr></table>'),
                         "a <b> & c"), (png, "last")])])
    assert ('<figure><table class="matrix"><tr><td></td></tr></table>'
            "<figcaption>a &lt;b&gt; &amp; c</figcaption></figure>") in doc
    assert doc.index("first") < doc.index('class="matrix"') < doc.index("last")
    assert doc.count("<img ") == 2


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
def test_report_renders_in_chromium_with_every_image(tmp_path: Path) -> None:
    png = _png()
    page = write_report(tmp_path / "report", "Report", "intro",
                        [Section("one", figures=[(png, "a"), (png, "b")])])
    assert loaded_images(page, tmp_path / "profile") == "2/2"
    # a broken image is caught: the check can fail
    broken = page.read_text().replace("base64,", "base64,AAAA", 1)
    page.write_text(broken)
    assert loaded_images(page, tmp_path / "profile2") == "1/2"


def test_figures_text_is_readable_at_page_size() -> None:
    from nonprehensile.viz._figures import new_figure
    from nonprehensile.viz.report import MIN_TEXT_PX, PAGE_WIDTH_PX, figure_to_png, readable

    for width in (6.0, 20.0):  # the wide one is shown scaled down to the page
        fig = new_figure(figsize=(width, 3), layout="constrained")
        ax = fig.add_subplot()
        ax.set_title("tiny", fontsize=5)
        ax.set_xticks([0, 1], ["a", "b"], fontsize=4)
        figure_to_png(fig, dpi=80)
        shown = min(1.0, PAGE_WIDTH_PX / (width * 80))
        sizes = [t.get_fontsize() for t in fig.findobj(lambda a: hasattr(a, "get_fontsize"))
                 if getattr(a := t, "get_text", lambda: "")() and a.get_visible()]
        assert sizes and min(sizes) * 80 / 72 * shown >= MIN_TEXT_PX - 1e-9
        assert readable(fig, 80) * 80 / 72 * shown >= MIN_TEXT_PX - 1e-9


def test_axes_switched_off_make_no_ticks_and_keep_their_texts_readable() -> None:
    """An axes switched off draws no axis: the report hides its axes, so that neither the
    readability pass nor the title's placement makes ticks for them (about a millisecond a
    tick: issue 16); its own texts are still raised to the page's smallest size."""
    from nonprehensile.viz._figures import new_figure
    from nonprehensile.viz.report import MIN_TEXT_PX, figure_to_png

    fig = new_figure(figsize=(6.0, 3.0))
    off = fig.add_axes((0.05, 0.1, 0.4, 0.8))
    off.set_xlim(0, 100)
    off.text(50, 0.5, "node", fontsize=4)
    off.set_title("off", fontsize=5)
    off.set_axis_off()
    on = fig.add_axes((0.55, 0.1, 0.4, 0.8))
    on.set_xticks([0, 1], ["a", "b"], fontsize=4)
    figure_to_png(fig, dpi=80)
    for axis in (off.xaxis, off.yaxis):
        assert not axis.get_visible()
        # the one tick every axis makes when its axes is made (what later ticks copy), not
        # the locator's six for 0 .. 100
        assert len(vars(axis).get("majorTicks", [])) <= 1
    assert on.xaxis.get_visible() and len(on.xaxis.get_major_ticks()) == 2
    least = MIN_TEXT_PX * 72 / 80
    assert min(t.get_fontsize() for t in (*off.texts, off.title)) >= least - 1e-9
    assert min(t.get_fontsize() for t in on.get_xticklabels()) >= least - 1e-9


def test_figure_png_is_the_drawn_figure_in_rgb() -> None:
    """The report's PNG holds exactly the pixels matplotlib's Agg draws (an opaque figure:
    RGB, the alpha channel dropped), at the figure's size in pixels."""
    import io as _io

    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image

    from nonprehensile.viz._figures import new_figure
    from nonprehensile.viz.report import figure_to_png

    def figure() -> Any:
        fig = new_figure(figsize=(3.0, 2.0))
        ax = fig.add_axes((0.15, 0.15, 0.8, 0.8))
        ax.plot([0, 1, 2], [2, 0, 1], color="C1")
        ax.fill_between([0, 1], [0, 1], color="C0", alpha=0.4)
        ax.set_xticks([0, 1, 2], ["x", "y", "z"], fontsize=12)
        ax.set_yticks([0, 1, 2], ["p", "q", "r"], fontsize=12)
        return fig

    png = figure_to_png(figure(), dpi=80)
    got = Image.open(_io.BytesIO(png))
    assert got.mode == "RGB" and got.size == (240, 160)
    import matplotlib as mpl

    from nonprehensile.viz.report import TEXT_HINTING

    fig = figure()
    fig.set_dpi(80)
    canvas = FigureCanvasAgg(fig)
    with mpl.rc_context({"text.hinting": TEXT_HINTING}):
        canvas.draw()
    drawn = np.asarray(canvas.buffer_rgba())
    assert drawn[..., 3].min() == 255
    np.testing.assert_array_equal(np.asarray(got), drawn[..., :3])


def test_filmstrip_is_its_frames_pixel_for_pixel() -> None:
    """Each frame of the physics filmstrip appears in the report's PNG unchanged (placed,
    not resampled), with its caption above it."""
    import io as _io

    import numpy as np
    from PIL import Image

    from nonprehensile.viz.physics import filmstrip_figure
    from nonprehensile.viz.report import figure_to_png

    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, size=(40, 60, 3), dtype=np.uint8) for _ in range(8)]
    fig = filmstrip_figure(frames, [f"frame {i}" for i in range(8)], per_row=3)
    assert [t.get_text() for t in fig.texts] == [f"frame {i}" for i in range(8)]
    img = np.asarray(Image.open(_io.BytesIO(figure_to_png(fig, dpi=80))))
    gap, band = 2, 16
    assert img.shape == (3 * (band + 40 + gap), 3 * (60 + gap), 3)
    for i, frame in enumerate(frames):
        r, c = divmod(i, 3)
        y, x = r * (band + 40 + gap) + band, c * (60 + gap)
        np.testing.assert_array_equal(img[y:y + 40, x:x + 60], frame)


def test_report_filmstrip_is_matplotlibs_picture_without_its_compositing() -> None:
    """The report's filmstrip PNG (frames copied into the captions' pixels, issue 16) is, pixel
    for pixel, the figure matplotlib draws with the frames placed by ``figimage``."""
    import io as _io

    import numpy as np
    from PIL import Image

    from nonprehensile.viz.physics import filmstrip_figure, filmstrip_png
    from nonprehensile.viz.report import figure_to_png

    rng = np.random.default_rng(4)
    frames = [rng.integers(0, 256, size=(30, 50, 3), dtype=np.uint8) for _ in range(7)]
    caps = [f"step {i // 3 + 1}, t = {i:.2f} s" for i in range(7)]
    ours = np.asarray(Image.open(_io.BytesIO(filmstrip_png(frames, caps, per_row=3))))
    ref = np.asarray(Image.open(_io.BytesIO(
        figure_to_png(filmstrip_figure(frames, caps, per_row=3), dpi=80))))
    np.testing.assert_array_equal(ours, ref)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.sampled_from([3, 4]), st.integers(0, 2**31))
def test_png_bytes_decode_to_the_same_pixels(h: int, w: int, channels: int, seed: int) -> None:
    """The report's PNG writer (unfiltered rows, issue 16) against Pillow's reader: every
    pixel back as written, RGB and RGBA, any size."""
    import io as _io

    import numpy as np
    from PIL import Image

    from nonprehensile.viz.report import png_bytes

    rng = np.random.default_rng(seed)
    pixels = rng.integers(0, 256, size=(h, w, channels), dtype=np.uint8)
    img = Image.open(_io.BytesIO(png_bytes(pixels)))
    img.load()  # checks every chunk's CRC and the stream's length
    assert img.mode == ("RGB" if channels == 3 else "RGBA")
    np.testing.assert_array_equal(np.asarray(img), pixels)


def test_png_bytes_refuses_what_it_cannot_write() -> None:
    import numpy as np

    from nonprehensile.viz.report import png_bytes

    for bad in (np.zeros((2, 2, 3), dtype=np.float64), np.zeros((2, 2, 2), dtype=np.uint8)):
        with pytest.raises(ValueError, match="uint8 pixels"):
            png_bytes(bad)
