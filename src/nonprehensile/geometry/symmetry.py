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

from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from nonprehensile.checks import check_tolerance
from nonprehensile.geometry.polyhedron import Polyhedron, wrap_index

__all__ = ["Symmetry", "group_arrays", "rotation_group"]

FloatArray = NDArray[np.float64]
IndexArray = NDArray[np.int32]
#: Index type of the symmetries' arrays: 4,000 symmetries of a 2,000-sided prism hold 32
#: million indices.
_INDEX = np.int32


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
    vertex_map : sequence of int
        Vertex ``i`` goes to vertex ``vertex_map[i]``.

    The three maps are read-only views of arrays: a 2,000-sided prism has 4,000 symmetries
    of 4,000 vertices and 2,002 faces each, which as dictionaries and tuples of Python
    objects would take gigabytes.
    """

    rotation: FloatArray
    face_map: Mapping[str, str]
    edge_shift: Mapping[str, int]
    vertex_map: Sequence[int]

    def map_edge(self, poly: Polyhedron, face: str, k: int) -> tuple[str, int]:
        """Image ``(face', k')`` of edge ``k`` of ``face``."""
        g = self.face_map[face]
        return g, wrap_index(k + self.edge_shift[face], poly.n_edges(g))

    def map_faces(self, faces: Sequence[str]) -> tuple[str, ...]:
        """Images of several faces (an edge or a vertex named by its faces)."""
        return tuple(self.face_map[f] for f in faces)


class _Ints(Sequence[int]):
    """A read-only sequence of Python ints over an integer array."""

    __slots__ = ("array",)

    def __init__(self, array: IndexArray) -> None:
        self.array = array

    def __len__(self) -> int:
        return len(self.array)

    def __getitem__(self, i: Any) -> Any:
        if isinstance(i, slice):
            return tuple(self.array[i].tolist())
        return int(self.array[i])

    def __iter__(self) -> Iterator[int]:
        return iter(self.array.tolist())

    def __eq__(self, other: object) -> bool:
        if isinstance(other, _Ints):
            return bool(np.array_equal(self.array, other.array))
        return isinstance(other, Sequence) and tuple(self) == tuple(other)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return repr(tuple(self))


class _FaceArrayMap(Mapping[str, Any]):
    """A read-only mapping from face IDs over an array indexed by face number: to face IDs
    (``names`` given) or to ints."""

    __slots__ = ("array", "index", "names")

    def __init__(self, index: Mapping[str, int], array: IndexArray,
                 names: Sequence[str] | None = None) -> None:
        self.index, self.array, self.names = index, array, names

    def __getitem__(self, face: str) -> Any:
        v = int(self.array[self.index[face]])
        return v if self.names is None else self.names[v]

    def __iter__(self) -> Iterator[str]:
        return iter(self.index)

    def __len__(self) -> int:
        return len(self.index)

    def __repr__(self) -> str:
        return repr(dict(self))


def _default_atol(poly: Polyhedron, atol: float | None) -> float:
    return poly.atol if atol is None else check_tolerance(atol, "atol")


class _Element:
    """A symmetry as arrays: ``x -> rot x + shift`` about the centroid, the vertex map, the
    face map (face numbers) and the edge shifts; composed without any search."""

    __slots__ = ("fmap", "rot", "shift", "t", "vmap")

    def __init__(self, rot: FloatArray, t: FloatArray, vmap: IndexArray,
                 fmap: IndexArray, shift: IndexArray) -> None:
        self.rot, self.t, self.vmap, self.fmap, self.shift = rot, t, vmap, fmap, shift

    def after(self, other: _Element, n_edges: IndexArray) -> _Element:
        """``self`` composed after ``other`` (``other`` first)."""
        return _Element(self.rot @ other.rot, self.rot @ other.t + self.t,
                        self.vmap[other.vmap], self.fmap[other.fmap],
                        (other.shift + self.shift[other.fmap]) % n_edges)


class _GroupSearch:
    """What finding the symmetries of one model needs: centred vertices and their tree, the
    faces as arrays, the directed edges of every loop."""

    def __init__(self, poly: Polyhedron, atol: float) -> None:
        v = poly.vertices
        self.poly, self.atol = poly, atol
        self.rel = v - v.mean(axis=0)
        self.tree = cKDTree(self.rel)
        self.com_rel = poly.com - v.mean(axis=0)
        lp = poly._loops
        self.lp = lp
        self.names = poly.face_ids
        self.index = {f: i for i, f in enumerate(self.names)}
        self.n_edges = np.asarray(lp.lengths, dtype=_INDEX)
        # every directed edge (u -> v of a loop) as u * n + v, sorted, with its face and its
        # place in the loop: a proper rotation sends a face's edge 1 to one of them
        n = np.int64(len(v))
        keys = lp.flat.astype(np.int64) * n + lp.flat[lp.nxt].astype(np.int64)
        self.order = np.argsort(keys, kind="stable")
        self.keys = keys[self.order]
        self.corner = (np.arange(len(lp.flat), dtype=np.int64) - lp.starts[lp.owner])
        self.gate = 4.0 * max(atol, poly.atol)

    def faces_of(
        self, vmap: IndexArray
    ) -> tuple[IndexArray, IndexArray] | None:
        """Where the vertex map ``vmap`` sends every face (its number) and each face's edge
        1 (the edge shift), or None when some face does not land on a face."""
        lp = self.lp
        n = np.int64(len(vmap))
        first = lp.flat[lp.starts].astype(np.int64)
        second = lp.flat[lp.nxt[lp.starts]].astype(np.int64)
        want = vmap[first] * n + vmap[second]
        at = np.searchsorted(self.keys, want)
        at = np.minimum(at, len(self.keys) - 1)
        if not np.array_equal(self.keys[at], want):
            return None
        corner = self.order[at]
        fmap = lp.owner[corner].astype(_INDEX)
        shift = self.corner[corner].astype(_INDEX)
        # every corner of every face must land on the image face, in loop order
        img = fmap[lp.owner]
        pos = (self.corner + shift[lp.owner]) % self.n_edges[img]
        if not np.array_equal(lp.flat[lp.starts[img] + pos], vmap[lp.flat]):
            return None
        return fmap, shift

    def plausible(self, src: FloatArray) -> list[tuple[int, int]]:
        """The flags (face number, edge k - 1) that the first face's edge 1 may be sent to:
        the rotation that does it also sends the first face's first three corners onto the
        other face's corners in order (within the gate; the third, farther from the edge, a
        looser one). Tested for every flag at once: a sphere of 300,000 triangles has a
        million flags, and a nearest-neighbour search over its vertices for each would take
        hours."""
        poly, lp, rel = self.poly, self.lp, self.rel
        n0 = int(lp.lengths[0])
        area = np.array(list(poly.face_areas.values()))
        ok_face = (lp.lengths == n0) & (np.abs(area - area[0]) <= self.gate * poly.diameter)
        corners = np.flatnonzero(ok_face[lp.owner])
        owner = lp.owner[corners]
        start = lp.flat[corners]
        nxt = lp.flat[lp.nxt[corners]]
        u = rel[nxt] - rel[start]
        u /= np.linalg.norm(u, axis=1)[:, None]
        nrm = poly._normal_array[owner]
        w = np.cross(nrm, u)
        pos = self.corner[corners]
        keep = np.ones(len(corners), dtype=bool)
        for m, slack in ((0, 1.0), (1, 1.0), (2, 4.0)):
            a, b, c = src.T @ rel[lp.flat[m % n0]]
            want = rel[lp.flat[lp.starts[owner] + (pos + m) % n0]]
            miss = np.linalg.norm(a * u + b * w + c * nrm - want, axis=1)
            keep &= miss <= slack * self.gate
        return list(zip(owner[keep].tolist(), pos[keep].tolist(), strict=True))

    def candidate(self, g: str, k: int, src: FloatArray, i0: int) -> _Element | None:
        """The symmetry sending edge 1 of the first face to edge ``k`` of ``g``, if any."""
        poly, rel, atol, gate = self.poly, self.rel, self.atol, self.gate
        u = poly.edge_direction(g, k)
        dst = np.column_stack([u, np.cross(poly.normals[g], u), poly.normals[g]])
        rot = dst @ src.T
        i, _ = poly.edge_vertices(g, k)
        # a measured object's edges are a little off: the rotation from one edge is only
        # a first guess (gated loosely), refined by a least-squares fit (Kabsch) over
        # every vertex it pairs, and then held to the tolerance
        if np.linalg.norm(rot @ rel[i0] - rel[i]) > gate:
            return None
        dist, idx = self.tree.query(rel @ rot.T)
        if dist.max() > gate or len(np.unique(idx)) != len(rel):
            return None
        rot, shift_t = _fit(rel, rel[idx], atol)
        if np.linalg.norm(rot @ self.com_rel + shift_t - self.com_rel) > atol:
            return None
        dist, idx = self.tree.query(rel @ rot.T + shift_t)
        if dist.max() > atol or len(np.unique(idx)) != len(rel):
            return None
        vmap = np.asarray(idx, dtype=_INDEX)
        faces = self.faces_of(vmap)
        if faces is None:
            return None
        return _Element(rot, shift_t, vmap, *faces)

    def holds(self, e: _Element) -> bool:
        """Whether a composed element is still a symmetry within the tolerance (measured
        models: two moves each off by up to the tolerance may be off by twice as much)."""
        miss = np.linalg.norm(self.rel @ e.rot.T + e.t - self.rel[e.vmap], axis=1)
        return bool(miss.max() <= self.atol) and bool(
            np.linalg.norm(e.rot @ self.com_rel + e.t - self.com_rel) <= self.atol)


def _closure(gens: list[_Element], identity: _Element, n_edges: IndexArray
             ) -> dict[bytes, _Element]:
    """Every product of ``gens``: the group they generate, keyed by vertex map."""
    group = {identity.vmap.tobytes(): identity}
    frontier = [identity]
    while frontier:
        nxt = []
        for x in frontier:
            for h in gens:
                y = h.after(x, n_edges)
                key = y.vmap.tobytes()
                if key not in group:
                    group[key] = y
                    nxt.append(y)
        frontier = nxt
    return group


@lru_cache(maxsize=128)
def _rotation_group_cached(poly: Polyhedron, atol: float) -> tuple[Symmetry, ...]:
    return tuple(_as_symmetry(poly, e) for e in _group_elements(poly, atol))


@lru_cache(maxsize=16)
def _group_elements(poly: Polyhedron, atol: float) -> tuple[_Element, ...]:
    """The group as arrays, identity first, then in the order of the vertex maps."""
    search = _GroupSearch(poly, atol)
    # A proper rotation symmetry is fixed by where it sends one flag (face f0, edge 1).
    # Trying every (face, edge) with the same number of edges would find them all, at one
    # nearest-neighbour search over the vertices each: 16 million point queries for the
    # 4,000 symmetries of a 2,000-sided prism. Instead a flag is tried only when no product
    # of the symmetries found so far sends edge 1 there: each one found is a generator, the
    # group is closed under products (exact array compositions), and at most log2 |G|
    # generators are ever needed.
    f0 = poly.face_ids[0]
    i0, _ = poly.edge_vertices(f0, 1)
    src = np.column_stack(
        [poly.edge_direction(f0, 1), np.cross(poly.normals[f0], poly.edge_direction(f0, 1)),
         poly.normals[f0]]
    )
    n_v = len(poly.vertices)
    identity = _Element(np.eye(3), np.zeros(3), np.arange(n_v, dtype=_INDEX),
                        np.arange(len(poly.faces), dtype=_INDEX),
                        np.zeros(len(poly.faces), dtype=_INDEX))
    gens: list[_Element] = []
    group = {identity.vmap.tobytes(): identity}
    covered = {(0, 0)}
    for gi, k0 in search.plausible(src):
        if (gi, k0) in covered:
            continue
        e = search.candidate(poly.face_ids[gi], k0 + 1, src, i0)
        if e is None:
            continue
        gens.append(e)
        group = _closure(gens, identity, search.n_edges)
        if not all(search.holds(x) for x in group.values()):
            # products of measured symmetries drift past the tolerance: test every
            # flag on its own, as the definition says
            return _every_flag(poly, search, src, i0, identity)
        covered = {(int(x.fmap[0]), int(x.shift[0])) for x in group.values()}
    return _ordered(group.values())


def _every_flag(poly: Polyhedron, search: _GroupSearch, src: FloatArray, i0: int,
                identity: _Element) -> tuple[_Element, ...]:
    f0 = poly.face_ids[0]
    found = [identity]
    for g in poly.face_ids:
        if poly.n_edges(g) != poly.n_edges(f0):
            continue
        for k in range(1, poly.n_edges(f0) + 1):
            if g == f0 and k == 1:
                continue
            e = search.candidate(g, k, src, i0)
            if e is not None:
                found.append(e)
    return _ordered(found)


def _ordered(elements: Iterable[_Element]) -> tuple[_Element, ...]:
    """Identity first, then by vertex map (lexicographic: big-endian bytes compare as the
    numbers do)."""
    def key(e: _Element) -> tuple[bool, bytes]:
        return (not np.array_equal(e.vmap, np.arange(len(e.vmap))),
                e.vmap.astype(">i8").tobytes())

    return tuple(sorted(elements, key=key))


def _as_symmetry(poly: Polyhedron, e: _Element) -> Symmetry:
    index = {f: i for i, f in enumerate(poly.face_ids)}
    rot = np.array(e.rot, dtype=np.float64)
    rot.setflags(write=False)
    for a in (e.vmap, e.fmap, e.shift):
        a.setflags(write=False)
    return Symmetry(rot, _FaceArrayMap(index, e.fmap, poly.face_ids),
                    _FaceArrayMap(index, e.shift), _Ints(e.vmap))


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


def group_arrays(
    poly: Polyhedron, atol: float | None = None
) -> tuple[NDArray[np.int32], NDArray[np.int32]]:
    """The group's face maps and edge shifts as arrays, for acting on many states at once.

    Returns
    -------
    face_maps : array of int, shape (n_symmetries, n_faces)
        ``face_maps[g, f]``: the number (in model order) of the face symmetry ``g`` sends
        face ``f`` to; rows in the order of :func:`rotation_group`.
    edge_shifts : array of int, shape (n_symmetries, n_faces)
        ``edge_shifts[g, f]``: :attr:`Symmetry.edge_shift` of face ``f``.
    """
    elements = _group_elements(poly, _default_atol(poly, atol))
    return np.stack([e.fmap for e in elements]), np.stack([e.shift for e in elements])
