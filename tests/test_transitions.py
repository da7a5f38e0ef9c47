"""The state-transition graph."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, strategies as st

from nonprehensile.errors import InputError
from nonprehensile.geometry import cube
from nonprehensile.maneuvers import roll
from nonprehensile.states import State, states_by_step
from nonprehensile.transitions import Transition, TransitionGraph


def cube_roll_graph() -> TransitionGraph:
    c = cube()
    g = TransitionGraph(states_by_step(c, 90))
    for s in states_by_step(c, 90):
        for k in range(1, 5):
            m = roll(c, s, edge=k)
            g.add(Transition(s, m.end, f"roll-{k}", "rolling", demonstrated=(s.face == "a")))
    return g


def test_cube_rolls_graph_and_adjacency_view() -> None:
    g = cube_roll_graph()
    assert len(g.states) == 24 and len(g) == 96
    states, cells = g.adjacency_view()
    i, j = states.index(State("a", 0)), states.index(State("d", 0))
    assert cells[i][j] == ["roll-4"]
    assert sum(len(c) for row in cells for c in row) == 96
    assert {t.end for t in g.successors(State("a", 0))} == {
        State("e", 180), State("f", 0), State("b", 270), State("d", 0)}


def test_parallel_arcs_and_demonstrated_kept() -> None:
    a, d = State("a", 0), State("d", 0)
    g = TransitionGraph()
    g.add(Transition(a, d, "push-roll", "rolling", True))
    g.add(Transition(a, d, "pull-roll", "rolling", False))
    g.add(Transition(a, d, "push-roll", "rolling", False))  # inferred never replaces shown
    assert len(g) == 2
    assert [t.demonstrated for t in g.transitions()] == [True, False]


@given(st.lists(st.tuples(st.sampled_from("abcdef"), st.integers(0, 3),
                          st.sampled_from("abcdef"), st.integers(0, 3), st.booleans()),
                max_size=12))
def test_json_round_trip(arcs: list[tuple[str, int, str, int, bool]]) -> None:
    g = TransitionGraph([State("a", 0)])
    for f, i, h, j, demo in arcs:
        g.add(Transition(State(f, 90 * i), State(h, 90 * j), f"s{i}{j}", "rolling", demo,
                         {"mapping": {f: h}}))
    back = TransitionGraph.from_dict(json.loads(json.dumps(g.to_dict())))
    assert back.states == g.states
    assert list(back.transitions()) == list(g.transitions())
    assert [t.info for t in back.transitions()] == [t.info for t in g.transitions()]


def test_bad_transitions() -> None:
    with pytest.raises(InputError, match="maneuver must be one of"):
        Transition(State("a", 0), State("b", 0), "x", "sliding")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="lacks keys"):
        Transition.from_dict({"from": {"face": "a", "theta": 0}})
    with pytest.raises(InputError):
        TransitionGraph.from_dict([])
