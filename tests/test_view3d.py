"""The rotatable 3-D views: self-contained HTML files, every face labeled, the plan drawn."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from nonprehensile.cli import main

plotly = pytest.importorskip("plotly", reason="the view3d extra (plotly) is not installed")

EXAMPLE = Path(__file__).parents[1] / "examples" / "cube.json"
REALDATA = Path(__file__).parents[2] / "shared" / "realdata" / "meshes"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(main, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def embedded_figure(page: str) -> list[dict[str, Any]]:
    """The traces the page hands to ``Plotly.newPlot``, read from the HTML itself."""
    start = page.index("Plotly.newPlot(")
    args = page[start + len("Plotly.newPlot("):]
    after_id = args.index(",") + 1  # the div's id, then the data
    data, _ = json.JSONDecoder().raw_decode(args[after_id:].lstrip())
    return list(data)


def values(v: Any) -> list[float]:
    """A trace's numbers, as the page holds them: a list, or plotly's typed array
    (``{"dtype": "f8", "bdata": base64}``)."""
    import base64

    import numpy as np

    if isinstance(v, dict):
        return np.frombuffer(base64.b64decode(v["bdata"]), dtype=v["dtype"]).tolist()
    return [float(x) for x in v]


def assert_self_contained(page: str) -> None:
    """Nothing in the page is fetched: no external script, style, frame or image, and apart
    from plotly.js itself (the wheel's own file, embedded byte for byte) no URL at all."""
    library = (Path(plotly.__file__).parent / "package_data" / "plotly.min.js").read_text()
    assert library in page, "plotly.js is not embedded whole"
    rest = page.replace(library, "")
    assert not re.search(r"<script[^>]*\bsrc\s*=", rest, re.I)
    assert not re.search(r"<(link|iframe|img|object|embed)\b", rest, re.I)
    assert "@import" not in rest
    urls = re.findall(r"(?:https?:)?//[a-z0-9.-]+\.[a-z]{2,}[^\s\"'<>)]*", rest, re.I)
    # SVG's namespace names are identifiers, never fetched
    assert [u for u in urls if "www.w3.org" not in u] == []


def faces_of(model: Path) -> list[str]:
    return list(json.loads(model.read_text())["faces"])


def test_object_html_is_self_contained_with_every_face_labeled(tmp_path: Path) -> None:
    out = tmp_path / "cube.html"
    code, _, err = run("object", "figure", str(EXAMPLE), "--html", str(out))
    assert code == 0 and "wrote" in err
    page = out.read_text()
    assert_self_contained(page)
    traces = {t.get("name"): t for t in embedded_figure(page)}
    # the independent truth: the model file's own face IDs
    assert sorted(traces["face IDs"]["text"]) == sorted(faces_of(EXAMPLE))
    # every edge numbered once per face: 4 per face of the cube, 1..4 each
    numbers = traces["edge numbers"]["text"]
    assert sorted(numbers) == sorted([str(k) for _ in range(6) for k in range(1, 5)])


def test_object_html_of_a_real_mesh_labels_all_its_faces(tmp_path: Path) -> None:
    mesh = REALDATA / "ballA.off"
    if not mesh.is_file():
        pytest.skip(f"{mesh} not found (the shared real data lies beside the repository)")
    model = tmp_path / "ball.json"
    assert run("object", "from-mesh", str(mesh), "-o", str(model), "--max-faces", "121")[0] == 0
    faces = faces_of(model)
    assert len(faces) > 40  # a model whose PNG figure has no labels
    out = tmp_path / "ball.html"
    assert run("object", "figure", str(model), "--html", str(out))[0] == 0
    page = out.read_text()
    assert_self_contained(page)
    traces = {t.get("name"): t for t in embedded_figure(page)}
    assert sorted(traces["face IDs"]["text"]) == sorted(faces)
    # the edge numbers are there, hidden until their legend entry is clicked
    assert traces["edge numbers"]["visible"] == "legendonly"
    # --faces labels the chosen ones only, in the HTML and in the PNG
    chosen = faces[:3]
    png = tmp_path / "ball.png"
    out2 = tmp_path / "ball2.html"
    code, _, _ = run("object", "figure", str(model), "--faces", ",".join(chosen),
                     "--html", str(out2), "-o", str(png))
    assert code == 0 and png.stat().st_size > 0
    traces = {t.get("name"): t for t in embedded_figure(out2.read_text())}
    assert traces["face IDs"]["text"] == chosen


def test_faces_option_labels_chosen_faces_on_a_large_model() -> None:
    """Above DETAIL_LIMIT faces the PNG figure has no labels; --faces brings back those of
    the chosen faces, each in the view it faces."""
    from nonprehensile.geometry.build import prism
    from nonprehensile.viz.labeled_object import DETAIL_LIMIT, object_figure

    poly = prism(DETAIL_LIMIT + 8)
    assert len(poly.faces) > DETAIL_LIMIT
    fig = object_figure(poly)
    assert not [t for t in fig.findobj() if str(getattr(t, "get_gid", lambda: "")() or "")
                .startswith("face:")]
    chosen = [list(poly.faces)[i] for i in (0, 1, 5)]
    fig = object_figure(poly, faces=chosen)
    gids = [a.get_gid() for a in fig.findobj() if a.get_gid()]
    assert sorted(g for g in gids if g.startswith("face:")) == sorted(f"face:{f}" for f in chosen)
    for f in chosen:
        assert sum(g.startswith(f"edge:{f}:") for g in gids) == poly.n_edges(f)


@pytest.mark.parametrize("faces", ["a,zz", "q"])
def test_unknown_face_is_one_line_naming_it(faces: str, tmp_path: Path) -> None:
    code, _, err = run("object", "figure", str(EXAMPLE), "--faces", faces, "--html",
                       str(tmp_path / "x.html"))
    assert code == 2
    assert err.count("\n") == 1 and "no face" in err and "a, b, c" in err
    assert not (tmp_path / "x.html").exists()


def test_figure_needs_an_output_and_html_needs_its_suffix(tmp_path: Path) -> None:
    code, _, err = run("object", "figure", str(EXAMPLE))
    assert code == 2 and "-o" in err and "--html" in err
    code, _, err = run("object", "figure", str(EXAMPLE), "--html", str(tmp_path / "x.png"))
    assert code == 2 and ".html" in err
    code, _, err = run("object", "figure", str(EXAMPLE), "--faces", ",")
    assert code == 2 and "--faces" in err


def test_plan_html_draws_every_step_bottom_face_paths_and_agent(tmp_path: Path) -> None:
    skills = Path(__file__).parents[1] / "examples" / "cube_skills.json"
    out = tmp_path / "plan.html"
    code, stdout, _ = run("plan", str(skills), "--from", "b:200", "--to", "e:110", "--step",
                          "90", "--at", "0.3", "0.1", "--dataset", "cube", "--html", str(out),
                          "--json")
    assert code == 0
    doc = json.loads(stdout)
    assert doc["html"] == str(out)
    page = out.read_text()
    assert_self_contained(page)
    traces = embedded_figure(page)
    groups = {t.get("legendgroup") for t in traces}
    steps = doc["steps"]
    assert len(groups) == len(steps) + 1  # a group per step and the goal
    for i, step in enumerate(steps, start=1):
        group = next(g for g in groups if g.startswith(f"step {i}:"))
        mine = [t for t in traces if t.get("legendgroup") == group]
        labels = next(t for t in mine if str(t.get("name")).endswith(": faces"))["text"]
        # every face labeled, the bottom face (the step's start state) said to be it
        assert f"{step['from']['face']} (bottom)" in labels and len(labels) == 6
        paths = [t for t in mine if t["type"] == "scatter3d" and t.get("mode") == "lines"
                 and "->" in str(t.get("name"))]
        assert paths  # the reference finger paths
        agent = next(t for t in mine if str(t.get("name")).endswith(": agent"))
        # the agent's triangle points along its x axis from where it stands (plan's offset)
        x, y = step["agent"]["translate"]
        assert min(abs(v - x) for v in values(agent["x"])) < 0.05
        assert min(abs(v - y) for v in values(agent["y"])) < 0.05


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
def test_object_html_renders_offline_in_chromium(tmp_path: Path) -> None:
    from nonprehensile.geometry import cube
    from nonprehensile.viz.view3d import object_view, write_html

    page = write_html(object_view(cube()), tmp_path / "cube.html")
    assert CHROMIUM is not None
    proc = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
         "--disable-background-networking", "--disable-component-update",
         # no network at all: whatever the page needs must be in it
         "--host-resolver-rules=MAP * ~NOTFOUND", "--proxy-server=127.0.0.1:9",
         f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=10000",
         "--dump-dom", page.resolve().as_uri()],
        capture_output=True, text=True, timeout=120, check=True)
    dom = proc.stdout
    # plotly drew its scene: the SVG layers around the WebGL canvas, and the title
    assert 'class="main-svg"' in dom and "gl-container" in dom
    assert "every face labeled" in dom


def test_figure_of_a_large_model_says_how_to_find_faces(tmp_path: Path) -> None:
    from nonprehensile.geometry.build import prism
    from nonprehensile.io import write_model
    from nonprehensile.viz.labeled_object import DETAIL_LIMIT

    model = tmp_path / "p.json"
    write_model(prism(DETAIL_LIMIT + 8), model)
    code, _, err = run("object", "figure", str(model), "-o", str(tmp_path / "p.png"))
    assert code == 0 and "--faces" in err and "--html" in err
    code, _, err = run("object", "figure", str(model), "-o", str(tmp_path / "q.png"),
                       "--faces", "a,b")
    assert code == 0 and "note:" not in err
    # a small model's picture labels every face: no note
    code, _, err = run("object", "figure", str(EXAMPLE), "-o", str(tmp_path / "c.png"))
    assert code == 0 and "note:" not in err


def test_plan_html_shows_where_the_agent_is_relocated(tmp_path: Path) -> None:
    """a:0 -> f:180 at no relocation cost turns the agent before its second step."""
    skills = Path(__file__).parents[1] / "examples" / "cube_skills.json"
    out = tmp_path / "plan.html"
    code, stdout, _ = run("plan", str(skills), "--from", "a:0", "--to", "f:180", "--step", "90",
                          "--relocation-cost", "0", "--html", str(out), "--json")
    assert code == 0
    doc = json.loads(stdout)
    moved = [i for i, s in enumerate(doc["steps"], start=1) if s["relocated"] and i > 1]
    assert moved and doc["relocations"] == len(moved)
    traces = embedded_figure(out.read_text())
    labels = [t["text"][0] for t in traces if str(t.get("name")).endswith(": agent label")]
    assert labels == [f"agent {i}" + (" (relocated)" if i in moved else "")
                      for i in range(1, len(doc["steps"]) + 1)]
    assert sum(str(t.get("name")).endswith(": relocation") for t in traces) == len(moved)
