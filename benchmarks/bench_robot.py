"""Robot arms (issue 22): the main plan on the bundled Panda, IK time, robot against free
fingertips, and a robot model from a PyPI wheel through ``--robot-xml``.

``python -m benchmarks robot`` prints:

1. the main plan (``b:200`` at (0.3, 0.1) -> ``e:110``, ``--step 90 --dataset cube``) executed
   by the closed-loop executor (transits included) and open loop, by the bundled Panda at the
   searched base, in one continuous simulation: per step the state, theta and position error,
   fingertip tracking error in contact, the longest time at a joint limit, link/rod contacts,
   IK time; the same plan by the free fingertips in the same run, and the CPU ratio robot /
   free;
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
    from dataclasses import replace

    from nonprehensile.cli.options import state_set
    from nonprehensile.control import ControlConfig, replanner
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.sim import Simulator
    from nonprehensile.sim.closed_loop import execute_plan
    from nonprehensile.sim.placement import place_base, plan_targets
    from nonprehensile.sim.robot import Robot
    from nonprehensile.sim.robot_run import ROBOT_MAX_ACCEL, RobotSimulator
    from nonprehensile.sim.robot_scene import Arm
    from nonprehensile.states import State

    poly, skills = read_skills(_skills())
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    goal = State("e", 110)
    p = plan(poly, exp, State("b", 200), goal, position=(0.3, 0.1), motions=motions,
             scale=ds.scale)
    replan = replanner(poly, exp, goal, motions=motions, scale=ds.scale)
    robot = Robot.builtin("panda")
    t0 = time.process_time()
    pl = place_base(robot, poly, ds.scale, plan_targets(p, ds.fingers))
    t_place = time.process_time() - t0
    print(f"base search: {pl.to_dict()} ({t_place:.2f} s CPU)")
    bases = [("searched", pl.base)]
    for loop in ("closed", "open"):
        free = Simulator(poly, scale=ds.scale, n_fingers=1)
        t0 = time.process_time()
        exf = execute_plan(free, p, fingers=ds.fingers, loop=loop, replan=replan)
        t_free = time.process_time() - t0
        nf = max(1, exf.n_steps)
        print(f"{loop} loop, free fingertips: success {exf.success}, final "
              f"{exf.to_dict()['final_state']}, {1000 * (exf.position_error or 0):.1f} mm; "
              f"{t_free:.3f} s CPU for {exf.sim_time:.2f} s simulated ({nf} physics steps)")
        for (label, base), every in ((b, e) for b in bases for e in (1, 8)):
            sim = RobotSimulator(poly, [Arm(robot, base)], scale=ds.scale, control_every=every)
            cfg = replace(ControlConfig(), max_accel=ROBOT_MAX_ACCEL)
            t0 = time.process_time()
            ex = execute_plan(sim, p, fingers=ds.fingers, loop=loop, replan=replan, config=cfg)
            t_robot = time.process_time() - t0
            log = sim.robot_log
            print(f"{loop} loop, Panda (IK at {1000 // every} Hz) at the {label} base "
                  f"{base.to_dict()}: success "
                  f"{ex.success}, final {ex.to_dict()['final_state']}, "
                  f"{1000 * (ex.position_error or 0):.1f} mm from the goal; {t_robot:.3f} s CPU "
                  f"for {ex.sim_time:.2f} s simulated")
            for (n, a, b), rec in zip(ex.step_traces, ex.steps, strict=False):
                m = log.metrics(*log.window(a, b)).to_dict()
                print(f"   step {n} {rec['skill']}: {rec['simulated']}, theta err "
                      f"{rec['theta_error_deg']} deg, {1000 * rec['position_error_m']:.1f} mm; "
                      f"tracking in contact max {m['tracking_error_contact_max_m']} m, "
                      f"longest at limit {m['longest_at_limit_s']} s, link/rod contact "
                      f"{m['other_contact_s']} s, IK median {m['ik_median_ms']} ms")
            m = log.metrics().to_dict()
            print(f"   whole run: {m}")
            # per transition: CPU per simulated second, the robot against the free fingertips
            rate_r = t_robot / ex.sim_time
            rate_f = t_free / exf.sim_time
            print(f"   CPU per simulated second: robot {rate_r:.3f}, free {rate_f:.3f}: "
                  f"{rate_r / rate_f:.2f}x; per executed step: robot "
                  f"{t_robot / max(1, len(ex.steps)):.3f} s, free "
                  f"{t_free / max(1, len(exf.steps)):.3f} s: "
                  f"{(t_robot / max(1, len(ex.steps))) / (t_free / max(1, len(exf.steps))):.2f}x")


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
