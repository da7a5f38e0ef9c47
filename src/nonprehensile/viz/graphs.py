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
    "transition_matrix_html",
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


def draw_arcs(
    ax: Axes,
    arcs: Sequence[tuple[tuple[float, float], tuple[float, float], float, Any, float, float]],
    *,
    shrink: float,
    head: float,
    zorder: float = 2,
) -> None:
    """Curved arrows drawn as two collections: one of bodies, one of heads.

    Each arc is ``(start, end, rad, color, linewidth, alpha)``: matplotlib's ``arc3``
    connection (a quadratic Bezier whose control point sits ``rad`` times the chord, turned
    clockwise, from its midpoint; computed on screen as matplotlib does), cut ``shrink``
    points from both ends, with a filled head ``head`` points long. A hundred
    ``FancyArrowPatch`` objects cost a second to lay out and draw (issue 16); two
    collections cost milliseconds. The shapes are computed for the axes' limits and position
    as they are at the call: set them first (a fixed layout).
    """
    import numpy as np
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.colors import to_rgba

    if not arcs:
        return
    to_px = ax.figure.dpi / 72.0
    data = ax.transData
    p0 = data.transform(np.array([a[0] for a in arcs], dtype=float))
    p1 = data.transform(np.array([a[1] for a in arcs], dtype=float))
    rad = np.array([a[2] for a in arcs], dtype=float)[:, None]
    chord = p1 - p0
    ctrl = (p0 + p1) / 2 + rad * np.stack([chord[:, 1], -chord[:, 0]], axis=1)
    t = np.linspace(0.0, 1.0, 64)[None, :, None]
    curve = ((1 - t) ** 2 * p0[:, None] + 2 * (1 - t) * t * ctrl[:, None]
             + t**2 * p1[:, None])  # (arcs, 64, 2) in pixels
    cut = shrink * to_px
    to_data = data.inverted()  # made once: each inverted() builds a new transform
    bodies, heads = [], []
    colors, widths = [], []  # appended with their arc's body: a skipped arc shifts none
    for i, arc in enumerate(arcs):
        c = curve[i]
        d0, d1 = np.hypot(*(c - p0[i]).T), np.hypot(*(c - p1[i]).T)
        keep = np.flatnonzero((d0 >= cut) & (d1 >= cut))
        if len(keep) < 2:
            continue
        a, b = int(keep[0]), int(keep[-1])
        # the ends exactly ``cut`` from the nodes (between the samples either side)
        ends = []
        if a > 0:
            f = (cut - d0[a - 1]) / max(float(d0[a] - d0[a - 1]), 1e-12)
            ends.append(c[a - 1] + f * (c[a] - c[a - 1]))
        ends.append(c[a:b + 1])
        if b < len(c) - 1:
            f = (d1[b] - cut) / max(float(d1[b] - d1[b + 1]), 1e-12)
            ends.append(c[b] + f * (c[b + 1] - c[b]))
        c = np.vstack(ends)
        tip = c[-1]
        u = tip - c[-2]
        u /= max(float(np.hypot(*u)), 1e-12)
        length = (head + arc[4]) * to_px
        base = tip - length * u
        normal = np.array([-u[1], u[0]]) * 0.45 * length
        body = np.vstack([c[np.hypot(*(c - tip).T) > length], base])
        bodies.append(to_data.transform(body))
        heads.append(to_data.transform(np.array([tip, base + normal, base - normal])))
        colors.append(to_rgba(arc[3], arc[5]))
        widths.append(arc[4])
    ax.add_collection(LineCollection(bodies, colors=colors, linewidths=widths,
                                     capstyle="butt", zorder=zorder), autolim=False)
    ax.add_collection(PolyCollection(heads, facecolors=colors, edgecolors="none",
                                     zorder=zorder), autolim=False)


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

    if ax is None:
        ax = new_figure(figsize=(8, 6)).add_axes((0.02, 0.02, 0.78, 0.9))
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
    xs = [p[0] for p in pos.values()]
    ys = [p[1] for p in pos.values()]
    ax.set_xlim(min(xs) - 0.8, max(xs) + 0.8)
    ax.set_ylim(min(ys) - 0.8, max(ys) + 0.8)
    for demonstrated in (False, True):
        draw_arcs(ax, [(pos[t.start], pos[t.end], 0.15 + 0.08 * names.index(t.skill.name),
                        colors[t.skill.name], 2.4 if demonstrated else 0.6,
                        1.0 if demonstrated else 0.55)
                       for t in exp.transitions
                       if t.demonstrated == demonstrated and t.skill.name in wanted
                       and t.start in pos and t.end in pos],
                  shrink=9, head=3.6, zorder=3 if demonstrated else 2)
    for s, (x, y) in pos.items():
        ax.text(x, y, str(s), ha="center", va="center", fontsize=7, zorder=4,
                bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": "0.3", "lw": 0.6})
    ax.set_axis_off()
    handles = [Line2D([], [], color=colors[n], lw=1.5, label=n) for n in names if n in wanted]
    handles += [Line2D([], [], color="0.2", lw=2.4, label="demonstrated"),
                Line2D([], [], color="0.2", lw=0.6, label="inferred")]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7,
              frameon=False)
    # y given: the title sits on the axes (nothing is above it), and matplotlib skips its
    # search for tick labels above the axes (their extents: milliseconds a title, issue 16)
    ax.set_title("State-transition graph: rows are faces, columns orientations", fontsize=9,
                 y=1.0)
    return ax


def plot_transition_matrix(exp: Expansion, ax: Axes | None = None, *,
                           legend: bool = True) -> Axes:
    """The adjacency matrix of the expanded graph (paper Fig. 7(b)), cells coloured by skill.

    Demonstrated transitions are outlined in black. ``legend=False`` leaves out the legend
    of the skills' colours (when another panel of the figure already has it).
    """
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Patch

    if ax is None:
        ax = new_figure(figsize=(7, 7)).add_axes((0.15, 0.12, 0.6, 0.8))
    states = exp.graph.states
    idx = {s: i for i, s in enumerate(states)}
    names = _skill_names(exp)
    colors = _skill_colors(names)
    n = len(states)
    # the matrix's frame: square cells, row 0 at the top (what imshow would set, without
    # drawing an image)
    ax.set_xlim(-0.5, n - 0.5)
    ax.set_ylim(n - 0.5, -0.5)
    ax.set_aspect("equal")
    cells: dict[tuple[int, int], list[Any]] = {}
    for t in exp.transitions:
        if t.start in idx and t.end in idx:
            cells.setdefault((idx[t.start], idx[t.end]), []).append(t)

    def box(x: float, y: float, w: float) -> list[tuple[float, float]]:
        return [(x, y), (x + w, y), (x + w, y + 1), (x, y + 1)]

    stripes, fills, outlined = [], [], []
    for (i, j), ts in cells.items():
        # several skills realising one transition share the cell as vertical stripes
        w = 1.0 / len(ts)
        for k, t in enumerate(ts):
            stripes.append(box(j - 0.5 + k * w, i - 0.5, w))
            fills.append(colors[t.skill.name])
        if any(t.demonstrated for t in ts):
            outlined.append(box(j - 0.5, i - 0.5, 1.0))
    # two collections, not a patch per cell: hundreds of patches cost a second (issue 16)
    ax.add_collection(PolyCollection(stripes, facecolors=fills, edgecolors="none"),
                      autolim=False)
    ax.add_collection(PolyCollection(outlined, facecolors="none", edgecolors="black",
                                     linewidths=1.2), autolim=False)
    if n <= MAX_DRAWN_STATES:
        labels = [str(s) for s in states]
        ax.set_xticks(range(n), labels, rotation=90, fontsize=6)
        ax.set_yticks(range(n), labels, fontsize=6)
    ax.set_xlabel("to state")
    ax.set_ylabel("from state")
    ax.grid(False)
    if legend:
        ax.legend(handles=[Patch(color=colors[k], label=k) for k in names], fontsize=6,
                  loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    ax.set_title("Transition matrix (outlined: demonstrated)", fontsize=9, y=1.0)  # as above
    return ax


def state_graph_figure(exp: Expansion, *, skills: Sequence[str] | None = None,
                       matrix: bool = True) -> Figure:
    """The state graph beside its transition matrix (the paper's Fig. 7).

    A fixed layout (each axes placed by hand, room left for the legends and the matrix's
    labels): a layout engine would cost a second full draw (issue 16). The graph's legend,
    between the two panels, gives the skills' colours for both; the matrix has its own only
    when the graph leaves out some skills. ``matrix=False`` draws the graph alone (the report
    shows the matrix as an HTML table, :func:`transition_matrix_html`); above
    :data:`MAX_DRAWN_STATES` states the matrix is drawn alone whatever ``matrix`` says.
    """
    if not matrix and len(exp.graph.states) <= MAX_DRAWN_STATES:
        fig = new_figure(figsize=(8.2, 6.5))
        plot_state_graph(exp, fig.add_axes((0.01, 0.02, 0.75, 0.92)), skills=skills)
        return fig
    fig = new_figure(figsize=(15, 6.5))
    if len(exp.graph.states) <= MAX_DRAWN_STATES:
        plot_state_graph(exp, fig.add_axes((0.005, 0.02, 0.41, 0.92)), skills=skills)
        every = skills is None or set(_skill_names(exp)) <= set(skills)
        plot_transition_matrix(exp, fig.add_axes((0.555, 0.12, 0.345, 0.82)),
                               legend=not every)
    else:
        plot_transition_matrix(exp, fig.add_axes((0.3, 0.1, 0.5, 0.84)))
    return fig


def transition_matrix_html(exp: Expansion) -> str:
    """The transition matrix (paper Fig. 7(b)) as an HTML table, for the report.

    One row per start state, one column per end state, in the graph's order; a cell holds one
    vertical stripe per skill realising that transition, in the skill's colour (the state
    graph's), and a demonstrated transition's cell is outlined (class ``shown``). Each
    coloured cell's ``title`` names its transition and skills. A legend of the colours
    follows. Drawn by matplotlib, the same matrix costs about 0.09 s for its 48 tick labels
    and cells; as a table the browser lays it out (issue 16). Meant for sets up to
    :data:`MAX_DRAWN_STATES` states (the size of the table grows with their square).
    """
    import html

    from matplotlib.colors import to_hex

    states = exp.graph.states
    idx = {s: i for i, s in enumerate(states)}
    names = _skill_names(exp)
    colors = {k: to_hex(c) for k, c in _skill_colors(names).items()}
    cells: dict[tuple[int, int], list[Any]] = {}
    for t in exp.transitions:
        if t.start in idx and t.end in idx:
            cells.setdefault((idx[t.start], idx[t.end]), []).append(t)
    names_of = [str(s) for s in states]
    labels = [html.escape(n) for n in names_of]
    head = "".join(f"<th><span>{lab}</span></th>" for lab in labels)
    rows = []
    for i, lab in enumerate(labels):
        tds = []
        for j in range(len(states)):
            ts = cells.get((i, j))
            if not ts:
                tds.append("<td></td>")
                continue
            w = 100.0 / len(ts)
            stops = ",".join(f"{colors[t.skill.name]} {k * w:.4g}% {(k + 1) * w:.4g}%"
                             for k, t in enumerate(ts))
            shown = ' class="shown"' if any(t.demonstrated for t in ts) else ""
            title = html.escape(f"{names_of[i]} -> {names_of[j]}: "
                                + ", ".join(t.skill.name for t in ts), quote=True)
            tds.append(f'<td{shown} title="{title}" '
                       f'style="background:linear-gradient(to right,{stops})"></td>')
        rows.append(f"<tr><th>{lab}</th>{''.join(tds)}</tr>")
    legend = "".join(f'<span><i style="background:{colors[k]}"></i>{html.escape(k)}</span>'
                     for k in names)
    return (f'<table class="matrix"><thead><tr><th>from \\ to</th>{head}</tr></thead>'
            f"<tbody>{''.join(rows)}</tbody></table>"
            f'<p class="legend">{legend}<span><i class="shown"></i>demonstrated</span></p>')


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
    if ax is None:
        ax = new_figure(figsize=(11, 4.5)).add_axes((0.01, 0.01, 0.98, 0.9))
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
    xs = [p[0] for p in pos.values()]
    ys = [p[1] for p in pos.values()]
    ax.set_xlim(min(xs) - 1.2, max(xs) + 1.2)
    ax.set_ylim(min(ys) - 0.8, max(ys) + 0.8)
    seen: dict[tuple[Any, Any], int] = {}
    arcs = []
    for a, b, d in graph.edges(data=True):
        k = seen.get((a, b), 0)
        seen[(a, b)] = k + 1
        rad = (-1) ** k * 0.25 * ((k + 1) // 2)
        (x0, y0), (x1, y1) = pos[a], pos[b]
        arcs.append(((x0, y0), (x1, y1), rad, colors[d["skill"]], 1.3, 1.0))
        label = d["motion"].label or d["skill"]
        # matplotlib's arc3 is a quadratic Bezier whose control point sits rad x (dy, -dx)
        # from the chord's midpoint; the curve's own midpoint is half way there
        dx, dy = x1 - x0, y1 - y0
        mx, my = (x0 + x1) / 2 + rad * dy / 2, (y0 + y1) / 2 - rad * dx / 2
        ax.text(mx, my, label, fontsize=6.5, ha="center", va="center", zorder=3,
                color=colors[d["skill"]],
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85})
    draw_arcs(ax, arcs, shrink=32, head=4.0)
    for node, (x, y) in pos.items():
        event = graph.nodes[node]["event"]
        text = format_event(event, "paper").replace(" ∧ ", " ∧\n")
        ids = "/".join(sorted(graph.nodes[node]["ids"]))
        ax.text(x, y, f"{ids}\n{text}", ha="center", va="center", fontsize=7, zorder=4,
                bbox={"boxstyle": "round,pad=0.35", "fc": "#f4f4f4", "ec": "0.3", "lw": 0.7})
    ax.set_axis_off()
    from matplotlib.lines import Line2D

    ax.legend(handles=[Line2D([], [], color=colors[k], lw=1.5, label=k) for k in skills],
              loc="lower center", ncols=len(skills), fontsize=7, frameon=False,
              bbox_to_anchor=(0.5, -0.02))
    title = graph.graph.get("initial"), graph.graph.get("final"), graph.graph.get("maneuver")
    ax.set_title(f"Skill graph of {title[0]} -> {title[1]} ({title[2]}): "
                 f"skills {', '.join(skills)}", fontsize=9, y=1.0)  # y: as above
    return ax


def skill_graphs_figure(graphs: Sequence[nx.MultiDiGraph]) -> Figure:
    """Several skill graphs stacked, one per maneuver (a fixed layout: issue 16)."""
    n = len(graphs)
    fig = new_figure(figsize=(12, 3.6 * n))
    for r, g in enumerate(graphs):
        plot_skill_graph(g, fig.add_axes((0.01, (n - 1 - r + 0.02) / n, 0.98, 0.9 / n)))
    return fig
