"""The object's proper rotation symmetry group (its action on states is
:mod:`nonprehensile.equivalence`).

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

__all__ = ["Symmetry", "rotation_group"]

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
