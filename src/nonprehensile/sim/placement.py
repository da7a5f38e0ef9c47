"""Where to stand the robot: a base placement search, and the joint trajectory of a plan.

:func:`place_base` tries base positions on rings around the plan's fingertip paths, the base
facing them, and keeps the one that reaches every target of the whole plan (largest fingertip
error under ``reach_tol``, 5 mm) with the largest joint-limit margin (least distance of any joint to
an end of its range, in radians, over the whole plan), the transits between steps included
(:func:`transit_path`). The search is kinematic (the IK at ``search_rate``, no collision
avoidance): the chosen base is then judged by physics.

:func:`joint_trajectory` runs the fingertip IK (with collision avoidance, the object at each
step's planned start pose) along a plan's reference motion at the control rate, and
:func:`write_joint_trajectories` writes it: per step and for the whole plan, a CSV (time, every
joint by name, their velocities) and a JSON (robot, base pose, controller, gains, rates,
limits).
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.control import ControlConfig
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import ObjectPose, Plan
from nonprehensile.sim.ik import FingertipIK, IKConfig
from nonprehensile.sim.robot import BasePose, Robot
from nonprehensile.sim.robot_driver import DEFAULT_CONTROL_EVERY
from nonprehensile.sim.robot_scene import Arm, build_robot_scene
from nonprehensile.sim.scene import DEFAULT_PARAMS, SimParams

__all__ = ["SETTLE_S", "JointTrajectory", "Placement", "joint_trajectory", "place_base",
           "plan_targets", "transit_path", "write_joint_trajectories"]

FloatArray = NDArray[np.float64]

#: Longest hold (s) on a step's last target in :func:`joint_trajectory` for the joints to come
#: to rest before the transit to the next step.
SETTLE_S = 1.0


@dataclass(frozen=True)
class Placement:
    """The result of :func:`place_base`.

    Attributes
    ----------
    base : BasePose
    reach_error_m : float
        Largest fingertip error over the plan's targets at this base.
    joint_margin_rad : float
        Least distance of a joint to an end of its range over the plan.
    feasible : bool
        Whether the reach error is under the tolerance.
    tried : int
        Candidate bases evaluated.
    candidates : tuple of Placement
        Every candidate evaluated, in the search's order (each with its own reach error,
        joint margin and verdict; ``tried`` its number from 1; no candidates of their own):
        the reachability map (:func:`nonprehensile.viz.reachability.reachability_figure`).
        Not part of equality or the JSON form.
    """

    base: BasePose
    reach_error_m: float
    joint_margin_rad: float
    feasible: bool
    tried: int
    candidates: tuple[Placement, ...] = field(default=(), compare=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"base": self.base.to_dict(), "reach_error_m": round(self.reach_error_m, 6),
                "joint_margin_rad": round(self.joint_margin_rad, 4),
                "feasible": self.feasible, "candidates": self.tried}

    def candidates_dict(self) -> list[dict[str, Any]]:
        """The candidates in JSON form (base, reach error, joint margin, feasible)."""
        return [{"base": c.base.to_dict(), "reach_error_m": round(c.reach_error_m, 6),
                 "joint_margin_rad": round(c.joint_margin_rad, 4), "feasible": c.feasible}
                for c in self.candidates]


def plan_targets(plan: Plan, fingers: Mapping[str, str], n_fingers: int = 1) -> list[
        tuple[FloatArray, float]]:
    """Each step's fingertip targets, shape (n_frames, n_fingers, 3), and rate (fingers a
    step does not use hold their last target, the first step's first one before that)."""
    from nonprehensile.sim.execute import step_targets

    out = []
    hold: FloatArray | None = None
    for step in plan.steps:
        targets, rate, _ = step_targets(step, fingers)
        n = len(next(iter(targets.values())))
        if hold is None:
            first = next(iter(targets.values()))[0]
            hold = np.repeat(first[None], n_fingers, axis=0)
        arr = np.repeat(hold[None], n, axis=0)
        for k, tr in targets.items():
            if k > n_fingers:
                raise InputError(f"step {step.transition.skill.name!r} uses finger R{k}; the "
                                 f"robots have {n_fingers} fingertip(s)")
            arr[:, k - 1] = tr
        hold = arr[-1]
        out.append((arr, rate))
    return out


def transit_path(start: FloatArray, end: FloatArray, *, lift: float = 0.05,
                 spacing: float = 0.005) -> FloatArray:
    """A base search's stand-in for the transit between two fingertip paths: straight up
    from ``start`` to ``lift`` (m) above the higher of the two ends, across, and straight down
    to ``end`` (each shape (n_fingers, 3)), every finger alike; no coordinate of a finger
    moves more than ``spacing`` (m) between two points; both ends included; shape
    (n, n_fingers, 3).

    The executor's transits retreat, clear the object and approach
    (:mod:`nonprehensile.transit`); this is the kinematic search's simpler path over the same
    ground, so that the arm's reach is judged between steps too, not on a jump."""
    a = np.asarray(start, dtype=np.float64)
    b = np.asarray(end, dtype=np.float64)
    top = max(float(a[..., 2].max()), float(b[..., 2].max())) + lift
    way = [a, np.concatenate([a[..., :2], np.full((*a.shape[:-1], 1), top)], -1),
           np.concatenate([b[..., :2], np.full((*b.shape[:-1], 1), top)], -1), b]
    legs = []
    for p0, p1 in itertools.pairwise(way):
        # ``n`` points make ``n - 1`` intervals of at most ``spacing``
        n = max(2, int(np.ceil(float(np.abs(p1 - p0).max()) / spacing)) + 1)
        legs.append(p0 + np.linspace(0, 1, n)[:, None, None] * (p1 - p0))
    return np.concatenate(legs)


def _rz(yaw_deg: float) -> FloatArray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def place_base(
    robot: Robot, poly: Polyhedron, scale: float, paths: Sequence[tuple[FloatArray, float]], *,
    radii: Sequence[float] = tuple(np.round(np.arange(0.35, 0.751, 0.05), 3)),
    n_directions: int = 16, search_rate: float = 50.0, reach_tol: float = 0.005,
    params: SimParams = DEFAULT_PARAMS, finger: int = 0,
    avoid: Sequence[BasePose] = (), min_separation: float = 0.4,
    side_cone_deg: float = 60.0,
) -> Placement:
    """Search a base pose for one arm that reaches the whole plan with the most joint margin.

    Parameters
    ----------
    robot : Robot
        One arm (its first tip site follows finger R1).
    poly, scale : the object model and metres per model unit.
    paths : sequence of (array, float)
        Targets per step, shape (n_frames, n_fingers, 3), and their rate (:func:`plan_targets`).
    radii : sequence of float
        Distances (m) of the candidate bases from the centre of the targets.
    n_directions : int
        Directions around it (the base faces the centre).
    search_rate : float
        Rate (Hz) the targets are followed at in the search.
    reach_tol : float
        A base is feasible when the fingertip error stays under this (m) while the IK follows
        the targets at ``search_rate`` (its lag included: out of reach is centimetres).
    finger : int
        Which finger of the paths (0 for R1) this arm's tip follows (its first tip site).
    avoid : sequence of BasePose
        Bases of other arms already placed: candidates closer than ``min_separation`` (m)
        to one are skipped.
    side_cone_deg : float
        With several fingers in the paths, the arm stands on its own finger's side: only
        bases within this angle of the direction from the fingers' common centre to this
        finger's targets are tried (in a pinch each arm then reaches the face nearest to it
        and its finger leans over no object; the search would otherwise pick, by joint
        margin, an arm reaching across the object to the far face). Ignored when the
        fingers' centres are within 5 mm of each other.
    """
    if not paths:
        raise InputError("the plan has no steps: nothing to place the robot for")
    scene = build_robot_scene(poly, scale=scale, arms=[Arm(robot, BasePose(0.0, 0.0, 0.0))],
                              params=params, mocap_object=True)
    ik = FingertipIK(scene, 1.0 / search_rate, IKConfig(collisions=False))
    ik.set_object(np.array([0.0, 0.0, -10.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    sampled: list[FloatArray] = []
    own: list[FloatArray] = []  # the plan's own targets (the centre of the candidates' rings)
    for arr, rate in paths:
        every = max(1, round(rate / search_rate))
        if not 0 <= finger < arr.shape[1]:
            raise InputError(f"finger R{finger + 1} is not in the paths "
                             f"({arr.shape[1]} finger(s))")
        seg = arr[::every, finger:finger + 1]
        if sampled:
            # the transit between two steps (a step's reference starts where the last one
            # did not end: 61 mm away in the main plan): followed as a jump, the IK's lag on
            # it counted as a reach error of 44 mm at every candidate, and the search then
            # ranked the bases by that lag instead of by their joint margin
            sampled.append(transit_path(sampled[-1][-1], seg[0]))
        sampled.append(seg)
        own.append(seg)
    allt = np.concatenate(sampled)
    centre = np.concatenate(own).reshape(-1, 3)[:, :2].mean(axis=0)
    every_finger = np.concatenate([arr[::max(1, round(rate / search_rate))]
                                   for arr, rate in paths]).reshape(-1, 3)[:, :2].mean(axis=0)
    side = centre - every_finger
    side_ok = float(np.hypot(*side)) > 0.005
    best: Placement | None = None
    tried = 0
    evaluated: list[Placement] = []
    for r in radii:
        for k in range(n_directions):
            a = 2 * math.pi * k / n_directions
            bx, by = centre[0] + r * math.cos(a), centre[1] + r * math.sin(a)
            if any(math.hypot(bx - o.x, by - o.y) < min_separation for o in avoid):
                continue
            if side_ok and math.cos(a - math.atan2(side[1], side[0])) < math.cos(
                    math.radians(side_cone_deg)):
                continue
            yaw = math.degrees(math.atan2(centre[1] - by, centre[0] - bx))
            base = BasePose(float(bx), float(by), yaw)
            local = (allt - np.array([bx, by, 0.0])) @ _rz(yaw)  # world -> base frame
            tried += 1
            ik.reset(scene.home)
            err = ik.converge(local[0], iterations=200)
            margin = math.inf
            for x in local[1:]:
                ik.step(x)
                e = float(np.linalg.norm(ik.tips() - x, axis=1).max())
                err = max(err, e)
                if err > 5 * reach_tol:
                    break
                q = ik.q
                margin = min(margin, float(np.min(np.minimum(q - scene.lower,
                                                             scene.upper - q))))
            cand = Placement(base, err, margin if math.isfinite(margin) else 0.0,
                             err <= reach_tol, tried)
            evaluated.append(cand)
            if best is None or (cand.feasible, cand.joint_margin_rad if cand.feasible
                                else -cand.reach_error_m) > (
                    best.feasible, best.joint_margin_rad if best.feasible
                    else -best.reach_error_m):
                best = cand
    if best is None:
        raise InputError("no candidate base is far enough from the other arms' bases on "
                         "this finger's side: give --base X Y YAW for each arm")
    return Placement(best.base, best.reach_error_m, best.joint_margin_rad, best.feasible,
                     tried, tuple(evaluated))


@dataclass(frozen=True)
class JointTrajectory:
    """Joint set points at the control rate.

    Attributes
    ----------
    name : str
        ``step1``, ``transit2``, ``step2``, ... (``transitK``: the transit before step
        ``K``) or ``plan``.
    time : ndarray, shape (n,)
        Seconds from the start of the plan.
    positions, velocities : ndarray, shape (n, n_joints)
    joint_names : tuple of str
    tip_error_m : float
        Largest distance of the IK's fingertip to its target (reach).
    """

    name: str
    time: FloatArray
    positions: FloatArray
    velocities: FloatArray
    joint_names: tuple[str, ...]
    tip_error_m: float


def joint_trajectory(
    arms: Sequence[Arm], poly: Polyhedron, scale: float, plan: Plan,
    fingers: Mapping[str, str], *, params: SimParams = DEFAULT_PARAMS,
    ik_config: IKConfig | None = None, control_every: int = DEFAULT_CONTROL_EVERY,
    finger_direction: str = "lean", config: ControlConfig | None = None,
    settle_s: float = SETTLE_S,
) -> list[JointTrajectory]:
    """The IK's joint trajectory along the plan's reference motion, one row per control step
    (``control_every`` physics steps; kinematic: the object stands at each step's planned
    start pose for collision avoidance), per step, per transit between steps, and for the
    whole plan (``step1``, ``transit2``, ``step2``, ..., ``plan``).

    After each step's reference (and each transit) the IK holds its last target until the
    joints come to rest (every joint slower than ``REST_SPEED``, at most ``settle_s`` seconds;
    the last row has velocity 0); the fingertips then move to the next step's first target by the
    executor's transit (:func:`~nonprehensile.transit.transit`: retreat, clear of the object
    posed at the next step's start by ``config.clearance``, approach along the face's normal;
    rest to rest within ``config.max_speed`` and its transit acceleration bound;
    ``config``: :func:`~nonprehensile.sim.robot_run.robot_control`'s, as ``simulate plan
    --robot`` executes). So the plan's trajectory is continuous: without the transits the
    next step's IK started 61 mm from its first target in the main plan and moved the joints
    at up to 1.5 rad/s on that jump. ``finger_direction="recorded"`` points each finger tool
    along its recorded finger (knuckle to tip, :func:`~nonprehensile.step_paths.
    step_directions`) where the references carry knuckle markers; ``"lean"`` (the default),
    the IK's rule.

    Parameters
    ----------
    arms : sequence of Arm
    poly : Polyhedron
    scale : float
        Metres per model unit.
    plan : Plan
    fingers : mapping of str to str
        The dataset's finger markers (``R1`` ...).
    params : SimParams
        The scene's (its timestep sets the control period with ``control_every``).
    ik_config : IKConfig, optional
    control_every : int
        Physics steps per control step (row).
    finger_direction : {"lean", "recorded"}
    config : ControlConfig, optional
        The transits' clearance and bounds, through
        :func:`~nonprehensile.sim.robot_run.robot_control` (default: its defaults).
    settle_s : float
        Longest hold on a part's last target for the joints to come to rest, s.

    Returns
    -------
    list of JointTrajectory
        ``step1``, ``transit2``, ``step2``, ..., then ``plan``. A step without a planned
        start pose (a plan built by hand) has no transit before it: its IK starts from the
        last step's end. Fingers the next step does not use move with the transit only where
        their target changes; the executor sends them home instead.
    """
    from nonprehensile.sim.robot_driver import REST_SPEED, check_finger_direction
    from nonprehensile.sim.robot_run import robot_control
    from nonprehensile.step_paths import step_directions
    from nonprehensile.transit import transit

    check_finger_direction(finger_direction)
    scene = build_robot_scene(poly, scale=scale, arms=arms, params=params, mocap_object=True)
    dt = params.timestep * control_every
    cfg = robot_control(config, n_fingers=scene.n_fingers)
    ik = FingertipIK(scene, dt, ik_config)
    paths = plan_targets(plan, fingers, scene.n_fingers)
    out: list[JointTrajectory] = []
    t0 = 0.0
    placed = False

    def run(name: str, x: FloatArray, dirs: FloatArray | None) -> None:
        """The IK along targets ``x`` (shape (n, n_fingers, 3)), then on the last one until
        the joints rest; appended to ``out`` as ``name``."""
        nonlocal t0
        qs, vs, err = [], [], 0.0
        for j, xi in enumerate(x):
            ik.set_pointing(None if dirs is None else dirs[j])
            q, v = ik.step(xi)
            qs.append(q)
            vs.append(v)
            err = max(err, float(np.linalg.norm(ik.tips() - xi, axis=1).max()))
        for _ in range(round(settle_s / dt)):
            if float(np.abs(vs[-1]).max()) < REST_SPEED:
                break
            q, v = ik.step(x[-1])
            qs.append(q)
            vs.append(v)
        vs[-1] = np.zeros_like(vs[-1])  # (at rest: the next leg starts from rest)
        tt = t0 + np.arange(len(qs)) * dt
        out.append(JointTrajectory(name, np.asarray(tt, dtype=np.float64), np.array(qs),
                                   np.array(vs), scene.joint_names, err))
        t0 = float(tt[-1]) + dt

    def see(pose: ObjectPose | None) -> None:
        if pose is not None:
            quat = np.empty(4)
            mujoco.mju_mat2Quat(quat, np.ascontiguousarray(pose.rotation).ravel())
            ik.set_object(np.asarray(pose.translation, dtype=float), quat)

    last: FloatArray | None = None
    for i, ((arr, rate), step) in enumerate(zip(paths, plan.steps, strict=True)):
        pose = step.start_pose
        see(pose)
        if last is not None and pose is not None:
            # from the last step's end to this one's first target, clear of the object
            # where this step finds it (rest to rest: the rows' ends are at rest)
            way = transit(poly, pose, last, arr[0],
                          dt=dt, clearance=cfg.clearance, finger_radius=params.finger_radius,
                          max_speed=cfg.max_speed, max_accel=cfg.transit_bound,
                          moving=np.linalg.norm(arr[0] - last, axis=1) > 1e-9)
            ik.set_pointing(None)
            run(f"transit{i + 1}", way, None)
        n = max(2, round((len(arr) - 1) / rate / dt) + 1)
        tt = np.arange(n) * dt
        tr = np.arange(len(arr)) / rate
        x = np.stack([np.stack([np.interp(tt, tr, arr[:, k, a]) for a in range(3)], axis=1)
                      for k in range(arr.shape[1])], axis=1)
        dirs = None
        if finger_direction == "recorded":
            got = step_directions(step, fingers)
            if got:  # (the recorded fingers; the others keep the rule: zero rows)
                dirs = np.zeros((n, scene.n_fingers, 3))
                for k, d in got.items():
                    # (step_directions gives step_targets' frames: plan_targets' here)
                    assert len(d) == len(tr), (len(d), len(tr))
                    if k <= scene.n_fingers:
                        dd = np.stack([np.interp(tt, tr, d[:, a]) for a in range(3)], axis=1)
                        dirs[:, k - 1] = dd / np.linalg.norm(dd, axis=1)[:, None]
        if not placed:
            ik.set_pointing(None if dirs is None else dirs[0])
            ik.converge(x[0])
            placed = True
        run(f"step{i + 1}", x, dirs)
        last = x[-1]  # (the IK's last target: the reference resampled at the control rate)
    if out:
        out.append(JointTrajectory(
            "plan", np.concatenate([j.time for j in out]),
            np.concatenate([j.positions for j in out]),
            np.concatenate([j.velocities for j in out]), scene.joint_names,
            max(j.tip_error_m for j in out)))
    return out


def write_joint_trajectories(trajectories: Sequence[JointTrajectory], out_dir: str | Path,
                             meta: Mapping[str, Any]) -> list[Path]:
    """Write ``joints_<name>.csv`` (``time``, each joint, ``<joint>_vel``) and
    ``joints_<name>.json`` (``meta`` with the file's columns, units and rate)."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    written = []
    for jt in trajectories:
        csv_path = d / f"joints_{jt.name}.csv"
        names = list(jt.joint_names)
        with csv_path.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["time", *names, *(f"{n}_vel" for n in names)])
            for t, q, v in zip(jt.time, jt.positions, jt.velocities, strict=True):
                w.writerow([f"{t:.6f}", *(f"{x:.9g}" for x in q), *(f"{x:.9g}" for x in v)])
        doc = {**meta, "trajectory": jt.name, "csv": csv_path.name,
               "columns": ["time", *names, *(f"{n}_vel" for n in names)],
               "units": {"time": "s", "position": "rad (m for slide joints)",
                         "velocity": "rad/s (m/s)"},
               "samples": len(jt.time), "ik_tip_error_max_m": round(jt.tip_error_m, 6)}
        json_path = d / f"joints_{jt.name}.json"
        json_path.write_text(json.dumps(doc, indent=2) + "\n")
        written += [csv_path, json_path]
    return written
