"""Real meshes nobody here made, measured objects, and models that carry their tolerance.

Meshes are read in place from ``shared/realdata/meshes`` beside the repository (CI) or beside
a folder above it (work trees); the tests that need them skip, saying so, when it is absent.
Stable faces are checked against trimesh's ``compute_stable_poses`` on the hull with the
model's centre of mass: an independent implementation.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from nonprehensile.cli import main
from nonprehensile.equivalence import equivalence_classes
from nonprehensile.errors import MeshError, ModelError, StateError
from nonprehensile.geometry import (
    Polyhedron,
    convex_hull,
    cube,
    from_mesh,
    rotation_group,
)
from nonprehensile.geometry.polyhedron import point_diameter
from nonprehensile.io import read_model, write_model
from nonprehensile.states import is_stable, states_by_step

trimesh = pytest.importorskip("trimesh")


def _shared() -> Path | None:
    repo = Path(__file__).resolve().parents[1]
    for folder in repo.parents:
        if (folder / "shared" / "realdata" / "meshes").is_dir():
            return folder / "shared" / "realdata" / "meshes"
    return None


MESHES = _shared()
needs_meshes = pytest.mark.skipif(
    MESHES is None, reason="shared/realdata/meshes is not beside the repository"
)

#: A sample of the real single-solid meshes: CAD parts with chamfers, texture-seam OBJ/PLY,
#: an open scan, curved objects, a non-convex part.
SAMPLE = ["featuretype.STL", "cube_blender_uv.ply", "BoxTextured.glb", "bunny.ply",
          "cylinder.stl", "fandisk.obj", "angle_block.STL", "20mm-xyz-cube.stl"]


def run(*args: str) -> tuple[int, str, str]:
    res = CliRunner().invoke(main, list(args))
    return res.exit_code, res.stdout, res.stderr


def max_bend(model: Polyhedron) -> float:
    """Largest angle (radians) between a face's normal and one of its fan triangles': a
    face merged within a tolerance bends a little, and trimesh's hull splits it there."""
    worst = 0.0
    for f, loop in model.faces.items():
        p = model.vertices[list(loop)]
        n = np.cross(p[2:] - p[0], p[1:-1] - p[0])
        n /= np.linalg.norm(n, axis=1)[:, None]
        worst = max(worst, float(np.arccos(np.clip(n @ model.normals[f], -1, 1)).max()))
    return worst


def agree(model: Polyhedron) -> bool:
    """Stable faces of ours and stable poses of trimesh match one to one (up to the bend)."""
    poses = stable_normals_by_trimesh(model)
    names = list(model.faces)
    normals = np.array([model.normals[f] for f in names])
    stable = np.array([is_stable(model, f) for f in names])
    near = normals @ poses.T > math.cos(1e-3 + 2 * max_bend(model))  # (faces, poses)
    return bool(near[stable].any(axis=1).all() and near[stable].any(axis=0).all())


def stable_normals_by_trimesh(model: Polyhedron) -> np.ndarray:
    tri = [[loop[0], loop[k], loop[k + 1]] for loop in model.faces.values()
           for k in range(1, len(loop) - 1)]
    hull = trimesh.Trimesh(model.vertices, np.array(tri)).convex_hull
    transforms, probs = trimesh.poses.compute_stable_poses(hull, center_mass=model.com)
    return np.array([t[:3, :3].T @ [0.0, 0.0, -1.0] for t, p in zip(transforms, probs,
                                                                      strict=True) if p > 0])


@needs_meshes
@pytest.mark.parametrize("name", SAMPLE)
def test_real_mesh_becomes_a_model_that_loads_and_rests_as_trimesh_says(
    tmp_path: Path, name: str
) -> None:
    assert MESHES is not None
    out = tmp_path / "m.json"
    code, _, err = run("object", "from-mesh", str(MESHES / name), "-o", str(out))
    assert code == 0, err
    code, show, err = run("object", "show", str(out), "--json")
    assert code == 0, err
    code, _, err = run("states", str(out), "--step", "90", "--json")
    assert code == 0, err
    model = read_model(out)
    ours = {f for f in model.faces if is_stable(model, f)}
    assert ours == {f for f, info in json.loads(show)["faces"].items() if info["stable"]}
    # every stable pose of trimesh rests on a stable face of ours, and the other way round
    assert agree(model)


@needs_meshes
def test_open_scan_gets_its_hull_with_one_note_and_strict_refuses(tmp_path: Path) -> None:
    assert MESHES is not None
    # the scan is in millimetres (194 units across): read as metres it would add a units note
    code, _, err = run("object", "from-mesh", str(MESHES / "reference.obj"), "--units", "mm",
                       "-o", str(tmp_path / "m.json"))
    assert code == 0 and "note:" in err and "convex hull" in err
    assert len(err.strip().splitlines()) == 1
    code, _, err = run("object", "from-mesh", str(MESHES / "reference.obj"), "--strict", "-o",
                       str(tmp_path / "m2.json"))
    assert code == 2 and "not closed" in err and len(err.strip().splitlines()) == 1


def test_model_file_carries_the_tolerance_it_was_built_at(tmp_path: Path) -> None:
    # a faceted ball merged at a coarse tolerance: faces bend more than the default allows
    ball = trimesh.creation.icosphere(subdivisions=3)
    path = tmp_path / "ball.stl"
    ball.export(path)
    model = from_mesh(path, rtol=1e-3)
    assert model.rtol >= 1e-3
    write_model(model, tmp_path / "ball.json")
    assert json.loads((tmp_path / "ball.json").read_text())["rtol"] == model.rtol
    again = read_model(tmp_path / "ball.json")
    assert again.rtol == model.rtol and len(again.faces) == len(model.faces)
    code, _, err = run("object", "show", str(tmp_path / "ball.json"))
    assert code == 0, err


def test_max_faces_facets_a_ball_and_stable_states_still_agree_with_trimesh(
    tmp_path: Path,
) -> None:
    ball = trimesh.creation.icosphere(subdivisions=4)  # 5120 triangles
    path = tmp_path / "ball.ply"
    ball.export(path)
    model = from_mesh(path, max_faces=300)
    assert len(model.faces) <= 300
    assert agree(model)


def test_closed_sphere_of_20480_triangles_in_bounded_memory(tmp_path: Path) -> None:
    # it died of MemoryError computing all pairwise vertex distances
    ball = trimesh.creation.icosphere(subdivisions=5)
    assert len(ball.faces) == 20480
    path = tmp_path / "ball.ply"
    ball.export(path)
    model = from_mesh(path)
    assert len(model.faces) == 20480
    assert model.diameter == pytest.approx(2.0, rel=1e-6)


def test_diameter_is_exact_on_lumpy_sets_and_within_a_hair_on_round_ones() -> None:
    rng = np.random.default_rng(3)
    from scipy.spatial.distance import pdist

    for pts in (rng.normal(size=(3000, 3)) * [1, 2, 3], rng.uniform(size=(300, 3)) + 1e6):
        assert point_diameter(pts) == pytest.approx(pdist(pts).max(), rel=1e-12)
    ball = rng.normal(size=(4000, 3))
    ball /= np.linalg.norm(ball, axis=1)[:, None]
    assert point_diameter(ball) == pytest.approx(pdist(ball).max(), rel=1e-5)


@pytest.mark.parametrize("big", [1e300, 1.5e308, 1e120])
def test_huge_coordinates_are_one_clear_error(tmp_path: Path, big: float) -> None:
    v = (cube().vertices * big).tolist()
    with pytest.raises(ModelError, match="magnitude"):
        Polyhedron(v, dict(cube().faces))
    with pytest.raises(MeshError, match="magnitude"):
        convex_hull(v)
    doc = {"vertices": v, "faces": {k: list(t) for k, t in cube().faces.items()}}
    (tmp_path / "m.json").write_text(json.dumps(doc))
    code, _, err = run("object", "show", str(tmp_path / "m.json"))
    assert code == 2 and "magnitude" in err and len(err.strip().splitlines()) == 1


def test_too_fine_a_step_is_refused_before_work_naming_the_option() -> None:
    with pytest.raises(StateError, match=r"--step.*limit of 500000"):
        states_by_step(cube(), 0.0036)
    code, _, err = run("states", "cube", "--step", "0.0036")
    assert code == 2 and "--step" in err and len(err.strip().splitlines()) == 1


def noisy_cube(seed: int) -> Polyhedron:
    """A 100 mm cube whose corners were each measured up to 0.5 mm off."""
    c = cube(100.0)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(8, 3))
    d *= 0.5 / np.linalg.norm(d, axis=1)[:, None]
    return Polyhedron(c.vertices + d, dict(c.faces), units="mm", rtol=0.01)


@pytest.mark.parametrize("seed", range(4))
def test_measured_cube_is_a_cube_at_1_mm_and_asymmetric_at_0_01_mm(seed: int) -> None:
    p = noisy_cube(seed)
    states = states_by_step(p, 90)
    assert len(rotation_group(p, atol=1.0)) == 24
    assert set(equivalence_classes(p, states, atol=1.0, angle_tol=1.0)) == {0}
    assert len(rotation_group(p, atol=0.01)) == 1
    assert len(set(equivalence_classes(p, states, atol=0.01, angle_tol=1.0))) == 24


def test_measured_cube_on_the_command_line(tmp_path: Path) -> None:
    path = tmp_path / "noisy.json"
    write_model(noisy_cube(0), path)
    code, out, err = run("states", str(path), "--step", "90", "--atol", "1", "--angle-tol", "1",
                         "--json")
    assert code == 0, err and json.loads(out)["n_classes"] == 1
    code, out, err = run("states", str(path), "--step", "90", "--atol", "0.01", "--angle-tol",
                         "1", "--json")
    assert code == 0 and json.loads(out)["n_classes"] == 24


@needs_meshes
def test_from_mesh_says_which_units_it_assumed(tmp_path: Path) -> None:
    # issue 15: a 20 mm STL cube read at the default metres is 34.6 m across; the command says
    # what it assumed and how to read millimetres, and says nothing when told mm
    assert MESHES is not None
    stl = str(MESHES / "20mm-xyz-cube.stl")
    code, stdout, stderr = run("object", "from-mesh", stl, "-o", str(tmp_path / "m.json"))
    assert code == 0, stderr
    assert "34.64 m across" in stdout
    assert "--units mm" in stderr
    code, stdout, stderr = run("object", "from-mesh", stl, "-o", str(tmp_path / "mm.json"),
                               "--units", "mm")
    assert code == 0, stderr
    assert "34.64 mm across" in stdout
    assert "--units mm" not in stderr
    assert json.loads((tmp_path / "mm.json").read_text())["units"] == "mm"
