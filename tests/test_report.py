"""The self-contained HTML report, rendered in a real headless browser."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

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
