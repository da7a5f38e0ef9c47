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

__all__ = ["plan_filmstrip_figure"]

#: Most panels on one row.
_PER_ROW = 4
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
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    steps = result.steps
    n_panels = len(steps) + 1
    cols = min(n_panels, _PER_ROW)
    rows = math.ceil(n_panels / cols)
    fig = new_figure(figsize=(3.6 * cols, 3.9 * rows + 0.5))
    frames: list[tuple[NDArray[np.float64], str, list[tuple[str, NDArray[np.float64]]],
                       Offset | None]] = []
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
        frames.append((verts, title, paths, agent))
    if steps:
        last = steps[-1]
        verts = _pose_points(poly, last.end_pose, last.end_world, last.agent or result.offset,
                             scale)
    else:
        verts = _pose_points(poly, None, result.start, result.offset, scale)
    frames.append((verts, f"goal {result.goal}", [], steps[-1].agent if steps else
                   result.offset))
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
    width, height = 1.0 / cols, (1.0 - 0.5 / (3.9 * rows + 0.5)) / rows
    for idx, (verts, title, paths, where) in enumerate(frames):
        r, c = divmod(idx, cols)
        ax: Any = fig.add_axes((c * width, 1.0 - 0.5 / (3.9 * rows + 0.5) - (r + 1) * height,
                                width, height * 0.92), projection="3d")  # an Axes3D
        faces = [verts[list(loop)] for loop in poly.faces.values()]
        ax.add_collection3d(Poly3DCollection(faces, facecolors="#c6dbef", edgecolors="#4a6a8a",
                                             linewidths=0.6 if len(faces) < 60 else 0.0,
                                             alpha=0.85))
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
        ax.view_init(elev=28, azim=-60)
        ax.set_title(title, fontsize=11)
        ax.tick_params(labelsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_zticks([])
        ax.set_xlabel(f"x ({units})", fontsize=10, labelpad=-12)
        ax.set_ylabel(f"y ({units})", fontsize=10, labelpad=-12)
    fig.suptitle(f"Plan {result.start} -> {result.goal}: object pose at each step, reference "
                 "finger paths (lines), agent (orange triangle, pointing along its x axis)",
                 fontsize=12)
    return fig
