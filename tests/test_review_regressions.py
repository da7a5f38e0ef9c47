"""Bad numbers and odd inputs found by review: each gets a clear error, never a traceback."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from nonprehensile.cli import main
from nonprehensile.equivalence import equivalence_classes
from nonprehensile.errors import InputError, ModelError, SkillError, StateError
from nonprehensile.geometry import Polyhedron, cube, rotation_group
from nonprehensile.geometry.build import convex_hull
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.states import State, check_states, states_by_step
from nonprehensile.transitions import Transition

EXAMPLES = Path(__file__).parents[1] / "examples"


def test_copies_of_a_state_share_a_class_even_without_symmetry() -> None:
    c = cube()
    states = [State("a", 0), State("a", 0), State("a", 360), State("a", 1e-9)]
    assert equivalence_classes(c, states) == [0, 0, 0, 0]
    scalene = convex_hull([[0, 0, 0], [2.0, 0.1, 0], [0.3, 1.7, 0.2], [0.1, 0.2, 1.3]])
    assert len(rotation_group(scalene)) == 1
    f = next(iter(scalene.faces))
    assert equivalence_classes(scalene, [State(f, 10), State(f, 10)]) == [0, 0]


def test_explicit_state_sets_refuse_duplicates() -> None:
    with pytest.raises(StateError, match="listed twice"):
        check_states(cube(), [State("a", 0), State("b", 0), State("a", 359.9999999)])
    assert len(check_states(cube(), [State("a", 0), State("a", 90)])) == 2


@pytest.mark.parametrize("value", ["abc", [1, 2, "x"], None.__class__])
def test_bad_centre_of_mass_is_a_model_error(value: object) -> None:
    c = cube()
    with pytest.raises(ModelError, match="center_of_mass"):
        Polyhedron(c.vertices, dict(c.faces), center_of_mass=value)  # type: ignore[arg-type]


@pytest.mark.parametrize("rtol", [float("nan"), -1.0, 0.0, float("inf")])
def test_bad_tolerances_are_refused(rtol: float) -> None:
    c = cube()
    with pytest.raises(ModelError, match="rtol: expected a finite number"):
        Polyhedron(c.vertices, dict(c.faces), rtol=rtol)
    with pytest.raises(InputError, match="atol"):
        rotation_group(c, atol=rtol)
    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    if rtol != 0.0:
        with pytest.raises(InputError, match="angle"):
            expand(poly, skills, states_by_step(poly, 90), angle_tol=rtol)


def test_cli_tolerance_and_output_path_errors(tmp_path: Path) -> None:
    runner = CliRunner()
    for args in (["object", "show", "cube", "--rtol", "nan"],
                 ["infer", str(EXAMPLES / "cube_skills.json"), "--step", "90", "--atol", "-1"],
                 ["object", "from-mesh", str(Path(__file__).parent / "data" / "cube.stl"),
                  "-o", str(tmp_path / "missing" / "x.json")]):
        res = runner.invoke(main, args)
        assert res.exit_code == 2, (args, res.output)
        assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
    assert not list(tmp_path.rglob("*.tmp"))


def test_reserved_skill_names(tmp_path: Path) -> None:
    data = json.loads((EXAMPLES / "cube_skills.json").read_text())
    data["object"] = str(EXAMPLES / "cube.json")
    data["skills"][0]["name"] = "twist:reverse"
    path = tmp_path / "s.json"
    path.write_text(json.dumps(data))
    with pytest.raises(SkillError, match="may not contain ':'"):
        read_skills(path)


def test_skills_file_with_a_missing_model_names_both_files(tmp_path: Path) -> None:
    data = json.loads((EXAMPLES / "cube_skills.json").read_text())
    data["object"] = "nope.json"
    path = tmp_path / "s.json"
    path.write_text(json.dumps(data))
    with pytest.raises(SkillError, match=r"s\.json: its object: .*nope\.json"):
        read_skills(path)


def test_odd_values_in_transitions_and_states() -> None:
    with pytest.raises(InputError, match="demonstrated"):
        Transition.from_dict({"from": {"face": "a", "theta": 0}, "to": {"face": "d", "theta": 0},
                              "skill": "x", "maneuver": "rolling", "demonstrated": "false"})
    with pytest.raises(StateError, match="finite"):
        State.parse("a:1e400")
    with pytest.raises(StateError, match="more than"):
        states_by_step(cube(), 1e-4)
    from nonprehensile.errors import ManeuverError
    from nonprehensile.maneuvers import roll

    with pytest.raises(ManeuverError, match=r"edges 1\.\.4"):
        roll(cube(), State("a", 0), edge=True)  # type: ignore[arg-type]


def test_states_command_takes_tolerances(tmp_path: Path) -> None:
    f = tmp_path / "s.json"
    f.write_text('[{"face": "a", "theta": 0}, {"face": "b", "theta": 90.001}]')
    res = CliRunner().invoke(main, ["states", "cube", "--states", str(f), "--json",
                                    "--angle-tol", "0.01"])
    assert res.exit_code == 0 and json.loads(res.stdout)["n_classes"] == 1
    res = CliRunner().invoke(main, ["states", "cube", "--states", str(f), "--json"])
    assert json.loads(res.stdout)["n_classes"] == 2


# ---------------------------------------------------------------- second review (motion, plans)
def test_plan_refuses_bad_costs_and_positions() -> None:
    from nonprehensile.planning import plan

    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    exp = expand(poly, skills, states_by_step(poly, 90))
    for costs, match in [({"twist": float("nan")}, "finite"), ({"twist": -5.0}, ">= 0"),
                         ({"nosuch": 3.0}, "unknown skill")]:
        with pytest.raises(InputError, match=match):
            plan(poly, exp, State("a", 0), State("b", 0), costs=costs)
    with pytest.raises(InputError, match="position"):
        plan(poly, exp, State("a", 0), State("b", 0), position=(float("nan"), 0.0))


def test_figures_refuse_unknown_suffixes(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    res = CliRunner().invoke(main, ["object", "figure", "cube", "-o", str(tmp_path / "f.xyz")])
    assert res.exit_code == 2 and "cannot write a figure as 'xyz'" in res.stderr


def test_clusterer_and_store_refuse_bad_data(tmp_path: Path) -> None:
    import sqlite3

    import numpy as np

    from nonprehensile.motion.clustering import HilbertClusterer
    from nonprehensile.motion.store import SQLiteStore

    with pytest.raises(InputError, match="n_components=None"):
        HilbertClusterer(2, method="runs", order=20)
    with pytest.raises(InputError, match="below"):
        HilbertClusterer(2).fit(np.random.default_rng(0).random((50, 10)) * 1e300)
    strings = tmp_path / "s.npy"
    np.save(strings, np.array(["a", "b"]))
    res = CliRunner().invoke(main, ["cluster", "fit", str(tmp_path / "x.db"), "--arrays",
                                    str(strings)])
    assert res.exit_code == 2 and "real numbers" in res.stderr
    db_path = tmp_path / "c.db"
    store = SQLiteStore(db_path)
    HilbertClusterer(2, store=store, random_state=0).fit(
        np.random.default_rng(1).random((30, 4)))
    store.close()
    with sqlite3.connect(db_path) as raw:
        raw.execute("DELETE FROM samples WHERE id = 10")
    with pytest.raises(InputError, match="deleted outside"):
        SQLiteStore(db_path)
    res = CliRunner().invoke(main, ["cluster", "add", str(tmp_path / "none.db"), "--arrays",
                                    str(strings)])
    assert res.exit_code == 2 and not (tmp_path / "none.db").exists()


def test_small_and_mismatched_datasets_for_plans(tmp_path: Path) -> None:
    pytest.importorskip("ezc3d")
    from nonprehensile.demonstrations.dataset import _number
    from nonprehensile.demonstrations.synth import synthesize
    from nonprehensile.pipeline import motions_from_dataset

    assert _number(10**400) is None
    with pytest.raises(InputError, match="gap_limit"):
        synthesize(tmp_path / "bad", seed=0, n_per_skill=1, gap_limit=2)
    synthesize(tmp_path / "small", seed=0, n_per_skill=2)
    poly, skills = read_skills(EXAMPLES / "cube_skills.json")
    _, motions = motions_from_dataset(tmp_path / "small", skills=skills, poly=poly)
    assert motions.reference("twist", "rest", "grip") is not None  # 2 demos: one cluster
    big = Polyhedron(poly.vertices * 3, dict(poly.faces), name="big")
    with pytest.raises(InputError, match="models differ"):
        motions_from_dataset(tmp_path / "small", skills=skills, poly=big)


def test_dataset_files_must_stay_inside_the_folder(tmp_path: Path) -> None:
    pytest.importorskip("ezc3d")
    import shutil

    from nonprehensile.demonstrations.dataset import check_dataset, dataset_path

    root = tmp_path / "d"
    shutil.copytree(dataset_path("cube"), root)
    ann = json.loads((root / "annotations.json").read_text())
    first = ann["demonstrations"][0]
    shutil.copy(root / first["file"], tmp_path / "outside.c3d")
    first["file"] = "../outside.c3d"
    (root / "annotations.json").write_text(json.dumps(ann))
    ds, problems = check_dataset(root)
    assert ds is None
    assert [p.message for p in problems] == [
        "the file lies outside the dataset folder; copy it in and name it by its path "
        "relative to the folder"]
