"""Figures of the graph models: the state-transition graph (paper Fig. 7) and skill graphs
(Fig. 5(b), Fig. 8).

Matplotlib (the ``viz`` extra) is imported only inside these functions, which build
:class:`matplotlib.figure.Figure` objects and never touch pyplot's global state.
"""

from __future__ import annotations

import itertools
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


def skill_components(exp: Expansion, skill: str) -> list[tuple[list[State], bool]]:
    """The arcs of one skill in the expanded graph, as chains: ``(states, closed)`` pairs.

    A skill is one world-fixed maneuver applied wherever it applies, so it takes each state
    to at most one state and comes from at most one: its arcs fall apart into cycles
    (``closed``: the last state leads back to the first; rolling a cube around one of its
    belts is a cycle of four) and open chains (ending where the maneuver leaves the state
    set). Chains come in the order of their first state in the graph; a cycle starts at its
    first state in that order.

    Raises
    ------
    InputError
        The skill has no arc, or its arcs are not chains (a state left twice by the skill:
        not the output of :func:`~nonprehensile.inference.expand`).
    """
    order = {s: i for i, s in enumerate(exp.graph.states)}
    nxt: dict[State, State] = {}
    prev: dict[State, State] = {}
    for t in exp.transitions:
        if t.skill.name != skill:
            continue
        if t.start in nxt or t.end in prev:
            raise InputError(f"skill {skill!r} leaves or enters a state twice ({t.start} -> "
                             f"{t.end}): its arcs are not one maneuver's")
        nxt[t.start] = t.end
        prev[t.end] = t.start
    if not nxt:
        raise InputError(f"skill {skill!r} has no arc in the graph; its skills are "
                         f"{', '.join(_skill_names(exp))}")

    def rank(s: State) -> int:
        return order.get(s, len(order))

    seen: set[State] = set()
    chains: list[tuple[list[State], bool]] = []
    # open chains first from their heads (states the skill does not enter), then cycles
    for head in sorted((s for s in nxt if s not in prev), key=rank):
        chain = [head]
        while chain[-1] in nxt:
            chain.append(nxt[chain[-1]])
        seen.update(chain)
        chains.append((chain, False))
    for s in sorted(nxt, key=rank):
        if s in seen:
            continue
        cycle = [s]
        while nxt[cycle[-1]] != s:
            cycle.append(nxt[cycle[-1]])
        seen.update(cycle)
        chains.append((cycle, True))
    chains.sort(key=lambda c: min(rank(s) for s in c[0]))
    return chains


#: Per-skill panels, in inches (data units are inches there): the gap between neighbouring
#: states along a chain, and the room a state's label needs around its node.
_SPACING = 0.62
_LABEL_W, _LABEL_H = 0.55, 0.36
_CELL_GAP = 0.15


def _chain_layout(chains: Sequence[tuple[list[State], bool]], max_width: float
                  ) -> tuple[dict[State, tuple[float, float]], float, float]:
    """Each chain on its own ellipse (wider than tall: labels are), packed row by row in at
    most ``max_width`` inches; returns the positions and the packed width and height."""
    import math

    cells = []
    for states, _ in chains:
        k = len(states)
        rx = max({3: 0.48, 4: 0.8}.get(k, 0.55), 1.3 * k * _SPACING / (2 * math.pi))
        ry = (0.6 if k == 4 else 0.62) * rx
        # a chain of four sits on the ellipse's corners, three on its top and lower corners
        phase = math.pi / 4 if k == 4 else math.pi / 2
        pts = [(rx * math.cos(phase + 2 * math.pi * i / k),
                ry * math.sin(phase + 2 * math.pi * i / k)) for i in range(k)]
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        w = max(xs) - min(xs) + _LABEL_W + _CELL_GAP
        h = max(ys) - min(ys) + _LABEL_H + 0.12
        cells.append((states, pts, min(xs), max(ys), w, h))
    pos: dict[State, tuple[float, float]] = {}
    x = y = row_h = width = 0.0
    for states, pts, x0, y1, w, h in cells:
        if x > 0 and x + w > max_width + 1e-9:
            x, y, row_h = 0.0, y - row_h, 0.0
        for s, (px, py) in zip(states, pts, strict=True):
            pos[s] = (x + (_LABEL_W + _CELL_GAP) / 2 + px - x0,
                      y - (_LABEL_H + 0.12) / 2 - (y1 - py))
        x += w
        width = max(width, x)
        row_h = max(row_h, h)
    return pos, width, -(y - row_h)


def plot_skill_arcs(exp: Expansion, skill: str, ax: Axes, *, color: Any = None,
                    max_width: float = 4.6) -> tuple[float, float]:
    """One skill's arcs of the expanded graph (a small multiple of :func:`transitions_figure`).

    Each chain of the skill (:func:`skill_components`) is drawn on its own ellipse: a state
    per node, the skill's arc from each state to the next; the demonstrated arc bold black,
    states outside the state set in dashed boxes. The axes' limits are set to the drawing
    (data units are inches at ``max_width`` inches a row); returns its width and height.
    """
    chains = skill_components(exp, skill)
    pos, width, height = _chain_layout(chains, max_width)
    # states the graph only reaches (outside the state set): no transition starts there
    inside = {t.start for t in exp.transitions}
    demonstrated = {(t.start, t.end) for t in exp.transitions
                    if t.skill.name == skill and t.demonstrated}
    color = color if color is not None else "0.2"
    # equal scales: the axes' own aspect, its limits centred on the drawing
    _, _, w, h = ax.get_position().bounds
    fig: Any = ax.get_figure(root=True)
    fw, fh = fig.get_size_inches()
    aw, ah = w * fw, h * fh
    scale = max(width / aw, height / ah, 1.0)
    cx, cy = width / 2, -height / 2
    ax.set_xlim(cx - scale * aw / 2, cx + scale * aw / 2)
    ax.set_ylim(cy - scale * ah / 2, cy + scale * ah / 2)
    arcs = []
    for states, closed in chains:
        pairs = list(itertools.pairwise(states))
        if closed:
            pairs.append((states[-1], states[0]))
        for a, b in pairs:
            shown = (a, b) in demonstrated
            rad = 0.45 if len(states) == 2 else 0.18
            arcs.append((pos[a], pos[b], rad, "black" if shown else color,
                         2.8 if shown else 1.3, 1.0))
    draw_arcs(ax, arcs, shrink=15, head=4.5)
    for s, (x, y) in pos.items():
        ax.text(x, y, str(s), ha="center", va="center", fontsize=9.5, zorder=4,
                bbox={"boxstyle": "round,pad=0.2", "fc": "white",
                      "ec": "0.3", "lw": 0.6, "ls": "-" if s in inside else "--"})
    ax.set_axis_off()
    return width, height


def transitions_figure(exp: Expansion, *, skills: Sequence[str] | None = None,
                       per_row: int = 3, page_width: float = 14.2) -> Figure:
    """The expanded state-transition graph as small multiples: one panel per skill.

    Drawn at once, a graph of every skill's arcs is a hairball (168 arcs on the cube's 24
    states); split by skill, each panel shows one maneuver applied wherever it applies:
    its arcs form cycles and chains (:func:`skill_components`), each on its own ellipse,
    the demonstrated arc bold black. A fixed layout (no layout engine: issue 16).

    Parameters
    ----------
    exp : Expansion
    skills : sequence of str, optional
        The skills to draw, in order (default every skill of the graph).
    per_row : int
        Panels on a row.
    page_width : float
        Width of the figure, inches.
    """
    import math

    names = _skill_names(exp)
    wanted = list(skills) if skills is not None else names
    for s in wanted:
        if s not in names:
            raise InputError(f"no skill {s!r} in the graph; its skills are {', '.join(names)}")
    colors = _skill_colors(names)
    maneuver = {t.skill.name: t.skill.maneuver for t in exp.transitions}
    cols = max(1, min(per_row, len(wanted)))
    rows = max(1, math.ceil(len(wanted) / cols))
    panel_w = page_width / cols
    chains = {s: skill_components(exp, s) for s in wanted}
    # each row of panels as tall as its tallest drawing (one scale for all)
    tall = [_chain_layout(chains[s], panel_w - 0.1)[2] + 0.1 for s in wanted]
    heights = [max(tall[r * cols:(r + 1) * cols]) for r in range(rows)]
    head = 0.45
    fw, fh = panel_w * cols, sum(heights) + head * rows
    fig = new_figure(figsize=(fw, fh))
    for n, skill in enumerate(wanted):
        r, c = divmod(n, cols)
        top = 1 - (sum(heights[:r]) + head * r) / fh
        panel_h = heights[r]
        ax = fig.add_axes((c * panel_w / fw, top - (head + panel_h) / fh, panel_w / fw,
                           panel_h / fh))
        plot_skill_arcs(exp, skill, ax, color=colors[skill], max_width=panel_w - 0.1)
        cycles = [st for st, closed in chains[skill] if closed]
        opened = [st for st, closed in chains[skill] if not closed]
        kinds = []
        if cycles:
            kinds.append(f"{len(cycles)} cycle{'s' if len(cycles) > 1 else ''}")
        if opened:
            kinds.append(f"{len(opened)} chain{'s' if len(opened) > 1 else ''}")
        size = "/".join(str(k) for k in sorted({len(st) for st, _ in chains[skill]}))
        fig.text((c + 0.5) * panel_w / fw, top - 0.06 / fh,
                 f"{skill} ({maneuver.get(skill, '?')}): {' + '.join(kinds)} of {size} states",
                 ha="center", va="top", fontsize=10, color=colors[skill], fontweight="bold")
    return fig


def transitions_svg(exp: Expansion, *, skills: Sequence[str] | None = None,
                    per_row: int = 3, page_px: float = 1150.0) -> str:
    """:func:`transitions_figure` as inline SVG markup, for the report.

    The same panels and layout, drawn by the browser: the cube's 168 labeled states cost
    matplotlib about 0.2 s to draw; as SVG they cost the report nothing (issue 16). Each arc
    is a ``path`` whose ``title`` names its transition; each panel is a ``g`` with
    ``data-skill``. Every text is escaped.
    """
    import html
    import math

    from matplotlib.colors import to_hex

    names = _skill_names(exp)
    wanted = list(skills) if skills is not None else names
    for s in wanted:
        if s not in names:
            raise InputError(f"no skill {s!r} in the graph; its skills are {', '.join(names)}")
    colors = {k: to_hex(c) for k, c in _skill_colors(names).items()}
    maneuver = {t.skill.name: t.skill.maneuver for t in exp.transitions}
    # states the graph only reaches (outside the state set): no transition starts there
    inside = {t.start for t in exp.transitions}
    cols = max(1, min(per_row, len(wanted)))
    ppi = 80.0  # px per layout inch: the report's figures' dpi
    panel_w = page_px / cols
    head = 30.0
    layouts = {s: _chain_layout(skill_components(exp, s), panel_w / ppi - 0.1)
               for s in wanted}
    rows = math.ceil(len(wanted) / cols)
    heights = [max(layouts[s][2] for s in wanted[r * cols:(r + 1) * cols]) * ppi + 8
               for r in range(rows)]
    hw, hh = _LABEL_W * ppi / 2 - 2, 10.0  # half the drawn box of a label

    def cut(p: tuple[float, float], toward: tuple[float, float]) -> tuple[float, float]:
        """Where the curve leaving ``p`` towards ``toward`` crosses p's box (plus a gap)."""
        ux, uy = toward[0] - p[0], toward[1] - p[1]
        n = math.hypot(ux, uy) or 1.0
        ux, uy = ux / n, uy / n
        s = min(hw / abs(ux) if abs(ux) > 1e-9 else math.inf,
                hh / abs(uy) if abs(uy) > 1e-9 else math.inf) + 3.0
        return p[0] + s * ux, p[1] + s * uy

    parts = []
    markers = "".join(
        f'<marker id="nph-head-{i}" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="7" '
        f'markerHeight="7" markerUnits="userSpaceOnUse" orient="auto-start-reverse">'
        f'<path d="M0,0 L10,5 L0,10 z" fill="{c}"/></marker>'
        for i, c in enumerate([*(colors[s] for s in wanted), "#000000"]))
    parts.append(f"<defs>{markers}</defs>")
    for n, skill in enumerate(wanted):
        r, c = divmod(n, cols)
        x0 = c * panel_w
        y0 = sum(heights[:r]) + head * (r + 1)
        pos, width, _ = layouts[skill]
        dx = x0 + (panel_w - width * ppi) / 2
        chains = skill_components(exp, skill)
        demonstrated = {(t.start, t.end) for t in exp.transitions
                        if t.skill.name == skill and t.demonstrated}
        px = {s: (dx + x * ppi, y0 - y * ppi) for s, (x, y) in pos.items()}
        cycles = sum(closed for _, closed in chains)
        opened = len(chains) - cycles
        kinds = " + ".join(k for k in (
            f"{cycles} cycle{'s' if cycles != 1 else ''}" if cycles else "",
            f"{opened} chain{'s' if opened != 1 else ''}" if opened else "") if k)
        size = "/".join(str(k) for k in sorted({len(st) for st, _ in chains}))
        heading = f"{skill} ({maneuver.get(skill, '?')}): {kinds} of {size} states"
        g = [f'<g data-skill="{html.escape(skill, quote=True)}">',
             f'<text x="{x0 + panel_w / 2:.1f}" y="{y0 - 12:.1f}" text-anchor="middle" '
             f'font-weight="bold" font-size="13" fill="{colors[skill]}">'
             f"{html.escape(heading)}</text>"]
        for states, closed in chains:
            # a light card behind each chain sets it apart from its neighbours
            xs = [px[s][0] for s in states]
            ys = [px[s][1] for s in states]
            g.append(f'<rect x="{min(xs) - hw - 4:.1f}" y="{min(ys) - hh - 4:.1f}" '
                     f'width="{max(xs) - min(xs) + 2 * hw + 8:.1f}" '
                     f'height="{max(ys) - min(ys) + 2 * hh + 8:.1f}" rx="8" fill="#f5f5f5"/>')
            pairs = list(itertools.pairwise(states))
            if closed:
                pairs.append((states[-1], states[0]))
            rad = 0.45 if len(states) == 2 else 0.18
            for a, b in pairs:
                (ax_, ay), (bx, by) = px[a], px[b]
                # matplotlib's arc3 in screen coordinates (y down): the control point turned
                # the other way, so the curves bulge outwards as in the PNG
                cx = (ax_ + bx) / 2 - rad * (by - ay)
                cy = (ay + by) / 2 + rad * (bx - ax_)
                s0, s1 = cut((ax_, ay), (cx, cy)), cut((bx, by), (cx, cy))
                shown = (a, b) in demonstrated
                colour = "#000000" if shown else colors[skill]
                head_id = len(wanted) if shown else n
                title = html.escape(f"{a} -> {b} by {skill}"
                                    + (" (demonstrated)" if shown else " (inferred)"))
                g.append(f'<path d="M{s0[0]:.1f},{s0[1]:.1f} Q{cx:.1f},{cy:.1f} '
                         f'{s1[0]:.1f},{s1[1]:.1f}" fill="none" stroke="{colour}" '
                         f'stroke-width="{3 if shown else 1.4}" '
                         f'marker-end="url(#nph-head-{head_id})"><title>{title}</title></path>')
        for node, (x, y) in px.items():
            dash = "" if node in inside else ' stroke-dasharray="3,2"'
            g.append(f'<rect x="{x - hw:.1f}" y="{y - hh:.1f}" width="{2 * hw:.1f}" '
                     f'height="{2 * hh:.1f}" rx="4" fill="white" stroke="#555"{dash}/>'
                     f'<text x="{x:.1f}" y="{y + 4.5:.1f}" text-anchor="middle" '
                     f'font-size="13">{html.escape(str(node))}</text>')
        g.append("</g>")
        parts.append("".join(g))
    total_h = sum(heights) + head * rows
    return (f'<svg class="transitions" xmlns="http://www.w3.org/2000/svg" '
            f'width="{page_px:.0f}" height="{total_h:.0f}" '
            f'viewBox="0 0 {page_px:.0f} {total_h:.0f}" font-family="sans-serif">'
            + "".join(parts) + "</svg>")
