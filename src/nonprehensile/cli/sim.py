"""``nonprehensile simulate``: execute demonstrations, transitions and plans in MuJoCo.

Registered in :data:`nonprehensile.cli.COMMANDS`. Exit 0 when everything ends as predicted,
1 when some transition ends elsewhere (listed), 2 on bad input.
"""

from __future__ import annotations

import sys
from collections import defaultdict
from collections.abc import Callable, Sequence
from typing import Any

import click
from rich.table import Table
from rich.text import Text

from nonprehensile.cli import HelpGroup
from nonprehensile.cli.common import (
    bounded,
    emit_json,
    err,
    handle_errors,
    out,
    progress_bar,
    record_options,
    stage_bars,
)
from nonprehensile.cli.options import (
    ANGLE,
    COORDINATE,
    POSITIVE,
    angle_tol_option,
    count,
    json_option,
    note_drift,
    number,
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
    robot_arms,
    robot_options,
    robot_skills,
    robot_table,
    wants_robot,
)
from nonprehensile.errors import InputError
from nonprehensile.states import State

__all__ = ["simulate_group"]

F = Callable[..., Any]


def _sim() -> Any:
    try:
        import nonprehensile.sim as sim
    except ImportError as exc:  # the extra is missing
        raise InputError(f"simulation needs MuJoCo: pip install 'nonprehensile[sim]' ({exc})"
                         ) from None
    return sim


#: --start-error's parts: metres, metres, degrees (the ranges _perturbation names).
_OFFSET = number(-0.05, 0.05, unit="m")
_YAW = number(-45.0, 45.0, unit="degrees")
#: A tolerance on the final position, metres.
_POSITION_TOL = number(0.0, 10.0, low_open=True, unit="m")
#: A noise standard deviation, metres.
_NOISE = number(0.0, 0.01, unit="m")


def _physics_options(fn: F) -> F:
    for opt in reversed([
        click.option("--friction", type=POSITIVE, default=None,
                     help="Object-table friction coefficient (default 0.6)."),
        click.option("--finger-friction", type=POSITIVE, default=None,
                     help="Object-fingertip friction coefficient (default 0.8)."),
        click.option("--mass", type=POSITIVE, default=None, help="Object mass, kg (default 0.1)."),
        click.option("--finger-radius", type=POSITIVE, default=None,
                     help="Fingertip sphere radius, m (default 0.006)."),
        click.option("--stiffness", type=POSITIVE, default=None,
                     help="Finger position gain, N/m per axis (default 600)."),
        click.option("--force-limit", type=POSITIVE, default=None,
                     help="Finger force limit, N per axis (default 8)."),
        click.option("--contact-timeconst", type=POSITIVE, default=None,
                     help="Contact softness: MuJoCo solref time constant, s (default 0.02; "
                          "smaller is stiffer, at least two 1 ms steps)."),
        click.option("--tol-deg", type=ANGLE, default=5.0, show_default=True,
                     help="A final theta within this many degrees is the predicted state."),
    ]):
        fn = opt(fn)
    return fn


def _perturbation_options(fn: F) -> F:
    for opt in reversed([
        click.option("--start-error", type=(_OFFSET, _OFFSET, _YAW), default=None,
                     metavar="DX DY DYAW",
                     help="The object really starts DX, DY metres and DYAW degrees (about "
                          "the vertical) from where it is believed to be."),
        click.option("--tracking-noise", type=_NOISE, default=None, metavar="M",
                     help="Object tracker noise, m (standard deviation per marker); only "
                          "closed-loop execution observes the object."),
        click.option("--finger-noise", type=_NOISE, default=None, metavar="M",
                     help="Fingertip position noise, m (standard deviation per axis, "
                          "50 ms correlation)."),
        click.option("--seed", type=count(0, 2**63 - 1), default=0, show_default=True,
                     help="Seed of the noise draws."),
    ]):
        fn = opt(fn)
    return fn


def _perturbation(kw: dict[str, Any], *, observed: bool = False) -> Any:
    """The --start-error / --tracking-noise / --finger-noise / --seed options as a
    Perturbation (popped from ``kw``); ``observed``: the execution watches the object."""
    _sim()
    from nonprehensile.sim.distribution import Perturbation

    se = kw.pop("start_error", None)
    tracking = kw.pop("tracking_noise", None)
    finger = kw.pop("finger_noise", None)
    seed = kw.pop("seed", 0)
    if seed is None or seed < 0 or seed >= 2**63:
        raise InputError(f"--seed must be a whole number in [0, 2^63), got {seed!r}")
    for name, v in (("--tracking-noise", tracking), ("--finger-noise", finger)):
        if v is not None and not (v == v and 0.0 <= v <= 0.01):  # v == v: not NaN
            raise InputError(f"{name} must be a number of metres in [0, 0.01], got {v!r}")
    if se is not None:
        for name, v, lim in zip(("DX", "DY", "DYAW"), se, (0.05, 0.05, 45.0), strict=True):
            if not (v == v and abs(v) <= lim):
                raise InputError(f"--start-error {name} must be a number in [-{lim:g}, "
                                 f"{lim:g}] ({'degrees' if name == 'DYAW' else 'm'}), "
                                 f"got {v!r}")
    if tracking and not observed:
        err.print("note: --tracking-noise changes nothing here: open-loop execution never "
                  "observes the object")
    return Perturbation(tuple(se) if se is not None else (0.0, 0.0, 0.0), tracking or 0.0,
                        finger or 0.0, seed)


def _params(kw: dict[str, Any]) -> Any:
    sim = _sim()
    names = {"friction": "friction_table", "finger_friction": "friction_finger",
             "mass": "mass", "finger_radius": "finger_radius", "stiffness": "stiffness",
             "force_limit": "max_force", "contact_timeconst": "contact_timeconst"}
    given = {names[k]: kw.pop(k) for k in list(names) if kw.get(k) is not None}
    for k in names:
        kw.pop(k, None)
    return sim.SimParams(**given)


def _finish(records: list[dict[str, Any]], as_json: bool, what: str,
            extra: dict[str, Any] | None = None) -> None:
    failed = [r for r in records if not r["success"]]
    if as_json:
        emit_json({"records": records, "n": len(records), "n_success": len(records) - len(failed),
                   **(extra or {})})
    else:
        for r in failed:
            sim = r.get("simulated")
            pos = r.get("position_error_m")
            err.print(f"ended elsewhere: {_name(r)}: predicted "
                      f"{State.from_dict(r['predicted'])}, simulated "
                      f"{State.from_dict(sim) if sim else 'no resting state'}"
                      + (f", {1000 * pos:.1f} mm from the predicted position"
                         if pos is not None else ""))
        out.print(f"{len(records) - len(failed)}/{len(records)} {what} ended as predicted")
    if failed:
        sys.exit(1)


def _name(r: dict[str, Any]) -> str:
    if "file" in r:
        return str(r["file"])
    if "step" in r:
        return f"step {r['step']} {r['skill']}"
    return f"{r['skill']} {State.from_dict(r['from'])} -> {State.from_dict(r['to'])}"


def _rate_table(title: str, records: list[dict[str, Any]], keys: Sequence[str]) -> Table:
    t = Table(title=title)
    for k in keys:
        t.add_column(k)
    t.add_column("ended as predicted")
    t.add_column("events in order")
    t.add_column("ms wall / transition")
    groups: dict[tuple[str, ...], list[dict[str, Any]]] = defaultdict(list)
    for r in records:
        groups[tuple(str(r[k]) for k in keys)].append(r)
    for key, rs in sorted(groups.items()):
        ok = sum(r["success"] for r in rs)
        chain = sum(r["chain_ok"] for r in rs)
        wall = 1000 * sum(r["simulation"]["wall_seconds"] for r in rs) / len(rs)
        t.add_row(*key, f"{ok}/{len(rs)}", f"{chain}/{len(rs)}", f"{wall:.0f}")
    return t


@click.group("simulate", cls=HelpGroup)
def simulate_group() -> None:
    """Execute demonstrations, inferred transitions and plans in the MuJoCo simulation."""


@simulate_group.command("dataset")
@click.argument("dataset", default="cube")
@click.option("--skill", "skill_names", multiple=True, help="Only these skills (repeatable).")
@_physics_options
@_perturbation_options
@json_option
@handle_errors
def simulate_dataset(dataset: str, skill_names: tuple[str, ...], as_json: bool,
                     tol_deg: float, **kw: Any) -> None:
    """Replay a dataset's demonstrations open loop: per skill and mentor, how many end in
    their annotated state."""
    params = _params(kw)
    pert = _perturbation(kw)
    sim = _sim()
    from nonprehensile.demonstrations.dataset import load_dataset
    from nonprehensile.sim.execute import fingers_of, replay_demonstration

    with stage_bars(as_json) as bars:
        ds = load_dataset(dataset, progress=lambda d, n: bars("loading", d, n))
        demos = [d for d in ds.demonstrations if not skill_names or d.skill.name in skill_names]
        if not demos:
            raise InputError(f"{dataset}: no demonstration of {list(skill_names)}; its skills "
                             f"are {[s.name for s in ds.skills]}")
        n = max(max(fingers_of(s), default=1) for s in ds.skills)
        simulator = sim.Simulator(ds.poly, scale=ds.scale, n_fingers=n, params=params)
        records = []
        for i, demo in enumerate(demos):
            records.append(replay_demonstration(
                simulator, ds, demo, angle_tol=tol_deg,
                perturbation=pert, noise_stream=f"finger/demo{i}").to_dict())
            bars("simulating", i + 1, len(demos))
    if not as_json:
        out.print(_rate_table(f"{dataset}: demonstrations replayed", records,
                              ["skill", "mentor"]))
    _finish(records, as_json, "demonstrations", {"params": params.to_dict(),
                                                 "perturbation": pert.to_dict()})


@simulate_group.command("infer")
@click.argument("skills_file", type=click.Path(dir_okay=False))
@click.option("--dataset", default="cube", show_default=True,
              help="Demonstrations (a folder, or `cube`) giving the reference motions.")
@click.option("--reference", type=click.Choice(["cluster", "demonstration"]),
              default="cluster", show_default=True,
              help="Each skill's motion: each arc's cluster medoid, the planner's own "
                   "references; or the skill's medoid demonstration taken whole.")
@click.option("--position-tol", type=_POSITION_TOL, default=0.010, show_default=True,
              help="A final position within this many metres of where the exact maneuver "
                   "puts the object.")
@click.option("--loop", type=click.Choice(["open", "closed"]), default="open",
              show_default=True,
              help="open: each reference runs where the object is predicted; closed: each "
                   "transition executed by the event-driven controller (transits, retries, "
                   "the final position correction; no re-plan: a transition is one step).")
@step_option
@states_option
@angle_tol_option
@_physics_options
@_perturbation_options
@json_option
@handle_errors
def simulate_infer(skills_file: str, dataset: str, reference: str, position_tol: float,
                   loop: str, step: float | None, states_file: str | None, angle_tol: float,
                   as_json: bool, tol_deg: float, **kw: Any) -> None:
    """Every demonstrated and inferred transition: predicted vs simulated final state and
    position."""
    params = _params(kw)
    pert = _perturbation(kw, observed=loop == "closed")
    if not (position_tol == position_tol and 0.0 < position_tol <= 1.0):  # not NaN
        raise InputError(f"--position-tol must be a number of metres in (0, 1], got "
                         f"{position_tol!r}")
    sim = _sim()
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import step_for
    from nonprehensile.sim.execute import fingers_of, simulate_step

    poly, skills = read_skills(skills_file, angle_tol=angle_tol)
    states = state_set(poly, step, states_file, angle_tol)
    exp = expand(poly, skills, states, angle_tol=angle_tol)
    with stage_bars(as_json) as bars:
        motions: Any
        if reference == "cluster":
            ds, motions = motions_from_dataset(dataset, skills=skills, poly=poly,
                                               progress=bars, angle_tol=angle_tol)
        else:
            from nonprehensile.demonstrations.dataset import load_dataset
            from nonprehensile.demonstrations.segment import segment_dataset
            from nonprehensile.sim.execute import DemonstrationLibrary

            ds = load_dataset(dataset, progress=lambda d, n: bars("loading", d, n),
                              angle_tol=angle_tol)
            if dict(ds.poly.faces) != dict(poly.faces):
                raise InputError(f"{dataset}: its demonstrations are of object "
                                 f"{ds.poly.name!r}, not of the skills file's {poly.name!r}")
            motions = DemonstrationLibrary(segment_dataset(ds)[1])
        n = max(max(fingers_of(t.skill), default=1) for t in exp.transitions)
        simulator = sim.Simulator(poly, scale=ds.scale, n_fingers=n, params=params)
        records = []
        if loop == "closed":
            from nonprehensile.control import ControlConfig
            from nonprehensile.planning import Offset, Plan
            from nonprehensile.sim.closed_loop import execute_plan, transition_record

            cfg = ControlConfig(angle_tol=tol_deg, position_tol=position_tol)
        for i, t in enumerate(exp.transitions):
            st = step_for(poly, t, motions=motions, scale=ds.scale, angle_tol=angle_tol)
            if loop == "closed":
                ex = execute_plan(simulator, Plan(st.start_world, st.end_world, Offset(),
                                                  (st,)),
                                  fingers=ds.fingers, config=cfg, perturbation=pert)
                records.append(transition_record(ex, st))
            else:
                records.append(simulate_step(
                    simulator, st, fingers=ds.fingers, angle_tol=tol_deg,
                    position_tol=position_tol, perturbation=pert,
                    noise_stream=f"finger/transition{i}").to_dict())
            bars("simulating", i + 1, len(exp.transitions))
    if not as_json:
        out.print(_rate_table(f"{poly.name}: transitions simulated", records,
                              ["source", "demonstrated"]))
    _finish(records, as_json, "transitions", {"params": params.to_dict(),
                                              "perturbation": pert.to_dict()})


@simulate_group.command("plan")
@click.argument("skills_file", type=click.Path(dir_okay=False))
@click.option("--from", "start", required=True, callback=parse_state,
              help="Start state FACE:THETA as the object lies.")
@click.option("--to", "goal", required=True, callback=parse_state, help="Goal state.")
@click.option("--at", "position", type=(COORDINATE, COORDINATE), default=(0.0, 0.0),
              show_default=True,
              help="Where the object is on the table (x y), metres.")
@click.option("--dataset", default="cube", show_default=True,
              help="Demonstrations (a folder, or `cube`) giving the reference motions.")
@click.option("--position-tol", type=_POSITION_TOL, default=0.010, show_default=True,
              help="A final position within this many metres of the goal position.")
@click.option("--loop", type=click.Choice(["closed", "open"]), default="closed",
              show_default=True,
              help="closed: event-driven, each arc anchored on the observed object, re-plans "
                   "when a step ends elsewhere; open: each step's reference runs where the "
                   "plan predicts the object.")
@click.option("--observation-rate", type=number(1.0, 1e5, unit="Hz"), default=120.0,
              show_default=True, metavar="HZ",
              help="Closed loop: the object tracker's sample rate.")
@click.option("--latency", type=number(0.0, 1.0, unit="s"), default=0.0, show_default=True,
              metavar="S",
              help="Closed loop: the tracker's latency, seconds.")
@click.option("--max-replans", type=count(0, 100), default=12, show_default=True,
              help="Closed loop: retries and re-plans allowed in one execution.")
@record_options("the executed steps, one episode per executed step,")
@step_option
@states_option
@angle_tol_option
@_physics_options
@_perturbation_options
@robot_options
@compliance_option
@force_feedforward_option
@radius_offset_option
@press_option
@direction_option
@json_option
@handle_errors
def simulate_plan_cmd(skills_file: str, start: State, goal: State,
                      position: tuple[float, float], dataset: str, position_tol: float,
                      loop: str, observation_rate: float, latency: float, max_replans: int,
                      record: str | None, record_fps: float,
                      step: float | None, states_file: str | None, angle_tol: float,
                      as_json: bool, tol_deg: float, **kw: Any) -> None:
    """Plan as `plan` does, then execute the plan in one continuous simulation, closed loop
    (default) or open loop, with transits between steps; the goal is the plan's last state at
    the position the plan predicts for it. With --robot or --robot-xml a robot arm executes
    it (docs/robot.md)."""
    robot_kw = {k: kw.pop(k) for k in ("robot", "robot_xml", "tip_sites", "base",
                                       "control_rate", "n_arms", "compliance", "press_depth",
                                       "finger_direction", "force_feedforward",
                                       "radius_offset")}
    use_robot = wants_robot(robot_kw)
    if loop == "open" and robot_kw.get("finger_direction") == "recorded":
        err.print("note: --finger-direction recorded changes nothing here: open loop, the "
                  "reference is never placed on the object as observed, and the finger "
                  "tools point by the rule")
    if use_robot and record:
        raise InputError("--record writes free-fingertip episodes; it does not take a robot "
                         "yet (drop --robot, or --record)")
    robot = load_robot(robot_kw) if use_robot else None
    params = _params(kw)
    # a bad --control-rate is refused now, before the dataset is loaded and the plan made
    every = control_every(robot_kw, params.timestep) if use_robot else 1
    pert = _perturbation(kw, observed=loop == "closed")
    sim = _sim()
    _check_record(record)
    from nonprehensile.control import ControlConfig, replanner
    from nonprehensile.finger_budget import plan_with_fingers
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.observation import ObservationModel
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.sim.closed_loop import execute_plan, scene_fingers

    # bad settings are refused before any work (one line naming the option, exit 2)
    options = {"angle_tol": "--tol-deg", "position_tol": "--position-tol",
               "max_replans": "--max-replans", "observation rate": "--observation-rate",
               "observation latency": "--latency"}
    try:
        cfg = ControlConfig(angle_tol=tol_deg, position_tol=position_tol,
                            max_replans=max_replans)
        obs_model = ObservationModel(rate=observation_rate, latency=latency)
    except InputError as exc:
        named = next((o for k, o in options.items() if k in str(exc)), None)
        raise InputError(f"{named}: {exc}" if named else str(exc)) from None
    poly, every_skill = read_skills(skills_file, angle_tol=angle_tol)
    skills, tips = robot_skills(robot, robot_kw, every_skill)
    states = state_set(poly, step, states_file, angle_tol)
    exp = expand(poly, skills, states, angle_tol=angle_tol)
    note_drift(exp, angle_tol)
    with stage_bars(as_json) as bars:
        ds, motions = motions_from_dataset(dataset, skills=skills, poly=poly, progress=bars,
                                           angle_tol=angle_tol)
    result = plan_with_fingers(poly, exp, start, goal, **tips, skills=every_skill,
                               states=states, position=position, motions=motions,
                               angle_tol=angle_tol, scale=ds.scale)
    if not result.steps:
        raise InputError(f"the object already rests in {goal}: nothing to execute")
    extra: dict[str, Any] = {}
    if use_robot:
        from nonprehensile.sim.robot_run import RobotSimulator, robot_control

        arms, placement = robot_arms(robot_kw, poly, ds.scale, result, ds.fingers, params,
                                     robot)
        simulator = RobotSimulator(poly, arms, scale=ds.scale, params=params,
                                   control_every=every,
                                   compliance=bool(robot_kw.get("compliance")),
                                   press_depth=robot_kw.get("press_depth", "auto"),
                                   finger_direction=robot_kw.get("finger_direction", "lean"),
                                   force_feedforward=auto_switch_of(robot_kw, "force_feedforward"),
                                   radius_offset=auto_switch_of(robot_kw, "radius_offset"))
        if simulator.n_fingers < scene_fingers(result, exp):
            raise InputError(f"the plan needs {scene_fingers(result, exp)} fingers; the robot "
                             f"has {simulator.n_fingers} fingertip site(s)")
        extra["robot"] = simulator.describe()
        extra["placement"] = placement_doc(placement)
        note = placement_note(extra["placement"])
        if note is not None:
            err.print(note, markup=False, highlight=False)
        # an arm's fingertip accelerates less than a free 20 g sphere
        cfg = robot_control(cfg, n_fingers=simulator.n_fingers)
    else:
        simulator = sim.Simulator(poly, scale=ds.scale, n_fingers=scene_fingers(result, exp),
                                  params=params)
    with progress_bar("simulating", as_json) as bar:
        ex = execute_plan(simulator, result, fingers=ds.fingers,
                          loop="closed" if loop == "closed" else "open",
                          replan=replanner(poly, exp, goal, motions=motions, scale=ds.scale,
                                           angle_tol=tol_deg),
                          config=cfg, observation=obs_model, perturbation=pert,
                          keep_trace=1 if record else 0)
        bar(1, 1)
    doc = ex.to_dict()
    records = doc["steps"]
    if use_robot:
        log = simulator.robot_log
        for (_, t0, t1), r in zip(ex.step_traces, records, strict=False):
            r["robot"] = log.metrics(*log.window(t0, t1)).to_dict()
        extra["robot_metrics"] = log.metrics().to_dict()
    recorded = None
    if record:
        from nonprehensile.export import write_episodes
        from nonprehensile.sim.episodes import step_episode

        episodes = [step_episode(poly, st, o, n_fingers=simulator.n_fingers,
                                 fingers=ds.fingers, fps=record_fps,
                                 meta={"plan": f"{start} -> {goal}", "step": i + 1,
                                       "n_steps": len(ex.executed), "loop": loop})
                    for i, (st, o) in enumerate(ex.executed)]
        write_episodes(episodes, record, extra_info={
            "source": "simulate plan", "object": poly.name, "scale_m_per_unit": ds.scale,
            "plan": f"{start} -> {goal}", "loop": loop, "params": params.to_dict()})
        recorded = {"output": record, "n_episodes": len(episodes),
                    "n_frames": sum(e.n_frames for e in episodes), "fps": record_fps}
        if not as_json:
            err.print(f"recorded {len(episodes)} episodes ({recorded['n_frames']} frames at "
                      f"{record_fps:g} fps) to {record}", markup=False)
    if not as_json:
        t = Table(title=f"plan {start} -> {goal} executed, {loop} loop")
        for c in ("step", "skill", "predicted", "simulated", "theta error", "position error",
                  "outcome", "observed events"):
            t.add_column(c)
        for r in records:
            simd = r["simulated"]
            events = " -> ".join(e["event"] for e in r["observed"] if "event" in e)
            t.add_row(str(r["step"]), r["skill"], str(State.from_dict(r["to"])),
                      str(State.from_dict(simd)) if simd else "-",
                      "-" if r["theta_error_deg"] is None else f"{r['theta_error_deg']:.1f} deg",
                      f"{1000 * r['position_error_m']:.1f} mm",
                      r["outcome"] + (f": {r['reason']}" if r["reason"] else ""), events or "-")
        out.print(t)
        if use_robot:
            out.print(robot_table(records, extra))
        for rp in doc["replans"]:
            out.print(f"re-planned after step {rp['after_step']} ({rp['reason']}): "
                      + ("; ".join(rp.get("steps", [])) or rp.get("error", "")))
        # a turn before a later step is onto that step's predicted state (or the
        # re-planner's frame), not onto the goal (the report's table reads it alike)
        from nonprehensile.viz.physics import correction_times

        whens = correction_times(doc["transits"], doc["corrections"])
        for c, when in zip(doc["corrections"], whens, strict=True):
            nxt = when if when.startswith("before ") else None
            if c["kind"] == "turn":
                after = c["theta_error_after_deg"]
                out.print(("" if nxt is None else f"{nxt}: ")
                          + f"turned the object by pushing face {c['face']} off its centre: "
                          f"theta {c['theta_error_before_deg']:+.1f} -> "
                          + ("?" if after is None else f"{after:+.1f}")
                          + (" deg from the goal" if nxt is None else " deg from its target"))
            else:
                out.print(f"slid the object {1000 * c['moved_m']:.1f} mm by pushing face "
                          f"{c['face']}: {1000 * c['error_after_m']:.1f} mm from the goal "
                          "position")
        lim = doc["limits"]
        out.print(f"fingertips: at most {lim['commanded_max_speed']:.2f} m/s and "
                  f"{lim['commanded_max_accel']:.1f} m/s^2 commanded; "
                  f"{lim['transit_finger_object_contact_s']:.3f} s of contact in transits")
        fs = doc["final_state"]
        pe = doc["position_error_m"]
        verdict = (f"reached {goal}" if ex.success else f"FAILED: {ex.reason}")
        out.print(f"{verdict} (final {State.from_dict(fs) if fs else 'no resting state'}, "
                  f"{1000 * pe:.1f} mm from the goal position)")
    if as_json:
        emit_json({"loop": loop, "success": ex.success, "execution": doc, "records": records,
                   "n": len(records), "n_success": sum(r["success"] for r in records),
                   "params": params.to_dict(), "perturbation": pert.to_dict(),
                   "observation": obs_model.to_dict(), "control": cfg.to_dict(),
                   "plan": result.to_dict(), **extra,
                   **({"record": recorded} if recorded else {})})
    if not ex.success:
        sys.exit(1)


def _check_record(record: str | None) -> None:
    """Refuse an existing ``--record`` folder before simulating (not after)."""
    from nonprehensile.export.episodes import check_new_folder

    if record is not None:
        check_new_folder(record, "the --record folder")


@simulate_group.command("record")
@click.argument("skills_file", type=click.Path(dir_okay=False))
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--n-per-skill", type=bounded(int, 1, 1000), default=30, show_default=True,
              help="Demonstrations to record of each skill (the mentors take turns).")
@click.option("--only", "only", multiple=True, metavar="SKILL",
              help="Record this skill only (repeatable); the dataset still lists every skill.")
@click.option("--keep-going", is_flag=True,
              help="When a skill cannot be recorded, record the others, write what succeeded, "
                   "list what did not and exit 1 (without it: nothing is written, exit 2).")
@click.option("--scale", type=bounded(float, 1e-6, 100.0), default=None,
              help="Metres per model unit, overriding the model's own `units` (default: from "
                   "them; the bundled cube is the unit cube, recorded at --scale 0.05).")
@click.option("--seed", type=bounded(int, 0, 2**63 - 1), default=20190520, show_default=True,
              help="Seed of the mentors' draws and the tracker noise.")
@click.option("--max-attempts", type=bounded(int, 1, 10_000), default=60, show_default=True,
              help="Takes a mentor may try for one demonstration before the skill is given "
                   "up (each failed take's reason is kept and summed up).")
@click.option("--format", "trajectory_format", type=click.Choice(["c3d", "csv"]),
              default="c3d", show_default=True,
              help="Recording files to write: C3D, or Motive CSV (with the object's rigid "
                   "body).")
@click.option("--physics-distribution", "under_distribution", is_flag=True,
              help="Record every take in its own sample of the physics distribution "
                   "(docs/physics.md) instead of one scene: friction, mass, fingertip, "
                   "stiffness, force limit and contact softness vary take by take (seeded "
                   "by --seed).")
@_physics_options
@json_option
@handle_errors
def simulate_record(skills_file: str, out_dir: str, n_per_skill: int, only: tuple[str, ...],
                    keep_going: bool, scale: float | None, seed: int, max_attempts: int,
                    trajectory_format: str, under_distribution: bool, as_json: bool,
                    tol_deg: float, **kw: Any) -> None:
    """Record a dataset of demonstrations from the physics itself: fingers push the
    simulated object; poses and contact events are read from physics.

    The simulation is in SI: the model's `units` give the scale (--scale overrides), and the
    mentors' paths scale with the object's size, so the same object in metres and in
    millimetres records the same takes. A take that fails is tried again; each failed take's
    reason is kept, and a skill that cannot be recorded is reported with its commonest
    reasons, counts and what to change.
    """
    params = _params(kw)
    from nonprehensile.errors import RecordError
    from nonprehensile.sim.record import record_dataset, write_recorded

    failures: dict[str, str] = {}
    with progress_bar("recording", as_json) as bar:
        try:
            dist = None
            if under_distribution:
                from nonprehensile.sim.distribution import PhysicsDistribution

                dist = PhysicsDistribution(base=params)
            ds, stats = record_dataset(skills_file, seed=seed, n_per_skill=n_per_skill,
                                       scale=scale, params=params, max_attempts=max_attempts,
                                       only=only or None, keep_going=keep_going,
                                       angle_tol=tol_deg,
                                       progress=bar, distribution=dist)
        except RecordError as exc:
            raise InputError(f"{skills_file}: {exc}; nothing was written (--keep-going "
                             "records the other skills)") from None
    failures = {k: v["failed"] for k, v in stats.items() if "failed" in v}
    path = write_recorded(ds, out_dir, trajectory_format) if ds.demonstrations else None
    doc = {"annotations": str(path) if path is not None else None,
           "demonstrations": len(ds.demonstrations), "takes": stats,
           "failed": failures, "scale": ds.scale, "params": params.to_dict()}
    if as_json:
        emit_json(doc)
    else:
        for name, st in stats.items():
            line = (f"{name}: {st['kept']} kept of {st['tried']} takes "
                    f"({st['fragile']} fragile)")
            if st["reasons"] and name not in failures:
                reasons = list(st["reasons"].items())
                top = ", ".join(f"{n} x {k}" for k, n in reasons[:3])
                rest = sum(n for _, n in reasons[3:])
                if rest:  # the counts shown add up to the takes that failed
                    top += f", {rest} x other reasons (--json lists every reason)"
                line += f"; failed takes: {top}"
            out.print(line)
        for line in failures.values():
            err.print(Text.assemble(("not recorded: ", "bold red"), line))
        if ds.demonstrations:
            out.print(f"wrote {len(ds.demonstrations)} demonstrations to {out_dir} "
                      f"(scale {ds.scale:g} m per model unit)")
        else:
            out.print(f"nothing written to {out_dir}: no skill could be recorded")
    if failures:
        sys.exit(1)


def _register() -> None:
    from nonprehensile.cli.robustness import robustness_cmd

    simulate_group.add_command(robustness_cmd)


_register()
