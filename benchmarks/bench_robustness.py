"""Robustness across the physics distribution (issue 21, items 4-7), measured.

1. ``cube``: all 168 cube transitions with the planner's references, ``NP_SAMPLES`` (20)
   samples each, every available loop: overall and per source skill, with 95 % intervals;
   the sweep's wall time on ``NP_WORKERS`` (2) processes against (simulated steps x bare
   ``mj_step`` time / workers), the bare time measured in the same run by replaying a subset
   of the sweep's own open-loop executions step for step in MuJoCo's C loop
   (``mujoco.rollout``) and in a plain Python ``mj_step`` loop, before and after the sweep;
2. ``hexprism``: the hexagonal prism's 36 transitions likewise (its demonstrations recorded
   from physics here, 10 per skill, as ``bench_physics`` records them);
3. ``demos``: the bundled demonstrations replayed across the distribution (each with its own
   recorded motion as the reference), ``NP_DEMO_SAMPLES`` (5) samples each;
4. ``dask``: a Dask ``LocalCluster`` run equal to the process pool's, sample by sample
   (24 transitions x 5 samples).

``python -m benchmarks robustness`` runs every part; ``NP_PARTS=cube,dask`` picks some.
``NP_FIGURE=path.png`` draws the cube's figure. Heavy: run it with ``nice`` on a quiet
machine.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import mujoco
import mujoco.rollout
import numpy as np

from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.pipeline import motions_from_dataset
from nonprehensile.sim import Simulator
from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION
from nonprehensile.sim.execute import step_targets
from nonprehensile.sim.robustness import (
    SweepResult,
    SweepSpec,
    available_loops,
    demonstration_units,
    frozen_library,
    run_sweep,
    transition_units,
)
from nonprehensile.sim.scene import SceneTuner
from nonprehensile.states import states_by_step

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = int(os.environ.get("NP_SAMPLES", "20"))
WORKERS = int(os.environ.get("NP_WORKERS", "2"))
SEED = int(os.environ.get("NP_SEED", "0"))
PARTS = os.environ.get("NP_PARTS", "cube,hexprism,demos,dask").split(",")
#: Loops to run (default every available one), and a folder to keep each sweep's JSON in.
LOOPS = [lp for lp in os.environ.get("NP_LOOPS", "closed,open").split(",")
         if lp in available_loops()]
OUT = os.environ.get("NP_OUT")


def _keep(name: str, r: SweepResult) -> None:
    if OUT:
        import json

        Path(OUT).mkdir(parents=True, exist_ok=True)
        path = Path(OUT) / f"{name}.json"
        path.write_text(json.dumps(r.to_dict()))
        print(f"   kept {path}")


def _report(title: str, r: SweepResult) -> None:
    print(f"   {title}: {len(r.spec.units)} units x {r.spec.n_samples} samples, loops "
          f"{list(r.spec.loops)}, seed {r.spec.seed}")
    for lp, rate in r.overall().items():
        print(f"     overall {lp:6s} {rate}")
    for name, rates in r.per_source().items():
        print(f"     {name:14s} " + "; ".join(f"{lp} {rate}" for lp, rate in rates.items()))
    reasons: dict[str, int] = {}
    for rec in r.records:
        if not rec.success:
            key = f"{rec.loop}: " + (rec.reason.split(" off")[0].split(",")[0][:40] or "?")
            reasons[key] = reasons.get(key, 0) + 1
    top = sorted(reasons.items(), key=lambda kv: -kv[1])[:6]
    print("     commonest failures: " + "; ".join(f"{k} x{v}" for k, v in top))
    crashed = [rec for rec in r.records if rec.extra.get("executor_error")]
    if crashed:
        print(f"     executions where the executor raised (counted as failures): "
              f"{len(crashed)}: {crashed[0].reason[:120]}")


def bare_step_time(spec: SweepSpec, picks: list[tuple[int, int]]) -> tuple[float, float, int]:
    """Seconds per physics step of the sweep's own open-loop executions ``(unit, sample)``,
    replayed with the same start and the same controls: (MuJoCo's C loop, a Python
    ``mj_step`` loop, steps replayed)."""
    sim = Simulator(spec.poly, scale=spec.scale, n_fingers=spec.n_fingers,
                    params=spec.distribution.base)
    tuner = SceneTuner(sim.model, sim.data, sim.params)
    m, d = sim.model, sim.data
    t_c = t_py = 0.0
    n_all = 0
    state_spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    for u, i in picks:
        unit = spec.units[u]
        if len(unit.plan.steps) != 1:
            continue
        s = spec.sample(u, i)
        tuner.tune(s.params)
        sim.params = sim.judge.params = s.params
        st = unit.plan.steps[0]
        targets, rate, _ = step_targets(st, spec.fingers)
        targets = s.perturbation.finger_targets(targets, rate, "finger/step1")
        res_steps = sim.run(s.perturbation.start_pose(st.start_pose), targets, rate).n_steps
        ctrl = sim.driver.controls(sim.resample(targets, rate, sim.check_targets(targets,
                                                                                  rate)))
        full = np.concatenate([ctrl[1:], np.repeat(ctrl[-1:], max(0, res_steps - len(ctrl)
                                                                   + 1), axis=0)])[:res_steps]
        mujoco.mj_resetData(m, d)
        sim.set_pose(s.perturbation.start_pose(st.start_pose))
        d.time = 0.0
        sim.driver.place(d, ctrl[0])
        mujoco.mj_forward(m, d)
        s0 = np.empty(mujoco.mj_stateSize(m, state_spec))
        mujoco.mj_getState(m, d, s0, state_spec)
        t0 = time.perf_counter()
        mujoco.rollout.rollout(m, d, s0, full[None])
        t_c += time.perf_counter() - t0
        mujoco.mj_setState(m, d, s0, state_spec)
        cv = d.ctrl
        t0 = time.perf_counter()
        for row in full:
            cv[:] = row
            mujoco.mj_step(m, d)
        t_py += time.perf_counter() - t0
        n_all += res_steps
    return t_c / n_all, t_py / n_all, n_all


def _cube() -> None:
    poly, skills = read_skills(ROOT / "examples" / "cube_skills.json")
    exp = expand(poly, skills, states_by_step(poly, 90))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    units = transition_units(poly, exp, motions, scale=ds.scale, angle_tol=1e-6)
    spec = SweepSpec(poly, ds.scale, tuple(units), DEFAULT_DISTRIBUTION.for_object(
        poly, ds.scale), SEED, SAMPLES, tuple(LOOPS), dict(ds.fingers),
        expansion=exp, library=frozen_library(exp, motions))
    picks = [(u, 0) for u in range(0, len(units), 4)]
    c0, p0, n0 = bare_step_time(spec, picks)
    res = run_sweep(spec, workers=WORKERS)
    c1, p1, _ = bare_step_time(spec, picks)
    _report("cube, 168 transitions", res)
    _keep(f"cube-{'-'.join(LOOPS)}-{SAMPLES}", res)
    bare_c, bare_py = (c0 + c1) / 2, (p0 + p1) / 2
    steps = res.steps()
    bound = steps * bare_c / WORKERS
    print(f"   sweep wall {res.wall_seconds:.1f} s on {WORKERS} processes, {steps} physics "
          f"steps; bare mj_step {1e6 * bare_c:.2f} us (C loop; {1e6 * c0:.2f} before, "
          f"{1e6 * c1:.2f} after, {n0} steps of {len(picks)} executions), "
          f"{1e6 * bare_py:.2f} us (Python loop)")
    print(f"   steps x bare / {WORKERS} = {bound:.1f} s: the sweep takes "
          f"{res.wall_seconds / bound:.2f}x (bar <= 1.5x); against the Python loop "
          f"{res.wall_seconds / (steps * bare_py / WORKERS):.2f}x")
    cpu = sum(r.wall_seconds for r in res.records)
    print(f"   executions' own wall time {cpu:.1f} s: {1e6 * cpu / steps:.2f} us per step "
          f"({cpu / steps / bare_c:.2f}x bare) inside the executors")
    fig = os.environ.get("NP_FIGURE")
    if fig:
        from nonprehensile.viz import save_figure
        from nonprehensile.viz.robustness import robustness_figure

        save_figure(robustness_figure(res.to_dict(records=False)), fig)
        print(f"   wrote {fig}")


def _hexprism() -> None:
    from nonprehensile.sim.record import record_dataset, write_recorded

    skills_file = ROOT / "examples" / "hexprism_skills.json"
    ds, stats = record_dataset(skills_file, n_per_skill=10)
    print(f"   hexprism physics takes: {stats}")
    poly, skills = read_skills(skills_file)
    with tempfile.TemporaryDirectory() as tmp:
        write_recorded(ds, tmp, "c3d")
        ds2, motions = motions_from_dataset(tmp, skills=skills, poly=poly, cache=False)
        exp = expand(poly, skills, states_by_step(poly, 90))
        units = transition_units(poly, exp, motions, scale=ds2.scale, angle_tol=1e-6)
        library = frozen_library(exp, motions)
    spec = SweepSpec(poly, ds2.scale, tuple(units), DEFAULT_DISTRIBUTION.for_object(
        poly, ds2.scale), SEED, SAMPLES, tuple(LOOPS), dict(ds2.fingers),
        expansion=exp, library=library)
    res = run_sweep(spec, workers=WORKERS)
    _report(f"hexprism, {len(units)} transitions", res)
    _keep(f"hexprism-{'-'.join(LOOPS)}-{SAMPLES}", res)
    print(f"   wall {res.wall_seconds:.1f} s")


def _demos() -> None:
    from nonprehensile.demonstrations.dataset import load_dataset

    ds = load_dataset("cube")
    exp = expand(ds.poly, ds.skills, states_by_step(ds.poly, 90))
    units = demonstration_units(ds, exp, angle_tol=1e-6)
    n = int(os.environ.get("NP_DEMO_SAMPLES", "5"))
    _, motions = motions_from_dataset("cube")
    spec = SweepSpec(ds.poly, ds.scale, tuple(units), DEFAULT_DISTRIBUTION.for_object(
        ds.poly, ds.scale), SEED, n, tuple(LOOPS), dict(ds.fingers),
        expansion=exp, library=frozen_library(exp, motions))
    res = run_sweep(spec, workers=WORKERS)
    _report("bundled demonstrations, each with its own motion", res)
    _keep(f"demos-{'-'.join(LOOPS)}-{n}", res)
    print(f"   wall {res.wall_seconds:.1f} s")


def _dask() -> None:
    import distributed

    poly, skills = read_skills(ROOT / "examples" / "cube_skills.json")
    exp = expand(poly, skills, states_by_step(poly, 90))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    units = transition_units(poly, exp, motions, scale=ds.scale, angle_tol=1e-6)[::7]
    spec = SweepSpec(poly, ds.scale, tuple(units), DEFAULT_DISTRIBUTION.for_object(
        poly, ds.scale), SEED, 5, tuple(LOOPS), dict(ds.fingers),
        expansion=exp, library=frozen_library(exp, motions))
    pool = run_sweep(spec, workers=WORKERS)
    with distributed.LocalCluster(n_workers=WORKERS, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        dsk = run_sweep(spec, scheduler=client)
    same = [r.outcome() for r in pool.records] == [r.outcome() for r in dsk.records]
    print(f"   Dask LocalCluster ({WORKERS} workers) vs process pool: {len(dsk.records)} "
          f"executions, equal sample by sample: {same} (wall {dsk.wall_seconds:.1f} s vs "
          f"{pool.wall_seconds:.1f} s)")


def main() -> None:
    parts = {"cube": _cube, "hexprism": _hexprism, "demos": _demos, "dask": _dask}
    print(f"   loops {LOOPS} (available {available_loops()}); workers {WORKERS}; samples "
          f"{SAMPLES}; load average {os.getloadavg()[0]:.1f}")
    for name in PARTS:
        if name in parts:
            print(f" - {name}", flush=True)
            t0 = time.perf_counter()
            parts[name]()
            print(f"   ({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
