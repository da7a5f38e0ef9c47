"""The recorded finger direction (issue 22, item 3): the references' knuckle markers give
each finger's direction, the controller turns it as it anchors the reference, and a robot's
IK points its finger tool along it (``finger_direction="recorded"``).

The truths are the references' own marker arrays (knuckle to tip, read here by index), the
anchor's turn about the vertical, and MuJoCo's pose of the arm's tool site.
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from nonprehensile.step_paths import knuckle_marker, step_directions, step_targets

SKILLS = str(Path(__file__).resolve().parents[1] / "src/nonprehensile/data/cube_skills.json")

_NAME = st.text(alphabet="abcdefghij_", min_size=0, max_size=8)


@given(stem=_NAME, others=st.lists(_NAME, max_size=4), has=st.booleans())
def test_knuckle_marker_is_the_tip_name_with_knuckle(stem: str, others: list[str],
                                                     has: bool) -> None:
    names = [*others, stem + "_tip"] + ([stem + "_knuckle"] if has else [])
    got = knuckle_marker(stem + "_tip", names)
    assert got == (stem + "_knuckle" if has else None)
    # a marker not named ``*_tip`` has no knuckle by the rule
    assert knuckle_marker(stem + "_pad", [*names, stem + "_pad_knuckle"]) is None


@functools.cache
def _main_step():  # type: ignore[no-untyped-def]
    """The planner's first step of the main job (a push-roll with the bundled references,
    which carry the index and thumb knuckles)."""
    from nonprehensile.cli.options import state_set
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.states import State

    poly, skills = read_skills(SKILLS)
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    p = plan(poly, exp, State("b", 200), State("a", 290), position=(0.3, 0.1),
             motions=motions, scale=ds.scale)
    return poly, ds, p


@pytest.fixture()
def main_step():  # type: ignore[no-untyped-def]
    return _main_step()


def test_step_directions_are_the_references_knuckle_to_tip(main_step) -> None:  # type: ignore[no-untyped-def]
    _, ds, p = main_step
    step = p.steps[0]
    dirs = step_directions(step, ds.fingers, smooth=1)
    targets, _, _ = step_targets(step, ds.fingers, smooth=1)
    assert set(dirs) == set(targets) == {1}
    # by hand: each arc's tip minus knuckle columns, the shared boundary frames once
    rows = []
    for i, (_, _, _, ref) in enumerate(step.motions):
        names = list(ref.marker_names)
        d = ref.positions[:, names.index("index_tip")] - \
            ref.positions[:, names.index("index_knuckle")]
        rows.append(d if i == 0 else d[1:])
    want = np.concatenate(rows)
    want /= np.linalg.norm(want, axis=1)[:, None]
    assert dirs[1].shape == targets[1].shape == want.shape
    np.testing.assert_allclose(dirs[1], want, atol=1e-12)
    # filtered as the targets are, and still unit vectors
    smooth = step_directions(step, ds.fingers)[1]
    np.testing.assert_allclose(np.linalg.norm(smooth, axis=1), 1.0, atol=1e-12)
    # the bundled pushes point down and along the push: the finger leans 30-45 degrees
    spec_tilt = np.degrees(np.arccos(-smooth[:, 2]))
    assert 25.0 < float(np.median(spec_tilt)) < 45.0
    # references without knuckle markers: no direction
    assert step_directions(step, {"R1": "index_pad"}) == {}


@settings(max_examples=20, deadline=None)
@given(yaw=st.floats(-20.0, 20.0), dx=st.floats(-0.01, 0.01), dy=st.floats(-0.01, 0.01))
def test_the_monitor_turns_the_directions_as_it_anchors_the_reference(
        yaw: float, dx: float, dy: float) -> None:
    """Observed turned by ``yaw`` about the vertical and shifted, the object gets its
    reference turned and shifted (``anchor_transform``, the truth here): the direction
    :meth:`StepMonitor.pointing` gives at a time is the recorded one of the reference frame
    the segment it emitted reaches at that time, turned by the same yaw."""
    from nonprehensile.control import ControlConfig, StepMonitor, anchor_transform, step_spec
    from nonprehensile.observation import Observation
    from nonprehensile.planning import ObjectPose

    poly, ds, p = _main_step()
    spec = step_spec(poly, p.steps[0], ds.fingers)
    for a in spec.arcs:  # frame by frame with the positions (their stops included)
        assert a.directions is not None and a.directions.shape == a.positions.shape
    arc = spec.arcs[0]
    s0 = spec.start_pose
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    com = s0.com + np.array([dx, dy, 0.0])
    turned = ObjectPose(rz @ s0.rotation, rz @ (s0.translation - s0.com) + com, com,
                        s0.scale)
    tf = anchor_transform(poly, arc.anchor, s0, turned)
    assert abs(tf.yaw - math.radians(yaw)) < 1e-6  # the anchor reads the turn
    c, s = math.cos(tf.yaw), math.sin(tf.yaw)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    placed = tf.apply(arc.positions)  # (n, 1, 3)
    # the fingertips commanded where the placed reference starts: the segment is the
    # placed reference itself, at 4 physics steps a reference frame
    tips = np.array([placed[0, 0], [0.1, 0.0, 0.5]])
    dt = 1.0 / (4.0 * spec.rate)
    mon = StepMonitor(poly, spec, ControlConfig(), dt=dt, finger_radius=0.006, rest=tips)
    t0 = 2.0
    seg = mon.begin(Observation(t0, turned, tips), tips).segment
    assert seg is not None
    for k in (0, len(arc.positions) // 3, len(arc.positions) - 1):
        np.testing.assert_allclose(seg[4 * k, 0], placed[k, 0], atol=1e-9)
        got = mon.pointing(t0 + k / spec.rate)
        assert got is not None and got.shape == (2, 3)
        np.testing.assert_allclose(got[0], rz @ arc.directions[k, 0], atol=1e-9)
        assert not got[1].any()  # R2 is not used by a push-roll
    # past the arc's end, its last direction
    late = mon.pointing(1e3)
    assert late is not None
    np.testing.assert_allclose(late[0], rz @ arc.directions[-1, 0], atol=1e-9)


def test_an_arc_refuses_directions_that_are_not_frame_by_frame(main_step) -> None:  # type: ignore[no-untyped-def]
    from dataclasses import replace

    from nonprehensile.control import step_spec
    from nonprehensile.errors import InputError

    poly, ds, p = main_step
    arc = step_spec(poly, p.steps[0], ds.fingers).arcs[0]
    with pytest.raises(InputError, match="frame by frame with its positions"):
        replace(arc, positions=arc.positions[:-1])
    assert replace(arc, positions=arc.positions[:-1], directions=None).directions is None


# ------------------------------------------------------------------------------- robot
if not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")


def _robot():  # type: ignore[no-untyped-def]
    pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")
    pytest.importorskip("mink", reason="the robot extra (mink) is not installed: "
                                       "pip install 'nonprehensile[robot]'")


def test_ik_points_given_fingers_along_their_directions() -> None:
    _robot()
    from nonprehensile.geometry.build import cube
    from nonprehensile.sim.ik import FingertipIK
    from nonprehensile.sim.robot import BasePose, Robot
    from nonprehensile.sim.robot_scene import Arm, build_robot_scene

    arms = [Arm(Robot.builtin(), BasePose(0.5, 0.0, 180.0)),
            Arm(Robot.builtin(), BasePose(-0.5, 0.0, 0.0))]
    scene = build_robot_scene(cube(), scale=0.05, arms=arms, mocap_object=True)
    ik = FingertipIK(scene, 0.01)
    targets = np.array([[0.04, 0.0, 0.02], [-0.04, 0.0, 0.02]])
    lean = ik.lean(targets)
    np.testing.assert_array_equal(ik.pointing(targets), lean)
    d = np.array([[-0.5, 0.0, -1.0], [0.0, 0.0, 0.0]])  # finger 2: no direction given
    ik.set_pointing(d)
    got = ik.pointing(targets)
    np.testing.assert_allclose(got[0], d[0] / np.linalg.norm(d[0]))
    np.testing.assert_array_equal(got[1], lean[1])
    ik.set_pointing(None)
    np.testing.assert_array_equal(ik.pointing(targets), lean)
    # a new start forgets them
    ik.set_pointing(d)
    ik.reset(scene.home)
    np.testing.assert_array_equal(ik.pointing(targets), ik.lean(targets))
    # one row per finger, finite, or one line saying so
    from nonprehensile.errors import InputError

    for bad in (d[:1], np.zeros((3, 3)), np.full((2, 3), np.nan), np.zeros(6)):
        with pytest.raises(InputError, match=r"set_pointing takes finite directions of shape "
                                             r"\(2, 3\)"):
            ik.set_pointing(bad)


def _tool_angles(main_step, mode: str) -> tuple[bool, np.ndarray]:  # type: ignore[no-untyped-def]
    """The main plan's first step by the Panda, closed loop, with ``finger_direction``
    ``mode``: at every observation of the step, the angle (degrees) between the tool's axis
    as MuJoCo poses it (the tip site's z, flange to tip) and the recorded direction the
    controller hands over."""
    from nonprehensile.sim.closed_loop import execute_plan
    from nonprehensile.sim.robot import BasePose, Robot
    from nonprehensile.sim.robot_run import RobotSimulator, robot_control
    from nonprehensile.sim.robot_scene import Arm

    poly, ds, p = main_step
    # the closed loop hands the directions over only to a driver that follows them: the
    # driver says it does, and with ``mode`` "lean" the IK is then given none of them
    sim = RobotSimulator(poly, [Arm(Robot.builtin(), BasePose(0.53, -0.51, 112.5))],
                         scale=ds.scale, finger_direction="recorded")
    site = int(sim.scene.tip_sites[0])
    angles: list[float] = []
    handed = sim.driver.point

    def point(d: np.ndarray | None) -> None:
        if d is not None:
            z = sim.data.site_xmat[site].reshape(3, 3)[:, 2]
            angles.append(math.degrees(math.acos(min(1.0, max(-1.0, float(z @ d[0]))))))
        handed(d if mode == "recorded" else None)

    sim.driver.point = point  # type: ignore[method-assign]
    ex = execute_plan(sim, p, fingers=ds.fingers, config=robot_control(n_fingers=1))
    return ex.success, np.array(angles)


def test_the_robots_finger_tool_points_as_the_recorded_finger(main_step) -> None:  # type: ignore[no-untyped-def]
    """Recorded: the tool's axis follows the recorded direction (within its bounded turn
    rate: median 10 degrees over the step, measured); the geometric lean does not (32
    degrees), so the measure tells the two apart. Both reach the predicted state."""
    _robot()
    ok, rec = _tool_angles(main_step, "recorded")
    ok_lean, lean = _tool_angles(main_step, "lean")
    assert ok and ok_lean
    assert len(rec) > 100 and len(lean) > 100
    assert float(np.median(rec)) < 15.0, np.median(rec)
    assert float(np.median(lean)) > 20.0, np.median(lean)


def test_a_step_that_raises_leaves_no_recorded_direction_behind(main_step, monkeypatch
                                                               ) -> None:  # type: ignore[no-untyped-def]
    """A sweep's worker catches an executor's exception and runs its next sample on the
    same robot: the directions handed over in the failed step must not steer it."""
    _robot()
    from nonprehensile.control import StepMonitor
    from nonprehensile.sim.closed_loop import execute_plan
    from nonprehensile.sim.robot import BasePose, Robot
    from nonprehensile.sim.robot_run import RobotSimulator, robot_control
    from nonprehensile.sim.robot_scene import Arm

    poly, ds, p = main_step
    sim = RobotSimulator(poly, [Arm(Robot.builtin(), BasePose(0.53, -0.51, 112.5))],
                         scale=ds.scale, finger_direction="recorded")
    update = StepMonitor.update
    seen: list[bool] = []

    def failing(self, obs, command):  # type: ignore[no-untyped-def]
        seen.append(sim.driver.ik._override is not None)
        if len(seen) > 20:
            raise RuntimeError("an executor's bug")
        return update(self, obs, command)

    monkeypatch.setattr(StepMonitor, "update", failing)
    with pytest.raises(RuntimeError, match="an executor's bug"):
        execute_plan(sim, p, fingers=ds.fingers, config=robot_control(n_fingers=1))
    assert any(seen)  # the step did point along the recorded finger ...
    assert sim.driver.ik._override is None  # ... and nothing of it is left


def test_finger_direction_is_checked_and_reported() -> None:
    _robot()
    from nonprehensile.errors import InputError
    from nonprehensile.geometry.build import cube
    from nonprehensile.sim.robot import BasePose, Robot
    from nonprehensile.sim.robot_run import RobotSimulator
    from nonprehensile.sim.robot_scene import Arm
    from nonprehensile.sim.robustness import SweepRobot

    arm = Arm(Robot.builtin(), BasePose(0.53, -0.51, 112.5))
    for bad in ("down", "", None, 1, True):
        with pytest.raises(InputError, match="finger_direction is one of"):
            RobotSimulator(cube(), [arm], scale=0.05, finger_direction=bad)  # type: ignore[arg-type]
        with pytest.raises(InputError, match="finger_direction is one of"):
            SweepRobot((arm,), finger_direction=bad)  # type: ignore[arg-type]
    sim = RobotSimulator(cube(), [arm], scale=0.05, finger_direction="recorded")
    assert sim.describe()["finger_command"]["finger_direction"] == "recorded"
    assert SweepRobot((arm,)).to_dict()["finger_direction"] == "lean"


def test_cli_finger_direction() -> None:
    """`simulate plan --robot panda --finger-direction recorded` runs and says so; without a
    robot, or with another value, one line and exit 2."""
    _robot()
    import json

    from click.testing import CliRunner

    from nonprehensile.cli import main

    args = ["simulate", "plan", SKILLS, "--from", "b:200", "--at", "0.3", "0.1", "--to",
            "a:290", "--step", "90", "--dataset", "cube"]
    res = CliRunner().invoke(main, [*args, "--robot", "panda", "--base", "0.53", "-0.51",
                                    "112.5", "--finger-direction", "recorded", "--json"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["success"]
    assert doc["robot"]["finger_command"]["finger_direction"] == "recorded"
    for bad, why in ((["--finger-direction", "recorded"], "give --robot NAME"),
                     (["--robot", "panda", "--finger-direction", "up"], "'up' is not one of")):
        res = CliRunner().invoke(main, [*args, *bad])
        assert res.exit_code == 2, res.output
        assert why in res.stderr
