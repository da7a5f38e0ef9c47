"""Demonstrated finger trajectories in 3-D (the paper's Fig. 12(a)).

Matplotlib (the ``viz`` extra) is imported only inside these functions; they build
:class:`matplotlib.figure.Figure` objects directly and never touch pyplot's global state.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from nonprehensile.demonstrations.dataset import Dataset, Demonstration
from nonprehensile.errors import InputError
from nonprehensile.states import state_pose
from nonprehensile.viz._figures import new_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["plot_trajectories", "trajectory_figure"]

#: The skills of the paper's Fig. 12: a tumbling maneuver realised by two skills (Fig. 9).
FIG12_SKILLS = ("tumble-lift", "tumble-twist")


def _selection(
    dataset: Dataset, skills: Sequence[str] | None, marker: str | None
) -> tuple[list[Demonstration], str]:
    where = f"{dataset.root}: " if dataset.root is not None else ""
    shown = list(dict.fromkeys(d.skill.name for d in dataset.demonstrations))
    if not shown:
        raise InputError(f"{where}the dataset has no demonstration, so there is no trajectory "
                         "to draw; add recordings to its annotations")
    if skills is None:
        # the tumbling pair of Fig. 12 where demonstrated, else the first demonstrated skill
        # (a skills file names skills a dataset need not demonstrate)
        skills = [s for s in FIG12_SKILLS if s in shown] or shown[:1]
    demos: list[Demonstration] = []
    for name in skills:
        demos.extend(dataset.of_skill(name))  # raises InputError naming the skills there are
    if not demos:
        raise InputError(f"{where}the dataset has no demonstration of {list(skills)}; it "
                         f"demonstrates {shown}")
    marker = marker or dataset.fingers.get("R1")
    have = demos[0].trajectory.marker_names
    if marker not in have:
        raise InputError(f"no marker named {marker!r}; the recordings have {list(have)}")
    return demos, marker


def plot_trajectories(
    ax: Any,
    dataset: Dataset,
    skills: Sequence[str] | None = None,
    *,
    marker: str | None = None,
    color_by: str = "skill",
    events_only: bool = True,
    show_object: bool = True,
) -> Any:
    """Draw one marker's trajectories of some skills on 3-D axes.

    Parameters
    ----------
    ax : mpl_toolkits.mplot3d.axes3d.Axes3D
        Axes to draw on.
    dataset : Dataset
        A loaded dataset.
    skills : sequence of str, optional
        Skills to draw; by default the tumbling pair of Fig. 12 where demonstrated, else the
        first demonstrated skill.
    marker : str, optional
        The marker; by default the tip marker of finger R1 (the index finger).
    color_by : {"skill", "mentor"}
        One colour per skill or per mentor.
    events_only : bool
        Draw only the part between the first and last events (the manipulation itself).
    show_object : bool
        Draw the object's edges in its initial pose (scaled, in the trajectories' units).

    Returns
    -------
    Axes3D
        ``ax``.

    Raises
    ------
    InputError
        Unknown skill or marker, or ``color_by`` not one of the two.
    """
    if color_by not in ("skill", "mentor"):
        raise InputError(f"color_by must be 'skill' or 'mentor', got {color_by!r}")
    demos, marker = _selection(dataset, skills, marker)
    keys = list(dict.fromkeys(d.skill.name if color_by == "skill" else d.mentor for d in demos))
    colors = {k: f"C{i % 10}" for i, k in enumerate(keys)}
    from matplotlib.lines import Line2D
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    units = demos[0].trajectory.units
    # one collection for every path (and one for the object's edges): a line object per
    # demonstration costs a tenth of a second more to draw (issue 16)
    paths, path_colors = [], []
    for d in demos:
        traj = d.trajectory.to_units(units)
        p = traj.marker(marker)
        if events_only:
            a = round(d.events[0].time * traj.rate)
            b = round(d.events[-1].time * traj.rate)
            p = p[a:b + 1]
        paths.append(p)  # a gap (NaN) in the marker is a gap in its line, as with ax.plot
        path_colors.append(colors[d.skill.name if color_by == "skill" else d.mentor])
    ax.add_collection3d(Line3DCollection(paths, colors=path_colors, linewidths=0.8,
                                         alpha=0.7))
    drawn = list(paths)
    if show_object:
        poly = dataset.poly
        r, t = state_pose(poly, demos[0].initial)
        size = dataset.scale * (1000.0 if units == "mm" else 1.0)
        world = (poly.vertices @ r.T + t) * size
        edges = [world[[i, j]] for i, j in poly.edges.values()]
        ax.add_collection3d(Line3DCollection(edges, colors="0.3", linewidths=1.2))
        drawn += edges
    every = np.vstack(drawn)
    if np.isfinite(every).all(axis=1).any():  # a collection does not set the limits itself
        ax.set_xlim3d(np.nanmin(every[:, 0]), np.nanmax(every[:, 0]))
        ax.set_ylim3d(np.nanmin(every[:, 1]), np.nanmax(every[:, 1]))
        ax.set_zlim3d(np.nanmin(every[:, 2]), np.nanmax(every[:, 2]))
    ax.set_xlabel(f"x ({units})")
    ax.set_ylabel(f"y ({units})")
    ax.set_zlabel(f"z ({units})")
    # equal scale on the three axes, so that circles look round
    lims = np.array([ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()])
    mid, half = lims.mean(axis=1), (lims[:, 1] - lims[:, 0]).max() / 2
    ax.set_xlim3d(mid[0] - half, mid[0] + half)
    ax.set_ylim3d(mid[1] - half, mid[1] + half)
    ax.set_zlim3d(max(mid[2] - half, lims[2, 0]), max(mid[2] - half, lims[2, 0]) + 2 * half)
    ax.legend(handles=[Line2D([], [], color=colors[k], lw=0.8, alpha=0.7, label=k)
                       for k in keys], loc="upper left", fontsize="small")
    return ax


def trajectory_figure(
    dataset: Dataset,
    skills: Sequence[str] | None = None,
    *,
    marker: str | None = None,
    color_by: str = "skill",
    figsize: tuple[float, float] = (7.0, 6.0),
) -> Figure:
    """The paper's Fig. 12(a): demonstrated trajectories of a maneuver's skills in 3-D.

    See :func:`plot_trajectories` for the parameters.

    Returns
    -------
    matplotlib.figure.Figure
    """

    fig = new_figure(figsize=figsize)
    ax = fig.add_axes((0.0, 0.0, 1.0, 0.93), projection="3d")  # fixed layout (issue 16)
    plot_trajectories(ax, dataset, skills, marker=marker, color_by=color_by)
    demos, m = _selection(dataset, skills, marker)
    names = ", ".join(dict.fromkeys(d.skill.name for d in demos))
    ax.set_title(f"{m} trajectories of {names} ({len(demos)} demonstrations)")
    return fig
