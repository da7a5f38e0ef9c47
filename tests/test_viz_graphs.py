"""Figures of the state-transition and skill graphs."""

from __future__ import annotations

from pathlib import Path

import pytest

from nonprehensile.inference import expand, infer_exact
from nonprehensile.io import read_skills
from nonprehensile.skills.skill import group_by_maneuver, skill_graph
from nonprehensile.states import State, states_by_step

pytest.importorskip("matplotlib")

from matplotlib.collections import LineCollection
from matplotlib.patches import ConnectionStyle

from nonprehensile.viz._figures import new_figure
from nonprehensile.viz.graphs import (
    draw_arcs,
    plot_skill_graph,
    plot_transition_matrix,
    state_graph_figure,
    transition_matrix_html,
)

EXAMPLES = Path(__file__).parents[1] / "examples"


def test_state_graph_figure(tmp_path: Path) -> None:
    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    exp = expand(poly, skills, states_by_step(poly, 90))
    fig = state_graph_figure(exp)
    graph_ax, matrix_ax = fig.axes[:2]
    # every state is labelled in the graph; every transition is a cell stripe in the matrix
    labels = {t.get_text() for t in graph_ax.texts}
    assert {str(s) for s in exp.graph.states} <= labels
    stripes, outlines = matrix_ax.collections[:2]
    assert len(stripes.get_paths()) == len(exp.transitions)
    assert len(outlines.get_paths()) == len({(t.start, t.end) for t in exp.transitions
                                             if t.demonstrated})
    # every transition is an arc (bodies: one collection per layer, inferred then shown)
    bodies = [c for c in graph_ax.collections if isinstance(c, LineCollection)]
    assert sum(len(c.get_paths()) for c in bodies) == len(exp.transitions)
    assert [len(c.get_paths()) for c in bodies][1] == sum(t.demonstrated for t in exp.transitions)
    path = tmp_path / "g.png"
    fig.savefig(path)
    assert path.stat().st_size > 10_000


def test_skill_graph_figure_shows_events_and_motions() -> None:
    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    g = skill_graph(poly, group_by_maneuver(poly, skills)[0])
    ax = plot_skill_graph(g)
    texts = [t.get_text() for t in ax.texts]
    assert sum("∧" in t or "(G," in t for t in texts) == g.number_of_nodes()
    assert {"quarter-circle", "straight-pull", "push"} <= set(texts)
    (bodies,) = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(bodies.get_paths()) == g.number_of_edges()
    # an adapted skill (Fig. 8) draws with its mapped faces
    (t,) = infer_exact(poly, skills[0], [State("a", 90)])
    ax = plot_skill_graph(skill_graph(poly, [t.skill]))
    assert any("(R1,e)" in x.get_text() for x in ax.texts)


def test_large_state_sets_draw_only_the_matrix() -> None:
    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    exp = expand(poly, skills[:1], states_by_step(poly, 5))
    fig = state_graph_figure(exp)
    assert len(fig.axes) == 1
    plot_transition_matrix(exp)


@pytest.mark.parametrize("rad", [-0.4, 0.0, 0.15, 0.3])
def test_arcs_follow_matplotlibs_arc3(rad: float) -> None:
    """The collection's curve is matplotlib's own arc3 connection (an independent truth): its
    points lie on the Bezier that ConnectionStyle.Arc3 makes, shrunk at both ends."""
    import numpy as np

    ax = new_figure(figsize=(4, 3), dpi=100).add_axes((0.1, 0.1, 0.8, 0.8))
    ax.set_xlim(0, 4)
    ax.set_ylim(-1, 2)
    a, b = (0.5, 0.0), (3.0, 1.5)
    draw_arcs(ax, [(a, b, rad, "C0", 1.0, 1.0)], shrink=9, head=4)
    (body,) = ax.collections[0].get_paths()
    ours = ax.transData.transform(body.vertices)
    ref = ConnectionStyle.Arc3(rad=rad)(ax.transData.transform(a), ax.transData.transform(b),
                                        shrinkA=9 * 100 / 72, shrinkB=9 * 100 / 72)
    curve = np.vstack([seg(np.linspace(0.0, 1.0, 200)) for seg, _ in ref.iter_bezier()])
    # every drawn point is on matplotlib's curve (within a pixel)
    dist = np.min(np.hypot(*(ours[:, None, :] - curve[None, :, :]).transpose(2, 0, 1)), axis=1)
    assert dist.max() < 1.0
    # it starts where matplotlib's shrunk curve starts; the head's tip is where it ends
    assert np.hypot(*(ours[0] - curve[0])) < 2.0
    (head,) = ax.collections[1].get_paths()
    tip = ax.transData.transform(head.vertices[:1])[0]
    assert np.hypot(*(tip - curve[-1])) < 2.0


def test_a_skipped_arc_shifts_no_colour() -> None:
    """An arc too short to draw (its ends within ``shrink`` of each other) is left out with its
    own colour and width: the arcs after it keep theirs."""
    from matplotlib.colors import to_rgba

    ax = new_figure(figsize=(4, 3), dpi=100).add_axes((0.1, 0.1, 0.8, 0.8))
    ax.set_xlim(0, 4)
    ax.set_ylim(-1, 2)
    arcs = [((1.0, 1.0), (1.001, 1.0), 0.2, "red", 3.0, 1.0),
            ((0.5, 0.0), (3.0, 1.5), 0.2, "blue", 1.0, 1.0)]
    draw_arcs(ax, arcs, shrink=9, head=4)
    bodies, heads = ax.collections[0], ax.collections[1]
    assert len(bodies.get_paths()) == 1
    assert tuple(bodies.get_colors()[0]) == to_rgba("blue")
    assert list(bodies.get_linewidths()) == [1.0]
    assert tuple(heads.get_facecolors()[0]) == to_rgba("blue")


def test_one_legend_of_skill_colours_serves_graph_and_matrix() -> None:
    """Beside the graph, whose legend lists every skill's colour, the matrix has none of its
    own (the same colours twice cost a legend's layout: issue 16); when the graph leaves
    skills out, the matrix keeps its own."""
    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    exp = expand(poly, skills, states_by_step(poly, 90))
    names = {s.name for s in skills}
    graph_ax, matrix_ax = state_graph_figure(exp).axes[:2]
    listed = {t.get_text() for t in graph_ax.get_legend().get_texts()}
    assert names <= listed and matrix_ax.get_legend() is None
    graph_ax, matrix_ax = state_graph_figure(exp, skills=[skills[0].name]).axes[:2]
    assert {t.get_text() for t in matrix_ax.get_legend().get_texts()} >= names
    alone = plot_transition_matrix(exp)
    assert alone.get_legend() is not None


def _matrix_cells(markup: str) -> tuple[list[str], list[str], list[list[dict[str, str]]]]:
    """Column headers, row headers and every row's cells (their attributes) of the table."""
    from html.parser import HTMLParser

    class Cells(HTMLParser):
        def __init__(self) -> None:
            super().__init__()
            self.cols: list[str] = []
            self.rows: list[str] = []
            self.cells: list[list[dict[str, str]]] = []
            self.where: list[str] = []
            self.text = ""

        def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
            self.where.append(tag)
            self.text = ""
            if tag == "tr" and "tbody" in self.where:
                self.cells.append([])
            if tag == "td" and "table" in self.where:
                self.cells[-1].append({k: v or "" for k, v in attrs})

        def handle_data(self, data: str) -> None:
            self.text += data

        def handle_endtag(self, tag: str) -> None:
            if tag == "th" and "thead" in self.where:
                self.cols.append(self.text)
            elif tag == "th" and "tbody" in self.where:
                self.rows.append(self.text)
            while self.where and self.where.pop() != tag:
                pass

    parser = Cells()
    parser.feed(markup)
    return parser.cols[1:], parser.rows, parser.cells


def test_transition_matrix_as_html_has_every_transition_in_its_cell() -> None:
    """The report's matrix as a table (issue 16): a row per start state, a column per end
    state, one stripe per transition in its skill's colour, outlined where demonstrated; the
    truth is the expansion's own list of transitions."""
    import re

    from matplotlib.colors import to_hex

    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    exp = expand(poly, skills, states_by_step(poly, 90))
    markup = transition_matrix_html(exp)
    cols, rows, cells = _matrix_cells(markup)
    names = [str(s) for s in exp.graph.states]
    assert cols == names and rows == names
    assert all(len(r) == len(names) for r in cells) and len(cells) == len(names)
    # tab10, the default colour cycle, in the order the skills first appear
    colour = {k: to_hex(f"C{i}") for i, k in enumerate(
        dict.fromkeys(t.skill.name for t in exp.transitions))}
    want: dict[tuple[str, str], list[str]] = {}
    for t in exp.transitions:
        want.setdefault((str(t.start), str(t.end)), []).append(t.skill.name)
    shown = {(str(t.start), str(t.end)) for t in exp.transitions if t.demonstrated}
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            cell = cells[i][j]
            if (a, b) not in want:
                assert "style" not in cell
                continue
            stripes = re.findall(r"(#[0-9a-f]{6}) ([\d.]+)% ([\d.]+)%", cell["style"])
            assert [c for c, _, _ in stripes] == [colour[k] for k in want[(a, b)]]
            assert float(stripes[0][1]) == 0.0 and float(stripes[-1][2]) == 100.0
            assert cell["title"] == f"{a} -> {b}: {', '.join(want[(a, b)])}"
            assert (cell.get("class") == "shown") == ((a, b) in shown)
    # the legend names every skill in its colour
    for k, c in colour.items():
        assert f'<i style="background:{c}"></i>{k}' in markup


def test_state_graph_alone_for_the_report() -> None:
    """``matrix=False``: the graph without the matrix (the report shows it as a table);
    above MAX_DRAWN_STATES only the matrix can be drawn, whatever is asked."""
    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    exp = expand(poly, skills, states_by_step(poly, 90))
    (ax,) = state_graph_figure(exp, matrix=False).axes
    assert {str(s) for s in exp.graph.states} <= {t.get_text() for t in ax.texts}
    assert not ax.axison
    big = expand(poly, skills[:1], states_by_step(poly, 5))
    (alone,) = state_graph_figure(big, matrix=False).axes
    assert len(alone.collections[0].get_paths()) == len(big.transitions)


def test_transition_matrix_html_escapes_names_once() -> None:
    """Face labels and skill names are the user's strings: every one in the table is escaped
    once (the headers and a cell's title, read back, are the plain text)."""
    import dataclasses

    from nonprehensile.inference import Expansion
    from nonprehensile.transitions import TransitionGraph

    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    exp = expand(poly, skills[:1], states_by_step(poly, 90))
    t0 = exp.transitions[0]
    a, b = State('f<&>"1', 0.0), State("g&amp;", 90.0)
    odd = dataclasses.replace(t0, skill=dataclasses.replace(t0.skill, name='p<&>"q',
                                                            initial=a, final=b))
    markup = transition_matrix_html(Expansion(TransitionGraph([a, b]), [odd], exp.method))
    cols, rows, cells = _matrix_cells(markup)
    assert cols == rows == [str(a), str(b)]
    assert cells[0][1]["title"] == f'{a} -> {b}: p<&>"q'
    assert "&amp;amp;amp;" not in markup
