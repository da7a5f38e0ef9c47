"""Every real mesh of ``../shared/realdata/meshes`` through the command line, checked by trimesh.

For each mesh file: ``object from-mesh`` (in-process CLI), then ``object show --json`` and
``states --step 90 --json`` on the model it wrote. A mesh that describes one solid body (one
connected piece, after welding, whose hull has volume) must pass all three, and its stable
faces must agree with ``trimesh.poses.compute_stable_poses`` run on the mesh's convex hull with
the model's centre of mass: every stable pose trimesh finds rests on a stable face of the
model with the same outward normal (within 1e-3 rad; trimesh merges nearly coplanar facets by
its own tolerance, so one pose may stand for several of our faces) or on a triangle of
trimesh's hull lying in a stable face of the model (a face planar within the model's
tolerance can tilt a thin triangle of another triangulation of it by more than the angle),
and every stable face of the model is such a pose. Faces whose stability margin is within
ten times the model's tolerance, or within what the tilt of trimesh's triangles of the face
moves the centre of mass's projection, are reported apart as marginal: there a rounding
decides.

Run: ``python -m benchmarks meshes`` (the table in docs/meshes.md is its output).
"""

from __future__ import annotations

import io
import json
import sys
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

import numpy as np


def _shared() -> Path:
    """``shared/`` beside the repository (CI), or beside a folder above it (worktrees)."""
    repo = Path(__file__).resolve().parents[1]
    for folder in repo.parents:
        if (folder / "shared" / "realdata").is_dir():
            return folder / "shared"
    return repo.parent / "shared"


ROOT = _shared() / "realdata" / "meshes"
#: Largest angle (radians) between the normals of a model face and a trimesh pose's face.
ANGLE = 1e-3
SKIP_SUFFIXES = {".mtl", ".bin", ".jpg", ".png"}


def run_cli(*args: str) -> tuple[int, str, str]:
    from click.testing import CliRunner

    from nonprehensile.cli import main

    res = CliRunner().invoke(main, list(args), catch_exceptions=True)
    code = res.exit_code
    return code, res.stdout, res.stderr if res.stderr_bytes is not None else ""


def single_solid(path: Path) -> tuple[bool, str]:
    """Whether trimesh sees one connected piece (after welding) whose hull has volume."""
    import trimesh

    try:
        with redirect_stderr(io.StringIO()):
            mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # any unreadable file is not a solid
        return False, f"unreadable: {str(exc).splitlines()[0][:40] if str(exc) else exc}"
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        return False, "no triangles"
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    pieces = int(mesh.body_count)
    if pieces != 1:
        return False, f"{pieces} pieces"
    try:
        vol = float(mesh.convex_hull.volume)
    except Exception:  # trimesh's hull of a degenerate mesh raises
        vol = 0.0
    if not vol > 0:
        return False, "flat"
    return True, "closed" if mesh.is_watertight else "open"


def trimesh_stable_poses(model: Any) -> tuple[list[np.ndarray], list[int], Any]:
    """Outward normals (object frame) of the faces trimesh's stable poses rest on, for each
    the hull triangle it rests on, and that hull (trimesh's own hull of the model's vertices,
    which keeps their numbering)."""
    import trimesh

    hull = trimesh.Trimesh(model.vertices, _triangles(model), process=True).convex_hull
    transforms, probs = trimesh.poses.compute_stable_poses(hull, center_mass=model.com)
    normals, triangles = [], []
    for t, pr in zip(transforms, probs, strict=True):
        if pr <= 0:
            continue
        n = t[:3, :3].T @ np.array([0.0, 0.0, -1.0])
        normals.append(n)
        triangles.append(int(np.argmax(hull.face_normals @ n)))
    return normals, triangles, hull


def _triangles(model: Any) -> np.ndarray:
    tri = []
    for loop in model.faces.values():
        for k in range(1, len(loop) - 1):
            tri.append([loop[0], loop[k], loop[k + 1]])
    return np.array(tri)


def compare(model: Any) -> tuple[int, int, int, int]:
    """(agree, only_ours, only_trimesh, marginal) counts of stable faces.

    A trimesh pose stands for the model's faces within :data:`ANGLE` of its normal, and for
    the face its hull triangle lies in: a face planar within the model's tolerance may tilt
    a thin triangle of trimesh's triangulation of it by more than the angle. Marginal: a
    face whose stability margin is within ten times the tolerance, or within what that tilt
    moves the centre of mass's projection (its height above the face times the tilt), where
    trimesh's triangles and our face may rightly disagree."""
    from nonprehensile.states import stability_margin

    names = list(model.faces)
    position = {f: i for i, f in enumerate(names)}
    normals = np.array([model.normals[f] for f in names])
    margin = np.array([stability_margin(model, f) for f in names])
    normals_t, pose_triangles, hull = trimesh_stable_poses(model)
    # the face of the model holding each triangle of trimesh's hull (-1: none), and the tilt
    face_of = np.full(len(hull.faces), -1)
    loops = {f: frozenset(loop) for f, loop in model.faces.items()}
    for t, tri in enumerate(hull.faces.tolist()):
        for f in model.vertex_faces[tri[0]]:
            if set(tri) <= loops[f]:
                face_of[t] = position[f]
                break
    tilt = np.zeros(len(names))
    inside = face_of >= 0
    cos_t = np.einsum("ij,ij->i", hull.face_normals[inside], normals[face_of[inside]])
    np.maximum.at(tilt, face_of[inside], np.arccos(np.clip(cos_t, -1.0, 1.0)))
    anchors = model.vertices[[model.faces[f][0] for f in names]]
    height = np.einsum("ij,ij->i", anchors - model.com, normals)
    ours = margin > model.atol
    marginal = np.abs(margin) <= 10 * model.atol + height * np.tan(tilt)
    matched = np.zeros(len(names), dtype=bool)
    only_theirs = 0
    for n, t in zip(normals_t, pose_triangles, strict=True):
        # trimesh merges facets by its own tolerance: a pose may stand for several of our
        # nearly coplanar faces, all within the angle
        near = normals @ n > np.cos(ANGLE)
        if face_of[t] >= 0:
            near[face_of[t]] = True
        matched |= near
        if not np.any(near & (ours | marginal)):
            only_theirs += 1
    agree = int(np.sum(ours & matched))
    only_ours = int(np.sum(ours & ~matched & ~marginal))
    return agree, only_ours, only_theirs, int(np.sum(marginal & ours & ~matched))


def check(path: Path, tmp: Path, *, light_others: bool = False) -> dict[str, Any]:
    """One mesh through the commands; with ``light_others``, a file that is not one solid
    only has to become a model that ``object show`` loads (or get exit 2)."""
    from nonprehensile.io import read_model

    solid, kind = single_solid(path)
    row: dict[str, Any] = {"mesh": path.name, "solid": solid, "kind": kind}
    out = tmp / (path.stem + ".json")
    t0 = time.perf_counter()
    code, _, err = run_cli("object", "from-mesh", str(path), "-o", str(out))
    row["from_mesh_s"] = time.perf_counter() - t0
    row["from_mesh"] = code
    row["message"] = err.strip().splitlines()[-1] if err.strip() else ""
    if code != 0:
        row["ok"] = not solid and code == 2
        return row
    code_show, show, _ = run_cli("object", "show", str(out), "--json")
    model = read_model(out)
    row["faces"] = len(model.faces)
    row["rtol"] = model.rtol
    if light_others and not solid:
        row.update(show=code_show, states="-", agree=0, only_ours=0, only_trimesh=0,
                   marginal=0, stable="-", ok=code_show == 0)
        return row
    code_states, _, _ = run_cli("states", str(out), "--step", "90", "--json")
    row["show"], row["states"] = code_show, code_states
    if code_show == 0:
        row["stable"] = sum(f["stable"] for f in json.loads(show)["faces"].values())
    agree, only_ours, only_theirs, marginal = compare(model)
    row.update(agree=agree, only_ours=only_ours, only_trimesh=only_theirs, marginal=marginal)
    row["ok"] = code_show == 0 and code_states == 0 and only_ours == 0 and only_theirs == 0
    return row


def main() -> None:
    import tempfile

    if not ROOT.is_dir():
        print(f"skipped: {ROOT} is absent")
        return
    files = sorted(p for p in ROOT.iterdir() if p.suffix.lower() not in SKIP_SUFFIXES)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for path in files:
            with redirect_stderr(io.StringIO()), redirect_stdout(io.StringIO()):
                row = check(path, Path(d))
            rows.append(row)
            print(_fmt(row), flush=True)
    solids = [r for r in rows if r["solid"]]
    passed = [r for r in solids if r["ok"]]
    others_ok = [r for r in rows if not r["solid"] and r["ok"]]
    print(f"single solids passing: {len(passed)} of {len(solids)}; other files handled "
          f"(model or one clear exit-2 line): {len(others_ok)} of {len(rows) - len(solids)}")


def _fmt(r: dict[str, Any]) -> str:
    if r["from_mesh"] != 0:
        return (f"| {r['mesh']} | {'yes' if r['solid'] else 'no'} ({r['kind']}) | exit "
                f"{r['from_mesh']}: {r['message'][:90]} | | | | {'ok' if r['ok'] else 'FAIL'} |")
    return (f"| {r['mesh']} | {'yes' if r['solid'] else 'no'} ({r['kind']}) | {r['faces']} "
            f"faces, rtol {r['rtol']:g}, {r['from_mesh_s']:.2f} s | {r['show']}/{r['states']} | "
            f"{r['agree']} (+{r['only_ours']} ours, +{r['only_trimesh']} trimesh, "
            f"{r['marginal']} marginal) | {r['stable']} | {'ok' if r['ok'] else 'FAIL'} |")


if __name__ == "__main__":
    sys.exit(main())
