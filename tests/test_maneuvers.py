"""Exact maneuvers, checked with plain poses and rotations."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, strategies as st
from scipy.spatial.transform import Rotation

from conftest import SOLIDS, random_hulls
from nonprehensile.errors import ManeuverError
from nonprehensile.geometry import Polyhedron, cube, octahedron
from nonprehensile.maneuvers import (
    classify,
    ground_clearance,
    roll,
    roll_directions,
    rotate,
    tumble,
)
from nonprehensile.states import State, is_stable, state_pose


def world(p: Polyhedron, s: State) -> np.ndarray:
    rot, t = state_pose(p, s)
    return p.vertices @ rot.T + t


def test_cube_roll_by_hand() -> None:
    c = cube()
    # a:0 -> over E(a,d): the spec's push-roll example lands on d:0
    m = roll(c, State("a", 0), edge=c.edge_index("a", "d"))
    assert m.kind == "rolling" and m.end == State("d", 0) and m.pivot == ("a", "d")
    assert m.angle == pytest.approx(90)
    # edge 4 of a (the edge with d) faces -x when theta = 0: rolling toward 180 degrees
    assert roll_directions(c, State("a", 0))[4] == pytest.approx(180)
    assert roll(c, State("a", 0), direction=180).end == State("d", 0)
    with pytest.raises(ManeuverError, match="no bottom edge faces direction 45"):
        roll(c, State("a", 0), direction=45)
    with pytest.raises(ManeuverError, match=r"edges 1\.\.4"):
        roll(c, State("a", 0), edge=5)


def _roll_cases() -> st.SearchStrategy[tuple[Polyhedron, State, int]]:
    @st.composite
    def cases(draw: st.DrawFn) -> tuple[Polyhedron, State, int]:
        p = draw(st.one_of(st.sampled_from([f() for f in SOLIDS.values()]), random_hulls()))
        face = draw(st.sampled_from(list(p.faces)))
        theta = draw(st.floats(0, 360, exclude_max=True))
        k = draw(st.integers(1, p.n_edges(face)))
        return p, State(face, theta), k

    return cases()


@given(_roll_cases())
def test_roll_keeps_the_edge_and_lands_on_the_neighbour(
    case: tuple[Polyhedron, State, int],
) -> None:
    p, s, k = case
    m = roll(p, s, edge=k)
    g = p.neighbor(s.face, k)
    assert m.end.face == g
    # independent check with the two poses: the shared edge has the same world direction
    # before and after, and lies on the ground in both
    i, j = p.edge_vertices(s.face, k)
    before, after = world(p, s), world(p, m.end)
    assert np.allclose(before[[i, j], 2], 0, atol=1e-9)
    assert np.allclose(after[[i, j], 2], 0, atol=1e-9)
    assert np.allclose(before[j] - before[i], after[j] - after[i], atol=1e-9)
    # the object moved over the edge: the centre of mass went to the edge's outward side
    out_dir = np.deg2rad(roll_directions(p, s)[k])
    u = np.array([np.cos(out_dir), np.sin(out_dir), 0])
    (rb, tb), (ra, ta) = state_pose(p, s), state_pose(p, m.end)
    com_b, com_a = rb @ p.com + tb, ra @ p.com + ta
    shift_b = (com_b - before[i]) @ u
    shift_a = (com_a - after[i]) @ u
    assert shift_a > shift_b
    # and rolling back over the same edge returns the state
    back = roll(p, m.end, edge=p.edge_index(g, s.face))
    assert back.end.isclose(s, 1e-6)


def test_rotate() -> None:
    m = rotate(cube(), State("a", 350), 20)
    assert m.kind == "rotating" and m.end == State("a", 10)
    with pytest.raises(ManeuverError, match="non-zero"):
        rotate(cube(), State("a", 0), 360)


def test_tumble_over_a_cube_corner() -> None:
    c = cube()
    # the corner V(a,b,d) is vertex 2; turning 120 degrees about the body diagonal through it
    # brings face b down
    m = tumble(c, State("a", 0), 2, "b")
    assert m.kind == "tumbling" and m.pivot == ("a", "b", "d")
    assert m.end.face == "b"
    assert ground_clearance(c, m.start, state_pose(c, m.end)[0] @ state_pose(c, m.start)[0].T,
                            world(c, m.start)[2]) == pytest.approx(0, abs=1e-9)
    # the corner did not move
    w0, w1 = world(c, m.start), world(c, m.end)
    shift = w1[2] - w0[2]
    assert shift[2] == pytest.approx(0, abs=1e-12)
    with pytest.raises(ManeuverError, match="not on the bottom face"):
        tumble(c, State("a", 0), 4, "b")
    with pytest.raises(ManeuverError, match="does not meet"):
        tumble(c, State("a", 0), 2, "e")


def test_tumble_through_the_ground_is_refused() -> None:
    c = cube()
    # landing on b at an orientation that needs a half turn about the corner: the geodesic
    # sweeps part of the cube below the table
    refused = []
    for theta in (0, 90, 180, 270):
        try:
            tumble(c, State("a", 0), 2, "b", theta=theta)
        except ManeuverError as exc:
            refused.append((theta, str(exc)))
    assert refused and all("through the ground" in msg for _, msg in refused)


def test_ground_clearance_closed_form_matches_sampling() -> None:
    c = octahedron()
    s = State("a", 10)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = Rotation.random(random_state=rng).as_matrix()
        pivot = world(c, s)[c.loop("a")[0]]
        exact = ground_clearance(c, s, q, pivot)
        rv = Rotation.from_matrix(q).as_rotvec()
        ts = np.linspace(0, 1, 4001)
        x = world(c, s) - pivot
        lows = [((x @ Rotation.from_rotvec(t * rv).as_matrix().T) + pivot)[:, 2].min() for t in ts]
        assert exact == pytest.approx(min(lows), abs=1e-5)
        assert exact <= min(lows) + 1e-12


@pytest.mark.parametrize("name", sorted(SOLIDS))
def test_classify_reads_the_type_from_geometry(name: str) -> None:
    p = SOLIDS[name]()
    faces = [f for f in p.faces if is_stable(p, f)]
    s = State(faces[0], 15)
    assert classify(p, s, State(s.face, 75)).kind == "rotating"
    for k in range(1, p.n_edges(s.face) + 1):
        m = roll(p, s, edge=k)
        assert classify(p, s, m.end).kind == "rolling"
    with pytest.raises(ManeuverError, match="same state"):
        classify(p, s, s)


def test_classify_tumbling_and_impossible() -> None:
    c = cube()
    assert classify(c, State("a", 0), State("d", 90)).kind == "tumbling"
    with pytest.raises(ManeuverError, match="share no edge or vertex"):
        classify(c, State("a", 0), State("c", 0))
