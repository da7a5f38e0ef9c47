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
    if skills is None:
        names = [s for s in FIG12_SKILLS if any(k.name == s for k in dataset.skills)]
        skills = names or [dataset.skills[0].name]
    demos: list[Demonstration] = []
    for name in skills:
        demos.extend(dataset.of_skill(name))  # raises InputError naming the skills there are
    if not demos:
        raise InputError(f"the dataset has no demonstration of {list(skills)}")
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
        Skills to draw; by default the tumbling pair of Fig. 12 when the dataset has it.
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
    units = demos[0].trajectory.units
    labelled: set[str] = set()
    for d in demos:
        traj = d.trajectory.to_units(units)
        p = traj.marker(marker)
        if events_only:
            a = round(d.events[0].time * traj.rate)
            b = round(d.events[-1].time * traj.rate)
            p = p[a:b + 1]
        key = d.skill.name if color_by == "skill" else d.mentor
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color=colors[key], lw=0.8, alpha=0.7,
                label=key if key not in labelled else None)
        labelled.add(key)
    if show_object:
        poly = dataset.poly
        r, t = state_pose(poly, demos[0].initial)
        size = dataset.scale * (1000.0 if units == "mm" else 1.0)
        world = (poly.vertices @ r.T + t) * size
        for i, j in poly.edges.values():
            seg = world[[i, j]]
            ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color="0.3", lw=1.2)
    ax.set_xlabel(f"x ({units})")
    ax.set_ylabel(f"y ({units})")
    ax.set_zlabel(f"z ({units})")
    # equal scale on the three axes, so that circles look round
    lims = np.array([ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()])
    mid, half = lims.mean(axis=1), (lims[:, 1] - lims[:, 0]).max() / 2
    ax.set_xlim3d(mid[0] - half, mid[0] + half)
    ax.set_ylim3d(mid[1] - half, mid[1] + half)
    ax.set_zlim3d(max(mid[2] - half, lims[2, 0]), max(mid[2] - half, lims[2, 0]) + 2 * half)
    ax.legend(loc="upper left", fontsize="small")
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

    fig = new_figure(figsize=figsize, layout="constrained")
    ax = fig.add_subplot(projection="3d")
    plot_trajectories(ax, dataset, skills, marker=marker, color_by=color_by)
    demos, m = _selection(dataset, skills, marker)
    names = ", ".join(dict.fromkeys(d.skill.name for d in demos))
    ax.set_title(f"{m} trajectories of {names} ({len(demos)} demonstrations)")
    return fig
