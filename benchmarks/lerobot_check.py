"""The real LeRobot opens our exports and reads back the source's values (issue 23).

Not part of ``make bench`` or CI: LeRobot pulls torch, so it lives in its own environment.
Make one (once; see docs/benchmarks.md#lerobot-export), then run this script with the
project's Python. The newest LeRobot (0.6.1) needs Python 3.12: ``python3.12 -m venv
/tmp/lerobot06-venv && /tmp/lerobot06-venv/bin/pip install "lerobot[dataset]==0.6.1"`` (a
CUDA torch, about 5 GB). On Python 3.11, LeRobot 0.4.4 beside the torch on this disk::

    python3.11 -m venv /tmp/lerobot-venv
    /tmp/lerobot-venv/bin/pip install torch==2.14.1 torchvision==0.29.1
    /tmp/lerobot-venv/bin/pip install --no-deps lerobot==0.4.4
    /tmp/lerobot-venv/bin/pip install "datasets>=4,<5" "huggingface-hub>=0.34.2,<0.36" \\
        pandas pyarrow "av>=15,<16" jsonlines "packaging>=24.2,<26" draccus==0.10.0 pillow \\
        termcolor deepdiff einops gymnasium "imageio[ffmpeg]" "accelerate>=1.10,<2"
    .venv/bin/python benchmarks/lerobot_check.py --lerobot-python /tmp/lerobot-venv/bin/python

It exports (1) the bundled cube dataset (``dataset export cube``) and (2) a simulated
execution of the plan a:0 -> c:90, open and closed loop (``simulate plan --record``),
opens each with
``lerobot.datasets.lerobot_dataset.LeRobotDataset`` in the other environment, iterates every
frame (``ds[i]`` for every ``i``, as a training loop's sampler does), and compares what LeRobot
returns with the source, independently of our writer:

* the cube: the C3D recordings as the loader reads them (metres): fingertips and markers at
  every recorded sample (the frames a dropout left empty are compared with the filled values
  and counted apart), the task text, the skill of every frame;
* the executions (open loop, and closed loop as ``simulate plan --record`` runs by default):
  the simulator's own trace (every 10th physics step at 100 fps): the object's position and
  orientation and the fingertips, and the order of the simulator's contact events.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# runs in the LeRobot environment: open with LeRobotDataset, read every frame, dump arrays
_CHILD = r"""
import json, sys, time
import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset
root, out = sys.argv[1], sys.argv[2]
import lerobot
t0 = time.perf_counter()
ds = LeRobotDataset("local/" + root.rstrip("/").split("/")[-1], root=root)
keys = [k for k in ds.meta.features]
cols = {k: [] for k in keys}
tasks = []
for i in range(len(ds)):
    item = ds[i]
    for k in keys:
        cols[k].append(item[k].numpy())
    tasks.append(item["task"])
arrays = {k.replace(".", "__"): np.stack(v) for k, v in cols.items()}
np.savez(out, **arrays)
meta = {"n": len(ds), "num_episodes": ds.num_episodes, "fps": ds.fps, "tasks": tasks,
        "version": lerobot.__version__ if hasattr(lerobot, "__version__") else "?",
        "codebase_version": ds.meta.info["codebase_version"],
        "seconds": time.perf_counter() - t0}
json.dump(meta, open(out + ".json", "w"))
"""


def _lerobot_read(python: str, root: Path, tmp: Path) -> tuple[dict[str, np.ndarray], dict]:
    out = tmp / f"{root.name}.npz"
    script = tmp / "child.py"
    script.write_text(_CHILD)
    env = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "PATH": "/usr/bin:/bin",
           "HOME": str(tmp), "HF_HOME": str(tmp / "hf")}
    r = subprocess.run([python, str(script), str(root), str(out)], capture_output=True,
                       text=True, env=env, check=False)
    if r.returncode != 0:
        raise SystemExit(f"LeRobot could not open {root}:\n{r.stderr[-3000:]}")
    data = dict(np.load(out))
    meta = json.loads(Path(str(out) + ".json").read_text())
    return {k.replace("__", "."): v for k, v in data.items()}, meta


def check_cube(python: str, tmp: Path) -> list[str]:
    from nonprehensile.demonstrations.dataset import load_dataset
    from nonprehensile.export import export_dataset
    from nonprehensile.motion.trajectory import fill_gaps

    t0 = time.perf_counter()
    root, episodes = export_dataset("cube", tmp / "cube")
    t_export = time.perf_counter() - t0
    got, meta = _lerobot_read(python, root, tmp)
    ds = load_dataset("cube")
    info = json.loads((root / "meta/info.json").read_text())
    skills = info["features"]["skill_index"]["labels"]
    rec_err = fill_err = 0.0
    n_rec = n_fill = 0
    bad_task = bad_skill = 0
    start = 0
    for i, d in enumerate(ds.demonstrations):
        ep = episodes[i]
        n = ep.n_frames
        sl = slice(start, start + n)
        assert (got["episode_index"][sl] == i).all()
        assert (got["frame_index"][sl] == np.arange(n)).all()
        assert np.allclose(got["timestamp"][sl], np.arange(n) / 120.0, atol=1e-6)
        traj = d.trajectory.to_units("m")
        i0 = int(ep.meta["source_frame"])  # type: ignore[arg-type]
        rec = traj.positions[i0:i0 + n]
        seen = ~np.isnan(rec).any(axis=2)
        mk = got["observation.markers"][sl].reshape(n, -1, 3).astype(np.float64)
        names = list(traj.marker_names)
        tips = got["observation.state"][sl].reshape(n, -1, 3).astype(np.float64)
        for k, f in enumerate(("R1", "R2")):
            j = names.index(ds.fingers[f])
            assert np.array_equal(tips[:, k], mk[:, j])
        e = np.abs(mk - rec)
        rec_err = max(rec_err, float(e[seen].max()))
        n_rec += int(seen.sum())
        filled = fill_gaps(rec, ds.gap_limit)
        if (~seen).any():
            fill_err = max(fill_err, float(np.abs(mk - filled)[~seen].max()))
            n_fill += int((~seen).sum())
        task = f"{d.skill.name}: {d.initial} -> {d.final}"
        bad_task += sum(t != task for t in meta["tasks"][start:start + n])
        bad_skill += int((got["skill_index"][sl] != skills.index(d.skill.name)).sum())
        start += n
    ok = rec_err < 1e-6 and bad_task == 0 and bad_skill == 0 and start == meta["n"]
    return [
        f"   | bundled cube (`dataset export cube`) | {meta['num_episodes']} | {meta['n']} | "
        f"{meta['fps']} | {meta['codebase_version']} | markers and fingertips vs the C3D "
        f"recordings: max error {rec_err:.2e} m over {n_rec} recorded samples; {n_fill} "
        f"dropout samples vs the filled values: {fill_err:.2e} m; tasks wrong {bad_task}, "
        f"skill labels wrong {bad_skill} | {t_export:.1f} s / {meta['seconds']:.1f} s | "
        f"{'met' if ok else 'NOT MET'} |",
    ]


def check_plan(python: str, tmp: Path, loop: str = "open") -> list[str]:
    from importlib import resources

    from nonprehensile.export import write_episodes
    from nonprehensile.export.demonstrations import event_name
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.sim import Simulator
    from nonprehensile.sim.episodes import plan_episodes
    from nonprehensile.sim.execute import simulate_plan
    from nonprehensile.states import State, states_by_step

    skills_file = Path(str(resources.files("nonprehensile") / "data" / "cube_skills.json"))
    poly, skills = read_skills(skills_file)
    exp = expand(poly, skills, states_by_step(poly, 90.0))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    result = plan(poly, exp, State("a", 0), State("c", 90), motions=motions, scale=ds.scale)
    sim = Simulator(poly, scale=ds.scale, n_fingers=2)
    t0 = time.perf_counter()
    if loop == "open":
        outcomes = simulate_plan(poly, result, scale=ds.scale, fingers=ds.fingers, sim=sim,
                                 keep_trace=1)
        eps = plan_episodes(poly, result, outcomes, n_fingers=2, fingers=ds.fingers, fps=100)
    else:  # as `simulate plan --record` runs it by default
        from nonprehensile.control import replanner
        from nonprehensile.sim.closed_loop import execute_plan
        from nonprehensile.sim.episodes import step_episode

        ex = execute_plan(sim, result, fingers=ds.fingers, loop="closed",
                          replan=replanner(poly, exp, State("c", 90), motions=motions,
                                           scale=ds.scale), keep_trace=1)
        outcomes = [o for _, o in ex.executed]
        eps = [step_episode(poly, st, o, n_fingers=2, fingers=ds.fingers, fps=100)
               for st, o in ex.executed]
    root = write_episodes(eps, tmp / f"plan-{loop}")
    t_export = time.perf_counter() - t0
    got, meta = _lerobot_read(python, root, tmp)
    info = json.loads((root / "meta/info.json").read_text())
    ev_labels = info["features"]["event_index"]["labels"]
    pos_err = tip_err = rot_err = 0.0
    order_ok = True
    start = 0
    for out, ep in zip(outcomes, eps, strict=True):
        n = ep.n_frames
        trace = out.result.trace
        assert trace is not None
        rows = trace[::10][:n]
        sl = slice(start, start + n)
        st = got["observation.state"][sl].astype(np.float64)
        pos_err = max(pos_err, float(np.abs(st[:, :3] - rows[:, 1:4]).max()))
        q = np.column_stack([rows[:, 5:8], rows[:, 4:5]])
        rot_err = max(rot_err, float(np.abs(np.abs(np.einsum("ij,ij->i", st[:, 3:7], q))
                                            - 1).max()))
        tip_err = max(tip_err, float(np.abs(st[:, 7:] - rows[:, 8:14]).max()))
        seen = [ev_labels[i] for i in got["event_index"][sl] if i >= 0]
        sim_events = list(dict.fromkeys(event_name(poly, e.event) for e in out.result.events))
        order_ok = order_ok and list(dict.fromkeys(seen)) == sim_events
        start += n
    ok = max(pos_err, tip_err) < 1e-6 and rot_err < 1e-6 and order_ok and start == meta["n"]
    succ = sum(o.success for o in outcomes)
    return [
        f"   | simulated plan a:0 -> c:90, {loop} loop, {succ}/{len(outcomes)} "
        f"steps succeeded | {meta['num_episodes']} | {meta['n']} | {meta['fps']} | "
        f"{meta['codebase_version']} | object position {pos_err:.2e} m, fingertips "
        f"{tip_err:.2e} m, orientation 1-|q.q| {rot_err:.1e} vs the simulator's trace; "
        f"contact-event labels in the simulator's order: {order_ok} | {t_export:.1f} s / "
        f"{meta['seconds']:.1f} s | {'met' if ok else 'NOT MET'} |",
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lerobot-python", default="/tmp/lerobot-venv/bin/python",
                    help="the Python of an environment with lerobot installed")
    args = ap.parse_args(argv)
    if not Path(args.lerobot_python).exists():
        print(f"no LeRobot environment at {args.lerobot_python}: see this script's docstring",
              file=sys.stderr)
        return 2
    ver = subprocess.run([args.lerobot_python, "-c",
                          "import importlib.metadata as m; print(m.version('lerobot'), "
                          "m.version('torch'), m.version('datasets'))"],
                         capture_output=True, text=True, check=False).stdout.split()
    print(f"   LeRobot {ver[0] if ver else '?'} (torch {ver[1] if len(ver) > 1 else '?'}, "
          f"datasets {ver[2] if len(ver) > 2 else '?'}); every frame read with "
          "LeRobotDataset(...)[i]")
    print("   | export | episodes | frames read | fps | codebase | values against the source "
          "| export s / LeRobot read s | bar |")
    with tempfile.TemporaryDirectory() as tmp:
        for line in (check_cube(args.lerobot_python, Path(tmp))
                     + check_plan(args.lerobot_python, Path(tmp), "open")
                     + check_plan(args.lerobot_python, Path(tmp), "closed")):
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
