"""The user's path: start-up, a second ``plan --dataset``, a large model's figure, the report's
figures, and the main job quiet and on a machine this benchmark loads itself (issues 15, 16).

Every command runs as a real process; CPU time is the child's user + system time. The loaded
runs start one busy process per core first (``os.cpu_count()``, each in a session of its own),
so "under load" means both cores busy with other work whatever else the machine does.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "nonprehensile.cli"]
SKILLS = str(ROOT / "examples" / "cube_skills.json")
ICO = Path(os.environ.get("NONPREHENSILE_SHARED") or ROOT.parent / "shared") / (
    "realdata/meshes/ico4.obj")


def run(args: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """(wall, cpu) seconds of one process."""
    before = os.times()
    t0 = time.perf_counter()
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                   env=env)
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = (after.children_user - before.children_user) + (
        after.children_system - before.children_system)
    return wall, cpu


def median_of(n: int, args: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    runs = [run(args, env) for _ in range(n)]
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)


REPORT_CPU = """
import sys, time
import nonprehensile.pipeline as pl
import matplotlib.figure, mpl_toolkits.mplot3d  # imports are counted apart
import nonprehensile.sim.execute as ex
spent = {{"sim": 0.0}}
step = ex.simulate_step
def timed_step(*a, **k):
    t = time.process_time()
    try:
        return step(*a, **k)
    finally:
        spent["sim"] += time.process_time() - t
ex.simulate_step = timed_step
import nonprehensile.viz.demo_report as dr  # the report's composition (issue 24 layout)
orig = dr.write_demo_report
def timed(*a, **k):
    t = time.process_time()
    r = orig(*a, **k)
    spent["report"] = time.process_time() - t
    return r
dr.write_demo_report = timed
pl.run_demo({out!r})
print("REPORT_CPU", spent["report"], spent["sim"])
print("HEAVY", ",".join(m for m in ("sklearn", "pandas", "scipy.stats") if m in sys.modules))
"""


def loadavg() -> str:
    return " / ".join(f"{v:.1f}" for v in os.getloadavg())


def main() -> None:
    print(f"load average (1 / 5 / 15 min) at the start: {loadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "NONPREHENSILE_CACHE": str(Path(tmp) / "cache")}
        for what in (["--version"], ["--help"]):
            wall, cpu = median_of(5, [*CLI, *what])
            print(f"nonprehensile {what[0]}: wall {wall:.3f} s, cpu {cpu:.3f} s (median of 5)")
        plan = [*CLI, "plan", SKILLS, "--from", "b:200", "--to", "e:110", "--step", "90",
                "--dataset", "cube", "--json"]
        wall, cpu = run(plan, env)
        print(f"plan --dataset cube, first (builds the library): wall {wall:.2f} s, "
              f"cpu {cpu:.2f} s")
        wall, cpu = median_of(3, plan, env)
        print(f"plan --dataset cube, again (cached library): wall {wall:.2f} s, "
              f"cpu {cpu:.2f} s (median of 3)")
        if ICO.is_file():
            model = str(Path(tmp) / "ico4.json")
            run([*CLI, "object", "from-mesh", str(ICO), "-o", model])
            wall, cpu = run([*CLI, "object", "figure", model, "-o", str(Path(tmp) / "i.png")])
            print(f"object figure, 1280-face ico4: wall {wall:.2f} s, cpu {cpu:.2f} s")
        proc = subprocess.run(
            [sys.executable, "-c", REPORT_CPU.format(out=str(Path(tmp) / "r"))],
            check=True, capture_output=True, text=True,
            env={**env, "NONPREHENSILE_CACHE": str(Path(tmp) / "cache-r")})
        report, sim = (float(v) for v in proc.stdout.split("REPORT_CPU")[1].split()[:2])
        heavy = proc.stdout.split("HEAVY")[1].split("\n")[0].strip()
        print(f"report stage of demo (every figure and table, and the physics section's "
              f"MuJoCo run): cpu {report:.2f} s; figures and tables without the simulation: "
              f"{report - sim:.2f} s (bar: < 1 s); simulation {sim:.2f} s")
        print(f"heavy modules the demo imported that it does not use: {heavy or 'none'}")
        # the demo as a user runs it: a fresh cache each time (cold), quiet and with every
        # core busy, interleaved so that a change in the machine's own load hits both alike
        quiet: list[tuple[float, float]] = []
        loaded: list[tuple[float, float]] = []
        for i in range(3):
            cold = {**os.environ, "NONPREHENSILE_CACHE": str(Path(tmp) / f"cold{i}")}
            demo = [*CLI, "demo", "--out", str(Path(tmp) / f"demo{i}"), "--json"]
            quiet.append(run(demo, cold))
            # each busy loop in a session of its own, as other work would be: with the
            # kernel's autogroup scheduling (Linux's default) loops started in the demo's
            # session share that session's CPU with it, so on a machine that others already
            # load the demo would get a third of its session's share whatever it does
            hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"],
                                     start_new_session=True)
                    for _ in range(os.cpu_count() or 2)]
            try:
                time.sleep(0.5)
                cold = {**cold, "NONPREHENSILE_CACHE": str(Path(tmp) / f"cold-loaded{i}")}
                loaded.append(run(demo, cold))
            finally:
                for h in hogs:
                    h.kill()
                    h.wait()
        warm = run([*CLI, "demo", "--out", str(Path(tmp) / "demo-warm"), "--json"],
                   {**os.environ, "NONPREHENSILE_CACHE": str(Path(tmp) / "cold0")})
        qw, qc = (statistics.median(r[k] for r in quiet) for k in (0, 1))
        lw, lc = (statistics.median(r[k] for r in loaded) for k in (0, 1))
        print(f"demo, fresh cache, quiet: wall {qw:.1f} s, cpu {qc:.2f} s (median of 3; "
              f"bar: cpu <= 4 s)")
        print(f"demo, fresh cache, both cores busy: wall {lw:.1f} s, cpu {lc:.2f} s "
              f"(median of 3); loaded / quiet wall = {lw / qw:.2f} (bar: <= 2)")
        print(f"demo, second run (its cache kept): wall {warm[0]:.1f} s, cpu {warm[1]:.2f} s")
        print(f"load average at the end: {loadavg()}")


if __name__ == "__main__":
    main()
