"""Skills, skill graphs and skills files."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from nonprehensile.cli import main
from nonprehensile.errors import SkillError
from nonprehensile.io import read_skills
from nonprehensile.skills.skill import group_by_maneuver, skill_graph, skill_to_dict

EXAMPLES = Path(__file__).parents[1] / "examples"
SKILLS = json.loads((EXAMPLES / "cube_skills.json").read_text())


def test_bundled_skills_and_the_paper_fig5_graph() -> None:
    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    assert [s.name for s in skills] == ["push-roll", "roll-arc", "roll-pull", "tumble-lift",
                                        "tumble-twist", "twist"]
    groups = group_by_maneuver(poly, skills)
    assert [[s.name for s in g] for g in groups] == [
        ["push-roll", "roll-arc", "roll-pull"], ["tumble-lift", "tumble-twist"], ["twist"]]
    g = skill_graph(poly, groups[0])
    # Fig. 5(b): push-roll has its own events (a branch); roll-arc and roll-pull share theirs
    # and differ only in motion: parallel arcs between the same events
    assert g.number_of_nodes() == 8
    starts = [n for n in g if g.in_degree(n) == 0]
    ends = [n for n in g if g.out_degree(n) == 0]
    assert len(starts) == 1 and len(ends) == 1
    assert g.out_degree(starts[0]) == 3  # three skills leave the resting event
    parallel = [(a, b) for a, b in g.edges() if g.number_of_edges(a, b) == 2]
    labels = {d["motion"].label for a, b, d in g.edges(data=True) if (a, b) in parallel}
    assert {"quarter-circle", "straight-pull"} <= labels
    twist = skill_graph(poly, groups[2])
    assert twist.number_of_nodes() == 3  # resting before and after are two events


def test_skill_steps_and_reverse() -> None:
    _, skills = read_skills(EXAMPLES / "cube_skills.json")
    twist = skills[-1]
    steps = list(twist.steps())
    assert [(s.source.id, s.target.id) for s in steps] == [("rest", "grip"), ("grip", "done")]
    rev = twist.reversed()
    assert (rev.initial, rev.final) == (twist.final, twist.initial)
    assert [e.id for e in rev.events] == ["done", "grip", "rest"]
    with pytest.raises(SkillError, match="not invertible"):
        skills[0].reversed()


def write_skills(tmp_path: Path, mutate: object) -> Path:
    data = json.loads(json.dumps(SKILLS))
    mutate(data["skills"][0])  # type: ignore[operator]
    data["object"] = str(EXAMPLES / "cube.json")
    path = tmp_path / "skills.json"
    path.write_text(json.dumps(data))
    return path


def _set(path: list[object], value: object) -> object:
    def mutate(skill: dict[str, object]) -> None:
        target: object = skill
        for key in path[:-1]:
            target = target[key]  # type: ignore[index]
        target[path[-1]] = value  # type: ignore[index]
    return mutate


def _sets(*changes: tuple[list[object], object]) -> object:
    def mutate(skill: dict[str, object]) -> None:
        for path, value in changes:
            _set(path, value)(skill)  # type: ignore[operator]
    return mutate


BAD = [
    (_set(["events", 1, "contacts"], ["(R1,z)", "(G,a)"]), "'push-roll'", "face 'z'"),
    (_set(["events", 2, "contacts"], ["(R1,f)", "(G,E(a,c))"]), "'push-roll'", "E(a,c)"),
    (_set(["motions", 1], {"from": "touch", "to": "landed"}), "'push-roll'", "consecutive"),
    (_set(["maneuver"], "tumbling"), "'push-roll'", "geometry"),
    (_set(["final"], {"face": "c", "theta": 0}), "'push-roll'", "final state c:0"),
    (_sets((["final"], {"face": "c", "theta": 0}), (["events", 4, "contacts"], ["(G,c)"])),
     "'push-roll'", "no single maneuver"),
    (_set(["events", 0, "contacts"], ["(G,b)"]), "'push-roll'", "rests on face 'a'"),
    (_set(["events", 1, "contacts"], "(R1,f) ∧ (G,a"), "'push-roll'", "(R1,f) ∧ (G,a"),
    (_set(["bogus"], 1), "'push-roll'", "unknown key"),
]


@pytest.mark.parametrize(("mutate", "skill", "element"), BAD)
def test_bad_skills_name_skill_and_element(
    tmp_path: Path, mutate: object, skill: str, element: str
) -> None:
    path = write_skills(tmp_path, mutate)
    with pytest.raises(SkillError) as info:
        read_skills(path)
    msg = str(info.value)
    assert skill in msg and element in msg and "skills.json" in msg
    result = CliRunner().invoke(main, ["infer", str(path), "--step", "90"])
    assert result.exit_code == 2
    assert element in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_skills_round_trip_and_inline_object(tmp_path: Path) -> None:
    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    from nonprehensile.io import skills_to_dict

    path = tmp_path / "inline.yaml"
    import yaml

    path.write_text(yaml.safe_dump(skills_to_dict(poly, skills)))
    poly2, skills2 = read_skills(path)
    assert skills2 == skills and poly2.faces == poly.faces
    assert [skill_to_dict(s) for s in skills2] == [skill_to_dict(s) for s in skills]


def test_cli_skills_show_and_infer_json() -> None:
    runner = CliRunner()
    res = runner.invoke(main, ["skills", "show", str(EXAMPLES / "cube_skills.json"), "--json"])
    assert res.exit_code == 0
    doc = json.loads(res.stdout)
    assert len(doc["graphs"]) == 3 and len(doc["graphs"][0]["nodes"]) == 8
    res = runner.invoke(main, ["infer", str(EXAMPLES / "cube_skills.json"), "--step", "90",
                               "--json", "--compare"])
    assert res.exit_code == 0
    doc = json.loads(res.stdout)
    assert doc["object"] == "cube" and doc["method"] == "exact"
    assert len(doc["states"]) == 24 and len(doc["transitions"]) == 24 * 7
    assert doc["disagreements"] == []
    first = doc["transitions"][0]
    assert set(first) == {"from", "to", "skill", "maneuver", "demonstrated", "mapping", "events"}
    assert first["mapping"] == {"a": "a", "d": "d", "f": "f"}
    res = runner.invoke(main, ["infer", str(EXAMPLES / "cube_skills.json"), "--step", "90",
                               "--method", "paper", "--json"])
    assert json.loads(res.stdout)["method"] == "paper"
    res = runner.invoke(main, ["infer", str(EXAMPLES / "cube_skills.json"), "--step", "90"])
    assert res.exit_code == 0 and "24 states, 168 transitions" in res.stdout
