"""A hexagonal prism's one-finger roll (push-roll) done from its top face
(:func:`nonprehensile.control.top_roll`), and the slides across on its leaning faces
(:func:`nonprehensile.control.correction_pushes`): geometry against the prism's own
construction, and one configuration of the physics distribution that failed before."""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

from nonprehensile.control import (
    ControlConfig,
    correction_pushes,
    raised,
    step_spec,
    top_roll,
)
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.planning import ObjectPose
from nonprehensile.skills.contacts import Face, Finger
from nonprehensile.states import State, state_pose, states_by_step

if not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
mujoco = pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")

from nonprehensile.pipeline import motions_from_dataset  # noqa: E402
from nonprehensile.planning import plan  # noqa: E402
from nonprehensile.sim import Simulator, closed_loop  # noqa: E402
from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION  # noqa: E402
from nonprehensile.sim.record import record_dataset, write_recorded  # noqa: E402

HEX_SKILLS = Path(__file__).resolve().parents[1] / "examples" / "hexprism_skills.json"
CUBE_SKILLS = Path(__file__).resolve().parents[1] / "examples" / "cube_skills.json"
SIDE = 0.025  # the hexagon's side (the model is in cm)
TOP = math.sqrt(3.0) * SIDE  # lying on a side face, the opposite one is this high


@pytest.fixture(scope="module")
def prism():  # type: ignore[no-untyped-def]
    """The prism, one recorded push-roll take, its expansion and scale."""
    poly, skills = read_skills(HEX_SKILLS)
    ds, _ = record_dataset(HEX_SKILLS, n_per_skill=1, only=["push-roll"], seed=5)
    with tempfile.TemporaryDirectory() as tmp:
        write_recorded(ds, tmp, "c3d")
        ds2, motions = motions_from_dataset(tmp, skills=skills, poly=poly, cache=False)
    exp = expand(poly, skills, states_by_step(poly, 90))
    return poly, exp, motions, ds2


def _roll_plan(prism, start: State, goal: State):  # type: ignore[no-untyped-def]
    poly, exp, motions, ds = prism
    return plan(poly, exp, start, goal, motions=motions, scale=ds.scale)


def test_top_roll_presses_the_top_face_above_the_pivot_and_turns_about_it(prism) -> None:  # type: ignore[no-untyped-def]
    poly, _, _, ds = prism
    radius = 0.008
    p = _roll_plan(prism, State("b", 0.0), State("c", 0.0))
    spec = step_spec(poly, p.steps[0], ds.fingers)
    rolled = top_roll(spec, poly, radius, inset=0.005, press=0.006, roll_deg=40.0)
    # the recorded fingers' directions belong to the recorded push, not to the roll made
    # up here: a robot's finger tool keeps its own rule (docs/robot.md)
    assert all(a.directions is not None for a in spec.arcs)
    assert all(a.directions is None for a in rolled.arcs)
    pose = spec.start_pose
    top = next(f for f in poly.face_ids if (pose.rotation @ poly.normals[f])[2] > 0.99)
    # the pivot: the bottom edge shared with the landing face c
    i, j = poly.edges[frozenset({"b", "c"})]
    a, b = pose.to_world(poly.vertices[[i, j]])
    assert a[2] == pytest.approx(0.0, abs=1e-9) and b[2] == pytest.approx(0.0, abs=1e-9)
    toward = (a + b) / 2 - pose.com
    toward[2] = 0.0
    toward /= np.linalg.norm(toward)
    # the approach ends touching the top face, 5 mm in from its edge above the pivot (the
    # top face's edge on that side is right above the pivot edge: a hexagon's top and
    # bottom sides are equally long and stacked)
    touch = rolled.arcs[0].positions[-1, 0]
    # (coming to rest carries the pad on by a third of its speed times 0.1 s: 1 mm)
    assert TOP + radius - 0.0011 <= touch[2] <= TOP + radius
    assert float((touch - (a + b) / 2) @ toward) == pytest.approx(-0.005, abs=1e-6)
    # the push presses 6 mm down, then drags toward the pivot side, horizontally
    push = rolled.arcs[1].positions[:, 0]
    assert push[:, 2].min() == pytest.approx(TOP + radius - 0.006, abs=1e-6)
    assert float((push[-1] - push[0]) @ toward) > 0.02
    # the roll turns the touching point 40 degrees about the pivot edge toward c, pressed
    # by 6 mm down and toward the pivot side (45 degrees) in the world
    lead = 0.006 * (np.array([0.0, 0.0, -1.0]) + toward) / math.sqrt(2.0)
    roll = rolled.arcs[2].positions[:, 0] - lead
    u = (b - a) / np.linalg.norm(b - a)

    def radial(q: np.ndarray) -> np.ndarray:
        r = q - a
        return np.asarray(r - (r @ u) * u)

    r0, r1 = radial(roll[0]), radial(roll[-1])
    assert roll[0] == pytest.approx([touch[0], touch[1], TOP + radius], abs=1e-6)
    assert np.linalg.norm(r1) == pytest.approx(np.linalg.norm(r0), rel=1e-6)
    assert math.degrees(math.acos(float(r0 @ r1) / float(np.linalg.norm(r0)) ** 2)) \
        == pytest.approx(40.0, abs=0.5)
    assert float((roll[-1] - roll[0]) @ toward) > 0  # over toward the landing face
    # the step's events name the top face where the skill named the pushed one
    fingered = {el.id for ev in rolled.events for q in ev for el in (q.x, q.y)
                if isinstance(el, Face) and any(isinstance(o, Finger) for o in (q.x, q.y))}
    assert fingered == {top}
    # raised() is not a no-op on a face that leans back: it moves the push up the face
    assert raised(spec, poly, radius) is not spec


def test_a_cube_push_roll_keeps_its_recorded_push() -> None:
    """A cube's pushed faces are vertical: :func:`top_roll` leaves its step as recorded, and
    the closed loop's first attempt (:func:`one_finger_push`) is the recorded push itself."""
    from nonprehensile.control import one_finger_push

    poly, skills = read_skills(CUBE_SKILLS)
    exp = expand(poly, skills, states_by_step(poly, 90))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    pushes = [t for t in exp.transitions if t.source.name == "push-roll"]
    assert pushes
    t = pushes[0]
    p = plan(poly, exp, t.skill.initial, t.skill.final, motions=motions, scale=ds.scale)
    assert p.steps[0].transition.source.name == "push-roll"
    spec = step_spec(poly, p.steps[0], ds.fingers)
    assert top_roll(spec, poly, 0.008) is spec
    assert one_finger_push(spec, poly, 0.008) is spec
    assert one_finger_push(spec, poly, 0.008, higher=True) is not spec  # the raised retry


def test_correction_pushes_slide_a_prism_across_on_a_leaning_face() -> None:
    poly, _ = read_skills(HEX_SKILLS)
    r, t = state_pose(poly, State("b", 0.0))
    pose = ObjectPose(r, 0.01 * t, 0.01 * (r @ poly.com) + 0.01 * t, 0.01)
    radius, clearance = 0.008, 0.015
    # 12 mm across the prism's axis (its axis lies along a horizontal face normal's
    # perpendicular): only a leaning face can take it
    caps = [f for f in poly.face_ids if abs((pose.rotation @ poly.normals[f])[2]) < 0.1]
    axis = pose.rotation @ poly.normals[caps[0]]
    across = np.cross(axis, [0.0, 0.0, 1.0])[:2]
    goal = pose.com[:2] + 0.012 * across
    pushes = correction_pushes(poly, pose, (float(goal[0]), float(goal[1])),
                               finger_radius=radius, clearance=clearance, tol=0.003)
    assert len(pushes) == 1
    (push,) = pushes
    n = pose.rotation @ poly.normals[push.face]
    assert n[2] == pytest.approx(0.5)  # an upper side face, leaning back 30 degrees
    assert push.distance == pytest.approx(0.012, abs=1e-6)
    assert push.direction[:2] == pytest.approx(across, abs=1e-9)
    # the pad's start: clearance out, horizontally, from touching the face 2 mm above its
    # lowest edge (half the prism's height)
    foot = np.array([*(push.start[:2] - clearance * -push.direction[:2]), push.start[2]]) \
        - radius * n
    assert foot[2] == pytest.approx(TOP / 2 + 0.002, abs=1e-9)
    corner = pose.to_world(poly.vertices[list(poly.faces[push.face])])[0]
    assert float(n @ (foot - corner)) == pytest.approx(0.0, abs=1e-9)


def _old_push(spec, poly, finger_radius, *, higher=False):  # type: ignore[no-untyped-def]
    """The closed loop's push before the roll from the top: the recorded one, raised on a
    retry."""
    return raised(spec, poly, finger_radius) if higher else spec


def test_a_prism_rolls_on_a_slippery_table_that_the_recorded_push_slid_on(  # type: ignore[no-untyped-def]
        prism, monkeypatch) -> None:
    """Sample 3 of the sweep's unit 3 (c:180 -> b:180, seed 0): table friction 0.32,
    light (61 g), a 10.8 mm pad at 801 N/m. Before, the recorded push on the leaning face
    slid it every time (12 re-plans spent); from the top it rolls."""
    poly, _, _, ds = prism
    dist = DEFAULT_DISTRIBUTION.for_object(poly, ds.scale)
    sample = dist.sample(0, index=3, stream=3)
    assert sample.params.friction_table == pytest.approx(0.321, abs=1e-3)
    p = _roll_plan(prism, State("c", 180.0), State("b", 180.0))
    sim = Simulator(poly, scale=ds.scale, n_fingers=2, params=sample.params)

    def run() -> closed_loop.Execution:
        return closed_loop.execute_plan(sim, p, fingers=ds.fingers, loop="closed",
                                        config=ControlConfig(max_replans=2),
                                        perturbation=sample.perturbation)

    ex = run()
    assert ex.success, ex.reason
    assert not ex.replans
    monkeypatch.setattr(closed_loop, "one_finger_push", _old_push)
    before = run()
    assert not before.success
    assert "slides instead of tipping" in before.steps[0]["reason"] \
        or "not observed" in before.steps[0]["reason"]
