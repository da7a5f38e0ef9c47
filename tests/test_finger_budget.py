"""Plans for an agent with a fixed number of fingertips (``nonprehensile.finger_budget``) and
the robot commands that use it: ``plan --robot``, ``simulate plan --robot``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from nonprehensile.cli import main
from nonprehensile.errors import InputError
from nonprehensile.finger_budget import (
    fingers_needed,
    more_fingertips,
    plan_with_fingers,
    skills_within,
)
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.planning import NoPlanError, SearchLimitError
from nonprehensile.states import State, states_by_step

SKILLS = Path(__file__).resolve().parents[1] / "src" / "nonprehensile" / "data" / \
    "cube_skills.json"
#: Two bottom faces only: the one-finger skills (rolls) leave ``a``'s four states unlinked,
#: the two-finger twist turns the cube on its face (the independent truth: a roll changes
#: the bottom face, a twist does not)
FEW_STATES = [State(f, t) for f in "ab" for t in (0.0, 90.0, 180.0, 270.0)]


def _fingers_in_file() -> dict[str, int]:
    """Each skill's highest finger ``Rk``, read from the skill file's text (not parsed)."""
    doc = json.loads(SKILLS.read_text())
    out = {}
    for sk in doc["skills"]:
        text = json.dumps(sk["events"])
        out[sk["name"]] = max((k for k in range(1, 10) if f"R{k}" in text), default=1)
    return out


def test_fingers_needed_and_skills_within_follow_the_fingers_the_skills_name() -> None:
    _, skills = read_skills(SKILLS)
    truth = _fingers_in_file()
    assert {s.name: fingers_needed(s) for s in skills} == truth
    assert sorted(s.name for s in skills_within(skills, 1)) == sorted(
        n for n, k in truth.items() if k == 1)
    assert skills_within(skills, 2) == skills
    two = [s for s in skills if truth[s.name] == 2]
    with pytest.raises(InputError, match=r"1 fingertip.*fewest any needs: 2.*--arms 2"):
        skills_within(two, 1)


def test_a_plan_out_of_one_fingertips_reach_names_the_steps_that_need_two() -> None:
    """a:0 -> a:90 on two faces' states: no roll links them, the twist does in one step."""
    poly, skills = read_skills(SKILLS)
    exp = expand(poly, skills_within(skills, 1), FEW_STATES)
    with pytest.raises(NoPlanError, match=r"1 fingertip.*1 step\(s\), step 1 twist \(2 "
                                          r"fingertips\).*--arms 2") as got:
        plan_with_fingers(poly, exp, State("a", 0.0), State("a", 90.0), n_fingers=1,
                          skills=skills, states=FEW_STATES)
    assert "\n" not in str(got.value)
    # with two fingertips the same call plans it
    p = plan_with_fingers(poly, expand(poly, skills, FEW_STATES), State("a", 0.0),
                          State("a", 90.0), n_fingers=2, skills=skills, states=FEW_STATES)
    assert [s.transition.skill.name for s in p.steps] == ["twist"]
    # with no skill set aside the search's own error stands
    one = skills_within(skills, 1)
    with pytest.raises(NoPlanError, match=r"^no sequence of known skills takes a:0 to a:90"):
        plan_with_fingers(poly, exp, State("a", 0.0), State("a", 90.0), n_fingers=1,
                          skills=one, states=FEW_STATES)


def test_a_search_that_gives_up_with_one_fingertip_says_what_every_skill_plans(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The search's limit (monkeypatched down to 10 nodes) stops the one-fingertip search of
    a:0 -> a:90 (three rolls); the twist's one step, every skill's plan, fits in it: the
    error stays the search's give-up (not a proof of no plan) and says what every skill
    needs; a hand of 2 tip sites per arm needs 1 arm."""
    import nonprehensile.planning as planning

    monkeypatch.setattr(planning, "MAX_SEARCH_NODES", 10)
    _, skills = read_skills(SKILLS)
    states = states_by_step(read_skills(SKILLS)[0], 90.0)
    poly = read_skills(SKILLS)[0]
    exp = expand(poly, skills_within(skills, 1), states)
    with pytest.raises(SearchLimitError, match=r"passed 10 states without reaching a:90.*it "
                                               r"searched the skills the robot's 1 fingertip"
                                               r".*step 1 twist \(2 fingertips\): give 2 "
                                               r"arms \(--arms 2"):
        plan_with_fingers(poly, exp, State("a", 0.0), State("a", 90.0), n_fingers=1,
                          skills=skills, states=states)
    assert "--arms 1, 2 fingertip(s) each" in more_fingertips(2, per_arm=2)
    assert "--arms 2, 2 fingertip(s) each" in more_fingertips(3, per_arm=2)


def test_plan_with_a_robot_plans_with_its_fingertips(tmp_path: Path) -> None:
    """``plan --robot panda`` (one arm, one fingertip) plans with the one-finger skills, as
    ``simulate plan --robot`` does: a:0 -> a:90, a twist without a robot, is rolled; before,
    it planned the twist and refused to write its joints. Out of one fingertip's reach the
    command says what the plan needs, in one line, exit 2."""
    pytest.importorskip("mink", reason="the robot extra (mink) is not installed: "
                                       "pip install 'nonprehensile[robot]'")
    truth = _fingers_in_file()
    args = [str(SKILLS), "--from", "a:0", "--to", "a:90", "--step", "90", "--dataset", "cube"]
    free = CliRunner().invoke(main, ["plan", *args, "--json"])
    assert free.exit_code == 0, free.output
    assert [s["skill"] for s in json.loads(free.stdout)["steps"]] == ["twist"]
    out = tmp_path / "joints"
    res = CliRunner().invoke(main, ["plan", *args, "--robot", "panda", "--out", str(out),
                                    "--json"])
    assert res.exit_code == 0, res.output
    steps = json.loads(res.stdout)["steps"]
    assert steps and all(truth[s["skill"]] == 1 for s in steps)
    assert (out / "joints_plan.csv").is_file()
    assert len(list(out.glob("joints_step*.csv"))) == len(steps)
    states = tmp_path / "states.json"
    states.write_text(json.dumps([s.to_dict() for s in FEW_STATES]))
    few = [str(SKILLS), "--from", "a:0", "--to", "a:90", "--states", str(states),
           "--dataset", "cube"]
    for cmd in (["plan", *few, "--robot", "panda", "--out", str(tmp_path / "x")],
                ["simulate", "plan", *few, "--robot", "panda"]):
        res = CliRunner().invoke(main, cmd)
        assert res.exit_code == 2, res.output
        line = res.output.strip().splitlines()[-1]
        assert "step 1 twist (2 fingertips)" in line and "--arms 2" in line, res.output
