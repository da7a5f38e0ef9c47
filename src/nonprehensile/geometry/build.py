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
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError

from nonprehensile.errors import MeshError, ModelError
from nonprehensile.geometry.polyhedron import DEFAULT_RTOL, Polyhedron

__all__ = [
    "box",
    "convex_hull",
    "cube",
    "face_name",
    "from_mesh",
    "octahedron",
    "prism",
    "tetrahedron",
]

FloatArray = NDArray[np.float64]

#: Mesh formats that :func:`from_mesh` is tested on; trimesh reads more.
MESH_FORMATS = ("stl", "obj", "ply", "off", "glb")


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


def cube(size: float = 1.0, *, name: str = "cube") -> Polyhedron:
    """The paper's cube, labeled as in ``examples/cube.json``.

    Faces: ``a`` bottom (``z = 0``), ``c`` top, ``b`` right (``x = size``), ``e`` left,
    ``d`` back (``y = size``), ``f`` front (``y = 0``). Edge numbers follow the paper's
    Section III text (``A(b, a) = 2``, ``A(a, b) = 3``) and the spec's example skill: pushed
    on ``f``, the cube rolls over ``E(a, d)`` from ``a:0`` to ``d:0``.
    """
    s = float(size)
    if not s > 0:
        raise ModelError(f"cube size must be positive, got {size!r}")
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


def box(width: float, depth: float, height: float, *, name: str = "box") -> Polyhedron:
    """A rectangular box ``width x depth x height`` (along x, y, z), corner at the origin."""
    dims = np.array([width, depth, height], dtype=float)
    if not np.all(np.isfinite(dims)) or np.any(dims <= 0):
        raise ModelError(f"box dimensions must be positive, got {dims.tolist()}")
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    return convex_hull(corners * dims, name=name)


def prism(
    n: int, radius: float = 1.0, height: float = 1.0, *, name: str | None = None
) -> Polyhedron:
    """A right prism on a regular ``n``-gon of circumradius ``radius``."""
    if n < 3:
        raise ModelError(f"a prism needs a polygon of at least 3 sides, got {n}")
    if not (radius > 0 and height > 0):
        raise ModelError(f"prism radius and height must be positive, got {radius}, {height}")
    ang = 2 * np.pi * np.arange(n) / n
    ring = np.column_stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(n)])
    top = ring + np.array([0.0, 0.0, height])
    return convex_hull(np.vstack([ring, top]), name=name or f"prism{n}")


def tetrahedron(edge: float = 1.0, *, name: str = "tetrahedron") -> Polyhedron:
    """A regular tetrahedron with the given edge length."""
    p = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    return convex_hull(p * (edge / (2 * math.sqrt(2))), name=name)


def octahedron(edge: float = 1.0, *, name: str = "octahedron") -> Polyhedron:
    """A regular octahedron with the given edge length."""
    p = np.vstack([np.eye(3), -np.eye(3)]) * (edge / math.sqrt(2))
    return convex_hull(p, name=name)


def _hull_faces(points: FloatArray, atol: float) -> list[tuple[FloatArray, list[int]]]:
    """Qhull's triangles merged into planar faces: (outward normal, vertex indices) each."""
    try:
        hull = ConvexHull(points)
    except QhullError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else "Qhull failed"
        raise MeshError(
            f"cannot build a convex hull of {len(points)} points: they are degenerate (all "
            f"coplanar, collinear or coincident). Qhull said: {first}"
        ) from None
    simplices = hull.simplices
    eqs = hull.equations
    n_tri = len(simplices)
    face_of = np.full(n_tri, -1)
    faces: list[tuple[FloatArray, list[int]]] = []
    # Grow each face from a seed triangle over neighbours lying in the seed's plane; testing
    # against the seed (not the neighbour) keeps a slowly curving surface from merging whole.
    for seed in range(n_tri):
        if face_of[seed] >= 0:
            continue
        fid = len(faces)
        n, off = eqs[seed, :3], eqs[seed, 3]
        stack, members = [seed], []
        face_of[seed] = fid
        while stack:
            t = stack.pop()
            members.append(t)
            for nb in hull.neighbors[t]:
                if face_of[nb] < 0 and np.all(np.abs(points[simplices[nb]] @ n + off) <= atol):
                    face_of[nb] = fid
                    stack.append(nb)
        verts = sorted({int(i) for t in members for i in simplices[t]})
        faces.append((n / np.linalg.norm(n), verts))
    return faces


def _order_loop(points: FloatArray, idx: list[int], n_out: FloatArray, atol: float) -> list[int]:
    """Order a face's vertices clockwise seen from outside, dropping collinear ones."""
    p = points[idx]
    c = p.mean(axis=0)
    n_in = -n_out
    u = p[0] - c
    u /= np.linalg.norm(u)
    w = np.cross(n_in, u)
    ang = np.arctan2((p - c) @ w, (p - c) @ u)  # counterclockwise about the inward normal
    loop = [idx[i] for i in np.argsort(ang, kind="stable")]
    changed = True
    while changed and len(loop) > 3:
        changed = False
        for k in range(len(loop)):
            a, b, d = points[loop[k - 1]], points[loop[k]], points[loop[(k + 1) % len(loop)]]
            line = d - a
            height = np.linalg.norm(np.cross(line, b - a)) / np.linalg.norm(line)
            if height <= atol:
                del loop[k]
                changed = True
                break
    return loop


def convex_hull(
    points: ArrayLike,
    *,
    name: str = "object",
    rtol: float = DEFAULT_RTOL,
    center_of_mass: ArrayLike | None = None,
    units: str = "m",
) -> Polyhedron:
    """The convex hull of a point set as an object model.

    Parameters
    ----------
    points : array-like, shape (n_points, 3)
        At least 4 points, not all coplanar.
    name : str
        Object name.
    rtol : float
        Tolerance, relative to the diameter, within which hull triangles are coplanar.
    center_of_mass : array-like, shape (3,), optional
        Default the centroid of the uniform hull.
    units : str
        Length units.

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
    except (TypeError, ValueError):
        raise MeshError("points must be an (n, 3) array of numbers") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise MeshError(f"points must have shape (n, 3), got {p.shape}")
    if len(p) < 4:
        raise MeshError(f"a convex hull needs at least 4 points, got {len(p)}")
    if not np.all(np.isfinite(p)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(p), axis=1))[0])
        raise MeshError(f"point {bad} is not finite: {p[bad].tolist()}")
    extent = float(np.linalg.norm(p.max(axis=0) - p.min(axis=0)))
    atol = rtol * extent
    faces = _hull_faces(p, atol)
    loops = [(n, _order_loop(p, idx, n, atol)) for n, idx in faces]

    used = sorted({i for _, loop in loops for i in loop})
    # vertices in lexicographic order of rounded coordinates, so names do not depend on the
    # order the points came in
    digits = max(0, int(-math.floor(math.log10(max(atol, 1e-15)))) - 1)
    keyed = sorted(used, key=lambda i: tuple(np.round(p[i], digits)))
    new_index = {old: new for new, old in enumerate(keyed)}
    vertices = p[keyed]

    def face_key(item: tuple[FloatArray, list[int]]) -> tuple[float, float]:
        n = item[0]
        az = math.atan2(n[1], n[0]) % (2 * math.pi)
        return (round(float(n[2]), 6), round(az, 6) % round(2 * math.pi, 6))

    order = sorted(range(len(loops)), key=lambda i: face_key(loops[i]))
    model_faces: dict[str, tuple[int, ...]] = {}
    for rank, i in enumerate(order):
        loop = [new_index[j] for j in loops[i][1]]
        start = loop.index(min(loop))
        model_faces[face_name(rank)] = tuple(loop[start:] + loop[:start])
    try:
        return Polyhedron(
            vertices,
            model_faces,
            name=name,
            center_of_mass=None if center_of_mass is None else np.asarray(center_of_mass),
            units=units,
            rtol=rtol,
        )
    except ModelError as exc:
        raise MeshError(
            f"the hull of the points does not make a valid model at tolerance rtol={rtol:g} "
            f"({exc}); try a larger tolerance"
        ) from None


def from_mesh(
    path: str | Path,
    *,
    name: str | None = None,
    rtol: float = 1e-6,
    allow_open: bool = False,
    units: str = "m",
) -> Polyhedron:
    """An object model from a mesh file (STL, OBJ, PLY, OFF, GLB, ... anything trimesh reads).

    The model is the mesh's convex hull, with coplanar triangles merged into polygon faces
    within ``rtol``. For a non-convex mesh, hull faces on which the mesh has no face (the
    object rests there on edges or vertices: the paper's virtual bottom faces) are marked
    virtual, and the centre of mass is the mesh's own (the hull's would be wrong).

    Parameters
    ----------
    path : str or Path
        The mesh file.
    name : str, optional
        Object name; default the file's stem.
    rtol : float
        Merging tolerance relative to the diameter.
    allow_open : bool
        Accept a mesh that does not close a volume, using the hull of its vertices (and the
        hull's centroid as centre of mass).
    units : str
        Length units of the file.

    Raises
    ------
    MeshError
        Unreadable file, missing ``trimesh``, open mesh (unless ``allow_open``), degenerate
        points; the message names the file.
    """
    path = Path(path)
    try:
        import trimesh  # optional dependency: only mesh files need it
    except ImportError:
        raise MeshError(
            f"{path}: reading mesh files needs trimesh; install it with "
            "`pip install 'nonprehensile[mesh]'`"
        ) from None
    if not path.is_file():
        raise MeshError(f"{path}: no such mesh file")
    try:
        mesh = trimesh.load(str(path), force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for corrupt or unknown files
        raise MeshError(f"{path}: trimesh cannot read it as a mesh: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0:
        raise MeshError(f"{path}: the file holds no triangle mesh")
    pts = np.asarray(mesh.vertices, dtype=float)
    if len(pts) < 4:
        raise MeshError(f"{path}: a solid needs at least 4 points, the mesh has {len(pts)}")
    if not mesh.is_watertight and not allow_open:
        n_open = len(
            trimesh.grouping.group_rows(  # type: ignore[no-untyped-call]
                mesh.edges_sorted, require_count=1
            )
        )
        raise MeshError(
            f"{path}: the mesh is not closed ({n_open} edges border only one triangle), so "
            "its volume and centre of mass are undefined; repair it, or accept the hull of "
            "its points with allow_open=True (--allow-open)"
        )
    try:
        hull = convex_hull(pts, name=name or path.stem, rtol=rtol, units=units)
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from None
    if not mesh.is_watertight:
        return hull
    if mesh.volume < 0:
        mesh.invert()
    convex = abs(mesh.volume - hull.volume) <= 1e-6 * hull.volume
    if convex:
        return hull
    try:
        return dataclasses.replace(
            hull,
            center_of_mass=np.asarray(mesh.center_mass, dtype=float),
            virtual_faces=_virtual_faces(hull, mesh, rtol),
        )
    except ModelError as exc:
        raise MeshError(f"{path}: {exc}") from None


def _virtual_faces(hull: Polyhedron, mesh: Any, rtol: float) -> frozenset[str]:
    """Hull faces on which the mesh has no triangle: the object touches them only along
    edges or at vertices (the paper's virtual bottom faces). A hull face partly covered by a
    mesh face (a non-convex face, such as the side of an L) is a real face: the object rests
    on that face, and the hull face is its supporting polygon."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)
    areas = np.asarray(mesh.area_faces, dtype=np.float64)
    atol = rtol * hull.diameter
    out = set()
    for f in hull.faces:
        n = hull.normals[f]
        p0 = hull.vertices[hull.faces[f][0]]
        on_plane = np.all(np.abs((tri - p0) @ n) <= atol, axis=1) & (normals @ n > 0.5)
        covered = float(areas[on_plane].sum())
        if covered <= 1e-6 * hull.face_areas[f]:
            out.add(f)
    return frozenset(out)
