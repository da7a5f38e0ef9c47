"""A :class:`~nonprehensile.sim.run.Simulator` whose fingers are robot arms.

:class:`RobotSimulator` builds the robot scene (:mod:`nonprehensile.sim.robot_scene`), drives
it with :class:`~nonprehensile.sim.robot_driver.RobotArms` and judges it with the same
:class:`~nonprehensile.sim.judge.Judge`; every executor that runs a ``Simulator`` (open loop
:func:`~nonprehensile.sim.execute.simulate_plan`, the closed loop) runs it unchanged. The
robot's own records (tracking error, limits, other contacts, IK time) are in
:attr:`RobotSimulator.robot_log`.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.control import ControlConfig
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import ObjectPose
from nonprehensile.sim.ik import IKConfig
from nonprehensile.sim.judge import Judge
from nonprehensile.sim.robot_driver import (
    DEFAULT_CONTROL_EVERY,
    DEFAULT_TRACKING_BOUND,
    RobotArms,
    RobotLog,
    check_finger_direction,
    check_press,
    servo_stiffness,
)
from nonprehensile.sim.robot_scene import Arm, RobotScene, build_robot_scene
from nonprehensile.sim.run import SimResult, Simulator, default_scale
from nonprehensile.sim.scene import DEFAULT_PARAMS, SimParams
from nonprehensile.transit import APPROACH_SPEED

__all__ = ["DEFAULT_TRACKING_GAIN", "PINCH_PRESS_DEPTH", "PINCH_TRACKING_BOUND",
           "PINCH_TRACKING_GAIN", "ROBOT_FOLLOW_DEPTH", "ROBOT_FORCE_CAP", "ROBOT_MAX_ACCEL",
           "ROBOT_PUSH_APPROACH", "ROBOT_TRACKING_SURFACE_BOUND", "ROBOT_TRANSIT_ACCEL",
           "RobotSimulator", "check_force_feedforward", "describe_robots",
           "resolve_force_cap", "resolve_force_feedforward", "resolve_press_depth",
           "resolve_radius_offset",
           "resolve_surface_bound", "resolve_tracking",
           "robot_control"]

#: Fingertip acceleration bound (m/s^2) of the executor's motions when an arm moves the
#: fingertip (``ControlConfig.max_accel``). The free fingertips' 20 m/s^2 asks the Panda's
#: shoulder for more than its 87 N m (measured, with the IK's 30 rad/s^2 joint bound, at
#: 62.5-250 Hz: 15-26 ms at a torque limit over the main plan); at 8 m/s^2 (well inside
#: Franka's 13 m/s^2 Cartesian datasheet limit) the longest time at a limit is 8 ms at
#: 100 Hz, and the plan runs 10 % shorter than at 4 m/s^2.
ROBOT_MAX_ACCEL = 8.0

#: One fingertip's (one arm's) transits' bound (m/s^2, ``ControlConfig.transit_accel``):
#: the same as its motions', where the free fingertips' transits use half of theirs
#: (10 m/s^2). At half (4 m/s^2) the transits were 40 % of the main plan's simulated time on
#: the Panda; at 8 m/s^2 the 72 single-finger transitions at nominal physics keep every
#: contact bar (no limit held over 10 ms). Two or more fingertips (arms) keep half of
#: ``max_accel``: at 8 m/s^2 the 96 two-finger transitions fell from 96/96 to 92/96 (measured
#: before the IK's observed object and the rod's outward lean)
#: (docs/benchmarks.md, "ik22").
ROBOT_TRANSIT_ACCEL = 8.0

#: The correction pushes' approach speed for robots (m/s; ``ControlConfig.push_approach``):
#: the transits' approach speed, ``transit.APPROACH_SPEED``. Measured on the 72
#: single-finger cube transitions by one arm at nominal physics: the robot's CPU against
#: the free fingertip's 2.86-2.91x in four runs against 3.21-3.33x at the push's own speed
#: (half of the robot's CPU there goes to the end-of-plan corrections; their approach was
#: the longest part of each: 15 mm at 20-30 mm/s), every transition still reached, the
#: same tracking; the main plan across the distribution 96/100 and 94/100 (seeds 0, 1;
#: link contact in 1 run of each) against 95/100 and 93/100 (2 and 0) (docs/benchmarks.md).
ROBOT_PUSH_APPROACH = APPROACH_SPEED

#: One arm's contact tracking correction gain, 1/s (:class:`RobotSimulator`'s
#: ``tracking_gain`` with one fingertip; several fingertips, a pinch, run
#: :data:`PINCH_TRACKING_GAIN` along the object's surface only).
DEFAULT_TRACKING_GAIN = 20.0

#: One arm's bound on its contact tracking correction's part along the object's surface, m
#: (:class:`RobotSimulator`'s ``tracking_surface_bound``, applied after each update; the part
#: along the object's normal, the press the servos lose to the contact force, is kept, and
#: the whole correction then keeps ``tracking_bound``). Measured with
#: the acceleration feed-forward on the 72 single-finger cube transitions at nominal
#: physics: every one reached, tracking in contact within 2.8 mm (1.2 mm without the bound),
#: 335.7 s simulated against 391.8 s (the roll-pulls' end-of-plan corrections 24 against 48,
#: the roll-arcs' 54 against 72: a correction along the surface holds the pad sideways and
#: turns the cube); the robot's CPU against the free fingertip's 2.70-2.72x against
#: 3.09-3.10x (over the bar of 3x). The main plan across the distribution 95/100 and
#: 94/100 in seeds 0 and 1 (95 and 94 without; 94 and 94 before the feed-forward's clip).
#: Normal only (0): 318 s, but the push-rolls tracked 3.2 mm; 1 mm: 351 s, 2.4 mm
#: (docs/benchmarks.md).
ROBOT_TRACKING_SURFACE_BOUND = 0.0005

#: One arm's force cap, N (:class:`RobotSimulator`'s ``force_cap="auto"``; the stiff arm's
#: command gives way along the contact force above it: ``RobotArms._cap``). The references
#: were recorded with a compliant fingertip (8-15 N at most); across the physics
#: distribution the stiff arm pressed heavy, grippy cubes with up to 340 N and held a
#: torque limit for over 10 ms while touching in 5 and 4 of 100 runs (seeds 0, 1); capped:
#: in 0 and 1, tracking in contact at most 10.0 and 10.4 mm against 20.9 and 21.3, rods on
#: the cube in 1 run of each against 3 and 2, 95/100 and 96/100 reached against 95 and 94.
#: At nominal physics the arm's pushes stay under 40 N (33.5 N at most over the 72
#: single-finger transitions): the same records; the CPU ratio over them 2.86-2.97x
#: against 2.77-2.80x (docs/benchmarks.md).
ROBOT_FORCE_CAP = 40.0

#: Several fingertips' (a pinch's) contact tracking correction: gain (1/s) and bound (m) of
#: the correction along the object's surface only (``RobotArms.tracking_tangential``: the
#: error along the object's normal, the depth no rigid pad can reach, is left out). The 96
#: two-finger transitions by two arms at nominal physics: 96/96 as without it, tracking in
#: contact max 3.8 mm against 7.0 mm, the tumble-lifts within 3 mm in 21/24 against 0/24,
#: no limit held over 10 ms and no link or rod contact, as without it; with 1.5 mm, 3 mm or
#: 4 mm bounds, or gains of 10 or 40, the tumble-twist's rod touched the cube in 1-10 runs
#: (docs/benchmarks.md, "pinch tracking"). Those figures were measured from start postures the
#: placement's iterations stopped short of, finger 1 running every correction push; from the
#: converged postures, each push run by the arm behind it, 96/96 at 6.3 mm, the tumble-lifts
#: within 3 mm in 18/24, no limit held, no link or rod contact (docs/robot.md); with the
#: servos' acceleration feed-forward since, 96/96 at 2.3 mm, every tumble within 3 mm.
PINCH_TRACKING_GAIN = 20.0
PINCH_TRACKING_BOUND = 0.002

#: Several fingertips' (a pinch's) contact-consistent command bound, m
#: (:class:`RobotSimulator`'s ``press_depth="auto"``; one fingertip runs without it). The
#: 96 two-finger transitions by two arms at nominal physics: 96/96 against 95/96 without,
#: tracking in contact max 7.0 mm against 63.5 mm, no limit held over 10 ms against 5 runs,
#: no link or rod contact against 5 runs, twist:reverse within 3 mm in 24/24 against 6/24;
#: one arm pushing loses slippery-table pushes with it (docs/benchmarks.md, press24).
PINCH_PRESS_DEPTH = 0.002


#: Robots' bound on the follow-through (m, ``ControlConfig.follow_depth``): it turns the
#: fingertips on about the object's pivot no further than where the arm's fingertip sphere
#: would lie 6 mm inside the object as observed. The main plan's 100 samples by one arm:
#: 94/100 as without it, the worst tracking in contact 21.3 mm against 42.6, the longest
#: time at a limit 42 ms against 705, 5 runs over 10 ms against 8 (seed 1: 94/100 both,
#: 17.7 against 31.5 mm, 7 runs against 10); at nominal physics the 72 one-arm and 96
#: two-arm transitions and the main plan keep their figures (docs/benchmarks.md).
ROBOT_FOLLOW_DEPTH = 0.006


def _real(x: object) -> bool:
    """Whether ``x`` is a real number (numpy's too; a bool is not a number here)."""
    return isinstance(x, numbers.Real) and not isinstance(x, (bool, np.bool_))


def resolve_tracking(n_fingers: int, gain: float | None = None,
                     tangential: bool | None = None,
                     bound: float | None = None) -> tuple[float, bool, float]:
    """The contact tracking correction that runs with ``n_fingers`` fingertips: its gain
    (1/s), whether it integrates the error along the object's surface only, and its bound
    (m); None: the default (one fingertip: :data:`DEFAULT_TRACKING_GAIN`, the whole error,
    ``robot_driver.DEFAULT_TRACKING_BOUND``; several: :data:`PINCH_TRACKING_GAIN`, the
    surface only, :data:`PINCH_TRACKING_BOUND`).

    Raises
    ------
    InputError
        A gain outside 0-1000 /s, a bound outside 0-0.05 m (NaN, a bool), a ``tangential``
        that is not True, False or None.
    """
    if gain is not None and not (_real(gain) and 0.0 <= float(gain) <= 1000.0):
        raise InputError(f"tracking_gain is a rate from 0 to 1000 /s, got {gain!r}")
    if tangential is not None and not isinstance(tangential, bool):
        raise InputError(f"tracking_tangential is True or False, got {tangential!r}")
    if bound is not None and not (_real(bound) and 0.0 <= float(bound) <= 0.05):
        raise InputError(f"tracking_bound is a distance from 0 to 0.05 m, got {bound!r}")
    pinch = n_fingers > 1
    return (float(gain) if gain is not None
            else PINCH_TRACKING_GAIN if pinch else DEFAULT_TRACKING_GAIN,
            pinch if tangential is None else tangential,
            float(bound) if bound is not None
            else PINCH_TRACKING_BOUND if pinch else DEFAULT_TRACKING_BOUND)


def resolve_force_feedforward(feedforward: object, cap: float | None,
                              n_fingers: int = 1) -> bool:
    """Whether the contact force is fed forward: ``"auto"`` (the default) with a force cap
    ``cap`` (N; None: none) and one fingertip, not otherwise; True or False as given. Refuse
    anything else, and True without a force cap or with several fingertips: the force fed
    forward is clipped at the cap, the give it feeds forward is the cap's, and it was
    measured for one arm pushing only (a pinch's squeeze fed forward would press harder).

    Raises
    ------
    InputError
        One line saying what came and what to drop.
    """
    if isinstance(feedforward, str) and feedforward == "auto":
        return cap is not None and n_fingers == 1
    if not isinstance(feedforward, bool):
        raise InputError(f"force_feedforward is True, False or 'auto', got {feedforward!r}")
    if feedforward and (cap is None or n_fingers > 1):
        raise InputError("force_feedforward needs the stiff arm's force cap and one "
                         f"fingertip (force_cap='auto' or a force in N; got {n_fingers} "
                         f"fingertip(s), force cap {cap}): drop it (or 'auto') with "
                         "compliance, several fingertips or force_cap=None")
    return feedforward


def resolve_radius_offset(offset: object, n_fingers: int = 1) -> bool:
    """Whether the arm's commands get the fingertip radius offset
    (:meth:`~nonprehensile.sim.robot_driver.RobotArms._tool`): ``"auto"`` (the default) with
    one fingertip, not with several (a pinch's depth is the contact-consistent command's
    bound, ``press_depth``; across the physics distribution two arms with the offset held
    fewer torque limits but lost three goals in one of two seeds: docs/benchmarks.md); True
    or False as given.

    Raises
    ------
    InputError
        One line saying what came.
    """
    if isinstance(offset, str) and offset == "auto":
        return n_fingers == 1
    if not isinstance(offset, bool):
        raise InputError(f"radius_offset is True, False or 'auto', got {offset!r}")
    return offset


def check_force_feedforward(feedforward: object, cap: float | None,
                            n_fingers: int = 1) -> None:
    """Refuse a contact force feed-forward switch :func:`resolve_force_feedforward` refuses.

    Raises
    ------
    InputError
        One line saying what came and what to drop.
    """
    resolve_force_feedforward(feedforward, cap, n_fingers)


def resolve_force_cap(cap: float | str | None, n_fingers: int,
                      compliance: bool = False) -> float | None:
    """The stiff arm's force cap that runs, N (None: none): ``"auto"`` is
    :data:`ROBOT_FORCE_CAP` with one fingertip of a stiff arm and none otherwise (several
    fingertips pinch: the cap would loosen the squeeze; the force-limited command has its
    own limit); a number or None as given.

    Raises
    ------
    InputError
        A cap that is not a finite positive number, None or ``"auto"``; a number with
        ``compliance`` (whose force limit is ``force_limit``).
    """
    if isinstance(cap, str) and cap == "auto":
        return ROBOT_FORCE_CAP if n_fingers == 1 and not compliance else None
    if cap is None:
        return None
    if not (_real(cap) and math.isfinite(float(cap)) and float(cap) > 0.0):
        raise InputError(f"force_cap is a force in N > 0, None for none or \"auto\", got "
                         f"{cap!r}")
    if compliance:
        raise InputError(f"force_cap={cap!r} is the stiff arm's cap; the force-limited "
                         "command (compliance=True) has its own: pass force_limit instead")
    return float(cap)


def resolve_surface_bound(n_fingers: int, bound: float | None = None,
                          tangential: bool = False) -> float:
    """The bound of the contact tracking correction's part along the object's surface
    that runs with ``n_fingers`` fingertips, m (``inf``: none): None is the default,
    :data:`ROBOT_TRACKING_SURFACE_BOUND` with one fingertip whose correction integrates the
    whole error, none otherwise (several fingertips; or a ``tangential`` correction, which
    integrates the surface part only: bounded to 0.5 mm it would be nearly off).

    Raises
    ------
    InputError
        A bound that is not a number from 0 to 0.05 m or ``inf`` (NaN, a bool, a string).
    """
    if bound is None:
        return ROBOT_TRACKING_SURFACE_BOUND if n_fingers == 1 and not tangential else math.inf
    if not (_real(bound) and (0.0 <= float(bound) <= 0.05 or float(bound) == math.inf)):
        raise InputError(f"tracking_surface_bound is a distance from 0 to 0.05 m, or inf for "
                         f"none, got {bound!r}")
    return float(bound)


def resolve_press_depth(depth: float | str | None, n_fingers: int) -> float | None:
    """The contact-consistent command's bound that runs, m (None: none): ``"auto"`` is
    :data:`PINCH_PRESS_DEPTH` with several fingertips and none with one; a number or None
    as given."""
    if depth == "auto":
        return PINCH_PRESS_DEPTH if n_fingers > 1 else None
    return None if depth is None else float(depth)

FloatArray = NDArray[np.float64]


def robot_control(config: ControlConfig | None = None, *, n_fingers: int,
                  max_accel: float = ROBOT_MAX_ACCEL) -> ControlConfig:
    """``config`` (default :class:`~nonprehensile.control.ControlConfig`) with the
    fingertip acceleration bounds of robots with ``n_fingers`` fingertips in all:
    ``max_accel`` for the motions; for the transits the caller's own
    ``config.transit_accel`` if it set one (at most ``max_accel``), else
    :data:`ROBOT_TRANSIT_ACCEL` (at most ``max_accel``) with one fingertip (one arm), half
    of ``max_accel`` (the free fingertips' rule) with more; and the follow-through's bound
    ``config.follow_depth`` if the caller set one, else :data:`ROBOT_FOLLOW_DEPTH`; and the
    correction pushes' approach ``config.push_approach`` if set (0: the constant-speed
    push), else :data:`ROBOT_PUSH_APPROACH`.

    Raises
    ------
    InputError
        ``n_fingers`` below 1.
    """
    if isinstance(n_fingers, bool) or not isinstance(n_fingers, int) or n_fingers < 1:
        raise InputError(f"a robot has at least one fingertip, got n_fingers={n_fingers!r}")
    cfg = config or ControlConfig()
    if cfg.follow_depth is None:  # a stiff arm is not turned on into an object that stays
        cfg = replace(cfg, follow_depth=ROBOT_FOLLOW_DEPTH)
    if cfg.push_approach is None:  # an arm follows its command: no pad lag to wait for
        cfg = replace(cfg, push_approach=ROBOT_PUSH_APPROACH)
    if cfg.transit_accel is not None:  # the caller's bound, never silently dropped
        ta: float | None = min(cfg.transit_accel, float(max_accel))
    else:
        ta = min(ROBOT_TRANSIT_ACCEL, float(max_accel)) if n_fingers == 1 else None
    return replace(cfg, max_accel=max_accel, transit_accel=ta)


class RobotSimulator(Simulator):
    """One object, the table and robot arms, at the physics step's control rate.

    Parameters
    ----------
    poly : Polyhedron
    arms : sequence of Arm
        Robots at their base poses; their tip sites are fingers R1, R2, ... in order.
    scale : float, optional
        Metres per model unit (default from the model's units).
    params : SimParams
        The scene's physics; ``finger_radius`` is the fingertip sphere put at each tip site;
        ``stiffness`` and ``max_force`` (the free fingertip's spring and force limit) are the
        arms' virtual finger (``compliance``); ``finger_mass`` is not used. Setting
        :attr:`params` (a sweep's sample) sets the virtual finger too.
    ik_config : IKConfig, optional
    control_every : int
        The IK runs every this many physics steps (control rate = physics rate / it; default
        :data:`~nonprehensile.sim.robot_driver.DEFAULT_CONTROL_EVERY`, 100 Hz); the servos'
        set points are interpolated in between.
    force_limit : float, optional
        The virtual finger's force limit, N per axis (default ``params.max_force``; ``inf``:
        a spring without a limit).
    compliance : bool, optional
        The force-limited finger command
        (:meth:`~nonprehensile.sim.robot_driver.RobotArms._comply`): the fingertip's command
        gives way along the measured contact force as the free fingertip's spring would.
        Off (the default): the stiff position-controlled arm (docs/robot.md gives the
        measured figures of both, for one arm and for two).
    tracking_gain : float, optional
        Gain (1/s) of the fingertips' contact tracking correction
        (:class:`~nonprehensile.sim.robot_driver.RobotArms`; 0: off). Default:
        :data:`DEFAULT_TRACKING_GAIN` with one fingertip, :data:`PINCH_TRACKING_GAIN` with
        several.
    tracking_tangential : bool, optional
        Whether the correction integrates the fingertip's error along the object's surface
        only (``RobotArms.tracking_tangential``). Default: False with one fingertip, True
        with several. With two arms pinching, the whole error integrated the part no rigid
        tip can close (the references put a pinching pad 2-8 mm inside the cube) into a
        harder squeeze (contact forces up to 70 N), the cube stayed tilted between the
        fingers and the tumble-twist's first attempt failed in every one of the 24
        two-finger tumble-twists at nominal physics (docs/benchmarks.md, two22c's section);
        along the surface only, the correction takes out the arms' lag as they carry the
        cube (3.5 mm at 0.45 m/s) and squeezes no harder.
    tracking_bound : float, optional
        The correction's bound, m. Default: the driver's 4 mm with one fingertip,
        :data:`PINCH_TRACKING_BOUND` with several.
    radius_offset : bool or "auto"
        Move each target near the object out along its normal by the arm's fingertip
        radius minus the references' (:meth:`~nonprehensile.sim.robot_driver.RobotArms.
        _tool`: a tool radius compensation; a fingertip no larger than the references' is
        not moved). ``"auto"``, the default: on with one fingertip,
        off with several (:func:`resolve_radius_offset`; docs/robot.md gives the measured
        figures).
    press_depth : float, None or "auto"
        The contact-consistent command (:meth:`~nonprehensile.sim.robot_driver.RobotArms.
        _press_push`): the deepest, in m, that a fingertip's command (the centre of the
        arm's fingertip sphere, radius ``params.finger_radius``) may put the sphere inside
        the object as the arm believes it (the latest observation); a command deeper is
        pushed out along the object's normal, keeping its motion along the surface. None:
        no bound (the references as they are). ``"auto"`` (the default): none with one
        fingertip (an arm pushing: the bound lost slippery-table pushes across the
        physics distribution), :data:`PINCH_PRESS_DEPTH` with several (arms pinching:
        measured better on every contact bar; docs/benchmarks.md, press24).
    press_correction : bool
        Whether the contact tracking correction may drive the IK's target past
        ``press_depth`` (True) or is bounded with it (False).
    finger_direction : {"lean", "recorded"}
        How the finger tools point during a plan step, closed loop: ``"lean"`` (the
        default), the IK's geometric rule (down, leaning out of a side face:
        :meth:`~nonprehensile.sim.ik.FingertipIK.lean`); ``"recorded"``, along the
        demonstrators' fingers, knuckle marker to tip marker, where the reference is at
        each observation (:meth:`~nonprehensile.control.StepMonitor.pointing`; references
        without knuckle markers, transits, let-goes, follow-throughs, recoveries and open
        loop keep the rule). Measured: docs/robot.md, "The finger's direction".
    accel_feedforward : bool
        Whether the servos are given the torque of the set points' acceleration, ``(M(q) +
        h D) qdd_ref``, through their position set points (the computed-torque
        feed-forward: :meth:`~nonprehensile.sim.robot_driver.RobotArms._accel_offset`; on
        by default, at a control rate below the physics rate). Off, the servos take that
        torque from their error: the fingertip lagged its command by 4-5 ms.
    tracking_surface_bound : float, optional
        The bound of the contact tracking correction's part along the object's surface, m,
        applied after each update (its part along the object's normal is kept; the whole
        correction keeps ``tracking_bound`` after that; ``inf``: none). Default:
        :data:`ROBOT_TRACKING_SURFACE_BOUND` with one fingertip integrating the whole error,
        none otherwise (a pinch, and ``tracking_tangential=True``, integrate only the surface
        part).
    force_cap : float, None or "auto"
        The stiff arm's force cap, N: above it each fingertip's command gives way along the
        contact force on it (every physics step while the fingertip touches, the contacts
        read every 5 steps; at most 0.1 m/s, so an impact at speed passes the cap for a
        tenth of a second or two), and comes back below it
        (:meth:`~nonprehensile.sim.robot_driver.RobotArms._cap`; the records' ``give``).
        ``"auto"`` (the default): :data:`ROBOT_FORCE_CAP` with one fingertip and the stiff
        arm, none with several or with ``compliance``; None: none.
    force_feedforward : bool or "auto"
        With a force cap: the contact force on each fingertip (the force sensor's reading,
        clipped at the cap, averaged over each control period) fed forward to the servos,
        ``K_p^-1 (-J^T F)`` on their position set points
        (:meth:`~nonprehensile.sim.robot_driver.RobotArms._pushed`), and the cap's give
        coming back at full speed fed forward as a motion (its velocity on the velocity
        servos, its acceleration bounded: ``RobotArms._cap``). ``"auto"`` (the default): on
        with a force cap and one fingertip, off otherwise (True there is refused). Without
        it the servos hold the force from their position error: the fingertip stood 4-7 mm
        from its command at 20-70 N across the physics distribution, and 2-5 of 100 runs kept
        within 3 mm in contact against 75-76 with it (100 samples of seeds 0 and 1; at
        nominal physics 0.5 mm over the 72 single-finger transitions against 2.8 mm). The
        arm that follows its command turns the cube further than the references (recorded
        with a compliant fingertip) expect: at nominal physics 5 % more simulated time and
        8-10 % more CPU (docs/robot.md).
    """

    def __init__(self, poly: Polyhedron, arms: Sequence[Arm], *, scale: float | None = None,
                 params: SimParams = DEFAULT_PARAMS, ik_config: IKConfig | None = None,
                 control_every: int = DEFAULT_CONTROL_EVERY,
                 force_limit: float | None = None, tracking_gain: float | None = None,
                 tracking_tangential: bool | None = None,
                 tracking_bound: float | None = None,
                 compliance: bool = False, radius_offset: bool | str = "auto",
                 press_depth: float | str | None = "auto",
                 press_correction: bool = True, finger_direction: str = "lean",
                 accel_feedforward: bool = True,
                 tracking_surface_bound: float | None = None,
                 force_cap: float | str | None = "auto",
                 force_feedforward: bool | str = "auto") -> None:
        if not isinstance(accel_feedforward, bool):
            raise InputError(f"accel_feedforward is True or False, got {accel_feedforward!r}")
        if force_limit is not None and not compliance:
            # before the force-limited command, force_limit alone made the tip yield: a call
            # written then must not now run the stiff arm without a word
            raise InputError(f"force_limit={force_limit!r} is the force-limited finger "
                             "command's limit: pass compliance=True with it, or drop it")
        # the correction's options checked before the scenes are built (n_fingers later)
        resolve_tracking(1, tracking_gain, tracking_tangential, tracking_bound)
        resolve_surface_bound(1, tracking_surface_bound)
        resolve_force_cap(force_cap, 1, compliance is True)
        check_force_feedforward(force_feedforward, math.inf)  # (its type now, its cap below)
        check_finger_direction(finger_direction)
        self.poly = poly
        self.scale = float(scale) if scale is not None else default_scale(poly)
        self._force_limit = force_limit
        self._params = params
        self.arms = tuple(arms)
        self.scene = build_robot_scene(poly, scale=self.scale, arms=self.arms, params=params)
        self.ik_scene = build_robot_scene(poly, scale=self.scale, arms=self.arms,
                                          params=params, mocap_object=True)
        self.n_fingers = self.scene.n_fingers
        if self.n_fingers > 10:
            raise InputError(f"at most 10 fingers, the robots have {self.n_fingers}")
        self.xml = ""  # built with MjSpec: see self.scene
        self.model = self.scene.model
        self.data = mujoco.MjData(self.model)
        self.judge = Judge(poly, self.scale, params, self.model, self.n_fingers)
        # one arm pushes; several pinch (see above)
        gain, tangential, bound = resolve_tracking(self.n_fingers, tracking_gain,
                                                   tracking_tangential, tracking_bound)
        self.robot_driver = RobotArms(self.scene, self.ik_scene, self.data, self.judge,
                                      params.timestep, ik_config, control_every,
                                      params.max_force if force_limit is None
                                      else force_limit, gain, compliance=compliance,
                                      finger_stiffness=params.stiffness)
        self.driver = self.robot_driver
        # the fingertip radius offset of the arm's commands (RobotArms._tool)
        normals = np.array([poly.normals[f] for f in poly.face_ids])
        offsets = np.array([poly.normals[f] @ poly.vertices[poly.faces[f][0]]
                            for f in poly.face_ids])
        self.robot_driver.set_shape(normals, offsets, self.scale)
        self.robot_driver.radius_offset = resolve_radius_offset(radius_offset, self.n_fingers)
        check_press(press_depth, press_correction)
        # one arm pushes: none; several pinch: the bound
        self.robot_driver.press_depth = resolve_press_depth(press_depth, self.n_fingers)
        self.robot_driver.press_correction = press_correction
        self.robot_driver.tracking_tangential = tangential
        self.robot_driver.tracking_bound = bound
        self.robot_driver.tracking_surface_bound = resolve_surface_bound(
            self.n_fingers, tracking_surface_bound, tangential)
        self.robot_driver.finger_radius = params.finger_radius
        self.robot_driver.finger_direction = finger_direction
        self.robot_driver.accel_feedforward = accel_feedforward
        self.robot_driver.force_cap = resolve_force_cap(force_cap, self.n_fingers,
                                                        compliance is True)
        self.robot_driver.force_feedforward = resolve_force_feedforward(
            force_feedforward, self.robot_driver.force_cap, self.n_fingers)
        self._body = self.judge.body
        self._qadr = self.judge.qadr
        self._dadr = self.judge.dadr
        self._finger_qadr = self.driver.qpos_indices()
        self._home_tips = self._tips_at_home()

    @property
    def params(self) -> SimParams:
        """The scene's physics (setting it sets the arms' virtual finger: ``stiffness``, and
        ``max_force`` unless a ``force_limit`` was given)."""
        return self._params

    @params.setter
    def params(self, value: SimParams) -> None:
        self._params = value
        drv = getattr(self, "robot_driver", None)
        if drv is not None:
            drv.finger_stiffness = value.stiffness
            drv.finger_radius = value.finger_radius
            if self._force_limit is None:
                drv.force_limit = value.max_force
            drv.check_compliance()

    @property
    def robot_log(self) -> RobotLog:
        """The robot's records since the last new start."""
        return self.robot_driver.log

    @property
    def ik_config(self) -> IKConfig:
        """The IK's weights and limits."""
        return self.robot_driver.ik.config

    def _tips_at_home(self) -> FloatArray:
        d = mujoco.MjData(self.model)
        d.qpos[self.scene.qadr] = self.scene.home
        mujoco.mj_kinematics(self.model, d)
        return np.array([d.site_xpos[int(s)] for s in self.scene.tip_sites])

    def park(self) -> FloatArray:
        """Fingers not in use stay where the arm's home pose puts them."""
        return np.array(self._home_tips)

    def run(self, start: ObjectPose | None, targets: Mapping[int, FloatArray], rate: float,
            *, settle: float | None = None, keep_trace: int = 0,
            signals: bool = False) -> SimResult:
        """As :meth:`Simulator.run`; a new ``start`` also places the arms anew (and clears
        :attr:`robot_log`), ``start=None`` carries on from where the arms are."""
        if start is not None:
            self.robot_driver.reset()
            self.robot_driver.see(None)  # a run observes nothing (see RobotArms.see)
        return super().run(start, targets, rate, settle=settle, keep_trace=keep_trace,
                           signals=signals)

    def describe(self) -> dict[str, Any]:
        """The robots, base poses, controller, gains, rates and limits (JSON), with the
        fingertips' command (``finger_command``: the force-limited command's switch, virtual
        finger and tracking correction) and where the IK's object pose comes from."""
        doc = describe_robots(self.arms, self.scene, self.params, self.ik_config,
                              self.robot_driver.every,
                              accel_feedforward=self.robot_driver.accel_feedforward)
        drv = self.robot_driver
        doc["finger_command"] = {
            "compliance": drv.compliance,
            "stiffness_n_per_m": float(drv.finger_stiffness),
            # None: a spring without a limit (JSON has no infinity)
            "force_limit_n": (float(drv.force_limit) if np.isfinite(drv.force_limit)
                              else None),
            "damping_n_s_per_m": float(drv.compliance_damping),
            "tracking_gain_per_s": drv.tracking_gain,
            # the correction along the object's surface only (True) or whole, and its bound
            "tracking_tangential": bool(drv.tracking_tangential),
            "tracking_bound_m": float(drv.tracking_bound),
            # the stiff arm's force cap (None: none), whether the contact force (clipped
            # at it) is fed forward, and the acceleration of its give's full-speed return
            "force_cap_n": drv.force_cap,
            "force_feedforward": bool(drv.force_feedforward),
            # (None: the give's return is not a fed-forward motion, the switch off)
            "give_accel_m_per_s2": (float(drv.give_accel) if drv.force_feedforward
                                    else None),
            # pressed past the cap, the force (in caps) from which the velocity set points go
            # no faster into the object than the fingertip (None: off, or no cap;
            # RobotArms._velocity_in_contact)
            "contact_velocity_full_caps": (float(drv.contact_velocity)
                                           if drv.force_cap is not None
                                           and drv.contact_velocity is not None else None),
            # the bound of its part along the object's surface (None: none)
            "tracking_surface_bound_m": (float(drv.tracking_surface_bound)
                                         if math.isfinite(drv.tracking_surface_bound)
                                         else None),
            # whether targets near the object move out by the fingertip radius minus the
            # references' (RobotArms._tool)
            "radius_offset": bool(drv.radius_offset),
            # the contact-consistent command's bound (None: the references as they are)
            "press_depth_m": drv.press_depth,
            "press_correction": bool(drv.press_correction),
            # how the finger tools point in a step ("lean" or "recorded": the knuckles)
            "finger_direction": drv.finger_direction,
        }
        doc["ik_object_pose"] = ("closed loop: each observation (RobotArms.see); open loop, "
                                 "where nothing is observed: the simulation's pose")
        return doc


def describe_robots(arms: Sequence[Arm], scene: RobotScene, params: SimParams,
                    ik_config: IKConfig,
                    control_every: int = DEFAULT_CONTROL_EVERY, *,
                    accel_feedforward: bool = True) -> dict[str, Any]:
    """The robots, base poses, controller, gains, rates and limits of a robot scene (JSON);
    ``accel_feedforward``: whether the servos get the set points' acceleration torque
    (:class:`RobotSimulator`'s switch; it runs only below the physics rate)."""
    m, sc = scene.model, scene
    ff = accel_feedforward and control_every > 1
    joints = []
    for j, name in enumerate(sc.joint_names):
        pa, va = int(sc.pos_act[j]), int(sc.vel_act[j])
        joints.append({
            "name": name, "lower": round(float(sc.lower[j]), 6),
            "upper": round(float(sc.upper[j]), 6),
            "velocity_limit": round(float(sc.velocity[j]), 6),
            "torque_limit": None if not np.isfinite(sc.torque[j])
            else round(float(sc.torque[j]), 6),
            "kp": round(float(m.actuator_gainprm[pa, 0]), 6),
            "kv": round(float(m.actuator_gainprm[va, 0]), 6),
            # the acceleration's torque goes through this joint's servo (a plain one only)
            "acceleration_feedforward": ff and math.isfinite(servo_stiffness(m, pa)),
        })
    return {
        "robots": [{"robot": a.robot.to_dict(), "base": a.base.to_dict(),
                    "prefix": f"arm{i}/"} for i, a in enumerate(arms)],
        "controller": {
            "kind": "joint position servo + velocity feed-forward + gravity compensation"
                    + (" + acceleration feed-forward" if ff else ""),
            "law": ("tau = kp (q_ref - q) + kv (qd_ref - qd) + (M(q) + h D) qdd_ref + g(q), "
                    "clamped to the torque limit; qdd_ref: the set points' acceleration "
                    "(constant over a control period: the quadratic spline's), M: the mass "
                    "matrix, h D: the physics step times the joint damping and velocity "
                    "gains (the implicit integrator's added inertia); the acceleration term "
                    "is sent as a position set-point offset of K_p^-1 (M + h D) qdd_ref, its "
                    "torque clipped to the joint's limit, to the joints whose position servo "
                    "is a plain one (joints[].acceleration_feedforward)" if ff
                    else "tau = kp (q_ref - q) + kv (qd_ref - qd) + g(q), clamped to the "
                    "torque limit"),
            "acceleration_feedforward": ff,
            "ik": "mink differential IK (daqp), one solve per control step",
            "ik_config": ik_config.to_dict(),
        },
        "rates": {"control_hz": round(1.0 / (params.timestep * control_every), 6),
                  "servo_hz": round(1.0 / params.timestep, 6),
                  "physics_hz": round(1.0 / params.timestep, 6)},
        "joints": joints,
        "fingertip_radius_m": params.finger_radius,
    }
