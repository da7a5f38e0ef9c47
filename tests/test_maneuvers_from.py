"""`nonprehensile maneuvers` and `skills show`'s right final state (issue 24 point 3)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import nonprehensile as nph
from nonprehensile.cli import main
from nonprehensile.errors import SkillError
from nonprehensile.geometry import box, prism
from nonprehensile.io import read_skills
from nonprehensile.states import state_pose

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "realdata" / "meshes"


@pytest.mark.parametrize("poly", [nph.load_model("cube"), box(4, 2, 1), prism(3, 1.0, 2.0)])
def test_every_roll_goes_across_its_edge(poly: nph.Polyhedron) -> None:
    face = nph.stable_faces(poly)[0]
    start = nph.State(face, 0.0)
    opts = nph.maneuvers_from(poly, start)
    rolls = [o for o in opts if o.maneuver.kind == "rolling"]
    assert [o.edge for o in rolls] == list(range(1, poly.n_edges(face) + 1))
    r, t = state_pose(poly, start)
    com = r @ poly.com + t
    for o in rolls:
        # independent truth: the centre of mass travels straight across the pivot edge, to
        # the side away from the bottom face's interior
        i, j = poly.edge_vertices(face, o.edge)
        a, b = r @ poly.vertices[i] + t, r @ poly.vertices[j] + t
        e = (b - a)[:2] / np.linalg.norm((b - a)[:2])
        foot = a[:2] + ((com[:2] - a[:2]) @ e) * e
        away = foot - com[:2]
        want = math.degrees(math.atan2(away[1], away[0])) % 360.0
        assert o.direction is not None
        assert abs((o.direction - want + 180.0) % 360.0 - 180.0) < 1e-6
        assert o.element == f"E({face},{poly.neighbor(face, o.edge)})"
        assert nph.classify(poly, start, o.maneuver.end).kind == "rolling"
    for o in opts:
        # the final state rests on its face: that face's normal points straight down
        rot, _ = state_pose(poly, o.maneuver.end)
        assert np.allclose(rot @ poly.normals[o.maneuver.end.face], [0, 0, -1], atol=1e-9)
        if o.maneuver.kind == "tumbling":
            assert o.vertex in poly.loop(face) and o.element.startswith("V(")


def test_the_papers_tumble_is_listed_and_rotations_follow_the_step() -> None:
    cube = nph.load_model("cube")
    opts = nph.maneuvers_from(cube, nph.State("a", 0), step=90)
    tumbles = {(o.element, str(o.maneuver.end)) for o in opts if o.maneuver.kind == "tumbling"}
    assert ("V(a,d,e)", "d:90") in tumbles  # Fig. 9
    turns = [o.maneuver.end.theta for o in opts if o.maneuver.kind == "rotating"]
    assert turns == [90.0, 180.0, 270.0]
    assert len([o for o in nph.maneuvers_from(cube, nph.State("a", 0), step=30)
                if o.maneuver.kind == "rotating"]) == 11
    assert nph.roll_directions(cube, nph.State("a", 0))  # the name docs/maneuvers.md uses


def test_cli_lists_them_and_refuses_bad_input_in_one_line() -> None:
    runner = CliRunner()
    r = runner.invoke(main, ["maneuvers", "cube", "--from", "a:0", "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    kinds = [m["kind"] for m in doc["maneuvers"]]
    assert kinds.count("rolling") == 4 and kinds.count("rotating") == 3
    first = doc["maneuvers"][0]
    assert set(first) >= {"kind", "from", "to", "element", "edge", "vertex", "direction",
                          "stable"}
    r = runner.invoke(main, ["maneuvers", "cube", "--from", "z:0"])
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
    assert "no face 'z'" in r.output and "['a', 'b'" in r.output
    r = runner.invoke(main, ["maneuvers", "cube", "--from", "a:0", "--step", "0"])
    assert r.exit_code == 2 and "--step" in r.output


@pytest.mark.skipif(not (REAL / "7_8ths_cube.stl").is_file(),
                    reason=f"real meshes not found at {REAL} (shared/ beside the repo)")
def test_a_real_mesh_lands_within_its_own_tolerance(tmp_path: Path) -> None:
    pytest.importorskip("trimesh")
    poly = nph.from_mesh(REAL / "7_8ths_cube.stl", units="mm")
    start = nph.State(nph.stable_faces(poly)[0], 0.0)
    rolls = [o for o in nph.maneuvers_from(poly, start) if o.maneuver.kind == "rolling"]
    assert len(rolls) == poly.n_edges(start.face)  # none refused as "no face points down"
    assert all(not str(o.maneuver.end).endswith(":360") for o in rolls)


def test_a_wrong_final_state_is_refused_with_the_right_one(tmp_path: Path) -> None:
    doc = {"object": "cube", "skills": [{
        "name": "r", "initial": {"face": "a", "theta": 0}, "final": {"face": "d", "theta": 45},
        "maneuver": "rolling",
        "events": [{"id": "rest", "contacts": ["(G,a)"]},
                   {"id": "touch", "contacts": ["(R1,f)", "(G,a)"]},
                   {"id": "done", "contacts": ["(G,d)"]}],
        "motions": [{"from": "rest", "to": "touch"}, {"from": "touch", "to": "done"}]}]}
    path = tmp_path / "skills.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(SkillError, match=r"onto face 'd' ends in d:0 \(rolling over E\(a,d\)\)"):
        read_skills(path)
    r = CliRunner().invoke(main, ["skills", "show", str(path)])
    assert r.exit_code == 2 and "write that final state" in r.output
    assert len(r.output.strip().splitlines()) == 1
    # no maneuver type given and no single maneuver: the message lists where they go
    doc["skills"][0]["final"] = {"face": "c", "theta": 45}
    del doc["skills"][0]["maneuver"]
    path.write_text(json.dumps(doc))
    with pytest.raises(SkillError, match=r"no maneuver from a:0 lands on face 'c'; it reaches "):
        read_skills(path)
