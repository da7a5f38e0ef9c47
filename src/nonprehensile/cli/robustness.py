"""``nonprehensile simulate robustness``: transitions or a plan judged across the physics
distribution (registered in the ``simulate`` group by :mod:`nonprehensile.cli.sim`)."""

from __future__ import annotations

from typing import Any

import click
from rich.table import Table

from nonprehensile.cli.common import (
    bounded,
    emit_json,
    err,
    handle_errors,
    out,
    record_options,
    stage_bars,
)
from nonprehensile.cli.options import (
    COORDINATE,
    angle_tol_option,
    json_option,
    note_drift,
    parse_state,
    state_set,
    states_option,
    step_option,
)
from nonprehensile.cli.robot import (
    auto_switch_of,
    compliance_option,
    control_every,
    direction_option,
    force_feedforward_option,
    load_robot,
    placement_doc,
    placement_note,
    press_option,
    radius_offset_option,
    robot_options,
    robot_skills,
    wants_robot,
)
from nonprehensile.errors import InputError
from nonprehensile.states import State

__all__ = ["robustness_cmd"]


def _optional_state(ctx: click.Context, param: click.Parameter, value: str | None
                    ) -> State | None:
    return None if value is None else parse_state(ctx, param, value)


def _loops(value: str) -> list[str]:
    return ["closed", "open"] if value == "both" else [value]


def _pct(d: dict[str, Any]) -> str:
    if not d["n"]:
        return "-"
    lo, hi = d["ci95"]
    return f"{d['k']}/{d['n']} {100 * d['rate']:.0f} % ({100 * lo:.0f}-{100 * hi:.0f})"


@click.command("robustness")
@click.argument("skills_file", type=click.Path(dir_okay=False))
@click.option("--dataset", default="cube", show_default=True,
              help="Demonstrations (a folder, or `cube`) giving the planner's reference "
                   "motions (per-arc cluster medoids).")
@step_option
@states_option
@click.option("--from", "start", default=None, callback=_optional_state,
              help="Sweep the plan from this state (with --to) instead of every transition.")
@click.option("--to", "goal", default=None, callback=_optional_state, help="The plan's goal.")
@click.option("--at", "position", type=(COORDINATE, COORDINATE), default=(0.0, 0.0),
              show_default=True,
              help="Where the object is on the table (x y, metres), with --from/--to.")
@click.option("--demonstrations", is_flag=True,
              help="Sweep the dataset's own demonstrations (each replayed with its recorded "
                   "motion as the reference) instead of the transitions.")
@click.option("--skill", "skill_names", multiple=True,
              help="Only transitions of these demonstrated skills (repeatable; "
                   "NAME:reverse for a reversed one).")
@click.option("--samples", type=bounded(int, 1, 100_000), default=20, show_default=True,
              help="Samples of the physics distribution per transition (or plan).")
@click.option("--seed", type=bounded(int, 0, 2**63 - 1), default=0, show_default=True,
              help="Seed of the samples (sample i of transition u: SeedSequence([seed, u, "
                   "i])).")
@click.option("--loop", type=click.Choice(["closed", "open", "both"]), default="both",
              show_default=True, help="Execution loop(s); both: closed and open side by side "
                                      "on the same samples.")
@click.option("--workers", type=bounded(int, 1, 256), default=None,
              help="Processes (one MuJoCo model each; default: the machine's cores).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Run on this Dask scheduler (tcp://host:8786) instead of a process pool "
                   "(extra `scale`).")
@click.option("--bins", "n_bins", type=bounded(int, 1, 50), default=4, show_default=True,
              help="Bins per parameter for the rates against each parameter.")
@click.option("--tol-deg", type=bounded(float, 1e-3, 180.0), default=5.0, show_default=True,
              help="A final theta within this many degrees is the predicted state.")
@click.option("--position-tol", type=bounded(float, 1e-5, 1.0), default=0.010,
              show_default=True,
              help="A final centre of mass within this many metres of the prediction.")
@click.option("-o", "--output", "rates_file", type=click.Path(dir_okay=False), default=None,
              help="Write the per-transition success rates here (JSON) for "
                   "`plan --robustness FILE`.")
@click.option("--figure", type=click.Path(dir_okay=False), default=None,
              help="Draw success against each parameter (open and closed loop) to this "
                   "image.")
@click.option("--no-replan", is_flag=True,
              help="Closed loop: a step that ends elsewhere fails (default: re-plan from the "
                   "observed state toward the goal, as `simulate plan`).")
@click.option("--no-records", is_flag=True,
              help="Leave the per-execution records out of the JSON.")
@record_options("every execution's steps")
@angle_tol_option
@robot_options
@compliance_option
@force_feedforward_option
@radius_offset_option
@press_option
@direction_option
@json_option
@handle_errors
def robustness_cmd(skills_file: str, dataset: str, step: float | None,
                   states_file: str | None, start: State | None, goal: State | None,
                   position: tuple[float, float], demonstrations: bool,
                   skill_names: tuple[str, ...], samples: int,
                   seed: int, loop: str, workers: int | None, scheduler: str | None,
                   n_bins: int, tol_deg: float, position_tol: float, rates_file: str | None,
                   figure: str | None, no_replan: bool, no_records: bool,
                   record: str | None, record_fps: float, angle_tol: float,
                   as_json: bool, **robot_kw: Any) -> None:
    """Execute every transition (or the plan --from --to) across the physics distribution:
    success rates with 95 % intervals per transition, per skill and per parameter bin. With
    --robot or --robot-xml robot arms execute them, one base placement for the whole sweep
    (searched over the units' fingertip paths, or --base) (docs/robot.md)."""
    use_robot = wants_robot(robot_kw)
    if use_robot and record:
        raise InputError("--record writes free-fingertip episodes; it does not take a robot "
                         "yet (drop --robot, or --record)")
    robot = load_robot(robot_kw) if use_robot else None
    n_bases, n_arms = len(robot_kw.get("base") or ()), int(robot_kw.get("n_arms", 1))
    if n_bases and n_bases != n_arms:  # before any work
        raise InputError(f"--base given {n_bases} time(s) for {n_arms} arm(s): give one "
                         "X Y YAW per arm, or none to search them")
    if (start is None) != (goal is None):
        raise InputError("give both --from and --to (a plan), or neither (every transition)")
    if start is not None and rates_file is not None:
        raise InputError("-o writes per-transition rates for the planner: sweep the "
                         "transitions (leave out --from/--to)")
    if start is not None and demonstrations:
        raise InputError("--demonstrations sweeps the dataset's demonstrations: leave out "
                         "--from/--to")
    if demonstrations and rates_file is not None:
        raise InputError("-o writes per-transition rates for the planner: sweep the "
                         "transitions (leave out --demonstrations)")
    if start is not None and skill_names:
        raise InputError("--skill selects transitions; a plan (--from/--to) uses what the "
                         "planner picks")
    if workers is not None and scheduler is not None:
        raise InputError("give --workers (a process pool) or --scheduler (Dask), not both")
    from nonprehensile.cli.sim import _check_record

    _check_record(record)
    try:
        import nonprehensile.sim.robustness as rob
    except ImportError as exc:
        raise InputError(f"simulation needs MuJoCo: pip install 'nonprehensile[sim]' ({exc})"
                         ) from None
    from nonprehensile.finger_budget import plan_with_fingers
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION

    # the physics rate is the distribution's (it does not vary the timestep)
    every = control_every(robot_kw, DEFAULT_DISTRIBUTION.base.timestep) if use_robot else 1

    loops = _loops(loop)
    rob.check_loops(loops)  # before any work: a missing loop is never replaced
    if figure is not None:
        from nonprehensile.viz._figures import require_matplotlib

        require_matplotlib()
    poly, every_skill = read_skills(skills_file, angle_tol=angle_tol)
    # sweep (and re-plan) only skills the robot has fingers for
    skills, tips = robot_skills(robot, robot_kw, every_skill)
    states = state_set(poly, step, states_file, angle_tol)
    exp = expand(poly, skills, states, angle_tol=angle_tol)
    note_drift(exp, angle_tol)
    if skill_names and start is None and not demonstrations:  # before loading the data
        known = sorted({t.source.name for t in exp.transitions})
        unknown = sorted(set(skill_names) - set(known))
        set_aside = {s.name: s for s in every_skill} if robot is not None else {}
        for k in (s.name for s in skills):
            set_aside.pop(k, None)
        too_few = [n for n in unknown if n.removesuffix(":reverse") in set_aside]
        if too_few:  # a skill the robot has no fingertips for is not swept
            from nonprehensile.finger_budget import fingers_needed, more_fingertips

            need = max(fingers_needed(set_aside[n.removesuffix(":reverse")])
                       for n in too_few)
            raise InputError(f"--skill {too_few}: needs {need} fingertips and the "
                             f"robot has {tips['n_fingers']} (only the skills it has "
                             "fingertips for are swept): "
                             f"{more_fingertips(need, tips['per_arm'])}")
        if unknown:
            raise InputError(f"--skill {unknown}: no transition of that skill; the "
                             f"transitions' skills are {known}")
    with stage_bars(as_json) as bars:
        ds, motions = motions_from_dataset(dataset, skills=skills, poly=poly, progress=bars,
                                           angle_tol=angle_tol)
        if start is not None and goal is not None:
            p = plan_with_fingers(poly, exp, start, goal, **tips, skills=every_skill,
                                  states=states, position=position, motions=motions,
                                  angle_tol=angle_tol, scale=ds.scale)
            if not p.steps:
                raise InputError(f"{start} is already the goal {goal}: nothing to execute")
            units = [rob.plan_unit(p)]
        elif demonstrations:
            known = sorted({d.skill.name for d in ds.demonstrations})
            unknown = sorted(set(skill_names) - set(known))
            if unknown:
                raise InputError(f"--skill {unknown}: the dataset demonstrates {known}")
            units = rob.demonstration_units(ds, exp, angle_tol=angle_tol,
                                            skills=list(skill_names) or None)
        else:
            units = rob.transition_units(poly, exp, motions, scale=ds.scale,
                                         angle_tol=angle_tol,
                                         sources=list(skill_names) or None)
        replan = {}
        if not no_replan:  # closed loop re-plans from what it observes, as `simulate plan`
            replan = {"expansion": exp, "library": rob.frozen_library(exp, motions)}
        dist = DEFAULT_DISTRIBUTION.for_object(poly, ds.scale)
        sweep_robot, placement = None, None
        if robot is not None:
            sweep_robot, placement = _sweep_robot(robot_kw, robot, units, poly, ds, dist,
                                                  every)
            note = placement_note(placement_doc(placement))
            if note is not None:  # said before the sweep runs from there
                err.print(note, markup=False, highlight=False)
        spec = rob.SweepSpec(poly, ds.scale, tuple(units), dist, seed, samples,
                             tuple(loops), dict(ds.fingers), tol_deg, position_tol, **replan,
                             record_fps=record_fps if record else None, robot=sweep_robot)
        result = rob.run_sweep(spec, workers=workers, scheduler=scheduler,
                               progress=lambda d, n: bars("executing", d, n))
    doc = result.to_dict(records=not no_records, n_bins=n_bins)
    doc["dataset"] = dataset
    if sweep_robot is not None:
        doc["placement"] = placement_doc(placement)
        doc["robot_metrics"] = _robot_summary(result)
    if record:
        from nonprehensile.export import write_episodes

        episodes = [e for r in result.records for e in r.episodes]
        write_episodes(episodes, record, extra_info={
            "source": "simulate robustness", "object": poly.name,
            "scale_m_per_unit": ds.scale, "seed": seed, "samples": samples, "loops": loops})
        doc["record"] = {"output": record, "n_episodes": len(episodes),
                         "n_frames": sum(e.n_frames for e in episodes), "fps": record_fps}
        err.print(f"recorded {len(episodes)} episodes ({doc['record']['n_frames']} frames at "
                  f"{record_fps:g} fps) to {record}", markup=False)
    if rates_file is not None:
        result.rates({"dataset": dataset, "step": step}).write(rates_file)
        doc["rates_file"] = rates_file
        err.print(f"wrote the success rates to {rates_file}", markup=False)
    if figure is not None:
        from nonprehensile.viz import save_figure
        from nonprehensile.viz.robustness import robustness_figure

        save_figure(robustness_figure(doc), figure)
        doc["figure"] = figure
        err.print(f"wrote {figure}", markup=False)
    if as_json:
        emit_json(doc)
        return
    _print(doc, loops)


def _sweep_robot(kw: dict[str, Any], robot: Any, units: list[Any], poly: Any, ds: Any,
                 dist: Any, every: int) -> tuple[Any, Any]:
    """The sweep's arms: at --base, or placed once for all units."""
    import nonprehensile.sim.robustness as rob

    n_arms = int(kw.get("n_arms", 1))
    bases = list(kw.get("base") or ())
    if bases:  # as many as arms (checked before any work)
        from nonprehensile.sim.robot import BasePose
        from nonprehensile.sim.robot_scene import Arm

        arms = [Arm(robot, BasePose(x, y, yaw)) for x, y, yaw in bases]
        placement = None
    else:
        arms, found = rob.place_sweep_arms(robot, units, poly, ds.scale, ds.fingers,
                                           n_arms=n_arms, params=dist.base)
        placement = found[0] if n_arms == 1 else found
    return rob.SweepRobot(tuple(arms), every, compliance=bool(kw.get("compliance")),
                          press_depth=kw.get("press_depth", "auto"),
                          finger_direction=kw.get("finger_direction", "lean"),
                          force_feedforward=auto_switch_of(kw, "force_feedforward"),
                          radius_offset=auto_switch_of(kw, "radius_offset")), placement


def _robot_summary(result: Any) -> dict[str, Any]:
    """The robot's worst figures over every execution (None where no execution gave one)."""
    ms = [r.extra["robot"] for r in result.records if "robot" in r.extra]

    def worst(key: str, pick: Any) -> Any:
        vals = [m[key] for m in ms if m.get(key) is not None]
        return pick(vals) if vals else None

    return {
        "executions": len(ms),
        "tracking_error_contact_max_m": worst("tracking_error_contact_max_m", max),
        "longest_at_limit_s": worst("longest_at_limit_s",
                                    lambda v: max(max(d.values(), default=0.0) for d in v)),
        "other_contact_s_max": worst("other_contact_s", max),
        "ik_median_ms_max": worst("ik_median_ms", max),
    }


def _print(doc: dict[str, Any], loops: list[str]) -> None:
    t = Table(title=f"{doc['object']}: success across the physics distribution "
                    f"({len(doc['units'])} unit(s) x {doc['samples']} samples, seed "
                    f"{doc['seed']}; k/n, rate, 95 % interval)")
    t.add_column("source skill")
    for lp in loops:
        t.add_column(f"{lp} loop")
    for name, rates in doc["per_source_skill"].items():
        t.add_row(name, *(_pct(rates[lp]) for lp in loops))
    t.add_row("all", *(_pct(doc["overall"][lp]) for lp in loops))
    out.print(t)
    if len(doc["units"]) > 1:
        worst = sorted(doc["units"], key=lambda u: u[loops[0]]["rate"] or 0.0)[:10]
        w = Table(title=f"the {len(worst)} least robust transitions ({loops[0]} loop)")
        for c in ("skill", "from", "to", *(f"{lp} loop" for lp in loops)):
            w.add_column(c)
        for u in worst:
            w.add_row(u["skill"], str(State.from_dict(u["from"])), str(State.from_dict(u["to"])),
                      *(_pct(u[lp]) for lp in loops))
        out.print(w)
    b = Table(title="success per parameter bin")
    b.add_column("parameter")
    b.add_column("bin")
    for lp in loops:
        b.add_column(f"{lp} loop")
    for name, bins in doc["bins"].items():
        for i, bn in enumerate(bins):
            b.add_row(name if i == 0 else "", f"{bn['low']:.4g} - {bn['high']:.4g}",
                      *(_pct(bn[lp]) for lp in loops))
    out.print(b)
    if doc.get("robot_metrics"):
        m, rb = doc["robot_metrics"], doc["robot"]
        where = "; ".join(f"{r['robot']} at ({r['base']['x']:.3f}, {r['base']['y']:.3f}) m, "
                          f"{r['base']['yaw_deg']:.1f} deg" for r in rb["robots"])

        def mm(v: Any) -> str:
            return "-" if v is None else f"{1000 * v:.1f}"

        out.print(f"robot: {where}; worst over {m['executions']} executions: tracking in "
                  f"contact {mm(m['tracking_error_contact_max_m'])} mm, longest at a limit "
                  f"{mm(m['longest_at_limit_s'])} ms, link/rod contact "
                  f"{mm(m['other_contact_s_max'])} ms, IK median {m['ik_median_ms_max']} ms")
    out.print(f"{doc['physics_steps']} physics steps in {doc['wall_seconds']:.1f} s wall "
              f"({doc['how']})")
