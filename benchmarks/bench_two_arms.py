"""Two arms on the cube's two-finger skills (issue 22): tracking, limits and link contacts.

``python -m benchmarks two_arms`` runs, closed loop at nominal physics, each from ``a:0`` at
(0.3, 0.1) by two bundled Pandas with one finger each (bases searched arm by arm, as
``simulate plan ... --robot panda --arms 2`` does):

* the twist ``a:0`` -> ``a:90`` (the planner's choice);
* the tumble-lift ``a:0`` -> ``b:0`` (the planner's choice);
* the tumble-twist ``a:0`` -> ``b:0`` (planned with tumble-twist as the only skill: the
  planner prefers tumble-lift for every transition both make).

Per run: success, the final state and its distance from the goal, how many step attempts
and retries or re-plans it took and how the first attempt ended, and over the whole
execution (transits included) the largest fingertip tracking error while a fingertip touches
the object (the distance from the fingertip's centre to the target it was given: the figure
of the single-arm rows in docs/benchmarks.md), the longest time a joint was at a position,
velocity or torque limit (which and when), the time a link or the rod touched the object or
the table, and the IK's median time. ``TWO_ARMS_COMPLIANCE=1`` gives the arms the
force-limited finger command (``RobotSimulator(compliance=True)``: the nominal fingertip's
600 N/m and 8 N; ``TWO_ARMS_FORCE_LIMIT=N`` sets the force limit); off by default.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

RUNS = (("twist", "a:90", None), ("tumble-lift", "b:0", None),
        ("tumble-twist", "b:0", "tumble-twist"))


def _skills() -> str:
    import nonprehensile

    return str(Path(nonprehensile.__file__).parent / "data" / "cube_skills.json")


def main() -> None:
    import numpy as np

    from nonprehensile.cli.options import state_set
    from nonprehensile.control import replanner
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.sim.closed_loop import execute_plan
    from nonprehensile.sim.execute import fingers_of
    from nonprehensile.sim.placement import place_base, plan_targets
    from nonprehensile.sim.robot import Robot
    from nonprehensile.sim.robot_run import RobotSimulator, robot_control
    from nonprehensile.sim.robot_scene import Arm
    from nonprehensile.states import State

    limit = os.environ.get("TWO_ARMS_FORCE_LIMIT")
    force_limit = None if limit is None else float(limit)
    compliance = os.environ.get("TWO_ARMS_COMPLIANCE", "0") == "1"
    poly, all_skills = read_skills(_skills())
    all_skills = [s for s in all_skills if max(fingers_of(s), default=1) <= 2]
    robot = Robot.builtin("panda")
    cfg = robot_control(n_fingers=2)
    for label, goal_s, only in RUNS:
        skills = [s for s in all_skills if only is None or s.name == only]
        exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
        ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
        face, theta = goal_s.split(":")
        start, goal = State("a", 0.0), State(face, float(theta))
        p = plan(poly, exp, start, goal, position=(0.3, 0.1), motions=motions,
                 scale=ds.scale)
        names = [st.to_dict().get("skill") for st in p.steps]
        t0 = time.process_time()
        paths = plan_targets(p, ds.fingers, 2)
        placed: list = []
        for i in range(2):
            placed.append(place_base(robot, poly, ds.scale, paths, finger=i,
                                     avoid=[q.base for q in placed]))
        t_place = time.process_time() - t0
        sim = RobotSimulator(poly, [Arm(robot, q.base) for q in placed], scale=ds.scale,
                             force_limit=force_limit, compliance=compliance)
        t0 = time.process_time()
        ex = execute_plan(sim, p, fingers=ds.fingers, loop="closed",
                          replan=replanner(poly, exp, goal, motions=motions, scale=ds.scale),
                          config=cfg)
        t_run = time.process_time() - t0
        log = sim.robot_log
        m = log.metrics()
        t = np.asarray(log.time)
        # which limit, where: the longest run of any joint at any limit
        sc = sim.scene
        q, qd, tau = np.array(log.q), np.array(log.qd), np.abs(np.array(log.tau))
        at = ((np.minimum(q - sc.lower, sc.upper - q) < np.radians(0.5))
              | (np.abs(qd) / sc.velocity >= 0.98) | (tau / sc.torque >= 0.98))
        flags = at.any(axis=1)
        best, start_i, run = 0, 0, 0
        for i, f in enumerate(flags):
            run = run + 1 if f else 0
            if run > best:
                best, start_i = run, i - run + 1
        where = ""
        if best:
            joints = sorted({sc.joint_names[j] for j in
                             np.nonzero(at[start_i:start_i + best].any(axis=0))[0]})
            touching = bool(np.asarray(log.touch)[start_i:start_i + best].any())
            where = (f" (t {t[start_i]:.3f}-{t[start_i + best - 1]:.3f} s, "
                     f"{'in contact' if touching else 'no fingertip contact'}, "
                     f"{', '.join(joints)})")
        c = m.tracking_error_contact_max_m
        print(f"{label} a:0 -> {goal_s} (plan {names}), bases "
              f"{[q.base.to_dict() for q in placed]} ({t_place:.1f} s CPU): success "
              f"{ex.success}, final {ex.to_dict()['final_state']}, "
              f"{1000 * (ex.position_error or 0):.1f} mm from the goal; tracking in contact "
              f"max {'-' if c is None else f'{1000 * c:.1f}'} mm; longest at a limit "
              f"{1000 * max(m.longest_at_limit_s.values(), default=0.0):.0f} ms "
              f"{ {k: round(1000 * v) for k, v in m.longest_at_limit_s.items()} }{where}; "
              f"link/rod contact {1000 * m.other_contact_s:.0f} ms; contact force max "
              f"{'-' if m.contact_force_max_n is None else f'{m.contact_force_max_n:.1f}'} N "
              f"(compliance {'on' if compliance else 'off'}); IK median "
              f"{m.ik_median_ms:.3f} ms; {t_run:.1f} s CPU for {ex.sim_time:.2f} s simulated",
              flush=True)
        # a success may be a retry's or a re-plan's: the first attempt's outcome says
        # whether the skill itself worked at these bases
        first = ex.steps[0] if ex.steps else {}
        print(f"   {len(ex.steps)} step attempt(s), {len(ex.replans)} retry/re-plan(s); "
              f"the first: {first.get('outcome', '-')}"
              + (f" ({first['reason']})" if first.get("reason") else ""), flush=True)


if __name__ == "__main__":
    main()
