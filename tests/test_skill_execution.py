"""Skill-specific execution in the controller (pure core, no simulator): a corner pivot's
anchor, a higher contact on a face that leans back, the follow-through of a tipping arc.

The truths are geometric and computed here by hand (rotations about known axes, the
hexagon's own dimensions), not by the functions under test.
"""

from __future__ import annotations

import math
import os
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nonprehensile.control import (
    ArcSpec,
    ControlConfig,
    StepMonitor,
    StepSpec,
    anchor_transform,
    raised,
)
from nonprehensile.geometry.build import cube
from nonprehensile.io import read_skills
from nonprehensile.observation import Observation
from nonprehensile.planning import ObjectPose
from nonprehensile.skills.contacts import Edge, Face, Finger, Ground, Vertex
from nonprehensile.states import State, state_pose

CUBE = cube()
SCALE = 0.05
EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples")


def _pose(poly, state: State, scale: float) -> ObjectPose:  # type: ignore[no-untyped-def]
    r, t = state_pose(poly, state)
    return ObjectPose(r, scale * t, scale * (r @ poly.com) + scale * t, scale)


def _turned(pose: ObjectPose, q: Rotation, about: np.ndarray) -> ObjectPose:
    """``pose`` turned by ``q`` about the world point ``about``."""
    m = q.as_matrix()
    return ObjectPose(m @ pose.rotation, m @ (pose.translation - about) + about,
                      m @ (pose.com - about) + about, pose.scale)


def _corner_tilt(pose: ObjectPose, edge: frozenset[str], deg: float) -> ObjectPose:
    """The cube tipped by ``deg`` about its bottom edge ``edge`` (the sense that keeps it
    above the table)."""
    i, j = CUBE.edges[edge]
    a, b = pose.to_world(CUBE.vertices[[i, j]])
    axis = (b - a) / np.linalg.norm(b - a)
    for sign in (1.0, -1.0):
        out = _turned(pose, Rotation.from_rotvec(sign * math.radians(deg) * axis), a)
        if out.to_world(CUBE.vertices)[:, 2].min() >= -1e-9:
            return out
    raise AssertionError("no sense keeps the cube above the table")  # pragma: no cover


def test_a_corner_anchor_keeps_the_turn_it_is_given() -> None:
    predicted = _pose(CUBE, State("a", 0.0), SCALE)
    corner = Vertex(frozenset({"a", "b", "d"}))
    k = CUBE.shared_vertices(corner.faces)[0]
    p0 = predicted.to_world(CUBE.vertices[k])
    # tipped onto the corner, twisted 20 degrees about the vertical through it, slid 3 mm
    tilt = Rotation.from_rotvec(math.radians(25.0) * np.array([1.0, -1.0, 0.0]) / math.sqrt(2))
    twist = Rotation.from_euler("z", 20.0, degrees=True)
    observed = _turned(predicted, twist * tilt, p0)
    slide = np.array([0.003, -0.001, 0.0])
    observed = ObjectPose(observed.rotation, observed.translation + slide,
                          observed.com + slide, SCALE)
    p1 = observed.to_world(CUBE.vertices[k])
    given = math.radians(4.0)
    tf = anchor_transform(CUBE, corner, predicted, observed, yaw=given)
    assert tf.yaw == pytest.approx(given)
    np.testing.assert_allclose(tf.apply(p0[None])[0, :2], p1[:2], atol=1e-12)
    # without a given turn the fit reads the tilted rotation's vertical part, not 4 degrees
    free = anchor_transform(CUBE, corner, predicted, observed)
    assert abs(math.degrees(free.yaw) - 4.0) > 10.0


def _one_finger_spec(poly, pose: ObjectPose, face: str, centre: np.ndarray,  # type: ignore[no-untyped-def]
                     ground: str) -> StepSpec:
    rest, touch = "rest", "touch"
    ev0 = frozenset({_pair(Ground(), Face(ground))})
    ev1 = frozenset({_pair(Finger(1), Face(face)), _pair(Ground(), Face(ground))})
    approach = np.stack([centre + np.array([0.0, 0.0, 0.02]), centre])[:, None, :]
    arcs = (ArcSpec(rest, touch, approach, Face(ground), False, seeks=True, tips=False),)
    return StepSpec(None, (1,), 120.0, arcs, (ev0, ev1), (rest, touch),  # type: ignore[arg-type]
                    (Face(ground), Face(ground)), pose, pose, {1: approach[:, 0]})


def _pair(x, y):  # type: ignore[no-untyped-def]
    from nonprehensile.skills.contacts import ContactPair

    return ContactPair(x, y)


def test_raised_on_a_vertical_face_touches_below_the_top() -> None:
    pose = _pose(CUBE, State("a", 0.0), SCALE)
    radius = 0.008
    # a pad touching face e (normal -x) at mid-height
    centre = np.array([-0.025 - radius, 0.0, 0.025])
    up = raised(_one_finger_spec(CUBE, pose, "e", centre, "a"), CUBE, radius)
    assert up.arcs[0].positions[-1, 0] == pytest.approx(
        [centre[0], centre[1], 0.05 - radius - 0.002])


def test_raised_on_a_face_that_leans_back_moves_up_the_face() -> None:
    poly, _ = read_skills(os.path.join(EXAMPLES, "hexprism_skills.json"))
    s = 0.01  # the model is in cm
    pose = _pose(poly, State("b", 0.0), s)
    side = 0.025  # the hexagon's side: 2.5 cm
    top = math.sqrt(3.0) * side  # lying on a side face, the opposite one is this high
    world = pose.to_world(poly.vertices)
    assert world[:, 2].max() == pytest.approx(top)
    # an upper side face leans back by 30 degrees from the vertical
    face = next(f for f in poly.face_ids
                if (pose.rotation @ poly.normals[f])[2] == pytest.approx(0.5))
    n = pose.rotation @ poly.normals[face]
    corners = pose.to_world(poly.vertices[list(poly.faces[face])])
    radius = 0.009
    contact = corners.mean(axis=0)  # the face's middle, at three quarters of the height
    assert contact[2] == pytest.approx(0.75 * top)
    centre = contact + radius * n
    up = raised(_one_finger_spec(poly, pose, face, centre, "b"), poly, radius)
    moved = up.arcs[0].positions[-1, 0]
    # still touching the face's plane, now 4 mm (along the 60-degree slope) below its top
    assert float(n @ (moved - corners[0])) == pytest.approx(radius)
    foot = moved - radius * n
    assert foot[2] == pytest.approx(top - 0.004 * math.sin(math.radians(60.0)))
    # moved along the slope only: the prism's axis coordinate is kept
    axis = np.cross(n, [0.0, 0.0, 1.0])
    assert float(axis @ (moved - centre)) == pytest.approx(0.0, abs=1e-12)


def _tipping_monitor(cfg: ControlConfig) -> tuple[StepMonitor, ObjectPose]:
    start = _pose(CUBE, State("a", 0.0), SCALE)
    edge = frozenset({"a", "d"})
    pivot = frozenset({_pair(Ground(), Edge(edge))})
    landed = frozenset({_pair(Ground(), Face("d"))})
    # a push toward +y (face d's side), 1 mm a frame
    path = np.array([[[0.0, -0.042, 0.04]], [[0.0, -0.041, 0.04]], [[0.0, -0.04, 0.04]]])
    arcs = (ArcSpec("pivot", "landed", path, Edge(edge), False, seeks=False, tips=True),)
    step = SimpleNamespace(transition=SimpleNamespace(start=State("a", 0.0),
                                                      end=State("d", 0.0)))
    spec = StepSpec(step, (1,), 120.0, arcs, (pivot, landed), ("pivot", "landed"),  # type: ignore[arg-type]
                    (Edge(edge), Face("d")), start, start, {1: path[:, 0]})
    mon = StepMonitor(CUBE, spec, cfg, dt=0.002, finger_radius=0.008,
                      rest=np.array([[0.0, 0.0, 0.3]]))
    return mon, _corner_tilt(start, edge, 20.0)


def test_a_tipping_arc_short_of_landing_follows_through_about_its_pivot() -> None:
    cfg = ControlConfig()
    mon, tilted = _tipping_monitor(cfg)
    far = np.array([[0.0, 0.0, 0.4]])  # the fingertip off the object: the edge alone
    command = np.array([[0.01, -0.03, 0.045]])
    mon.begin(Observation(0.0, tilted, far), command)
    assert mon.current == mon.spec.events[0]
    dec = mon.update(Observation(0.1, tilted, far), command)  # past the arc's 17 ms
    assert dec.segment is not None and not dec.done
    path = dec.segment[:, 0]
    i, j = CUBE.edges[frozenset({"a", "d"})]
    a, b = tilted.to_world(CUBE.vertices[[i, j]])
    u = (b - a) / np.linalg.norm(b - a)

    def radial(p: np.ndarray) -> np.ndarray:
        r = p - a
        return r - (r @ u) * u

    # a turn about the edge: the distance to it kept, the position along it kept
    np.testing.assert_allclose(np.linalg.norm([radial(p) for p in path], axis=1),
                               np.linalg.norm(radial(command[0])), atol=1e-9)
    np.testing.assert_allclose((path - a) @ u, (command[0] - a) @ u, atol=1e-9)
    r0, r1 = radial(path[0]), radial(path[-1])
    angle = math.degrees(math.atan2(float(np.cross(r0, r1) @ u), float(r0 @ r1)))
    assert abs(angle) == pytest.approx(cfg.follow_deg, abs=1e-6)
    # in the sense that takes the landing face d down onto the table
    n_d = tilted.rotation @ CUBE.normals["d"]
    turned = Rotation.from_rotvec(math.radians(angle) * u).apply(n_d)
    assert turned[2] < n_d[2] - 0.1
    # once per arc: the next observation asks for nothing new
    assert mon.update(Observation(0.12, tilted, far), path[-1][None]).segment is None


def test_no_follow_through_when_switched_off_or_not_on_a_pivot() -> None:
    mon, tilted = _tipping_monitor(ControlConfig(follow_deg=0.0))
    far = np.array([[0.0, 0.0, 0.4]])
    command = np.array([[0.01, -0.03, 0.045]])
    mon.begin(Observation(0.0, tilted, far), command)
    assert mon.update(Observation(0.1, tilted, far), command).segment is None
    # flat on its start face (it has not tipped yet): no turn about a pivot, the push goes
    # on along its last direction, slowly and for a bounded length
    cfg = ControlConfig()
    mon, _ = _tipping_monitor(cfg)
    flat = _pose(CUBE, State("a", 0.0), SCALE)
    command = mon.spec.arcs[0].positions[0]  # on the reference: no blend into it
    mon.begin(Observation(0.0, flat, far), command)
    dec = mon.update(Observation(0.1, flat, far), command)
    assert dec.segment is not None
    step = dec.segment[-1, 0] - dec.segment[0, 0]
    np.testing.assert_allclose(step / np.linalg.norm(step), [0.0, 1.0, 0.0], atol=1e-9)
    assert float(np.linalg.norm(step)) == pytest.approx(cfg.reach, rel=0.02)
    speed = np.linalg.norm(np.diff(dec.segment[:, 0], axis=0), axis=1) / 0.002
    assert float(speed.max()) <= cfg.reach_speed + 1e-9
