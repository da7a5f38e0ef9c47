"""The main job end to end, from the command line, and its report in a real browser."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("matplotlib")
pytest.importorskip("sklearn")
pytest.importorskip("ezc3d")

from nonprehensile.cli import main
from nonprehensile.io import load_model
from nonprehensile.maneuvers import classify
from nonprehensile.pipeline import write_plan_motions
from nonprehensile.states import State
from test_report import CHROMIUM, loaded_dom, loaded_images

# demo_cache and demo_run (the main job run once by the CLI) are session fixtures in
# conftest.py: tests/test_report_runs.py reads the same run's robot execution


def test_demo_writes_report_and_summary(demo_run: tuple[Path, dict[str, object]]) -> None:
    out, doc = demo_run
    page = out / "index.html"
    assert page.stat().st_size > 100_000
    html = page.read_text()
    assert html.count("data:image/png;base64,") >= 5
    # the transition matrix is a table of the 24 states (issue 16), not drawn in a PNG
    matrix = html[html.index('<table class="matrix">'):]
    assert matrix[:matrix.index("</table>")].count("<tr>") == 1 + 24
    summary = json.loads((out / "summary.json").read_text())
    assert summary["states"]["count"] == 24 and summary["inference"]["transitions"] == 168
    assert summary["dataset"]["demonstrations"] == 180
    assert doc["report"] == str(page)
    # where two skills share contact events but move differently (Fig. 5 skills 2 and 3, and
    # the tumbling pair of Fig. 9), the clusters separate them exactly
    moving = [a for a in summary["clustering"] if len(a["labels"]) > 1]
    assert {tuple(a["labels"]) for a in moving} == {("quarter-circle", "straight-pull"),
                                                     ("lift-over", "twist-over")}
    assert all(a["clusters"] == 2 and a["ari_vs_skill"] == 1.0 for a in moving)


def test_demo_plan_is_exact_and_never_demonstrated(
    demo_run: tuple[Path, dict[str, object]],
) -> None:
    _, doc = demo_run
    plan = doc["plan"]
    assert isinstance(plan, dict)
    start, goal = State.from_dict(plan["start"]), State.from_dict(plan["goal"])
    demonstrated = {State("a", 0), State("d", 0), State("d", 90), State("a", 90)}
    assert not any(start.isclose(s) or goal.isclose(s) for s in demonstrated)
    cube = load_model("cube")
    cur = start
    for step in plan["steps"]:
        a, b = State.from_dict(step["from"]), State.from_dict(step["to"])
        assert a.isclose(cur)
        assert classify(cube, a, b).kind == step["maneuver"]
        assert all(m["reference"] is not None for m in step["motions"])
        cur = b
    assert cur.isclose(goal)
    assert plan["offset"]["rotate_deg"] == pytest.approx(20)


def test_plan_reference_files(tmp_path: Path) -> None:
    from nonprehensile.demonstrations.formats import read_c3d, read_motive_csv
    from nonprehensile.inference import expand
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.states import states_by_step

    ds, motions = motions_from_dataset("cube")
    exp = expand(ds.poly, list(ds.skills), states_by_step(ds.poly, 90))
    result = plan(ds.poly, exp, State("a", 0), State("d", 0), motions=motions,
                  position=(0.5, 0.0))
    files = write_plan_motions(result, tmp_path)
    assert len(files) == 2 * 4 + 1  # and plan.json, with the object poses
    traj = read_c3d(next(f for f in files if f.suffix == ".c3d"))
    ref = result.steps[0].motions[0][3]
    assert ref is not None
    assert traj.to_units("m").positions.shape == ref.positions.shape
    assert abs(traj.to_units("m").positions - ref.positions).max() < 1e-6
    # every file reads back, at the readers' defaults, to its reference motion: exact to the
    # format's precision (C3D float32, CSV six decimals: half a unit of the last, plus
    # round-off), never a frame turned on its side
    refs = [ref for step in result.steps for *_, ref in step.motions if ref is not None]
    for suffix, reader, tol in ((".c3d", read_c3d, 2e-7), (".csv", read_motive_csv, 5.01e-7)):
        back = [reader(f).to_units("m") for f in files if f.suffix == suffix]
        assert len(back) == len(refs)
        for got, want in zip(back, refs, strict=True):
            assert got.marker_names == want.marker_names and got.rate == want.rate
            scale = max(1.0, float(np.abs(want.positions).max()))
            assert np.abs(got.positions - want.positions).max() <= tol * scale
    # the offset moved the demonstrated motion by half a metre along x
    assert ref.positions[..., 0].mean() > 0.3


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
def test_demo_report_renders_in_chromium(
    demo_run: tuple[Path, dict[str, object]], tmp_path: Path
) -> None:
    out, _ = demo_run
    page = out / "index.html"
    n = page.read_text().count("<img ")
    assert loaded_images(page, tmp_path / "profile") == f"{n}/{n}"
    # the plan's pictures are among the loaded images: the filmstrip shows every step
    dom = loaded_dom(page, tmp_path / "profile2")
    film = [img for img in re.findall(r"<img [^>]*>", dom) if 'alt="Plan filmstrip' in img]
    assert len(film) == 1 and "data:image/png;base64," in film[0]


def test_demo_report_names_version_seed_command_and_reads_well(
    demo_run: tuple[Path, dict[str, object]],
) -> None:
    out, _ = demo_run
    html = (out / "index.html").read_text()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["meta"]["seed"] == "0" and summary["meta"]["nonprehensile"]
    for key in ("nonprehensile", "seed", "command"):
        assert f"<th>{key}</th>" in html
    assert "nonprehensile demo" in summary["meta"]["command"]
    assert not re.search(r"\b1 (demonstrations|demos|transitions|steps|faces)\b", html)
    # every skill is drawn on the state-transition graph; the plan says where the agent is
    assert "one panel per skill" in html and "<th>agent</th>" in html


def test_demo_report_has_the_figures_of_issue_24(
    demo_run: tuple[Path, dict[str, object]],
) -> None:
    """Issue 24 point 6: the transition graph in per-skill panels, the plan's filmstrip, the
    physics filmstrip and the per-step tracking error / contact force / slip plots, and one
    ARI column whose header says what it means."""
    import html as html_lib

    out, _ = demo_run
    page = (out / "index.html").read_text()
    summary = json.loads((out / "summary.json").read_text())
    svg = page[page.index('<svg class="transitions"'):]
    svg = svg[:svg.index("</svg>")]
    skills = re.findall(r'<g data-skill="([^"]+)">', svg)
    # one panel per skill of the graph (the six demonstrated and the twist's reverse)
    assert len(skills) == len(set(skills)) == 7
    assert set(summary["skills"]) < set(skills)
    # every transition is an arc, the demonstrated ones marked so
    arcs = re.findall(r"<path d=\"M[^>]*><title>([^<]*)</title>", svg)
    assert len(arcs) == summary["inference"]["transitions"] == 168
    assert sum(t.endswith("(demonstrated)") for t in arcs) == 6
    alts = re.findall(r'<img alt="([^"]*)"', page)
    assert any(a.startswith("Plan filmstrip") for a in alts)
    physics = summary["physics"]
    assert isinstance(physics, dict)
    if "steps" in physics:  # MuJoCo installed (the sim extra)
        assert any(a.startswith("What the execution did") for a in alts)
        for step in physics["steps"]:
            sig = step["signals"]
            # a push that rolls a 5 cm cube: the finger presses, tracks within millimetres
            assert 0.0 < sig["max_contact_force_n"] < 50.0
            assert 0.0 < sig["max_tracking_error_m"] < 0.02
            assert sig["max_slip_m_per_s"] is not None
    # the motion table: one score column, its meaning in the header, the rest in tooltips
    table = page[page.index("<th>arc</th>"):]
    table = table[:table.index("</table>")]
    headers = re.findall(r"<th[^>]*>([^<]*)</th>", table)
    assert [h for h in headers if "ARI" in h] == [
        "clusters match the skills? (ARI: 1 exactly, 0 chance)"]
    tips = [html_lib.unescape(t) for t in re.findall(r'<td title="([^"]*)"', table)]
    assert len(tips) == len(summary["clustering"])
    assert all("skill x mentor" in t for t in tips)
    assert "Rest the pointer on a score" in page


def test_plan_cli_with_dataset_and_out(tmp_path: Path) -> None:
    skills = str(Path(__file__).parents[1] / "examples" / "cube_skills.json")
    out = tmp_path / "refs"
    res = CliRunner().invoke(main, ["plan", skills, "--from", "a:0", "--to", "a:90", "--step",
                                    "90", "--dataset", "cube", "--out", str(out), "--json"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    (step,) = doc["steps"]
    assert step["skill"] == "twist" and step["demonstrated"]
    assert all(m["reference"]["n_frames"] > 0 for m in step["motions"])
    assert sorted(p.suffix for p in out.iterdir()) == [".c3d", ".c3d", ".csv", ".csv", ".json"]
    res = CliRunner().invoke(main, ["plan", skills, "--from", "a:0", "--to", "a:90", "--step",
                                    "90", "--out", str(out)])
    assert res.exit_code == 2 and "--dataset" in res.stderr


def _counted_builds(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                    ) -> tuple[Path, list[int], Path]:
    """A small synthetic dataset, the list each motion-library build appends to, and a
    cache folder."""
    import nonprehensile.pipeline as pipeline
    from nonprehensile.demonstrations.synth import synthesize

    root = tmp_path / "ds"
    synthesize(root, seed=5, n_per_skill=2, mentors=2, dropouts=0.0)
    built: list[int] = []
    real = pipeline.cluster_segments

    def counting(*args: object, **kwargs: object) -> object:
        built.append(1)
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(pipeline, "cluster_segments", counting)
    return root, built, tmp_path / "cache"


def test_motion_library_is_built_once_and_rebuilt_when_a_file_changes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import os

    import nonprehensile.pipeline as pipeline

    root, built, cache = _counted_builds(tmp_path, monkeypatch)
    ds1, m1 = pipeline.motions_from_dataset(root, cache=cache)
    ds2, m2 = pipeline.motions_from_dataset(root, cache=cache)
    assert len(built) == 1 and len(list(cache.glob("motions-*.pickle"))) == 1
    assert np.array_equal(m1.labels, m2.labels) and np.array_equal(m1.vectors, m2.vectors)
    assert len(ds2.demonstrations) == len(ds1.demonstrations)
    # another seed is another library
    pipeline.motions_from_dataset(root, cache=cache, seed=1)
    assert len(built) == 2
    # a changed file (here: its modification time) invalidates the cached one
    f = next(root.glob("*.c3d"))
    st = f.stat()
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    pipeline.motions_from_dataset(root, cache=cache)
    assert len(built) == 3
    # a damaged cache file is rebuilt, never fatal; no cache at all works too
    for p in cache.glob("motions-*.pickle"):
        p.write_bytes(b"not a pickle")
    pipeline.motions_from_dataset(root, cache=cache)
    pipeline.motions_from_dataset(root, cache=False)
    assert len(built) == 5


def test_motion_library_is_kept_per_angle_tolerance(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A library built at one --angle-tol is not reused at another (the dataset's skills and
    states were read at it); at the same tolerance it is."""
    import nonprehensile.pipeline as pipeline
    from nonprehensile.states import DEFAULT_ANGLE_TOL

    root, built, cache = _counted_builds(tmp_path, monkeypatch)
    pipeline.motions_from_dataset(root, cache=cache)  # the default tolerance
    assert len(built) == 1
    pipeline.motions_from_dataset(root, cache=cache, angle_tol=0.5)  # another: rebuilt
    assert len(built) == 2 and len(list(cache.glob("motions-*.pickle"))) == 2
    pipeline.motions_from_dataset(root, cache=cache, angle_tol=0.5)  # the same: kept
    pipeline.motions_from_dataset(root, cache=cache, angle_tol=DEFAULT_ANGLE_TOL)
    assert len(built) == 2
    assert pipeline._dataset_key(root, 0) != pipeline._dataset_key(root, 0, 0.5)


def test_demo_report_has_the_robustness_and_robot_sections(
    demo_run: tuple[Path, dict[str, object]], demo_cache: Path,
) -> None:
    """Issue 21 item 8 and issue 22 item 8: the robustness figure (success against table
    friction and mass, open and closed loop) with its samples and seed stated, and the
    robot's filmstrip and its tracking error / joint margins over time, from real runs."""
    import html as html_lib

    out, _ = demo_run
    page = (out / "index.html").read_text()
    summary = json.loads((out / "summary.json").read_text())
    alts = [html_lib.unescape(a) for a in re.findall(r'<img alt="([^"]*)"', page)]
    rob = summary["robustness"]
    if "error" in rob:  # only without the sim extra
        pytest.importorskip("mujoco")
        raise AssertionError(rob["error"])
    assert rob["samples"] == 3 and rob["seed"] == 0 and rob["source"] == "computed"
    assert any(a.startswith("Success rate against table friction and object mass")
               for a in alts)
    assert "3 times, once per sample" in page and "(seed 0;" in page
    sweep = json.loads(next(demo_cache.glob("sweep-*.json")).read_text())
    assert sweep["key"] == rob["key"] and len(sweep["records"]) == 6
    robot = summary["robot"]
    if "error" in robot:
        pytest.importorskip("mink")  # skips only when mink is really absent
        raise AssertionError(robot["error"])
    assert any(a.startswith("Filmstrip of the arm") for a in alts)
    assert any(a.startswith("The robot's records over the whole execution") for a in alts)
    assert robot["success"] and not robot["cached"]
    assert list(demo_cache.glob("robot-*.pickle"))
