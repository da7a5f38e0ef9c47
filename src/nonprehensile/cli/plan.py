"""``nonprehensile plan``: from skills to a plan (``skills`` is in :mod:`nonprehensile.cli.skills`,
``infer`` in :mod:`nonprehensile.cli.infer`, ``demo`` in :mod:`nonprehensile.cli.demo`).

Registered in :data:`nonprehensile.cli.COMMANDS`.
"""

from __future__ import annotations

from typing import Any

import click
from rich.table import Table

from nonprehensile.cli.common import (
    bounded,
    emit_json,
    err,
    fmt_num,
    handle_errors,
    out,
    stage_bars,
)
from nonprehensile.cli.options import (
    COORDINATE,
    angle_tol_option,
    atol_option,
    json_option,
    note_drift,
    number,
    parse_state,
    rtol_option,
    state_set,
    states_option,
    step_option,
)
from nonprehensile.cli.robot import (
    control_every,
    direction_option,
    load_robot,
    placement_doc,
    placement_note,
    robot_arms,
    robot_options,
    robot_skills,
    wants_robot,
)
from nonprehensile.errors import InputError
from nonprehensile.finger_budget import plan_with_fingers
from nonprehensile.geometry.units import metres_per_unit
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.pipeline import motions_from_dataset, write_plan_motions
from nonprehensile.planning import (
    DEFAULT_RELOCATION_COST,
    DEFAULT_ROBUSTNESS_THRESHOLD,
    RobustnessCosts,
)
from nonprehensile.states import State

__all__ = ["plan_cmd", "print_plan"]


def _parse_costs(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> dict[
        str, float] | None:
    if not value:
        return None
    out = {}
    for item in value:
        name, sep, num = item.partition("=")
        try:
            out[name] = float(num)
        except ValueError:
            raise click.BadParameter(
                f"expected SKILL=COST (e.g. push-roll=2.5), got {item!r}") from None
        if not sep or not name:
            raise click.BadParameter(f"expected SKILL=COST (e.g. push-roll=2.5), got {item!r}")
    return out


def print_plan(plan_doc: dict[str, Any]) -> None:
    """A plan as a person reads it: offset, then each step's events and motions."""
    off = plan_doc["offset"]
    out.print(
        f"plan {State.from_dict(plan_doc['start'])} -> {State.from_dict(plan_doc['goal'])}: "
        f"{len(plan_doc['steps'])} step(s), cost {fmt_num(plan_doc['cost'])}; relocate the "
        f"agent by {fmt_num(off['rotate_deg'])} degrees and ({fmt_num(off['translate'][0])}, "
        f"{fmt_num(off['translate'][1])})"
        + (f"; it relocates {plan_doc.get('relocations')} more time(s) between steps"
           if plan_doc.get("relocations") else "")
    )
    for i, step in enumerate(plan_doc["steps"], start=1):
        agent = step.get("agent")
        where = ""
        if agent is not None:
            moved = "relocated: " if step.get("relocated") and i > 1 else ""
            where = (f"; {moved}agent at {fmt_num(agent['rotate_deg'])} deg, "
                     f"({fmt_num(agent['translate'][0])}, {fmt_num(agent['translate'][1])})")
        t = Table(title=f"step {i}: {State.from_dict(step['from'])} -> "
                        f"{State.from_dict(step['to'])} by {step['skill']} ({step['maneuver']}, "
                        f"{'demonstrated' if step['demonstrated'] else 'inferred'}){where}")
        t.add_column("event")
        t.add_column("contacts")
        t.add_column("then")
        t.add_column("reference motion")
        for j, ev in enumerate(step["events"]):
            m = step["motions"][j] if j < len(step["motions"]) else None
            ref = m["reference"] if m else None
            n_demos = ref["n_demonstrations"] if ref else 0
            ref_text = (f"cluster {ref['cluster']} medoid of {n_demos} "
                        f"demonstration{'' if n_demos == 1 else 's'}, {ref['n_frames']} frames"
                        if ref else ("-" if m else ""))
            t.add_row(ev["id"], " ∧ ".join(ev["contacts"]), m["label"] if m else "", ref_text)
        out.print(t)


def _write_joints(robot_kw: dict[str, Any], robot: Any, poly: Any, ds: Any, result: Any,
                  out_dir: str, doc: dict[str, Any]) -> list[Any]:
    """The robot's joint trajectories of the plan, per step and whole (CSV + JSON)."""
    from nonprehensile.sim.ik import IKConfig
    from nonprehensile.sim.placement import joint_trajectory, write_joint_trajectories
    from nonprehensile.sim.robot_run import describe_robots
    from nonprehensile.sim.robot_scene import build_robot_scene
    from nonprehensile.sim.scene import DEFAULT_PARAMS

    arms, placement = robot_arms(robot_kw, poly, ds.scale, result, ds.fingers, DEFAULT_PARAMS,
                                 robot)
    cfg = IKConfig()
    every = control_every(robot_kw, DEFAULT_PARAMS.timestep)
    direction = robot_kw.get("finger_direction", "lean")
    trajectories = joint_trajectory(arms, poly, ds.scale, result, ds.fingers, ik_config=cfg,
                                    control_every=every, finger_direction=direction)
    scene = build_robot_scene(poly, scale=ds.scale, arms=arms, params=DEFAULT_PARAMS)
    meta = describe_robots(arms, scene, DEFAULT_PARAMS, cfg, every)
    meta["placement"] = placement_doc(placement)
    meta["finger_direction"] = direction
    meta["note"] = ("kinematic: the IK along the plan's fingertip reference at the control rate, "
                    "each step and each transit between steps (transitK: to step K's first "
                    "target, clear of the object) ending at rest, "
                    "the object at each step's planned start pose; `simulate plan --robot` "
                    "executes it in physics. The CSV holds the IK's joint positions and "
                    "velocities; the controller's acceleration feed-forward "
                    "(controller.acceleration_feedforward) is the executing controller's own, "
                    "computed from its model as it runs, not written here")
    doc["robot"] = meta
    note = placement_note(meta["placement"])
    if note is not None:
        err.print(note, markup=False, highlight=False)
    written = list(write_joint_trajectories(trajectories, out_dir, meta))
    if placement is not None:  # searched: the reachability map of each arm's search
        from pathlib import Path

        import numpy as np

        from nonprehensile.sim.placement import plan_targets
        from nonprehensile.viz import save_figure
        from nonprehensile.viz._figures import require_matplotlib
        from nonprehensile.viz.reachability import reachability_figure

        try:
            require_matplotlib()
        except InputError as exc:  # the trajectories are written; the picture is optional
            err.print(f"no reachability map: {exc}")
            return written
        searched = placement if isinstance(placement, list) else [placement]
        per_arm = len(robot.tip_sites) if robot is not None else 1
        paths = plan_targets(result, ds.fingers, per_arm * len(searched))
        for i, pl in enumerate(searched):
            xy = np.concatenate([arr[:, i * per_arm, :2] for arr, _ in paths])
            name = "reachability.png" if len(searched) == 1 else f"reachability_arm{i + 1}.png"
            written.append(save_figure(
                reachability_figure(pl.candidates_dict(), pl.base.to_dict(), xy),
                Path(out_dir) / name))
    return written


@click.command("plan")
@click.argument("skills_file", type=click.Path(dir_okay=False))
@click.option("--from", "start", required=True, callback=parse_state,
              help="Start state FACE:THETA as the object lies (any orientation).")
@click.option("--to", "goal", required=True, callback=parse_state,
              help="Goal state FACE:THETA in the same (world) frame.")
@step_option
@states_option
@click.option("--at", "position", type=(COORDINATE, COORDINATE), default=(0.0, 0.0),
              show_default=True,
              help="Where the object is on the table (x y), for the agent's offset.")
@click.option("--cost", "costs", multiple=True, callback=_parse_costs,
              help="Cost of a skill, SKILL=COST (repeatable); default 1 per transition.")
@click.option("--relocation-cost", type=number(0.0, 1e9), default=DEFAULT_RELOCATION_COST,
              show_default=True,
              help="Cost of relocating the agent between steps (its first placement is free).")
@click.option("--dataset", default=None,
              help="Demonstrations (a dataset folder, or `cube`) to attach reference motions.")
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False),
              help="Write each step's reference trajectories here (C3D and CSV).")
@robot_options
@direction_option
@click.option("--robustness", "rates_file", type=click.Path(dir_okay=False), default=None,
              help="Success rates measured across the physics distribution (`simulate "
                   "robustness -o FILE`): they become arc costs, and transitions below "
                   "--robustness-threshold are avoided.")
@click.option("--robustness-threshold", type=bounded(float, 0.0, 1.0),
              default=DEFAULT_ROBUSTNESS_THRESHOLD, show_default=True,
              help="Avoid transitions whose measured success rate is below this.")
@click.option("--robustness-loop", type=click.Choice(["closed", "open"]), default=None,
              help="Whose rates to use (default: closed loop if the file holds it).")
@click.option("--robustness-weight", type=bounded(float, 0.0, 1e6), default=1.0,
              show_default=True,
              help="Cost per unit of -ln(success rate) added to a transition's cost.")
@click.option("--html", "html_out", default=None, type=click.Path(dir_okay=False),
              help="Write a rotatable 3-D view of the plan: one self-contained HTML file "
              "(plotly.js embedded, opens offline) with the object's pose at each step, the "
              "reference finger paths (with --dataset) and the agent; needs the view3d extra.")
@rtol_option
@atol_option
@angle_tol_option
@json_option
@handle_errors
def plan_cmd(
    skills_file: str, start: State, goal: State, step: float | None, states_file: str | None,
    position: tuple[float, float], costs: dict[str, float] | None, relocation_cost: float,
    dataset: str | None, out_dir: str | None, rates_file: str | None,
    robustness_threshold: float, robustness_loop: str | None, robustness_weight: float,
    html_out: str | None, rtol: float | None, atol: float | None, angle_tol: float,
    as_json: bool, **robot_kw: Any,
) -> None:
    """Plan transitions, contact events and finger motions from --from to --to."""
    use_robot = wants_robot(robot_kw)
    if use_robot and (out_dir is None or dataset is None):
        raise InputError("--robot writes the plan's joint trajectories: give --dataset and "
                         "--out DIR too")
    robot = load_robot(robot_kw) if use_robot else None
    if use_robot:  # a bad --control-rate is refused now, before any planning
        from nonprehensile.sim.scene import DEFAULT_PARAMS

        control_every(robot_kw, DEFAULT_PARAMS.timestep)
    poly, every_skill = read_skills(skills_file, rtol=rtol, angle_tol=angle_tol)
    # a robot plans with the skills it has fingertips for (as `simulate plan --robot`)
    skills, tips = robot_skills(robot, robot_kw, every_skill)
    if costs and len(skills) < len(every_skill):  # a set-aside skill's cost weighs nothing
        aside = {s.name for s in every_skill} - {s.name for s in skills}
        costs = {k: v for k, v in costs.items() if k not in aside} or None
    states = state_set(poly, step, states_file, angle_tol)
    exp = expand(poly, skills, states, atol=atol, angle_tol=angle_tol)
    note_drift(exp, angle_tol)
    if out_dir is not None and dataset is None:
        raise InputError("--out writes reference trajectories: give --dataset too")
    if html_out is not None and not html_out.lower().endswith((".html", ".htm")):
        raise InputError(f"--html {html_out}: the 3-D view is an HTML file; name it .html")
    robustness = None
    if rates_file is not None:
        from nonprehensile.success_rates import read_success_rates

        rates = read_success_rates(rates_file)
        if rates.object != poly.name:
            raise InputError(f"{rates_file}: its rates were measured on object "
                             f"{rates.object!r}, not on {poly.name!r}")
        if not rates.loops():
            raise InputError(f"{rates_file}: holds no measured transition")
        robustness = RobustnessCosts(rates, robustness_loop or rates.loops()[0],
                                     robustness_threshold, robustness_weight)
    motions = None
    # world positions in metres: from the model's units, or the dataset's recorded scale
    scale = metres_per_unit(poly.units)
    markers: list[str] | None = None
    if dataset is not None:
        with stage_bars(as_json) as bars:
            ds, motions = motions_from_dataset(dataset, skills=skills, poly=poly,
                                               progress=bars, angle_tol=angle_tol)
        scale = ds.scale
        markers = list(ds.fingers.values())
    result = plan_with_fingers(poly, exp, start, goal, **tips, skills=every_skill,
                               states=states, atol=atol, position=position, costs=costs,
                               motions=motions, angle_tol=angle_tol, scale=scale,
                               relocation_cost=relocation_cost, robustness=robustness)
    doc = result.to_dict()
    if out_dir is not None:
        written = write_plan_motions(result, out_dir)
        if use_robot:
            written += _write_joints(robot_kw, robot, poly, ds, result, out_dir, doc)
        doc["files"] = [str(p) for p in written]
        err.print(f"wrote {len(written)} files to {out_dir}")
    if html_out is not None:
        from nonprehensile.viz.view3d import plan_view, write_html

        write_html(plan_view(poly, result, scale=scale, markers=markers,
                             units="m" if dataset is not None else poly.units), html_out)
        doc["html"] = str(html_out)
        err.print(f"wrote {html_out}")
    if as_json:
        emit_json(doc)
        return
    print_plan(doc)
    if doc.get("robustness") is not None:
        print_robustness(doc["robustness"])


def print_robustness(rob: dict[str, Any]) -> None:
    """What the measured success rates did to a plan."""
    avoided = rob["avoided"]
    by_skill: dict[str, int] = {}
    for a in avoided:
        by_skill[a["skill"]] = by_skill.get(a["skill"], 0) + 1
    est = rob.get("estimated_success")
    out.print(
        f"success rates ({rob['loop']} loop): {len(avoided)} transition(s) avoided below "
        f"{100 * rob['threshold']:g} %"
        + (f" ({', '.join(f'{k}: {v}' for k, v in sorted(by_skill.items()))})"
           if by_skill else "")
        + (f"; every step succeeding: {100 * est:.0f} % (the measured rates' product)"
           if est is not None else "")
        + (f"; {rob['unmeasured_steps']} step(s) not measured" if rob["unmeasured_steps"]
           else ""))
    for a in avoided[:20]:
        out.print(f"  avoided {a['skill']} {State.from_dict(a['from'])} -> "
                  f"{State.from_dict(a['to'])}: {a['reason']}", markup=False)
    if len(avoided) > 20:
        out.print(f"  ... and {len(avoided) - 20} more (--json lists them all)")
    if "without_rates" in rob:
        steps = ", ".join(f"{m['skill']} {State.from_dict(m['from'])} -> "
                          f"{State.from_dict(m['to'])}"
                          + (f" ({100 * m['success']['rate']:.0f} %)" if m["success"] else "")
                          for m in rob["without_rates"])
        out.print(f"without the rates the plan would be: {steps}", markup=False)
