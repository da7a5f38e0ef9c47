"""The object model of the paper's Section III: a convex polyhedron with labeled faces.

Conventions (``shared/spec/conventions.md``):

* each face is a loop of vertex indices listed clockwise when the face is viewed from outside;
* edge ``k`` (1-based) of a face runs from loop vertex ``k`` to loop vertex ``k + 1``;
* the adjacency matrix ``A[f][g] = k`` says edge ``k`` of face ``f`` is shared with face ``g``;
* the face shape ``Delta_f = [d_1, d_2, ...]`` (``d_1 = 0``) gives the angle, counterclockwise
  seen from inside the object, that turns edge 1 onto edge ``k``.

A :class:`Polyhedron` is a value: it is validated when made and never changes; every derived
quantity (normals, ``A``, ``Delta``, centre of mass, ...) is computed once, on first use.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from nonprehensile.checks import check_tolerance
from nonprehensile.errors import InputError, ModelError

__all__ = ["DEFAULT_RTOL", "Polyhedron", "check_polyhedron", "wrap_index"]

#: Default length tolerance, relative to the object's diameter.
DEFAULT_RTOL = 1e-7

FloatArray = NDArray[np.float64]


def wrap_index(k: int, n: int) -> int:
    """Modular edge index on a face with ``n`` edges: ``0 -> n``, ``n + 1 -> 1``.

    Parameters
    ----------
    k : int
        Any integer edge index.
    n : int
        Number of edges of the face.

    Returns
    -------
    int
        The equivalent index in ``1..n``.
    """
    return (k - 1) % n + 1


def _newell(points: FloatArray) -> FloatArray:
    """Newell's normal of a polygon: right-handed with respect to the loop order.

    Parameters
    ----------
    points : array, shape (n, 3)
        The loop's vertices in order.

    Returns
    -------
    array, shape (3,)
        Twice the vector area of the polygon (not normalised).
    """
    nxt = np.roll(points, -1, axis=0)
    return np.asarray(np.sum(np.cross(points, nxt), axis=0), dtype=np.float64)


@dataclass(frozen=True, eq=False)
class Polyhedron:
    """A convex polyhedron with labeled faces (the paper's object model).

    Parameters
    ----------
    vertices : array-like, shape (n_vertices, 3)
        Points in the object's own frame.
    faces : mapping of str to sequence of int
        Face ID to its vertex loop (0-based indices into ``vertices``), clockwise from outside.
    name : str
        Name of the object.
    center_of_mass : array-like, shape (3,), optional
        Centre of mass; default the centroid of the uniform solid.
    virtual_faces : iterable of str
        Faces of the convex hull that are not faces of the original (non-convex) object: the
        paper's virtual bottom faces, where the object rests on edges or vertices.
    units : str
        Length units of ``vertices`` (default metres).
    rtol : float
        Length tolerance relative to the object's diameter, used by validation and by every
        geometric comparison made with this model.

    Raises
    ------
    ModelError
        If the loops are not planar, not convex, not consistently ordered clockwise from
        outside, do not close the surface, or the solid is not convex; the message names the
        face.
    """

    vertices: FloatArray
    faces: Mapping[str, tuple[int, ...]]
    name: str = "object"
    center_of_mass: FloatArray | None = None
    virtual_faces: frozenset[str] = field(default_factory=frozenset)
    units: str = "m"
    rtol: float = DEFAULT_RTOL

    def __post_init__(self) -> None:
        object.__setattr__(self, "rtol", _check_rtol(self.rtol))
        vertices, faces = check_polyhedron(self.vertices, self.faces, rtol=self.rtol)
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "virtual_faces", frozenset(self.virtual_faces))
        unknown = sorted(set(self.virtual_faces) - set(faces))
        if unknown:
            raise ModelError(
                f"virtual_faces names {unknown}, which are not faces of the model; "
                f"expected a subset of {sorted(faces)}"
            )
        if self.center_of_mass is not None:
            try:
                com = np.array(self.center_of_mass, dtype=float)
            except (TypeError, ValueError):
                com = np.full(1, np.nan)
            if com.shape != (3,) or not np.all(np.isfinite(com)):
                raise ModelError(
                    f"center_of_mass must be 3 finite numbers, got {self.center_of_mass!r}"
                )
            outside = self._plane_distances(com[None, :]).max()
            if outside > self.atol:
                raise ModelError(
                    f"center_of_mass {com.tolist()} lies outside the polyhedron "
                    f"(by {outside:.3g} {self.units}); a rigid body's centre of mass is inside "
                    "its convex hull"
                )
            object.__setattr__(self, "center_of_mass", com)
            com.setflags(write=False)
        else:
            object.__setattr__(self, "center_of_mass", self._solid_centroid())

    # ------------------------------------------------------------------ basic sizes
    @property
    def face_ids(self) -> tuple[str, ...]:
        """Face IDs in the model's order."""
        return tuple(self.faces)

    @cached_property
    def diameter(self) -> float:
        """Largest distance between two vertices."""
        v = self.vertices
        return float(np.max(np.linalg.norm(v[:, None, :] - v[None, :, :], axis=-1)))

    @property
    def atol(self) -> float:
        """Absolute length tolerance: ``rtol`` times the diameter."""
        return self.rtol * self.diameter

    @property
    def com(self) -> FloatArray:
        """Centre of mass, shape (3,)."""
        assert self.center_of_mass is not None  # set in __post_init__
        return self.center_of_mass

    # ------------------------------------------------------------------ faces
    def n_edges(self, face: str) -> int:
        """Number of edges of ``face``."""
        return len(self.loop(face))

    def loop(self, face: str) -> tuple[int, ...]:
        """Vertex loop of ``face`` (clockwise from outside).

        Raises
        ------
        ModelError
            If the object has no such face.
        """
        try:
            return self.faces[face]
        except KeyError:
            raise ModelError(
                f"the object {self.name!r} has no face {face!r}; its faces are "
                f"{list(self.faces)}"
            ) from None

    @cached_property
    def normals(self) -> dict[str, FloatArray]:
        """Outward unit normal of each face, shape (3,) each."""
        out = {}
        for f, loop in self.faces.items():
            n = -_newell(self.vertices[list(loop)])  # loops are clockwise from outside
            out[f] = n / np.linalg.norm(n)
        return out

    @cached_property
    def face_centroids(self) -> dict[str, FloatArray]:
        """Area centroid of each face, shape (3,) each."""
        out = {}
        for f, loop in self.faces.items():
            p = self.vertices[list(loop)]
            # fan triangulation from the first vertex, weighted by triangle area
            a, b, c = p[0], p[1:-1], p[2:]
            areas = np.linalg.norm(np.cross(b - a, c - a), axis=1)
            cents = (a + b + c) / 3.0
            out[f] = (areas[:, None] * cents).sum(axis=0) / areas.sum()
        return out

    @cached_property
    def face_areas(self) -> dict[str, float]:
        """Area of each face."""
        return {
            f: 0.5 * float(np.linalg.norm(_newell(self.vertices[list(loop)])))
            for f, loop in self.faces.items()
        }

    def edge_vertices(self, face: str, k: int) -> tuple[int, int]:
        """Vertex indices ``(start, end)`` of edge ``k`` of ``face`` (modular ``k``)."""
        loop = self.loop(face)
        n = len(loop)
        k = wrap_index(k, n)
        return loop[k - 1], loop[k % n]

    def edge_direction(self, face: str, k: int) -> FloatArray:
        """Unit direction of edge ``k`` of ``face`` in the object frame, shape (3,)."""
        i, j = self.edge_vertices(face, k)
        d = self.vertices[j] - self.vertices[i]
        return np.asarray(d / np.linalg.norm(d), dtype=np.float64)

    # ------------------------------------------------------------------ adjacency
    @cached_property
    def _directed_edges(self) -> dict[tuple[int, int], tuple[str, int]]:
        """Directed edge ``(i, j)`` to the face that runs it and its edge number there."""
        out: dict[tuple[int, int], tuple[str, int]] = {}
        for f, loop in self.faces.items():
            n = len(loop)
            for k in range(1, n + 1):
                out[(loop[k - 1], loop[k % n])] = (f, k)
        return out

    @cached_property
    def adjacency(self) -> dict[str, dict[str, int]]:
        """The paper's adjacency matrix of edge numbers as nested dicts.

        ``adjacency[f][g] = k`` means edge ``k`` of face ``f`` is shared with face ``g``;
        faces that share no edge (and the diagonal) are absent.
        """
        out: dict[str, dict[str, int]] = {f: {} for f in self.faces}
        for (i, j), (f, k) in self._directed_edges.items():
            g, _ = self._directed_edges[(j, i)]
            out[f][g] = k
        # keep each row ordered by edge number: the order a reader walks the face
        return {f: dict(sorted(row.items(), key=lambda kv: kv[1])) for f, row in out.items()}

    def adjacency_matrix(self) -> tuple[tuple[str, ...], NDArray[np.int64]]:
        """The adjacency matrix as an array, as printed in the paper's Fig. 3(b).

        Returns
        -------
        labels : tuple of str
            Face IDs of the rows and columns.
        A : array of int, shape (n_faces, n_faces)
            Edge numbers; ``0`` where undefined (diagonal, faces sharing no edge).
        """
        labels = self.face_ids
        pos = {f: i for i, f in enumerate(labels)}
        a = np.zeros((len(labels), len(labels)), dtype=np.int64)
        for f, row in self.adjacency.items():
            for g, k in row.items():
                a[pos[f], pos[g]] = k
        return labels, a

    def neighbor(self, face: str, k: int) -> str:
        """The face across edge ``k`` (modular) of ``face``."""
        i, j = self.edge_vertices(face, k)
        return self._directed_edges[(j, i)][0]

    def edge_index(self, face: str, other: str) -> int:
        """``A[face][other]``: the number, on ``face``, of the edge shared with ``other``.

        Raises
        ------
        ModelError
            If the two faces share no edge.
        """
        self.loop(face)
        row = self.adjacency[face]
        if other not in row:
            self.loop(other)
            raise ModelError(
                f"faces {face!r} and {other!r} share no edge; {face!r} borders {list(row)}"
            )
        return row[other]

    @cached_property
    def delta(self) -> dict[str, tuple[float, ...]]:
        """Face shapes ``Delta_f``: edge alignment angles in degrees, ``d_1 = 0``.

        ``d_k`` turns edge 1 onto edge ``k``, counterclockwise seen from inside the object
        (that is, positively about the inward normal), in ``[0, 360)``.
        """
        out = {}
        for f in self.faces:
            n_in = -self.normals[f]
            dirs = np.array([self.edge_direction(f, k) for k in range(1, self.n_edges(f) + 1)])
            e1 = dirs[0]
            sin = np.cross(e1, dirs) @ n_in
            cos = dirs @ e1
            ang = np.degrees(np.arctan2(sin, cos)) % 360.0
            ang = np.where(np.isclose(ang, 360.0, atol=1e-9), 0.0, ang)
            ang[0] = 0.0
            out[f] = tuple(float(round(a, 10)) for a in ang)
        return out

    # ------------------------------------------------------------------ edges and vertices
    @cached_property
    def edges(self) -> dict[frozenset[str], tuple[int, int]]:
        """Each edge, keyed by its two faces, to its vertex indices (as run by the first face)."""
        out: dict[frozenset[str], tuple[int, int]] = {}
        for (i, j), (f, _) in self._directed_edges.items():
            g = self._directed_edges[(j, i)][0]
            out.setdefault(frozenset((f, g)), (i, j))
        return out

    @cached_property
    def vertex_faces(self) -> tuple[frozenset[str], ...]:
        """For each vertex index, the set of faces that meet there."""
        acc: list[set[str]] = [set() for _ in range(len(self.vertices))]
        for f, loop in self.faces.items():
            for i in loop:
                acc[i].add(f)
        return tuple(frozenset(s) for s in acc)

    def shared_vertices(self, faces: Iterable[str]) -> list[int]:
        """Indices of the vertices that every one of ``faces`` contains."""
        wanted = set(faces)
        for f in wanted:
            self.loop(f)
        return [i for i, fs in enumerate(self.vertex_faces) if wanted <= fs]

    # ------------------------------------------------------------------ solid
    def _plane_distances(self, points: FloatArray) -> FloatArray:
        """Signed distances of ``points`` (shape (m, 3)) to every face plane, shape (m, F)."""
        n = np.array([self.normals[f] for f in self.faces])
        p = np.array([self.vertices[self.faces[f][0]] for f in self.faces])
        return np.asarray(points @ n.T - np.sum(n * p, axis=1))

    @cached_property
    def volume(self) -> float:
        """Volume of the solid."""
        return self._volume_and_centroid()[0]

    def _solid_centroid(self) -> FloatArray:
        com = self._volume_and_centroid()[1]
        com.setflags(write=False)
        return com

    def _volume_and_centroid(self) -> tuple[float, FloatArray]:
        # Decompose into tetrahedra (vertex centroid, fan triangle); the reference point is
        # interior because the solid is convex, so every volume is positive.
        ref = self.vertices.mean(axis=0)
        vol = 0.0
        acc = np.zeros(3)
        for loop in self.faces.values():
            p = self.vertices[list(loop)]
            a, b, c = p[0], p[1:-1], p[2:]
            # outward normal is -(b-a)x(c-a) direction for a clockwise loop
            v = (np.cross(c - a, b - a) @ (a - ref)) / 6.0
            vol += float(v.sum())
            acc += ((ref + a + b + c) / 4.0 * v[:, None]).sum(axis=0)
        return vol, acc / vol


def _check_rtol(rtol: object) -> float:
    try:
        return check_tolerance(rtol, "rtol")
    except InputError as exc:
        raise ModelError(str(exc)) from None


def check_polyhedron(
    vertices: object, faces: object, *, rtol: float = DEFAULT_RTOL
) -> tuple[FloatArray, dict[str, tuple[int, ...]]]:
    """Validate a polyhedron given as vertices and clockwise face loops.

    Parameters
    ----------
    vertices : array-like, shape (n_vertices, 3)
        Points in the object's frame.
    faces : mapping of str to sequence of int
        Face ID to vertex loop.
    rtol : float
        Length tolerance relative to the diameter.

    Returns
    -------
    vertices : array, shape (n_vertices, 3)
        A read-only float copy.
    faces : dict of str to tuple of int
        The loops as tuples.

    Raises
    ------
    ModelError
        Naming the face (or vertex) at fault and how to fix it.
    """
    rtol = _check_rtol(rtol)
    try:
        v = np.array(vertices, dtype=float)
    except (TypeError, ValueError):
        raise ModelError(
            "vertices must be a list of [x, y, z] points (3 numbers each); got a ragged or "
            "non-numeric list"
        ) from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise ModelError(f"vertices must have shape (n, 3), got shape {v.shape}")
    if len(v) < 4:
        raise ModelError(f"a polyhedron needs at least 4 vertices, got {len(v)}")
    bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
    if bad.size:
        raise ModelError(f"vertex {int(bad[0])} is not finite: {v[bad[0]].tolist()}")
    v.setflags(write=False)
    if not isinstance(faces, Mapping):
        raise ModelError(
            f"faces must map face IDs to vertex loops, got {type(faces).__name__}"
        )
    if len(faces) < 4:
        raise ModelError(f"a polyhedron needs at least 4 faces, got {len(faces)}")
    loops: dict[str, tuple[int, ...]] = {}
    for f, loop in faces.items():
        if not isinstance(f, str) or not f:
            raise ModelError(f"face IDs must be non-empty strings, got {f!r}")
        if not isinstance(loop, (list, tuple)) or not all(
            isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in loop
        ):
            raise ModelError("the loop must be a list of vertex indices", face=f)
        t = tuple(int(i) for i in loop)
        if len(t) < 3:
            raise ModelError(f"a face needs at least 3 vertices, got {len(t)}", face=f)
        if len(set(t)) != len(t):
            raise ModelError(f"the loop {list(t)} repeats a vertex", face=f)
        out_of_range = [i for i in t if not 0 <= i < len(v)]
        if out_of_range:
            raise ModelError(
                f"vertex index {out_of_range[0]} is out of range 0..{len(v) - 1}", face=f
            )
        loops[f] = t

    used = {i for t in loops.values() for i in t}
    unused = sorted(set(range(len(v))) - used)
    if unused:
        raise ModelError(
            f"vertex {unused[0]} {v[unused[0]].tolist()} is on no face; remove it or add it "
            "to the faces that meet there"
        )

    diameter = float(np.max(np.linalg.norm(v[:, None, :] - v[None, :, :], axis=-1)))
    atol = rtol * diameter
    center = v.mean(axis=0)

    newell = {}
    for f, t in loops.items():
        p = v[list(t)]
        nv = _newell(p)
        norm = float(np.linalg.norm(nv))
        if norm <= atol * diameter:
            raise ModelError(
                "the face has no area: its vertices are collinear, or its loop crosses itself",
                face=f,
            )
        n_loop = nv / norm
        off = np.abs((p - p.mean(axis=0)) @ n_loop)
        if off.max() > atol:
            i = int(np.argmax(off))
            raise ModelError(
                f"the face is not planar: vertex {t[i]} is {off[i]:.3g} off its plane "
                f"(tolerance {atol:.3g})",
                face=f,
            )
        # convex polygon: every turn goes the same way as the loop's normal; the height of
        # each corner above the line through its neighbours measures how sharp the turn is
        e = np.roll(p, -1, axis=0) - p
        e_next = np.roll(e, -1, axis=0)
        len_e = np.linalg.norm(e, axis=1)
        len_next = np.linalg.norm(e_next, axis=1)
        sin = (np.cross(e, e_next) @ n_loop) / (len_e * len_next)
        height = sin * np.minimum(len_e, len_next)
        i = int(np.argmin(height))
        if height[i] <= atol:
            corner = t[(i + 1) % len(t)]
            if height[i] >= -atol:
                raise ModelError(
                    f"vertex {corner} is collinear with its neighbours on the loop; remove it",
                    face=f,
                )
            raise ModelError(
                f"the face is not convex (it turns the other way at vertex {corner}), or its "
                "loop is not in order around the face",
                face=f,
            )
        newell[f] = n_loop

    # closed, consistently ordered surface: every directed edge once, its reverse once
    directed: dict[tuple[int, int], str] = {}
    for f, t in loops.items():
        n = len(t)
        for k in range(n):
            key = (t[k], t[(k + 1) % n])
            if key in directed:
                raise ModelError(
                    f"faces {directed[key]!r} and {f!r} both run edge {key[0]}->{key[1]} in "
                    "the same direction: the loops are not consistently ordered; list every "
                    "loop clockwise as seen from outside",
                    face=f,
                )
            directed[key] = f
    for (i, j), f in directed.items():
        if (j, i) not in directed:
            raise ModelError(
                f"edge {i}-{j} belongs to no other face: the surface is not closed; add the "
                "missing face or fix the loop",
                face=f,
            )
    n_edges = len(directed) // 2
    euler = len(v) - n_edges + len(loops)
    if euler != 2:
        raise ModelError(
            f"V - E + F = {len(v)} - {n_edges} + {len(loops)} = {euler}, expected 2: the "
            "faces do not bound one solid without holes"
        )

    # clockwise from outside: the loop's right-handed normal points into the solid
    for f, t in loops.items():
        c = v[list(t)].mean(axis=0)
        if (c - center) @ newell[f] > 0:
            raise ModelError(
                "the loop is counterclockwise seen from outside; list it clockwise "
                f"(reverse it: {list(reversed(t))})",
                face=f,
            )

    # convex solid: no vertex in front of any face plane
    for f, t in loops.items():
        n_out = -newell[f]
        d = (v - v[t[0]]) @ n_out
        if d.max() > atol:
            i = int(np.argmax(d))
            raise ModelError(
                f"vertex {i} lies {d[i]:.3g} outside the face's plane: the polyhedron is not "
                "convex; use the convex hull (nonprehensile object from-mesh) instead",
                face=f,
            )
    for (i, j), f in directed.items():
        g = directed[(j, i)]
        if f < g and np.all(np.abs((v[list(loops[g])] - v[i]) @ newell[f]) <= atol):
            raise ModelError(
                f"faces {f!r} and {g!r} are coplanar across edge {i}-{j}; merge them into one face",
                face=f,
            )
    return v, loops
