"""Builders: primitives, convex hulls and mesh files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, strategies as st

from conftest import DATA, GROUP_ORDERS, SOLIDS, rotation_matrix
from nonprehensile.errors import MeshError
from nonprehensile.geometry import (
    Polyhedron,
    convex_hull,
    cube,
    face_name,
    from_mesh,
    prism,
    rotation_group,
)
from nonprehensile.states import is_stable

trimesh = pytest.importorskip("trimesh")


def same_up_to_relabeling(p: Polyhedron, q: Polyhedron, atol: float = 1e-9) -> bool:
    """True when q is p with faces renamed, vertices renumbered and loops started elsewhere."""
    if len(p.vertices) != len(q.vertices) or len(p.faces) != len(q.faces):
        return False
    # match vertices by position
    d = np.linalg.norm(p.vertices[:, None] - q.vertices[None], axis=-1)
    vmap = d.argmin(axis=1)
    if d.min(axis=1).max() > atol or len(set(vmap.tolist())) != len(vmap):
        return False

    def cycles(loop: tuple[int, ...]) -> set[tuple[int, ...]]:
        return {loop[i:] + loop[:i] for i in range(len(loop))}

    q_loops = [cycles(loop) for loop in q.faces.values()]
    for loop in p.faces.values():
        mapped = tuple(int(vmap[i]) for i in loop)
        if not any(mapped in c for c in q_loops):
            return False
    return True


@pytest.mark.parametrize("name", sorted(SOLIDS))
def test_rotation_group_orders(name: str) -> None:
    assert len(rotation_group(SOLIDS[name]())) == GROUP_ORDERS[name]


def test_face_names() -> None:
    assert [face_name(i) for i in (0, 1, 25, 26, 27, 51, 52, 701, 702)] == [
        "a", "b", "z", "aa", "ab", "az", "ba", "zz", "aaa"]


def test_face_names_in_bulk_are_the_names_one_by_one() -> None:
    from nonprehensile.geometry.build import face_names

    assert face_names(0) == []
    assert face_names(20_000) == [face_name(i) for i in range(20_000)]


def test_prism_faces_named_bottom_first_top_last() -> None:
    p = prism(6)
    names = list(p.faces)
    assert np.allclose(p.normals[names[0]], [0, 0, -1])
    assert np.allclose(p.normals[names[-1]], [0, 0, 1])
    assert p.n_edges("a") == 6 and p.delta["a"] == pytest.approx((0, 60, 120, 180, 240, 300))
    assert all(p.n_edges(f) == 4 for f in names[1:-1])


@given(st.integers(0, 10**6))
def test_hull_of_shuffled_points_is_the_same_model(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(12, 3))
    a = convex_hull(pts)
    b = convex_hull(pts[rng.permutation(len(pts))])
    assert a.faces == b.faces
    assert np.array_equal(a.vertices, b.vertices)


def test_hull_drops_interior_and_edge_points() -> None:
    c = cube()
    extra = np.array([[0.5, 0.5, 0.5], [0.5, 0, 0], [0.5, 0.5, 0]])  # centre, mid-edge, mid-face
    h = convex_hull(np.vstack([c.vertices, extra]))
    assert len(h.vertices) == 8 and len(h.faces) == 6
    assert same_up_to_relabeling(h, c)


@given(st.integers(0, 10**6))
def test_from_mesh_of_a_triangulated_cube_is_the_cube(seed: int) -> None:
    rot = rotation_matrix(seed)
    mesh = trimesh.load(DATA / "cube.stl", force="mesh")
    c = cube()
    # the mesh's cube, placed anywhere: same up to relabeling as the hand-written cube so placed
    moved = Polyhedron(c.vertices @ rot.T, dict(c.faces))
    mesh.apply_transform(np.block([[rot, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))
    assert len(mesh.faces) == 12  # triangulated: coplanar triangles must be merged
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cube.stl"
        mesh.export(path)
        model = from_mesh(path)
    assert same_up_to_relabeling(model, moved, atol=1e-6)
    assert len(rotation_group(model, atol=1e-6)) == 24


@pytest.mark.parametrize("fname", ["cube.stl", "hexprism.obj"])
def test_from_mesh_files(fname: str) -> None:
    model = from_mesh(DATA / fname)
    assert model.name == fname.split(".")[0]
    assert not model.virtual_faces
    expected = {"cube.stl": (6, 24), "hexprism.obj": (8, 12)}[fname]
    assert (len(model.faces), len(rotation_group(model, atol=1e-6))) == expected


@pytest.mark.parametrize("suffix", ["ply", "off", "glb", "obj", "stl"])
def test_from_mesh_reads_every_format(tmp_path: object, suffix: str) -> None:
    from pathlib import Path

    mesh = trimesh.load(DATA / "hexprism.obj", force="mesh")
    path = Path(str(tmp_path)) / f"prism.{suffix}"
    mesh.export(path)
    model = from_mesh(path)
    assert len(model.faces) == 8
    assert model.volume == pytest.approx(mesh.volume, rel=1e-6)


def test_non_convex_mesh_marks_virtual_faces_and_keeps_its_centre_of_mass() -> None:
    model = from_mesh(DATA / "lshape.obj")
    mesh = trimesh.load(DATA / "lshape.obj", force="mesh")
    # the L (2 x 2 with a 1 x 1 notch, 1 deep) rests on the diagonal across its notch only
    # on two edges: that hull face is virtual; the L's sides are real (partly covered) faces
    assert len(model.virtual_faces) == 1
    (v,) = model.virtual_faces
    assert np.allclose(model.normals[v], [np.sqrt(0.5), 0, np.sqrt(0.5)])
    assert np.allclose(model.com, mesh.center_mass)
    assert np.allclose(model.com, [5 / 6, 0.5, 5 / 6])
    assert model.volume == pytest.approx(3.5)  # the hull's, not the L's 3.0
    assert is_stable(model, v)


@pytest.mark.parametrize(
    ("fname", "match"),
    [
        ("flat.obj", "coplanar"),
        ("triangle.obj", "at least 4 points"),
        ("missing.stl", "no such mesh file"),
    ],
)
def test_bad_meshes(fname: str, match: str) -> None:
    with pytest.raises(MeshError, match=match) as info:
        from_mesh(DATA / fname)
    assert fname in str(info.value)


def test_open_mesh_becomes_its_hull_with_a_note_and_strict_refuses_it(tmp_path: Path) -> None:
    notes: list[str] = []
    # a box missing one face: trimesh fills the quad hole, and says so
    model = from_mesh(DATA / "open_box.stl", notes=notes)
    assert len(model.faces) == 6 and notes and "filled" in notes[0]
    # a box missing two adjacent faces: a hole of 6 edges stays open; the hull is taken
    box = trimesh.creation.box()
    keep = np.abs(box.face_normals @ [1, 0, 0]) < 0.5
    keep &= box.face_normals @ [0, 0, 1] < 0.5
    box.update_faces(keep)
    path = tmp_path / "open2.stl"
    box.export(path)
    notes.clear()
    model = from_mesh(path, notes=notes)
    assert len(model.faces) == 6
    assert len(notes) == 1 and "not closed" in notes[0] and "convex hull" in notes[0]
    with pytest.raises(MeshError, match=r"open2\.stl: it is not closed"):
        from_mesh(path, strict=True)
    with pytest.raises(MeshError, match="coplanar"):
        from_mesh(DATA / "flat.obj")


def test_convex_hull_bad_points() -> None:
    with pytest.raises(MeshError, match="at least 4 points"):
        convex_hull(np.zeros((3, 3)))
    with pytest.raises(MeshError, match="degenerate"):
        convex_hull(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]]))
    with pytest.raises(MeshError, match="not finite"):
        convex_hull(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, np.inf]]))
    with pytest.raises(MeshError, match="shape"):
        convex_hull(np.zeros((5, 2)))


def test_hull_model_checked_without_a_second_hull_agrees_with_the_full_check() -> None:
    # the builders skip only the whole-solid hull comparison; the diameter (so the tolerance)
    # is the one a full check of the same vertices and faces finds
    rng = np.random.default_rng(11)
    for pts in (rng.standard_normal((40, 3)), rng.standard_normal((3000, 3)) * [1, 2, 3]):
        built = convex_hull(pts, rtol=1e-6)
        again = Polyhedron(built.vertices, dict(built.faces), rtol=built.rtol)
        assert again.diameter == built.diameter and again.atol == built.atol
        assert again.volume == built.volume


def test_a_small_face_is_not_a_flat_one() -> None:
    # a cube with one corner cut 0.3 mm deep (per metre): the cut's area, 7.8e-8, is below
    # the tolerance times the diameter, but the triangle is 4e-4 wide, far above the
    # tolerance; simulator meshes of fine CAD parts are full of such faces
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    e = 3e-4
    cut = [[1 - e, 1, 1], [1, 1 - e, 1], [1, 1, 1 - e]]
    model = convex_hull(np.vstack([corners[:-1], cut]))
    assert len(model.faces) == 7
    assert min(model.face_areas.values()) == pytest.approx(np.sqrt(3) / 4 * 2 * e * e)


def test_corners_that_do_not_turn_are_found_for_the_builder_to_leave_out() -> None:
    from nonprehensile.geometry.build import _unturned_corners

    # a cube's loops, with a point 1e-9 outside the middle of edge 0-1, on both faces there
    # (a point Qhull may keep as a corner): within the tolerance of the hull of the others
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1],
                  [1, 1, 1], [0, 1, 1], [0.5, -1e-9, -1e-9]], float)
    faces = {"a": (3, 2, 1, 8, 0), "b": (6, 2, 1, 5), "c": (4, 7, 6, 5), "d": (7, 3, 2, 6),
             "e": (0, 3, 7, 4), "f": (0, 8, 1, 5, 4)}
    assert _unturned_corners(v, faces, 1e-7).tolist() == [8]
    assert _unturned_corners(v, faces, 1e-10).tolist() == []  # a real corner at that scale
