"""Robot arms (issue 22): the main plan on the bundled Panda, IK time, robot against free
fingertips, and a robot model from a PyPI wheel through ``--robot-xml``.

``python -m benchmarks robot`` prints:

1. the main plan (``b:200`` at (0.3, 0.1) -> ``e:110``, ``--step 90 --dataset cube``) executed
   open loop by the bundled Panda at the searched base, in one continuous simulation: per step
   the state, theta and position error, fingertip tracking error in contact, the longest time
   at a joint limit, link/rod contacts, IK time; the same plan by the free fingertips in the
   same run, and the CPU-time ratio robot / free per transition;
2. a third-party Panda from a PyPI wheel: ``dm-robotics-panda`` (Franka's Panda as MJCF with
   meshes, DeepMind's packaging) installed with ``pip install --no-deps --target DIR`` into a
   folder outside the project's environment (never committed). Its ``panda.xml`` has no
   actuators (dm_robotics adds them in code), so this script does what a user would: it loads
   the file with ``mujoco.MjSpec``, adds a joint position servo per joint (the project's Panda
   gains, the datasheet's torque limits as force ranges), a finger rod and a tip site on the
   flange body ``panda_link8``, writes the result next to the wheel's meshes, and runs the main
   plan's first step with ``simulate plan --robot-xml FILE --tip-site tip --base ...``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

WHEEL = "dm-robotics-panda==0.4.8"
MAIN = ["--from", "b:200", "--at", "0.3", "0.1", "--step", "90", "--dataset", "cube"]


def _skills() -> str:
    import nonprehensile

    return str(Path(nonprehensile.__file__).parent / "data" / "cube_skills.json")


def _cli(args: list[str]) -> tuple[int, dict]:
    res = subprocess.run([sys.executable, "-m", "nonprehensile.cli", *args, "--json"],
                         capture_output=True, text=True, check=False)
    try:
        doc = json.loads(res.stdout)
    except json.JSONDecodeError:
        print(res.stderr)
        doc = {}
    return res.returncode, doc


def main_plan() -> None:
    from nonprehensile.cli.options import state_set
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.sim import Simulator
    from nonprehensile.sim.execute import simulate_plan
    from nonprehensile.sim.placement import place_base, plan_targets
    from nonprehensile.sim.robot import Robot
    from nonprehensile.sim.robot_run import RobotSimulator
    from nonprehensile.sim.robot_scene import Arm
    from nonprehensile.states import State

    poly, skills = read_skills(_skills())
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    p = plan(poly, exp, State("b", 200), State("e", 110), position=(0.3, 0.1),
             motions=motions, scale=ds.scale)
    robot = Robot.builtin("panda")
    t0 = time.process_time()
    pl = place_base(robot, poly, ds.scale, plan_targets(p, ds.fingers))
    t_place = time.process_time() - t0
    print(f"base search: {pl.to_dict()} ({t_place:.2f} s CPU)")
    free = Simulator(poly, scale=ds.scale, n_fingers=1)
    t0 = time.process_time()
    out_free = simulate_plan(poly, p, scale=ds.scale, fingers=ds.fingers, sim=free)
    t_free = time.process_time() - t0
    sim = RobotSimulator(poly, [Arm(robot, pl.base)], scale=ds.scale)
    bounds = [0]
    t0 = time.process_time()
    out = simulate_plan(poly, p, scale=ds.scale, fingers=ds.fingers, sim=sim,
                        progress=lambda i, n: bounds.append(len(sim.robot_log.time)))
    t_robot = time.process_time() - t0
    for i, (o, f) in enumerate(zip(out, out_free, strict=True)):
        c = o.comparison.to_dict()
        m = sim.robot_log.metrics(bounds[i], bounds[i + 1]).to_dict()
        print(f"step {i + 1}: robot {c['simulated']} theta err {c['theta_error_deg']} deg, "
              f"position err {c['position_error_m']} m, success {o.success} | free "
              f"{f.comparison.to_dict()['simulated']} success {f.success}")
        print(f"   tracking in contact max {m['tracking_error_contact_max_m']} m, longest at "
              f"limit {m['longest_at_limit_s']} s, link/rod contact {m['other_contact_s']} s, "
              f"IK median {m['ik_median_ms']} ms (max {m['ik_max_ms']} ms)")
    print(f"CPU per transition: robot {t_robot / len(out):.3f} s, free fingertips "
          f"{t_free / len(out):.3f} s: ratio {t_robot / t_free:.2f}x (same run)")


def wheel_robot(folder: Path) -> Path:
    """Install the wheel outside the environment and write the user's robot file."""
    import mujoco
    import numpy as np

    site = folder / "site"
    if not (site / "dm_robotics" / "panda" / "assets" / "panda" / "panda.xml").exists():
        subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                        "--target", str(site), WHEEL], check=True)
    src = site / "dm_robotics" / "panda" / "assets" / "panda" / "panda.xml"
    spec = mujoco.MjSpec.from_file(str(src))
    kp = (4500, 4500, 3500, 3500, 2000, 2000, 2000)
    kv = (450, 450, 350, 350, 200, 200, 200)
    tau = (87, 87, 87, 87, 12, 12, 12)
    for i in range(1, 8):
        j = spec.joint(f"panda_joint{i}")
        # the file's identified joint 6 damping is negative
        j.damping = np.maximum(np.asarray(j.damping, dtype=float), 0.0)
        a = spec.add_actuator()
        a.name = f"servo{i}"
        a.target = f"panda_joint{i}"
        a.trntype = mujoco.mjtTrn.mjTRN_JOINT
        a.set_to_position(kp=kp[i - 1], kv=kv[i - 1])
        a.forcelimited = 1
        a.forcerange = [-tau[i - 1], tau[i - 1]]
        j.armature = 0.1
    flange = spec.body("panda_link8")
    rod = flange.add_geom()
    rod.name = "rod"
    rod.type = mujoco.mjtGeom.mjGEOM_CAPSULE
    rod.fromto = [0, 0, 0, 0, 0, 0.104]
    rod.size = [0.004, 0, 0]
    tip = flange.add_site()
    tip.name = "tip"
    tip.pos = [0, 0, 0.12]
    out = src.parent / "dm_panda_finger.xml"  # beside the wheel's meshes and texture
    out.write_text(spec.to_xml())
    return out


def main(plan: bool = True) -> None:
    if plan:
        main_plan()
    folder = Path("/tmp/nonprehensile-bench-robot")
    folder.mkdir(exist_ok=True)
    try:
        xml = wheel_robot(folder)
    except (subprocess.CalledProcessError, OSError, ValueError) as exc:
        print(f"PyPI robot: skipped ({exc})")
        return
    t0 = time.perf_counter()
    rc, doc = _cli(["simulate", "plan", _skills(), *MAIN, "--to", "a:290",
                    "--robot-xml", str(xml), "--tip-site", "tip"])
    wall = time.perf_counter() - t0
    rec = (doc.get("records") or [{}])[0]
    print(f"PyPI robot ({WHEEL}) first step via --robot-xml {xml}: exit {rc}, simulated "
          f"{rec.get('simulated')}, theta err {rec.get('theta_error_deg')} deg, position err "
          f"{rec.get('position_error_m')} m, success {rec.get('success')}; base "
          f"{(doc.get('placement') or {}).get('base')}; robot {rec.get('robot')} "
          f"({wall:.1f} s wall)")


if __name__ == "__main__":
    main()
