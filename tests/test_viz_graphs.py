"""Figures of the state-transition and skill graphs."""

from __future__ import annotations

from pathlib import Path

import pytest

from nonprehensile.inference import expand, infer_exact
from nonprehensile.io import read_skills
from nonprehensile.skills.skill import group_by_maneuver, skill_graph
from nonprehensile.states import State, states_by_step

pytest.importorskip("matplotlib")

from nonprehensile.viz.graphs import (
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
    n_stripes = sum(1 for p in matrix_ax.patches if p.get_facecolor()[3] > 0)
    assert n_stripes == len(exp.transitions)
    demonstrated = [p for p in matrix_ax.patches if p.get_facecolor()[3] == 0]
    assert len(demonstrated) == len({(t.start, t.end) for t in exp.transitions if t.demonstrated})
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
    assert len(ax.patches) == g.number_of_edges()
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
