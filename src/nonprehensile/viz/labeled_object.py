"""The figure of the labeled object: the paper's Fig. 3 (faces, edge numbers, ``A``, ``Delta``).

:func:`plot_object` draws the polyhedron in 3-D with each face's ID at its centroid and each
face's edge numbers just inside that face, next to the edge they number, so that every edge
shows two numbers, one per face (the paper's Fig. 3(a)). :func:`plot_adjacency` prints the
adjacency matrix of edge numbers as the paper does (Fig. 3(b)) and :func:`plot_delta` the face
shapes ``Delta_f``. :func:`object_figure` puts them together.

A single view of a convex solid shows only the faces that face the viewer, so the figure shows
two exactly opposite views: every face faces exactly one of them unless it is seen edge-on, and
the default view (:func:`default_view`) sees every face nearly as frontally as any view can,
so none is edge-on. We prefer two views to one view plus an unfolded net because a
view of a convex solid never overlaps itself, whereas an edge unfolding of a general convex
polyhedron may (whether a non-overlapping one always exists is Durer's open problem), and
because the views keep the solid's shape, its centre of mass and its virtual faces in sight.

The views use an orthographic projection with equal scales on the three axes, so a face faces
the viewer exactly when its outward normal has a positive component along the view direction.
Every label is a text artist with a ``gid`` that names it: ``"face:<ID>"`` for a face ID,
``"edge:<ID>:<k>"`` for edge number ``k`` of face ``<ID>``, ``"vertex:<i>"`` for a vertex index.

Matplotlib (the ``viz`` extra) is imported only inside these functions; they build
:class:`matplotlib.figure.Figure` objects directly and never touch pyplot's global state, so
they work with any backend, Agg included.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.states import is_stable
from nonprehensile.viz._figures import new_figure, require_matplotlib

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "check_faces",
    "default_view",
    "object_figure",
    "plot_adjacency",
    "plot_delta",
    "plot_object",
    "view_direction",
]

FloatArray = NDArray[np.float64]

#: Text written in the adjacency table where ``A`` is undefined (diagonal, faces not adjacent).
UNDEFINED = "-"

#: The view matplotlib opens 3-D axes with; :func:`default_view` prefers views near it.
_MPL_VIEW = (30.0, -60.0)
#: :func:`default_view` accepts views that see the most oblique face at least this fraction
#: as frontally as the best view does.
_VIEW_QUALITY = 0.8
#: ... and draw the centre of mass at least this fraction of the diameter from every label.
_COM_CLEARANCE = 0.05

# Pastel fills keep black labels readable on every face.
_FACE_COLORS = (
    "#a6cee3", "#b2df8a", "#fb9a99", "#fdbf6f", "#cab2d6", "#ffff99",
    "#8dd3c7", "#bebada", "#fdb462", "#b3de69", "#fccde5", "#d9d9d9",
)
_EDGE_NUMBER_COLOR = "#08306b"
#: Default fraction of the way from an edge's midpoint to its face's centroid where the edge
#: number is written.
_LABEL_OFFSET = 0.3
# The centre-of-mass sign: a white disc with a black ring, quartered by a black cross.
_COM_STYLE: tuple[dict[str, Any], dict[str, Any]] = (
    {"marker": "o", "markersize": 10, "markerfacecolor": "white", "markeredgecolor": "black",
     "markeredgewidth": 1.3},
    {"marker": "+", "markersize": 10, "markeredgecolor": "black", "markeredgewidth": 1.3},
)
# A light box behind each label keeps it readable over hatching and hidden edges.
_LABEL_BOX = {"boxstyle": "round,pad=0.12", "facecolor": "white", "edgecolor": "none",
              "alpha": 0.65}


def _check_poly(poly: object) -> Polyhedron:
    if not isinstance(poly, Polyhedron):
        raise InputError(
            f"expected an object model (nonprehensile.geometry.Polyhedron), got "
            f"{type(poly).__name__}; build one with nonprehensile.geometry.cube() or load a "
            "model file"
        )
    return poly


def _check_view(view: object) -> tuple[float, float]:
    try:
        elev, azim = (float(x) for x in view)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise InputError(
            f"view must be two angles in degrees (elev, azim), e.g. (30, -60); got {view!r}"
        ) from None
    if not (math.isfinite(elev) and math.isfinite(azim)):
        raise InputError(f"view angles must be finite degrees, got {view!r}")
    return elev, azim


def view_direction(view: tuple[float, float]) -> FloatArray:
    """Unit vector from the object towards the viewer for a matplotlib ``(elev, azim)`` view.

    Parameters
    ----------
    view : tuple of float
        Elevation above the ``xy`` plane and azimuth from ``+x``, in degrees (matplotlib's
        ``Axes3D.view_init`` convention, ``z`` vertical).

    Returns
    -------
    array, shape (3,)
        ``[cos(elev) cos(azim), cos(elev) sin(azim), sin(elev)]``.
    """
    elev, azim = (math.radians(a) for a in _check_view(view))
    return np.array(
        [math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)]
    )


def default_view(poly: Polyhedron) -> tuple[float, float]:
    """A view that sees every face of ``poly`` nearly as frontally as possible, and clearly.

    The score of a view direction ``v`` is the smallest ``|n_f . v|`` over the faces'
    outward normals ``n_f``: the cosine of the angle at which the most oblique face is seen,
    hence also the ratio of its drawn to its true area; from a view and its opposite every
    face is seen at least that frontally. The best score is ``1/sqrt(3)`` for a cube (along
    its body diagonal). Views of the upper hemisphere are tried on a 5-degree grid; those
    that draw the centre of mass within 0.05 diameters of a label or a vertex are set aside
    (unless all do), and of the rest whose score is at least 0.8 times their best, this
    returns the one closest to matplotlib's default view ``(30, -60)``. The exact optimum is
    often a degenerate picture (the cube's body diagonal draws its nearest corner on its
    centre of mass, a regular tetrahedron's best view an edge's labels).

    Parameters
    ----------
    poly : Polyhedron
        The object.

    Returns
    -------
    tuple of float
        ``(elev, azim)`` in degrees, multiples of 5, ``0 <= elev < 90``.
    """
    poly = _check_poly(poly)
    normals = np.array([poly.normals[f] for f in poly.faces])
    # A 5-degree grid finds the optimum within a few percent and gives round angles; the
    # score (a min of |.|) is not smooth, so a grid is simpler and safer than an optimiser.
    elev, azim = np.meshgrid(np.arange(0.0, 90.0, 5.0), np.arange(-180.0, 180.0, 5.0))
    elev, azim = elev.ravel(), azim.ravel()
    e, a = np.radians(elev), np.radians(azim)
    dirs = np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    score = np.abs(dirs @ normals.T).min(axis=1)
    # The centre of mass is drawn over the solid: keep its image off every label and vertex
    # (a symmetric solid seen along an axis of symmetry draws a corner or an edge's labels
    # right on it). Distance of each point's image from the centre's image, per direction:
    rel = _label_points(poly) - poly.com  # (n_points, 3)
    along = dirs @ rel.T  # (n_dirs, n_points)
    dist2 = np.maximum(np.sum(rel * rel, axis=1)[None, :] - along**2, 0.0)
    clear = np.sqrt(dist2.min(axis=1)) >= _COM_CLEARANCE * poly.diameter
    if not np.any(clear):
        clear[:] = True
    good = clear & (score >= _VIEW_QUALITY * score[clear].max())
    near = np.flatnonzero(good)
    best = int(near[int(np.argmax(dirs[near] @ view_direction(_MPL_VIEW)))])
    return float(elev[best]), float(azim[best])


def _label_points(poly: Polyhedron, offset: float = _LABEL_OFFSET) -> FloatArray:
    """Every point a label is written at: face centroids, edge numbers, vertices.

    Returns
    -------
    array, shape (n_faces + 2 * n_edges + n_vertices, 3)
    """
    pts = [poly.face_centroids[f] for f in poly.faces]
    pts += [
        _edge_label_point(poly, f, k, offset)
        for f in poly.faces
        for k in range(1, poly.n_edges(f) + 1)
    ]
    return np.vstack([np.array(pts), poly.vertices])


def _opposite(view: tuple[float, float]) -> tuple[float, float]:
    """The view from exactly the other side: direction ``-v``."""
    elev, azim = view
    return -elev, (azim + 360.0) % 360.0 - 180.0


def _edge_label_point(poly: Polyhedron, face: str, k: int, offset: float) -> FloatArray:
    """Where edge number ``k`` of ``face`` is written, shape (3,).

    The point lies on the segment from the edge's midpoint to the face's centroid, at the
    fraction ``offset`` of its length: inside the face (the face is convex), on the face's
    side of the edge, so the two numbers of one edge sit on either side of it and never on
    top of each other.
    """
    i, j = poly.edge_vertices(face, k)
    mid = 0.5 * (poly.vertices[i] + poly.vertices[j])
    return np.asarray(mid + offset * (poly.face_centroids[face] - mid), dtype=float)


def plot_object(
    poly: Polyhedron,
    ax: Axes | None = None,
    *,
    view: tuple[float, float] | None = None,
    labeled_faces: Iterable[str] | None = None,
    label_offset: float = _LABEL_OFFSET,
    show_vertices: bool = False,
    face_fontsize: float = 14.0,
    edge_fontsize: float = 10.0,
    legend: bool = True,
) -> Axes:
    """Draw the labeled polyhedron in 3-D, as in the paper's Fig. 3(a).

    Faces facing the viewer are filled, with their ID at the centroid and their edge numbers
    ``1, 2, ...`` (clockwise seen from outside) just inside the face next to each edge; edges
    hidden behind the solid are dotted. Virtual faces (the paper's virtual bottom faces) are
    hatched with a dashed outline. The centre of mass is marked with the usual quartered disc.

    Parameters
    ----------
    poly : Polyhedron
        The object model.
    ax : matplotlib 3-D Axes, optional
        Where to draw (made with ``projection="3d"``); default a new figure's axes.
    view : tuple of float, optional
        ``(elev, azim)`` in degrees; default :func:`default_view`.
    labeled_faces : iterable of str, optional
        Faces whose ID and edge numbers are written; default the faces facing the viewer
        (outward normal ``n_f`` with ``n_f . v > 0``, ``v`` the :func:`view_direction`).
    label_offset : float
        Where each edge number sits on the segment from its edge's midpoint to the face's
        centroid, as a fraction of that segment in ``(0, 1)``: larger moves numbers off the
        edge, towards the face ID.
    show_vertices : bool
        Also write each vertex index (the numbers the model file's loops use) next to the
        vertices of the labeled faces.
    face_fontsize, edge_fontsize : float
        Font sizes in points of the face IDs and of the edge numbers.
    legend : bool
        Add a legend for the centre of mass (and virtual faces, if any).

    Returns
    -------
    matplotlib Axes
        The 3-D axes drawn on; its text artists carry ``gid`` ``"face:<ID>"``,
        ``"edge:<ID>:<k>"`` and ``"vertex:<i>"``.

    Raises
    ------
    InputError
        If matplotlib is missing, ``ax`` is not a 3-D axes, the view is not two angles, or
        ``label_offset`` is outside ``(0, 1)``; :class:`~nonprehensile.errors.ModelError` if
        ``labeled_faces`` names a face the object lacks.
    """
    require_matplotlib()  # before the imports below, so a missing extra is named
    from matplotlib.legend_handler import HandlerTuple
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from mpl_toolkits.mplot3d.axes3d import Axes3D

    poly = _check_poly(poly)
    elev, azim = default_view(poly) if view is None else _check_view(view)
    if not 0.0 < label_offset < 1.0:
        raise InputError(
            f"label_offset must be a fraction in (0, 1) of the way from an edge to its face's "
            f"centroid, got {label_offset!r}; 0.3 is the default"
        )
    if ax is None:
        ax = new_figure(figsize=(6.0, 6.0), layout="constrained").add_subplot(projection="3d")
    if not isinstance(ax, Axes3D):
        raise InputError(
            f"ax must be a 3-D axes (made with add_subplot(projection='3d')), got "
            f"{type(ax).__name__}"
        )
    v_dir = view_direction((elev, azim))
    # screen directions of the orthographic view: right (horizontal) and up
    right = np.array([-math.sin(math.radians(azim)), math.cos(math.radians(azim)), 0.0])
    up = np.cross(v_dir, right)
    front = {f for f in poly.faces if float(poly.normals[f] @ v_dir) > 0.0}
    labeled = front if labeled_faces is None else set(labeled_faces)
    for f in labeled:
        poly.loop(f)  # ModelError naming an unknown face

    # The projection is orthographic and the solid convex, so which face hides which is known
    # exactly: draw in a fixed order (hidden edges, faces, marks, labels) instead of letting
    # matplotlib sort whole collections by depth, which misorders touching polygons.
    ax.computed_zorder = False
    ax.set_proj_type("ortho")
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()

    for idx, (f, loop) in enumerate(poly.faces.items()):
        corners = poly.vertices[list(loop)]
        virtual = f in poly.virtual_faces
        if f in front:
            coll = Poly3DCollection(
                [corners],
                facecolors=_FACE_COLORS[idx % len(_FACE_COLORS)],
                edgecolors="#202020",
                linewidths=1.4,
                linestyles="--" if virtual else "-",
                alpha=0.75,
                zorder=2,
            )
            if virtual:
                coll.set_hatch("///")
        else:
            coll = Poly3DCollection(
                [corners],
                facecolors="none",
                edgecolors="#9a9a9a",
                linewidths=0.8,
                linestyles=":",
                zorder=1,
            )
        coll.set_gid(f"facet:{f}")
        ax.add_collection3d(coll)

    com = poly.com
    # the usual centre-of-mass sign (a quartered disc), distinct from a vertex or a dot
    for style in _COM_STYLE:
        ax.plot([com[0]], [com[1]], [com[2]], linestyle="none", zorder=3, gid="com", **style)

    for f in poly.faces:
        if f not in labeled:
            continue
        c = poly.face_centroids[f]
        ax.text(
            c[0], c[1], c[2], f, gid=f"face:{f}", fontsize=face_fontsize, fontweight="bold",
            ha="center", va="center", zorder=5, bbox=_LABEL_BOX,
        )
        for k in range(1, poly.n_edges(f) + 1):
            p = _edge_label_point(poly, f, k, label_offset)
            ax.text(
                p[0], p[1], p[2], str(k), gid=f"edge:{f}:{k}", fontsize=edge_fontsize,
                color=_EDGE_NUMBER_COLOR, ha="center", va="center", zorder=4, bbox=_LABEL_BOX,
            )
    if show_vertices:
        shown = sorted({i for f in labeled for i in poly.faces[f]})
        neighbours: dict[int, set[int]] = {i: set() for i in shown}
        for i, j in poly.edges.values():
            for u, w in ((i, j), (j, i)):
                if u in neighbours:
                    neighbours[u].add(w)
        for i in shown:
            # Write the index in the widest angle between the vertex's edges as drawn: off
            # the solid for a corner on the outline, inside a face (clear of its edges) for a
            # corner in front.
            rel = poly.vertices[sorted(neighbours[i])] - poly.vertices[i]
            ang = np.sort(np.arctan2(rel @ up, rel @ right))
            gaps = np.diff(np.append(ang, ang[0] + 2 * math.pi))
            widest = int(np.argmax(gaps))
            phi = ang[widest] + gaps[widest] / 2
            p = poly.vertices[i] + 0.06 * poly.diameter * (
                math.cos(phi) * right + math.sin(phi) * up
            )
            ax.text(
                p[0], p[1], p[2], str(i), gid=f"vertex:{i}", fontsize=edge_fontsize - 1,
                color="#7f2704", fontstyle="italic", ha="center", va="center", zorder=4,
                bbox=_LABEL_BOX,
            )

    # Equal scales on the three axes keep the view direction in data coordinates equal to
    # view_direction(view), so the front faces computed above are the ones drawn in front; a
    # box the shape of the object's bounding box (not a cube) lets a flat object fill the axes.
    lo, hi = poly.vertices.min(axis=0), poly.vertices.max(axis=0)
    span = np.maximum(hi - lo, 0.05 * poly.diameter)  # a flat object still gets some depth
    center = 0.5 * (lo + hi)
    ax.set_xlim(center[0] - span[0] / 2, center[0] + span[0] / 2)
    ax.set_ylim(center[1] - span[1] / 2, center[1] + span[1] / 2)
    ax.set_zlim(center[2] - span[2] / 2, center[2] + span[2] / 2)
    # Matplotlib scales the box so that its diagonal fits the axes whatever the view; zoom
    # until the object's own drawing (its extent across and up the screen) fills a fixed
    # share of them instead, leaving room for vertex indices outside the solid.
    extent = max(float(np.ptp(poly.vertices @ right)), float(np.ptp(poly.vertices @ up)))
    margin = 0.75 if show_vertices else 0.9
    zoom = margin * float(np.linalg.norm(span)) / extent
    ax.set_box_aspect(tuple(float(x) for x in span), zoom=zoom)

    if legend:
        handles: list[tuple[Line2D, Line2D] | Line2D | Patch] = [
            (
                Line2D([], [], linestyle="none", **_COM_STYLE[0]),
                Line2D([], [], linestyle="none", **_COM_STYLE[1]),
            ),
            Line2D([], [], color="#9a9a9a", linestyle=":"),
        ]
        if poly.virtual_faces:
            handles.append(
                Patch(facecolor="white", edgecolor="#202020", hatch="///", linestyle="--")
            )
        labels = ["centre of mass", "hidden edge", "virtual face"][: len(handles)]
        ax.legend(handles, labels, loc="lower left", fontsize=8, frameon=False,
                  handler_map={tuple: HandlerTuple(ndivide=1)})
    return cast("Axes", ax)  # mpl_toolkits is untyped: Axes3D is an Axes to the type checker


def _format_angle(d: float) -> str:
    """Degrees as a short string: whole degrees without decimals, else one decimal."""
    r = round(d, 1)
    return f"{r:.0f}" if r == int(r) else f"{r:.1f}"


def plot_adjacency(poly: Polyhedron, ax: Axes | None = None, *, fontsize: float = 11.0) -> Axes:
    """Print the adjacency matrix of edge numbers as a table (the paper's Fig. 3(b)).

    Row ``f``, column ``g`` holds ``A(f, g) = k``: edge ``k`` of face ``f`` is shared with
    face ``g``. The diagonal and faces that share no edge are undefined and show ``"-"``.

    Parameters
    ----------
    poly : Polyhedron
        The object model.
    ax : matplotlib Axes, optional
        A 2-D axes to draw in (its frame is hidden); default a new figure's axes.
    fontsize : float
        Font size of the table in points.

    Returns
    -------
    matplotlib Axes
        The axes; ``ax.tables[0]`` is the table, cell ``(i + 1, j)`` holding ``A`` of row
        face ``i`` and column face ``j`` (model order), row 0 the column labels, column -1
        the row labels.

    Raises
    ------
    InputError
        If matplotlib is missing or ``poly`` is not an object model.
    """

    poly = _check_poly(poly)
    if ax is None:
        n = len(poly.faces)
        fig = new_figure(figsize=(1.0 + 0.45 * n, 0.8 + 0.35 * n), layout="constrained")
        ax = fig.add_subplot()
    labels = list(poly.face_ids)
    cells = [
        [str(poly.adjacency[f][g]) if g in poly.adjacency[f] else UNDEFINED for g in labels]
        for f in labels
    ]
    ax.set_axis_off()
    header = "#e8e8e8"
    table = ax.table(
        cellText=cells,
        rowLabels=labels,
        colLabels=labels,
        # leave a tenth of the axes for the row labels, which sit left of the columns
        colWidths=[0.9 / len(labels)] * len(labels),
        rowColours=[header] * len(labels),
        colColours=[header] * len(labels),
        cellLoc="center",
        rowLoc="center",
        loc="center",
    )
    table.auto_set_font_size(False)
    table.set_fontsize(fontsize)
    table.scale(1.0, 1.4)
    for (row, col), cell in table.get_celld().items():
        if row == 0 or col == -1:
            cell.get_text().set_fontweight("bold")
        if col == -1:
            cell.PAD = 0.3  # the row label column is sized to its text: give the IDs air
        elif cell.get_text().get_text() == UNDEFINED:
            cell.get_text().set_color("#9a9a9a")
    ax.set_title(
        "Adjacency matrix A: A(row, column) = number, on the row face,\n"
        "of the edge it shares with the column face",
        fontsize=fontsize,
    )
    return ax


def plot_delta(poly: Polyhedron, ax: Axes | None = None, *, fontsize: float = 11.0) -> Axes:
    """Tabulate each face's shape ``Delta_f`` (edge alignment angles), its size and stability.

    Parameters
    ----------
    poly : Polyhedron
        The object model.
    ax : matplotlib Axes, optional
        A 2-D axes to draw in; default a new figure's axes.
    fontsize : float
        Font size of the table in points.

    Returns
    -------
    matplotlib Axes
        The axes; ``ax.tables[0]`` has one row per face (model order) with columns
        ``Delta_f`` in degrees, the number of edges, and whether the object can rest on the
        face (a virtual face is marked so).

    Raises
    ------
    InputError
        If matplotlib is missing or ``poly`` is not an object model.
    """

    poly = _check_poly(poly)
    if ax is None:
        fig = new_figure(figsize=(4.5, 0.8 + 0.35 * len(poly.faces)), layout="constrained")
        ax = fig.add_subplot()
    rows = []
    for f in poly.faces:
        delta = "[" + ", ".join(_format_angle(d) for d in poly.delta[f]) + "]"
        rests = "yes" if is_stable(poly, f) else "no"
        if f in poly.virtual_faces:
            rests += " (virtual)"
        rows.append([delta, str(poly.n_edges(f)), rests])
    header = "#e8e8e8"
    ax.set_axis_off()
    table = ax.table(
        cellText=rows,
        rowLabels=list(poly.face_ids),
        colLabels=[r"$\Delta_f$ (deg)", "edges", "stable"],
        rowColours=[header] * len(rows),
        colColours=[header] * 3,
        cellLoc="center",
        rowLoc="center",
        loc="center",
    )
    table.auto_set_font_size(False)
    table.set_fontsize(fontsize)
    table.scale(1.0, 1.4)
    table.auto_set_column_width([-1, 0, 1, 2])
    for (row, col), cell in table.get_celld().items():
        if row == 0 or col == -1:
            cell.get_text().set_fontweight("bold")
        if col == -1:
            cell.PAD = 0.3  # the row label column is sized to its text: give the IDs air
    ax.set_title(
        "Face shapes: edge k points at angle d_k from edge 1,\n"
        "counterclockwise seen from inside the object",
        fontsize=fontsize,
    )
    return ax


def object_figure(
    poly: Polyhedron,
    *,
    view: tuple[float, float] | None = None,
    show_vertices: bool = False,
    figsize: tuple[float, float] | None = None,
    tables: bool = True,
    faces: Iterable[str] | None = None,
) -> Figure:
    """The whole object model on one figure: two opposite labeled views, ``A`` and ``Delta``.

    A model of more than :data:`DETAIL_LIMIT` faces is drawn simplified: both views shaded,
    without tables, and labeled only where ``faces`` names faces (thousands of labels are
    unreadable and take minutes to draw; ``object show --json`` lists them).

    Top: the object from ``view`` and from exactly the opposite side; each face is labeled in
    the view it faces (its ID and its edge numbers), so every face ID and every edge number
    appears once. Bottom: the adjacency matrix (:func:`plot_adjacency`) and the face shapes
    (:func:`plot_delta`).

    Parameters
    ----------
    poly : Polyhedron
        The object model.
    view : tuple of float, optional
        ``(elev, azim)`` of the first view in degrees; default :func:`default_view`, which
        sees no face edge-on (a face seen edge-on is labeled in the second view, where its
        labels crowd onto a line).
    show_vertices : bool
        Also write vertex indices (see :func:`plot_object`).
    figsize : tuple of float, optional
        Width and height in inches; default sized to the number of faces.
    tables : bool
        Draw ``A`` and ``Delta`` below the views (a report shows them as HTML tables).
    faces : iterable of str, optional
        Label these faces only (their IDs and edge numbers, in the view each faces; on a
        large model they are also drawn in orange); default every face, or none above
        :data:`DETAIL_LIMIT` faces.

    Returns
    -------
    matplotlib.figure.Figure
        Not attached to pyplot: save it with ``fig.savefig(path)``.

    Raises
    ------
    InputError
        If matplotlib is missing, ``poly`` is not an object model or the view is not two
        angles; a face in ``faces`` that the model lacks (named, with the fix).
    """

    poly = _check_poly(poly)
    chosen = None if faces is None else check_faces(poly, faces)
    first = default_view(poly) if view is None else _check_view(view)
    second = _opposite(first)
    if len(poly.faces) > DETAIL_LIMIT or not tables:
        return _plain_figure(poly, first, second, figsize, labels=len(poly.faces) <= DETAIL_LIMIT,
                             show_vertices=show_vertices, chosen=chosen)
    v_dir = view_direction(first)
    # every face in exactly one view: the first takes the faces facing it, the second the rest
    front = [f for f in poly.faces if float(poly.normals[f] @ v_dir) > 0.0]
    back = [f for f in poly.faces if f not in front]
    if chosen is not None:
        front = [f for f in front if f in chosen]
        back = [f for f in back if f in chosen]

    n = len(poly.faces)
    table_height = 1.2 + 0.32 * n
    if figsize is None:
        figsize = (max(12.0, 4.0 + 0.5 * n), 6.0 + table_height)
    fig = new_figure(figsize=figsize, layout="constrained")
    grid = fig.add_gridspec(2, 2, height_ratios=[6.0, table_height], width_ratios=[1.2, 1.0])
    for col, (v, labeled) in enumerate(((first, front), (second, back))):
        ax = fig.add_subplot(grid[0, col], projection="3d")
        plot_object(
            poly, ax, view=v, labeled_faces=labeled, show_vertices=show_vertices,
            legend=col == 0
        )
        side = "first view" if col == 0 else "opposite view"
        ax.set_title(
            f"{side} (elev {v[0]:g}°, azim {v[1]:g}°): faces {', '.join(labeled) or 'none'}",
            fontsize=11)
    plot_adjacency(poly, fig.add_subplot(grid[1, 0]))
    plot_delta(poly, fig.add_subplot(grid[1, 1]))
    virtual = ""
    if poly.virtual_faces:
        virtual = f"; virtual faces: {', '.join(sorted(poly.virtual_faces))}"
    fig.suptitle(
        f"Object model of {poly.name!r}: {n} faces; edge numbers run clockwise seen from "
        f"outside{virtual}",
        fontsize=13,
    )
    return fig


#: Most faces drawn with labels and tables; larger models are drawn simplified.
DETAIL_LIMIT = 40


def check_faces(poly: Polyhedron, faces: Iterable[str]) -> list[str]:
    """The faces named, in the model's order.

    Raises
    ------
    InputError
        A face the model lacks (naming a few it has), or no face at all.
    """
    wanted = [str(f).strip() for f in faces]
    wanted = [f for f in wanted if f]
    unknown = [f for f in wanted if f not in poly.faces]
    if unknown:
        known = list(poly.faces)
        shown = ", ".join(known[:12]) + (" ..." if len(known) > 12 else "")
        raise InputError(f"{poly.name}: no face {', '.join(map(repr, unknown))}; its faces "
                         f"are {shown} (`nonprehensile object show` lists them)")
    if not wanted:
        raise InputError("no face to label: give face IDs separated by commas, e.g. a,b,c")
    return [f for f in poly.faces if f in set(wanted)]


def _plain_figure(
    poly: Polyhedron, first: tuple[float, float], second: tuple[float, float],
    figsize: tuple[float, float] | None, *, labels: bool, show_vertices: bool,
    chosen: list[str] | None = None,
) -> Figure:
    """Two opposite views without tables; shaded, one collection per view when the model is
    large (a collection per face, or a label per edge, is what takes minutes), its
    ``chosen`` faces orange and labeled."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    n = len(poly.faces)
    fig = new_figure(figsize=figsize or (11.0, 5.4))
    for col, v in enumerate((first, second)):
        ax: Any = fig.add_axes((0.01 + 0.5 * col, 0.02, 0.48, 0.84), projection="3d")
        v_dir = view_direction(v)
        facing = [f for f in poly.faces if float(poly.normals[f] @ v_dir) > 0.0]
        if labels:
            shown = facing if chosen is None else [f for f in facing if f in chosen]
            plot_object(poly, ax, view=v, labeled_faces=shown, show_vertices=show_vertices,
                        legend=col == 0)
        else:
            light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
            names = list(poly.faces)
            shade = np.array([0.35 + 0.55 * max(float(poly.normals[f] @ light), 0.0)
                              for f in names])
            colors = np.c_[0.55 * shade, 0.7 * shade, shade]
            picked = set(chosen or ())
            for i, f in enumerate(names):
                if f in picked:  # the chosen faces in a light orange, labels readable on it
                    lit = 0.75 + 0.25 * shade[i]
                    colors[i] = (lit, 0.72 * lit, 0.4 * lit)
            coll = Poly3DCollection([poly.vertices[list(poly.faces[f])] for f in names],
                                    facecolors=colors, edgecolors="none")
            ax.add_collection3d(coll)
            ax.computed_zorder = False  # the labels over the solid
            for f in (f for f in facing if f in picked):
                c = poly.face_centroids[f]
                ax.text(c[0], c[1], c[2], f, gid=f"face:{f}", fontsize=12, fontweight="bold",
                        ha="center", va="center", zorder=5, bbox=_LABEL_BOX)
                for k in range(1, poly.n_edges(f) + 1):
                    p = _edge_label_point(poly, f, k, _LABEL_OFFSET)
                    ax.text(p[0], p[1], p[2], str(k), gid=f"edge:{f}:{k}", fontsize=8,
                            color=_EDGE_NUMBER_COLOR, ha="center", va="center", zorder=4,
                            bbox=_LABEL_BOX)
            ax.set_proj_type("ortho")
            ax.view_init(elev=v[0], azim=v[1])
            ax.set_axis_off()
            lo, hi = poly.vertices.min(axis=0), poly.vertices.max(axis=0)
            span = np.maximum(hi - lo, 0.05 * poly.diameter)
            c = 0.5 * (lo + hi)
            ax.set_xlim(c[0] - span[0] / 2, c[0] + span[0] / 2)
            ax.set_ylim(c[1] - span[1] / 2, c[1] + span[1] / 2)
            ax.set_zlim(c[2] - span[2] / 2, c[2] + span[2] / 2)
            ax.set_box_aspect(tuple(float(x) for x in span))
        side = "first view" if col == 0 else "opposite view"
        ax.set_title(f"{side} (elev {v[0]:g}°, azim {v[1]:g}°)", fontsize=12)
    if labels or chosen:
        what = "edge numbers run clockwise seen from outside"
        if chosen:
            what = f"faces {', '.join(chosen)} labeled (orange); {what}"
    else:
        what = ("labels omitted (label some with --faces a,b,...): `object show --json` "
                "lists every face, edge and A")
    fig.suptitle(f"Object model of {poly.name!r}: {n} faces; {what}", fontsize=13)
    return fig
