"""Physics (issue 9): the bars of the physics issue, measured in MuJoCo.

1. the main job's plan (b:200 at (0.3, 0.1) m -> e:110) executed open loop: every step in the
   goal state (face, theta within 5 degrees, centre of mass within 10 mm);
2. the bundled demonstrations replayed: share ending in the annotated state, per skill;
3. every demonstrated and inferred transition of the cube and of a hexagonal prism (whose
   demonstrations are recorded from physics here): share ending in the predicted state;
4. simulation time per transition, and the step loop's cost against bare ``mj_step`` (the
   baseline measured in the same run);
5. a sensitivity sweep: push-roll replays under other table frictions and masses.

``python -m benchmarks physics`` (a few minutes on 2 cores).
"""

from __future__ import annotations

import os
import time
from collections import defaultdict
from pathlib import Path

import mujoco

from nonprehensile.demonstrations.dataset import Dataset
from nonprehensile.demonstrations.segment import segment_dataset
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.pipeline import (
    DEFAULT_GOAL,
    DEFAULT_POSITION,
    DEFAULT_START,
    motions_from_dataset,
)
from nonprehensile.planning import plan, step_for
from nonprehensile.sim import SimParams, Simulator
from nonprehensile.sim.execute import (
    DemonstrationLibrary,
    replay_demonstration,
    simulate_plan,
    simulate_step,
)
from nonprehensile.sim.record import record_dataset
from nonprehensile.states import states_by_step

ROOT = Path(__file__).resolve().parents[1]


def _rates(rows: list[tuple[str, bool]]) -> dict[str, tuple[int, int]]:
    out: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for k, ok in rows:
        out[k][0] += ok
        out[k][1] += 1
    return {k: (v[0], v[1]) for k, v in sorted(out.items())}


def _infer(ds: Dataset, motions: object) -> tuple[int, int, float]:
    sim = Simulator(ds.poly, scale=ds.scale)
    exp = expand(ds.poly, list(ds.skills), states_by_step(ds.poly, 90))
    ok = n = 0
    wall = 0.0
    for t in exp.transitions:
        st = step_for(ds.poly, t, motions=motions, scale=ds.scale)  # type: ignore[arg-type]
        try:
            o = simulate_step(sim, st, fingers=ds.fingers, check_position=False)
        except Exception as exc:
            print(f"   {t.skill.name} {t.start}->{t.end}: not simulated ({exc})")
            n += 1
            continue
        ok += o.success
        n += 1
        wall += o.result.wall_time
    return ok, n, wall / max(n, 1)


def main() -> None:
    cpu0 = time.process_time()
    print(f"   load average at start {os.getloadavg()[0]:.1f} (2 cores)")
    skills = ROOT / "examples" / "cube_skills.json"
    poly, sk = read_skills(skills)
    ds, motions = motions_from_dataset("cube", skills=sk, poly=poly)
    exp = expand(poly, sk, states_by_step(poly, 90))
    pl = plan(poly, exp, DEFAULT_START, DEFAULT_GOAL, position=DEFAULT_POSITION,
              motions=motions, scale=ds.scale)
    print("1. main job's plan, open loop:")
    for o in simulate_plan(poly, pl, scale=ds.scale, fingers=ds.fingers):
        r = o.to_dict()
        print(f"   step {r['step']} {r['skill']}: predicted {r['predicted']}, simulated "
              f"{r['simulated']}, theta error {r['theta_error_deg']} deg, position error "
              f"{1000 * r['position_error_m']:.1f} mm (bars 5 deg, 10 mm), success "
              f"{r['success']}")

    print("2. bundled demonstrations replayed (ended in the annotated state):")
    sim = Simulator(ds.poly, scale=ds.scale)
    rows = []
    walls = []
    steps = 0
    for d in ds.demonstrations:
        o = replay_demonstration(sim, ds, d)
        rows.append((d.skill.name, o.success))
        walls.append(o.result.wall_time)
        steps += o.result.n_steps
    for k, (a, b) in _rates(rows).items():
        print(f"   {k:14s} {a}/{b} = {100 * a / b:.0f} %")
    per_step = sum(walls) / steps
    print(f"   wall {1000 * sum(walls) / len(walls):.0f} ms per demonstration, "
          f"{1e6 * per_step:.1f} us per physics step (contacts and settling included)")
    # baseline: bare mj_step on the same scene, same number of steps
    t0 = time.perf_counter()
    for _ in range(20000):
        mujoco.mj_step(sim.model, sim.data)
    bare = (time.perf_counter() - t0) / 20000
    print(f"   bare mj_step {1e6 * bare:.1f} us: our loop costs {per_step / bare:.2f}x")

    print("3. demonstrated and inferred transitions (ended in the predicted state):")
    # each skill's medoid demonstration, whole (simulate infer's default)
    ok, n, wall = _infer(ds, DemonstrationLibrary(segment_dataset(ds)[1]))
    print(f"   cube: {ok}/{n} = {100 * ok / n:.0f} %, {1000 * wall:.0f} ms wall per transition")
    hex_ds, stats = record_dataset(ROOT / "examples" / "hexprism_skills.json", n_per_skill=10)
    print(f"   hexprism physics takes: {stats}")
    ok, n, wall = _infer(hex_ds, DemonstrationLibrary(segment_dataset(hex_ds)[1]))
    print(f"   hexprism: {ok}/{n} = {100 * ok / n:.0f} %, {1000 * wall:.0f} ms wall per "
          "transition")

    print("4. sensitivity: push-roll replays under other physics")
    push = [d for d in ds.demonstrations if d.skill.name == "push-roll"]
    for kw in ({"friction_table": 0.3}, {"friction_table": 0.9}, {"mass": 0.05},
               {"mass": 0.3}):
        s2 = Simulator(ds.poly, scale=ds.scale, params=SimParams(**kw))  # type: ignore[arg-type]
        got = sum(replay_demonstration(s2, ds, d).success for d in push)
        print(f"   {kw}: {got}/{len(push)}")
    print(f"   CPU {time.process_time() - cpu0:.0f} s; load average at end "
          f"{os.getloadavg()[0]:.1f} (2 cores)")


if __name__ == "__main__":
    main()
