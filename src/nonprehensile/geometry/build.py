"""Builders of object models: primitives, the convex hull of points, and meshes.

Hull faces are found with Qhull (through :mod:`scipy.spatial`), then the triangles Qhull
returns are merged into polygon faces where they are coplanar within the tolerance. Faces of
a built model are named ``a, b, ..., z, aa, ab, ...`` in a deterministic order: by the height
of their outward normal (bottom first, top last), then counterclockwise by its azimuth from
``+x``; each loop starts at its vertex that comes first in the lexicographic order of
coordinates. Mesh files are read with trimesh, imported only when needed (the ``mesh`` extra).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import string
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError, cKDTree

from nonprehensile.bounds import MAX_COORDINATE as MAX_RECORDED_COORDINATE
from nonprehensile.checks import RTOL_RANGE, Range, check_number
from nonprehensile.errors import InputError, MeshError, ModelError
from nonprehensile.geometry.polyhedron import (
    COLLINEAR_FRACTION,
    DEFAULT_RTOL,
    MAX_COORDINATE,
    MIN_SIZE,
    Polyhedron,
    _Loops,
    corner_heights,
    vertex_diameter,
)
from nonprehensile.geometry.units import check_units

__all__ = [
    "box",
    "convex_hull",
    "cube",
    "face_name",
    "face_names",
    "from_mesh",
    "octahedron",
    "prism",
    "tetrahedron",
]

FloatArray = NDArray[np.float64]

#: Default merging tolerance of :func:`from_mesh`, relative to the object's size: mesh files
#: often store single-precision coordinates (7 digits).
MESH_RTOL = 1e-6

#: Mesh formats that :func:`from_mesh` is tested on; trimesh reads more.
MESH_FORMATS = ("stl", "obj", "ply", "off", "glb")

#: Most sides of :func:`prism`'s polygon (its model holds about 6 numbers a side).
MAX_PRISM_SIDES = 1_000_000
#: Point sets from this size on are large: a Qhull run over them takes seconds, so the
#: builder retries as few times as it can (:func:`_hull_model`).
LARGE_HULL = 50_000
#: Most triangles a hull may have to be built into a model: a 327,680-triangle sphere takes
#: about 15 s and 1.3 GB; a 1.3-million-triangle one took 90 s of CPU and 3.3 GB
#: (docs/benchmarks.md).
MAX_HULL_TRIANGLES = 400_000
#: Most faces :func:`convex_hull` may be asked to facet a curved object into.
MAX_FACES = 10_000_000

_SIZE = Range(MIN_SIZE, MAX_COORDINATE)


def face_name(i: int) -> str:
    """The ``i``-th face name: ``a .. z, aa, ab, ..., az, ba, ...`` (spreadsheet columns)."""
    if i < 0:
        raise ValueError(f"face index must be >= 0, got {i}")
    s = ""
    i += 1
    while i:
        i, r = divmod(i - 1, 26)
        s = chr(ord("a") + r) + s
    return s


def face_names(n: int) -> list[str]:
    """The first ``n`` face names, ``[face_name(0), ..., face_name(n - 1)]``, made in bulk
    (names of one letter, then of two, ... in order: what :func:`face_name` gives)."""
    out: list[str] = []
    width = 1
    while len(out) < n:
        words = itertools.product(string.ascii_lowercase, repeat=width)
        out.extend(map("".join, itertools.islice(words, n - len(out))))
        width += 1
    return out


def cube(size: float = 1.0, *, name: str = "cube") -> Polyhedron:
    """The paper's cube, labeled as in ``examples/cube.json``.

    Faces: ``a`` bottom (``z = 0``), ``c`` top, ``b`` right (``x = size``), ``e`` left,
    ``d`` back (``y = size``), ``f`` front (``y = 0``). Edge numbers follow the paper's
    Section III text (``A(b, a) = 2``, ``A(a, b) = 3``) and the spec's example skill: pushed
    on ``f``, the cube rolls over ``E(a, d)`` from ``a:0`` to ``d:0``.
    """
    s = float(check_number(size, "cube size", _SIZE, ModelError))
    v = s * np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
        dtype=float,
    )
    faces = {
        "a": (3, 0, 1, 2),
        "b": (6, 2, 1, 5),
        "c": (4, 7, 6, 5),
        "d": (7, 3, 2, 6),
        "e": (0, 3, 7, 4),
        "f": (0, 4, 5, 1),
    }
    return Polyhedron(v, faces, name=name)


def box(width: float, depth: float, height: float, *, name: str = "box",
        rtol: float = DEFAULT_RTOL) -> Polyhedron:
    """A rectangular box ``width x depth x height`` (along x, y, z), corner at the origin.

    Built from its six faces (no hull: a thin plate is still a box), named as
    :func:`convex_hull` names them.

    Raises
    ------
    ModelError
        A side that is not a finite number from :data:`MIN_SIZE` up, or one shorter than the
        tolerance (``rtol`` times the diagonal): at that tolerance the box is flat.
    """
    dims = np.array([check_number(v, f"box {what}", _SIZE, ModelError)
                     for v, what in zip((width, depth, height), ("width", "depth", "height"),
                                        strict=True)], dtype=float)
    rtol = float(check_number(rtol, "rtol", RTOL_RANGE, ModelError))
    diag = float(np.linalg.norm(dims))
    k = int(np.argmin(dims))
    if dims[k] <= rtol * diag:
        raise ModelError(
            f"box {('width', 'depth', 'height')[k]} {dims[k]:g} is within the length tolerance "
            f"{rtol * diag:.3g} (rtol {rtol:g} x the diagonal {diag:.4g}): at that tolerance "
            f"the box is flat; pass a smaller rtol (below {dims[k] / diag:.2g}) or a thicker box"
        )
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    # corner index 4x + 2y + z
    loops = [(0, 2, 6, 4), (1, 5, 7, 3), (0, 4, 5, 1), (2, 3, 7, 6), (0, 1, 3, 2),
             (4, 6, 7, 5)]
    return _explicit_model(corners * dims, loops, name=name, rtol=rtol)


def prism(
    n: int, radius: float = 1.0, height: float = 1.0, *, name: str | None = None
) -> Polyhedron:
    """A right prism on a regular ``n``-gon of circumradius ``radius``.

    Built from its ``n + 2`` faces (no hull: the sides of a 100,000-gon are further apart
    than the tolerance, yet a hull would merge them), named as :func:`convex_hull` names
    them.

    Raises
    ------
    ModelError
        ``n`` not a whole number from 3 to :data:`MAX_PRISM_SIDES`, a size that is not a
        finite number from :data:`MIN_SIZE` up, or sides shorter than the model's tolerance.
    """
    n = int(check_number(n, "prism sides n", Range(3, MAX_PRISM_SIDES, integer=True),
                         ModelError))
    radius = float(check_number(radius, "prism radius", _SIZE, ModelError))
    height = float(check_number(height, "prism height", _SIZE, ModelError))
    rtol = DEFAULT_RTOL
    atol = rtol * math.hypot(2 * radius, height)
    # a corner of the n-gon stands r (1 - cos(2 pi / n)) off the line through its
    # neighbours: within the tolerance the polygon has no corner there
    turn = radius * (1.0 - math.cos(2 * math.pi / n))
    if turn <= atol or height <= atol:
        most = int(2 * math.pi / math.acos(1.0 - atol / radius)) if atol < radius else 3
        raise ModelError(
            f"a prism of {n} sides, radius {radius:g} and height {height:g}: "
            + (f"its corners stand {turn:.3g} off the line through their neighbours, within "
               f"the length tolerance {atol:.3g}; use at most {most} sides at this size"
               if turn <= atol else
               f"its height is within the length tolerance {atol:.3g}; make it taller")
        )
    ang = 2 * np.pi * np.arange(n) / n
    ring = np.column_stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(n)])
    top = ring + np.array([0.0, 0.0, height])
    # ring i = vertex i, top i = vertex n + i; loops clockwise seen from outside
    i = np.arange(n)
    j = (i + 1) % n
    sides = np.column_stack([i, n + i, n + j, j])
    loops: list[tuple[int, ...]] = [tuple(range(n)), tuple(range(2 * n - 1, n - 1, -1)),
                                    *map(tuple, sides.tolist())]
    return _explicit_model(np.vstack([ring, top]), loops, name=name or f"prism{n}",
                           rtol=rtol)


def tetrahedron(edge: float = 1.0, *, name: str = "tetrahedron") -> Polyhedron:
    """A regular tetrahedron with the given edge length."""
    edge = float(check_number(edge, "tetrahedron edge", _SIZE, ModelError))
    p = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    return convex_hull(p * (edge / (2 * math.sqrt(2))), name=name)


def octahedron(edge: float = 1.0, *, name: str = "octahedron") -> Polyhedron:
    """A regular octahedron with the given edge length."""
    edge = float(check_number(edge, "octahedron edge", _SIZE, ModelError))
    p = np.vstack([np.eye(3), -np.eye(3)]) * (edge / math.sqrt(2))
    return convex_hull(p, name=name)


def _explicit_model(points: FloatArray, loops: Sequence[tuple[int, ...]], *, name: str,
                    rtol: float) -> Polyhedron:
    """The convex polyhedron of ``points`` with faces ``loops`` (clockwise from outside,
    every point a corner; a loop given the other way round is reversed), named and numbered
    as :func:`convex_hull` does."""
    centre = points.mean(axis=0)
    newell = _Loops.of(loops).newell(points)
    # clockwise from outside: Newell's normal of the loop points inward
    inward = np.einsum("ij,ij->i", newell, points[[lp[0] for lp in loops]] - centre) < 0
    loops = [lp if ok else lp[::-1] for lp, ok in zip(loops, inward, strict=True)]
    newell = np.where(inward[:, None], -newell, newell)
    normals = newell / np.linalg.norm(newell, axis=1)[:, None]
    lengths = np.array([len(lp) for lp in loops], dtype=np.int64)
    flat = np.fromiter((i for lp in loops for i in lp), dtype=np.int64, count=int(lengths.sum()))
    keyed, faces = _assemble(points, flat, lengths, normals, rtol * vertex_diameter(points))
    return Polyhedron(points[keyed], faces, name=name, rtol=rtol, hull_facets=True)


def _qhull(points: FloatArray, radius: float, angle: float) -> Any:
    """Qhull's hull of ``points``, merging facets within ``radius`` or ``angle`` (degrees).

    Qhull's pre-merging (options ``C-`` and ``A-``) merges facets whose centrums lie within
    ``radius`` of a neighbour's plane, or whose normals are within ``angle``, and keeps the
    result convex; it also drops vertices that end up inside a merged facet or on an edge.
    """
    opts = f"C-{radius:.17g}" if radius > 0 else "C-0"
    if angle > 0:
        opts += f" A-{math.cos(math.radians(angle)):.17g}"
    try:
        return ConvexHull(points, qhull_options=opts)
    except QhullError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else "Qhull failed"
        raise MeshError(
            f"cannot build a convex hull of {len(points)} points: they are degenerate (all "
            f"coplanar, collinear or coincident). Qhull said: {first}"
        ) from None


def _hull_loops(
    points: FloatArray, hull: Any
) -> tuple[NDArray[np.int64], NDArray[np.int64], FloatArray]:
    """The merged facets of a Qhull hull as loops clockwise from outside, and their normals.

    Returns ``(flat, lengths, normals)``: every loop's vertex indices one after the other,
    each loop's length, and the outward unit normals, shape (n_facets, 3).

    ``scipy`` always triangulates Qhull's output; the triangles of one merged facet share
    its hyperplane exactly, so they are grouped by their equation. A merged facet is convex,
    so its loop is its corners in angular order about its centre. Its corners are the
    vertices of its triangles that lie on three facets or more: a vertex on only two lies on
    an edge between them, and one on a single facet lies inside it (Qhull's triangulation
    may keep such points, in degenerate triangles).
    """
    simplices = np.asarray(hull.simplices, dtype=np.int64)
    eqs = np.asarray(hull.equations, dtype=np.float64)
    # group the triangles by equation, numbered in the lexicographic order of the equations
    # (what ``np.unique(eqs, axis=0)`` numbers, at a third of its cost)
    by_eq = np.lexsort(eqs.T[::-1])
    change = np.any(eqs[by_eq[1:]] != eqs[by_eq[:-1]], axis=1)
    group = np.empty(len(eqs), dtype=np.int64)
    group[by_eq] = np.concatenate([[0], np.cumsum(change)])
    n_groups = int(group.max()) + 1
    normals = np.zeros((n_groups, 3))
    normals[group] = eqs[:, :3]
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    n = np.int64(len(points))
    pairs = np.sort(np.repeat(group, 3) * n + simplices.ravel())
    pairs = pairs[np.concatenate([[True], pairs[1:] != pairs[:-1]])]
    owner, vertex = pairs // n, pairs % n
    counts = np.bincount(vertex, minlength=len(points))
    keep = counts[vertex] >= 3
    owner, vertex = owner[keep], vertex[keep]
    # angle of each corner about its facet's centre, counterclockwise seen from outside
    centre = np.zeros((n_groups, 3))
    for k in range(3):
        centre[:, k] = np.bincount(owner, weights=points[vertex, k], minlength=n_groups)
    centre /= np.maximum(np.bincount(owner, minlength=n_groups), 1)[:, None]
    nrm = normals[owner]
    ref = np.where(np.abs(nrm[:, 0:1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(nrm, ref)
    u /= np.linalg.norm(u, axis=1)[:, None]
    w = np.cross(nrm, u)
    rel = points[vertex] - centre[owner]
    ang = np.arctan2(np.einsum("ij,ij->i", rel, w), np.einsum("ij,ij->i", rel, u))
    order = np.lexsort((-ang, owner))  # clockwise from outside: decreasing angle
    owner, vertex = owner[order], vertex[order]
    bounds = np.flatnonzero(np.diff(owner)) + 1
    present = owner[np.r_[0, bounds]] if len(owner) else np.zeros(0, dtype=np.int64)
    if len(present) != n_groups:  # a facet left with no corner: keep the ones that have
        normals = normals[present]
    lengths = np.diff(np.concatenate([[0], bounds, [len(vertex)]])) if len(owner) else (
        np.zeros(0, dtype=np.int64))
    return vertex, lengths.astype(np.int64), normals


def _assemble(
    points: FloatArray,
    flat: NDArray[np.int64],
    lengths: NDArray[np.int64],
    normals: FloatArray,
    atol: float,
) -> tuple[NDArray[np.int64], dict[str, tuple[int, ...]]]:
    """Renumber vertices and name faces in the builders' deterministic order: the model's
    vertices are ``points[keyed]``; returns ``keyed`` and the faces.

    The loops are given as in :func:`_hull_loops`. Vectorised over corners: one gather
    renumbers every loop, puts the faces in order and starts each loop at its smallest new
    vertex index."""
    n_loops = len(lengths)
    used = np.unique(flat)
    # vertices in lexicographic order of rounded coordinates, so names do not depend on the
    # order the points came in
    digits = max(0, int(-math.floor(math.log10(max(atol, 1e-15)))) - 1)
    r = np.round(points[used], digits)
    keyed = used[np.lexsort((r[:, 2], r[:, 1], r[:, 0]))]
    new_index = np.full(len(points), -1, dtype=np.int64)
    new_index[keyed] = np.arange(len(keyed))
    az = np.round(np.arctan2(normals[:, 1], normals[:, 0]) % (2 * math.pi), 6) % round(
        2 * math.pi, 6
    )
    height = np.round(normals[:, 2], 6)
    order = np.lexsort((az, height))
    mapped = new_index[flat]
    starts = np.zeros(n_loops, dtype=np.int64)
    np.cumsum(lengths[:-1], out=starts[1:])
    owner = np.repeat(np.arange(n_loops, dtype=np.int64), lengths)
    # where each loop's smallest vertex sits (a loop repeats no vertex: one place)
    low = np.minimum.reduceat(mapped, starts)
    at_low = np.flatnonzero(mapped == low[owner])
    shift = np.zeros(n_loops, dtype=np.int64)
    shift[owner[at_low]] = at_low - starts[owner[at_low]]
    # corner j of the face of rank r is corner (j + shift) of loop order[r]
    new_len = lengths[order]
    new_starts = np.zeros(n_loops, dtype=np.int64)
    np.cumsum(new_len[:-1], out=new_starts[1:])
    old = np.repeat(order, new_len)
    j = np.arange(len(flat), dtype=np.int64) - np.repeat(new_starts, new_len)
    out = mapped[starts[old] + (j + shift[old]) % lengths[old]].tolist()
    bounds = [*new_starts.tolist(), len(out)]
    faces = {name: tuple(out[bounds[k] : bounds[k + 1]])
             for k, name in enumerate(face_names(n_loops))}
    return keyed, faces


def _planarity_rtol(vertices: FloatArray, faces: dict[str, tuple[int, ...]]) -> float:
    """How far (relative to the diameter) the loops stray from their planes."""
    lp = _Loops.of(faces.values())
    newell = lp.newell(vertices)
    n = newell / np.maximum(np.linalg.norm(newell, axis=1), 1e-300)[:, None]
    p = vertices[lp.flat]
    off = np.abs(np.einsum("ij,ij->i", p - lp.means(vertices)[lp.owner], n[lp.owner]))
    # every vertex is a corner of the hull; the model's check reuses the diameter
    return float(off.max()) / max(vertex_diameter(vertices), 1e-300)


def _unturned_corners(
    vertices: FloatArray, faces: dict[str, tuple[int, ...]], rtol: float
) -> NDArray[np.int64]:
    """Vertices where some face's loop does not turn: within the tolerance of the line
    through their neighbours on it (collinear), or turning back (a point Qhull left inside a
    merged facet, within its thickness, that also touches small facets). The model check
    refuses both; both lie within the tolerance of the hull of the other points."""
    lp = _Loops.of(faces.values())
    newell = lp.newell(vertices)
    n_loop = newell / np.maximum(np.linalg.norm(newell, axis=1), 1e-300)[:, None]
    atol = rtol * vertex_diameter(vertices)
    height = corner_heights(vertices, lp, n_loop)
    return np.unique(lp.flat[lp.nxt][height <= atol * COLLINEAR_FRACTION])


def _round_up(x: float) -> float:
    """``x`` rounded up to two significant digits (a tolerance that reads well in a file)."""
    if x <= 0:
        return x
    e = math.floor(math.log10(x)) - 1
    return float(f"{math.ceil(x / 10.0**e - 1e-9)}e{e}")


def _hull_model(
    p: FloatArray,
    *,
    name: str,
    rtol: float,
    angle: float,
    max_faces: int | None,
    center_of_mass: ArrayLike | None,
    units: str,
) -> Polyhedron:
    extent = float(np.linalg.norm(p.max(axis=0) - p.min(axis=0)))
    size = extent / math.sqrt(3.0)  # at most the diameter: the merge radius errs small
    radius = rtol * size
    hull = _qhull(p, radius, angle)
    if len(hull.simplices) > MAX_HULL_TRIANGLES:
        raise MeshError(
            f"the convex hull of the points has {len(hull.simplices):,} triangles, more than "
            f"the {MAX_HULL_TRIANGLES:,} a model is built from (a model's checks, states and "
            "plans grow with its faces: 1.3 million take minutes and over 2 GB, and no "
            "manipulation needs them); simplify the mesh first to at most "
            f"{MAX_HULL_TRIANGLES:,} triangles, e.g. trimesh's "
            "simplify_quadric_decimation, MeshLab's Quadric Edge Collapse Decimation or "
            "Blender's Decimate modifier"
        )
    if max_faces is not None:
        # coarser and coarser merging until the hull has few enough faces
        for _ in range(60):
            lengths = _hull_loops(p, hull)[1]
            if len(lengths) <= max_faces:
                break
            radius = max(radius * 2.0, 1e-12 * extent)
            hull = _qhull(p, radius, angle)
        else:
            raise MeshError(f"cannot facet the hull into at most {max_faces} faces")
    first_radius = radius

    def attempt(
        q: FloatArray, radius: float, hull: Any, unturned: bool = False
    ) -> tuple[Polyhedron | ModelError, NDArray[np.int64]]:
        """The model of Qhull's facets of ``q``, or why it is not valid, and (if asked) the
        corners that do not turn, which may be why (indices into ``q``)."""
        flat, lengths, normals = _hull_loops(q, hull)
        keyed, faces = _assemble(q, flat, lengths, normals, radius)
        vertices = q[keyed]
        # the model carries the tolerance it is valid at: at least the one asked for, and
        # enough for the (slightly bent) faces Qhull merged
        model_rtol = max(rtol, _round_up(radius / size),
                         _round_up(1.25 * _planarity_rtol(vertices, faces)))
        try:
            return Polyhedron(
                vertices,
                faces,
                name=name,
                center_of_mass=None if center_of_mass is None else np.asarray(center_of_mass),
                units=units,
                rtol=model_rtol,
                hull_facets=True,
            ), np.zeros(0, dtype=np.int64)
        except ModelError as exc:
            # kept without its traceback, whose frames hold the failed model's arrays
            exc = exc.with_traceback(None)
            if not unturned:
                return exc, np.zeros(0, dtype=np.int64)
            return exc, keyed[_unturned_corners(vertices, faces, model_rtol)]

    def by_merging(radius: float, hull: Any) -> Polyhedron | ModelError:
        # nearly coplanar or nearly collinear leftovers: merge a little more, each time
        got: Polyhedron | ModelError | None = None
        for _ in range(8):
            got, _ = attempt(p, radius, hull)
            if isinstance(got, Polyhedron):
                return got
            radius = max(radius * 2.0, 1e-12 * extent)
            hull = _qhull(p, radius, angle)
        assert got is not None
        return got

    def by_removal(hull: Any) -> Polyhedron | None:
        # Qhull keeps corners that are straight within the tolerance (a point a hair off the
        # line between two others, where the facets that meet there were not merged) or turn
        # back (a point inside a merged facet's thickness), and a larger merging radius makes
        # more of them. Such a point is within the tolerance of the hull of the others: leave
        # it out, at the first radius, until every corner turns.
        keep = np.ones(len(p), dtype=bool)
        for _ in range(32):
            sub = np.flatnonzero(keep)
            if len(sub) < 4:
                break
            got, unturned = attempt(p[sub], first_radius, hull, unturned=True)
            if isinstance(got, Polyhedron):
                return got
            if not len(unturned):
                break
            keep[sub[unturned]] = False
            hull = _qhull(p[np.flatnonzero(keep)], first_radius, angle)
        return None

    if len(p) < LARGE_HULL:
        got = by_merging(radius, hull)
        if isinstance(got, Polyhedron):
            return got
        model = by_removal(_qhull(p, first_radius, angle))
    else:
        # a Qhull run over this many points takes seconds: leaving out the few corners that
        # do not turn costs one more, merging coarser up to eight (a 1.3-million-triangle
        # sphere: 2 runs instead of 10)
        model = by_removal(hull)
        if model is None:
            got = by_merging(radius * 2.0, _qhull(p, radius * 2.0, angle))
            if isinstance(got, Polyhedron):
                return got
    if model is not None:
        return model
    raise MeshError(
        f"the hull of the points does not make a valid model at tolerance rtol={rtol:g} "
        f"({got}); try a larger tolerance (--rtol) or fewer faces (--max-faces)"
    )


def convex_hull(
    points: ArrayLike,
    *,
    name: str = "object",
    rtol: float = DEFAULT_RTOL,
    center_of_mass: ArrayLike | None = None,
    units: str = "m",
    angle: float = 0.0,
    max_faces: int | None = None,
) -> Polyhedron:
    """The convex hull of a point set as an object model.

    Parameters
    ----------
    points : array-like, shape (n_points, 3)
        At least 4 points, not all coplanar.
    name : str
        Object name.
    rtol : float
        Tolerance relative to the object's size: hull facets within ``rtol`` times the size
        of one plane are merged into one face. The model carries the tolerance it is valid at
        (``Polyhedron.rtol``): ``rtol``, or more where merged faces bend further.
    center_of_mass : array-like, shape (3,), optional
        Default the centroid of the uniform hull.
    units : str
        Length units.
    angle : float
        Also merge neighbouring facets whose normals differ by at most ``angle`` degrees.
    max_faces : int, optional
        Facet a curved object coarsely enough to have at most this many faces.

    Returns
    -------
    Polyhedron

    Raises
    ------
    MeshError
        Fewer than 4 points, non-finite points, or all points coplanar.
    """
    try:
        p = np.asarray(points, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise MeshError("points must be an (n, 3) array of numbers") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise MeshError(f"points must have shape (n, 3), got {p.shape}")
    if len(p) < 4:
        raise MeshError(f"a convex hull needs at least 4 points, got {len(p)}")
    if not np.all(np.isfinite(p)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(p), axis=1))[0])
        raise MeshError(f"point {bad} is not finite: {p[bad].tolist()}")
    big = float(np.abs(p).max())
    if big > MAX_COORDINATE:
        raise MeshError(
            f"a coordinate of magnitude {big:.3g} is beyond {MAX_COORDINATE:g}: products of "
            "such numbers overflow; express the points in other units"
        )
    # the largest side of the bounding box (no squares: they underflow near 1e-160)
    size = float(np.max(p.max(axis=0) - p.min(axis=0)))
    if size < MIN_SIZE:
        raise MeshError(
            f"the points span {size:.3g} (the largest side of their bounding box), below the "
            f"smallest object size {MIN_SIZE:g}: express them in smaller units (mm, um)"
        )
    rtol = float(check_number(rtol, "rtol", RTOL_RANGE, MeshError))
    angle = float(check_number(angle, "merge angle",
                               Range(0.0, 90.0, high_open=True, unit="degrees"), MeshError))
    if max_faces is not None:
        max_faces = int(check_number(max_faces, "max_faces",
                                     Range(4, MAX_FACES, integer=True), MeshError))
    try:
        units = check_units(units)
    except InputError as exc:
        raise MeshError(str(exc)) from None
    return _hull_model(p, name=name, rtol=rtol, angle=angle, max_faces=max_faces,
                       center_of_mass=center_of_mass, units=units)


def typed_decimals(p: FloatArray) -> FloatArray:
    """Single-precision coordinates (STL, most GLB) read as the decimals they were written as.

    A file that stores float32 holds 0.04 as 0.0399999991: read as such, the same part
    written in metres and in millimetres (40, exact) is not the same object in SI. Each
    coordinate becomes the shortest decimal (6 to 9 significant digits) that gives the same
    float32, as every float32 printer shows it. Data that is not all float32 is returned as
    it is.

    Parameters
    ----------
    p : array, shape (n, 3)

    Returns
    -------
    array, shape (n, 3)
    """
    f32 = p.astype(np.float32)
    if not np.array_equal(f32.astype(np.float64), p):
        return p
    out = p.copy()
    nz = p != 0.0
    x, want = p[nz], f32[nz]
    e = np.floor(np.log10(np.abs(x)))
    res, done = x.copy(), np.zeros(x.shape, dtype=bool)
    for digits in (6, 7, 8, 9):  # float32 always round-trips through 9 significant digits
        d = digits - 1 - e
        up = d >= 0
        cand = np.where(up, np.rint(x * 10.0 ** np.where(up, d, 0)) / 10.0 ** np.where(up, d, 0),
                        np.rint(x / 10.0 ** np.where(up, 0, -d)) * 10.0 ** np.where(up, 0, -d))
        ok = ~done & (cand.astype(np.float32) == want)
        res[ok] = cand[ok]
        done |= ok
    out[nz] = res
    return out


def from_mesh(
    path: str | Path,
    *,
    name: str | None = None,
    rtol: float = MESH_RTOL,
    angle: float = 0.0,
    max_faces: int | None = None,
    strict: bool = False,
    units: str = "m",
    notes: list[str] | None = None,
    allow_open: bool = True,
) -> Polyhedron:
    """An object model from a mesh file (STL, OBJ, PLY, OFF, GLB, ... anything trimesh reads).

    The mesh is cleaned as trimesh does it (duplicate vertices welded, also across texture
    seams; degenerate and duplicate triangles dropped; windings made consistent; small holes
    filled). The model is the mesh's convex hull, with nearly coplanar facets merged within
    ``rtol`` (relative to the size) or ``angle``. For a closed non-convex mesh, hull faces on
    which the mesh has no face (the object rests there on edges or vertices: the paper's
    virtual bottom faces) are marked virtual, and the centre of mass is the mesh's own (the
    hull's would be wrong). An open or non-manifold mesh, or one of several pieces, has no
    defined volume: its model is the hull of its points, with the hull's centroid as centre
    of mass, and a note says so (``strict=True`` refuses it instead).

    Parameters
    ----------
    path : str or Path
        The mesh file.
    name : str, optional
        Object name; default the file's stem.
    rtol : float
        Merging tolerance relative to the object's size; the model carries it (or the larger
        tolerance its merged faces need) as its own ``rtol``.
    angle : float
        Also merge neighbouring hull facets whose normals differ by at most this many degrees.
    max_faces : int, optional
        Facet a curved object (a ball, a can) coarsely enough to have at most this many faces.
    strict : bool
        Refuse an open, non-manifold or multi-piece mesh instead of taking its hull.
    units : str
        Length units of the file.
    notes : list of str, optional
        One-line notes on what was done to the mesh are appended here.
    allow_open : bool
        Kept for compatibility: open meshes are accepted unless ``strict``.

    Raises
    ------
    MeshError
        Unreadable file, missing ``trimesh``, degenerate or non-finite points, an open mesh
        with ``strict``; the message names the file.
    """
    path = Path(path)
    notes = [] if notes is None else notes
    try:
        units = check_units(units)
    except ModelError as exc:
        raise MeshError(f"{path}: {exc}") from None
    try:
        import trimesh  # optional dependency: only mesh files need it
    except ImportError:
        raise MeshError(
            f"{path}: reading mesh files needs trimesh; install it with "
            "`pip install 'nonprehensile[mesh]'`"
        ) from None
    if not path.is_file():
        raise MeshError(f"{path}: no such mesh file")
    log = logging.getLogger("trimesh")
    level = log.level
    # trimesh logs the tracebacks of the loaders it falls back from (binary STL, then ASCII):
    # what it could not read is reported here, on one line
    log.setLevel(logging.CRITICAL)
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for corrupt or unknown files
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise MeshError(f"{path}: trimesh cannot read it as a mesh: {first}") from None
    finally:
        log.setLevel(level)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0:
        raise MeshError(f"{path}: the file holds no triangle mesh")
    tris = np.asarray(mesh.faces)
    if tris.size and (tris.min() < 0 or tris.max() >= len(mesh.vertices)):
        # trimesh does not check the indices when it does not process the mesh
        raise MeshError(
            f"{path}: a triangle names vertex {int(tris.max())} of {len(mesh.vertices)}; the "
            "file is damaged"
        )
    pts = np.asarray(mesh.vertices, dtype=float)
    bad = np.flatnonzero(~np.all(np.isfinite(pts), axis=1))
    if bad.size:
        raise MeshError(
            f"{path}: vertex {int(bad[0])} is not finite ({pts[bad[0]].tolist()}); fix or "
            "remove it in the mesh"
        )
    big = np.flatnonzero(np.abs(pts).max(axis=1) > MAX_RECORDED_COORDINATE)
    if big.size:
        # (trimesh's vertex welding overflows int64 on such numbers; no real part is so large)
        raise MeshError(
            f"{path}: vertex {int(big[0])} {pts[big[0]].tolist()} is beyond "
            f"{MAX_RECORDED_COORDINATE:g} in magnitude; the file is damaged or its units are "
            "wrong"
        )
    if len(pts) < 4:
        raise MeshError(f"{path}: a solid needs at least 4 points, the mesh has {len(pts)}")
    span = float(np.max(pts.max(axis=0) - pts.min(axis=0)))
    if span < MIN_SIZE:
        raise MeshError(
            f"{path}: the mesh spans {span:.3g} (the largest side of its bounding box), below "
            f"the smallest object size {MIN_SIZE:g}; are its units right? Express it in "
            "smaller units (mm, um)"
        )
    # trimesh welds vertices closer than 1e-8 (an absolute distance): a mesh a millimetre
    # across in metres would lose its shape. Scale it up by a power of two (exact) while it
    # is cleaned, and back after.
    up = 2.0 ** -math.frexp(span)[1] if span < 1e-2 else 1.0
    try:
        if up != 1.0:
            mesh.apply_scale(up)  # type: ignore[no-untyped-call]
        filled = bool(len(mesh.faces)) and _clean(mesh, trimesh)
        if up != 1.0:
            mesh.apply_scale(1.0 / up)  # type: ignore[no-untyped-call]
    except (OverflowError, ValueError, IndexError) as exc:
        # trimesh's welding hashes coordinates and indices as int64: a damaged file overflows
        raise MeshError(f"{path}: trimesh cannot process the mesh ({exc}); the file is "
                        "damaged") from None
    if filled:
        notes.append(f"{path.name}: filled small holes in the mesh to close it")
    pts = np.asarray(mesh.vertices, dtype=float) if len(mesh.vertices) >= 4 else pts
    pts = typed_decimals(pts)
    closed = len(mesh.faces) > 0 and bool(mesh.is_watertight)
    pieces = int(mesh.body_count) if len(mesh.faces) else 1
    why = ""
    if not len(mesh.faces):
        why = "it has no triangles"
    elif pieces > 1:
        why = f"it is {pieces} separate pieces"
    elif not closed:
        open_edges = len(trimesh.grouping.group_rows(  # type: ignore[no-untyped-call]
            mesh.edges_sorted, require_count=1))
        why = (f"it is not closed ({open_edges} edges border only one triangle)"
               if open_edges else "it is not a manifold (some edges border more than two "
               "triangles)")
    if why and strict:
        raise MeshError(
            f"{path}: {why}, so its volume and centre of mass are undefined; repair it, or "
            "leave out --strict to use the convex hull of its points"
        )
    volume, com = 0.0, np.zeros(3)
    surface = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    if not why:
        if mesh.volume < 0:
            mesh.invert()
        volume, com = float(mesh.volume), np.asarray(mesh.center_mass, dtype=float)
        surface = (np.array(mesh.vertices, dtype=float), np.array(mesh.faces, dtype=np.int64))
    # what is left of the mesh is its caches (edges, adjacency): 1 GB for a million
    # triangles, freed before the hull needs the memory
    del mesh
    try:
        hull = convex_hull(pts, name=name or path.stem, rtol=rtol, angle=angle,
                           max_faces=max_faces, units=units)
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from None
    if why:
        notes.append(
            f"{path.name}: {why}: the model is the convex hull of its points, with the hull's "
            "centroid as centre of mass"
        )
        return hull
    area = float(sum(hull.face_areas.values()))
    if hull.volume - volume <= 2 * hull.atol * area:
        return hull  # convex: the hull is the object
    try:
        return dataclasses.replace(hull, center_of_mass=com,
                                   virtual_faces=_virtual_faces(hull, *surface))
    except ModelError as exc:
        raise MeshError(f"{path}: {exc}") from None


def _clean(mesh: Any, trimesh: Any) -> bool:
    """Weld, drop degenerate and duplicate triangles, orient, fill small holes (in place).

    Returns whether holes were filled."""
    # texture seams and split normals duplicate vertices: weld them all
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if not len(mesh.faces):
        return False
    filled = False
    if not mesh.is_watertight:
        filled = bool(trimesh.repair.fill_holes(mesh))
    if mesh.is_watertight and not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
    return filled


def _virtual_faces(hull: Polyhedron, vertices: FloatArray, triangles: NDArray[np.int64]
                   ) -> frozenset[str]:
    """Hull faces on which the mesh has no triangle: the object touches them only along
    edges or at vertices (the paper's virtual bottom faces). A hull face partly covered by a
    mesh face (a non-convex face, such as the side of an L) is a real face: the object rests
    on that face, and the hull face is its supporting polygon."""
    tri = vertices[triangles]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    tri_n = cross / np.maximum(norm, 1e-300)[:, None]
    areas = 0.5 * norm
    names = hull.face_ids
    normals = np.array([hull.normals[f] for f in names])
    anchors = hull.vertices[[hull.faces[f][0] for f in names]]
    atol = hull.atol
    # each triangle can only lie on a hull face of about its own normal: look at a few
    k = min(8, len(names))
    _, cand = cKDTree(normals).query(tri_n, k=k)
    cand = np.asarray(cand).reshape(len(tri), k)
    covered = np.zeros(len(names))
    taken = np.zeros(len(tri), dtype=bool)
    for j in range(k):
        f = cand[:, j]
        dist = np.abs(np.einsum("tvk,tk->tv", tri - anchors[f][:, None, :], normals[f]))
        on = (~taken) & np.all(dist <= atol, axis=1) & (np.einsum("tk,tk->t", tri_n,
                                                                   normals[f]) > 0.5)
        covered += np.bincount(f[on], weights=areas[on], minlength=len(names))
        taken |= on
    face_area = np.array([hull.face_areas[f] for f in names])
    return frozenset(f for f, c, a in zip(names, covered, face_area, strict=True)
                     if c <= 1e-6 * a)
