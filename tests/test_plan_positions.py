"""The plan tracks the object's pose through every step (issue 9, item 1).

Rolling and tumbling move the object across the table. Each step's reference finger motion
must be placed where the object is at the start of that step: at every step's first finger
contact, the reference fingertip must touch the contacted element of the object in its
tracked pose. Before the fix every step used the plan-wide offset, and step 2 of the main
job's plan missed its face by about 50 mm.
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from numpy.typing import NDArray

from nonprehensile.cli import main
from nonprehensile.demonstrations.segment import segment_dataset
from nonprehensile.demonstrations.synth import synthesize_dataset
from nonprehensile.inference import expand
from nonprehensile.io import load_model
from nonprehensile.pipeline import (
    DEFAULT_GOAL,
    DEFAULT_POSITION,
    DEFAULT_START,
    write_plan_motions,
)
from nonprehensile.planning import Plan, plan
from nonprehensile.references import ClusteredMotions, flatten_segments
from nonprehensile.skills.contacts import Edge, Face, Finger, Vertex
from nonprehensile.states import state_pose, states_by_step

FloatArray = NDArray[np.float64]
SKILLS = Path(__file__).resolve().parents[1] / "examples" / "cube_skills.json"


@pytest.fixture(scope="module")
def main_plan() -> Plan:
    ds = synthesize_dataset(seed=3, n_per_skill=3)
    _, segments = segment_dataset(ds)
    x = flatten_segments(segments, n_points=50)
    library = ClusteredMotions(segments, np.zeros(len(segments), dtype=np.int64), x)
    exp = expand(ds.poly, list(ds.skills), states_by_step(ds.poly, 90))
    return plan(ds.poly, exp, DEFAULT_START, DEFAULT_GOAL, position=DEFAULT_POSITION,
                motions=library, scale=ds.scale)


def _dist_to_element(p: FloatArray, pts: FloatArray, normal: FloatArray | None) -> float:
    """Distance from ``p`` to a vertex (1 point), an edge (2) or a convex face polygon."""
    def seg(a: FloatArray, b: FloatArray) -> float:
        s = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
        return float(np.linalg.norm(p - (a + s * (b - a))))

    if len(pts) == 1:
        return float(np.linalg.norm(p - pts[0]))
    if len(pts) == 2:
        return seg(pts[0], pts[1])
    assert normal is not None
    foot = p - ((p - pts[0]) @ normal) * normal
    e = np.roll(pts, -1, axis=0) - pts
    side = np.cross(e, foot - pts) @ normal
    ref = np.cross(e, pts.mean(axis=0) - pts) @ normal
    if np.all(side * ref >= -1e-12):
        return float(abs((p - pts[0]) @ normal))
    return min(seg(a, b) for a, b in zip(pts, np.roll(pts, -1, axis=0), strict=True))


def test_reference_fingertip_touches_the_tracked_object_at_first_contact(
        main_plan: Plan) -> None:
    cube = load_model("cube")
    assert len(main_plan.steps) >= 2
    fingers = {1: "index_tip", 2: "thumb_tip"}
    for k, step in enumerate(main_plan.steps):
        skill = step.transition.skill
        assert step.start_pose is not None
        i = next(i for i, e in enumerate(skill.events)
                 if any(isinstance(p.x, Finger) for p in e.pairs))
        _, _, _, ref = step.motions[i - 1]  # the arc that ends at the first contact
        assert ref is not None
        for pair in skill.events[i].pairs:
            if not isinstance(pair.x, Finger):
                continue
            el = pair.y
            tip = ref.positions[-1, ref.marker_names.index(fingers[pair.x.index])]
            if isinstance(el, Face):
                idx = list(cube.faces[el.id])
                normal = step.start_pose.rotation @ cube.normals[el.id]
            else:
                assert isinstance(el, (Edge, Vertex))
                idx = [j for j, fs in enumerate(cube.vertex_faces) if el.faces <= fs]
                normal = None
            pts = step.start_pose.to_world(cube.vertices[idx])
            d = _dist_to_element(tip, pts, normal)
            assert d < 0.004, f"step {k + 1}: fingertip {d * 1000:.1f} mm from {el}"


def test_tracked_poses_are_exact_and_chained(main_plan: Plan) -> None:
    cube = load_model("cube")
    first = main_plan.steps[0].start_pose
    assert first is not None
    assert np.allclose(first.position, DEFAULT_POSITION)
    for a, b in itertools.pairwise(main_plan.steps):
        assert a.end_pose is not None and b.start_pose is not None
        assert np.allclose(a.end_pose.com, b.start_pose.com)
    for step in main_plan.steps:
        assert step.start_pose is not None and step.end_pose is not None
        for pose, state in ((step.start_pose, step.start_world),
                            (step.end_pose, step.end_world)):
            # the state's orientation, resting on the table
            assert np.allclose(pose.rotation, state_pose(cube, state)[0], atol=1e-9)
            assert abs(pose.to_world(cube.vertices)[:, 2].min()) < 1e-12
        moved = math.dist(step.start_pose.position, step.end_pose.position)
        if step.transition.skill.maneuver == "rolling":
            assert moved == pytest.approx(0.05)  # a 5 cm cube rolls by its edge length
        elif step.transition.skill.maneuver == "rotating":
            assert moved == pytest.approx(0.0, abs=1e-12)
        else:
            assert moved > 0.01


def test_plan_json_and_out_carry_the_poses(tmp_path: Path) -> None:
    runner = CliRunner()
    res = runner.invoke(main, ["plan", str(SKILLS), "--from", "a:0", "--to", "c:0",
                               "--step", "90", "--at", "0.3", "0.1", "--json"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    steps = doc["steps"]
    assert steps[0]["pose"]["from"]["position"] == pytest.approx([0.3, 0.1])
    for a, b in itertools.pairwise(steps):
        assert a["pose"]["to"]["com"] == pytest.approx(b["pose"]["from"]["com"])
    q = steps[-1]["pose"]["to"]["quaternion_wxyz"]
    assert sum(v * v for v in q) == pytest.approx(1.0)


def test_plan_out_writes_the_poses(main_plan: Plan, tmp_path: Path) -> None:
    written = write_plan_motions(main_plan, tmp_path)
    assert tmp_path / "plan.json" in written
    doc = json.loads((tmp_path / "plan.json").read_text())
    assert len(doc["steps"]) == len(main_plan.steps)
    last = main_plan.steps[-1].end_pose
    assert last is not None
    assert doc["steps"][-1]["pose"]["to"]["com"] == pytest.approx(last.com.tolist())
