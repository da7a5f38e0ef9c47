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
   plan's first step with ``simulate plan --robot-xml FILE --tip-site tip --base ...``;
3. ``sweep``: the main plan on the bundled Panda, closed loop (transits, re-plans), one
   continuous simulation per sample, over ``NP_ROBOT_SAMPLES`` (100) samples of the
   closed-loop issue's distribution (``DEFAULT_DISTRIBUTION``: friction, mass, fingertip
   radius, contact softness, start error, tracker and fingertip noise; the free fingertips'
   stiffness and force limit do not apply to an arm), ``simulate robustness --robot panda``'s
   library path: the rate with its 95 % interval, the failures' reasons, the robot's worst
   tracking error in contact, time at a limit and link contact, and the runs within 3 mm of
   tracking in contact by the sample's fingertip radius (1 mm bins);
4. ``transitions``: every cube transition at nominal physics (one sample, no perturbation),
   closed loop with re-plans: the single-finger ones by one Panda (placed once for all of
   them), the two-finger ones by two Pandas; the rates per group and per source skill.

5. ``cost``: every single-finger cube transition at nominal physics, closed loop, executed by
   one Panda and by the free fingertip alternately in this process: the CPU of each, the
   ratio of the sums ("a robot-executed transition <= 3x the free-fingertip one" over every
   transition one arm runs, beside the main plan's in part 1).

``NP_PARTS`` picks parts (default ``plan,wheel``; ``sweep`` and ``transitions`` are long:
``NP_PARTS=sweep NP_ROBOT_SAMPLES=100 NP_WORKERS=2 nice python -m benchmarks robot``);
``NP_ROBOT_UNITS=K`` runs every K-th transition only (development); ``NP_ROBOT_ARMS=1`` or
``2`` runs one group of ``transitions`` only; ``NP_ROBOT_COMPLIANCE=1`` gives the arms the
force-limited finger command (each sample's stiffness and force limit, docs/robot.md) in
``sweep``, ``transitions`` and ``plan``. ``NP_ROBOT_FINGER_DIRECTION=recorded`` points the
finger tools along the recorded fingers (docs/robot.md) in every part.
The contact force is fed forward to one stiff arm's servos by default
(``RobotSimulator(force_feedforward="auto")``, docs/robot.md); ``NP_ROBOT_FORCE_FF=0``
turns it off (``=1`` asks for it) in the ``plan``, ``sweep``, ``cost`` and one-arm
``transitions`` runs (the ``wheel`` part's user robot keeps the default).
``NP_ROBOT_RADIUS_OFFSET=0`` turns the fingertip radius offset (on with one fingertip by
default, ``RobotSimulator(radius_offset="auto")``) off, ``=1`` on, in every part but
``wheel``.
``NP_ROBOT_REPEAT=R`` (default 1) executes the main
plan ``R`` times by each driver in ``plan`` and prints the median CPU of each (the same plan
from the same start: the records are those of the last execution; on a shared machine one
execution's CPU time moves by a third).
"""

from __future__ import annotations

import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

WHEEL = "dm-robotics-panda==0.4.8"
PARTS = os.environ.get("NP_PARTS", "plan,wheel").split(",")
SAMPLES = int(os.environ.get("NP_ROBOT_SAMPLES", "100"))
WORKERS = int(os.environ.get("NP_WORKERS", "2"))
SEED = int(os.environ.get("NP_SEED", "0"))
EVERY_UNIT = int(os.environ.get("NP_ROBOT_UNITS", "1"))
ARMS = [int(a) for a in os.environ.get("NP_ROBOT_ARMS", "1,2").split(",")]
REPEAT = max(1, int(os.environ.get("NP_ROBOT_REPEAT", "1")))
COMPLIANCE = os.environ.get("NP_ROBOT_COMPLIANCE", "0") == "1"
# the contact-consistent command's bound in mm ("off": none; unset: the default), and
# whether the contact correction may press past it (NP_ROBOT_PRESS_CORRECTION=0: no)
_PRESS = os.environ.get("NP_ROBOT_PRESS")
# the robots' options from the environment (the press bound, its correction, the finger's
# direction), passed to every part's RobotSimulator / SweepRobot
ROBOT_KW: dict = ({} if _PRESS is None else
                  {"press_depth": None if _PRESS == "off" else float(_PRESS) / 1000.0})
if "NP_ROBOT_PRESS_CORRECTION" in os.environ:
    ROBOT_KW["press_correction"] = os.environ["NP_ROBOT_PRESS_CORRECTION"] == "1"
# how the finger tools point in a step ("lean", the default, or "recorded": the knuckles)
if "NP_ROBOT_FINGER_DIRECTION" in os.environ:
    ROBOT_KW["finger_direction"] = os.environ["NP_ROBOT_FINGER_DIRECTION"]
# the stiff arm's contact force feed-forward (NP_ROBOT_FORCE_FF=1: on, 0: off; by default
# "auto": on with one stiff arm's fingertip)
if os.environ.get("NP_ROBOT_FORCE_FF") == "1":
    if COMPLIANCE:
        raise SystemExit("NP_ROBOT_FORCE_FF=1 goes with the stiff arm's force cap: drop it, "
                         "or NP_ROBOT_COMPLIANCE=1")
    ROBOT_KW["force_feedforward"] = True
elif os.environ.get("NP_ROBOT_FORCE_FF") == "0":
    ROBOT_KW["force_feedforward"] = False
# the fingertip radius offset (NP_ROBOT_RADIUS_OFFSET=1: on, 0: off; by default "auto": on
# with one fingertip)
if os.environ.get("NP_ROBOT_RADIUS_OFFSET") in ("0", "1"):
    ROBOT_KW["radius_offset"] = os.environ["NP_ROBOT_RADIUS_OFFSET"] == "1"
MAIN = ["--from", "b:200", "--at", "0.3", "0.1", "--step", "90", "--dataset", "cube"]


def _compliance(n_fingers: int) -> str:
    """The force-limited finger command's state, as printed (the same for any arms)."""
    del n_fingers
    return "on" if COMPLIANCE else "off (the default)"


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
    from nonprehensile.control import replanner
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.sim import Simulator
    from nonprehensile.sim.closed_loop import execute_plan
    from nonprehensile.sim.placement import place_base, plan_targets
    from nonprehensile.sim.robot import Robot
    from nonprehensile.sim.robot_driver import DEFAULT_CONTROL_EVERY
    from nonprehensile.sim.robot_run import RobotSimulator, robot_control
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
        times = []
        for _ in range(REPEAT):
            t0 = time.process_time()
            exf = execute_plan(free, p, fingers=ds.fingers, loop=loop, replan=replan)
            times.append(time.process_time() - t0)
        t_free = statistics.median(times)
        nf = max(1, exf.n_steps)
        print(f"{loop} loop, free fingertips: success {exf.success}, final "
              f"{exf.to_dict()['final_state']}, {1000 * (exf.position_error or 0):.1f} mm; "
              f"{t_free:.3f} s CPU for {exf.sim_time:.2f} s simulated ({nf} physics steps)")
        for (label, base), every in ((b, e) for b in bases
                                 for e in (DEFAULT_CONTROL_EVERY, 1)):
            sim = RobotSimulator(poly, [Arm(robot, base)], scale=ds.scale, control_every=every,
                                 compliance=COMPLIANCE, **ROBOT_KW)
            cfg = robot_control(n_fingers=sim.n_fingers)
            times = []
            for _ in range(REPEAT):
                t0 = time.process_time()
                ex = execute_plan(sim, p, fingers=ds.fingers, loop=loop, replan=replan,
                                  config=cfg)
                times.append(time.process_time() - t0)
            t_robot = statistics.median(times)
            log = sim.robot_log
            print(f"{loop} loop, Panda (IK at {1000 / every:g} Hz) at the {label} base "
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


def _cube() -> tuple:
    from nonprehensile.cli.options import state_set
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset

    poly, skills = read_skills(_skills())
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    return poly, skills, ds, motions, lambda sk: expand(poly, sk, state_set(poly, 90.0, None,
                                                                           1e-6))


def _robot_report(res) -> None:
    from collections import Counter

    for lp, rate in res.overall().items():
        lo, hi = rate.interval
        print(f"   {lp} loop: {rate.k}/{rate.n} = {100 * rate.rate:.1f} % (95 % interval "
              f"{100 * lo:.1f}-{100 * hi:.1f})")
    for name, rates in res.per_source().items():
        print(f"     {name:16s} " + "; ".join(f"{lp} {r.k}/{r.n}" for lp, r in rates.items()))
    why = Counter(r.reason.split(":")[0] for r in res.records if not r.success)
    for reason, n in why.most_common(8):
        print(f"     failed {n}x: {reason}")
    ms = [r.extra["robot"] for r in res.records if "robot" in r.extra]
    ok = [r.extra["robot"] for r in res.records if "robot" in r.extra and r.success]
    for label, group in (("all", ms), ("successful", ok)):
        if not group:
            continue
        trk = [m["tracking_error_contact_max_m"] for m in group
               if m["tracking_error_contact_max_m"] is not None]
        ref = [m.get("reference_error_contact_max_m") for m in group]
        ref = [v for v in ref if v is not None]
        lim = [max(m["longest_at_limit_s"].values(), default=0.0) for m in group]
        oth = [m["other_contact_s"] for m in group]
        lim_c = [m.get("longest_at_limit_contact_s", 0.0) for m in group]
        frc = [m.get("contact_force_max_n") for m in group]
        frc = sorted(v for v in frc if v is not None)
        give = sorted(m.get("give_contact_max_m") or 0.0 for m in group)
        print(f"   robot, {label} {len(group)} executions: tracking in contact max "
              f"{1000 * max(trk, default=0):.1f} mm (median of the maxima "
              f"{1000 * sorted(trk)[len(trk) // 2] if trk else 0:.1f} mm; against the "
              f"noise-free reference {1000 * max(ref, default=0):.1f} mm, median "
              f"{1000 * sorted(ref)[len(ref) // 2] if ref else 0:.1f} mm); longest at a "
              f"limit {1000 * max(lim):.0f} ms ({sum(v > 0.010 for v in lim)} over 10 ms); "
              f"link/rod contact max {1000 * max(oth):.0f} ms ({sum(v > 0 for v in oth)} "
              f"with any); IK median {max(m['ik_median_ms'] for m in group):.3f} ms (worst)")
        print(f"     while touching: longest at a limit {1000 * max(lim_c):.0f} ms "
              f"({sum(v > 0.010 for v in lim_c)} over 10 ms); contact force (the fingertip's "
              f"force sensor) max {max(frc, default=0):.1f} N, median of the maxima "
              f"{frc[len(frc) // 2] if frc else 0:.1f} N; the compliance's give max "
              f"{1000 * give[-1]:.1f} mm")
        kinds = Counter(k for m in group for k, v in m["longest_at_limit_s"].items()
                        if v > 0.010)
        if kinds:
            print("     over 10 ms at a limit, by kind: " + ", ".join(
                f"{k} {n}" for k, n in kinds.most_common()))
    # the contact bars per source skill, and which limit was held longest
    by: dict[str, list] = {}
    for r in res.records:
        if "robot" in r.extra:
            by.setdefault(res.spec.units[r.unit].source, []).append(r.extra["robot"])
    for name, group in sorted(by.items()):
        kinds = Counter(max(m["longest_at_limit_s"], key=m["longest_at_limit_s"].get)
                        for m in group if max(m["longest_at_limit_s"].values(),
                                              default=0.0) > 0.010)
        # while touching, per kind: runs with that limit held over 10 ms during contact
        touching = Counter(k for m in group for k, v in
                           m.get("longest_at_limit_contact_by_kind_s", {}).items()
                           if v > 0.010)
        trk = sorted(m["tracking_error_contact_max_m"] for m in group
                     if m["tracking_error_contact_max_m"] is not None)
        print(f"     {name:16s} tracking <= 3 mm {sum(v <= 0.003 for v in trk)}/{len(group)} "
              f"(median {1000 * trk[len(trk) // 2] if trk else 0:.1f} mm, max "
              f"{1000 * trk[-1] if trk else 0:.1f} mm); over 10 ms at a limit "
              f"{sum(kinds.values())} {dict(kinds)}, while touching "
              f"{sum(m.get('longest_at_limit_contact_s', 0.0) > 0.010 for m in group)} "
              f"{dict(touching)}; link/rod contact "
              f"{sum(m['other_contact_s'] > 0 for m in group)}")
    # the contact tracking bar by the sample's fingertip radius (1 mm bins, the last one
    # closed): the references were recorded with a 6 mm pad, and the tool's pin and the
    # radius offset act by the radius (docs/benchmarks.md)
    radii = [(r.values.get("finger_radius"), r.extra["robot"]) for r in res.records
             if "robot" in r.extra and r.values.get("finger_radius") is not None]
    mm = [(1000.0 * x, m) for x, m in radii]
    if len({round(x, 6) for x, _ in mm}) > 1:
        lo, hi = math.floor(min(x for x, _ in mm)), math.ceil(max(x for x, _ in mm))
        bins = []
        for b in range(lo, max(hi, lo + 1)):
            grp = [m for x, m in mm if b <= x < b + 1 or (b + 1 == hi and x == hi)]
            ok = sum((m["tracking_error_contact_max_m"] or 0.0) <= 0.003 for m in grp)
            bins.append(f"{b}-{b + 1} mm {ok}/{len(grp)}")
        print("     tracking <= 3 mm by fingertip radius: " + ", ".join(bins))
    print(f"   {res.steps()} physics steps, {res.wall_seconds:.0f} s wall ({res.how})")


def sweep() -> None:
    """The main plan on the Panda across the distribution (part 3)."""
    from nonprehensile.planning import plan
    from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION
    from nonprehensile.sim.execute import fingers_of
    from nonprehensile.sim.robot import Robot
    from nonprehensile.sim.robustness import (
        SweepRobot,
        SweepSpec,
        frozen_library,
        place_sweep_arms,
        plan_unit,
        run_sweep,
    )
    from nonprehensile.states import State

    poly, skills, ds, motions, expand_ = _cube()
    skills = [s for s in skills if max(fingers_of(s), default=1) <= 1]  # one arm, one finger
    exp = expand_(skills)
    p = plan(poly, exp, State("b", 200), State("e", 110), position=(0.3, 0.1),
             motions=motions, scale=ds.scale)
    units = (plan_unit(p),)
    dist = DEFAULT_DISTRIBUTION.for_object(poly, ds.scale)
    arms, found = place_sweep_arms(Robot.builtin("panda"), units, poly, ds.scale, ds.fingers,
                                   params=dist.base)
    print(f"main plan ({len(p.steps)} steps) on the Panda at {found[0].to_dict()}, "
          f"{SAMPLES} samples, seed {SEED}, {WORKERS} workers")
    spec = SweepSpec(poly, ds.scale, units, dist, SEED, SAMPLES, ("closed",),
                     dict(ds.fingers), expansion=exp, library=frozen_library(exp, motions),
                     robot=SweepRobot(tuple(arms), compliance=COMPLIANCE, **ROBOT_KW))
    print(f"   force-limited finger command: {_compliance(1)}; contact-consistent command: "
          f"{ROBOT_KW or 'the default'}")
    _robot_report(run_sweep(spec, workers=WORKERS))


def _nominal(poly: object, scale: float) -> tuple:
    """The closed-loop issue's distribution for the cube, and its nominal point (every
    range collapsed to the base value, no start error, no noise)."""
    from dataclasses import replace

    from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION, PhysicsDistribution

    dist = DEFAULT_DISTRIBUTION.for_object(poly, scale)
    b = dist.base
    return dist, replace(dist, **{n: (getattr(b, n), getattr(b, n))
                                  for n in PhysicsDistribution.RANGED},
                         start_offset=0.0, start_yaw=0.0, tracking_noise=0.0, finger_noise=0.0)


def transitions() -> None:
    """Every cube transition at nominal physics by one arm or two (part 4)."""

    from nonprehensile.sim.closed_loop import scene_fingers
    from nonprehensile.sim.execute import fingers_of
    from nonprehensile.sim.robot import Robot
    from nonprehensile.sim.robustness import (
        SweepRobot,
        SweepSpec,
        frozen_library,
        place_sweep_arms,
        run_sweep,
        transition_units,
    )

    poly, skills, ds, motions, expand_ = _cube()
    dist, nominal = _nominal(poly, ds.scale)
    panda = Robot.builtin("panda")
    full = expand_(skills)
    everything = transition_units(poly, full, motions, scale=ds.scale, angle_tol=1e-6)
    print(f"{len(everything)} cube transitions at nominal physics, closed loop, "
          f"{WORKERS} workers" + (f", every {EVERY_UNIT}th only" if EVERY_UNIT > 1 else ""))
    for n_arms in ARMS:
        # one arm: re-plans among the single-finger skills only (it has one fingertip)
        sk = [s for s in skills if max(fingers_of(s), default=1) <= n_arms]
        exp = expand_(sk) if n_arms == 1 else full
        units = [u for u in transition_units(poly, exp, motions, scale=ds.scale,
                                             angle_tol=1e-6)
                 if scene_fingers(u.plan) == n_arms][::EVERY_UNIT]
        t0 = time.perf_counter()
        arms, found = place_sweep_arms(panda, units, poly, ds.scale, ds.fingers,
                                       n_arms=n_arms, params=dist.base)
        print(f"  {n_arms}-finger transitions by {n_arms} Panda(s): {len(units)}; bases "
              f"{[f.to_dict()['base'] for f in found]} "
              f"({time.perf_counter() - t0:.0f} s search)")
        # (the contact force feed-forward goes with one arm's force cap: not for two)
        kw = {k: v for k, v in ROBOT_KW.items() if n_arms == 1 or k != "force_feedforward"}
        spec = SweepSpec(poly, ds.scale, tuple(units), nominal, SEED, 1, ("closed",),
                         dict(ds.fingers), expansion=exp, library=frozen_library(exp, motions),
                         robot=SweepRobot(tuple(arms), compliance=COMPLIANCE, **kw))
        print(f"   force-limited finger command: {_compliance(n_arms)}; contact-consistent "
              f"command: {kw or 'the default'}")
        _robot_report(run_sweep(spec, workers=WORKERS, chunk_size=1))


def cost() -> None:
    """Every single-finger cube transition executed by one Panda and by the free fingertip,
    closed loop at nominal physics, one after the other in this process (part 5): the CPU
    of each execution, the ratio of the sums and the median of the per-transition ratios."""

    from nonprehensile.sim.closed_loop import scene_fingers
    from nonprehensile.sim.execute import fingers_of
    from nonprehensile.sim.robot import Robot
    from nonprehensile.sim.robustness import (
        SweepRobot,
        SweepSpec,
        _Worker,
        frozen_library,
        place_sweep_arms,
        transition_units,
    )

    poly, skills, ds, motions, expand_ = _cube()
    dist, nominal = _nominal(poly, ds.scale)
    sk = [s for s in skills if max(fingers_of(s), default=1) <= 1]
    exp = expand_(sk)
    units = tuple(u for u in transition_units(poly, exp, motions, scale=ds.scale,
                                              angle_tol=1e-6)
                  if scene_fingers(u.plan) == 1)[::EVERY_UNIT]
    arms, found = place_sweep_arms(Robot.builtin("panda"), units, poly, ds.scale, ds.fingers,
                                   n_arms=1, params=dist.base)
    lib = frozen_library(exp, motions)
    specs = {kind: SweepSpec(poly, ds.scale, units, nominal, SEED, 1, ("closed",),
                             dict(ds.fingers), expansion=exp, library=lib,
                             robot=SweepRobot(tuple(arms), **ROBOT_KW) if kind == "robot"
                             else None)
             for kind in ("robot", "free")}
    workers = {kind: _Worker(spec) for kind, spec in specs.items()}
    for w in workers.values():  # warm: the first execution compiles and caches
        w.run(0, 0)
    cpu: dict[str, list[float]] = {"robot": [], "free": []}
    ok = {"robot": 0, "free": 0}
    sim = {"robot": 0.0, "free": 0.0}
    for u in range(len(units)):
        # alternate which goes first, so a burst of load hits both alike
        for kind in (("robot", "free") if u % 2 == 0 else ("free", "robot")):
            t0 = time.process_time()
            rec = workers[kind].run(u, 0)[0]
            cpu[kind].append(time.process_time() - t0)
            ok[kind] += rec.success
            sim[kind] += rec.sim_seconds
    r, f = sum(cpu["robot"]), sum(cpu["free"])
    per = sorted(a / b for a, b in zip(cpu["robot"], cpu["free"], strict=True))
    print(f"{len(units)} single-finger transitions, nominal, closed loop, one Panda at "
          f"{found[0].to_dict()['base']} against the free fingertip, in one process: "
          f"success {ok['robot']} / {ok['free']}; CPU robot {r:.2f} s, free {f:.2f} s: "
          f"**{r / f:.2f}x** (sum); per transition median {statistics.median(per):.2f}x, "
          f"range {per[0]:.2f}-{per[-1]:.2f}x; simulated {sim['robot']:.1f} s / "
          f"{sim['free']:.1f} s; per simulated second "
          f"{(r / sim['robot']) / (f / sim['free']):.2f}x")


def main(plan: bool = True) -> None:
    if "cost" in PARTS:
        cost()
    if "sweep" in PARTS:
        sweep()
    if "transitions" in PARTS:
        transitions()
    if plan and "plan" in PARTS:
        main_plan()
    if "wheel" not in PARTS:
        return
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
