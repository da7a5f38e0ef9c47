"""Figures of the graph models: the state-transition graph (paper Fig. 7) and skill graphs
(Fig. 5(b), Fig. 8).

Matplotlib (the ``viz`` extra) is imported only inside these functions, which build
:class:`matplotlib.figure.Figure` objects and never touch pyplot's global state.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import networkx as nx

from nonprehensile.errors import InputError
from nonprehensile.inference import Expansion
from nonprehensile.skills.contacts import format_event
from nonprehensile.states import State
from nonprehensile.viz._figures import new_figure

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "plot_skill_graph",
    "plot_state_graph",
    "plot_transition_matrix",
    "skill_graphs_figure",
    "state_graph_figure",
]

#: Above this many states the drawn graph is unreadable; only the matrix is drawn.
MAX_DRAWN_STATES = 60


def _skill_colors(names: Sequence[str]) -> dict[str, Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return {n: cmap(i % 10) for i, n in enumerate(names)}


def _skill_names(exp: Expansion) -> list[str]:
    names: list[str] = []
    for t in exp.transitions:
        if t.skill.name not in names:
            names.append(t.skill.name)
    return names


def _grid_positions(states: Sequence[State]) -> dict[State, tuple[float, float]]:
    """States on a grid: one row per face, columns by orientation."""
    faces: list[str] = []
    for s in states:
        if s.face not in faces:
            faces.append(s.face)
    pos = {}
    for s in states:
        row = [t for t in states if t.face == s.face]
        pos[s] = (float(row.index(s)), -float(faces.index(s.face)))
    return pos


def plot_state_graph(
    exp: Expansion, ax: Axes | None = None, *, skills: Sequence[str] | None = None
) -> Axes:
    """The expanded state-transition graph: demonstrated arcs bold, inferred arcs thin.

    Parameters
    ----------
    exp : Expansion
        From :func:`nonprehensile.inference.expand`.
    ax : Axes, optional
    skills : sequence of str, optional
        Draw only these skills' arcs (default all).

    Returns
    -------
    Axes
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import FancyArrowPatch

    if ax is None:
        ax = new_figure(figsize=(8, 6)).add_subplot()
    states = list(exp.graph.states)
    if len(states) > MAX_DRAWN_STATES:
        raise InputError(
            f"{len(states)} states are too many to draw as a graph (at most "
            f"{MAX_DRAWN_STATES}); draw the transition matrix instead"
        )
    pos = _grid_positions(states)
    names = _skill_names(exp)
    colors = _skill_colors(names)
    wanted = set(skills) if skills is not None else set(names)
    for t in exp.transitions:
        if t.skill.name not in wanted or t.start not in pos or t.end not in pos:
            continue
        rad = 0.15 + 0.08 * names.index(t.skill.name)
        ax.add_patch(FancyArrowPatch(
            pos[t.start], pos[t.end], connectionstyle=f"arc3,rad={rad}",
            arrowstyle="-|>", mutation_scale=9, shrinkA=9, shrinkB=9,
            color=colors[t.skill.name], lw=2.4 if t.demonstrated else 0.6,
            alpha=1.0 if t.demonstrated else 0.55, zorder=3 if t.demonstrated else 2,
        ))
    for s, (x, y) in pos.items():
        ax.text(x, y, str(s), ha="center", va="center", fontsize=7, zorder=4,
                bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": "0.3", "lw": 0.6})
    xs = [p[0] for p in pos.values()]
    ys = [p[1] for p in pos.values()]
    ax.set_xlim(min(xs) - 0.8, max(xs) + 0.8)
    ax.set_ylim(min(ys) - 0.8, max(ys) + 0.8)
    ax.set_axis_off()
    handles = [Line2D([], [], color=colors[n], lw=1.5, label=n) for n in names if n in wanted]
    handles += [Line2D([], [], color="0.2", lw=2.4, label="demonstrated"),
                Line2D([], [], color="0.2", lw=0.6, label="inferred")]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7,
              frameon=False)
    ax.set_title("State-transition graph: rows are faces, columns orientations", fontsize=9)
    return ax


def plot_transition_matrix(exp: Expansion, ax: Axes | None = None) -> Axes:
    """The adjacency matrix of the expanded graph (paper Fig. 7(b)), cells coloured by skill.

    Demonstrated transitions are outlined in black.
    """
    import numpy as np
    from matplotlib.patches import Patch, Rectangle

    if ax is None:
        ax = new_figure(figsize=(7, 7)).add_subplot()
    states = exp.graph.states
    idx = {s: i for i, s in enumerate(states)}
    names = _skill_names(exp)
    colors = _skill_colors(names)
    n = len(states)
    ax.imshow(np.ones((n, n, 3)), extent=(-0.5, n - 0.5, n - 0.5, -0.5))
    cells: dict[tuple[int, int], list[Any]] = {}
    for t in exp.transitions:
        if t.start in idx and t.end in idx:
            cells.setdefault((idx[t.start], idx[t.end]), []).append(t)
    for (i, j), ts in cells.items():
        # several skills realising one transition share the cell as vertical stripes
        w = 1.0 / len(ts)
        for k, t in enumerate(ts):
            ax.add_patch(Rectangle((j - 0.5 + k * w, i - 0.5), w, 1, fc=colors[t.skill.name],
                                   ec="none"))
        if any(t.demonstrated for t in ts):
            ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fc="none", ec="black", lw=1.2))
    if n <= MAX_DRAWN_STATES:
        labels = [str(s) for s in states]
        ax.set_xticks(range(n), labels, rotation=90, fontsize=6)
        ax.set_yticks(range(n), labels, fontsize=6)
    ax.set_xlabel("to state")
    ax.set_ylabel("from state")
    ax.grid(False)
    ax.legend(handles=[Patch(color=colors[k], label=k) for k in names], fontsize=6,
              loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    ax.set_title("Transition matrix (outlined: demonstrated)", fontsize=9)
    return ax


def state_graph_figure(exp: Expansion, *, skills: Sequence[str] | None = None) -> Figure:
    """The state graph beside its transition matrix (the paper's Fig. 7)."""
    fig = new_figure(figsize=(15, 6.5), layout="constrained")
    if len(exp.graph.states) <= MAX_DRAWN_STATES:
        a, b = fig.subplots(1, 2, width_ratios=[1.25, 1])
        plot_state_graph(exp, a, skills=skills)
        plot_transition_matrix(exp, b)
    else:
        plot_transition_matrix(exp, fig.add_subplot())
    return fig


def plot_skill_graph(graph: nx.MultiDiGraph, ax: Axes | None = None) -> Axes:
    """A skill graph (paper Fig. 5(b)): contact events as nodes, motions as arcs.

    Parameters
    ----------
    graph : networkx.MultiDiGraph
        From :func:`nonprehensile.skills.skill.skill_graph`.
    ax : Axes, optional

    Returns
    -------
    Axes
    """
    from matplotlib.patches import FancyArrowPatch

    if ax is None:
        ax = new_figure(figsize=(11, 4.5)).add_subplot()
    # columns by longest path from the start, rows spread the branches of each column
    layers: dict[Any, int] = {}
    for node in nx.topological_sort(graph):
        preds = list(graph.predecessors(node))
        layers[node] = 1 + max((layers[p] for p in preds), default=-1)
    columns: dict[int, list[Any]] = {}
    for node, layer in layers.items():
        columns.setdefault(layer, []).append(node)
    pos = {}
    for layer, nodes in columns.items():
        for i, node in enumerate(nodes):
            pos[node] = (2.2 * layer, (len(nodes) - 1) / 2 - i)
    skills = sorted({d["skill"] for _, _, d in graph.edges(data=True)})
    colors = _skill_colors(skills)
    seen: dict[tuple[Any, Any], int] = {}
    for a, b, d in graph.edges(data=True):
        k = seen.get((a, b), 0)
        seen[(a, b)] = k + 1
        rad = (-1) ** k * 0.25 * ((k + 1) // 2)
        (x0, y0), (x1, y1) = pos[a], pos[b]
        ax.add_patch(FancyArrowPatch(
            (x0, y0), (x1, y1), connectionstyle=f"arc3,rad={rad}", arrowstyle="-|>",
            mutation_scale=10, shrinkA=32, shrinkB=32, color=colors[d["skill"]], lw=1.3,
        ))
        label = d["motion"].label or d["skill"]
        # matplotlib's arc3 is a quadratic Bezier whose control point sits rad x (dy, -dx)
        # from the chord's midpoint; the curve's own midpoint is half way there
        dx, dy = x1 - x0, y1 - y0
        mx, my = (x0 + x1) / 2 + rad * dy / 2, (y0 + y1) / 2 - rad * dx / 2
        ax.text(mx, my, label, fontsize=6.5, ha="center", va="center", zorder=3,
                color=colors[d["skill"]],
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85})
    for node, (x, y) in pos.items():
        event = graph.nodes[node]["event"]
        text = format_event(event, "paper").replace(" ∧ ", " ∧\n")
        ids = "/".join(sorted(graph.nodes[node]["ids"]))
        ax.text(x, y, f"{ids}\n{text}", ha="center", va="center", fontsize=7, zorder=4,
                bbox={"boxstyle": "round,pad=0.35", "fc": "#f4f4f4", "ec": "0.3", "lw": 0.7})
    xs = [p[0] for p in pos.values()]
    ys = [p[1] for p in pos.values()]
    ax.set_xlim(min(xs) - 1.2, max(xs) + 1.2)
    ax.set_ylim(min(ys) - 0.8, max(ys) + 0.8)
    ax.set_axis_off()
    from matplotlib.lines import Line2D

    ax.legend(handles=[Line2D([], [], color=colors[k], lw=1.5, label=k) for k in skills],
              loc="lower center", ncols=len(skills), fontsize=7, frameon=False,
              bbox_to_anchor=(0.5, -0.02))
    title = graph.graph.get("initial"), graph.graph.get("final"), graph.graph.get("maneuver")
    ax.set_title(f"Skill graph of {title[0]} -> {title[1]} ({title[2]}): "
                 f"skills {', '.join(skills)}", fontsize=9)
    return ax


def skill_graphs_figure(graphs: Sequence[nx.MultiDiGraph]) -> Figure:
    """Several skill graphs stacked, one per maneuver."""
    fig = new_figure(figsize=(12, 3.6 * len(graphs)), layout="constrained")
    axes = fig.subplots(len(graphs), 1, squeeze=False)[:, 0]
    for g, ax in zip(graphs, axes, strict=True):
        plot_skill_graph(g, ax)
    return fig
