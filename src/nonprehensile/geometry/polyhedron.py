"""The object model of the paper's Section III: a convex polyhedron with labeled faces.

Conventions (docs/object-model.md):

* each face is a loop of vertex indices listed clockwise when the face is viewed from outside;
* edge ``k`` (1-based) of a face runs from loop vertex ``k`` to loop vertex ``k + 1``;
* the adjacency matrix ``A[f][g] = k`` says edge ``k`` of face ``f`` is shared with face ``g``;
* the face shape ``Delta_f = [d_1, d_2, ...]`` (``d_1 = 0``) gives the angle, counterclockwise
  seen from inside the object, that turns edge 1 onto edge ``k``.

A :class:`Polyhedron` is a value: it is validated when made and never changes; every derived
quantity (normals, ``A``, ``Delta``, centre of mass, ...) is computed once, on first use.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import InitVar, dataclass, field
from functools import cached_property, lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

from nonprehensile.checks import DEFAULT_RTOL, RTOL_RANGE
from nonprehensile.errors import InputError, ModelError

__all__ = [
    "DEFAULT_RTOL",
    "MAX_COORDINATE",
    "MIN_SIZE",
    "Polyhedron",
    "check_polyhedron",
    "point_diameter",
    "wrap_index",
]

#: Largest coordinate magnitude accepted: squares and cubes of it stay finite in float64.
MAX_COORDINATE = 1e100
#: Smallest object accepted, in its own units (the largest side of its bounding box): its
#: areas (size^2) and volumes (size^3) stay far from float underflow, and no real part is a
#: picometre across in metres.
MIN_SIZE = 1e-12
#: A corner whose height above the line through its neighbours is at most this fraction of
#: the tolerance is collinear (a vertex to remove).
COLLINEAR_FRACTION = 1.0
#: Neighbouring faces within this fraction of the tolerance of one plane are one face.
COPLANAR_FRACTION = 1.0

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
    hull_facets : bool
        True when the faces are a convex hull's own facets, as the builders make them
        (:func:`~nonprehensile.geometry.convex_hull`, ``from_mesh``): the solid is convex by
        construction, so the last check, of its volume against a second convex hull of its
        vertices, is skipped (at 50,000 vertices that hull is 15 % of building the model).
        Every face, edge and the closed surface are checked all the same. Not stored: a copy
        made with :func:`dataclasses.replace` is checked in full.

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
    hull_facets: InitVar[bool] = False

    def __post_init__(self, hull_facets: bool) -> None:
        object.__setattr__(self, "rtol", _check_rtol(self.rtol))
        checked = _check(self.vertices, self.faces, self.rtol, hull_facets=bool(hull_facets))
        faces = checked.loops
        object.__setattr__(self, "vertices", checked.vertices)
        object.__setattr__(self, "faces", faces)
        # derived arrays found while checking: cached, never recomputed
        self.__dict__["diameter"] = checked.diameter
        self.__dict__["_loops"] = checked.flat
        self.__dict__["_normal_array"] = checked.unit_normals
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
        """Largest distance between two vertices (found once, from the convex hull)."""
        return point_diameter(self.vertices)

    @cached_property
    def _loops(self) -> _Loops:
        return _Loops.of(self.faces.values())

    @cached_property
    def _normal_array(self) -> FloatArray:
        n = -self._loops.newell(self.vertices)
        return np.asarray(n / np.linalg.norm(n, axis=1)[:, None], dtype=np.float64)

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
        # loops are clockwise from outside, so Newell's vector points inward
        return dict(zip(self.faces, self._normal_array, strict=True))

    @cached_property
    def normal_matrix(self) -> FloatArray:
        """The outward unit normals as rows in the faces' order, shape (n_faces, 3) (the
        values of :attr:`normals`; read only)."""
        out = np.array(list(self.normals.values()), dtype=np.float64)
        out.setflags(write=False)
        return out

    @cached_property
    def plane_offsets(self) -> FloatArray:
        """Each face plane's offset: its outward unit normal dotted with its first vertex,
        in the faces' order, shape (n_faces,) (a point ``x`` is outside face ``i`` when
        ``normal_matrix[i] @ x > plane_offsets[i]``; read only)."""
        out = np.array([self.normals[f] @ self.vertices[self.faces[f][0]] for f in self.faces])
        out.setflags(write=False)
        return out

    @cached_property
    def first_edge_directions(self) -> dict[str, FloatArray]:
        """:meth:`edge_direction` of each face's edge 1 (a state's ``theta`` is measured on
        it), shape (3,) each."""
        return {f: self.edge_direction(f, 1) for f in self.faces}

    @cached_property
    def face_centroids(self) -> dict[str, FloatArray]:
        """Area centroid of each face, shape (3,) each."""
        lp = self._loops
        a, b, c = _fans(self.vertices, lp)
        # fan triangulation from the first vertex, weighted by triangle area
        areas = np.linalg.norm(np.cross(b - a, c - a), axis=1)
        owner = lp.owner[_fan_mask(lp)]
        acc = np.zeros((len(lp.lengths), 3))
        np.add.at(acc, owner, areas[:, None] * (a + b + c) / 3.0)
        tot = np.bincount(owner, weights=areas, minlength=len(lp.lengths))
        return dict(zip(self.faces, acc / tot[:, None], strict=True))

    @cached_property
    def face_areas(self) -> dict[str, float]:
        """Area of each face."""
        areas = 0.5 * np.linalg.norm(self._loops.newell(self.vertices), axis=1)
        return dict(zip(self.faces, areas.tolist(), strict=True))

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
        lp = self._loops
        v = self.vertices
        dirs = v[lp.flat[lp.nxt]] - v[lp.flat]
        dirs /= np.linalg.norm(dirs, axis=1)[:, None]
        e1 = dirs[lp.starts][lp.owner]
        n_in = -self._normal_array[lp.owner]
        sin = np.einsum("ij,ij->i", np.cross(e1, dirs), n_in)
        cos = np.einsum("ij,ij->i", dirs, e1)
        ang = np.degrees(np.arctan2(sin, cos)) % 360.0
        ang = np.where(np.isclose(ang, 360.0, atol=1e-9), 0.0, ang)
        ang[lp.starts] = 0.0
        ang = np.round(ang, 10)
        return {
            f: tuple(ang[s : s + n].tolist())
            for f, s, n in zip(self.faces, lp.starts.tolist(), lp.lengths.tolist(), strict=True)
        }

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
        n = self._normal_array
        p = self.vertices[self._loops.flat[self._loops.starts]]
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
        a, b, c = _fans(self.vertices, self._loops)
        # outward normal is -(b-a)x(c-a) direction for a clockwise loop
        v = np.einsum("ij,ij->i", np.cross(c - a, b - a), a - ref) / 6.0
        vol = float(v.sum())
        acc = ((ref + a + b + c) / 4.0 * v[:, None]).sum(axis=0)
        return vol, acc / vol


def _check_rtol(rtol: object) -> float:
    try:
        return float(RTOL_RANGE.check(rtol, "rtol"))
    except InputError as exc:
        raise ModelError(str(exc)) from None


@dataclass(frozen=True)
class _Loops:
    """The face loops flattened into arrays, for vectorised per-face work.

    Attributes
    ----------
    flat : array of int, shape (n_corners,)
        Every loop's vertex indices, face after face (the faces' order).
    owner : array of int, shape (n_corners,)
        Index of the face each corner belongs to.
    starts, lengths : arrays of int, shape (n_faces,)
        Where each face's corners start in ``flat`` and how many there are.
    nxt : array of int, shape (n_corners,)
        Position in ``flat`` of the next corner of the same loop (wrapping round).
    """

    flat: NDArray[np.int64]
    owner: NDArray[np.int64]
    starts: NDArray[np.int64]
    lengths: NDArray[np.int64]
    nxt: NDArray[np.int64]

    @classmethod
    def of(cls, loops: Iterable[Sequence[int]]) -> _Loops:
        seqs = list(loops)
        lengths = np.fromiter(map(len, seqs), dtype=np.int64, count=len(seqs))
        flat = np.fromiter(itertools.chain.from_iterable(seqs), dtype=np.int64,
                           count=int(lengths.sum()))
        starts = np.zeros(len(seqs), dtype=np.int64)
        np.cumsum(lengths[:-1], out=starts[1:])
        owner = np.repeat(np.arange(len(seqs), dtype=np.int64), lengths)
        pos = np.arange(len(flat), dtype=np.int64) - starts[owner]
        nxt = starts[owner] + (pos + 1) % lengths[owner]
        return cls(flat, owner, starts, lengths, nxt)

    def face_sum(self, values: FloatArray) -> FloatArray:
        """Per-face sums of per-corner ``values`` (shape (n_corners, ...))."""
        return np.asarray(np.add.reduceat(values, self.starts, axis=0), dtype=np.float64)

    def face_max(self, values: FloatArray) -> FloatArray:
        """Per-face maxima of per-corner ``values``."""
        return np.asarray(np.maximum.reduceat(values, self.starts, axis=0), dtype=np.float64)

    def newell(self, v: FloatArray) -> FloatArray:
        """Newell's vector of every loop (twice its vector area), shape (n_faces, 3)."""
        p = v[self.flat]
        return self.face_sum(np.cross(p, p[self.nxt]))

    def means(self, v: FloatArray) -> FloatArray:
        """Vertex mean of every loop, shape (n_faces, 3)."""
        return self.face_sum(v[self.flat]) / self.lengths[:, None]


def point_diameter(points: FloatArray) -> float:
    """Largest distance between two of ``points`` (shape (n, 3)), exactly, in O(n) memory.

    Only the convex hull's vertices can realise the diameter. Small sets are compared all
    against all, in chunks; larger ones are cut into blocks of nearby points, and only the
    pairs of blocks whose bounding boxes can hold a pair farther apart than the best pair
    found so far are compared (a farthest-pair search: on a sphere, only roughly antipodal
    blocks remain).
    """
    p = np.asarray(points, dtype=np.float64)
    if len(p) < 2:
        return 0.0
    if len(p) > 64:
        with contextlib.suppress(QhullError):  # flat or degenerate: every point may matter
            p = p[ConvexHull(p).vertices]
    return _diameter_of(p)


class _PointsKey:
    """A point array as a memo key: hashed and compared by content (a read-only copy)."""

    __slots__ = ("_hash", "array")

    def __init__(self, points: FloatArray) -> None:
        a = np.array(points, dtype=np.float64, order="C")
        a.setflags(write=False)
        self.array = a
        digest = hashlib.blake2b(a.tobytes(), digest_size=16).digest()
        self._hash = hash((a.shape, digest))

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, _PointsKey) and self._hash == other._hash
                and self.array.shape == other.array.shape
                and bool(np.array_equal(self.array, other.array)))


@lru_cache(maxsize=8)
def _hull_facts(key: _PointsKey) -> tuple[float, float]:
    hull = ConvexHull(key.array)
    return float(hull.volume), _diameter_of(key.array[hull.vertices])


def hull_volume_and_diameter(points: FloatArray) -> tuple[float, float]:
    """Volume of the convex hull of ``points`` (shape (n, 3)) and their diameter.

    Found once per point set: building a model checks its planarity against the diameter,
    then validating it needs the same hull again (at 50,000 vertices each costs a Qhull run
    and a farthest-pair search, 0.45 s), so the last few results are kept by content.

    Raises
    ------
    scipy.spatial.QhullError
        If the points are flat (coplanar, collinear or coincident).
    """
    return _hull_facts(_PointsKey(points))


@lru_cache(maxsize=8)
def _vertex_diameter(key: _PointsKey) -> float:
    return _diameter_of(key.array)


def vertex_diameter(vertices: FloatArray) -> float:
    """The diameter of a convex polyhedron's vertices (shape (n, 3)), all of them corners of
    its hull: :func:`hull_volume_and_diameter` without the hull. Kept for the last few point
    sets, by content: a builder measures its faces' planarity against it, then validating
    the model needs it again."""
    return _vertex_diameter(_PointsKey(vertices))


def _diameter_of(p: FloatArray) -> float:
    n = len(p)
    if n <= 256:
        # all pairs by one product (fast), then the near-best pairs again exactly: the
        # expansion |x|^2 + |y|^2 - 2 x.y loses digits far from the origin
        q = p - p.mean(axis=0)
        sq = np.einsum("ij,ij->i", q, q)
        d2 = sq[:, None] + sq[None, :] - 2.0 * (q @ q.T)
        top = float(d2.max())
        rows, cols = np.nonzero(d2 >= top - 1e-9 * max(top, 1e-300) - 1e-300)
        diff = q[rows] - q[cols]
        return float(np.sqrt(np.einsum("ij,ij->i", diff, diff).max()))
    # a lower bound from a few farthest-point steps (each pair found is a true distance)
    c = p.mean(axis=0)
    i = int(np.argmax(np.einsum("ij,ij->i", p - c, p - c)))
    best2 = 0.0
    for _ in range(4):
        d2 = np.einsum("ij,ij->i", p - p[i], p - p[i])
        j = int(np.argmax(d2))
        best2 = max(best2, float(d2[j]))
        i = j
    blocks = _kd_blocks(p, 32)
    bmin = np.nanmin(blocks, axis=1)
    bmax = np.nanmax(blocks, axis=1)
    # bounds on the farthest pair of each pair of blocks, 256 rows at a time (memory linear
    # in the number of blocks)
    m = len(blocks)
    ia_parts, ib_parts, bound_parts = [], [], []
    kept = 0
    for a0 in range(0, m, 256):
        span = np.maximum(np.abs(bmax[a0 : a0 + 256, None, :] - bmin[None, :, :]),
                          np.abs(bmax[None, :, :] - bmin[a0 : a0 + 256, None, :]))
        b2 = np.einsum("ijk,ijk->ij", span, span)
        ra, rb = np.nonzero(b2 >= best2)
        ra = ra + a0
        upper = ra <= rb
        ia_parts.append(ra[upper])
        ib_parts.append(rb[upper])
        bound_parts.append(b2[ra[upper] - a0, rb[upper]])
        kept += int(upper.sum())
        if kept * 32 * 32 > _EXACT_BUDGET:
            # nearly round: too many pairs of blocks could hold the diameter; take the
            # widest pair over many directions, improved by farthest-point steps (within
            # 1.3 %, in practice exact)
            return max(float(np.sqrt(best2)), _widest_pair(p))
    ia, ib = np.concatenate(ia_parts), np.concatenate(ib_parts)
    bounds = np.concatenate(bound_parts)
    order = np.argsort(-bounds, kind="stable")  # promising pairs first
    ia, ib, bounds = ia[order], ib[order], bounds[order]
    for c0 in range(0, len(ia), 256):
        sel = bounds[c0 : c0 + 256] >= best2
        if not sel.any():
            break
        x = blocks[ia[c0 : c0 + 256][sel]]
        y = blocks[ib[c0 : c0 + 256][sel]]
        diff = x[:, :, None, :] - y[:, None, :, :]
        d2 = np.einsum("abcd,abcd->abc", diff, diff)
        best2 = max(best2, float(np.nanmax(d2)))
    return float(np.sqrt(best2))


#: Most point pairs the exact diameter compares before it settles for the widest pair over
#: many directions (a nearly round hull of thousands of vertices).
_EXACT_BUDGET = 1_000_000


def _widest_pair(p: FloatArray, n_dirs: int = 200) -> float:
    """A long pair of ``p``: the extreme points along each of ``n_dirs`` directions spread
    evenly (a Fibonacci sphere), each pair then improved by farthest-point steps. A true pair
    distance, at least the diameter times the cosine of the directions' covering angle
    (about 0.16 rad: within 1.3 %), and in practice the diameter itself."""
    i = np.arange(n_dirs) + 0.5
    phi = np.arccos(1 - 2 * i / n_dirs)
    theta = np.pi * (1 + 5**0.5) * i
    d = np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi),
                         np.cos(phi)])
    q = p - p.mean(axis=0)

    def project(rows: slice | list[int]) -> FloatArray:
        # three broadcast products, not a BLAS call: an inner dimension of 3 gains nothing
        # from threads, and threads on a busy machine cost a lot
        e = d[rows]
        return np.asarray(e[:, 0:1] * q[:, 0] + e[:, 1:2] * q[:, 1] + e[:, 2:3] * q[:, 2])

    # a few directions at a time: the whole (n_dirs, n) matrix would be 80 MB per
    # temporary at 50,000 points, and memory traffic is what a busy machine lacks
    width = np.empty(n_dirs)
    for d0 in range(0, n_dirs, 16):
        proj = project(slice(d0, d0 + 16))
        width[d0 : d0 + 16] = proj.max(axis=1) - proj.min(axis=1)
    best2 = 0.0
    for row in project(np.argsort(-width)[:8].tolist()):
        a = int(np.argmax(row))
        for _ in range(4):
            diff = q - q[a]
            d2 = np.einsum("ij,ij->i", diff, diff)
            b = int(np.argmax(d2))
            best2 = max(best2, float(d2[b]))
            a = b
    return float(np.sqrt(best2))


def _kd_blocks(p: FloatArray, leaf: int) -> FloatArray:
    """``p`` cut by median splits into blocks of at most ``leaf`` nearby points, padded with
    NaN: shape (n_blocks, leaf, 3)."""
    todo = [np.arange(len(p))]
    leaves = []
    while todo:
        a = todo.pop()
        if len(a) <= leaf:
            leaves.append(a)
            continue
        q = p[a]
        axis = int(np.argmax(q.max(axis=0) - q.min(axis=0)))
        mid = len(a) // 2
        part = np.argpartition(q[:, axis], mid)
        todo += [a[part[:mid]], a[part[mid:]]]
    out = np.full((len(leaves), leaf, 3), np.nan)
    for k, a in enumerate(leaves):
        out[k, : len(a)] = p[a]
    return out


@dataclass(frozen=True)
class _Checked:
    vertices: FloatArray
    loops: dict[str, tuple[int, ...]]
    flat: _Loops
    diameter: float
    unit_normals: FloatArray  # outward, shape (n_faces, 3)


def check_polyhedron(
    vertices: object, faces: object, *, rtol: float = DEFAULT_RTOL
) -> tuple[FloatArray, dict[str, tuple[int, ...]]]:
    """Validate a polyhedron given as vertices and clockwise face loops.

    Every check is vectorised over faces, edges or vertices: the work is linear in the size
    of the model (plus one ``O(n log n)`` convex hull of the vertices for the diameter and
    the final convexity check).

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
    checked = _check(vertices, faces, rtol)
    return checked.vertices, checked.loops


def _fast_loops(
    faces: Mapping[object, object], n_vertices: int
) -> dict[str, tuple[int, ...]] | None:
    """The loops as tuples when every one is a valid list of indices (checked in bulk), else
    None (then :func:`_slow_loops` names the culprit)."""
    out: dict[str, tuple[int, ...]] = {}
    for f, t in faces.items():
        if type(f) is not str or not f or type(t) not in (list, tuple):
            return None
        out[f] = tuple(t)  # type: ignore[arg-type]
    flat = list(itertools.chain.from_iterable(out.values()))
    if not set(map(type, flat)) <= {int}:
        if not all(isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in flat):
            return None
        out = {f: tuple(int(i) for i in t) for f, t in out.items()}
        flat = [int(i) for i in flat]
    if not flat or min(flat) < 0 or max(flat) >= n_vertices:
        return None  # (before numpy: an index beyond int64 would overflow there)
    lengths = np.fromiter(map(len, out.values()), dtype=np.int64, count=len(out))
    if lengths.min() < 3:
        return None
    # a loop that repeats a vertex: two equal (loop, vertex) keys, found in one sort
    idx = np.fromiter(flat, dtype=np.int64, count=len(flat))
    key = np.sort(np.repeat(np.arange(len(out), dtype=np.int64), lengths) * n_vertices + idx)
    if (key[1:] == key[:-1]).any():
        return None
    return out


def _slow_loops(faces: Mapping[object, object], n_vertices: int) -> dict[str, tuple[int, ...]]:
    """The loops as tuples, checked one by one; the first bad one raises naming its face."""
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
        if min(t) < 0 or max(t) >= n_vertices:
            i = next(i for i in t if not 0 <= i < n_vertices)
            raise ModelError(f"vertex index {i} is out of range 0..{n_vertices - 1}", face=f)
        loops[f] = t
    return loops


def _check(
    vertices: object, faces: object, rtol: float, *, hull_facets: bool = False
) -> _Checked:
    rtol = _check_rtol(rtol)
    try:
        v = np.array(vertices, dtype=float)
    except (TypeError, ValueError, OverflowError):
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
    big = float(np.abs(v).max())
    if big > MAX_COORDINATE:
        i = int(np.argmax(np.abs(v).max(axis=1)))
        raise ModelError(
            f"vertex {i} has a coordinate of magnitude {big:.3g}, beyond {MAX_COORDINATE:g}: "
            "products of such numbers overflow; express the model in other units"
        )
    span = float(np.max(v.max(axis=0) - v.min(axis=0)))
    if span < MIN_SIZE:
        raise ModelError(
            f"the vertices span {span:.3g} (the largest side of their bounding box), below the "
            f"smallest object size {MIN_SIZE:g}: express the model in smaller units (mm, um)"
        )
    v.setflags(write=False)
    if not isinstance(faces, Mapping):
        raise ModelError(
            f"faces must map face IDs to vertex loops, got {type(faces).__name__}"
        )
    if len(faces) < 4:
        raise ModelError(f"a polyhedron needs at least 4 faces, got {len(faces)}")
    loops = _fast_loops(faces, len(v))
    if loops is None:
        loops = _slow_loops(faces, len(v))
    names = list(loops)
    lp = _Loops.of(loops.values())
    used = np.zeros(len(v), dtype=bool)
    used[lp.flat] = True
    if not used.all():
        i = int(np.flatnonzero(~used)[0])
        raise ModelError(
            f"vertex {i} {v[i].tolist()} is on no face; remove it or add it to the faces "
            "that meet there"
        )

    hull_volume: float | None = None
    try:
        if hull_facets:
            # convex by construction: every vertex is a corner of the hull, so the diameter
            # of them all is the hull's (and the builder has just found it)
            diameter = vertex_diameter(v)
        else:
            hull_volume, diameter = hull_volume_and_diameter(v)
    except QhullError:
        raise ModelError(
            "the vertices are flat (all coplanar, collinear or coincident): they bound no "
            "solid"
        ) from None
    atol = rtol * diameter
    center = v.mean(axis=0)

    def first(mask: NDArray[np.bool_]) -> int:
        return int(np.flatnonzero(mask)[0])

    newell = lp.newell(v)
    norm = np.linalg.norm(newell, axis=1)
    p = v[lp.flat]
    means = lp.means(v)
    rel = p - means[lp.owner]
    reach = np.sqrt(lp.face_max(np.einsum("ij,ij->i", rel, rel)))  # farthest corner
    # no width: twice the area is at most the tolerance times the face's own reach (a small
    # face of a finely tessellated part is not flat, a sliver within the tolerance is)
    flat_face = norm <= atol * reach
    if flat_face.any():
        raise ModelError(
            "the face has no area: its vertices are collinear, or its loop crosses itself",
            face=names[first(flat_face)],
        )
    n_loop = newell / norm[:, None]  # right-handed about the loop: inward when clockwise
    off = np.abs(np.einsum("ij,ij->i", p - means[lp.owner], n_loop[lp.owner]))
    worst = lp.face_max(off)
    if (worst > atol).any():
        fi = first(worst > atol)
        seg = slice(lp.starts[fi], lp.starts[fi] + lp.lengths[fi])
        k = int(np.argmax(off[seg]))
        raise ModelError(
            f"the face is not planar: vertex {loops[names[fi]][k]} is {off[seg][k]:.3g} off "
            f"its plane (tolerance {atol:.3g}; the model's rtol is {rtol:g}: raise it for a "
            "measured object)",
            face=names[fi],
        )
    # convex polygon: every turn goes the same way as the loop's normal; the height of each
    # corner above the line through its neighbours measures how sharp the turn is
    height = corner_heights(v, lp, n_loop)
    low = -lp.face_max(-height)  # per-face minimum
    bad_turn = low <= atol * COLLINEAR_FRACTION
    if bad_turn.any():
        fi = first(bad_turn)
        seg = slice(lp.starts[fi], lp.starts[fi] + lp.lengths[fi])
        k = int(np.argmin(height[seg]))
        t = loops[names[fi]]
        corner = t[(k + 1) % len(t)]
        if height[seg][k] >= -atol:
            raise ModelError(
                f"vertex {corner} is collinear with its neighbours on the loop; remove it",
                face=names[fi],
            )
        raise ModelError(
            f"the face is not convex (it turns the other way at vertex {corner}), or its "
            "loop is not in order around the face",
            face=names[fi],
        )

    # closed, consistently ordered surface: every directed edge once, its reverse once
    nv = np.int64(len(v))
    tail, head = lp.flat, lp.flat[lp.nxt]
    key = tail * nv + head
    order = np.argsort(key, kind="stable")
    sk = key[order]
    dup = np.flatnonzero(sk[1:] == sk[:-1])
    if dup.size:
        c0, c1 = sorted((int(order[dup[0]]), int(order[dup[0] + 1])))
        i, j = int(tail[c1]), int(head[c1])
        raise ModelError(
            f"faces {names[lp.owner[c0]]!r} and {names[lp.owner[c1]]!r} both run edge {i}->{j} "
            "in the same direction: the loops are not consistently ordered; list every loop "
            "clockwise as seen from outside",
            face=names[lp.owner[c1]],
        )
    rev = head * nv + tail
    pos = np.minimum(np.searchsorted(sk, rev), len(sk) - 1)
    missing = sk[pos] != rev
    if missing.any():
        c = first(missing)
        raise ModelError(
            f"edge {int(tail[c])}-{int(head[c])} belongs to no other face: the surface is not "
            "closed; add the missing face or fix the loop",
            face=names[lp.owner[c]],
        )
    partner = order[pos]  # the corner that runs each edge the other way
    n_edges = len(key) // 2
    euler = len(v) - n_edges + len(loops)
    if euler != 2:
        raise ModelError(
            f"V - E + F = {len(v)} - {n_edges} + {len(loops)} = {euler}, expected 2: the "
            "faces do not bound one solid without holes"
        )

    # clockwise from outside: the loop's right-handed normal points into the solid
    ccw = np.einsum("ij,ij->i", means - center, n_loop) > 0
    if ccw.any():
        fi = first(ccw)
        raise ModelError(
            "the loop is counterclockwise seen from outside; list it clockwise "
            f"(reverse it: {list(reversed(loops[names[fi]]))})",
            face=names[fi],
        )

    # convex solid, edge by edge: the face across each edge lies behind this face's plane
    n_out = -n_loop
    f_of, g_of = lp.owner, lp.owner[partner]
    front = np.einsum("ij,ij->i", means[g_of] - p, n_out[f_of])
    if (front > atol).any():
        c = int(np.argmax(front))
        raise ModelError(
            f"the solid is not convex: face {names[g_of[c]]!r} rises {front[c]:.3g} in front "
            f"of this face's plane across edge {int(tail[c])}-{int(head[c])}; use the convex "
            "hull (nonprehensile object from-mesh) instead",
            face=names[f_of[c]],
        )
    # coplanar neighbours: g's vertices all within a small part of the tolerance of f's
    # plane (the normals' angle times g's extent bounds how far they can stray)
    extent = 2.0 * reach
    sin_fg = np.linalg.norm(np.cross(n_out[f_of], n_out[g_of]), axis=1)
    same = (sin_fg * np.maximum(extent[f_of], extent[g_of]) <= atol * COPLANAR_FRACTION) & (
        f_of < g_of
    )
    if same.any():
        c = first(same)
        raise ModelError(
            f"faces {names[f_of[c]]!r} and {names[g_of[c]]!r} are coplanar across edge "
            f"{int(tail[c])}-{int(head[c])}; merge them into one face",
            face=names[f_of[c]],
        )
    # and as a whole: a closed surface convex at every edge bounds its own convex hull
    vol = _signed_volume(v, lp, center)
    area = float(norm.sum()) / 2.0
    if hull_volume is not None and hull_volume - vol > 2 * atol * area:
        raise ModelError(
            f"the solid is not convex: its volume {vol:.6g} falls short of its convex hull's "
            f"{hull_volume:.6g}; use the convex hull (nonprehensile object from-mesh) instead"
        )
    return _Checked(v, loops, lp, diameter, n_out)


def corner_heights(v: FloatArray, lp: _Loops, n_loop: FloatArray) -> FloatArray:
    """Signed height of every corner above the line through its two neighbours on its loop,
    shape (n_corners,): corner ``k`` of the flat order is the one between the edges starting
    at ``k`` and at ``lp.nxt[k]`` (so it is vertex ``lp.flat[lp.nxt[k]]``). Positive where
    the loop turns the way of ``n_loop`` (the loops' right-handed unit normals, shape
    (n_faces, 3)); ``-inf`` where an edge has no length."""
    p = v[lp.flat]
    e = p[lp.nxt] - p
    e_next = e[lp.nxt]
    len_e = np.linalg.norm(e, axis=1)
    len_next = len_e[lp.nxt]
    with np.errstate(divide="ignore", invalid="ignore"):
        sin = np.einsum("ij,ij->i", np.cross(e, e_next), n_loop[lp.owner]) / (len_e * len_next)
    return np.asarray(np.nan_to_num(sin * np.minimum(len_e, len_next), nan=-np.inf))


def _fan_mask(lp: _Loops) -> NDArray[np.bool_]:
    """Corners that start a fan triangle (all but each loop's first and last)."""
    pos = np.arange(len(lp.flat)) - lp.starts[lp.owner]
    return np.asarray((pos >= 1) & (pos <= lp.lengths[lp.owner] - 2))


def _fans(v: FloatArray, lp: _Loops) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Fan triangles of every loop from its first vertex: points a, b, c, shape (m, 3) each;
    the face of each is ``lp.owner[_fan_mask(lp)]``."""
    mask = _fan_mask(lp)
    a = v[lp.flat[lp.starts[lp.owner[mask]]]]
    b = v[lp.flat[mask]]
    c = v[lp.flat[lp.nxt[mask]]]
    return a, b, c


def _signed_volume(v: FloatArray, lp: _Loops, ref: FloatArray) -> float:
    a, b, c = _fans(v, lp)
    return float((np.einsum("ij,ij->i", np.cross(c - a, b - a), a - ref)).sum() / 6.0)
