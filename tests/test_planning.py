"""Planning (paper Section VII) checked with exact geometry."""

from __future__ import annotations

import json
from pathlib import Path

import networkx as nx
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, strategies as st

from nonprehensile.cli import main
from nonprehensile.errors import InputError
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.maneuvers import classify
from nonprehensile.planning import NoPlanError, Offset, ReferenceMotion, find_offset, plan
from nonprehensile.states import State, states_by_step

SKILLS = Path(__file__).parents[1] / "examples" / "cube_skills.json"
POLY, ALL_SKILLS = read_skills(SKILLS)
STATES = states_by_step(POLY, 90)
EXP = expand(POLY, ALL_SKILLS, STATES)


def check_plan_geometry(p: object, start: State, goal: State) -> None:
    """Every step is an arc of the graph, steps chain, and the exact maneuver of each step
    takes its start to its end; the last step ends at the goal."""
    pl = plan(POLY, EXP, start, goal)
    cur = start
    for step in pl.steps:
        t = step.transition
        assert EXP.graph.graph.has_edge(t.start, t.end, key=t.skill.name)
        assert step.start_world.isclose(cur)
        m = classify(POLY, step.start_world, step.end_world)
        assert m.kind == t.skill.maneuver
        cur = step.end_world
    assert cur.isclose(goal)


@given(st.sampled_from(STATES), st.sampled_from(STATES))
def test_plans_between_any_two_states(a: State, b: State) -> None:
    check_plan_geometry(POLY, a, b)


@given(st.sampled_from(STATES), st.sampled_from(STATES), st.floats(-170, 170))
def test_offset_start(a: State, b: State, turn: float) -> None:
    start = State(a.face, a.theta + turn)
    goal = State(b.face, b.theta + turn)
    pl = plan(POLY, EXP, start, goal, position=(0.3, -0.2))
    assert pl.offset.translate == (0.3, -0.2)
    # the agent's first placement turns it so that it sees the start as a model state ...
    first, nearest = find_offset(POLY, STATES, start)
    assert any(pl.offset.state_to_model(start).isclose(s) for s in STATES)
    # ... the nearest such turn unless another one makes the plan cheaper
    target = nearest.state_to_model(goal)
    if any(target.isclose(s) for s in STATES):
        target = next(s for s in STATES if target.isclose(s))
        old = nx.shortest_path_length(EXP.graph.graph, first, target)
        assert pl.cost <= old
        if pl.cost == old:
            assert abs(pl.offset.rotate_deg) <= 45 + 1e-9
    check_plan_geometry(POLY, start, goal)


def test_offset_maps_points_and_states() -> None:
    model, off = find_offset(POLY, STATES, State("b", 100), position=(1.0, 2.0))
    assert model == State("b", 90) and off.rotate_deg == pytest.approx(10)
    assert off.state_to_world(model).isclose(State("b", 100))
    assert np.allclose(Offset(90, (1, 2)).to_world(np.array([[1.0, 0, 0]])), [[1, 3, 0]])


def test_shortest_plan_and_costs() -> None:
    pl = plan(POLY, EXP, State("a", 0), State("d", 0))
    assert len(pl.steps) == 1 and pl.steps[0].transition.demonstrated
    assert pl.steps[0].transition.skill.name == "push-roll"  # demonstrated, then by name
    pl = plan(POLY, EXP, State("a", 0), State("d", 0), costs={"push-roll": 5.0})
    assert pl.steps[0].transition.skill.name == "roll-arc" and pl.cost == 1.0
    assert plan(POLY, EXP, State("a", 0), State("a", 0)).steps == ()


def test_unreachable_goal_names_reachable_states() -> None:
    exp = expand(POLY, ALL_SKILLS[:1], STATES)  # push-roll only: rolls one way
    with pytest.raises(NoPlanError) as info:
        plan(POLY, exp, State("a", 0), State("a", 45))
    # turning the agent between rolls rolls the cube any way: all 24 orientations, none other
    assert set(info.value.reachable) == set(STATES)
    assert "reachable states (24)" in str(info.value)
    with pytest.raises(NoPlanError, match="even relocating the agent"):
        plan(POLY, EXP, State("a", 0), State("a", 45))


def test_relocation_is_a_move_with_its_cost() -> None:
    exp = expand(POLY, ALL_SKILLS[:1], STATES)  # push-roll only
    # the model alone never turns the cube on its face a; the agent walking around it does
    pl = plan(POLY, exp, State("a", 0), State("a", 90), relocation_cost=0.25)
    check = State("a", 0)
    for step in pl.steps:
        assert step.start_world.isclose(check)
        assert step.agent is not None
        m = classify(POLY, step.start_world, step.end_world)
        assert m.kind == "rolling"
        check = step.end_world
    assert check.isclose(State("a", 90))
    assert pl.relocations >= 1
    assert pl.cost == pytest.approx(len(pl.steps) + 0.25 * pl.relocations)
    assert [s.relocation_cost for s in pl.steps[1:] if s.relocated] == [0.25] * pl.relocations
    # a relocation is a move like any other: a dearer one never makes the plan cheaper
    dear = plan(POLY, exp, State("a", 0), State("a", 90), relocation_cost=5)
    assert dear.cost >= pl.cost
    doc = pl.to_dict()
    assert doc["relocations"] == pl.relocations
    assert all(s["agent"]["rotate_deg"] is not None for s in doc["steps"])
    with pytest.raises(InputError, match="relocation cost"):
        plan(POLY, exp, State("a", 0), State("a", 90), relocation_cost=-1)


@pytest.mark.parametrize("step", [90.0, 10.0, 1.0])
def test_issue_task_planned_at_any_step(step: float) -> None:
    states = states_by_step(POLY, step)
    exp = expand(POLY, ALL_SKILLS, states)
    pl = plan(POLY, exp, State("b", 200), State("e", 110))
    assert [(str(s.start_world), str(s.end_world)) for s in pl.steps] == [
        ("b:200", "a:290"), ("a:290", "e:110")]
    assert pl.offset.rotate_deg == pytest.approx(20) and pl.relocations == 0


class FakeLibrary:
    def reference(self, skill: str, source: str, target: str) -> ReferenceMotion | None:
        if skill != "twist":
            return None
        pos = np.zeros((3, 1, 3))
        pos[:, 0, 0] = [1.0, 2.0, 3.0]  # along +x in the demonstration's frame
        return ReferenceMotion(pos, ("tip",), 120.0, 0, 5)


def test_reference_motions_follow_offset_and_reversal() -> None:
    pl = plan(POLY, EXP, State("a", 90), State("a", 0), motions=FakeLibrary())
    (step,) = pl.steps
    assert step.transition.skill.name == "twist:reverse"
    ref = step.motions[0][3]
    assert ref is not None
    # reversed in time: the reverse skill's first arc is the demonstrated last arc backwards
    assert ref.positions[:, 0, 0].tolist() == [3.0, 2.0, 1.0]
    pl = plan(POLY, EXP, State("a", 90 + 30), State("a", 180 + 30), motions=FakeLibrary(),
              position=(1.0, 0.0))
    ref = pl.steps[0].motions[0][3]
    assert ref is not None
    assert np.allclose(ref.positions[0, 0], [1 + np.cos(np.radians(30)), np.sin(np.radians(30)),
                                             0])


def test_plan_cli_json_and_exit_codes() -> None:
    runner = CliRunner()
    res = runner.invoke(main, ["plan", str(SKILLS), "--from", "a:10", "--to", "c:100",
                               "--step", "90", "--json"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["start"] == {"face": "a", "theta": 10.0}
    assert doc["offset"] == {"rotate_deg": 10.0, "translate": [0.0, 0.0]}
    step = doc["steps"][0]
    assert set(step) >= {"from", "to", "skill", "maneuver", "demonstrated", "mapping", "events",
                         "motions"}
    assert doc["steps"][-1]["to"] == {"face": "c", "theta": 100.0}
    res = runner.invoke(main, ["plan", str(SKILLS), "--from", "a:0", "--to", "a:45",
                               "--step", "90"])
    assert res.exit_code == 2 and "reachable" in res.stderr
    res = runner.invoke(main, ["plan", str(SKILLS), "--from", "a:0", "--to", "c:90",
                               "--step", "90"])
    assert (res.exit_code == 0 and "push-roll" in res.stdout) or "roll" in res.stdout


def test_a_reference_is_computed_once_and_is_the_medoid() -> None:
    """The library keeps each arc's reference: asked again it is the same object, and it is
    the medoid of the arc's main cluster computed afresh (by brute force here)."""
    import pickle
    from collections import Counter

    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset

    root = Path(__file__).resolve().parents[1] / "examples" / "cube_skills.json"
    poly, skills = read_skills(root)
    _, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    seg = motions.segments[0]
    skill, src, tgt = seg.skill, seg.motion.source, seg.motion.target
    got = motions.reference(skill, src, tgt)
    assert got is not None and motions.reference(skill, src, tgt) is got
    rows = [i for i, s in enumerate(motions.segments)
            if s.skill == skill and (s.motion.source, s.motion.target) == (src, tgt)]
    counts = Counter(int(motions.labels[i]) for i in rows)
    top = max(counts, key=lambda c: (counts[c], -c))
    members = [i for i in rows if motions.labels[i] == top]
    x = motions.vectors[members]
    total = [sum(float(np.linalg.norm(x[a] - x[b])) for b in range(len(x)))
             for a in range(len(x))]
    best = members[int(np.argmin(total))]
    want = motions.segments[best].trajectory.to_units("m").positions
    np.testing.assert_allclose(got.positions, want)
    # a library pickled before it kept references still answers (and keeps them)
    old = pickle.loads(pickle.dumps(motions))
    old.__dict__.pop("_reference_memo", None)
    assert old.reference(skill, src, tgt) is not None
