"""Closed-loop execution (issue 21): the main plan closed vs open loop, across the physics
distribution, and the no-teleport figures.

1. the main job's plan (``b:200`` at (0.3, 0.1) m -> ``e:110``, ``--step 90 --dataset cube``)
   at nominal physics, closed and open loop;
2. the same plan over ``N`` samples (default 200, seed 0) of the documented distribution
   (``sim.distribution.DEFAULT_DISTRIBUTION``): share reaching the goal (face, theta within
   5 degrees, centre of mass within 10 mm of the goal position), closed and open loop side by
   side, with a 95 % Wilson interval, the failures' reasons, and the share per table-friction
   and mass bin;
3. no teleport, over every execution of 2: the largest commanded fingertip speed and
   acceleration (overall and in transits), the largest simulated fingertip speed,
   fingertip-object contact in transits (a transit runs from the moment its fingertips are
   observed to have let go of the object to the observation the next motion starts from),
   and, beside it, the let-gos (the end of the previous motion's contact: a step's, a push's,
   an aborted step's): the contact read while letting go, each let-go's time from its start
   to its fingertips' first reading off the object (the judge's MuJoCo contacts, every 5 ms;
   per execution its largest, and how many let-gos exceed
   ``closed_loop.LET_GO_SEPARATION``), the re-contacts after that first separation (during
   the let-go itself, and after it through the hold and the transit), and how far the object's
   centre of mass moved while a fingertip still touched it;
4. the executors' Python overhead at nominal physics: wall time per physics step (planning of
   re-plans excluded: there are none) against bare ``mj_step`` on the same model, same run.

``python -m benchmarks closed_loop [N]`` (about 2 minutes for 200 samples on one core).
"""

from __future__ import annotations

import math
import sys
import time
from collections import Counter, defaultdict
from typing import Any

import mujoco

from nonprehensile.control import ControlConfig, replanner
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.pipeline import (
    DEFAULT_GOAL,
    DEFAULT_POSITION,
    DEFAULT_START,
    motions_from_dataset,
)
from nonprehensile.planning import plan
from nonprehensile.sim import Simulator
from nonprehensile.sim.closed_loop import LET_GO_SEPARATION, execute_plan, scene_fingers
from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION
from nonprehensile.states import states_by_step

SKILLS = "examples/cube_skills.json"


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of k successes in n."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def setup() -> tuple[Any, ...]:
    poly, skills = read_skills(SKILLS)
    exp = expand(poly, skills, states_by_step(poly, 90))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    pl = plan(poly, exp, DEFAULT_START, DEFAULT_GOAL, position=DEFAULT_POSITION,
              motions=motions, scale=ds.scale)
    rp = replanner(poly, exp, DEFAULT_GOAL, motions=motions, scale=ds.scale)
    rp.n_fingers = scene_fingers(pl, exp)  # type: ignore[attr-defined]
    return poly, ds, pl, rp


def run_one(poly: Any, ds: Any, pl: Any, rp: Any, params: Any, pert: Any,
            loop: str) -> Any:
    sim = Simulator(poly, scale=ds.scale, n_fingers=rp.n_fingers, params=params)
    return execute_plan(sim, pl, fingers=ds.fingers, loop=loop,  # type: ignore[arg-type]
                        replan=rp, perturbation=pert, config=ControlConfig())


def overhead(poly: Any, ds: Any, pl: Any, rp: Any) -> tuple[float, float, float]:
    """(us per physics step of the closed-loop and of the open-loop execution at nominal
    physics, us per bare mj_step), best of 3, same run."""
    from nonprehensile.sim.distribution import NO_PERTURBATION

    best = {"closed": math.inf, "open": math.inf}
    for loop in best:
        for _ in range(3):
            ex = run_one(poly, ds, pl, rp, DEFAULT_DISTRIBUTION.base, NO_PERTURBATION, loop)
            best[loop] = min(best[loop], ex.wall_time / ex.n_steps)
    sim = Simulator(poly, scale=ds.scale, n_fingers=rp.n_fingers)
    m, d = sim.model, sim.data
    mujoco.mj_resetData(m, d)
    sim.set_pose(pl.steps[0].start_pose)
    step = mujoco.mj_step
    bare = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(5000):
            step(m, d)
        bare = min(bare, (time.perf_counter() - t0) / 5000)
    return 1e6 * best["closed"], 1e6 * best["open"], 1e6 * bare


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    n = int(next((a for a in args if a.isdigit()), "200"))
    poly, ds, pl, rp = setup()
    base = DEFAULT_DISTRIBUTION.base
    from nonprehensile.sim.distribution import NO_PERTURBATION

    print("1. main plan at nominal physics")
    for loop in ("closed", "open"):
        ex = run_one(poly, ds, pl, rp, base, NO_PERTURBATION, loop)
        print(f"   {loop:6s}: success {ex.success}, final {ex.final_state}, "
              f"{1000 * (ex.position_error or 0):.1f} mm from the goal position, "
              f"{len(ex.replans)} re-plans, {len(ex.corrections)} corrections")
    print(f"2. main plan over {n} samples of the distribution (seed 0)")
    samples = DEFAULT_DISTRIBUTION.samples(n, 0)
    ok: dict[str, int] = Counter()
    reasons: dict[str, Counter[str]] = defaultdict(Counter)
    bins: dict[tuple[str, str, str], list[int]] = defaultdict(lambda: [0, 0])
    lim = {"speed": 0.0, "accel": 0.0, "tip": 0.0, "contact": 0.0, "transit_accel": 0.0,
           "let_go": 0.0}
    let_go: dict[str, int] = Counter()
    lg_sep: dict[str, list[float]] = defaultdict(list)  # per let-go that touched at its start
    lg_exec: dict[str, list[float]] = defaultdict(list)  # per execution, its largest
    lg_moved: dict[str, list[float]] = defaultdict(list)
    lg_free: dict[str, list[float]] = defaultdict(list)
    lg_count: dict[str, int] = Counter()
    wall: dict[str, float] = defaultdict(float)
    replans = corrections = 0
    touched: dict[str, int] = Counter()
    where: Counter[str] = Counter()
    for s in samples:
        for loop in ("closed", "open"):
            t0 = time.perf_counter()
            ex = run_one(poly, ds, pl, rp, s.params, s.perturbation, loop)
            wall[loop] += time.perf_counter() - t0
            ok[loop] += ex.success
            if not ex.success:
                reasons[loop][_kind(ex.reason)] += 1
            v = s.values()
            fb = f"{0.1 * math.floor(v['friction_table'] / 0.1 + 1e-9):.1f}"
            mb = f"{0.05 * math.floor(v['mass'] / 0.05 + 1e-9):.2f}"
            bins[(loop, "friction", fb)][0] += ex.success
            bins[(loop, "friction", fb)][1] += 1
            bins[(loop, "mass", mb)][0] += ex.success
            bins[(loop, "mass", mb)][1] += 1
            lim["speed"] = max(lim["speed"], ex.commanded_speed)
            lim["accel"] = max(lim["accel"], ex.commanded_accel)
            lim["tip"] = max(lim["tip"], ex.tip_speed or 0.0)
            lim["contact"] = max(lim["contact"], ex.transit_contact_s)
            lim["transit_accel"] = max(lim["transit_accel"], ex.transit_accel)
            lim["let_go"] = max(lim["let_go"], ex.let_go_contact_s)
            let_go[loop] += ex.let_go_contact_s > 0
            touched_in = [r for r in (*ex.steps, *ex.transits, *ex.corrections)
                          if (r.get("let_go") or {}).get("finger_object_contact_s", 0) > 0]
            let_go[f"{loop} aborted"] += any("step" in r for r in touched_in)
            let_go[f"{loop} transit"] += any("before" in r for r in touched_in)
            let_go[f"{loop} push"] += any("kind" in r for r in touched_in)
            gos = [r["let_go"] for r in (*ex.steps, *ex.transits, *ex.corrections)
                   if r.get("let_go")]
            lg_count[loop] += len(gos)
            lg_exec[loop].append(ex.let_go_separation_s)
            for g in gos:
                sep = math.inf if g["separated_s"] is None else g["separated_s"]
                if sep > 0:
                    lg_sep[loop].append(sep)
                lg_count[f"{loop} over"] += sep > LET_GO_SEPARATION
                lg_moved[loop].append(g["object_moved_in_contact_m"])
                free = math.inf if g["free_s"] is None else g["free_s"]
                if free > 0:
                    lg_free[loop].append(free)
                lg_count[f"{loop} free over"] += free > LET_GO_SEPARATION
                during = sum(1 for a in g["recontacts_at_s"] if a <= g["seconds"] + 1e-9)
                lg_count[f"{loop} again during"] += during
                lg_count[f"{loop} again after"] += (g["recontacts"] or 0) - during
                lg_count[f"{loop} again execs"] += bool(g["recontacts"])
            if ex.transit_contact_s > 0:
                touched[loop] += 1
                where.update(t["before"].split(" ")[0] for t in ex.transits
                             if t["finger_object_contact_s"] > 0)
            if loop == "closed":
                replans += len(ex.replans)
                corrections += len(ex.corrections)
    for loop in ("closed", "open"):
        lo, hi = wilson(ok[loop], n)
        print(f"   {loop:6s}: {ok[loop]}/{n} = {100 * ok[loop] / n:.1f} % "
              f"(95 % interval {100 * lo:.1f}-{100 * hi:.1f} %), "
              f"{wall[loop] / n:.2f} s wall per execution")
        for why, c in reasons[loop].most_common():
            print(f"           {c:4d} x {why}")
    print(f"   closed loop: {replans} re-plans, {corrections} correction pushes in all")
    for what in ("friction", "mass"):
        keys = sorted({k[2] for k in bins if k[1] == what})
        print(f"   by {what}: " + "; ".join(
            f"{k}: closed {bins[('closed', what, k)][0]}/{bins[('closed', what, k)][1]}, "
            f"open {bins[('open', what, k)][0]}/{bins[('open', what, k)][1]}" for k in keys))
    print("3. no teleport, over every execution above")
    print(f"   commanded fingertip speed <= {lim['speed']:.3f} m/s, acceleration <= "
          f"{lim['accel']:.1f} m/s^2; simulated fingertip speed <= {lim['tip']:.3f} m/s; "
          f"fingertip-object contact in transits: {lim['contact']:.3f} s at most; executions "
          f"with any: closed {touched['closed']}/{n}, open {touched['open']}/{n} "
          f"(transits before: {dict(where)}); commanded acceleration in transits <= "
          f"{lim['transit_accel']:.1f} m/s^2")
    print("   letting go (the end of a step's or push's contact, before its transit): "
          "executions with contact while letting go: " + ", ".join(
              f"{lp} {let_go[lp]}/{n} (of an aborted step {let_go[lp + ' aborted']}, before "
              f"a transit {let_go[lp + ' transit']}, after a correction push "
              f"{let_go[lp + ' push']})" for lp in ("closed", "open"))
          + f"; {lim['let_go']:.3f} s at most in one execution")
    for lp in ("closed", "open"):
        seps = sorted(lg_sep[lp])
        ex_max = sorted(lg_exec[lp])

        def pct(xs: list[float], q: float) -> str:
            return f"{1000 * xs[min(len(xs) - 1, int(q * len(xs)))]:.0f}" if xs else "-"

        print(f"   {lp} let-gos: {lg_count[lp]} in all, {len(seps)} touching at their start; "
              f"time to the first reading off the object (ms) median {pct(seps, 0.5)}, "
              f"90 % {pct(seps, 0.9)}, 99 % {pct(seps, 0.99)}, max {pct(seps, 1.0)}; "
              f"per execution's largest: median {pct(ex_max, 0.5)}, 90 % {pct(ex_max, 0.9)}, "
              f"max {pct(ex_max, 1.0)}; over {1000 * LET_GO_SEPARATION:.0f} ms: "
              f"{lg_count[lp + ' over']}; re-contacts after the first separation: "
              f"{lg_count[lp + ' again during']} during the let-go, "
              f"{lg_count[lp + ' again after']} after it (hold, transit); off for good "
              f"(the end of the let-go's last contact): max {pct(sorted(lg_free[lp]), 1.0)}"
              f" ms, over {1000 * LET_GO_SEPARATION:.0f} ms: {lg_count[lp + ' free over']}; "
              f"object moved "
              f"while touched: 99 % {pct(sorted(lg_moved[lp]), 0.99)} mm, max "
              f"{1000 * max(lg_moved[lp], default=0.0):.1f} mm")
    us, us_open, bare = overhead(poly, ds, pl, rp)
    print(f"4. at nominal physics: closed-loop execution {us:.1f} us per physics step "
          f"({us / bare:.2f}x), open loop {us_open:.1f} us ({us_open / bare:.2f}x), bare "
          f"mj_step {bare:.1f} us (a resting cube), same run")


def _kind(reason: str) -> str:
    """A failure reason without its numbers, to count alike failures together."""
    out = []
    for word in reason.split():
        out.append("#" if any(ch.isdigit() for ch in word) else word)
    return " ".join(out)[:140]


if __name__ == "__main__":
    main()
