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
