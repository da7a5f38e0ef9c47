"""Meshes shipped in robot-simulator packages on PyPI, through the command line, checked by trimesh.

The packages (fixed versions, fetched once with ``pip download --no-deps`` into a cache) and
the licences of their assets:

* ``pybullet`` 3.2.7: ``pybullet_data`` (zlib licence of Bullet; the 1,000 procedurally made
  objects of ``random_urdfs``, robots, toys, furniture);
* ``robosuite`` 1.5.2 (MIT): robots, grippers, manipulation objects;
* ``dm-control`` 1.0.50 (Apache 2.0): the dog's bones, the fruit fly, a Kinova arm;
* ``gymnasium-robotics`` 1.4.2 (MIT): Fetch, the Shadow hand, the Adroit hand, a kitchen.

Every STL, OBJ, PLY and OFF file in their wheels (read as zip files, never installed or
imported; files with the same bytes counted once) goes through the checks of
``bench_meshes``: ``object from-mesh`` at the defaults, ``object show --json``, ``states
--step 90 --json``, and the stable faces against ``trimesh.poses.compute_stable_poses`` on
the hull with the model's centre of mass, for every single solid; a file of several pieces
(most of ``random_urdfs``) or a flat one only has to become a model that ``object show``
loads, or get one clear exit-2 line. Nothing of these packages is committed here.

Cache: ``$NONPREHENSILE_MESH_CACHE`` or ``~/.cache/nonprehensile/simmeshes`` (340 MB of
wheels, 570 MB of meshes). Set ``NONPREHENSILE_SIMMESHES=N`` to check every N-th file only
(default 1: all of them) and ``NONPREHENSILE_SIMMESHES_JOBS`` for the worker processes
(default 2). Run: ``python -m benchmarks simmeshes`` (about 13 CPU minutes).
"""

from __future__ import annotations

import hashlib
import io
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
import zipfile
from collections import Counter
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

PACKAGES = (
    ("pybullet", "3.2.7"),
    ("robosuite", "1.5.2"),
    ("dm-control", "1.0.50"),
    ("gymnasium-robotics", "1.4.2"),
)
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off")


def cache_dir() -> Path:
    """Where wheels and extracted meshes are kept between runs."""
    env = os.environ.get("NONPREHENSILE_MESH_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "nonprehensile" / "simmeshes"


def fetch(cache: Path) -> list[Path]:
    """Download the wheels (once) and extract their mesh files (once); the unique files, in
    a stable order."""
    wheels = cache / "wheels"
    wheels.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    seen: set[str] = set()
    for name, version in PACKAGES:
        stem = name.replace("-", "_")
        found = sorted(wheels.glob(f"{stem}-{version}-*.whl"))
        if not found:
            subprocess.run(
                [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary", ":all:",
                 "--dest", str(wheels), f"{name}=={version}"],
                check=True, capture_output=True,
            )
            found = sorted(wheels.glob(f"{stem}-{version}-*.whl"))
        out = cache / "meshes" / stem
        with zipfile.ZipFile(found[0]) as z:
            for info in sorted(z.infolist(), key=lambda i: i.filename):
                if not info.filename.lower().endswith(MESH_SUFFIXES):
                    continue
                target = out / info.filename
                if not target.is_file():
                    target.parent.mkdir(parents=True, exist_ok=True)
                    target.write_bytes(z.read(info))
                digest = hashlib.sha1(target.read_bytes()).hexdigest()
                if digest not in seen:
                    seen.add(digest)
                    files.append(target)
    return files


def _check_one(args: tuple[str, str]) -> dict[str, Any]:
    """The checks of ``bench_meshes`` on one file (in a worker process)."""
    from benchmarks.bench_meshes import check

    path, root = Path(args[0]), Path(args[1])
    with tempfile.TemporaryDirectory() as d:
        try:
            with redirect_stderr(io.StringIO()), redirect_stdout(io.StringIO()):
                row = check(path, Path(d), light_others=True)
        except Exception as exc:  # a crash of the checks themselves is a failure too
            row = {"mesh": path.name, "solid": True, "kind": "crash", "from_mesh": 1,
                   "message": f"{type(exc).__name__}: {exc}", "ok": False}
    row["package"] = path.relative_to(root).parts[0]
    row["where"] = str(path.relative_to(root))
    return row


def main() -> None:
    from benchmarks.bench_meshes import _fmt

    cache = cache_dir()
    try:
        files = fetch(cache)
    except (subprocess.CalledProcessError, OSError) as exc:
        print(f"skipped: cannot fetch the simulator packages into {cache}: {exc}")
        return
    step = max(1, int(os.environ.get("NONPREHENSILE_SIMMESHES", "1")))
    jobs = max(1, int(os.environ.get("NONPREHENSILE_SIMMESHES_JOBS",
                                      str(min(2, os.cpu_count() or 1)))))
    files = files[::step]
    print(f"{len(files)} mesh files (every {step}, {jobs} processes) from "
          + ", ".join(f"{n} {v}" for n, v in PACKAGES)
          + f"; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    work = [(str(f), str(cache / "meshes")) for f in files]
    with multiprocessing.get_context("spawn").Pool(jobs) as pool:
        for row in pool.imap(_check_one, work, chunksize=4):
            rows.append(row)
            if len(rows) % 200 == 0:
                print(f"  {len(rows)} files, {sum(not r['ok'] for r in rows)} failing so far",
                      flush=True)
            if not row["ok"]:
                print(f"FAIL {row['where']}: " + _fmt(row), flush=True)
    # CPU of the workers (reaped when the pool closed): what the run cost, whatever the load
    cpu = sum(os.times()[2:4])
    print(f"checked in {time.perf_counter() - t0:.0f} s (cpu of the workers {cpu:.0f} s)")
    print("| package | files | single solids | solids passing | other files | others "
          "handled |")
    print("| --- | --- | --- | --- | --- | --- |")
    for pkg in sorted({r["package"] for r in rows}):
        mine = [r for r in rows if r["package"] == pkg]
        solids = [r for r in mine if r["solid"]]
        others = [r for r in mine if not r["solid"]]
        print(f"| {pkg} | {len(mine)} | {len(solids)} | {sum(r['ok'] for r in solids)} | "
              f"{len(others)} | {sum(r['ok'] for r in others)} |")
    solids = [r for r in rows if r["solid"]]
    kinds = Counter("several pieces" if r["kind"].endswith("pieces") else r["kind"]
                    for r in rows if not r["solid"])
    print(f"single solids passing: {sum(r['ok'] for r in solids)} of {len(solids)}; other "
          f"files handled (model or one clear exit-2 line): "
          f"{sum(r['ok'] for r in rows if not r['solid'])} of {len(rows) - len(solids)} "
          f"({', '.join(f'{k}: {n}' for k, n in kinds.most_common(6))})")
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
