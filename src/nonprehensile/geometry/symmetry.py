"""The object's proper rotation symmetry group and geometric equivalence of states.

Two states are geometrically equivalent (paper Section V, spec "Maneuvers and geometric
equivalence") when the object occupies the same space in both, up to a horizontal
translation: their poses differ by a proper rotation symmetry ``g`` of the object,
``R_1 = R_2 g``. We require a symmetry to fix the centre of mass as well as the shape, so a
loaded die (or a model with a user-given centre of mass off the centroid) has fewer
symmetries than its shape: its equivalent states must also behave the same under gravity.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from nonprehensile.checks import check_tolerance
from nonprehensile.geometry.polyhedron import Polyhedron, wrap_index
from nonprehensile.states import DEFAULT_ANGLE_TOL, State

__all__ = [
    "Symmetry",
    "apply_to_state",
    "equivalence_classes",
    "equivalent",
    "rotation_group",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Symmetry:
    """One proper rotation symmetry ``g`` of an object.

    Attributes
    ----------
    rotation : array, shape (3, 3)
        ``g`` as a rotation about the object's centre (the vertex centroid), object frame.
    face_map : mapping of str to str
        Face ``f`` goes to face ``face_map[f]``.
    edge_shift : mapping of str to int
        Edge ``k`` of face ``f`` goes to edge ``k + edge_shift[f]`` (modular) of
        ``face_map[f]``; a proper rotation keeps every loop's direction, so the shift is the
        same for every edge of a face.
    vertex_map : tuple of int
        Vertex ``i`` goes to vertex ``vertex_map[i]``.
    """

    rotation: FloatArray
    face_map: Mapping[str, str]
    edge_shift: Mapping[str, int]
    vertex_map: tuple[int, ...]

    def map_edge(self, poly: Polyhedron, face: str, k: int) -> tuple[str, int]:
        """Image ``(face', k')`` of edge ``k`` of ``face``."""
        g = self.face_map[face]
        return g, wrap_index(k + self.edge_shift[face], poly.n_edges(g))

    def map_faces(self, faces: Sequence[str]) -> tuple[str, ...]:
        """Images of several faces (an edge or a vertex named by its faces)."""
        return tuple(self.face_map[f] for f in faces)


def _default_atol(poly: Polyhedron, atol: float | None) -> float:
    return poly.atol if atol is None else check_tolerance(atol, "atol")


@lru_cache(maxsize=128)
def _rotation_group_cached(poly: Polyhedron, atol: float) -> tuple[Symmetry, ...]:
    v = poly.vertices
    center = v.mean(axis=0)
    rel = v - center
    tree = cKDTree(rel)
    com_rel = poly.com - center

    # A proper rotation symmetry is fixed by where it sends one flag (face f0, edge 1):
    # trying every (face, edge) with the same number of edges finds them all.
    f0 = poly.face_ids[0]
    n0 = poly.n_edges(f0)
    i0, _ = poly.edge_vertices(f0, 1)
    src = np.column_stack(
        [poly.edge_direction(f0, 1), np.cross(poly.normals[f0], poly.edge_direction(f0, 1)),
         poly.normals[f0]]
    )
    vertex_set_to_face = {frozenset(loop): f for f, loop in poly.faces.items()}
    # how far the first guess may be off: the model's own faces are planar only within its
    # tolerance, so their edge frames are that far from exact
    gate = 4.0 * max(atol, poly.atol)
    found: list[Symmetry] = []
    for g in poly.face_ids:
        if poly.n_edges(g) != n0 or abs(poly.face_areas[g] - poly.face_areas[f0]) > (
            gate * poly.diameter
        ):
            continue
        for k in range(1, n0 + 1):
            u = poly.edge_direction(g, k)
            dst = np.column_stack([u, np.cross(poly.normals[g], u), poly.normals[g]])
            rot = dst @ src.T
            i, _ = poly.edge_vertices(g, k)
            # a measured object's edges are a little off: the rotation from one edge is only
            # a first guess (gated loosely), refined by a least-squares fit (Kabsch) over
            # every vertex it pairs, and then held to the tolerance
            if np.linalg.norm(rot @ rel[i0] - rel[i]) > gate:
                continue
            dist, idx = tree.query(rel @ rot.T)
            if dist.max() > gate or len(set(idx.tolist())) != len(v):
                continue
            rot, shift_t = _fit(rel, rel[idx], atol)
            if np.linalg.norm(rot @ com_rel + shift_t - com_rel) > atol:
                continue
            dist, idx = tree.query(rel @ rot.T + shift_t)
            if dist.max() > atol or len(set(idx.tolist())) != len(v):
                continue
            vmap = tuple(int(j) for j in idx)
            face_map: dict[str, str] = {}
            shift: dict[str, int] = {}
            for f, loop in poly.faces.items():
                h = vertex_set_to_face.get(frozenset(vmap[j] for j in loop))
                if h is None:
                    break
                face_map[f] = h
                # edge 1 of f (loop[0] -> loop[1]) lands on edge m of h
                m = poly.faces[h].index(vmap[loop[0]]) + 1
                shift[f] = m - 1
            else:
                rot.setflags(write=False)
                found.append(Symmetry(rot, face_map, shift, vmap))
    # identity first, then a stable order
    found.sort(key=lambda s: (not np.allclose(s.rotation, np.eye(3)), s.vertex_map))
    return tuple(found)


def _kabsch(a: FloatArray, b: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The rigid motion ``x -> R x + t`` minimising ``sum w_i |R a_i + t - b_i|^2``."""
    ca, cb = w @ a, w @ b
    u, _, vt = np.linalg.svd((a - ca).T @ ((b - cb) * w[:, None]))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = np.asarray(vt.T @ np.diag([1.0, 1.0, d]) @ u.T, dtype=np.float64)
    return rot, cb - rot @ ca


def _fit(a: FloatArray, b: FloatArray, atol: float) -> tuple[FloatArray, FloatArray]:
    """The rigid motion taking points ``a`` onto ``b`` (shapes (n, 3)) with the smallest
    largest miss, as far as it matters: least squares first (Kabsch), then, when a point
    still misses by more than ``atol``, Lawson's reweighting toward the minimax fit (two
    measured vertices, each off by up to ``atol / 2``, may miss each other by ``atol``)."""
    w = np.full(len(a), 1.0 / len(a))
    rot, t = _kabsch(a, b, w)
    for _ in range(50):
        miss = np.linalg.norm(a @ rot.T + t - b, axis=1)
        if miss.max() <= atol or not miss.any():
            break
        w = w * miss
        w /= w.sum()
        rot, t = _kabsch(a, b, w)
    return rot, t


def rotation_group(poly: Polyhedron, atol: float | None = None) -> tuple[Symmetry, ...]:
    """The object's proper rotation symmetry group.

    Parameters
    ----------
    poly : Polyhedron
        The object.
    atol : float, optional
        Length tolerance for a vertex to land on a vertex (default the model's ``atol``);
        raise it for measured, imperfect models.

    Returns
    -------
    tuple of Symmetry
        The group's elements, identity first. Its order is 24 for a cube, 12 for a regular
        tetrahedron, 1 for a solid with no symmetry.
    """
    return _rotation_group_cached(poly, _default_atol(poly, atol))


def apply_to_state(poly: Polyhedron, g: Symmetry, state: State) -> State:
    """The state equivalent to ``state`` through symmetry ``g``.

    With ``R`` the pose of ``state``, the result has pose ``R g^-1``: the object occupies the
    same space, with face ``g(F_b)`` on the ground.

    Returns
    -------
    State
        ``{g(F_b), theta + Delta_F_b[j]}`` where ``g`` takes edge ``j`` of ``F_b`` to edge 1.
    """
    f = state.face
    n = poly.n_edges(f)
    j = wrap_index(1 - g.edge_shift[f], n)
    return State(g.face_map[f], state.theta + poly.delta[f][j - 1])


def equivalent(
    poly: Polyhedron,
    a: State,
    b: State,
    *,
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> Symmetry | None:
    """The symmetry taking state ``a`` to state ``b``, or None if they are not equivalent."""
    for g in rotation_group(poly, atol):
        if apply_to_state(poly, g, a).isclose(b, angle_tol):
            return g
    return None


def equivalence_classes(
    poly: Polyhedron,
    states: Sequence[State],
    *,
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[int]:
    """Number the geometric-equivalence classes of a state set.

    Parameters
    ----------
    poly : Polyhedron
    states : sequence of State
    atol : float, optional
        Length tolerance of the symmetry group.
    angle_tol : float
        Angle tolerance in degrees.

    Returns
    -------
    list of int
        ``classes[i]`` is the class of ``states[i]``; classes are numbered 0, 1, ... in order
        of first appearance.
    """
    group = rotation_group(poly, atol)
    angle_tol = float(angle_tol)
    n = len(states)
    if n == 0:
        return []
    # states by face: sorted angles and their positions in ``states``
    faces = np.array([s.face for s in states])
    thetas = np.array([s.theta for s in states], dtype=np.float64)
    by_face: dict[str, tuple[NDArray[np.float64], NDArray[np.int64]]] = {}
    for f in np.unique(faces).tolist():
        pos = np.flatnonzero(faces == f)
        order = np.argsort(thetas[pos], kind="stable")
        by_face[f] = (thetas[pos][order], pos[order])
    # images[g][i]: the first state equal to g . states[i] within the tolerance, or -1. The
    # identity is in the group, so copies of one state (equal within the tolerance) merge.
    images = []
    for g in group:
        img = np.full(n, -1, dtype=np.int64)
        for f, (th, pos) in by_face.items():
            if f not in g.face_map or g.face_map[f] not in by_face:
                continue
            h = g.face_map[f]
            j = wrap_index(1 - g.edge_shift[f], poly.n_edges(f))
            target = (th + poly.delta[f][j - 1]) % 360.0
            img[pos] = _match(target, *by_face[h], angle_tol)
        images.append(img)
    # a class is an orbit of the group: label each state by the smallest position in its
    # orbit, repeating until stable (chains of near-copies within the tolerance)
    label = np.arange(n, dtype=np.int64)
    for _ in range(n):
        new = label.copy()
        for img in images:
            ok = img >= 0
            np.minimum.at(new, np.flatnonzero(ok), label[img[ok]])
            np.minimum.at(new, img[ok], label[ok])
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    # classes numbered in order of first appearance
    _, first, inverse = np.unique(label, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return [int(c) for c in rank[inverse]]


def _match(
    target: NDArray[np.float64], thetas: NDArray[np.float64], pos: NDArray[np.int64],
    tol: float,
) -> NDArray[np.int64]:
    """For each angle of ``target``, the smallest position among the sorted ``thetas`` within
    ``tol`` degrees (modulo 360), or -1."""
    out = np.full(len(target), np.iinfo(np.int64).max, dtype=np.int64)
    for shift in (-360.0, 0.0, 360.0):
        lo = np.searchsorted(thetas, target - tol + shift, side="left")
        hi = np.searchsorted(thetas, target + tol + shift, side="right")
        one = hi - lo == 1
        out[one] = np.minimum(out[one], pos[lo[one]])
        for k in np.flatnonzero(hi - lo > 1).tolist():  # near-copies: rare
            out[k] = min(int(out[k]), int(pos[lo[k] : hi[k]].min()))
    out[out == np.iinfo(np.int64).max] = -1
    return out
