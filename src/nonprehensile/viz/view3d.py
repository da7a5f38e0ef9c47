"""Rotatable 3-D views as one self-contained HTML file: the labeled object, and a plan.

Drawn with plotly (the ``view3d`` extra, ``pip install 'nonprehensile[view3d]'``), imported
only inside these functions. We chose plotly because its wheel ships plotly.js itself
(``plotly/package_data/plotly.min.js``), so :func:`write_html` embeds the whole library in the
page: the file opens in any browser with no network and no other file, which is what a user
sends to a colleague or keeps beside a plan. The alternatives need more: three.js or
vtk.js viewers fetch their scripts from a CDN or need a JavaScript build step, PyVista's
HTML export needs VTK and trame; matplotlib has no rotatable output outside a GUI window.
The price is size: about 4.8 MB of embedded JavaScript per file.

:func:`object_view` draws the object with every face filled, outlined and labeled with its
ID (and, on models up to :data:`EDGE_NUMBER_LIMIT` faces, each face's edge numbers, clockwise
seen from outside: the paper's Fig. 3(a)); hovering a label gives the face's ``Delta``, its
neighbours and the edge each is shared along. ``faces`` labels chosen faces only (a scan of
hundreds of faces). :func:`plan_view` draws a plan: the object's pose where each step starts
and at the goal (bottom face in red), the reference finger paths of each step, and where the
agent stands at each step (a triangle on the table pointing along its ``x`` axis), each step
its own legend group that a click shows or hides.

Every label is a point of a ``Scatter3d`` trace whose ``text`` is the label: tests read the
figure's JSON (``figure.to_dict()``) to check that every face is labeled.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import ObjectPose, Offset, Plan
from nonprehensile.states import State, state_pose
from nonprehensile.viz.labeled_object import check_faces

if TYPE_CHECKING:
    import plotly.graph_objects as go

__all__ = [
    "EDGE_NUMBER_LIMIT",
    "figure_json",
    "object_view",
    "plan_view",
    "require_plotly",
    "write_html",
]

FloatArray = NDArray[np.float64]

#: Models with more faces get face IDs only (their edge numbers would cover the object).
EDGE_NUMBER_LIMIT = 40

# the report's pastel face colours (viz.labeled_object), so the two figures agree
_FACE_COLORS = (
    "#a6cee3", "#b2df8a", "#fb9a99", "#fdbf6f", "#cab2d6", "#ffff99",
    "#8dd3c7", "#bebada", "#fdb462", "#b3de69", "#fccde5", "#d9d9d9",
)
_BOTTOM_COLOR = "#d62728"
_STEP_COLORS = ("#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2",
                "#17becf", "#bcbd22")


def require_plotly() -> None:
    """Import plotly or say which extra to install.

    Raises
    ------
    InputError
        If plotly is not installed.
    """
    try:
        import plotly.graph_objects  # noqa: F401  (imported to check that it is there)
    except ImportError:
        raise InputError(
            "the rotatable 3-D view needs plotly, which is not installed; install it with "
            "`pip install 'nonprehensile[view3d]'`"
        ) from None


def _triangles(poly: Polyhedron) -> tuple[list[int], list[int], list[int], list[str]]:
    """A fan triangulation of every face (faces are convex): vertex indices and the face of
    each triangle."""
    i, j, k, face_of = [], [], [], []
    for f, loop in poly.faces.items():
        for n in range(1, len(loop) - 1):
            i.append(loop[0])
            j.append(loop[n])
            k.append(loop[n + 1])
            face_of.append(f)
    return i, j, k, face_of


def _outline(points: FloatArray, poly: Polyhedron) -> tuple[list[float | None], ...]:
    """Every edge of the object once, as one polyline with gaps (None) between edges."""
    xs: list[float | None] = []
    ys: list[float | None] = []
    zs: list[float | None] = []
    for a, b in poly.edges.values():
        for p in (points[a], points[b]):
            xs.append(float(p[0]))
            ys.append(float(p[1]))
            zs.append(float(p[2]))
        xs.append(None)
        ys.append(None)
        zs.append(None)
    return xs, ys, zs


def _face_info(poly: Polyhedron, f: str) -> str:
    """A face's hover text: edges, Delta, neighbours by edge number."""
    delta = ", ".join(f"{d:g}" for d in poly.delta[f])
    nb = ", ".join(f"edge {k}: {g}" for g, k in sorted(poly.adjacency[f].items(),
                                                       key=lambda gk: gk[1]))
    virtual = " (virtual)" if f in poly.virtual_faces else ""
    return (f"face {f}{virtual}<br>{poly.n_edges(f)} edges, Delta = [{delta}] deg"
            f"<br>neighbours: {nb}")


def _labels(poly: Polyhedron, points: FloatArray, rotation: FloatArray, faces: Sequence[str],
            size: float) -> tuple[FloatArray, list[str], list[str]]:
    """Label positions (face centroids lifted off the face along its outward normal, in the
    world), texts and hover texts of ``faces``."""
    lift = 0.04 * size
    pos, text, hover = [], [], []
    for f in faces:
        c = points[list(poly.faces[f])].mean(axis=0)
        pos.append(c + lift * (rotation @ poly.normals[f]))
        text.append(f)
        hover.append(_face_info(poly, f))
    return np.array(pos).reshape(-1, 3), text, hover


def _edge_numbers(poly: Polyhedron, points: FloatArray, faces: Sequence[str]
                  ) -> tuple[FloatArray, list[str], list[str]]:
    """Edge numbers of ``faces``, each inside its face next to its edge (a third of the way
    from the edge's midpoint to the face's centroid, as the PNG figure writes them)."""
    pos, text, hover = [], [], []
    for f in faces:
        loop = list(poly.faces[f])
        centre = points[loop].mean(axis=0)
        for k in range(1, poly.n_edges(f) + 1):
            a, b = poly.edge_vertices(f, k)
            mid = 0.5 * (points[a] + points[b])
            pos.append(mid + 0.3 * (centre - mid))
            text.append(str(k))
            other = next((g for g, e in poly.adjacency[f].items() if e == k), "?")
            hover.append(f"edge {k} of face {f}, shared with face {other}")
    return np.array(pos).reshape(-1, 3), text, hover


def _solid(go: Any, poly: Polyhedron, points: FloatArray, *, name: str, colors: list[str],
           opacity: float, group: str | None = None, show_legend: bool = True) -> list[Any]:
    """The object's faces (a Mesh3d, one colour per face) and its edges (a line)."""
    i, j, k, face_of = _triangles(poly)
    order = {f: n for n, f in enumerate(poly.faces)}
    mesh = go.Mesh3d(
        x=points[:, 0], y=points[:, 1], z=points[:, 2], i=i, j=j, k=k,
        facecolor=[colors[order[f]] for f in face_of], opacity=opacity, flatshading=True,
        hoverinfo="skip", name=name, legendgroup=group or name, showlegend=show_legend,
        lighting={"ambient": 0.75, "diffuse": 0.5, "specular": 0.05},
    )
    xs, ys, zs = _outline(points, poly)
    line = go.Scatter3d(x=xs, y=ys, z=zs, mode="lines", line={"color": "#202020", "width": 3},
                        hoverinfo="skip", name=f"{name}: edges", legendgroup=group or name,
                        showlegend=False)
    return [mesh, line]


def _text_trace(go: Any, pos: FloatArray, text: list[str], hover: list[str], *, name: str,
                size: int, color: str, group: str | None = None, visible: Any = True) -> Any:
    return go.Scatter3d(
        x=pos[:, 0], y=pos[:, 1], z=pos[:, 2], mode="text", text=text, hovertext=hover,
        hoverinfo="text", textfont={"size": size, "color": color}, name=name,
        legendgroup=group or name, visible=visible,
    )


def _layout(title: str, *, aspect: str = "data") -> dict[str, Any]:
    axis = {"showbackground": False, "showgrid": True, "gridcolor": "#e0e0e0",
            "zeroline": False}
    return {
        "title": {"text": title, "x": 0.5},
        "scene": {"aspectmode": aspect, "xaxis": dict(axis), "yaxis": dict(axis),
                  "zaxis": dict(axis), "camera": {"projection": {"type": "orthographic"},
                                                   "eye": {"x": 1.25, "y": -1.6, "z": 0.9}}},
        "legend": {"itemclick": "toggle", "groupclick": "togglegroup"},
        "margin": {"l": 0, "r": 0, "t": 90, "b": 0},
        "paper_bgcolor": "white",
    }


def object_view(poly: Polyhedron, *, faces: Iterable[str] | None = None,
                edge_numbers: bool | None = None) -> go.Figure:
    """The object, rotatable, with every face (or the chosen ``faces``) labeled.

    Parameters
    ----------
    poly : Polyhedron
        The object model (drawn in its own frame and units).
    faces : iterable of str, optional
        Faces to label; default every face. Chosen faces are drawn in colour, the others
        grey.
    edge_numbers : bool, optional
        Show each labeled face's edge numbers (a legend entry shows or hides them); default
        shown when at most :data:`EDGE_NUMBER_LIMIT` faces are labeled, else hidden until
        clicked.

    Returns
    -------
    plotly.graph_objects.Figure
        Save it with :func:`write_html`. Its face labels are the ``text`` of the trace named
        ``"face IDs"``; edge numbers are in ``"edge numbers"``.

    Raises
    ------
    InputError
        plotly missing, or a face the model lacks.
    """
    require_plotly()
    import plotly.graph_objects as go

    labeled = list(poly.faces) if faces is None else check_faces(poly, faces)
    every = faces is None
    chosen = set(labeled)
    colors = ([_FACE_COLORS[n % len(_FACE_COLORS)] for n in range(len(poly.faces))] if every
              else ["#fdbf6f" if f in chosen else "#d9d9d9" for f in poly.faces])
    pts = np.asarray(poly.vertices, dtype=float)
    size = float(poly.diameter) or 1.0
    traces = _solid(go, poly, pts, name=poly.name, colors=colors, opacity=0.9)
    pos, text, hover = _labels(poly, pts, np.eye(3), labeled, size)
    traces.append(_text_trace(go, pos, text, hover, name="face IDs", size=18, color="black"))
    if edge_numbers is None:
        edge_numbers = len(labeled) <= EDGE_NUMBER_LIMIT
    epos, etext, ehover = _edge_numbers(poly, pts, labeled)
    # lifted off the faces like the IDs, so that the solid does not hide them
    lift = np.array([0.02 * size * poly.normals[f] for f in labeled
                     for _ in range(poly.n_edges(f))]).reshape(-1, 3)
    traces.append(_text_trace(go, epos + lift, etext, ehover, name="edge numbers", size=12,
                              color="#08306b", visible=True if edge_numbers else "legendonly"))
    com = poly.com
    traces.append(go.Scatter3d(x=[com[0]], y=[com[1]], z=[com[2]], mode="markers",
                               marker={"size": 5, "color": "black", "symbol": "cross"},
                               name="centre of mass", hovertext=["centre of mass"],
                               hoverinfo="text"))
    which = "every face" if every else f"faces {', '.join(labeled)}"
    title = (f"{poly.name}: {len(poly.faces)} faces, {which} labeled; edge numbers run "
             "clockwise seen from outside<br><sub>drag to rotate, scroll to zoom, hover a "
             "label for its face's Delta and neighbours</sub>")
    fig = go.Figure(traces)
    fig.update_layout(**_layout(title))
    units = poly.units
    fig.update_scenes(xaxis_title=f"x ({units})", yaxis_title=f"y ({units})",
                      zaxis_title=f"z ({units})")
    return fig


def _pose_points(poly: Polyhedron, pose: ObjectPose | None, state: State, offset: Offset,
                 scale: float) -> tuple[FloatArray, FloatArray]:
    """The model's vertices in the world (shape (n_vertices, 3)) and the object-to-world
    rotation."""
    if pose is not None:
        return pose.to_world(poly.vertices), np.asarray(pose.rotation)
    rot, trans = state_pose(poly, offset.state_to_model(state))
    c, s = math.cos(math.radians(offset.rotate_deg)), math.sin(math.radians(offset.rotate_deg))
    yaw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return offset.to_world(scale * (poly.vertices @ rot.T + trans)), yaw @ rot


def _agent_triangle(where: Offset, size: float) -> FloatArray:
    """The agent's marker: a triangle on the table at its frame's origin, pointing along
    its ``x`` axis (shape (3, 3))."""
    a = math.radians(where.rotate_deg)
    x, y = where.translate
    return np.array([[x + size * math.cos(a), y + size * math.sin(a), 0.0],
                     [x + 0.5 * size * math.cos(a + 2.4), y + 0.5 * size * math.sin(a + 2.4),
                      0.0],
                     [x + 0.5 * size * math.cos(a - 2.4), y + 0.5 * size * math.sin(a - 2.4),
                      0.0]])


def plan_view(poly: Polyhedron, result: Plan, *, scale: float = 1.0,
              markers: Sequence[str] | None = None, units: str = "m") -> go.Figure:
    """A plan, rotatable: the object at each step, the finger paths and the agent.

    Step ``i`` (a legend group: click to show or hide it) draws the object where the step
    starts, its bottom face red and every face labeled, the reference paths of its motions
    (one line per marker and arc), and the agent where it stands for that step; the goal is
    drawn the same way. One scale for all, so the object's travel shows.

    Parameters
    ----------
    poly : Polyhedron
    result : Plan
        From :func:`nonprehensile.planning.plan`; its steps' poses place the object.
    scale : float
        World units per model unit, where a step carries no pose.
    markers : sequence of str, optional
        The reference markers to draw (e.g. the finger tips); default all.
    units : str
        World length unit, for the axes.

    Returns
    -------
    plotly.graph_objects.Figure
    """
    require_plotly()
    import plotly.graph_objects as go

    steps = result.steps
    frames: list[tuple[str, State, ObjectPose | None, Offset, list[Any]]] = []
    for i, step in enumerate(steps):
        agent = step.agent or result.offset
        moved = ", agent relocated" if step.relocated and i > 0 else ""
        name = (f"step {i + 1}: {step.start_world} -> {step.end_world} by "
                f"{step.transition.skill.name}{moved}")
        frames.append((name, step.start_world, step.start_pose, agent, list(step.motions)))
    last_agent = steps[-1].agent or result.offset if steps else result.offset
    frames.append((f"goal {result.goal}", steps[-1].end_world if steps else result.start,
                   steps[-1].end_pose if steps else None, last_agent, []))
    size = scale * float(poly.diameter) or 1.0
    order = {f: n for n, f in enumerate(poly.faces)}
    traces: list[Any] = []
    for n, (name, state, pose, agent, motions) in enumerate(frames):
        color = _STEP_COLORS[n % len(_STEP_COLORS)]
        pts, rot = _pose_points(poly, pose, state, agent, scale)
        bottom = state.face
        colors = [_FACE_COLORS[order[f] % len(_FACE_COLORS)] for f in poly.faces]
        colors[order[bottom]] = _BOTTOM_COLOR
        traces += _solid(go, poly, pts, name=name, colors=colors, opacity=0.55, group=name)
        # the labels ride on the pose; the bottom face's says so
        pos, text, hover = _labels(poly, pts, rot, list(poly.faces), size)
        text = [f"{t} (bottom)" if t == bottom else t for t in text]
        traces.append(_text_trace(go, pos, text, hover, name=f"{name}: faces", size=13,
                                  color="black", group=name))
        traces[-1].showlegend = False
        for k, (source, target, _, ref) in enumerate(motions):
            if ref is None:
                continue
            for j, marker in enumerate(ref.marker_names):
                if markers is not None and marker not in markers:
                    continue
                p = ref.positions[:, j]
                ok = ~np.isnan(p).any(axis=1)
                traces.append(go.Scatter3d(
                    x=p[ok, 0], y=p[ok, 1], z=p[ok, 2], mode="lines",
                    line={"color": color, "width": 5, "dash": "solid" if k % 2 == 0 else "dash"},
                    name=f"{source} -> {target}: {marker}", legendgroup=name,
                    showlegend=False, hovertext=f"{name}<br>{source} -> {target}: {marker}",
                    hoverinfo="text"))
        tag = "goal" if n == len(frames) - 1 else f"step {n + 1}"
        top = pts[int(np.argmax(pts[:, 2]))]
        traces.append(go.Scatter3d(
            x=[pts[:, 0].mean()], y=[pts[:, 1].mean()], z=[top[2] + 0.25 * size],
            mode="text", text=[tag], textfont={"size": 15, "color": color}, hovertext=[name],
            hoverinfo="text", legendgroup=name, showlegend=False, name=f"{name}: tag"))
        if n < len(steps):
            # where the agent stands for this step, and whether it moved there
            moved_here = n > 0 and steps[n].relocated
            traces.append(go.Scatter3d(
                x=[agent.translate[0]], y=[agent.translate[1]], z=[0.12 * size],
                mode="text", text=[f"agent {n + 1}" + (" (relocated)" if moved_here else "")],
                textfont={"size": 12, "color": "#7f3f00"}, hoverinfo="skip",
                legendgroup=name, showlegend=False, name=f"{name}: agent label"))
            if moved_here:
                before = steps[n - 1].agent or result.offset
                traces.append(go.Scatter3d(
                    x=[before.translate[0], agent.translate[0]],
                    y=[before.translate[1], agent.translate[1]], z=[0.0, 0.0],
                    mode="lines+markers", line={"color": "#ff7f0e", "width": 3, "dash": "dot"},
                    marker={"size": 3, "color": "#ff7f0e"}, legendgroup=name,
                    showlegend=False, name=f"{name}: relocation",
                    hovertext=(f"agent relocated: turned {before.rotate_deg:g} -> "
                               f"{agent.rotate_deg:g} deg"), hoverinfo="text"))
        tri = _agent_triangle(agent, 0.3 * size)
        traces.append(go.Mesh3d(
            x=tri[:, 0], y=tri[:, 1], z=tri[:, 2], i=[0], j=[1], k=[2], color="#ff7f0e",
            opacity=1.0, name=f"{name}: agent", legendgroup=name, showlegend=False,
            hovertext=(f"agent: turned {agent.rotate_deg:g} deg, at ({agent.translate[0]:.3g}, "
                       f"{agent.translate[1]:.3g}) {units}"), hoverinfo="text"))
    fig = go.Figure(traces)
    has_paths = any(ref is not None for s in steps for *_, ref in s.motions)
    paths = ("the reference finger paths" if has_paths
             else "no finger paths (plan with reference motions: --dataset)")
    title = (f"Plan {result.start} -> {result.goal}: the object where each step starts (bottom "
             f"face red), {paths},<br>the agent (orange triangle, pointing along its x axis)"
             "<br><sub>drag to rotate, scroll to zoom; click a step in the legend to hide it"
             "</sub>")
    fig.update_layout(**_layout(title))
    fig.update_scenes(xaxis_title=f"x ({units})", yaxis_title=f"y ({units})",
                      zaxis_title=f"z ({units})")
    return fig


def write_html(fig: go.Figure, path: str | Path) -> Path:
    """Write ``fig`` as one self-contained HTML file: plotly.js embedded, no network needed.

    Raises
    ------
    InputError
        A suffix other than ``.html``/``.htm``.
    """
    path = Path(path)
    if path.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"{path}: the 3-D view is an HTML file; name it with .html")
    from nonprehensile.io import write_text_file

    # include_plotlyjs=True embeds the library from plotly's wheel; no MathJax (off by
    # default) and no link to plotly's site in the mode bar, so nothing is fetched
    html = fig.to_html(include_plotlyjs=True, full_html=True,
                       config={"displaylogo": False, "responsive": True},
                       default_width="100%", default_height="95vh")
    return write_text_file(path, html)


def figure_json(fig: go.Figure) -> dict[str, Any]:
    """The figure as plain JSON (what the page holds), for tests and other programs."""
    return dict(json.loads(fig.to_json()))
