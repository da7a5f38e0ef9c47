"""States: the value type, poses, stability and state sets."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, strategies as st

from conftest import SOLIDS, random_hulls
from nonprehensile.errors import GeometryError, StateError
from nonprehensile.geometry import Polyhedron, convex_hull, cube
from nonprehensile.states import (
    MAX_STATES,
    State,
    _coarser,
    angle_diff,
    check_states,
    is_stable,
    stability_margin,
    stable_faces,
    state_of_pose,
    state_pose,
    states_by_step,
)


def test_state_normalises_and_parses() -> None:
    assert State("a", 360).theta == 0.0
    assert State("a", -90).theta == 270.0
    assert State("a", 359.9999999999999).theta == 0.0
    assert State.parse("d:90") == State("d", 90)
    assert State.parse(" top : -45 ") == State("top", 315)
    assert str(State("a", 90)) == "a:90"
    assert State.from_dict({"face": "a", "theta": 90}) == State("a", 90.0)
    assert State("a", 0.0000001).isclose(State("a", 359.9999999))
    assert angle_diff(10, 350) == pytest.approx(20)


@pytest.mark.parametrize("text", ["a", "a:", ":90", "a:ninety", "a:90:1"])
def test_bad_state_text(text: str) -> None:
    with pytest.raises(StateError, match="FACE:THETA"):
        State.parse(text)


@pytest.mark.parametrize("theta", ["1e300", "-1e7", "1000000"])
def test_parse_refuses_an_angle_past_a_million_degrees(theta: str) -> None:
    # reduced modulo 360 such an angle has lost its digits: State.parse("a:1e300") was a:0
    with pytest.raises(StateError, match="below 1e\\+06"):
        State.parse(f"a:{theta}")
    assert State.parse("a:999999.5") == State("a", 999999.5)


def test_bad_state_values() -> None:
    with pytest.raises(StateError, match="finite"):
        State("a", float("nan"))
    with pytest.raises(StateError, match="theta must be a number"):
        State.from_dict({"face": "a", "theta": "ninety"})
    with pytest.raises(StateError):
        State.from_dict({"face": "a"})


def test_cube_state_pose_by_hand() -> None:
    c = cube()
    # a:0: face a down; its edge 1 (vertex 3 -> 0, direction -y in the object) along +x
    rot, t = state_pose(c, State("a", 0))
    assert np.allclose(rot @ c.normals["a"], [0, 0, -1])
    assert np.allclose(rot @ [0, -1, 0], [1, 0, 0])
    world = c.vertices @ rot.T + t
    assert world[:, 2].min() == pytest.approx(0.0)
    assert np.allclose(rot @ c.com + t, [0, 0, 0.5])


@given(random_hulls(), st.floats(0, 360, exclude_max=True), st.data())
def test_pose_round_trip(p: Polyhedron, theta: float, data: st.DataObject) -> None:
    face = data.draw(st.sampled_from(list(p.faces)))
    s = State(face, theta)
    rot, t = state_pose(p, s)
    assert np.allclose(rot.T @ rot, np.eye(3)) and np.linalg.det(rot) == pytest.approx(1.0)
    back = state_of_pose(p, rot)
    assert back.isclose(s, 1e-6)
    world = p.vertices @ rot.T + t
    on_ground = world[list(p.loop(face)), 2]
    assert np.allclose(on_ground, 0.0, atol=1e-9) and world[:, 2].min() > -1e-9


def test_state_of_pose_rejects_a_pose_on_an_edge() -> None:
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_euler("x", 45, degrees=True).as_matrix()
    with pytest.raises(GeometryError, match="points down"):
        state_of_pose(cube(), rot)


def test_stability_by_hand() -> None:
    # a leaning solid: the top is shifted so far that the centre of mass overhangs a side
    bottom = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    top = [[3, 0, 1], [4, 0, 1], [4, 1, 1], [3, 1, 1]]
    p = convex_hull(np.array(bottom + top, float))
    down = next(f for f in p.faces if np.allclose(p.normals[f], [0, 0, -1]))
    # the centroid of this parallelepiped is at x = 2, outside the bottom [0, 1]
    assert p.com[0] == pytest.approx(2.0)
    assert not is_stable(p, down)
    assert stability_margin(p, down) == pytest.approx(-1.0)
    assert down not in stable_faces(p)
    with pytest.raises(StateError, match="cannot rest on face"):
        check_states(p, [State(down, 0)])
    # the cube's margin is half its side; a margin demand above that makes it unstable
    assert stability_margin(cube(), "a") == pytest.approx(0.5)
    assert not is_stable(cube(), "a", margin=0.6)


def test_states_by_step() -> None:
    c = cube()
    s = states_by_step(c, 90)
    assert len(s) == 24 and s[:4] == [State("a", t) for t in (0, 90, 180, 270)]
    assert len(states_by_step(SOLIDS["prism6"](), 1)) == 8 * 360
    with pytest.raises(StateError, match="divide 360"):
        states_by_step(c, 7)
    with pytest.raises(StateError, match="above 0 and at most 360"):
        states_by_step(c, 0)
    # too fine to count, or past the state limit: both name the option and a fix that is
    # itself accepted (360 / 83,333 = 0.00432... would be refused as not dividing 360)
    for step in (1e-300, 1e-9, 1e-4):
        with pytest.raises(StateError, match=r"\(--step\) of .* use a coarser step that "
                                             r"divides 360 degrees, such as 0\.0045 \(the "
                                             r"finest the limit allows on this object is "
                                             r"0\.00432\)"):
            states_by_step(c, step)
    assert len(states_by_step(c, 0.0045)) == 6 * 80_000
    with pytest.raises(StateError, match="500001 faces are more than the limit even at one "
                                         "orientation each: choose fewer faces"):
        states_by_step(c, 90, faces=["a"] * 500_001)
    with pytest.raises(StateError, match="does not have"):
        check_states(c, [State("z", 0)])


@given(st.integers(1, 500_000))
def test_the_coarser_step_a_refusal_names_divides_360_and_fits_the_limit(n_faces: int) -> None:
    text = _coarser(n_faces)
    m = re.fullmatch(r"use a coarser step that divides 360 degrees, such as ([0-9.e+-]+) "
                     r"\(the finest the limit allows on this object is ([0-9.e+-]+)\)", text)
    assert m, text
    step, finest = float(m.group(1)), 360.0 / (MAX_STATES // n_faces)
    n = round(360.0 / step)
    assert abs(n * step - 360.0) <= 1e-9 * 360 and n * n_faces <= MAX_STATES
    # written with two significant digits where one divides 360 near enough
    assert finest <= step <= 1.5 * finest
    assert float(m.group(2)) == pytest.approx(finest, rel=5e-3)


def test_theta_convention_edge_k_points_along_theta_plus_delta() -> None:
    p = SOLIDS["scalene"]()
    for f in stable_faces(p):
        s = State(f, 30.0)
        rot, _ = state_pose(p, s)
        for k in range(1, p.n_edges(f) + 1):
            d = rot @ p.edge_direction(f, k)
            assert abs(d[2]) < 1e-12
            ang = math.degrees(math.atan2(d[1], d[0]))
            assert angle_diff(ang, 30.0 + p.delta[f][k - 1]) == pytest.approx(0, abs=1e-9)


@given(st.sampled_from("abcdef"), st.floats(-1e4, 1e4, allow_nan=False))
def test_a_states_exact_text_reads_back_within_a_billionth_of_a_degree(face: str,
                                                                      theta: float) -> None:
    """`State.exact` (the maneuvers table's final state, the skills file's advice): read back
    within 1e-9 degrees of the angle, where ``str``'s six digits are not (359.99998997 prints
    as "0"), never in exponent notation; ``str`` itself where that is exact enough."""
    s = State(face, theta)
    back = State.parse(s.exact())
    assert back.face == face and abs(angle_diff(back.theta, s.theta)) <= 1e-9
    assert "e" not in s.exact().split(":")[1]  # never in exponent notation
    if "e" not in str(s) and abs(angle_diff(State.parse(str(s)).theta, s.theta)) <= 1e-9:
        assert s.exact() == str(s)


def test_exact_text_examples() -> None:
    assert State("a", 90.0).exact() == "a:90"
    assert str(State("b", 359.999989973)) == "b:0"
    assert State("b", 359.999989973).exact() == "b:359.999989973"
    assert State("a", 100.0 / 3.0).exact() == "a:33.333333333"
    assert State("c", 359.9999999999).exact() == "c:0"  # within 1e-9 of 0: str's "0"
    # never an exponent, in str either (robustness reasons read "instead of d:5.157e-06")
    assert str(State("d", 5.157e-06)) == "d:0.000005157" == State("d", 5.157e-06).exact()
    assert str(State("d", 1e-12)) == "d:0"
