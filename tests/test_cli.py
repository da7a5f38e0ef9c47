"""The command line: results as the spec's JSON, readable tables, one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import DATA
from nonprehensile.cli import main

EXAMPLE = str(Path(__file__).parents[1] / "examples" / "cube.json")


def run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(main, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def test_object_show_json_follows_the_spec() -> None:
    code, out, _ = run("object", "show", EXAMPLE, "--json")
    assert code == 0
    doc = json.loads(out)
    assert doc["name"] == "cube" and doc["symmetry_order"] == 24
    a = doc["faces"]["a"]
    assert a == {"loop": [3, 0, 1, 2], "delta": [0, 90, 180, 270], "normal": [0, 0, -1],
                 "stable": True, "virtual": False}
    assert doc["adjacency"]["a"] == {"e": 1, "f": 2, "b": 3, "d": 4}
    assert doc["adjacency"]["b"]["a"] == 2


def test_object_show_table_prints_the_adjacency_matrix() -> None:
    code, out, _ = run("object", "show", "cube")
    assert code == 0
    rows = [line for line in out.splitlines() if line.startswith("│ a │")]
    # the paper-style matrix row of face a: - 3 - 4 1 2
    assert any(r.split("│")[2:8] == [" - ", " 3 ", " - ", " 4 ", " 1 ", " 2 "] for r in rows)
    assert "symmetry order 24" in out


def test_states_json() -> None:
    code, out, _ = run("states", "cube", "--step", "90", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["n_classes"] == 1 and len(doc["states"]) == 24
    assert doc["states"][1] == {"face": "a", "theta": 90.0, "class": 0}


def test_states_from_file(tmp_path: Path) -> None:
    f = tmp_path / "s.json"
    f.write_text('[{"face": "a", "theta": 0}, {"face": "c", "theta": 45}]')
    code, out, _ = run("states", EXAMPLE, "--states", str(f), "--json")
    assert code == 0 and json.loads(out)["n_classes"] == 2


@pytest.mark.parametrize("mesh", ["cube.stl", "hexprism.obj"])
def test_from_mesh(tmp_path: Path, mesh: str) -> None:
    pytest.importorskip("trimesh")
    out_path = tmp_path / "model.json"
    code, out, _ = run("object", "from-mesh", str(DATA / mesh), "-o", str(out_path), "--json")
    assert code == 0 and out_path.exists()
    doc = json.loads(out)
    assert len(doc["faces"]) == {"cube.stl": 6, "hexprism.obj": 8}[mesh]
    code, out, _ = run("object", "show", str(out_path), "--json")
    assert json.loads(out)["faces"] == doc["faces"]


def bad_model(tmp_path: Path, name: str, text: str) -> str:
    p = tmp_path / name
    p.write_text(text)
    return str(p)


CUBE = json.loads(Path(EXAMPLE).read_text())


def variant(**changes: object) -> str:
    d = json.loads(json.dumps(CUBE))
    for k, v in changes.items():
        if k.startswith("face_"):
            d["faces"][k[5:]] = v
        elif k == "drop_face":
            del d["faces"][v]  # type: ignore[arg-type]
        else:
            d[k] = v
    return json.dumps(d)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('{"name": "cube", ', "malformed JSON at line 1"),
        ('{"faces": {}}', "missing key(s) ['vertices']"),
        (variant(vertices=[*CUBE["vertices"][:6], [1, 1, 1.4], [0, 1, 1]]), "not planar"),
        (variant(face_a=[3, 1, 0, 2]), "face 'a'"),
        (variant(drop_face="c"), "not closed"),
    ],
)
def test_bad_models_exit_2_with_one_line(tmp_path: Path, text: str, match: str) -> None:
    path = bad_model(tmp_path, "bad.json", text)
    code, out, err = run("object", "show", path)
    assert code == 2 and out == ""
    assert match in err and "bad.json" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


@pytest.mark.parametrize(
    ("mesh", "match"),
    [("triangle.obj", "at least 4 points"), ("flat.obj", "coplanar"),
     ("missing.stl", "no such mesh file")],
)
def test_bad_meshes_exit_2(tmp_path: Path, mesh: str, match: str) -> None:
    pytest.importorskip("trimesh")
    code, _, err = run("object", "from-mesh", str(DATA / mesh), "-o", str(tmp_path / "m.json"))
    assert code == 2 and match in err and mesh in err
    assert len(err.strip().splitlines()) == 1


def test_coplanar_points_exit_2(tmp_path: Path) -> None:
    pytest.importorskip("trimesh")
    code, _, err = run("object", "from-mesh", str(DATA / "flat.obj"), "--allow-open",
                       "-o", str(tmp_path / "m.json"))
    assert code == 2 and "coplanar" in err


def test_bad_state_options() -> None:
    code, _, err = run("states", "cube")
    assert code == 2 and "exactly one of --step" in err
    code, _, err = run("states", "cube", "--step", "7")
    assert code == 2 and "divide 360" in err


def test_real_process_exit_code_and_no_traceback(tmp_path: Path) -> None:
    path = bad_model(tmp_path, "broken.json", "{")
    proc = subprocess.run(
        [sys.executable, "-m", "nonprehensile.cli", "object", "show", path],
        capture_output=True, text=True, check=False,
    )
    assert proc.returncode == 2 and proc.stdout == ""
    assert "broken.json" in proc.stderr and "Traceback" not in proc.stderr


def test_figures_from_the_cli(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    skills = str(Path(EXAMPLE).parent / "cube_skills.json")
    for args, name in [
        (["object", "figure", "cube"], "object.png"),
        (["skills", "show", skills], "skills.png"),
        (["infer", skills, "--step", "90"], "graph.png"),
    ]:
        path = tmp_path / name
        opt = "-o" if args[0] == "object" else "--figure"
        code, _, err = run(*args, opt, str(path))
        assert code == 0 and path.stat().st_size > 10_000, err
