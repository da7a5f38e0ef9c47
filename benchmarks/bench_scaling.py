"""The geometric core at 100 / 1,000 / 10,000 faces, with trimesh beside it (issue 16).

The object is the convex hull of a jittered Fibonacci sphere (nearly concyclic points: nearly
coplanar neighbouring facets, the hard case for merging), written as a binary STL. Every
figure is measured in a fresh subprocess, so its peak memory (``ru_maxrss``) is its own:

* ``trimesh``: ``trimesh.load`` + ``compute_stable_poses`` (the baseline of the same run);
* ``from_mesh``: the model from the STL at default tolerances;
* ``read_model``: loading the model file it wrote (what every command does first);
* ``show``: the whole ``object show --json`` command in-process (load, A, Delta, stability,
  symmetry group);
* ``exact`` / ``paper``: expanding three rolling skills over every stable face's states
  (step 120) by the exact method and by the paper's.

Then ``from_mesh`` on a 100,000-triangle hull. Each figure is wall time, with the process's
CPU time beside it, and the load average is printed before and after: on a shared machine
the wall time of a busy run says little. Run: ``python -m benchmarks scaling``.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CHILD = r"""
import json, resource, sys, time
what, path, out = sys.argv[1], sys.argv[2], sys.argv[3]
if what == "trimesh":
    import trimesh
    t0, c0 = time.perf_counter(), time.process_time()
    mesh = trimesh.load(path)
    trimesh.poses.compute_stable_poses(mesh)
elif what == "from_mesh":
    import trimesh  # imported outside the timing, as for the baseline
    from nonprehensile.geometry import from_mesh
    from nonprehensile.io import write_model
    t0, c0 = time.perf_counter(), time.process_time()
    model = from_mesh(path)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    write_model(model, out)
elif what == "read_model":
    from nonprehensile.io import read_model
    t0, c0 = time.perf_counter(), time.process_time()
    read_model(out)
elif what == "show":
    import io, contextlib
    from click.testing import CliRunner
    from nonprehensile.cli import main
    from nonprehensile.cli import object as cli_object  # import outside the timing
    t0, c0 = time.perf_counter(), time.process_time()
    res = CliRunner().invoke(main, ["object", "show", out, "--json"])
    assert res.exit_code == 0, res.output
else:
    from benchmarks.bench_inference import _roll_skill
    from nonprehensile.inference import expand
    from nonprehensile.io import read_model
    from nonprehensile.states import State, stable_faces, states_by_step
    model = read_model(out)
    f = stable_faces(model)[0]
    skills = [_roll_skill(model, State(f, 0), k, f"roll{k}") for k in (1, 2, 3)]
    states = states_by_step(model, 120)
    t0, c0 = time.perf_counter(), time.process_time()
    expand(model, skills, states, method=what)
if what != "from_mesh":
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
print(json.dumps({"s": dt, "cpu": dc,
                  "mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def sphere_hull_stl(n_faces: int, path: Path) -> int:
    """Write the hull of a jittered Fibonacci sphere with about ``n_faces`` triangles."""
    import trimesh

    n = n_faces // 2 + 2
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = math.pi * (1 + 5**0.5) * i
    pts = np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi),
                           np.cos(phi)])
    pts += 1e-4 / math.sqrt(n) * np.random.default_rng(0).standard_normal(pts.shape)
    pts /= np.linalg.norm(pts, axis=1)[:, None]
    hull = trimesh.Trimesh(pts).convex_hull
    hull.export(path)
    return len(hull.faces)


def measure(what: str, path: Path, out: Path) -> dict[str, float]:
    repo = Path(__file__).resolve().parents[1]
    res = subprocess.run([sys.executable, "-c", CHILD, what, str(path), str(out)],
                         capture_output=True, text=True, cwd=repo, check=True)
    return dict(json.loads(res.stdout.strip().splitlines()[-1]))


def _load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    print(_load(), flush=True)
    rows: dict[int, dict[str, dict[str, float]]] = {}
    with tempfile.TemporaryDirectory() as d:
        for n in (100, 1000, 10000):
            stl, out = Path(d) / f"hull{n}.stl", Path(d) / f"hull{n}.json"
            faces = sphere_hull_stl(n, stl)
            row = {w: measure(w, stl, out) for w in
                   ("from_mesh", "read_model", "show", "exact", "paper", "trimesh")}
            rows[n] = row
            print(f"{faces:6d} faces: " + "  ".join(
                f"{w} {r['s']:.3f} s (cpu {r['cpu']:.3f}) {r['mb']:.0f} MB"
                for w, r in row.items())
                + f"  from_mesh/trimesh {row['from_mesh']['s'] / row['trimesh']['s']:.3f}",
                flush=True)
        big = rows[10000]
        ratio = big["from_mesh"]["s"] / big["trimesh"]["s"]
        print(f"bar from_mesh at 10k <= 0.5x trimesh: x{ratio:.3f}, peak "
              f"{big['from_mesh']['mb']:.0f} MB (< 400 MB)")
        print(f"bar object show at 10k < 1 s and < 400 MB: {big['show']['s']:.3f} s, "
              f"{big['show']['mb']:.0f} MB")
        for w in ("from_mesh", "read_model", "show", "exact", "paper", "trimesh"):
            bar = " (bar <= 12x)" if w in ("from_mesh", "read_model", "exact", "paper") else ""
            print(f"growth 1k -> 10k, {w}: x{rows[10000][w]['s'] / rows[1000][w]['s']:.1f} "
                  f"(cpu x{rows[10000][w]['cpu'] / rows[1000][w]['cpu']:.1f}){bar}")
        stl, out = Path(d) / "hull100k.stl", Path(d) / "hull100k.json"
        faces = sphere_hull_stl(100_000, stl)
        r = measure("from_mesh", stl, out)
        print(f"from_mesh on a {faces}-triangle hull: {r['s']:.2f} s (cpu {r['cpu']:.2f} s), "
              f"{r['mb']:.0f} MB (bar: < 2 s)")
    print(_load())


if __name__ == "__main__":
    main()
