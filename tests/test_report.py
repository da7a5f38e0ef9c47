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
    assert CHROMIUM is not None
    proc = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", f"--user-data-dir={profile}", "--virtual-time-budget=10000",
         "--dump-dom", page.resolve().as_uri()],
        capture_output=True, text=True, timeout=120, check=True,
    )
    marker = 'data-images-loaded="'
    start = proc.stdout.index(marker) + len(marker)
    return proc.stdout[start:proc.stdout.index('"', start)]


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
