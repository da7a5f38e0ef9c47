"""The object model against hand-worked examples and exact geometry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, strategies as st

from conftest import random_hulls, rotation_matrix
from nonprehensile.errors import ModelError
from nonprehensile.geometry import Polyhedron, cube, rotation_group, wrap_index
from nonprehensile.states import stable_faces

CUBE_V = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]
CUBE_F = {"a": [3, 0, 1, 2], "b": [6, 2, 1, 5], "c": [4, 7, 6, 5], "d": [7, 3, 2, 6],
          "e": [0, 3, 7, 4], "f": [0, 4, 5, 1]}


def test_paper_cube_adjacency_by_hand() -> None:
    # Worked by hand from the loops: edge k of a face runs loop[k-1] -> loop[k]; e.g. face a
    # = [3, 0, 1, 2]: edge 1 is 3->0 on x = 0 (face e), edge 2 is 0->1 on y = 0 (face f), ...
    expected = {
        "a": {"e": 1, "f": 2, "b": 3, "d": 4},
        "b": {"d": 1, "a": 2, "f": 3, "c": 4},
        "c": {"e": 1, "d": 2, "b": 3, "f": 4},
        "d": {"e": 1, "a": 2, "b": 3, "c": 4},
        "e": {"a": 1, "d": 2, "c": 3, "f": 4},
        "f": {"e": 1, "c": 2, "b": 3, "a": 4},
    }
    c = cube()
    assert c.adjacency == expected
    # the paper's Section III: A(b,a) = 2 and A(a,b) = 3
    assert c.edge_index("b", "a") == 2
    assert c.edge_index("a", "b") == 3
    labels, a = c.adjacency_matrix()
    assert labels == tuple("abcdef")
    assert a[0].tolist() == [0, 3, 0, 4, 1, 2]
    assert np.all(np.diag(a) == 0)


def test_paper_cube_delta_and_normals() -> None:
    c = Polyhedron(np.array(CUBE_V, float), {k: tuple(v) for k, v in CUBE_F.items()})
    for f in "abcdef":
        assert c.delta[f] == (0.0, 90.0, 180.0, 270.0)
    assert np.allclose(c.normals["a"], [0, 0, -1])
    assert np.allclose(c.normals["b"], [1, 0, 0])
    assert np.allclose(c.normals["c"], [0, 0, 1])
    assert np.allclose(c.com, [0.5, 0.5, 0.5])
    assert c.volume == pytest.approx(1.0)
    assert stable_faces(c) == list("abcdef")


def test_delta_of_a_right_triangle_face() -> None:
    # a triangular prism whose bottom is the right triangle (0,0)-(0,1)-(1,0): seen from inside
    # (from above), the loop runs counterclockwise, turning by 135 then 135 degrees
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], float)
    faces = {"bot": (0, 1, 2), "top": (3, 5, 4), "s1": (0, 3, 4, 1), "s2": (1, 4, 5, 2),
             "s3": (2, 5, 3, 0)}
    p = Polyhedron(v, faces)
    assert p.delta["bot"] == pytest.approx((0.0, 135.0, 270.0))
    assert p.delta["s1"] == pytest.approx((0.0, 90.0, 180.0, 270.0))


@given(random_hulls())
def test_adjacency_names_the_same_edge_both_ways(p: Polyhedron) -> None:
    for f, row in p.adjacency.items():
        for g, k in row.items():
            i, j = p.edge_vertices(f, k)
            assert p.edge_vertices(g, p.adjacency[g][f]) == (j, i)
            assert p.neighbor(f, k) == g
    n_edges = sum(len(r) for r in p.adjacency.values()) // 2
    assert len(p.vertices) - n_edges + len(p.faces) == 2
    assert len(p.edges) == n_edges


@given(random_hulls(), st.integers(0, 10**6))
def test_label_level_results_do_not_depend_on_placement(p: Polyhedron, seed: int) -> None:
    rot = rotation_matrix(seed)
    moved = Polyhedron(p.vertices @ rot.T + [3.0, -1.0, 2.0], dict(p.faces), rtol=p.rtol)
    assert moved.adjacency == p.adjacency
    for f in p.faces:
        assert moved.delta[f] == pytest.approx(p.delta[f], abs=1e-7)
        assert np.allclose(moved.normals[f], rot @ p.normals[f])
    assert stable_faces(moved) == stable_faces(p)
    assert len(rotation_group(moved)) == len(rotation_group(p))
    assert moved.volume == pytest.approx(p.volume)


def test_wrap_index() -> None:
    assert wrap_index(0, 4) == 4
    assert wrap_index(5, 4) == 1
    assert wrap_index(-3, 4) == 1
    assert [wrap_index(k, 3) for k in range(1, 4)] == [1, 2, 3]


def _faces(**changes: list[int]) -> dict[str, list[int]]:
    f = dict(CUBE_F)
    f.update(changes)
    return f


@pytest.mark.parametrize(
    ("vertices", "faces", "match"),
    [
        (CUBE_V[:3], CUBE_F, "at least 4 vertices"),
        ([[0, 0]] * 8, CUBE_F, r"shape \(n, 3\)"),
        ([[0, 0, 0], [1, 0], [1, 1, 0], [0, 1, 0]], CUBE_F, "ragged"),
        ([*CUBE_V[:7], [0, 1, float("nan")]], CUBE_F, "vertex 7 is not finite"),
        (CUBE_V, {"a": [3, 0, 1, 2]}, "at least 4 faces"),
        (CUBE_V, _faces(a=[3, 0, 1, 9]), "face 'a'.*out of range"),
        (CUBE_V, _faces(a=[3, 0, 1, 1]), "face 'a'.*repeats a vertex"),
        (CUBE_V, _faces(a=[3, 0]), "face 'a'.*at least 3 vertices"),
        (CUBE_V, _faces(a=[2, 1, 0, 3]), "not consistently ordered"),
        (CUBE_V, {k: list(reversed(v)) for k, v in CUBE_F.items()}, "counterclockwise"),
        (CUBE_V, _faces(a=[3, 1, 0, 2]), "face 'a'.*crosses itself"),
        ([*CUBE_V, [0.5, 0.3, 0]], _faces(a=[3, 0, 8, 1, 2]), "face 'a'.*not convex"),
        (CUBE_V, {k: v for k, v in CUBE_F.items() if k != "c"}, "not closed"),
        ([*CUBE_V[:6], [1, 1, 1.2], [0, 1, 1]], CUBE_F, "not planar"),
        ([*CUBE_V[:6], [1.3, 1.3, 1.3], [0, 1, 1]], CUBE_F, "not planar"),
    ],
)
def test_invalid_models_name_the_culprit(vertices: object, faces: object, match: str) -> None:
    with pytest.raises(ModelError, match=match):
        Polyhedron(vertices, faces)  # type: ignore[arg-type]


def test_non_convex_solid_is_refused() -> None:
    # a cube whose top centre is pushed down into a pit: 4 planar triangles, not convex
    v = [*CUBE_V, [0.5, 0.5, 0.6]]
    faces = {k: val for k, val in CUBE_F.items() if k != "c"}
    faces.update({"c1": [4, 7, 8], "c2": [7, 6, 8], "c3": [6, 5, 8], "c4": [5, 4, 8]})
    with pytest.raises(ModelError, match="not convex"):
        Polyhedron(v, faces)  # type: ignore[arg-type]


def test_unused_vertex_and_coplanar_faces_are_refused() -> None:
    with pytest.raises(ModelError, match=r"vertex 8 .* is on no face"):
        Polyhedron([*CUBE_V, [5, 5, 5]], CUBE_F)  # type: ignore[arg-type]
    # split the bottom into two coplanar triangles
    faces = {k: v for k, v in CUBE_F.items() if k != "a"}
    faces.update({"a1": [3, 0, 1], "a2": [3, 1, 2]})
    with pytest.raises(ModelError, match="coplanar"):
        Polyhedron(CUBE_V, faces)  # type: ignore[arg-type]


def test_center_of_mass_given_and_checked() -> None:
    p = Polyhedron(CUBE_V, CUBE_F, center_of_mass=[0.2, 0.5, 0.5])  # type: ignore[arg-type]
    assert np.allclose(p.com, [0.2, 0.5, 0.5])
    with pytest.raises(ModelError, match="outside the polyhedron"):
        Polyhedron(CUBE_V, CUBE_F, center_of_mass=[2, 0, 0])  # type: ignore[arg-type]
    with pytest.raises(ModelError, match="3 finite numbers"):
        Polyhedron(CUBE_V, CUBE_F, center_of_mass=[0, 0])  # type: ignore[arg-type]
    with pytest.raises(ModelError, match="virtual_faces"):
        Polyhedron(CUBE_V, CUBE_F, virtual_faces=frozenset({"zz"}))  # type: ignore[arg-type]


def test_unknown_face_and_non_adjacent_faces() -> None:
    c = cube()
    with pytest.raises(ModelError, match="no face 'z'"):
        c.loop("z")
    with pytest.raises(ModelError, match="share no edge"):
        c.edge_index("a", "c")
    assert c.shared_vertices(["a", "b", "d"]) == [2]
    assert c.shared_vertices(["a", "c"]) == []


def test_hull_volume_and_diameter_are_kept_by_content_not_by_array() -> None:
    from scipy.spatial import ConvexHull
    from scipy.spatial.distance import pdist

    from nonprehensile.geometry.polyhedron import hull_volume_and_diameter

    pts = np.random.default_rng(3).standard_normal((300, 3))
    vol, diam = hull_volume_and_diameter(pts)
    assert vol == pytest.approx(ConvexHull(pts).volume, rel=1e-12)
    assert diam == pytest.approx(pdist(pts).max(), rel=1e-12)
    # the same numbers in another array hit the memo; changed numbers in place do not
    assert hull_volume_and_diameter(pts.copy()) == (vol, diam)
    pts *= 2.0
    vol2, diam2 = hull_volume_and_diameter(pts)
    assert vol2 == pytest.approx(8 * vol) and diam2 == pytest.approx(2 * diam)
