"""Robustness sweeps: transitions and plans executed across the physics distribution.

A sweep executes **units** (a transition of the expanded graph made a one-step plan with
:func:`~nonprehensile.planning.step_for`, or a whole plan) with the planner's own reference
motions, once per sample of a :class:`~nonprehensile.sim.distribution.PhysicsDistribution`
and per loop (open, closed), and counts how many end as predicted (face, ``theta`` within the
angle tolerance, centre of mass within the position tolerance of the plan's prediction).

* **Seeding**: execution ``i`` of unit ``u`` runs sample ``i`` of stream ``u`` of the sweep's
  seed (``SeedSequence([seed, u, i])``): every transition sees its own draws (the
  per-parameter bins fill with ``n_units * n_samples`` distinct values), the open and the
  closed loop the same ones (a paired comparison), and a result never depends on which worker
  ran it, nor in what order.
* **Scale**: one compiled MuJoCo model per worker process, retuned per sample
  (:class:`~nonprehensile.sim.scene.SceneTuner`); a process pool by default
  (:func:`run_sweep` ``workers``), a Dask cluster with ``scheduler`` (extra ``scale``). Both
  give the same records, sample by sample.
* **Loops**: ``closed`` and ``open``, both by the executor ``simulate plan`` runs
  (:func:`~nonprehensile.sim.closed_loop.execute_plan`: the same transits and verdict); a
  loop that is not available is refused, never replaced by another.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from nonprehensile.demonstrations.dataset import DEFAULT_FINGERS
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import Offset, Plan
from nonprehensile.sim.compare import DEFAULT_ANGLE_TOL_DEG, DEFAULT_POSITION_TOL
from nonprehensile.sim.distribution import PhysicsDistribution, PhysicsSample
from nonprehensile.sim.run import Simulator
from nonprehensile.sim.scene import SceneTuner
from nonprehensile.success_rates import Rate, SuccessRates, TransitionKey

__all__ = [
    "EXECUTORS",
    "SampleRecord",
    "SweepResult",
    "SweepRobot",
    "SweepSpec",
    "SweepUnit",
    "available_loops",
    "check_loops",
    "demonstration_units",
    "frozen_library",
    "place_sweep_arms",
    "plan_unit",
    "run_sweep",
    "transition_units",
]

Progress = Callable[[int, int], None]


# ----------------------------------------------------------------------------- the units
@dataclass(frozen=True)
class SweepUnit:
    """What one execution runs: a plan (one step for a transition).

    Attributes
    ----------
    plan : Plan
        With reference motions.
    label : dict
        JSON-ready description (skill, source, from, to, demonstrated; or the plan's ends).
    key : TransitionKey or None
        The transition's key for the planner's rates (None for a whole plan).
    source : str
        The demonstrated skill behind it (``NAME:reverse`` for a reversed one), or
        ``"plan"``.
    """

    plan: Plan
    label: dict[str, Any]
    key: TransitionKey | None
    source: str


def frozen_library(expansion: Any, motions: Any) -> _Memo:
    """A motion library holding only the references ``expansion``'s skills use, each asked
    of ``motions`` once: small to send to every worker (a re-planner's library)."""
    from nonprehensile.planning import _demonstrated_name

    memo = _Memo(motions)
    for t in expansion.transitions:
        name = _demonstrated_name(t.source.name)
        for st in t.source.steps():
            # a reversed skill asks for its demonstrated arcs the other way round
            memo.reference(name, st.motion.source, st.motion.target)
            memo.reference(name, st.motion.target, st.motion.source)
    memo.library = None  # everything is asked: the clusters need not travel
    return memo


class _Memo:
    """A motion library asked once per arc: the same arc's reference serves every transition
    of its skill (a cluster medoid costs a distance matrix)."""

    def __init__(self, library: Any) -> None:
        self.library = library
        self._got: dict[tuple[str, str, str], Any] = {}

    def reference(self, skill: str, source: str, target: str) -> Any:
        key = (skill, source, target)
        if key not in self._got:
            self._got[key] = (None if self.library is None
                              else self.library.reference(skill, source, target))
        return self._got[key]


def transition_units(poly: Polyhedron, expansion: Any, motions: Any, *, scale: float,
                     angle_tol: float, sources: Sequence[str] | None = None
                     ) -> list[SweepUnit]:
    """Every transition of ``expansion`` (of the demonstrated skills ``sources`` only, when
    given: ``NAME:reverse`` for a reversed one) as a one-step plan with the planner's
    references (per-arc cluster medoids, as :func:`~nonprehensile.planning.plan` attaches
    them), its object's centre of mass at the origin."""
    from nonprehensile.planning import step_for

    motions = _Memo(motions)
    out = []
    for t in expansion.transitions:
        if sources is not None and t.source.name not in sources:
            continue
        st = step_for(poly, t, motions=motions, scale=scale, angle_tol=angle_tol)
        missing = [f"{a} -> {b}" for a, b, _, ref in st.motions if ref is None]
        if missing:
            raise InputError(f"skill {t.source.name!r} has no reference motion for its arc(s) "
                             f"{missing}: the dataset does not demonstrate it")
        plan = Plan(t.start, t.end, Offset(), (st,))
        label = {"skill": t.skill.name, "source": t.source.name,
                 "demonstrated": t.demonstrated, "from": t.start.to_dict(),
                 "to": t.end.to_dict()}
        out.append(SweepUnit(plan, label, TransitionKey.of(t.skill.name, t.start, t.end),
                             t.source.name))
    return out


class _OneDemonstration:
    """A motion library holding one demonstration's own segments (metres)."""

    def __init__(self, segments: Sequence[Any]) -> None:
        self._arcs = {(s.motion.source, s.motion.target): s for s in segments}
        self.skill = segments[0].skill if segments else ""

    def reference(self, skill: str, source: str, target: str) -> Any:
        from nonprehensile.planning import ReferenceMotion

        seg = self._arcs.get((source, target))
        if seg is None or skill != self.skill:
            return None
        traj = seg.trajectory.to_units("m")
        return ReferenceMotion(np.asarray(traj.positions), tuple(traj.marker_names),
                               traj.rate, 0, 1)


def demonstration_units(dataset: Any, expansion: Any, *, angle_tol: float,
                        skills: Sequence[str] | None = None) -> list[SweepUnit]:
    """Every demonstration of ``dataset`` (of ``skills`` only, when given) as a one-step plan
    whose references are its own recorded segments, the object where it was recorded
    (centre of mass at the origin): the demonstration replayed, judged by the same executors
    and verdict as a planned transition.

    Raises
    ------
    InputError
        A demonstration whose transition is not in ``expansion``, or with gaps its dataset's
        gap limit does not bridge.
    """
    from nonprehensile.demonstrations.segment import segment_dataset
    from nonprehensile.planning import step_for

    _, segments = segment_dataset(dataset)
    by_demo: dict[str, list[Any]] = {}
    for seg in segments:
        by_demo.setdefault(seg.demonstration.file, []).append(seg)
    arcs = {(t.source.name, t.start): t for t in expansion.transitions if t.demonstrated}
    out = []
    for demo in dataset.demonstrations:
        if skills is not None and demo.skill.name not in skills:
            continue
        key = (demo.skill.name, demo.initial)
        t = arcs.get(key) or next(
            (t for (name, start), t in arcs.items()
             if name == demo.skill.name and start.isclose(demo.initial, angle_tol)), None)
        if t is None:
            raise InputError(f"{demo.file}: its transition {demo.skill.name} from "
                             f"{demo.initial} is not a demonstrated transition of the state "
                             "set (use the dataset's own step)")
        lib = _OneDemonstration(by_demo.get(demo.file, []))
        st = step_for(dataset.poly, t, motions=lib, scale=dataset.scale, angle_tol=angle_tol)
        bad = [f"{a} -> {b}" for a, b, _, ref in st.motions
               if ref is None or not np.isfinite(ref.positions).all()]
        if bad:
            raise InputError(f"{demo.file}: no usable recorded motion on arc(s) {bad} (gaps "
                             "longer than the dataset's gap limit)")
        label = {"file": demo.file, "skill": demo.skill.name, "source": demo.skill.name,
                 "mentor": demo.mentor, "demonstrated": True,
                 "from": t.start.to_dict(), "to": t.end.to_dict()}
        out.append(SweepUnit(Plan(t.start, t.end, Offset(), (st,)), label, None,
                             demo.skill.name))
    return out


def plan_unit(plan: Plan) -> SweepUnit:
    """A whole plan as one unit (its success: the goal reached)."""
    if not plan.steps:
        raise InputError("the plan has no step to execute")
    label = {"skill": " + ".join(s.transition.skill.name for s in plan.steps),
             "source": "plan", "demonstrated": all(s.transition.demonstrated
                                                    for s in plan.steps),
             "from": plan.start.to_dict(), "to": plan.goal.to_dict(),
             "steps": len(plan.steps)}
    return SweepUnit(plan, label, None, "plan")


# -------------------------------------------------------------------------- the records
@dataclass(frozen=True)
class SampleRecord:
    """One execution's verdict.

    Attributes
    ----------
    unit, sample : int
        Which unit, which sample of its stream.
    loop : str
    success : bool
    reason : str
        Why it failed ("" on success).
    final : dict or None
        The resting state reached (``{"face", "theta"}``), None if none.
    theta_error, position_error : float or None
        Degrees, metres (against the plan's prediction).
    physics_steps : int
    sim_seconds, wall_seconds : float
    values : dict
        The sample's varied quantities (:meth:`PhysicsSample.values`).
    extra : dict
        What the executor reports beside (events in order, retries, ...).
    episodes : tuple of Episode
        The executed steps as episodes, when the sweep records (``record_fps``).
    """

    unit: int
    sample: int
    loop: str
    success: bool
    reason: str
    final: dict[str, Any] | None
    theta_error: float | None
    position_error: float | None
    physics_steps: int
    sim_seconds: float
    wall_seconds: float
    values: dict[str, float]
    extra: dict[str, Any] = field(default_factory=dict)
    #: With ``SweepSpec.record_fps``: the executed steps as learning episodes
    #: (:mod:`nonprehensile.sim.episodes`); not part of the verdict or its JSON.
    episodes: tuple[Any, ...] = field(default=(), compare=False, repr=False)

    def outcome(self) -> tuple[Any, ...]:
        """What must be equal between two runs of the same sweep (everything but timing)."""
        return (self.unit, self.sample, self.loop, self.success, self.reason, self.final,
                self.theta_error, self.position_error, self.physics_steps)

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"unit": self.unit, "sample": self.sample, "loop": self.loop,
                "success": self.success, "reason": self.reason, "final": self.final,
                "theta_error_deg": None if self.theta_error is None
                else round(self.theta_error, 4),
                "position_error_m": None if self.position_error is None
                else round(self.position_error, 6),
                "physics_steps": self.physics_steps, "sim_seconds": round(self.sim_seconds, 4),
                "wall_seconds": round(self.wall_seconds, 4),
                "values": {k: round(v, 9) for k, v in self.values.items()}, **self.extra}


# ---------------------------------------------------------------------------- executors
Executor = Callable[["_Worker", SweepUnit, PhysicsSample], dict[str, Any]]


def _execution(worker: _Worker, unit: SweepUnit, sample: PhysicsSample,
               loop: str) -> dict[str, Any]:
    """One execution by :func:`~nonprehensile.sim.closed_loop.execute_plan`, the executor
    ``simulate plan`` runs: the same transits, verdict and records whatever the loop. With
    the spec's expansion, the closed loop may re-plan from where the object is observed
    toward the unit's goal (as ``simulate plan`` does): a transition's rate is then that of
    reaching its end state when the planner picks it; without, a step that ends elsewhere
    fails."""
    from nonprehensile.control import ControlConfig
    from nonprehensile.sim.closed_loop import execute_plan

    spec = worker.spec
    replan = worker.replanner(unit)
    cfg = ControlConfig(angle_tol=spec.angle_tol, position_tol=spec.position_tol)
    if spec.robot is not None:  # an arm's fingertip accelerates less than a free sphere
        from nonprehensile.sim.robot_run import robot_control

        cfg = robot_control(cfg, n_fingers=spec.robot.n_fingers,
                            max_accel=spec.robot.max_accel)
        # every sample's records (tracking, limits, IK times) its own, not left to the
        # driver's re-placement test (the arm itself is placed anew by that test, as a fresh
        # simulator would place it)
        worker.sim.robot_log.clear()  # type: ignore[attr-defined]
    ex = execute_plan(worker.sim, unit.plan, fingers=spec.fingers,
                      loop="closed" if loop == "closed" else "open", replan=replan,
                      config=cfg,
                      perturbation=sample.perturbation, angle_tol=spec.angle_tol,
                      position_tol=spec.position_tol,
                      keep_trace=1 if spec.record_fps else 0)
    episodes: tuple[Any, ...] = ()
    if spec.record_fps:
        from nonprehensile.sim.episodes import step_episode

        params = {f"param.{k}": v for k, v in sample.values().items()}
        episodes = tuple(
            step_episode(spec.poly, st, o, n_fingers=worker.sim.n_fingers,
                         fingers=spec.fingers, fps=spec.record_fps,
                         meta={"plan": f"{unit.plan.start} -> {unit.plan.goal}", "step": i + 1,
                               "n_steps": len(ex.executed), "loop": loop,
                               "sample": sample.index, **params})
            for i, (st, o) in enumerate(ex.executed))
    extra: dict[str, Any] = {"replans": len(ex.replans), "corrections": len(ex.corrections),
                             "fingertip_max_speed": (None if ex.tip_speed is None
                                                     else round(ex.tip_speed, 4)),
                             "transit_contact_s": round(ex.transit_contact_s, 4)}
    if spec.robot is not None:  # tracking, limits, link contacts, IK time of the whole run
        extra["robot"] = worker.sim.robot_log.metrics().to_dict()  # type: ignore[attr-defined]
    return {
        "success": bool(ex.success), "reason": "" if ex.success else ex.reason,
        "final": ex.final_state.to_dict() if ex.final_state is not None else None,
        "theta_error": ex.theta_error, "position_error": ex.position_error,
        "physics_steps": ex.n_steps, "sim_seconds": ex.sim_time,
        "extra": extra,
        "episodes": episodes,
    }


def _closed_loop(worker: _Worker, unit: SweepUnit, sample: PhysicsSample) -> dict[str, Any]:
    return _execution(worker, unit, sample, "closed")


def _open_loop(worker: _Worker, unit: SweepUnit, sample: PhysicsSample) -> dict[str, Any]:
    return _execution(worker, unit, sample, "open")


#: Executors by loop name.
EXECUTORS: dict[str, Executor] = {"closed": _closed_loop, "open": _open_loop}


def available_loops() -> list[str]:
    """The loops this installation can execute."""
    return [lp for lp in ("closed", "open") if lp in EXECUTORS]


def check_loops(loops: Sequence[str]) -> tuple[str, ...]:
    """The loops, each known and available, without repeats.

    Raises
    ------
    InputError
        An unknown loop, or one this installation cannot execute (never replaced by
        another).
    """
    out: list[str] = []
    for lp in loops:
        if lp not in ("closed", "open"):
            raise InputError(f"unknown loop {lp!r}: expected closed or open")
        if lp not in EXECUTORS:
            raise InputError(f"{lp}-loop execution is not available in this version (it has "
                             f"{available_loops()}); a sweep never runs another loop in its "
                             "place")
        if lp not in out:
            out.append(lp)
    if not out:
        raise InputError("give at least one loop (closed, open)")
    return tuple(out)


# ----------------------------------------------------------------------------- the robot
@dataclass(frozen=True)
class SweepRobot:
    """Robot arms that execute every unit of a sweep in place of the free fingertips.

    Each worker builds the robot scene once (:class:`~nonprehensile.sim.robot_run.
    RobotSimulator`) and retunes it per sample like the free fingertips' scene: the object's
    mass, every pair's friction and softness, the fingertip sphere's radius; the free
    fingertips' ``stiffness``, ``max_force`` and ``finger_mass`` do not apply to an arm.

    Attributes
    ----------
    arms : tuple of Arm
        Robots at their base poses (:func:`place_sweep_arms`, or given); their tip sites are
        fingers R1, R2, ... in order.
    control_every : int
        Physics steps per IK solve (the control rate is the physics rate / it).
    max_accel : float, optional
        Fingertip acceleration bound of the executor's motions and transits (m/s^2, the
        transits' at most :data:`~nonprehensile.sim.robot_run.ROBOT_TRANSIT_ACCEL`:
        :func:`~nonprehensile.sim.robot_run.robot_control`); default
        :data:`~nonprehensile.sim.robot_run.ROBOT_MAX_ACCEL`, as ``simulate plan --robot``.
    compliance : bool
        The arms' force-limited finger command with each sample's ``stiffness`` and
        ``max_force`` (:class:`~nonprehensile.sim.robot_run.RobotSimulator`; off by
        default).
    press_depth : float, None or "auto"
        The contact-consistent command's bound, m (the deepest a fingertip command may put
        the arm's fingertip sphere inside the object as observed; None: none; ``"auto"``,
        the default: none with one arm's fingertip, 2 mm with several), and
    press_correction : bool
        whether the contact tracking correction may press past it
        (:class:`~nonprehensile.sim.robot_run.RobotSimulator`).
    finger_direction : {"lean", "recorded"}
        How the finger tools point in a step (``"lean"``, the default, or along the
        recorded fingers: :class:`~nonprehensile.sim.robot_run.RobotSimulator`).
    force_cap : float, None or "auto"
        The stiff arm's force cap, N (``"auto"``, the default: 40 N with one fingertip,
        none with several or with the compliance; None: none;
        :class:`~nonprehensile.sim.robot_run.RobotSimulator`).
    force_feedforward : bool or "auto"
        With a force cap, the contact force fed forward to the servos (``"auto"``, the
        default: with a force cap and one fingertip;
        :class:`~nonprehensile.sim.robot_run.RobotSimulator`).
    radius_offset : bool or "auto"
        The fingertip radius offset of the arms' commands, each sample's fingertip radius
        against the references' (``"auto"``, the default: with one fingertip;
        :class:`~nonprehensile.sim.robot_run.RobotSimulator`).
    """

    arms: tuple[Any, ...]
    control_every: int = 10  # robot_driver.DEFAULT_CONTROL_EVERY (a test holds them equal)
    max_accel: float = None  # type: ignore[assignment]
    compliance: bool = False
    press_depth: float | str | None = "auto"
    press_correction: bool = True
    finger_direction: str = "lean"
    force_cap: float | str | None = "auto"
    force_feedforward: bool | str = "auto"
    radius_offset: bool | str = "auto"

    def __post_init__(self) -> None:
        if self.max_accel is None:
            from nonprehensile.sim.robot_run import ROBOT_MAX_ACCEL

            object.__setattr__(self, "max_accel", ROBOT_MAX_ACCEL)
        object.__setattr__(self, "arms", tuple(self.arms))
        if not self.arms:
            raise InputError("a sweep's robot needs at least one arm")
        c = self.control_every
        if isinstance(c, bool) or not isinstance(c, int) or not 1 <= c <= 100:
            raise InputError(f"control_every must be a whole number in [1, 100], got {c!r}")
        if not (isinstance(self.max_accel, (int, float)) and math.isfinite(self.max_accel)
                and self.max_accel > 0):
            raise InputError(f"max_accel must be a finite positive number, got "
                             f"{self.max_accel!r}")
        from nonprehensile.sim.robot_driver import check_finger_direction, check_press

        check_press(self.press_depth, self.press_correction)
        check_finger_direction(self.finger_direction)
        from nonprehensile.sim.robot_run import (
            check_force_feedforward,
            resolve_force_cap,
            resolve_radius_offset,
        )

        # (each refuses a bad setting in one line now, not at the first worker's scene)
        resolve_force_cap(self.force_cap, self.n_fingers, self.compliance is True)
        check_force_feedforward(self.force_feedforward, self.force_cap_n, self.n_fingers)
        resolve_radius_offset(self.radius_offset, self.n_fingers)

    @property
    def n_fingers(self) -> int:
        """Fingertips over all arms."""
        return sum(len(a.robot.tip_sites) for a in self.arms)

    def simulator(self, poly: Polyhedron, scale: float, params: Any) -> Simulator:
        """The robot scene of these arms (one per worker)."""
        from nonprehensile.sim.robot_run import RobotSimulator

        return RobotSimulator(poly, self.arms, scale=scale, params=params,
                              control_every=self.control_every,
                              compliance=self.compliance, press_depth=self.press_depth,
                              press_correction=self.press_correction,
                              finger_direction=self.finger_direction,
                              force_cap=self.force_cap,
                              force_feedforward=self.force_feedforward,
                              radius_offset=self.radius_offset)

    def to_dict(self) -> dict[str, Any]:
        """JSON form: robots, bases, rates."""
        return {"robots": [{"robot": a.robot.name, "tip_sites": list(a.robot.tip_sites),
                            "base": a.base.to_dict()} for a in self.arms],
                "control_every": self.control_every, "max_accel": self.max_accel,
                "compliance": bool(self.compliance), "press_depth": self.press_depth,
                # the bound that runs ("auto" resolved by the number of fingertips; None: none)
                "press_depth_m": self.press_depth_m,
                "press_correction": bool(self.press_correction),
                "finger_direction": self.finger_direction,
                # the stiff arm's force cap that runs ("auto" resolved; None: none)
                "force_cap_n": self.force_cap_n,
                # whether the contact force is fed forward ("auto" resolved; a cap only)
                "force_feedforward": self.force_feedforward_on,
                # whether the commands get the fingertip radius offset ("auto" resolved)
                "radius_offset": self.radius_offset_on,
                # the contact tracking correction that runs (robot_run.resolve_tracking)
                **self.tracking()}

    @property
    def radius_offset_on(self) -> bool:
        """Whether the commands get the fingertip radius offset (``"auto"`` resolved as
        :class:`~nonprehensile.sim.robot_run.RobotSimulator` resolves it)."""
        from nonprehensile.sim.robot_run import resolve_radius_offset

        return resolve_radius_offset(self.radius_offset, self.n_fingers)

    @property
    def force_feedforward_on(self) -> bool:
        """Whether the contact force is fed forward (``"auto"`` resolved as
        :class:`~nonprehensile.sim.robot_run.RobotSimulator` resolves it)."""
        from nonprehensile.sim.robot_run import resolve_force_feedforward

        return resolve_force_feedforward(self.force_feedforward, self.force_cap_n,
                                         self.n_fingers)

    @property
    def force_cap_n(self) -> float | None:
        """The stiff arm's force cap that runs, N (``"auto"`` resolved as
        :class:`~nonprehensile.sim.robot_run.RobotSimulator` resolves it), None for none."""
        from nonprehensile.sim.robot_run import resolve_force_cap

        return resolve_force_cap(self.force_cap, self.n_fingers, self.compliance is True)

    def tracking(self) -> dict[str, Any]:
        """The contact tracking correction the arms run (the scene's defaults by the number
        of fingertips): gain, whether along the object's surface only, bound, and the bound
        of its part along the surface (None: none); and whether the servos get the set
        points' acceleration torque (the scene's default, which runs below the physics
        rate only: as ``robot.controller.acceleration_feedforward`` of ``simulate plan``)."""
        from nonprehensile.sim.robot_run import resolve_surface_bound, resolve_tracking

        gain, tangential, bound = resolve_tracking(self.n_fingers)
        surface = resolve_surface_bound(self.n_fingers, None, tangential)
        return {"tracking_gain_per_s": gain, "tracking_tangential": tangential,
                "tracking_bound_m": bound,
                "tracking_surface_bound_m": surface if math.isfinite(surface) else None,
                "acceleration_feedforward": self.control_every > 1}

    @property
    def press_depth_m(self) -> float | None:
        """The contact-consistent command's bound that runs, m (``"auto"`` resolved as
        :class:`~nonprehensile.sim.robot_run.RobotSimulator` resolves it), None for none."""
        from nonprehensile.sim.robot_run import resolve_press_depth

        return resolve_press_depth(self.press_depth, self.n_fingers)


def place_sweep_arms(robot: Any, units: Sequence[SweepUnit], poly: Polyhedron, scale: float,
                     fingers: Mapping[str, str], *, n_arms: int = 1, params: Any = None,
                     max_units: int = 16, search_rate: float = 10.0
                     ) -> tuple[list[Any], list[Any]]:
    """Base poses for ``n_arms`` copies of ``robot`` that reach every unit of a sweep.

    A worker keeps one robot scene for all units, so one placement serves them all:
    :func:`~nonprehensile.sim.placement.place_base` (arm by arm, each for its first
    fingertip, away from the bases placed before) over the fingertip paths of up to
    ``max_units`` units spread evenly over the sweep (a transition sweep has every object
    at the origin: its paths overlap), one after another, joined by straight moves 5 cm
    above the higher end (each unit starts from a transit in the execution), followed at
    ``search_rate`` Hz (a plan's own search uses 50 Hz; a sweep's paths are many times
    longer).

    Returns
    -------
    arms : list of Arm
    placements : list of Placement
        One per arm (its reach error and joint margin).
    """
    from nonprehensile.sim.placement import place_base, plan_targets
    from nonprehensile.sim.robot_scene import Arm
    from nonprehensile.sim.scene import DEFAULT_PARAMS

    if isinstance(n_arms, bool) or not isinstance(n_arms, int) or not 1 <= n_arms <= 4:
        raise InputError(f"n_arms must be a whole number in [1, 4], got {n_arms!r}")
    if not units:
        raise InputError("nothing to place the robot for: no unit")
    n_tips = len(robot.tip_sites) * n_arms
    pick = np.unique(np.linspace(0, len(units) - 1, min(len(units), max_units)).round()
                     ).astype(int)
    rate = 0.0
    parts: list[np.ndarray] = []
    for u in pick:
        for arr, r in plan_targets(units[int(u)].plan, fingers, n_tips):
            rate = max(rate, r)
            if parts:  # a bridge from the last path's end to this one's start, lifted
                a, b = parts[-1][-1], arr[0]
                top = max(float(a[..., 2].max()), float(b[..., 2].max())) + 0.05
                lift = [np.concatenate([a[..., :2], np.full((*a.shape[:-1], 1), top)], -1),
                        np.concatenate([b[..., :2], np.full((*b.shape[:-1], 1), top)], -1)]
                way = [a, *lift, b]
                steps = []
                for p0, p1 in itertools.pairwise(way):
                    n = max(2, int(np.ceil(float(np.abs(p1 - p0).max()) / 0.005)))
                    steps.append(p0 + np.linspace(0, 1, n)[:, None, None] * (p1 - p0))
                parts.append(np.concatenate(steps))
            parts.append(arr)
    # one path at the fastest rate: the slower ones' frames are a little denser (the search
    # follows them at its own rate)
    paths = [(np.concatenate(parts), rate)]
    placements: list[Any] = []
    per_arm = len(robot.tip_sites)
    for i in range(n_arms):
        placements.append(place_base(robot, poly, scale, paths, search_rate=search_rate,
                                     params=params if params is not None else DEFAULT_PARAMS,
                                     finger=i * per_arm,
                                     avoid=[p.base for p in placements]))
    return [Arm(robot, p.base) for p in placements], placements


# ------------------------------------------------------------------------------ the spec
@dataclass(frozen=True)
class SweepSpec:
    """Everything a worker needs: picklable, sent once to every worker.

    Attributes
    ----------
    poly : Polyhedron
    scale : float
        Metres per model unit.
    units : tuple of SweepUnit
    distribution : PhysicsDistribution
        For this object (:meth:`PhysicsDistribution.for_object`).
    seed : int
    n_samples : int
        Per unit.
    loops : tuple of str
    fingers : mapping
        Finger name -> tip marker of the references.
    angle_tol, position_tol : float
        Degrees, metres.
    expansion, library : optional
        The expanded graph and a motion library (:func:`frozen_library`): closed loop, an
        execution re-plans with them from where the object is observed (None: it may not).
    record_fps : float or None
        Record every execution's steps as episodes at this frame rate
        (``simulate robustness --record``); None: do not.
    robot : SweepRobot or None
        Robot arms execute every unit (each worker builds their scene once); None: the free
        fingertips.
    """

    poly: Polyhedron
    scale: float
    units: tuple[SweepUnit, ...]
    distribution: PhysicsDistribution
    seed: int
    n_samples: int
    loops: tuple[str, ...] = ("closed", "open")
    fingers: Mapping[str, str] = field(default_factory=lambda: dict(DEFAULT_FINGERS))
    angle_tol: float = DEFAULT_ANGLE_TOL_DEG
    position_tol: float = DEFAULT_POSITION_TOL
    expansion: Any = None
    library: Any = None
    record_fps: float | None = None
    robot: SweepRobot | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "loops", check_loops(self.loops))
        if self.robot is not None and not isinstance(self.robot, SweepRobot):
            raise InputError(f"robot must be a SweepRobot, got {type(self.robot).__name__}")
        if self.robot is not None and self.record_fps:
            raise InputError("recording episodes writes free-fingertip actions; a robot's "
                             "sweep does not record (drop the robot, or the recording)")
        if isinstance(self.n_samples, bool) or not isinstance(self.n_samples, int) or \
                not 1 <= self.n_samples <= 100_000:
            raise InputError(f"the number of samples must be a whole number in [1, 100000], "
                             f"got {self.n_samples!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or \
                not 0 <= self.seed < 2**63:
            raise InputError(f"the seed must be a whole number in [0, 2^63), got {self.seed!r}")
        if not self.units:
            raise InputError("nothing to sweep: no transition or plan")
        for name, v in (("angle_tol", self.angle_tol), ("position_tol", self.position_tol)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a finite positive number, got {v!r}")
        if self.robot is not None and self.robot.n_fingers < self.n_fingers:
            raise InputError(f"the units need {self.n_fingers} fingers; the robot has "
                             f"{self.robot.n_fingers} fingertip site(s) (more arms: n_arms, "
                             "--arms; or sweep the skills it has fingers for)")

    @property
    def n_fingers(self) -> int:
        """Fingertips every unit's plan (and any re-plan) needs."""
        from nonprehensile.sim.closed_loop import scene_fingers

        return max(scene_fingers(u.plan, self.expansion) for u in self.units)

    def sample(self, unit: int, index: int) -> PhysicsSample:
        """Sample ``index`` of unit ``unit``'s stream."""
        return self.distribution.sample(self.seed, index=index, stream=unit)


class _Worker:
    """One compiled scene, retuned per sample (one per process)."""

    def __init__(self, spec: SweepSpec) -> None:
        self.spec = spec
        self.sim = (Simulator(spec.poly, scale=spec.scale, n_fingers=spec.n_fingers,
                              params=spec.distribution.base) if spec.robot is None
                    else spec.robot.simulator(spec.poly, spec.scale, spec.distribution.base))
        self.tuner = SceneTuner(self.sim.model, self.sim.data, self.sim.params)
        self._replanners: dict[int, Any] = {}

    def replanner(self, unit: SweepUnit) -> Any:
        """The re-planner of a whole plan's unit (None without an expansion)."""
        spec = self.spec
        if spec.expansion is None:
            return None
        key = id(unit)
        if key not in self._replanners:
            from nonprehensile.control import replanner

            self._replanners[key] = replanner(spec.poly, spec.expansion, unit.plan.goal,
                                              motions=spec.library, scale=spec.scale,
                                              angle_tol=spec.angle_tol)
        return self._replanners[key]

    def run(self, unit: int, sample: int) -> list[SampleRecord]:
        s = self.spec.sample(unit, sample)
        self.tuner.tune(s.params)
        # the simulator and its judge read timestep, settling and tolerances from params
        self.sim.params = s.params
        self.sim.judge.params = s.params
        out = []
        for loop in self.spec.loops:
            wall0 = time.perf_counter()
            try:
                got = EXECUTORS[loop](self, self.spec.units[unit], s)
            except Exception as exc:  # an executor's bug is a failed sample
                # one execution that raises must neither end the sweep (losing every other
                # result) nor vanish from it: it counts as a failure, saying why
                got = {"success": False,
                       "reason": f"the executor raised {type(exc).__name__}: {exc}",
                       "final": None, "theta_error": None, "position_error": None,
                       "physics_steps": 0, "sim_seconds": 0.0,
                       "extra": {"executor_error": True}}
            out.append(SampleRecord(
                unit, sample, loop, got["success"], got["reason"], got["final"],
                got["theta_error"], got["position_error"], int(got["physics_steps"]),
                float(got["sim_seconds"]), time.perf_counter() - wall0, s.values(),
                got.get("extra", {}),
                tuple(replace(e, meta={**e.meta, "unit": unit}) for e in got.get(
                    "episodes", ()))))
        return out


#: The worker of this process (process pool and Dask workers), keyed by its spec's token.
_WORKERS: dict[str, _Worker] = {}
_SPECS: dict[str, SweepSpec] = {}


def _init_pool(token: str, spec: SweepSpec) -> None:
    _SPECS[token] = spec


def _chunk(token: str, tasks: Sequence[tuple[int, int]],
           spec: SweepSpec | None = None) -> list[SampleRecord]:
    """Run tasks ``(unit, sample)`` on this process's worker."""
    w = _WORKERS.get(token)
    if w is None:
        s = spec if spec is not None else _SPECS[token]
        _WORKERS.clear()  # one model per process: a new sweep replaces the last one's
        w = _WORKERS[token] = _Worker(s)
    return [r for u, i in tasks for r in w.run(u, i)]


def _chunks(spec: SweepSpec, size: int) -> list[list[tuple[int, int]]]:
    out = []
    for u in range(len(spec.units)):
        idx = list(range(spec.n_samples))
        out += [[(u, i) for i in idx[j:j + size]] for j in range(0, len(idx), size)]
    return out


def run_sweep(
    spec: SweepSpec, *, workers: int | None = None, scheduler: str | Any | None = None,
    chunk_size: int = 10, progress: Progress | None = None,
) -> SweepResult:
    """Execute every unit of ``spec`` for each of its samples and loops.

    Parameters
    ----------
    spec : SweepSpec
    workers : int, optional
        Processes of the pool (default: the machine's cores; 1 runs in this process).
    scheduler : str or distributed.Client, optional
        A Dask scheduler's address (``tcp://host:8786``) or a client: run there instead.
    chunk_size : int
        Samples of one unit per task.
    progress : callable, optional
        ``progress(done, total)`` in executions.

    Returns
    -------
    SweepResult
        Records sorted by unit, sample and loop.
    """
    import hashlib
    import pickle

    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
        raise InputError(f"chunk_size must be a whole number >= 1, got {chunk_size!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or not 1 <= workers <= 256):
        raise InputError(f"workers must be a whole number in [1, 256], got {workers!r}")
    if workers is not None and scheduler is not None:
        raise InputError("give workers (a process pool) or a scheduler (Dask), not both")
    blob = pickle.dumps(spec)
    token = hashlib.blake2b(blob, digest_size=12).hexdigest()
    chunks = _chunks(spec, chunk_size)
    total = len(spec.units) * spec.n_samples * len(spec.loops)
    done = 0
    records: list[SampleRecord] = []
    wall0 = time.perf_counter()

    def got(rs: list[SampleRecord]) -> None:
        nonlocal done
        records.extend(rs)
        done += len(rs)
        if progress is not None:
            progress(done, total)

    how: str
    if scheduler is not None:
        how = "dask"
        for rs in _dask_map(scheduler, token, spec, chunks):
            got(rs)
    else:
        n = workers if workers is not None else (os.cpu_count() or 1)
        n = max(1, min(n, len(chunks)))
        how = f"processes:{n}"
        if n == 1:
            for c in chunks:
                got(_chunk(token, c, spec))
        else:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor, as_completed

            # spawn, not fork: the parent may run threads (progress bars, a Dask client)
            with ProcessPoolExecutor(n, mp_context=mp.get_context("spawn"),
                                     initializer=_init_pool, initargs=(token, spec)) as ex:
                futs = [ex.submit(_chunk, token, c) for c in chunks]
                for f in as_completed(futs):
                    got(f.result())
    records.sort(key=lambda r: (r.unit, r.sample, spec.loops.index(r.loop)))
    return SweepResult(spec, tuple(records), time.perf_counter() - wall0, how)


def _dask_map(scheduler: str | Any, token: str, spec: SweepSpec,
              chunks: list[list[tuple[int, int]]]) -> Iterator[list[SampleRecord]]:
    try:
        from distributed import Client, as_completed
    except ImportError as exc:
        raise InputError(f"--scheduler needs Dask: pip install 'nonprehensile[scale]' ({exc})"
                         ) from None
    own = isinstance(scheduler, str)
    client: Any
    try:
        client = Client(scheduler, timeout="10s") if own else scheduler  # type: ignore[no-untyped-call]
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"cannot reach the Dask scheduler {scheduler!r}: {exc}") from None
    try:
        spec_f = client.scatter(spec, broadcast=True)
        futs = [client.submit(_chunk, token, c, spec_f, pure=False) for c in chunks]
        for f in as_completed(futs):  # type: ignore[no-untyped-call]
            yield f.result()
    finally:
        if own:
            client.close()


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True)
class SweepResult:
    """A sweep's records and what they say.

    Attributes
    ----------
    spec : SweepSpec
    records : tuple of SampleRecord
        Sorted by unit, sample and loop.
    wall_seconds : float
    how : str
        ``processes:K`` or ``dask``.
    """

    spec: SweepSpec
    records: tuple[SampleRecord, ...]
    wall_seconds: float
    how: str

    def _rate(self, pick: Callable[[SampleRecord], bool], loop: str) -> Rate:
        rs = [r for r in self.records if r.loop == loop and pick(r)]
        return Rate(sum(r.success for r in rs), len(rs))

    def overall(self) -> dict[str, Rate]:
        """Per loop, over everything."""
        return {lp: self._rate(lambda r: True, lp) for lp in self.spec.loops}

    def per_unit(self) -> list[dict[str, Rate]]:
        """Per unit and loop."""
        acc: list[dict[str, list[int]]] = [
            {lp: [0, 0] for lp in self.spec.loops} for _ in self.spec.units]
        for r in self.records:
            c = acc[r.unit][r.loop]
            c[0] += r.success
            c[1] += 1
        return [{lp: Rate(*c) for lp, c in a.items()} for a in acc]

    def per_source(self) -> dict[str, dict[str, Rate]]:
        """Per demonstrated skill behind the units (``twist:reverse`` apart) and loop."""
        out: dict[str, dict[str, Rate]] = {}
        for u, rates in zip(self.spec.units, self.per_unit(), strict=True):
            d = out.setdefault(u.source, {lp: Rate(0, 0) for lp in self.spec.loops})
            for lp, r in rates.items():
                d[lp] = d[lp] + r
        return dict(sorted(out.items()))

    def bins(self, n_bins: int = 4) -> dict[str, list[dict[str, Any]]]:
        """Per varied quantity: ``n_bins`` equal bins of its range, each with its rate per
        loop (quantities the distribution holds fixed are left out)."""
        if isinstance(n_bins, bool) or not isinstance(n_bins, int) or not 1 <= n_bins <= 100:
            raise InputError(f"the number of bins must be a whole number in [1, 100], got "
                             f"{n_bins!r}")
        out: dict[str, list[dict[str, Any]]] = {}
        for name, (lo, hi) in self.spec.distribution.ranges().items():
            if hi <= lo:
                continue
            edges = np.linspace(lo, hi, n_bins + 1)
            counts = np.zeros((n_bins, len(self.spec.loops), 2), dtype=int)
            for r in self.records:
                b = min(n_bins - 1, max(0, int(np.searchsorted(edges, r.values[name],
                                                               side="right")) - 1))
                c = counts[b, self.spec.loops.index(r.loop)]
                c[0] += r.success
                c[1] += 1
            out[name] = [{"low": float(edges[b]), "high": float(edges[b + 1]),
                          **{lp: Rate(int(counts[b, j, 0]), int(counts[b, j, 1]))
                             for j, lp in enumerate(self.spec.loops)}}
                         for b in range(n_bins)]
        return out

    def steps(self) -> int:
        """Physics steps simulated, all executions."""
        return sum(r.physics_steps for r in self.records)

    def rates(self, meta: Mapping[str, Any] | None = None) -> SuccessRates:
        """Per-transition rates for the planner (``plan --robustness``)."""
        counts = [(self.spec.units[r.unit].key, r.loop, r.success) for r in self.records
                  if self.spec.units[r.unit].key is not None]
        if not counts:
            raise InputError("a sweep of a whole plan has no per-transition rates to write; "
                             "sweep the transitions (no --from/--to)")
        return SuccessRates.from_counts(
            [(k, lp, ok) for k, lp, ok in counts if k is not None], self.spec.poly.name,
            {"seed": self.spec.seed, "samples": self.spec.n_samples,
             "angle_tol_deg": self.spec.angle_tol, "position_tol_m": self.spec.position_tol,
             "distribution": self.spec.distribution.to_dict(), **(meta or {})})

    def to_dict(self, *, records: bool = True, n_bins: int = 4) -> dict[str, Any]:
        """JSON form: rates per loop overall, per source skill, per unit and per bin (each
        ``{k, n, rate, ci95}``), and each execution's record."""
        def rates(d: Mapping[str, Rate]) -> dict[str, Any]:
            return {lp: r.to_dict() for lp, r in d.items()}

        doc: dict[str, Any] = {
            "object": self.spec.poly.name, "seed": self.spec.seed,
            "samples": self.spec.n_samples, "loops": list(self.spec.loops),
            "robot": None if self.spec.robot is None else self.spec.robot.to_dict(),
            "distribution": self.spec.distribution.to_dict(),
            "angle_tol_deg": self.spec.angle_tol, "position_tol_m": self.spec.position_tol,
            "overall": rates(self.overall()),
            "per_source_skill": {k: rates(v) for k, v in self.per_source().items()},
            "units": [{**u.label, **rates(r)}
                      for u, r in zip(self.spec.units, self.per_unit(), strict=True)],
            "bins": {name: [{"low": round(b["low"], 9), "high": round(b["high"], 9),
                             **{lp: b[lp].to_dict() for lp in self.spec.loops}}
                            for b in bs] for name, bs in self.bins(n_bins).items()},
            "physics_steps": self.steps(), "wall_seconds": round(self.wall_seconds, 3),
            "how": self.how,
        }
        if records:
            doc["records"] = [r.to_dict() for r in self.records]
        return doc


def with_loops(spec: SweepSpec, loops: Sequence[str]) -> SweepSpec:
    """The same sweep under other loops."""
    return replace(spec, loops=tuple(loops))
