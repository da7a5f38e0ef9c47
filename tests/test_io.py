"""Model and state files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings

from conftest import random_hulls
from nonprehensile.errors import InputError, ModelError
from nonprehensile.geometry import Polyhedron, cube
from nonprehensile.io import load_model, read_model, read_states, write_model
from nonprehensile.states import State


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(random_hulls())
def test_model_file_round_trip(tmp_path: Path, p: Polyhedron) -> None:
    for suffix in ("json", "yaml"):
        path = tmp_path / f"m.{suffix}"
        write_model(p, path)
        q = read_model(path)
        assert q.faces == p.faces and q.name == p.name
        assert np.array_equal(q.vertices, p.vertices)
        assert np.array_equal(q.com, p.com)


def test_bundled_cube_is_the_builder_cube() -> None:
    a, b = load_model("cube"), cube()
    assert a.faces == b.faces and np.array_equal(a.vertices, b.vertices)
    examples = Path(__file__).parents[1] / "examples" / "cube.json"
    assert read_model(examples).faces == a.faces


def write(tmp_path: Path, text: str, name: str = "m.json") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_bad_model_files(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"m.json: malformed JSON at line 1, column"):
        read_model(write(tmp_path, '{"vertices": [[0,0,0]'))
    with pytest.raises(InputError, match=r"m.yaml: malformed YAML at line"):
        read_model(write(tmp_path, "vertices: [[0,0,0]\nfaces: {", "m.yaml"))
    with pytest.raises(ModelError, match=r"m.json: missing key\(s\) \['faces'\]"):
        read_model(write(tmp_path, '{"vertices": []}'))
    with pytest.raises(ModelError, match=r"unknown key\(s\) \['centre'\]"):
        read_model(write(tmp_path, '{"vertices": [], "faces": {}, "centre": 1}'))
    with pytest.raises(ModelError, match="must be a JSON/YAML object"):
        read_model(write(tmp_path, "[1, 2]"))
    good = json.loads(Path(__file__).parents[1].joinpath("examples", "cube.json").read_text())
    good["vertices"][6] = [1, 1, 1.5]
    with pytest.raises(ModelError, match=r"m.json: face '.': the face is not planar"):
        read_model(write(tmp_path, json.dumps(good)))
    with pytest.raises(InputError, match="no such model file"):
        load_model(tmp_path / "nope.json")


def test_states_file(tmp_path: Path) -> None:
    path = write(tmp_path, '[{"face": "a", "theta": 90}, {"face": "b", "theta": 0}]')
    assert read_states(path) == [State("a", 90), State("b", 0)]
    with pytest.raises(InputError, match="entry 1"):
        read_states(write(tmp_path, '[{"face": "a", "theta": 90}, {"face": "b"}]'))


@pytest.mark.parametrize(("text", "needle"), [
    ('[{"face": "z", "theta": 0}]', "names face 'z'"),
    ('[{"face": "a", "theta": 0}, {"face": "a", "theta": 360}]', "listed twice"),
    ("[]", "the state list is empty"),
    ('{"states": []}', "the state list is empty"),
])
def test_a_state_set_file_is_named_in_its_problems(tmp_path: Path, text: str,
                                                   needle: str) -> None:
    """--states FILE with a face the object lacks or a state twice: the message named no
    file; an empty list was an empty state set (states and infer printed nothing, exit 0)."""
    from click.testing import CliRunner

    from nonprehensile.cli import main

    path = write(tmp_path, text, "states.json")
    skills = Path(__file__).resolve().parents[1] / "src" / "nonprehensile" / "data" / \
        "cube_skills.json"
    for args in (["states", "cube"], ["infer", str(skills)]):
        res = CliRunner().invoke(main, [*args, "--states", str(path)])
        assert res.exit_code == 2, res.output
        line = res.output.strip()
        assert "\n" not in line and f"{path}: " in line and needle in line, line


def test_the_states_commands_json_is_a_states_file(tmp_path: Path) -> None:
    """What `nonprehensile states MODEL --json` prints is read as a states file (its entries'
    other keys, `class`, ignored): the same states as the command's own set."""
    from click.testing import CliRunner

    from nonprehensile.cli import main
    from nonprehensile.states import states_by_step

    res = CliRunner().invoke(main, ["states", "cube", "--step", "90", "--json"])
    assert res.exit_code == 0, res.output
    path = tmp_path / "s.json"
    path.write_text(res.stdout)
    assert read_states(path) == states_by_step(cube(), 90.0)
    skills = Path(__file__).resolve().parents[1] / "src" / "nonprehensile" / "data" / \
        "cube_skills.json"
    res = CliRunner().invoke(main, ["infer", str(skills), "--states", str(path), "--json"])
    assert res.exit_code == 0 and len(json.loads(res.stdout)["transitions"]) == 168, res.output
    with pytest.raises(InputError, match='"states" list'):
        read_states(write(tmp_path, '{"states": 3}'))


def test_json_files_are_read_without_pyyaml() -> None:
    """PyYAML is imported for YAML files only (10-15 ms of every command: issue 16)."""
    import subprocess
    import sys

    code = ("import sys; from nonprehensile.io import load_model; load_model('cube'); "
            "print('yaml' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=60).stdout
    assert out.strip() == "False"
