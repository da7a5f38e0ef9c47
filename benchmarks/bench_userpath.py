"""The user's path: start-up, a second ``plan --dataset``, a large model's figure, the report's
figures, and the main job quiet and on a machine this benchmark loads itself (issues 15, 16).

Every command runs as a real process; CPU time is the child's user + system time. The loaded
run starts one busy process per core first (``os.cpu_count()``), so "under load" means both
cores busy with other work whatever else the machine does.
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
import time, nonprehensile.pipeline as pl
import matplotlib.figure, mpl_toolkits.mplot3d  # imports are counted apart
orig = pl._write_report
def timed(*a, **k):
    t = time.process_time()
    r = orig(*a, **k)
    print("REPORT_CPU", time.process_time() - t)
    return r
pl._write_report = timed
pl.run_demo({out!r})
"""


def main() -> None:
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
        proc = subprocess.run([sys.executable, "-c", REPORT_CPU.format(out=str(Path(tmp) / "r"))],
                              check=True, capture_output=True, text=True)
        report = float(proc.stdout.split("REPORT_CPU")[1].split()[0])
        print(f"report figures and tables (demo's report stage): cpu {report:.2f} s")
        demo = [*CLI, "demo", "--out", str(Path(tmp) / "demo"), "--json"]
        quiet_wall, quiet_cpu = run(demo)
        print(f"demo, quiet: wall {quiet_wall:.1f} s, cpu {quiet_cpu:.1f} s")
        hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                for _ in range(os.cpu_count() or 2)]
        try:
            time.sleep(0.5)
            loaded_wall, loaded_cpu = run(demo)
        finally:
            for h in hogs:
                h.kill()
                h.wait()
        print(f"demo, both cores busy: wall {loaded_wall:.1f} s, cpu {loaded_cpu:.1f} s; "
              f"loaded / quiet wall = {loaded_wall / quiet_wall:.2f} (bar: <= 2)")


if __name__ == "__main__":
    main()
