"""Big valid inputs (issue 25): a million-triangle mesh, the states of 1,000- and 2,000-sided
prisms.

Every figure is one real command (``python -m nonprehensile.cli ...``) in a fresh process:
its wall time, its CPU time and its peak memory (``ru_maxrss`` of that process alone, from
``os.wait4``). Baselines measured in the same run, on the same files:

* for ``object from-mesh``: reading the STL with trimesh and Qhull's hull of its vertices
  (``scipy.spatial.ConvexHull``), the work no model builder can skip (the 1.31-million-
  triangle sphere is refused after that work: its hull has more than
  ``MAX_HULL_TRIANGLES``; the 327,680-triangle one is built);
* for ``states``: ``states cube --step 90`` (start-up, reading a model, printing).

The inputs are made here (the project writes them: trimesh's icosphere, subdivided 8 times:
1,310,720 triangles, 64 MB of binary STL; ``nph.prism``), and the load average is printed
before and after: on a shared machine the wall time of a busy run says little.
Run: ``python -m benchmarks big_inputs``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BASELINE_HULL = r"""
import sys, numpy as np, trimesh
from scipy.spatial import ConvexHull
mesh = trimesh.load(sys.argv[1], force="mesh")
ConvexHull(np.asarray(mesh.vertices))
"""


def _run(argv: list[str]) -> tuple[float, float, float, int]:
    """Wall seconds, CPU seconds, peak RSS (MB) and exit code of one process."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    code = os.waitstatus_to_exitcode(status)
    if code != 0 and proc.stderr is not None:
        print("   ", proc.stderr.read().decode(errors="replace").strip()[-300:])
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, code


def main() -> None:
    import trimesh

    import nonprehensile as nph
    from nonprehensile.io import write_model

    cli = [sys.executable, "-m", "nonprehensile.cli"]
    print(f"   load average before: {os.getloadavg()[0]:.1f}")
    rows: list[tuple[str, tuple[float, float, float, int]]] = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        sphere = d / "sphere1m.stl"
        trimesh.creation.icosphere(subdivisions=8).export(sphere)
        sphere7 = d / "sphere327k.stl"
        trimesh.creation.icosphere(subdivisions=7).export(sphere7)
        for n in (1000, 2000):
            write_model(nph.prism(n), d / f"prism{n}.json")
        rows.append(("baseline: trimesh.load + ConvexHull, 1.31M triangles",
                     _run([sys.executable, "-c", BASELINE_HULL, str(sphere)])))
        rows.append(("object from-mesh, 1.31M triangles (64 MB STL): refused",
                     _run([*cli, "object", "from-mesh", str(sphere), "-o", str(d / "s.json")])))
        rows.append(("object from-mesh, 327,680 triangles (16 MB STL)",
                     _run([*cli, "object", "from-mesh", str(sphere7), "-o", str(d / "s.json")])))
        rows.append(("object show of that model --json",
                     _run([*cli, "object", "show", str(d / "s.json"), "--json"])))
        rows.append(("baseline: states cube --step 90", _run([*cli, "states", "cube", "--step",
                                                               "90", "--json"])))
        rows.append(("states prism1000 --step 90", _run([*cli, "states", str(d / "prism1000.json"),
                                                         "--step", "90", "--json"])))
        rows.append(("states prism2000 --step 10", _run([*cli, "states", str(d / "prism2000.json"),
                                                         "--step", "10", "--json"])))
    print(f"   {'what':58} {'wall s':>7} {'CPU s':>7} {'peak MB':>8} exit")
    for what, (wall, cpu, rss, code) in rows:
        print(f"   {what:58} {wall:7.1f} {cpu:7.1f} {rss:8.0f} {code:4d}")
    base, mesh = rows[0][1], rows[1][1]
    print(f"   refusing the 1.31M sphere / baseline: {mesh[1] / base[1]:.2f}x CPU, "
          f"{mesh[2] / base[2]:.2f}x memory")
    base, s1, s2 = rows[4][1], rows[5][1], rows[6][1]
    print(f"   states / baseline CPU: prism1000 step 90 {s1[1] / base[1]:.1f}x, "
          f"prism2000 step 10 {s2[1] / base[1]:.1f}x")
    print(f"   load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
