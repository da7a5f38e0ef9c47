"""A plan as a filmstrip: the object's pose step by step in 3-D, with the reference finger paths
and where the agent stands (paper Section VII).

Panel ``i`` shows the object where step ``i`` starts (the plan tracks its pose through the
exact maneuvers), the finger paths of that step's reference motions (world frame), and the
agent: a triangle on the table at the origin of its frame, pointing along its ``x`` axis
(its rotation about the vertical). The last panel shows the object at the goal. Matplotlib
is imported inside the function; the figure uses a fixed layout (no layout engine pass).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import ObjectPose, Offset, Plan
from nonprehensile.states import State, state_pose
from nonprehensile.viz._figures import new_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["BOTTOM_COLOR", "plan_filmstrip_figure"]

#: Most panels on one row.
_PER_ROW = 4
#: Colour of the bottom face in the panels.
BOTTOM_COLOR = "#d62728"
_PATH_COLORS = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b")


def _pose_points(poly: Polyhedron, pose: ObjectPose | None, state: State, offset: Offset,
                 scale: float) -> NDArray[np.float64]:
    """The model's vertices in the world (shape (n_vertices, 3))."""
    if pose is not None:
        return pose.to_world(poly.vertices)
    rot, trans = state_pose(poly, offset.state_to_model(state))
    return offset.to_world(scale * (poly.vertices @ rot.T + trans))


def plan_filmstrip_figure(
    poly: Polyhedron,
    result: Plan,
    *,
    scale: float = 1.0,
    markers: Sequence[str] | None = None,
    units: str = "m",
) -> Figure:
    """The plan's filmstrip: one 3-D panel per state of the plan, start to goal.

    Parameters
    ----------
    poly : Polyhedron
    result : Plan
        A plan (:func:`nonprehensile.planning.plan`); its steps' poses place the object.
    scale : float
        World units per model unit (used where a step carries no pose).
    markers : sequence of str, optional
        The reference markers to draw (e.g. the finger tips); default all.
    units : str
        World length unit, for the axes.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    steps = result.steps
    n_panels = len(steps) + 1
    cols = min(n_panels, _PER_ROW)
    rows = math.ceil(n_panels / cols)
    head_in, panel_in = 0.75, 4.3  # the suptitle's band; a panel's height
    fig = new_figure(figsize=(3.6 * cols, panel_in * rows + head_in))
    frames: list[tuple[NDArray[np.float64], str, list[tuple[str, NDArray[np.float64]]],
                       Offset | None, str]] = []
    for i, step in enumerate(steps):
        agent = step.agent or result.offset
        verts = _pose_points(poly, step.start_pose, step.start_world, agent, scale)
        paths = []
        for source, target, _, ref in step.motions:
            if ref is None:
                continue
            for k, name in enumerate(ref.marker_names):
                if markers is None or name in markers:
                    paths.append((f"{source}->{target} {name}", ref.positions[:, k]))
        moved = " (agent relocated)" if step.relocated and i > 0 else ""
        title = (f"{i + 1}. {step.start_world} -> {step.end_world}\n"
                 f"{step.transition.skill.name}{moved}")
        frames.append((verts, title, paths, agent, step.start_world.face))
    if steps:
        last = steps[-1]
        verts = _pose_points(poly, last.end_pose, last.end_world, last.agent or result.offset,
                             scale)
    else:
        verts = _pose_points(poly, None, result.start, result.offset, scale)
    frames.append((verts, f"goal {result.goal}", [], steps[-1].agent if steps else
                   result.offset, result.goal.face))
    # one scale for every panel, so that the object's travel shows
    pts = [f[0] for f in frames] + [p for f in frames for _, p in f[2]]
    allp = np.vstack([p[~np.isnan(p).any(axis=1)] for p in pts])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    for f in frames:
        if f[3] is not None:
            lo[:2] = np.minimum(lo[:2], f[3].translate)
            hi[:2] = np.maximum(hi[:2], f[3].translate)
    lo[2] = 0.0
    size = float(np.max(hi - lo)) * 1.1 or 1.0
    center = 0.5 * (lo + hi)
    fig_h = panel_in * rows + head_in
    width, height = 1.0 / cols, (1.0 - head_in / fig_h) / rows
    elev, azim = 28.0, -60.0
    e, a = math.radians(elev), math.radians(azim)
    toward_viewer = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    names = list(poly.faces)
    for idx, (verts, title, paths, where, bottom) in enumerate(frames):
        r, c = divmod(idx, cols)
        ax: Any = fig.add_axes((c * width + 0.01 * width, 1.0 - head_in / fig_h
                                - (r + 1) * height + 0.06 * height, width * 0.88,
                                height * 0.8), projection="3d")  # an Axes3D
        ax.computed_zorder = False  # labels drawn over the translucent solid
        faces = [verts[list(loop)] for loop in poly.faces.values()]
        # the bottom face first, in red, seen through the translucent solid drawn over it
        ax.add_collection3d(Poly3DCollection([verts[list(poly.faces[bottom])]],
                                             facecolors=BOTTOM_COLOR, edgecolors="#7f0000",
                                             linewidths=1.0, gid=f"bottom:{bottom}"))
        ax.add_collection3d(Poly3DCollection(
            [p for f, p in zip(names, faces, strict=True) if f != bottom],
            facecolors="#c6dbef", edgecolors="#4a6a8a",
            linewidths=0.6 if len(faces) < 60 else 0.0, alpha=0.6))
        if len(names) <= 40:
            # the IDs of the faces turned to the viewer, so the pose reads at a glance
            for fid, corners in zip(names, faces, strict=True):
                centre = corners.mean(axis=0)
                n = np.cross(corners[1] - corners[0], corners[2] - corners[0])
                outward = n if n @ (centre - verts.mean(axis=0)) > 0 else -n
                if fid != bottom and outward @ toward_viewer > 0:
                    ax.text(*centre, fid, fontsize=10, fontweight="bold", ha="center",
                            va="center", color="#08306b", zorder=10)
        for j, (label, p) in enumerate(paths):
            ax.plot(p[:, 0], p[:, 1], p[:, 2], color=_PATH_COLORS[j % len(_PATH_COLORS)],
                    lw=1.4, label=label if idx == 0 else None)
        if where is not None:
            a = math.radians(where.rotate_deg)
            d = 0.12 * size
            x, y = where.translate
            tri = np.array([[x + d * math.cos(a), y + d * math.sin(a), 0.0],
                            [x + 0.5 * d * math.cos(a + 2.4), y + 0.5 * d * math.sin(a + 2.4),
                             0.0],
                            [x + 0.5 * d * math.cos(a - 2.4), y + 0.5 * d * math.sin(a - 2.4),
                             0.0]])
            ax.add_collection3d(Poly3DCollection([tri], facecolors="#ff7f0e",
                                                 edgecolors="#7f3f00"))
        ax.set_xlim(center[0] - size / 2, center[0] + size / 2)
        ax.set_ylim(center[1] - size / 2, center[1] + size / 2)
        ax.set_zlim(0.0, size)
        ax.set_box_aspect((1.0, 1.0, 1.0))
        ax.view_init(elev=elev, azim=azim)
        ax.set_title(f"{title}\nbottom face {bottom} (red)", fontsize=11)
        # a few round values on each axis: where the object and the agent are, in units
        ticks = MaxNLocator(3)
        ax.set_xticks(ticks.tick_values(center[0] - size / 2, center[0] + size / 2))
        ax.set_yticks(ticks.tick_values(center[1] - size / 2, center[1] + size / 2))
        ax.set_zticks(ticks.tick_values(0.0, size))
        ax.set_xlim(center[0] - size / 2, center[0] + size / 2)
        ax.set_ylim(center[1] - size / 2, center[1] + size / 2)
        ax.set_zlim(0.0, size)
        ax.tick_params(labelsize=8, pad=0)
        ax.set_xlabel(f"x ({units})", fontsize=9, labelpad=2)
        ax.set_ylabel(f"y ({units})", fontsize=9, labelpad=2)
        ax.set_zlabel(f"z ({units})", fontsize=9, labelpad=2)
    fig.suptitle(f"Plan {result.start} -> {result.goal}: the object where each step starts "
                 "(bottom face red),\nreference finger paths (lines), agent (orange triangle "
                 "pointing along its x axis)", fontsize=12, y=1.0 - 0.08 / fig_h, va="top")
    return fig
