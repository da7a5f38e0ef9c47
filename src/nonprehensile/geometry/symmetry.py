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
from nonprehensile.states import DEFAULT_ANGLE_TOL, State, StateIndex

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
    found: list[Symmetry] = []
    for g in poly.face_ids:
        if poly.n_edges(g) != n0 or abs(poly.face_areas[g] - poly.face_areas[f0]) > (
            atol * poly.diameter * 4
        ):
            continue
        for k in range(1, n0 + 1):
            u = poly.edge_direction(g, k)
            dst = np.column_stack([u, np.cross(poly.normals[g], u), poly.normals[g]])
            rot = dst @ src.T
            i, _ = poly.edge_vertices(g, k)
            if np.linalg.norm(rot @ rel[i0] - rel[i]) > atol:
                continue
            if np.linalg.norm(rot @ com_rel - com_rel) > atol:
                continue
            dist, idx = tree.query(rel @ rot.T)
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
    index = StateIndex(states)

    parent = list(range(len(states)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, s in enumerate(states):
        # the identity too: it merges copies of one state (equal within the tolerance)
        for g in group:
            for j in index.find_all(apply_to_state(poly, g, s), angle_tol):
                ri, rj = find(i), find(j)
                if ri != rj:
                    parent[max(ri, rj)] = min(ri, rj)
    labels: dict[int, int] = {}
    out = []
    for i in range(len(states)):
        r = find(i)
        out.append(labels.setdefault(r, len(labels)))
    return out

