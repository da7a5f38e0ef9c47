"""The robot finger driver: fingertip targets -> IK at the control rate -> joint servos.

:class:`RobotArms` implements :class:`~nonprehensile.sim.driver.FingerDriver`, so the judge's
rules and records are those of the free fingertips. Its :meth:`~RobotArms.controls` are
computed **online**: row ``i`` is solved when the step loop asks for it, right before physics
step ``i``, with the object's collision geometry where the executor believes it is then
(:meth:`RobotArms.see`: closed loop the latest observation, never the simulation's true pose;
open loop, which observes nothing, the simulation's; a precomputed joint path would avoid the
object where it was, not where it is). Each row holds,
for every joint, the position servo's set point (the IK's joint positions) and the velocity
servo's (the IK's joint velocities: feed-forward, so the arm does not lag its set points);
the torque of the set points' acceleration is fed forward through the position set points
(:meth:`RobotArms._accel_offset`), and gravity is compensated through the actuators
(:mod:`nonprehensile.sim.robot_scene`).

:class:`RobotLog` records, every control step, the fingertip tracking error, joint positions,
velocities and actuator torques, whether a fingertip touches the object, whether a link or the
rod touches the object or the table, and the IK's time; :meth:`RobotLog.metrics` sums them up.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.planning import ObjectPose
from nonprehensile.sim.ik import FingertipIK, IKConfig
from nonprehensile.sim.judge import CONTACT_EVERY, Judge
from nonprehensile.sim.robot_scene import RobotScene

__all__ = ["COMPLIANCE_DAMPING", "DEFAULT_CONTROL_EVERY", "GIVE_ACCEL", "LIMIT_BANDS",
           "RobotArms", "RobotLog", "RobotMetrics", "check_press", "servo_stiffness"]

FloatArray = NDArray[np.float64]

try:  # the clip ufunc: np.clip without its Python dispatch (the same values, a fifth of
    # the time: every control period clips the feed-forwards' offsets)
    from numpy._core.umath import clip as _clip  # type: ignore[attr-defined]
except ImportError:  # pragma: no cover - other numpy layouts
    _clip = np.clip

# the reductions ``ndarray.sum``, ``.max`` and ``.any`` call, without their Python wrappers
# (the same values: each control period in contact makes a handful of them)
_SUM, _MAX, _ANY = np.add.reduce, np.maximum.reduce, np.logical_or.reduce

#: Physics steps per IK solve by default: 10, a 100 Hz control rate over the 1 kHz physics
#: (the servos get set points interpolated every physics step). The main plan at nominal
#: physics meets the contact bars at it (closed loop: tracking in contact 2.8 mm, 8 ms at a
#: limit, no link contact; at 1 kHz 2.8 mm and 5 ms) at a tenth of the IK's cost; at 62.5 Hz
#: the main plan's first push-roll, open loop, tracks 4.3 mm off and loses its contact on the
#: edge (docs/robot.md).
DEFAULT_CONTROL_EVERY = 10

#: Joint speed (rad/s) under which a hold's set points stop following the IK
#: (:meth:`RobotArms._segment`): the arm has come to rest on the held target.
REST_SPEED = 1e-3

#: The fingertip radius the references were recorded with, m (the free fingertip's, the
#: bundled demonstrations' synthetic mentor's: :class:`~nonprehensile.sim.scene.SimParams`).
REFERENCE_RADIUS = 0.006

#: One fingertip's contact tracking correction bound, m (:meth:`RobotArms._correct`).
DEFAULT_TRACKING_BOUND = 0.004

#: The share of each joint's torque limit the set points' accelerations may take with
#: the arm's dynamics (:meth:`RobotArms._within_torque`; the rest is the servos' margin).
TORQUE_SHARE = 0.8

#: The share of a light joint's limit (under :data:`LIGHT_JOINT` N m: the Panda's wrist,
#: 12 N m). Chosen when the budget's model left out the implicit integrator's inertia
#: (:func:`_implicit_inertia`): at 0.8 the wrist, driven at 30 rad/s^2 to 2.3 rad/s as a
#: transit of the main plan began, held its 12 N m for 12-13 ms (the model asked 9 N m); at
#: 0.6, 6 ms. With that inertia counted the main plan at nominal physics holds no limit at
#: 0.6, 0.7 or 0.8 (torque margin 13, 13 and 6 %): 0.6 is kept for the servos' margin.
TORQUE_SHARE_LIGHT = 0.6
LIGHT_JOINT = 30.0

#: Newton steps of the contact-consistent command's push (:meth:`RobotArms._press_push`).
PRESS_ITERATIONS = 6

#: The force-limited finger command's damping ``B`` (N s/m, :meth:`RobotArms._comply`).
COMPLIANCE_DAMPING = 300.0

#: With the contact force feed-forward (``RobotArms.force_feedforward``), the force cap's
#: give, coming back at its full speed (the contact force at most ``cap - B give_speed``),
#: accelerates and stops at most this much, m/s^2, and its velocity is fed forward to the
#: servos, taken up at the same rate (:meth:`RobotArms._cap`). 1, 2 and 5 m/s^2 measured
#: alike across the physics distribution with the force fed forward every physics step
#: (docs/benchmarks.md; the landed per-period form was measured at 2); 2 keeps the velocity
#: servos' steps small (2 mm/s a physics step at the fingertip).
GIVE_ACCEL = 2.0

#: One stiff arm pressed past its force cap: the contact force, in caps, from which the
#: velocity set points go no faster into the object than the fingertip itself (in
#: proportion from the cap up to it; 1: in full as soon as the force passes the cap;
#: :meth:`RobotArms._velocity_in_contact`). Across the physics distribution (the main
#: plan, 100 samples, seeds 0-2, 300 runs; 281 reached, 281 within 3 mm in contact, 4 runs
#: over 10 ms at a limit while touching, 1 with a rod on the cube or table without it) at 1:
#: 282, 285, 2 and 0, runs pressing past 100 N 10 against 53; ramped to 2 caps: 283, 286, 3
#: and 2 (seed 0's reached 96 against 97); from 1.5 to 2.5 caps: 283, 286, 5 and 2
#: (docs/benchmarks.md).
CONTACT_VELOCITY_FULL = 1.0

#: The time constant (s) of the critically damped smoothing (two first-order low-passes in
#: series) of the physics distribution's fingertip noise (a Gauss-Markov process with no
#: derivative, 50 ms) before an arm's servos realise it with its velocity fed forward
#: (:meth:`RobotArms.with_noise`); the smoothed process is scaled to keep the noise's
#: standard deviation (the smoothing alone keeps 71 % at 30 ms) and follows the raw one
#: about 45 ms behind (correlation 0.85 there). On the position set points alone the
#: velocity servos held the arm back and most of the noise counted as tracking error (3-4
#: mm in contact: the worst row of most runs with the force fed forward; 4 times the error
#: of the smoothed noise fed forward in free space, the tests). Across the distribution
#: (100 samples, seed 0, force fed forward; measured before the smoothed rows ran on past
#: a segment's end) at 20, 30 and 40 ms: 75, 72 and 73 runs within
#: 3 mm in contact, and 11, 2 and 4 runs over 10 ms at a torque limit (the faster the
#: smoothing, the more the velocity fed forward shakes the wrist); unscaled at 20 ms (78 %
#: of the deviation): 81 and 3.
NOISE_SMOOTHING = 0.03

#: A joint is "at" a limit within these bands: position within 0.5 degrees of an end of its
#: range, velocity and torque at or above 98 % of their limits.
LIMIT_BANDS = {"position_rad": np.radians(0.5), "velocity_fraction": 0.98,
               "torque_fraction": 0.98}


#: How a step's finger tools may point (``RobotArms.finger_direction``): ``"lean"``, the
#: IK's geometric rule (:meth:`~nonprehensile.sim.ik.FingertipIK.lean`); ``"recorded"``,
#: along the demonstrations' fingers (knuckle to tip) where the references carry knuckle
#: markers, the rule elsewhere.
FINGER_DIRECTIONS = ("lean", "recorded")


def check_finger_direction(value: object) -> None:
    """Refuse a ``finger_direction`` that is not one of :data:`FINGER_DIRECTIONS`."""
    if not isinstance(value, str) or value not in FINGER_DIRECTIONS:
        raise InputError(f"finger_direction is one of {list(FINGER_DIRECTIONS)}, got "
                         f"{value!r}")


def check_press(depth: object, correction: object = True) -> None:
    """Refuse a contact-consistent command that is not one (one line saying what came):
    ``depth`` None, ``"auto"`` (by the number of fingertips:
    :class:`~nonprehensile.sim.robot_run.RobotSimulator`) or a finite depth of 0 to 20 mm
    in m, ``correction`` a bool."""
    if depth is not None and depth != "auto" and not (isinstance(depth, numbers.Real)
                                  and not isinstance(depth, (bool, np.bool_))
                                  and 0.0 <= float(depth) <= 0.02):  # (NaN, inf: no)
        raise InputError(f"the press depth is None, 'auto' or 0..0.02 m, got {depth!r}")
    if not isinstance(correction, bool):
        raise InputError(f"press_correction is True or False, got {correction!r}")


@dataclass(frozen=True)
class RobotMetrics:
    """What the robot did during a run (see :class:`RobotLog`).

    Attributes
    ----------
    tracking_error_contact_max_m, tracking_error_contact_mean_m : float or None
        Fingertip tracking error (actual centre to the commanded one) while a fingertip
        touches the object; None if none did. The commanded fingertip is the executor's
        target plus the distribution's fingertip position error where a sweep adds one
        (``finger_noise``: it is part of the command, put on the servos' set points, see
        :meth:`RobotArms.with_noise`).
    tracking_error_max_m : float
        Over the whole run (transits and jumps between steps included).
    reference_error_contact_max_m : float or None
        As ``tracking_error_contact_max_m``, against the executor's target itself (the
        planner's reference, without the give, the force-limited command's or the force
        cap's, and the noise).
    contact_force_max_n : float or None
        The largest contact force on a fingertip (norm, N; the force sensor's reading at the
        solves) while a fingertip touches the object.
    give_contact_max_m : float or None
        The largest give of the compliance (command to target) while touching, m.
    longest_at_limit_contact_s : float
        The longest time any joint stayed at any limit while a fingertip touched the object
        (``longest_at_limit_s`` counts the whole run, transits included).
    longest_at_limit_contact_by_kind_s : dict of str to float
        As ``longest_at_limit_contact_s``, per kind of limit (``position``, ``velocity``,
        ``torque``): whose limit is held while touching (the bars' "no limit held for more
        than 10 ms" during contact) without reading the log.
    position_margin_min_rad : float
        Least distance of a joint to an end of its range.
    velocity_margin_min, torque_margin_min : float
        Least ``1 - |value| / limit`` over joints and time (torque: None without limits).
    longest_at_limit_s : dict of str to float
        Longest time a joint stayed at a position, velocity or torque limit.
    time_at_limit_s : float
        Time any joint was at any limit.
    other_contact_s : float
        Time a link or the rod touched the object or the table.
    ik_median_ms, ik_max_ms : float
        IK time per solve.
    n_solves : int
    """

    tracking_error_contact_max_m: float | None
    tracking_error_contact_mean_m: float | None
    tracking_error_max_m: float
    position_margin_min_rad: float
    velocity_margin_min: float
    torque_margin_min: float | None
    longest_at_limit_s: dict[str, float]
    time_at_limit_s: float
    other_contact_s: float
    ik_median_ms: float
    ik_max_ms: float
    n_solves: int
    reference_error_contact_max_m: float | None = None
    contact_force_max_n: float | None = None
    give_contact_max_m: float | None = None
    longest_at_limit_contact_s: float = 0.0
    longest_at_limit_contact_by_kind_s: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON form (rounded)."""
        def r(v: float | None, n: int = 6) -> float | None:
            return None if v is None else round(float(v), n)
        return {
            "tracking_error_contact_max_m": r(self.tracking_error_contact_max_m),
            "tracking_error_contact_mean_m": r(self.tracking_error_contact_mean_m),
            "tracking_error_max_m": r(self.tracking_error_max_m),
            "reference_error_contact_max_m": r(self.reference_error_contact_max_m),
            "contact_force_max_n": r(self.contact_force_max_n, 3),
            "give_contact_max_m": r(self.give_contact_max_m),
            "longest_at_limit_contact_s": round(self.longest_at_limit_contact_s, 4),
            "longest_at_limit_contact_by_kind_s": {
                k: round(v, 4) for k, v in self.longest_at_limit_contact_by_kind_s.items()},
            "position_margin_min_rad": r(self.position_margin_min_rad, 4),
            "velocity_margin_min": r(self.velocity_margin_min, 4),
            "torque_margin_min": r(self.torque_margin_min, 4),
            "longest_at_limit_s": {k: round(v, 4) for k, v in self.longest_at_limit_s.items()},
            "time_at_limit_s": round(self.time_at_limit_s, 4),
            "other_contact_s": round(self.other_contact_s, 4),
            "ik_median_ms": round(self.ik_median_ms, 4),
            "ik_max_ms": round(self.ik_max_ms, 4),
            "ik_solves": self.n_solves,
        }


class RobotLog:
    """Per-physics-step records of a robot run (see the module docstring), in preallocated
    arrays (grown by doubling): a row per physics step costs a few slice copies, not a
    handful of new arrays (the per-step list appends of each array were a fifth of a robot
    run's time).

    Attributes ``time`` (n,), ``q``, ``qd``, ``tau``, ``q_ref``, ``qd_ref`` (n, n_joints),
    ``error`` (n,: the largest fingertip distance to its command, the target plus the
    fingertip noise), ``error_ref`` (n,: to the noise-free target), ``touch``, ``other`` (n,
    bool) and ``ik`` (n,: seconds of the solve made at that step, NaN where the set point
    was interpolated) are views of the rows recorded so far.
    """

    def __init__(self, scene: RobotScene, dt: float) -> None:
        self.scene = scene
        self.dt = dt
        self.clear()

    def clear(self, capacity: int = 4096) -> None:
        """Forget everything recorded."""
        nj, nf = len(self.scene.joint_names), self.scene.n_fingers
        self.n = 0
        self._time = np.zeros(capacity)
        self._q = np.zeros((capacity, nj))
        self._qd = np.zeros((capacity, nj))
        self._tau = np.zeros((capacity, nj))
        self._q_ref = np.zeros((capacity, nj))
        self._qd_ref = np.zeros((capacity, nj))
        self._tips = np.zeros((capacity, nf, 3))
        self._target = np.zeros((capacity, nf, 3))
        self._noise = np.zeros((capacity, nf, 3))  # the fingertip noise on the set points
        self._give = np.zeros((capacity, nf, 3))  # the give (RobotArms._comply, _cap)
        self._tool = np.zeros((capacity, nf, 3))  # the tip radius offset (RobotArms._tool)
        self._force = np.full((capacity, nf), math.nan)  # measured contact force at solves
        self._touch = np.zeros(capacity, dtype=bool)
        self._other = np.zeros(capacity, dtype=bool)
        self._ik = np.full(capacity, math.nan)
        # the rows below which ``_tool`` and ``_noise`` may hold anything but zeros (past
        # them a control period with no offset or noise need not write its zeros again)
        self._tool_to = 0
        self._noise_to = 0
        self._flat()

    def _flat(self) -> None:
        """Flat memoryviews of the arrays :meth:`RobotArms.record` writes every physics step
        (``time``, ``q``, ``qd``, ``tau``, the tips, ``touch``, ``other``), made again with
        the arrays: a row written through them is a memcpy, without numpy's indexing (a
        third of its row assignment's cost)."""
        self._mv = tuple(memoryview(getattr(self, name).reshape(-1)) for name in
                         ("_time", "_q", "_qd", "_tau", "_tips", "_touch", "_other"))

    def __getstate__(self) -> dict[str, Any]:
        """The log without its memoryviews (they do not pickle): :meth:`__setstate__`
        makes them again."""
        state = dict(self.__dict__)
        del state["_mv"]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._flat()

    _ROWS = ("_time", "_q", "_qd", "_tau", "_q_ref", "_qd_ref", "_tips", "_target", "_noise",
             "_give", "_tool", "_force", "_touch", "_other", "_ik")

    def reserve(self, rows: int) -> None:
        """Room for ``rows`` more rows (the arrays double when full)."""
        need = self.n + rows
        cap = len(self._time)
        if need <= cap:
            return
        while cap < need:
            cap *= 2
        for name in self._ROWS:
            old = getattr(self, name)
            new = np.full((cap, *old.shape[1:]), math.nan) if name in ("_ik", "_force") else \
                np.zeros((cap, *old.shape[1:]), dtype=old.dtype)
            new[:self.n] = old[:self.n]
            setattr(self, name, new)
        self._flat()

    @property
    def time(self) -> FloatArray:
        """Simulated time of each row, s."""
        return self._time[:self.n]

    @property
    def error(self) -> FloatArray:
        """The largest fingertip tracking error of each row (tip centre to its command: the
        executor's target, plus the fingertip radius offset along the object's normal
        (:meth:`RobotArms._tool`), plus the give along the contact force (the force-limited
        command's, :meth:`RobotArms._comply`, or the force cap's, :meth:`RobotArms._cap`),
        plus the fingertip noise put on the set points:
        what the IK and the servos were asked to reach), m."""
        e = (self._tips[:self.n] - self._target[:self.n] - self._tool[:self.n]
             - self._give[:self.n] - self._noise[:self.n])
        return np.asarray(np.sqrt((e * e).sum(axis=2).max(axis=1)), dtype=np.float64)

    @property
    def error_ref(self) -> FloatArray:
        """The largest fingertip distance of each row to the executor's target itself (the
        planner's reference: neither the give nor the noise), m."""
        e = self._tips[:self.n] - self._target[:self.n]
        return np.asarray(np.sqrt((e * e).sum(axis=2).max(axis=1)), dtype=np.float64)

    @property
    def tool(self) -> FloatArray:
        """The fingertip radius offset of each row's command (:meth:`RobotArms._tool`),
        shape (n, n_fingers, 3), m."""
        return self._tool[:self.n]

    @property
    def give(self) -> FloatArray:
        """The give of each row (the force-limited command's or the force cap's: command
        minus target, noise excluded), shape (n, n_fingers, 3), m."""
        return self._give[:self.n]

    @property
    def force(self) -> FloatArray:
        """The contact force on each fingertip (norm, N) as the force sensor read it at each
        solve, shape (n, n_fingers); NaN between solves."""
        return self._force[:self.n]

    @property
    def q(self) -> FloatArray:
        """Joint positions, shape (n, n_joints)."""
        return self._q[:self.n]

    @property
    def qd(self) -> FloatArray:
        """Joint velocities, shape (n, n_joints)."""
        return self._qd[:self.n]

    @property
    def tau(self) -> FloatArray:
        """Actuator torques on the joints, shape (n, n_joints)."""
        return self._tau[:self.n]

    @property
    def q_ref(self) -> FloatArray:
        """Joint position set points, shape (n, n_joints): the IK's spline, without the
        offsets the servos get on top (the fingertip noise's, the give's, the feed-forwards')."""
        return self._q_ref[:self.n]

    @property
    def qd_ref(self) -> FloatArray:
        """Joint velocity set points (feed-forward), shape (n, n_joints): the IK's spline,
        without the fingertip noise's velocity (as ``q_ref`` is without its offset)."""
        return self._qd_ref[:self.n]

    @property
    def touch(self) -> NDArray[np.bool_]:
        """Whether a fingertip touched the object (read every ``CONTACT_EVERY`` steps)."""
        return self._touch[:self.n]

    @property
    def other(self) -> NDArray[np.bool_]:
        """Whether a link or the rod touched the object or the table (likewise)."""
        return self._other[:self.n]

    @property
    def ik(self) -> FloatArray:
        """Seconds of the IK solve made at each row, NaN where none was."""
        return self._ik[:self.n]

    def metrics(self, start: int = 0, stop: int | None = None) -> RobotMetrics:
        """Sum up what was recorded (control steps ``start:stop``)."""
        sc, dt = self.scene, self.dt
        sl = slice(start, stop)
        if not len(self.time[sl]):
            return RobotMetrics(None, None, 0.0, float("nan"), float("nan"), None, {}, 0.0,
                                0.0, 0.0, 0.0, 0)
        err = self.error[sl]
        err_ref = self.error_ref[sl]
        touch = self.touch[sl]
        q, qd, tau = self.q[sl], self.qd[sl], self.tau[sl]
        margin_pos = np.minimum(q - sc.lower, sc.upper - q)
        vel_frac = np.abs(qd) / sc.velocity
        finite = np.isfinite(sc.torque)
        tau_frac = np.abs(tau[:, finite]) / sc.torque[finite] if finite.any() else None
        at = {
            "position": (margin_pos < LIMIT_BANDS["position_rad"]).any(axis=1),
            "velocity": (vel_frac >= LIMIT_BANDS["velocity_fraction"]).any(axis=1),
            "torque": (tau_frac >= LIMIT_BANDS["torque_fraction"]).any(axis=1)
            if tau_frac is not None else np.zeros(len(q), dtype=bool),
        }
        longest = {k: _longest_run(v) * dt for k, v in at.items()}
        any_at = at["position"] | at["velocity"] | at["torque"]
        ik = self.ik[sl] * 1e3
        ik = ik[np.isfinite(ik)]
        force = self.force[sl][touch]
        force = force[np.isfinite(force)]
        give = self.give[sl][touch]
        return RobotMetrics(
            float(err[touch].max()) if touch.any() else None,
            float(err[touch].mean()) if touch.any() else None,
            float(err.max()),
            float(margin_pos.min()),
            float(1.0 - vel_frac.max()),
            float(1.0 - tau_frac.max()) if tau_frac is not None else None,
            longest,
            float(any_at.sum() * dt),
            float(np.sum(self.other[sl]) * dt),
            float(np.median(ik)) if len(ik) else 0.0,
            float(ik.max()) if len(ik) else 0.0,
            len(ik),
            float(err_ref[touch].max()) if touch.any() else None,
            float(force.max()) if len(force) else None,
            float(np.sqrt((give * give).sum(axis=2)).max()) if touch.any() else None,
            _longest_run(any_at & touch) * dt,
            {k: _longest_run(v & touch) * dt for k, v in at.items()},
        )

    def window(self, t0: float, t1: float) -> tuple[int, int]:
        """The control steps recorded between simulated times ``t0`` and ``t1`` (s), as
        ``(start, stop)`` for :meth:`metrics` (times increase within one execution)."""
        t = self.time
        return int(np.searchsorted(t, t0 - 1e-9)), int(np.searchsorted(t, t1 + 1e-9))

    def joint_rows(self) -> FloatArray:
        """``[t, q_ref..., qd_ref...]`` per control step, shape (n, 1 + 2 n_joints)."""
        return np.column_stack([self.time, self.q_ref, self.qd_ref])


def _as_slice(idx: NDArray[np.int64]) -> slice | NDArray[np.int64]:
    """``idx`` as a slice when it is a run of consecutive indices, else itself."""
    if len(idx) and np.array_equal(idx, np.arange(idx[0], idx[0] + len(idx))):
        return slice(int(idx[0]), int(idx[0]) + len(idx))
    return idx


def _as_stride(idx: NDArray[np.int64]) -> slice | NDArray[np.int64]:
    """``idx`` as a slice when its indices are evenly spaced and rising (a step of 1 or
    more), else itself."""
    if len(idx) >= 2:
        step = int(idx[1]) - int(idx[0])
        if step >= 1 and np.array_equal(idx, np.arange(idx[0], idx[0] + step * len(idx),
                                                        step)):
            return slice(int(idx[0]), int(idx[0]) + step * (len(idx) - 1) + 1, step)
    return _as_slice(idx)


def _implicit_inertia(m: Any, dofs: NDArray[np.int64]) -> FloatArray:
    """The inertia the physics' implicit integration adds to each of ``dofs``, kg m^2.

    MuJoCo's ``implicit`` and ``implicitfast`` integrators take the forces' derivative with
    respect to the velocities into the step: ``(M + h D) dv / h = f(v)``, with ``D`` the
    joint damping plus every velocity gain of an affine-bias actuator on the joint (the
    velocity servos' ``kv``, a position servo's own ``kv``). The actuator's force, read at
    the step's start, is then ``(M + h D) a + c + g`` for the acceleration ``a`` the step
    makes: at 1 ms and ``kv`` 200 N m s/rad, ``h D`` is 0.2 kg m^2, where the Panda's wrist
    (joint 6) has 0.14 (its armature 0.1): the wrist's 30 rad/s^2 takes 10 N m, not the 4
    N m the mass matrix says. Zero under the explicit integrators (Euler, RK4)."""
    out = np.zeros(len(dofs))
    if int(m.opt.integrator) not in (int(mujoco.mjtIntegrator.mjINT_IMPLICIT),
                                     int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST)):
        return out
    where = {int(dof): k for k, dof in enumerate(dofs)}
    for k, dof in enumerate(dofs):
        out[k] += float(m.dof_damping[dof])
    for i in range(m.nu):
        if (int(m.actuator_trntype[i]) != int(mujoco.mjtTrn.mjTRN_JOINT)
                or int(m.actuator_biastype[i]) != int(mujoco.mjtBias.mjBIAS_AFFINE)
                or int(m.actuator_dyntype[i]) != int(mujoco.mjtDyn.mjDYN_NONE)):
            continue
        at = where.get(int(m.jnt_dofadr[m.actuator_trnid[i, 0]]))
        if at is not None:  # force = ... + biasprm[2] * velocity, velocity = gear * qvel
            gear = float(m.actuator_gear[i, 0])
            out[at] += max(0.0, -float(m.actuator_biasprm[i, 2])) * gear * gear
    return out * float(m.opt.timestep)


def servo_stiffness(m: Any, act: int) -> float:
    """A position servo's stiffness on its joint, N m/rad: ``kp`` times the gear (its force
    ``kp (ctrl - gear q)`` acts on the joint times the gear, and an offset of ``ctrl`` gives
    ``gear kp`` times it), for a plain servo (no activation dynamics, a fixed gain, an
    affine bias); ``inf`` for any other, so that the acceleration feed-forward
    (:meth:`RobotArms._accel_offset`) offsets its set point by nothing: a servo with a time
    constant would deliver the offset late, and another gain law is not ``kp``."""
    plain = (int(m.actuator_dyntype[act]) == int(mujoco.mjtDyn.mjDYN_NONE)
             and int(m.actuator_gaintype[act]) == int(mujoco.mjtGain.mjGAIN_FIXED)
             and int(m.actuator_biastype[act]) == int(mujoco.mjtBias.mjBIAS_AFFINE))
    k = float(m.actuator_gainprm[act, 0]) * float(m.actuator_gear[act, 0])
    return k if plain and k > 0.0 else math.inf


def _longest_run(flags: NDArray[np.bool_]) -> int:
    """Length of the longest run of True in ``flags`` (shape (n,)).

    Where each run starts and ends, from the steps of the flags padded with False: one
    numpy pass, where a Python loop over a run's every physics step cost 1.5 ms a flag
    array (seven per run's records: 3 % of a transition executed by one arm)."""
    f = np.asarray(flags, dtype=np.int8)
    if not f.any():
        return 0
    edges = np.diff(f, prepend=np.int8(0), append=np.int8(0))
    return int((np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)).max())


class _Segment:
    """The actuator rows of one control period, computed at its solve: rows ``start`` to
    ``start + len(rows)`` of a target trajectory."""

    __slots__ = ("q", "qd", "row_list", "rows", "start", "stop")

    def __init__(self, start: int, rows: FloatArray, q: FloatArray, qd: FloatArray) -> None:
        self.start: int = start
        self.stop: int = start + len(rows)
        self.rows: FloatArray = rows  # (k, model.nu)
        # its rows' views, made at once (each physics step reads one: a list index, not a
        # numpy one)
        self.row_list: list[FloatArray] = list(rows)
        # (k + 1, n_joints): the position set points (without the noise) and their velocity
        # feed-forward, row ``k`` where the set points go on after the period (the state a
        # new trajectory carries on from, :meth:`RobotArms.begin`)
        self.q: FloatArray = q
        self.qd: FloatArray = qd


class _OnlineControls:
    """The rows of one target trajectory, solved as the step loop reads them (in order).

    The IK runs every ``driver.every`` rows, for the target a period and a half ahead; the
    rows in between follow a quadratic spline through its solutions
    (:meth:`RobotArms._segment`), so the servos get a set point and its velocity every
    physics step without lagging the reference. A control period's rows are computed at
    once, at its solve; reading a row records the robot's state before that physics step
    (:class:`RobotLog`). Past the last row, :meth:`hold` gives the rows that hold the last
    target (the arm comes to rest on it through the spline)."""

    def __init__(self, driver: RobotArms, targets: FloatArray,
                 noise: FloatArray | None = None,
                 noise_velocity: FloatArray | None = None) -> None:
        self.driver = driver
        self.targets = targets
        self.noise = noise  # the fingertip position error per row (see with_noise)
        self.noise_velocity = noise_velocity  # and its velocity (None: not fed forward)
        self._i = -1
        self._row: FloatArray | None = None
        self.seg: _Segment | None = None
        driver.begin()

    def __len__(self) -> int:
        return len(self.targets)

    def __getitem__(self, i: int) -> FloatArray:
        if i == self._i + 1 and self._row is not None:  # the step loop's next row
            seg = self.seg
            if seg is not None and seg.start <= i < seg.stop:
                # (hold's row within the period, here: a Python call fewer every step)
                row = self.driver._advance(seg, i)
                self._i = i
                self._row = row
                return row
            return self.hold()
        if i < 0 or i >= len(self.targets):
            raise IndexError(i)
        if i == self._i and self._row is not None:
            return self._row
        if i < self._i:  # read again from the start: a new pass over the same targets
            self._i = -1
            self.seg = None
            self.driver.begin()
        got = self._row
        for j in range(self._i + 1, i + 1):
            got = self.driver.row(self, j)
        self._i = i
        self._row = got
        assert got is not None
        return got

    def hold(self) -> FloatArray:
        """The row after the one read last, the targets held at their last one: what the
        step loop applies while it holds a trajectory's end (a hold until an observation,
        a settle). The set points carry on along the spline and come to rest on the last
        target, as the IK leads them there (a held last row stopped a moving arm at once:
        a step of ``kv v`` in every velocity servo, up to 120 N m asked). Within the
        targets it is the next row, which the step loop reads through ``[]``."""
        i = self._i + 1
        seg = self.seg
        if seg is not None and seg.start <= i < seg.stop and self._row is not None:
            row = self.driver._advance(seg, i)
        else:
            row = self.driver.row(self, i)
        self._i = i
        self._row = row
        return row


class RobotArms:
    """Robot arms as a finger driver.

    Parameters
    ----------
    scene : RobotScene
        The simulated scene.
    ik_scene : RobotScene
        Its kinematic copy (``mocap_object=True``).
    data : mujoco.MjData
        The simulation's data (read before each solve: the joints, the fingertips and their
        contacts, the robot's own sensing; the object's pose comes from :meth:`see`).
    judge : Judge
        Reads the contacts for the log.
    dt : float
        Control period = physics step, s.
    ik_config : IKConfig, optional
    control_every : int
        The IK runs every this many physics steps (the control rate is the physics rate over
        it); the joint set points are interpolated in between.
    compliance : bool
        The force-limited finger command (:meth:`_comply`; off by default, docs/robot.md
        says why): each fingertip's command is the target pulled back along the contact
        force its force sensor measures, so that the force obeys the free fingertip's spring
        (``finger_stiffness``) and force limit (``force_limit``). Off: the stiff
        position-controlled arm of the targets.
    finger_stiffness : float
        The virtual finger's spring, N/m per axis (the free fingertips' ``stiffness``).
    force_limit : float
        The virtual finger's force limit, N per axis (the free fingertips' ``max_force``;
        ``inf``: a spring without a limit).
    compliance_damping : float
        The compliance's damping ``B`` (N s/m): the give moves at ``(F - spring) / B``.
    tracking_gain : float
        Gain (1/s) of the contact tracking correction (:meth:`_correct`; 0: off): in
        contact, the fingertip's error against its command is integrated into its IK
        target.
    """

    def __init__(self, scene: RobotScene, ik_scene: RobotScene, data: Any, judge: Judge,
                 dt: float, ik_config: IKConfig | None = None,
                 control_every: int = DEFAULT_CONTROL_EVERY,
                 force_limit: float = 8.0, tracking_gain: float = 20.0, *,
                 compliance: bool = False, finger_stiffness: float = 600.0,
                 compliance_damping: float = COMPLIANCE_DAMPING) -> None:
        if isinstance(control_every, bool) or not isinstance(control_every, int) or not \
                1 <= control_every <= 100:
            raise InputError(f"the IK runs every 1..100 physics steps, got {control_every!r}")
        self.every = control_every
        if not (isinstance(tracking_gain, (int, float)) and math.isfinite(tracking_gain)
                and 0.0 <= tracking_gain <= 1000.0):
            raise InputError(f"the contact tracking gain is 0..1000 1/s (0: off), got "
                             f"{tracking_gain!r}")
        self._last: tuple[_Segment, int] | None = None  # the row read last
        self.scene = scene
        self.n_fingers = scene.n_fingers
        self.data = data
        self.judge = judge
        self.dt = dt
        self.ik = FingertipIK(ik_scene, dt, ik_config)
        self.ik.period = control_every * dt
        self.log = RobotLog(scene, dt)
        # the set points' spline basis per control period length (_segment)
        self._basis: dict[int, tuple[FloatArray, FloatArray, FloatArray]] = {}
        self.placed = False
        m = scene.model
        self._obj = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
        self._obj_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object")
        self._tip_sites = np.asarray(scene.tip_sites, dtype=np.int64)
        self._tip_geoms = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"finger{k}")
                                    for k in range(1, scene.n_fingers + 1)])
        self._link_geoms = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g)
                                     for g in scene.collision_geoms])
        self._tip_set = {int(g) for g in self._tip_geoms}
        self._link_set = {int(g) for g in self._link_geoms}
        # the joints' qpos / qvel as slices where they are contiguous (one arm, or arms one
        # after another): a view copied, not a gather, every step
        self._qsl = _as_slice(scene.qadr)
        self._dsl = _as_slice(scene.dadr)
        # the rows the log copies every physics step (record) as flat memoryviews of the
        # data's arrays, made once (MjData's arrays never move): a memcpy into the log's
        # (RobotLog._flat) each; None unless the joints and the tips are each in a row (an
        # index array would gather a copy, not a view)
        tips = _as_slice(self._tip_sites)
        self._sources = (tuple(memoryview(v.reshape(-1)) for v in (
            data.qpos[self._qsl], data.qvel[self._dsl], data.qfrc_actuator[self._dsl],
            data.site_xpos[tips]))
            if isinstance(self._qsl, slice) and isinstance(self._dsl, slice)
            and isinstance(tips, slice) else None)
        self._widths = (len(scene.joint_names), 3 * scene.n_fingers)
        self._tips_view: FloatArray | None = (data.site_xpos[tips] if isinstance(tips, slice)
                                              else None)
        # the actuator rows' columns (_segment): the position and velocity servos' as
        # strided slices where they are evenly spaced (the Panda's alternate), written as
        # views, not gathered; the velocity bounds negated once (``-v``: exact)
        self._ctrl: FloatArray = data.ctrl  # (float64, never moves: read as a view)
        self._pos_cols = _as_stride(scene.pos_act)
        self._vel_cols = _as_stride(scene.vel_act)
        # both column sets slices: a row block's columns are views, written in place
        self._cols_views = isinstance(self._pos_cols, slice) and isinstance(self._vel_cols,
                                                                           slice)
        self._vel_max = scene.velocity
        self._servos_only = sorted([*scene.pos_act.tolist(), *scene.vel_act.tolist()]) == \
            list(range(m.nu))
        self._vel_min = -scene.velocity
        self._n = 0
        self._touch = False
        self._other = False
        self._noise_next: FloatArray | None = None
        self._noise_vel_next: FloatArray | None = None
        # the fingertip noise's smoothing (s; 0: the raw process, position only; see
        # with_noise)
        self.noise_smoothing = NOISE_SMOOTHING
        self._jac = np.zeros((3, m.nv))
        self._pinv: FloatArray | None = None  # tip position -> joints, at the last solve
        self.compliance = compliance  # checked (a bool) by check_compliance
        self.finger_stiffness = finger_stiffness
        self.force_limit = force_limit
        self.compliance_damping = compliance_damping
        self.check_compliance()
        self.give_bound = 0.03
        self.give_speed = 0.1
        # the stiff arm's force cap (N; None: none) and its damping (N s/m): _cap
        self.force_cap: float | None = None
        self.cap_damping = COMPLIANCE_DAMPING
        self._cap_on = False  # the cap's give is not zero
        # pressed past the cap, the velocity set points' part into the object no faster
        # than the fingertip's own, in full from this many caps (None: off;
        # _velocity_in_contact)
        self.contact_velocity: float | None = CONTACT_VELOCITY_FULL
        # the contact force fed forward to the servos, clipped at the cap (_cap)
        self.force_feedforward = False
        # the give's acceleration bound where it comes back at full speed, and the rate its
        # velocity feed-forward is taken up at (m/s^2; _cap)
        self.give_accel = GIVE_ACCEL
        self._give_speed_now = [0.0] * scene.n_fingers  # the return's speed per step, m
        self._give_fed = [False] * scene.n_fingers  # a return at full speed (fed forward)
        self._give_last = np.zeros((scene.n_fingers, 3))  # the give one step before
        self._give_vel = np.zeros((scene.n_fingers, 3))  # its velocity fed forward, m/s
        # the tips' Jacobian of the last _tip_jac (_tip_pinv's, or _pushed's at the last solve;
        # or one within its period)
        self._jac_c: FloatArray | None = None
        # the contact forces (clipped at the cap) summed over the steps since the last
        # solve, and that solve's step count (_cap, _pushed)
        self._push_sum = [0.0] * (3 * scene.n_fingers)
        self._push_any = False
        self._push_n0 = 0
        self._tip_contact = False  # a fingertip touches anything (_contacts)
        self._offset = np.zeros((scene.n_fingers, 3))  # the give (_comply, _cap), m
        # the contact tracking correction (see _correct)
        self.tracking_gain = float(tracking_gain)
        self.tracking_bound = DEFAULT_TRACKING_BOUND
        self.torque_guard = 0.85
        self.release_rate = 50.0
        # integrate only the error along the object's surface (_correct_by_normal; needs
        # the object's faces: set_shape. RobotSimulator's default with several fingertips)
        self.tracking_tangential = False
        # the bound of the correction's part along the object's surface (m; inf: none, the
        # whole correction bounded by tracking_bound alone; _correct_by_normal.
        # RobotSimulator's default with one fingertip: robot_run.ROBOT_TRACKING_SURFACE_BOUND)
        self.tracking_surface_bound = math.inf
        self._corr = np.zeros((scene.n_fingers, 3))
        # the finite torque limits by joint (_correct's guard)
        self._torque_limits = [(i, lim) for i, lim in enumerate(
            np.asarray(scene.torque, dtype=np.float64).tolist()) if math.isfinite(lim)]
        self._fbuf = np.zeros(6)
        # the contact forces _yield read at a solve, for the cap of the same physics step
        self._solve_forces: list[list[float]] | None = None
        self._f3 = self._fbuf[:3]  # (its force part, a view made once: _tip_force_rows)
        self._tip_index = {int(g): k for k, g in enumerate(self._tip_geoms)}
        # the object's believed pose (body origin, (w, x, y, z)): see()
        self._seen: tuple[FloatArray, FloatArray] | None = None
        self._force_now = np.full(scene.n_fingers, math.nan)
        self._pinv_c: FloatArray | None = None
        # the tips' Jacobian _pushed read at this solve, whose inverse the give takes only if
        # it is needed (_give_pinv): most control periods that push have no give
        self._jac_give: FloatArray | None = None
        self._eye_damp = 1e-6 * np.eye(3 * scene.n_fingers)  # (_tip_pinv's damping)
        # the set points' position and velocity at the next period's start (_segment;
        # None: at rest on the IK's joints)
        self._state: tuple[FloatArray, FloatArray] | None = None
        self._rest = False  # a hold has brought the set points to rest (_segment)
        # the set points' torque budget (_within_torque): a share of each joint's limit
        self.torque_share = TORQUE_SHARE
        self.min_accel_share = 0.25
        self.torque_share_light = TORQUE_SHARE_LIGHT
        nv = m.nv
        self._acc_full = np.zeros(nv)
        self._ma_full = np.zeros(nv)
        self._damping = np.array(m.dof_damping[scene.dadr])
        self._implicit = _implicit_inertia(m, scene.dadr)
        # the set points' acceleration feed-forward (_accel_offset): on, and each position
        # servo's stiffness on its joint (N m/rad: the gain times the gear, as the servo's
        # force ``kp (ctrl - gear q)`` acts on the joint times the gear, the set points
        # being joint positions)
        self.accel_feedforward = True
        self._kp_joint = np.array([servo_stiffness(m, int(a)) for a in scene.pos_act])
        self._torque_max = np.where(np.isfinite(scene.torque), scene.torque, 1e30)
        self._torque_min = -self._torque_max  # (negation is exact)
        # the last kept ``v1`` of the torque budget and its ``(M + h D) a`` (_within_torque)
        self._ma_last: tuple[FloatArray, FloatArray] | None = None
        # the contact force feed-forward's offset within each joint's torque limit, rad
        self._push_lim = self._torque_max / self._kp_joint
        self._damping_list: list[float] = self._damping.tolist()
        self._lower_list: list[float] = np.asarray(scene.lower, dtype=np.float64).tolist()
        self._upper_list: list[float] = np.asarray(scene.upper, dtype=np.float64).tolist()
        # the joints' torque budget per the shares it was made with (_within_torque)
        self._lim_key: tuple[float, float] | None = None
        self._lim: list[float] = []
        # the bias forces' and velocities' views (MjData's arrays never move)
        self._bias_views = ((data.qfrc_bias[self._dsl], data.qvel[self._dsl])
                            if isinstance(self._dsl, slice) else None)
        self._controls: _OnlineControls | None = None  # the trajectory read now (hold_row)
        # the fingertip radius offset (_tool; off on this driver, RobotSimulator's "auto"
        # turns it on for one fingertip), and the object's shape it needs
        self.radius_offset = False
        # how the finger tools point in a step: "recorded" (the knuckle markers, where the
        # references carry them) or "lean" (the IK's rule only): point()
        self.finger_direction = "lean"
        self._planes: tuple[FloatArray, FloatArray] | None = None
        self._seen_rot: FloatArray | None = None
        self.finger_radius = REFERENCE_RADIUS
        self.reference_radius = REFERENCE_RADIUS
        self.tool_band = 0.015
        self.tool_blend = 0.002
        # the contact-consistent command (_press_push; off by default, docs/robot.md says
        # why): the deepest a fingertip command may put the tip inside the object as
        # observed (m; None: no bound), whether the contact tracking correction may press
        # past it (False: the IK's target is bounded too, _bounded), the softmax scale of
        # the push's normal round an edge (m), and the push's rate limit (m/s, None: none;
        # _press_limited) with the push it carries on from
        self.press_depth: float | None = None
        self.press_correction = True
        self.press_blend = 0.008
        self.press_rate: float | None = 0.1
        self._press_last = np.zeros((scene.n_fingers, 3))

    # --------------------------------------------------------------------- protocol
    def controls(self, targets: FloatArray) -> Any:
        """The actuator rows along ``targets`` (shape (n_samples, n_fingers, 3)), each solved
        by the IK when the step loop reads it (a sequence of rows, shape (model.nu,))."""
        arr = np.asarray(targets, dtype=np.float64)
        noise, self._noise_next = self._noise_next, None
        vel, self._noise_vel_next = self._noise_vel_next, None
        # (the noise may run past the targets' end: with_noise)
        if noise is not None and (noise.shape[1:] != arr.shape[1:] or len(noise) < len(arr)):
            noise = None
        if noise is None or (vel is not None and vel.shape != noise.shape):
            vel = None
        self._controls = _OnlineControls(self, arr, noise, vel)
        return self._controls

    def hold_row(self) -> FloatArray:
        """The actuator row of the next physics step while the step loop holds the end of
        the last :meth:`controls` (their last target held, see :meth:`_OnlineControls.hold`);
        before any, the controls as they are."""
        ctl = self._controls
        if ctl is None or not self.placed:
            return np.array(self.data.ctrl, dtype=np.float64)
        return ctl.hold()

    def with_noise(self, targets: FloatArray, noise: FloatArray,
                   velocity: FloatArray | None = None) -> FloatArray:
        """The targets of the next :meth:`controls` with a fingertip position error ``noise``
        (as many rows as the targets or more, each of the targets' row shape; the
        distribution's ``finger_noise``, a Gauss-Markov process) and its velocity
        ``velocity`` (m/s, the shape of ``noise``; None: not fed forward).

        The free fingertips get the error added to their targets; an arm gets it on its
        servos' set points only, never through the IK: as a joint offset ``J^+ noise`` on the
        position servos and ``J^+ velocity`` on the velocity servos (``J``: the tip sites'
        position Jacobian at the last solve). ``noise`` may be longer than the targets: its
        rows past their end are those of the holds that follow (the smoothed error coming to
        rest); past its own end its last row is held, with no velocity. The executor smooths
        the process first where the driver asks for it
        (``noise_smoothing``, :data:`NOISE_SMOOTHING`): the raw process has no derivative
        (its 1 kHz differences are 0.2 m/s for a 1 mm, 50 ms process), and a feed-forward of
        them held the Panda's joints at their torque limits for seconds (measured: 2.7 s,
        36 mm tracking error on the main plan's first step); on the position set points alone
        the arm realised a quarter less of it (0.76 of its spread, the tests) and lagged it by
        millimetres."""
        self._noise_next = np.asarray(noise, dtype=np.float64)
        self._noise_vel_next = (None if velocity is None
                                else np.asarray(velocity, dtype=np.float64))
        return targets

    def place(self, data: Any, targets: FloatArray) -> None:
        """Before a run: the arm stands at rest with its fingertips on ``targets`` (shape
        (n_fingers, 3)), or at the joint positions of an actuator row (shape (model.nu,):
        what :meth:`controls` gives), the first time after a :meth:`reset`; later calls
        leave the arm where it is (no teleport)."""
        sc = self.scene
        if self.placed and np.abs(data.qpos[sc.qadr] - self.ik.q).max() < 0.05:
            return
        # not placed, or the data was reset under the arm (an executor's mj_resetData): the
        # arm is placed anew and its records start again
        if self.placed:
            self.reset()
        arr = np.asarray(targets, dtype=np.float64)
        if (arr.size == 3 * self.n_fingers and arr.size != sc.model.nu) or arr.ndim == 2:
            row = self.solve(arr.reshape(self.n_fingers, 3))
        else:
            row = arr
        q = row[sc.pos_act]
        data.qpos[sc.qadr] = q
        data.qvel[sc.dadr] = 0.0
        data.ctrl[:] = row
        self.placed = True

    @property
    def finger_origins(self) -> list[tuple[float, float]]:
        """Where each finger comes from: its arm's base (the root body below the world), x
        and y in m, finger order (the closed loop gives a correction push to the finger
        behind it, :func:`~nonprehensile.control.push_finger`)."""
        return self.ik.bases

    def tips(self, data: Any) -> FloatArray:
        """The fingertip sites' positions now, shape (n_fingers, 3)."""
        if data is self.data and self._tips_view is not None:
            return self._tips_view.copy()  # (the sites in a row: a view made once, copied)
        # (an index array's gather is already a copy)
        return np.asarray(data.site_xpos[self._tip_sites], dtype=np.float64)

    def qpos_indices(self) -> NDArray[np.int64]:
        """The arms' joint positions in ``qpos``."""
        return self.scene.qadr

    # ---------------------------------------------------------------------- control
    def reset(self) -> None:
        """Forget the arm's placement: the next run places it again (a new start)."""
        self.placed = False
        self.ik.reset(self.scene.home)
        self.log.clear()
        self._n = 0
        self._offset[:] = 0.0
        self._cap_on = False
        self._give_last[:] = 0.0
        self._give_vel[:] = 0.0
        self._push_sum = [0.0] * len(self._push_sum)
        self._push_any = False
        self._push_n0 = 0
        self._give_speed_now = [0.0] * len(self._give_speed_now)
        self._corr[:] = 0.0
        self._press_last[:] = 0.0
        self._state = None

    def begin(self) -> None:
        """A new target trajectory: the set points carry on from where those of the row read
        last were going (position and velocity: a trajectory replaced mid-period would
        otherwise start from the period's end), and the IK from the knot they head for
        (:meth:`_segment`). At 1 kHz the IK starts from the set point the servos have now."""
        if not self.placed or self._last is None:
            return
        seg, i = self._last
        r = i - seg.start
        if self.every == 1:
            self.ik.set_q(np.asarray(seg.q[r]))
            return
        q0, v0 = seg.q[r + 1], seg.qd[r + 1]
        self._state = (np.array(q0), np.array(v0))
        self._rest = False
        # (the IK's acceleration bound keeps counting from its own last step: counted from
        # the set points' velocity here, the main plan's first push-roll, open loop, lost
        # its landing event)
        self.ik.set_q(q0 + (0.5 * self.every * self.dt) * v0)

    def row(self, ctl: _OnlineControls, j: int) -> FloatArray:
        """Row ``j`` of ``ctl``'s targets (see :class:`_OnlineControls`): a new control
        period solved at ``j``, or a row of the current one."""
        targets = ctl.targets
        if not self.placed:  # a new start: converge from home onto the first targets
            noise = None if ctl.noise is None else ctl.noise[j]
            return self.solve(targets[j], last=j == len(targets) - 1, noise=noise)
        seg = ctl.seg
        if seg is None or not seg.start <= j < seg.stop:
            seg = ctl.seg = self._segment(ctl, j)
            try:
                return self._advance(seg, j)
            finally:
                self._solve_forces = None  # (the solve's reading: this physics step's only)
        return self._advance(seg, j)

    def _advance(self, seg: _Segment, j: int) -> FloatArray:
        """Row ``j`` of ``seg``, recorded (:meth:`record`) and with the give of this physics
        step (:meth:`_with_give`): what every physics step reads, in one Python call (the
        record's usual path and the give's test written out here: each call and attribute
        read of a physics step's path, a few hundred of them a control period, cost more in
        place, among the physics' memory traffic, than back to back)."""
        src = self._sources
        if src is None:
            self.record(seg, j)
            return self._with_give(seg, j, seg.rows[j - seg.start])
        d, log = self.data, self.log
        nc = self._n
        if nc % CONTACT_EVERY == 0:  # as often as the judge reads contacts
            self._touch, self._other, self._tip_contact = self._contacts(d)
        self._n = nc + 1
        self._last = (seg, j)
        n = log.n
        if n >= len(log._time):
            log.reserve(1)
        t, q, qd, tau, tips, touch, other = log._mv
        nj, nt = self._widths
        a, b = n * nj, n * nt
        q[a:a + nj], qd[a:a + nj], tau[a:a + nj], tips[b:b + nt] = src
        t[n] = d.time
        touch[n] = self._touch
        other[n] = self._other
        log.n = n + 1
        row = seg.row_list[j - seg.start]
        if self.compliance:
            return self._comply(seg, j, row)
        if self.force_cap is not None and (self._tip_contact or self._cap_on):
            return self._cap(row)
        return row

    def _with_give(self, seg: _Segment, j: int, row: FloatArray) -> FloatArray:
        """Row ``j`` of ``seg`` (``row``, just recorded) with the fingertips' give of this
        physics step: the force-limited command's (:meth:`_comply`), or the stiff arm's force
        cap's while a fingertip touches or a give is left (:meth:`_cap`)."""
        if self.compliance:
            return self._comply(seg, j, row)
        if self.force_cap is not None and (self._tip_contact or self._cap_on):
            return self._cap(row)
        return row

    def _segment(self, ctl: _OnlineControls, j: int) -> _Segment:
        """Solve the control period starting at row ``j``: the IK once, then its rows.

        At 1 kHz (``every`` 1) the IK solves for target ``j`` and the row holds its joints
        and velocities. Slower, the IK's solutions are the knots of a uniform quadratic
        B-spline, one every ``k = every`` rows, and the rows are the spline: the set points'
        velocity runs linearly, over each period, from the previous period's mean velocity
        between knots to this one's, and the velocity feed-forward is the exact derivative
        of the position set points. Position and velocity are continuous across periods and
        across new trajectories (:meth:`begin`), so the velocity servos (``kv`` 200-450
        N m s/rad) never see a step. Linear set points with each period's mean velocity as
        feed-forward stepped the velocity set point every period, by up to 1.2 rad/s at a
        new trajectory, and held joints at their torque limits for 1-13 ms at hundreds of
        period boundaries of a run (at ``kv`` 200 a 0.06 rad/s step is the wrist's whole
        12 N m). The spline runs half a period behind its knots, so the IK solves for the
        target ``1.5 k`` rows ahead (a period and a half): the set point at row ``j`` is then
        the knots' mean around target ``j``. The spline is C1 and stays within its knots'
        hull (a cubic through the same points overshot inside a period). Rows past the
        trajectory's end (``j >= len``, :meth:`_OnlineControls.hold`) hold its last target:
        the spline comes to rest on it, and once it has, nothing more is solved. At 1 kHz the
        last row's velocity is zero and a hold keeps that row. Below 1 kHz the position set
        points sent to the servos carry the acceleration feed-forward of the period
        (:meth:`_accel_offset`; the log's ``q_ref`` is the spline without it); at 1 kHz, where
        the IK's velocities come one solve at a time, there is none."""
        targets = ctl.targets
        n = len(targets)
        last = n - 1
        kk = 1 if self.every == 1 else self.every
        # the rows' targets (and fingertip noise): past the end, the last one held
        idx = slice(j, j + kk) if j + kk <= n else np.minimum(np.arange(j, j + kk), last)
        ahead = targets[min(j + kk + kk // 2, last)]  # the knot's (every > 1)
        rows_t = targets[idx]  # (once: the radius offset's and the log's)
        # the noise's rows (with_noise: it may run past the targets' end, then is held)
        noise = ctl.noise
        nn = 0 if noise is None else len(noise)
        nidx = (idx if noise is None else slice(j, j + kk) if j + kk <= nn
                else np.minimum(np.arange(j, j + kk), nn - 1))
        tool = self._tool(rows_t, ahead)
        now = targets[min(j, last)]  # past the end (hold): the last target, held
        if tool is not None:  # the commands: the targets plus the tip radius offset
            now = now + tool[0]
            ahead = ahead + tool[-1]
        t0 = self.log.n
        noise_j = None if noise is None else noise[min(j, nn - 1)]
        solved = True
        ff: FloatArray | None = None  # the acceleration feed-forward (with the spline only)
        if self.every == 1:
            k = 1
            if j >= n and self._last is not None:
                # holding at 1 kHz: the trajectory's last row (at rest, below), as before
                solved = False
                seg0, i0 = self._last
                q1 = np.array(seg0.q[i0 - seg0.start])
                qd1 = np.zeros_like(q1)
            else:
                self._set_object()
                q1, qd1 = self.ik.step(self._bounded(self._yield(now, 1, noise_j, now=now)))
                if j + 1 >= n:  # the IK solves every step: its last row holds still
                    qd1 = np.zeros_like(qd1)
            q = np.stack([q1, q1])
            qd = np.stack([qd1, qd1])
        else:
            k = self.every
            h = k * self.dt
            if self._state is None:  # placed at rest
                self._state = (self.ik.q, np.zeros(len(self.scene.dadr)))
            s0, v0 = self._state
            solved = not (j >= n and self._rest)
            if not solved:
                # holding, at rest: the set points stay (no solve: a hold until the next
                # observation or a settle costs no IK, as a held row did)
                v1 = v0
            else:
                self._set_object()
                # the knot the set points head for now (the IK's joints, but for rounding
                # and a knot clipped into the joints' range at a new trajectory)
                knot = s0 + (0.5 * h) * v0
                self.ik.dt = h
                q1, _ = self.ik.step(self._bounded(self._yield(ahead, k, noise_j, now=now)))
                self.ik.dt = self.dt
                v1 = (q1 - knot) / h
                if self.torque_share > 0.0:
                    v1 = self._within_torque(v0, v1, h, s0)
                if j >= n and float(np.abs(v1).max()) < REST_SPEED:
                    # the hold has brought the arm to rest: the set points stop there
                    # (the posture's slow drift in the null space is not followed)
                    v1 = np.zeros_like(v1)
                    self._rest = True
            basis = self._basis.get(k)
            if basis is None:  # tau, tau^2 / (2 h) and tau / h at rows 0..k of a period
                tau = np.arange(k + 1, dtype=np.float64)[:, None] * self.dt
                basis = self._basis[k] = (tau, tau * tau / (2.0 * h), tau / h)
            a, b, c = basis
            dv = v1 - v0
            if self.accel_feedforward and solved:  # (a hold at rest accelerates nothing)
                # (the torque budget's product where it kept ``v1``: ``dv / h`` is its
                # acceleration, ``(v1 - v0) / h``, bit for bit)
                got, self._ma_last = self._ma_last, None
                ff = self._accel_offset(dv / h, got[1] if got is not None and got[0] is v1
                                        else None)
            # (columns ``a``, ``b``, ``c`` broadcast against the rows: the same products)
            # (``s0 + a v0 + b dv`` and ``v0 + c dv``, each product and sum in the same
            # order, into the new arrays themselves: no temporaries)
            q = np.multiply(a, v0)
            np.add(s0, q, out=q)
            tmp = np.multiply(b, dv)
            np.add(q, tmp, out=q)
            qd = np.multiply(c, dv)
            np.add(v0, qd, out=qd)
            self._state = (q[k], qd[k])
        self._pinv = None
        qk, qdk = q[:k], qd[:k]
        # (the servos' columns are every actuator's on a robot scene: nothing to carry over
        # from ``ctrl`` then)
        rows = (np.empty((k, len(self._ctrl))) if self._servos_only
                else np.repeat(self._ctrl[None, :], k, axis=0))
        base = qk if noise is None else qk + self._noise_offset(noise[nidx])
        if ff is None:
            rows[:, self._pos_cols] = base
        elif self._cols_views:  # the torque the period's acceleration takes (_accel_offset)
            # (written into the rows' view at once: the same sum as the copy, then ``+=``)
            np.add(base, ff, out=rows[:, self._pos_cols])
        else:
            rows[:, self._pos_cols] = base
            rows[:, self._pos_cols] += ff
        if self.force_feedforward:  # the contact force's (_pushed)
            push = self._pushed()
            if push is not None:
                rows[:, self._pos_cols] += push
        qdc = qdk  # (the velocity set points: the spline's, plus the noise's velocity)
        if ctl.noise_velocity is not None:  # (with_noise)
            nv = ctl.noise_velocity[nidx]
            if j + kk > nn:  # past the noise's end it is held: no velocity
                nv = np.where((np.arange(j, j + kk) >= nn)[:, None, None], 0.0, nv)
            qdc = qdk + self._noise_offset(nv)
        if self._cols_views:  # (the same bounds, written into the rows' view)
            vv = rows[:, self._vel_cols]
            np.minimum(qdc, self._vel_max, out=vv)
            np.maximum(vv, self._vel_min, out=vv)
        else:
            rows[:, self._vel_cols] = np.maximum(np.minimum(qdc, self._vel_max),
                                                 self._vel_min)
        # the log's set points and targets of the period, written once (a period replaced
        # before its end is overwritten from where it stopped); the give, the force and the
        # IK time are left as the log made them (0, NaN, NaN) past the period's first row:
        # nothing writes those past the row recorded last (_comply writes that row, a solve
        # only its own row, the next to be recorded)
        log = self.log
        if log.n + k > len(log._time):
            log.reserve(k)
        log._q_ref[t0:t0 + k] = qk
        log._qd_ref[t0:t0 + k] = qdk
        log._target[t0:t0 + k] = rows_t
        # (no offset or noise: zeros, written only over rows that may hold others)
        if tool is not None:
            log._tool[t0:t0 + k] = tool[:k]
            log._tool_to = max(log._tool_to, t0 + k)
        elif t0 < log._tool_to:
            log._tool[t0:t0 + k] = 0.0
        if noise is not None:
            log._noise[t0:t0 + k] = noise[nidx]
            log._noise_to = max(log._noise_to, t0 + k)
        elif t0 < log._noise_to:
            log._noise[t0:t0 + k] = 0.0
        if not self.compliance:  # the stiff arm's force, read at the solve (_yield)
            log._force[t0] = self._force_now
        log._ik[t0] = self.ik.solve_times[-1] if self.ik.solve_times and solved else math.nan
        return _Segment(j, rows, q, qd)

    def _accel_offset(self, acc: FloatArray, ma: FloatArray | None = None) -> FloatArray:
        """The acceleration feed-forward: the offset of the position set points (rad, shape
        (n_joints,)) whose servo force is the torque the set points' joint acceleration
        ``acc`` (rad/s^2, shape (n_joints,): the spline's, constant over a control period)
        takes, ``K_p^-1 (M(q) + h D) qdd_ref`` (the mass matrix at the arm's state now, and
        the inertia the physics' implicit integration adds, :func:`_implicit_inertia`, as
        :meth:`_within_torque` counts it).

        The servos' law is then ``tau = K_p (q_ref - q) + K_v (qd_ref - qd) + (M + h D)
        qdd_ref + g(q)``: the computed-torque feed-forward of an industrial joint
        controller, put through the position servos (a user's robot need have nothing but
        position and velocity servos). Without it the servos took that torque from the
        error ``q_ref - q``: at the Panda's ``K_p`` 2000-4500 N m/rad the fingertip lagged
        its command by 4-5 ms in free motion (1.3-2.1 mm median at 0.2-0.5 m/s, measured in
        a two-arm tumble-twist), and the two-arm tumbles tracked up to 3.1 mm (tumble-lift)
        and 6.3 mm (tumble-twist) in contact against 1.8 and 2.3 mm with it
        (docs/benchmarks.md). Coriolis and centrifugal torques are left out (a few tenths of
        a N m at these speeds); gravity the actuators compensate. The torque budget
        (:meth:`_within_torque`) scales the period's acceleration so that this torque stays
        within a share of each joint's limit, but not always (its floor, a joint whose bias
        alone is past the share, the budget off): the offset's torque is clipped to the
        joint's limit itself. A joint whose position servo is not a plain one (activation
        dynamics, a gain that is not fixed: :func:`servo_stiffness`) gets none. The torque
        steps at each period's boundary as the spline's acceleration does (a ramp over the
        period, which delays it, was measured worse: an 11 ms torque limit in the two-arm
        transitions against 10 ms).

        ``ma``: ``(M + h D) acc`` where :meth:`_within_torque` computed it for the same
        ``acc`` at the same state (the same numbers: its mass matrix product not made
        again)."""
        if ma is None:
            d, m = self.data, self.scene.model
            full = self._acc_full
            full[self._dsl] = acc
            mujoco.mj_mulM(m, d, self._ma_full, full)
            ma = self._ma_full[self._dsl] + self._implicit * acc
        # (no joint's offset torque past its limit)
        need = _clip(ma, self._torque_min, self._torque_max)
        return np.asarray(need / self._kp_joint, dtype=np.float64)

    def _within_torque(self, v0: FloatArray, v1: FloatArray, h: float,
                       q0: FloatArray | None = None) -> FloatArray:
        """``v1``, the set points' velocity at the period's end, with the period's joint
        acceleration ``(v1 - v0) / h`` scaled down (every joint alike: the fingertip keeps
        its direction and falls behind) so that the torque it takes with the arm's own
        dynamics now, ``(M + h D) a + c + g`` (mass matrix, the inertia the physics'
        implicit integration adds, :func:`_implicit_inertia`, Coriolis and gravity, passive
        damping: the actuators compensate gravity), stays within ``torque_share`` of each
        joint's limit (``torque_share_light`` for the wrist). The IK then carries on from
        where the set points go (its knot moved back).

        The IK's joint acceleration bound (30 rad/s^2) is a kinematic one: in the main
        plan's fast transits the shoulder, with the arm stretched out, needs 48 N m against
        gravity, and 15 rad/s^2 more took it past its 87 N m for 20-40 ms. The arm's model
        (MuJoCo's here, a real arm's dynamic model there) says what it can do. Without the
        ``h D`` term the wrist's 30 rad/s^2 looked like 4 N m where it took 10: a transit of
        the main plan held the wrist's 12 N m for 17 ms."""
        d, m = self.data, self.scene.model
        a = (v1 - v0) / h
        full = self._acc_full
        full[self._dsl] = a
        mujoco.mj_mulM(m, d, self._ma_full, full)
        # the few joints' numbers in plain Python (this runs every control period; numpy
        # calls on 7 numbers cost more than the arithmetic): the same IEEE operations in
        # the same order as the arrays' (``bias + damping qvel``, ``lim - bias``,
        # ``-lim - bias``, ``hi / need``), so the same numbers
        ma = self._ma_full[self._dsl] + self._implicit * a
        need = ma.tolist()
        views = self._bias_views
        if views is not None:
            fb, qv = views
        else:
            fb, qv = d.qfrc_bias[self._dsl], d.qvel[self._dsl]
        key = (self.torque_share, self.torque_share_light)
        if key != self._lim_key:  # the shares are attributes: the limits as they are now
            self._lim_key = key
            self._lim = (self._torque_max * np.where(self._torque_max < LIGHT_JOINT,
                                                     self.torque_share_light,
                                                     self.torque_share)).tolist()
        # per joint the largest s with |bias + s need| <= lim; a joint whose bias alone is
        # past it has no say (scaling the accelerations cannot help it, and a set point
        # that may not accelerate at all runs on at its velocity, away from the IK: the
        # main plan then ran into the joints' limits)
        s_min = math.inf
        for nd, b, dq, v, lm in zip(need, fb.tolist(), self._damping_list, qv.tolist(),
                                    self._lim, strict=True):
            bias = b + dq * v
            if abs(nd) > 1e-12 and abs(bias) < lm:
                s = ((lm - bias) if nd > 0.0 else (-lm - bias)) / nd
                if s < s_min:
                    s_min = s
        # at least ``min_accel_share`` of the IK's acceleration: the set points still turn
        # towards the IK's path (braking included), if more slowly
        # (where no joint's torque asks for less than the whole acceleration, the scale is 1
        # whatever the floor: the range's share, at most 1, is not worked out)
        floor = self.min_accel_share
        if q0 is not None and s_min < 1.0:  # and enough to stop short of a range's end
            floor = max(floor, self._range_share(q0, v0, v1, h))  # (_range_share)
        scale = float(min(1.0, max(floor, s_min)))
        if scale >= 1.0:
            # (the acceleration feed-forward's torque of this ``v1``: _segment hands it on)
            self._ma_last = (v1, ma)
            return v1
        out = v0 + scale * (v1 - v0)
        knot = self.ik.q
        self.ik.set_q(knot - (v1 - out) * h, velocity=out)
        return out

    def _range_share(self, q0: FloatArray, v0: FloatArray, v1: FloatArray, h: float) -> float:
        """The least share of the IK's acceleration ``(v1 - v0) / h`` that still stops each
        joint the IK brakes (set points at ``q0``, moving at ``v0``) before the IK's margin
        inside its range's end (``position_margin_deg``): the deceleration ``v0^2 / (2 d)``
        over the room ``d`` left after this period, over the IK's. Only joints that need at
        least half the IK's acceleration bound count (near the end of their stopping
        distance: a joint far from its end whose IK barely decelerates it yet would ask for
        the whole acceleration); 0 where none does, 1 where the room is gone. The torque
        budget keeps at least this share: scaled below it, the braking came too late and the
        set points ran past the joint's range (a transit across the distribution put the
        wrist 17 mrad past its upper end for 34 ms, decelerating from 1.5 rad/s); a
        position limit is hard."""
        # per joint in plain Python (this runs every control period, and numpy calls on 7
        # numbers cost more than the arithmetic): the same IEEE operations in the same order
        # as the arrays' (``upper - margin - q0``, ``room - |v0| h``, ``v0 v0 / (2 room)``,
        # ``need h / |dv|``), so the same number; a joint that does not brake (NaN
        # included) or is not near its end gives 0, as its masked entry did
        margin = math.radians(self.ik.config.position_margin_deg)
        bound = float(self.ik.config.joint_accel)
        half = 0.5 * bound if math.isfinite(bound) else -math.inf  # (inf: every braking one)
        best = 0.0
        for q, v, w, lo, hi in zip(q0.tolist(), v0.tolist(), v1.tolist(), self._lower_list,
                                   self._upper_list, strict=True):
            dv = w - v
            if not dv * v < 0.0:  # not braking
                continue
            room = ((hi - margin - q) if v > 0.0 else (q - lo - margin)) - abs(v) * h
            need = v * v / (2.0 * room) if room > 0.0 else math.inf
            if not need >= half:
                continue
            want = need * h / abs(dv)
            if want > best:
                best = want
        return min(1.0, best)

    def _noise_offset(self, noise: FloatArray) -> FloatArray:
        """Joint offsets moving the tips by ``noise`` (shape (k, n_fingers, 3)), shape
        (k, n_joints): damped least squares on the tip sites' position Jacobian, computed
        once per solve."""
        if self._pinv is None:
            self._pinv = self._tip_pinv()
        noise = np.asarray(noise, dtype=np.float64)
        return np.asarray(noise.reshape(len(noise), -1) @ self._pinv.T)

    def _tip_pinv(self) -> FloatArray:
        """Damped least-squares inverse of the tip sites' position Jacobian now, shape
        (n_joints, 3 n_fingers)."""
        return self._pinv_of(self._tip_jac())

    def _tip_jac(self) -> FloatArray:
        """The tip sites' position Jacobian now, shape (3 n_fingers, n_joints) (kept as
        ``_jac_c``)."""
        sc = self.scene
        m, d = sc.model, self.data
        rows = []
        for s in self._tip_sites:
            mujoco.mj_jacSite(m, d, self._jac, None, int(s))
            rows.append(self._jac[:, sc.dadr])
        jac = np.concatenate(rows)
        self._jac_c = jac
        return jac

    def _pinv_of(self, jac: FloatArray) -> FloatArray:
        """Damped least-squares inverse of the tips' Jacobian ``jac`` (:meth:`_tip_jac`)."""
        return np.asarray(jac.T @ np.linalg.inv(jac @ jac.T + self._eye_damp))

    def _give_pinv(self) -> FloatArray:
        """The give's inverse Jacobian (``_pinv_c``): the one of the last solve's period
        (a hold at rest solves nothing: an earlier period's), made from the Jacobian
        :meth:`_pushed` read at that solve where it did (the same numbers as its inverse made
        then), else from the Jacobian now."""
        pinv = self._pinv_c
        if pinv is None:
            jac = self._jac_give
            pinv = self._pinv_c = self._tip_pinv() if jac is None else self._pinv_of(jac)
            self._jac_give = None
        return pinv

    def solve(self, targets: FloatArray, *, last: bool = False,
              noise: FloatArray | None = None) -> FloatArray:
        """The actuator row holding the fingertips on ``targets`` (shape (n_fingers, 3)),
        converged from the home posture (a new start: the arm is placed there), its position
        set points offset by the fingertip error ``noise`` (see :meth:`with_noise`)."""
        sc = self.scene
        self._set_object()
        self.ik.reset(sc.home)
        self.ik.converge(targets)
        q = self.ik.q
        # placed at rest: the acceleration bound counts from zero, not from the last
        # iteration of the convergence
        self.ik.set_q(q, velocity=np.zeros(len(q)))
        self._pinv = None
        row = np.array(self.data.ctrl, dtype=np.float64)
        row[sc.pos_act] = q if noise is None else q + self._noise_offset(noise[None])[0]
        row[sc.vel_act] = 0.0
        self._last = (_Segment(0, row[None], np.stack([q, q]), np.zeros((2, len(q)))), 0)
        self._state = None
        self._rest = False
        return row

    def see(self, pose: ObjectPose | None) -> None:
        """Where the object is believed to be: the pose the IK's collision avoidance and
        finger pointing use from the next solve on. The closed loop gives each observation
        as it arrives (and the planned start before the first): a real arm's IK knows the
        object only through the tracker, like everything else that decides.

        ``None`` (the default, and what the open loop gives): the simulation's pose. Open
        loop nothing is observed, and a pose held from before the motion is wrong: a pushing
        fingertip follows the face it pushes into where the object stood, and the collision
        limit stops it there (the main plan's first push-roll then did not roll).
        """
        if pose is None:
            self._seen = None
            self._seen_rot = None
            return
        quat = np.empty(4)
        # (a contiguous copy of its own, as the believed rotation: one copy, not two)
        rot = np.array(pose.rotation, dtype=np.float64, order="C")
        mujoco.mju_mat2Quat(quat, rot.ravel())
        self._seen = (np.array(pose.translation, dtype=np.float64), quat)
        self._seen_rot = rot

    def point(self, directions: FloatArray | None) -> None:
        """The recorded finger directions where the reference being run is (shape
        (n_fingers, 3), unit, world; zero rows for fingers the step does not use; None:
        none), handed over by the closed loop at each observation
        (:meth:`~nonprehensile.control.StepMonitor.pointing`): with
        ``finger_direction == "recorded"`` the IK points each finger tool along its
        finger's, else (and with None) by its own rule
        (:meth:`~nonprehensile.sim.ik.FingertipIK.lean`)."""
        self.ik.set_pointing(directions if self.finger_direction == "recorded" else None)

    def tumbling(self, tumbling: bool) -> None:
        """Whether the next step tumbles the object (its start and end faces differ): the
        fingers lean further out of a pinched face (:meth:`~nonprehensile.sim.ik.
        FingertipIK.set_tumbling`; several fingertips only)."""
        self.ik.set_tumbling(tumbling)

    def set_shape(self, normals: FloatArray, offsets: FloatArray, scale: float) -> None:
        """The object's face planes (model frame: unit ``normals``, shape (faces, 3), and
        ``offsets``, ``n . x = offset`` on a face) and its scale, for the fingertip radius
        offset (:meth:`_tool`)."""
        self._planes = (np.asarray(normals, dtype=np.float64),
                        np.asarray(offsets, dtype=np.float64) * float(scale))

    def _tool(self, rows: FloatArray, ahead: FloatArray) -> FloatArray | None:
        """The fingertip radius offset of the targets ``rows`` (shape (k, n_fingers, 3))
        and ``ahead`` (shape (n_fingers, 3)), plus the contact-consistent command's push
        where ``press_depth`` is set (:meth:`_press_push`, rate-limited by
        :meth:`_press_limited`), shape (k + 1, n_fingers, 3); None where there is neither
        (the arm's fingertip no larger than the references' or the offset off, and nothing
        pushed; or no object shape).

        The references are fingertip-centre paths recorded with a fingertip of radius
        ``reference_radius`` (the free fingertip's 6 mm); the arm's tip has
        ``finger_radius``. A target near the object is moved out along the object's normal
        there by the difference, so that the arm's pad touches the object where the
        recorded pad did (a tool radius compensation): a 12 mm tip on a 6 mm reference put
        its centre 6 mm inside the cube, where the stiff arm pressed 100-330 N and tracked
        its command 7-30 mm off across the physics distribution. The offset is full where a
        target lies within ``reference_radius`` of the object's faces (the recorded pad
        touching or pressing) and fades out linearly over ``tool_band`` beyond, so the
        approach stays continuous and the offset pad touches first where the recorded one
        did. The normal blends the face normals by a softmax of the face planes' distances
        (``tool_blend`` m), so that it turns smoothly round an edge. The object is where the
        IK believes it (:meth:`see`).

        The offset only moves out: a tip smaller than the recorded pad keeps the targets
        (moved 1 mm deeper, a 5 mm tip's pin came within the IK's collision margin of the
        face, and the IK held the fingertip short of its command: 18 and 10 of the 20 and 12
        runs with a 5-6 mm tip within 3 mm in contact, against 20 and 12 without).

        ``radius_offset`` switches it (off on this driver;
        :class:`~nonprehensile.sim.robot_run.RobotSimulator`'s ``"auto"``, its default,
        turns it on with one fingertip). Across the main plan's 100 samples (seeds 0 and 1,
        the stiff arm's force cap and feed-forward, the tool's pin) runs within 3 mm in
        contact went from 82 and 78 to 93 and 93, and success from 96 and 93 to 97 and 94;
        when it was first tried, before the force cap, it lost three slippery-table pushes
        with large fingertips (91/100 against 94/100; docs/benchmarks.md, arm22)."""
        # out only: a tip smaller than the recorded pad is not sent deeper (below)
        delta = max(self.finger_radius - self.reference_radius, 0.0)
        offset = self.radius_offset and delta > 0.0
        press = self.press_depth
        if self._planes is None or (not offset and press is None):
            return None
        normals, offsets = self._planes
        t, rot = self._believed_pose()
        pts = np.concatenate([np.asarray(rows, dtype=np.float64).reshape(-1, 3),
                              np.asarray(ahead, dtype=np.float64).reshape(-1, 3)])
        local = (pts - t) @ rot  # the object's frame (unscaled: offsets are scaled)
        dist = local @ normals.T - offsets  # (m, faces), world metres
        out = np.zeros_like(pts)
        if offset:
            nrm, top = self._blended_normals(dist, rot)
            fade = np.clip((self.reference_radius + self.tool_band - top) / self.tool_band,
                           0.0, 1.0)
            out = (delta * fade)[:, None] * nrm
            local = local + out @ rot
        if press is not None:
            push = self._press_push(local, press, rot) @ rot.T
            if self.press_rate is not None:
                push = self._press_limited(push.reshape(len(rows) + 1, -1, 3)).reshape(-1, 3)
            out = out + push
        if not offset and not out.any():
            return None
        return np.asarray(out.reshape(len(rows) + 1, -1, 3))

    def _believed_pose(self) -> tuple[FloatArray, FloatArray]:
        """The object's body origin (shape (3,)) and rotation (shape (3, 3)) where the arm
        believes it (:meth:`see`), else the simulation's."""
        if self._seen is not None and self._seen_rot is not None:
            return self._seen[0], self._seen_rot
        d = self.data
        return d.xpos[self._obj], d.xmat[self._obj].reshape(3, 3)

    def _blended_normals(self, dist: FloatArray, rot: FloatArray
                         ) -> tuple[FloatArray, FloatArray]:
        """The object's outward unit normals (world, shape (m, 3)) at points whose signed
        distances to the face planes are ``dist`` (shape (m, faces), m): the face normals
        blended by a softmax of those distances over ``tool_blend``, so that the normal
        turns smoothly round an edge; and each point's largest distance (shape (m,))."""
        assert self._planes is not None
        top = _MAX(dist, axis=1)
        w = np.exp((dist - top[:, None]) / self.tool_blend)
        nrm = (w @ self._planes[0]) @ rot.T
        nrm /= np.sqrt(_SUM(nrm * nrm, axis=1))[:, None]
        return nrm, top

    def _press_limited(self, push: FloatArray) -> FloatArray:
        """The pushes of a control period's rows and its knot's target (shape (k + 1,
        n_fingers, 3), world m), each row's moved from the row before's by at most
        ``press_rate`` (m/s) times the physics step (the knot's, ``k // 2 + 1`` steps past
        the last row), from the last row the previous period gave: where the reference
        crosses the object's interior the push turned from one face to another within a
        control period, a command step of 8-35 mm no tip follows."""
        out = np.array(push)
        step = float(self.press_rate) * self.dt  # type: ignore[arg-type]
        prev = self._press_last
        k = len(out) - 1
        for i in range(k + 1):
            room = step if i < k else step * (k // 2 + 1)
            base = prev if i == 0 else out[i - 1]
            dv = out[i] - base
            n = np.sqrt((dv * dv).sum(axis=1))
            big = n > room
            if big.any():
                dv[big] *= (room / n[big])[:, None]
            out[i] = base + dv
        self._press_last = np.array(out[k - 1] if k > 0 else out[0])
        return out

    def _press_push(self, local: FloatArray, depth: float, rot: FloatArray) -> FloatArray:
        """The push out of the object (object frame, m; shape of ``local``, (m, 3)) that
        keeps each fingertip command ``local`` (the centre of the arm's fingertip sphere,
        radius ``finger_radius``, in the object's frame, m; ``rot``: the object's rotation,
        for the table's side) at most ``depth`` (m) inside the object: the command's
        distance to the object at least ``need = finger_radius - depth``.

        The distance is the Euclidean one outside the object and the largest face plane
        distance inside (:meth:`_signed_distance`). The push goes along the face normals
        blended by a softmax of the command's plane distances (``press_blend`` m, as the
        radius offset's in :meth:`_tool`), so that its direction turns smoothly round an edge
        as the command moves, and never out through a face that looks down at the table
        (more than 45 degrees below the horizon, as :func:`~nonprehensile.transit.escape`: a
        command deep inside a cube that lags the plan is nearest whichever face, the bottom
        one too; it was pushed 17 mm into the table). Its length is where that ray leaves
        the bound: from where it leaves the face planes moved out by ``need`` (far enough:
        a plane distance is a lower bound of the distance), Newton's steps back; the signed
        distance to a convex body is convex along a line, so each step stays far enough and
        the last one is on the bound (exact off a face and round a box's edges and
        vertices). A command already far enough (its largest plane distance at least
        ``need``) is not moved: the motion along the surface and every approach stay the
        reference's."""
        normals, offsets = self._planes  # type: ignore[misc]
        need = self.finger_radius - depth
        dist = local @ normals.T - offsets
        top = dist.max(axis=1)
        out = np.zeros_like(local)
        near = np.flatnonzero(top < need)
        if not len(near):
            return out
        x = local[near]
        d = dist[near]
        # never out through a face that looks down at the table (as transit.escape): a
        # reference deep in a lagging cube is nearest whichever face, the bottom one too
        d = np.where((normals @ rot.T)[:, 2] >= -math.sqrt(0.5), d, -np.inf)
        w = np.exp((d - d.max(axis=1)[:, None]) / self.press_blend)
        u = w @ normals
        u /= np.sqrt((u * u).sum(axis=1))[:, None]
        # start where the ray leaves the face planes moved out by ``need`` (a plane
        # distance is a lower bound of the distance: that point is far enough, exactly so
        # off a face), then Newton's steps back towards where it leaves the rounded bound:
        # the signed distance is convex along the ray, so each step stays far enough
        un = u @ normals.T  # (m, faces); some face has un > 0 (u blends the normals)
        exits = np.where(un > 1e-9, (need - d) / np.where(un > 1e-9, un, 1.0), np.inf)
        s = exits.min(axis=1)
        for _ in range(PRESS_ITERATIONS):
            g, grad = self._signed_distance(x + s[:, None] * u)
            slope = (grad * u).sum(axis=1)
            back = np.where(slope > 1e-6, (g - need) / np.where(slope > 1e-6, slope, 1.0), 0.0)
            back = np.clip(back, 0.0, s)
            s = s - back
            if float(back.max()) < 1e-9:
                break
        out[near] = s[:, None] * u
        return out

    def _signed_distance(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The signed distance (m) of points ``x`` (object frame, shape (m, 3)) to the
        object and its gradient (unit, shape (m, 3)): outside, the distance to the nearest
        point by projections on the face planes the point lies beyond (three rounds where
        it lies beyond several: exact for a box, within a fraction of a millimetre between
        oblique faces); inside, the largest face plane distance and that face's normal."""
        normals, offsets = self._planes  # type: ignore[misc]
        dist = x @ normals.T - offsets
        top = dist.max(axis=1)
        idx = dist.argmax(axis=1)
        g = np.array(top)
        grad = np.array(normals[idx])
        out = np.flatnonzero(top > 0.0)
        if len(out):
            y = np.array(x[out])
            for _ in range(3):
                for n, off in zip(normals, offsets, strict=True):
                    over = y @ n - off
                    y -= np.maximum(over, 0.0)[:, None] * n
            v = x[out] - y
            r = np.sqrt((v * v).sum(axis=1))
            g[out] = r
            ok = r > 1e-12
            grad[out[ok]] = v[ok] / r[ok][:, None]
        return g, grad

    def _bounded(self, targets: FloatArray) -> FloatArray:
        """The IK's targets (shape (n_fingers, 3): the commands plus the contact tracking
        correction, :meth:`_correct`) held at most ``press_depth`` inside the object as
        well (:meth:`_press_push`), where ``press_correction`` is off: the correction then
        closes the error along the surface (friction's lag) but cannot drive a command
        into the object past the bound (against an object that does not give, it
        integrated its whole ``tracking_bound`` into the press)."""
        if self.press_depth is None or self.press_correction or self._planes is None:
            return targets
        t, rot = self._believed_pose()
        arr = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
        push = self._press_push((arr - t) @ rot, self.press_depth, rot)
        if not push.any():
            return targets
        return np.asarray((arr + push @ rot.T).reshape(np.shape(targets)))

    def _set_object(self) -> None:
        """The IK's object at the believed pose (:meth:`see`)."""
        if self._seen is not None:
            # (see makes a new pair of arrays for each pose, never changed in place)
            self.ik.set_object_kept(*self._seen)
        else:
            d = self.data
            self.ik.set_object(d.xpos[self._obj], d.xquat[self._obj])

    def check_compliance(self) -> None:
        """Refuse a virtual finger that is not one (one line saying what came)."""
        k, f, b = self.finger_stiffness, self.force_limit, self.compliance_damping

        def real(x: object) -> bool:  # numpy's numbers too; a bool is not a number here
            return isinstance(x, numbers.Real) and not isinstance(x, (bool, np.bool_))

        if not isinstance(self.compliance, bool):
            raise InputError(f"compliance is True or False, got {self.compliance!r}")
        if not (real(k) and math.isfinite(k) and k > 0.0):
            raise InputError(f"the finger's stiffness is a finite positive N/m, got {k!r}")
        if not (real(f) and f > 0.0 and not math.isnan(f)):
            raise InputError(f"the finger's force limit is a positive N (inf: none), got "
                             f"{f!r}")
        if not (real(b) and math.isfinite(b) and b > 0.0):
            raise InputError(f"the compliance's damping is a finite positive N s/m, got "
                             f"{b!r}")

    def _yield(self, targets: FloatArray, steps: int, noise: FloatArray | None = None, *,
               now: FloatArray | None = None) -> FloatArray:
        """The IK's targets: ``targets`` plus each fingertip's give (:meth:`_comply`,
        updated over ``steps`` physics steps) and its contact tracking correction
        (:meth:`_correct`). ``now``: the targets of this physics step, when ``targets`` lie
        ``steps`` ahead; ``noise``: the fingertip position error on the set points now, part
        of the command."""
        arr = np.asarray(targets, dtype=np.float64)
        now_ = arr if now is None else np.asarray(now, dtype=np.float64)
        # the correction against the command now (the give is added there, in contact only)
        out = self._correct(arr, now_, steps, noise)
        if self.compliance or self.force_cap is not None:
            self._pinv_c = None  # the give's Jacobian, at this solve's joints (_comply, _cap)
            self._jac_give = None
        if self.compliance:
            return out  # (its force is logged every physics step: _comply)
        if self._touch:  # the stiff arm's force, for the records only
            rows = self._tip_force_rows()
            # (the force cap reads the same contacts at this physics step: row hands these
            # on to it)
            self._solve_forces = rows
            f = np.array(rows, dtype=np.float64)
            self._force_now = np.sqrt((f * f).sum(axis=1))
        else:
            self._force_now[:] = 0.0
        return out

    def _comply(self, seg: _Segment, j: int, row: FloatArray) -> FloatArray:
        """Row ``j`` of ``seg`` (``row``) with each fingertip's give (``self._offset``, the
        command minus the target), updated over this physics step: a damper admittance with
        the free fingertip's spring, at the physics rate.

        The free fingertip is a 20 g sphere on a spring of stiffness ``k`` (N/m per axis)
        whose force saturates at ``f`` (N per axis): pressed into an object that does not
        give, it stops where the object's push ``F`` equals the spring's pull ``k g`` (``g``:
        its give behind the target), and past ``f`` it yields. The arm gets the same law as
        an outer loop on its (stiff) position control: its fingertip's command is the target
        plus a give ``g`` that moves as ``B dg/dt = F - sat_f(k g)`` (``B``: the damping,
        ``compliance_damping``), where ``F`` is the contact force on the fingertip, read from
        MuJoCo's contact forces on the tip geom (object and table; a real arm's wrist F/T
        sensor or tactile fingertip; the physics distribution has no force noise, so the
        reading is exact). In steady contact ``F = k g`` below the limit and ``|F_i| <= f``
        per axis above it: the force of the free fingertip at the same target. Off the
        object (no force) the give returns by the same law (``B dg/dt = -k g``). The give
        is bounded by ``give_bound`` (m).

        The give goes on the position servos' set points as a joint offset ``J^+ g`` (``J``:
        the tip sites' position Jacobian at the last solve), every physics step, not through
        the IK: at the 100 Hz control rate a force read once per period samples an impact
        at random, and the arm hopped on the table in a 40 ms limit cycle (70 N impacts)
        where the same law at 1 kHz holds the spring's force. A damper, not a virtual mass:
        the loop from command to force runs through the servos and a stiff contact, and a
        20 g mass on it would ring; ``B`` keeps its crossover ``(K + k) / B`` (``K``: the
        contact's stiffness through the arm) under the servos' bandwidth. The give moves at
        most ``give_speed`` (m/s).
        """
        h = self.dt
        off = self._offset
        f = self._tip_forces()
        k, lim, b = self.finger_stiffness, self.force_limit, self.compliance_damping
        step = (h / b) * (f - np.clip(k * off, -lim, lim))
        n = np.sqrt((step * step).sum(axis=1))
        fast = n > self.give_speed * h
        if fast.any():
            step[fast] *= (self.give_speed * h / n[fast])[:, None]
        off += step
        n = np.sqrt((off * off).sum(axis=1))
        over = n > self.give_bound
        if over.any():
            off[over] *= (self.give_bound / n[over])[:, None]
        self.log._force[self.log.n - 1] = np.sqrt((f * f).sum(axis=1))
        return self._given(row, bool(off.any()))

    def _cap(self, row: FloatArray) -> FloatArray:
        """Row ``row`` with each fingertip's give under the stiff arm's force cap
        (``force_cap``, N), updated over this physics step from the contact force on the
        fingertip (object and table, MuJoCo's contact forces: a wrist F/T sensor's reading),
        and with that force fed forward (``force_feedforward``, :meth:`_pushed`).

        Above the cap the give ``g`` (``self._offset``, part of the command) moves along the
        force, out of what the fingertip presses, as ``B dg/dt = |F| - cap``
        (``cap_damping``); below it, it comes back towards none as ``B d|g|/dt = -(cap -
        |F|)``: continuous at the cap, so the command settles where the force is the cap,
        and off the object it returns (at most ``give_speed`` either way; bounded by
        ``give_bound``). On the servos' set points as the force-limited command's give is
        (``J^+ g``, every physics step: read once per control period the force samples the
        impacts, and an arm pressed into the table hopped, 0 to 500 N). Only while a
        fingertip has a contact or a give: elsewhere a step costs nothing more.

        With ``force_feedforward``, where the give comes back at its full speed (``|F| <=
        cap - B give_speed``, off the object or nearly: there its speed does not depend on
        the force) it is a motion of the command like the IK's: it starts and stops at most
        at ``give_accel``, and its velocity goes on the velocity servos' set points (``J^+
        dg/dt``, taken up and let go at the same rate; so for up to 50 ms after the give
        leaves its full-speed return the velocity fed forward runs down behind it, and it
        stops with the give: :meth:`_give_velocity`). Without that the velocity servos held it
        back: the fingertip lagged a give coming back at 0.1 m/s by ``K_v / K_p`` times that,
        6-10 mm, the worst tracking error in contact of about half the runs across the
        physics distribution. Elsewhere the give's velocity is not fed forward: the cap's
        loop then has no lag but the contact's, and fed forward at every speed 68 of 100
        runs held a torque limit over 10 ms while touching (docs/benchmarks.md)."""
        cap = self.force_cap
        assert cap is not None  # (called only with a cap)
        # (the contact forces the solve of this very physics step read, where it did: the
        # same contacts, the same numbers)
        fl = self._solve_forces
        if fl is None:
            fl = self._tip_force_rows()
        smooth = self.force_feedforward
        if smooth:  # (summed for the next solve's offset: _pushed)
            acc = self._push_sum
            for i, (x, y, z) in enumerate(fl):
                if x or y or z:
                    n = math.sqrt(x * x + y * y + z * z)
                    k = cap / n if n > cap else 1.0
                    acc[3 * i] += x * k
                    acc[3 * i + 1] += y * k
                    acc[3 * i + 2] += z * k
                    self._push_any = True
        if not self._cap_on:  # no give: only a force past the cap starts one (most steps)
            c2 = cap * cap
            # (``all(|f|^2 <= c2)`` as a loop, without a generator: NaN is not within)
            for x, y, z in fl:
                if not x * x + y * y + z * z <= c2:
                    break
            else:
                return row
        h, b = self.dt, self.cap_damping
        v = self.give_speed * h
        full = cap - b * self.give_speed  # (below this force the return runs at full speed)
        a = self.give_accel
        g = self._offset
        speeds, fed = self._give_speed_now, self._give_fed
        on = False
        past: list[tuple[int, float]] = []  # the fingertips pressed past the cap, and how hard
        for i, gi in enumerate(g.tolist()):
            fx, fy, fz = fl[i]
            n = math.sqrt(fx * fx + fy * fy + fz * fz)
            gx, gy, gz = gi
            ng = math.sqrt(gx * gx + gy * gy + gz * gz)
            fed[i] = False
            if n > cap:
                past.append((i, n))
                s_ = min(h * (n - cap) / b, v) / n
                gx, gy, gz = gx + s_ * fx, gy + s_ * fy, gz + s_ * fz
                ng = math.sqrt(gx * gx + gy * gy + gz * gz)
                if ng > self.give_bound:
                    k = self.give_bound / ng
                    gx, gy, gz, ng = gx * k, gy * k, gz * k, self.give_bound
                speeds[i] = 0.0
            elif ng > 0.0:
                step = min(h * (cap - n) / b, v)
                if smooth and n <= full:  # full speed: started and stopped at give_accel
                    # (the step ``u m`` whose run down ``u m, u (m - 1), ..., u`` covers
                    # the give: ``m (m + 1) / 2 = |g| / u``, ``u`` the speed a step gains)
                    u = a * h * h
                    step = min(step, speeds[i] + u, u * (math.sqrt(0.25 + 2.0 * ng / u) - 0.5))
                    fed[i] = True
                speeds[i] = step
                k = max(0.0, ng - step) / ng
                gx, gy, gz, ng = gx * k, gy * k, gz * k, ng * k
            else:
                speeds[i] = 0.0
            g[i] = (gx, gy, gz)
            on = on or ng > 0.0
        self._cap_on = on
        vel = self._give_velocity(fed) if on and smooth else None
        if not on:
            self._give_vel[:] = 0.0  # (the return ended at rest: decelerated)
        out = self._given(row, on, vel)
        if past and self.contact_velocity is not None:
            out = self._velocity_in_contact(out, past, cap)
        return out

    def _velocity_in_contact(self, row: FloatArray, past: list[tuple[int, float]],
                             cap: float) -> FloatArray:
        """Row ``row`` with the velocity set points of each fingertip pressed past the force
        cap (``past``: its index and contact force, N) no faster into the object than the
        fingertip itself: the part of their fingertip velocity (``J qd_ref``, ``J`` the
        give's Jacobian) along the object's outward normal there (the face normals blended
        as for the radius offset, :meth:`_tool`; the object where the arm believes it) that
        goes in faster than the fingertip moves (``J qd``, the joints' own velocities) is
        taken out, as ``J^+`` of it on the velocity servos' set points: in proportion to
        the force's excess over the cap, in full from ``contact_velocity`` times the cap.
        Only while a fingertip touches the object (the table has no reference to follow
        into it); the position set points, the give and the force fed forward are left as
        they are.

        Why: the velocity set points carry the references' motion, and where the object
        does not move as they expect (a heavy, grippy cube rolling slower than its
        reference) the fingertip cannot follow them into it: the velocity servos then
        press with ``K_v`` times the difference (``K_v / K_p`` = 0.1 s on the Panda: 10
        cm/s into a face is as much as 10 mm of position error), which the cap's give,
        on the position set points only, does not take back. Across the physics
        distribution the worst runs pressed 100-217 N on a rolling cube's top face (the
        references 2-9 cm/s into it, the face rising at 1-10 cm/s) with the command's
        normal position on the fingertip (its error along the normal under 1.2 mm): the
        friction of that press (finger friction 0.92-1.15) held the fingertip while its
        target slid along the face, 4-6 mm behind (docs/benchmarks.md). Only past the cap
        and into the object: below it, and along the face, the servos' velocity feed-forward
        is what makes them track."""
        if self._planes is None or not self._touch:
            return row
        if self.n_fingers > 1:
            # the flag says that some fingertip touches the object: only those that do now
            # are taken (a fingertip pressed past the cap on the table has no reference to
            # follow into the object, and the object's normal there means nothing to it)
            on = self._tips_on_object()
            past = [(i, f) for i, f in past if i in on]
            if not past:
                return row
        pinv = self._give_pinv()  # (the give's, made by _given this physics step)
        jac = self._jac_c
        assert jac is not None
        vc = self.scene.vel_act
        qd_set = row[vc]
        v_set = (jac @ qd_set).reshape(-1, 3)
        v_tip = (jac @ self.data.qvel[self._dsl]).reshape(-1, 3)
        normals, offsets = self._planes
        t, rot = self._believed_pose()
        tips = self.tips(self.data)
        nrm, _ = self._blended_normals(((tips - t) @ rot) @ normals.T - offsets, rot)
        full = self.contact_velocity
        assert full is not None
        dv = np.zeros((self.n_fingers, 3))
        for i, f in past:
            into = float((v_set[i] - v_tip[i]) @ nrm[i])  # < 0: faster into it than the tip
            if into < 0.0:
                share = 1.0 if full <= 1.0 else min(1.0, (f - cap) / ((full - 1.0) * cap))
                dv[i] = (-into * share) * nrm[i]
        if not dv.any():
            return row
        out = np.array(row)
        out[vc] = np.maximum(np.minimum(qd_set + pinv @ dv.ravel(), self._vel_max),
                             self._vel_min)
        return out

    def _tips_on_object(self) -> set[int]:
        """The fingertips (indices) touching the object now, by the judge's rule (contacts
        within 0.1 mm)."""
        con = self.data.contact
        obj, index = self._obj_geom, self._tip_index
        on: set[int] = set()
        for (a, b), dd in zip(con.geom.tolist(), con.dist.tolist(), strict=True):
            if dd > 1e-4:
                continue
            if a == obj and b in index:
                on.add(index[b])
            elif b == obj and a in index:
                on.add(index[a])
        return on

    def _give_velocity(self, fed: list[bool]) -> FloatArray | None:
        """The give's velocity fed forward now (shape (n_fingers, 3), m/s; None: none):
        each fingertip's ``dg/dt`` where its give comes back at full speed (``fed``), none
        elsewhere, the feed-forward moving towards it at most ``give_accel`` (the velocity
        servos see no step but one: when the give reaches none the feed-forward stops, from
        at most ``give_accel`` times a step (2 mm/s) after a full-speed return, from what
        is left of its run-down after any other)."""
        w, last, g = self._give_vel, self._give_last, self._offset
        if any(fed) or w.any():
            u = (g - last) * (1.0 / self.dt)
            for i, f in enumerate(fed):
                if not f:
                    u[i] = 0.0
            dw = u - w
            nd = np.sqrt((dw * dw).sum(axis=1))
            lim = self.give_accel * self.dt
            big = nd > lim
            if big.any():
                dw[big] *= (lim / nd[big])[:, None]
            w += dw
        last[:] = g
        return w if w.any() else None

    def _pushed(self) -> FloatArray | None:
        """The contact force feed-forward of the control period starting now: the offset of
        the position set points (rad, shape (n_joints,); None: no force), ``K_p^-1 (-J^T
        F)``, ``F`` each fingertip's contact force clipped at the force cap and averaged
        over the physics steps since the last solve (:meth:`_cap` sums it every physics
        step while its gate is open: a fingertip's contact, read every ``CONTACT_EVERY``
        steps, or a give), ``J`` the tip sites' position Jacobian (:meth:`_tip_jac`'s, at
        this solve's joints or within the period before); each joint's torque within its
        limit on its own (the acceleration's offset is clipped on its own too, and the
        torque budget, :meth:`_within_torque`, does not count this one), none for a servo
        that is not a plain one (as the acceleration's torque, :meth:`_accel_offset`).

        The servos held a contact force from their position error: the fingertip stood
        ``C F`` from its command (``C``, the arm's compliance at the tip: 2.3 mm at 35 N in
        the tests' pose near the base; 4-7 mm at 20-70 N in the physics distribution's
        runs, much of it across the force, along the face pushed, where the contact
        tracking correction may move the command by 0.5 mm only). Clipped at the cap: an
        impact's force (200-500 N for a few ms) is not pushed back against (unclipped,
        across the physics distribution, the arm pressed up to 290 N and a third of the runs
        held a torque limit over 10 ms). Per control period, averaged: the offset follows
        the force one period late and steps at the period's boundary as the acceleration's
        does, with no numpy per physics step; fed every physics step it measured alike
        (docs/benchmarks.md)."""
        steps = self._n - self._push_n0
        self._push_n0 = self._n
        if not self._push_any:
            return None
        acc = self._push_sum
        f = np.array(acc) * (1.0 / max(steps, 1))
        acc[:] = [0.0] * len(acc)
        self._push_any = False
        if self._pinv_c is None and self._jac_give is None:
            # the Jacobian at this solve's joints; its inverse only if a give needs it
            self._jac_give = self._tip_jac()
        jac = self._jac_c
        assert jac is not None
        d = -(jac.T @ f) / self._kp_joint
        lim = self._push_lim
        return np.asarray(_clip(d, -lim, lim), dtype=np.float64)

    def _given(self, row: FloatArray, on: bool, vel: FloatArray | None = None) -> FloatArray:
        """Row ``row`` with the give (``self._offset``) logged on the row just recorded and,
        where ``on`` (any give), put on the position servos' set points as the joint offset
        ``J^+ g`` (``J``: the tip sites' position Jacobian at the last solve), and ``vel``
        (the give's velocity fed forward, m/s, shape (n_fingers, 3); None: none) on the
        velocity servos' as ``J^+ vel``, within the joints' velocity limits."""
        g = self._offset
        self.log._give[self.log.n - 1] = g  # the row just recorded (record)
        if not on:
            return row
        pinv = self._give_pinv()
        out = np.array(row)
        out[self.scene.pos_act] += pinv @ g.ravel()
        if vel is not None:
            vc = self.scene.vel_act
            out[vc] = np.maximum(np.minimum(out[vc] + pinv @ vel.ravel(),
                                            self._vel_max), self._vel_min)
        return out

    def _correct(self, targets: FloatArray, now: FloatArray, steps: int,
                 noise: FloatArray | None) -> FloatArray:
        """``targets`` plus each fingertip's contact correction, updated over ``steps``
        physics steps.

        In contact the object pushes back on the fingertip and the stiff but finite joint
        servos give: a 3.2-3.4 mm steady error in the pushes of a roll-arc and a roll-pull
        at nominal physics (the joints' set points 2-3 mrad ahead of the joints). The
        correction integrates the fingertip's error against its command (``now``, the
        target, plus the give, plus ``noise``) while it touches the object, at
        ``tracking_gain`` (1/s; with several fingertips, every fingertip's while any one
        touches: measured better in the two-arm tumbles than a per-fingertip switch,
        ``docs/robot.md``; with ``tracking_tangential``, ``RobotSimulator``'s default for
        several, only the error's part along the object's surface; with a finite
        ``tracking_surface_bound``, ``RobotSimulator``'s default for one, the correction's
        part along the surface within that bound: :meth:`_correct_by_normal`), so the set
        points lead by what the contact takes. It is bounded by
        ``tracking_bound`` (m), is held (not grown) while any joint's torque is above
        ``torque_guard`` of its limit (a fingertip against an object that does not give
        must not press harder, up to the limits), and fades with the time constant
        ``1 / release_rate`` once the fingertip is off the object (a let-go or a transit
        must not carry it). Measured at 1 kHz: holding it fits the nominal transitions
        better than letting it fade when a fingertip is blocked (> 6 mm from its command)
        or near a torque limit, or capping its growth (0.05 m/s): 2.1-3.0 mm and up to
        16 ms against 0.8-1.8 mm and 6 ms in the same roll-arcs and roll-pulls.
        """
        c = self._corr
        gain = self.tracking_gain
        if gain <= 0.0:
            return targets
        dt = steps * self.dt
        if self._touch:
            # per fingertip and axis in plain Python (a few numbers: numpy calls on them cost
            # more than the arithmetic), the same IEEE operations in the same order as the
            # arrays' were (``tip - (now + give) - noise``, ``c - g e``, the norm's
            # ``(x x + y y) + z z``, ``c (bound / norm)``), so the same numbers (held to the
            # numpy form by tests/test_robot_setpoints.py)
            qf = self.data.qfrc_actuator[self._dsl].tolist()
            ratios = [abs(qf[i]) / lim for i, lim in self._torque_limits]
            top = max(ratios, default=-math.inf)
            # (with a NaN torque numpy's maximum was NaN, never above the guard: so here)
            guard = top > self.torque_guard and all(r == r for r in ratios)
            cl: list[list[float]] = c.tolist()
            if not guard and (self.tracking_tangential
                              or self.tracking_surface_bound < math.inf):
                cl = self._correct_by_normal(now, noise, min(gain * dt, 1.0))
            elif not guard:
                src = self._sources
                tips = (src[3].tolist() if src is not None else
                        self.data.site_xpos[self._tip_sites].ravel().tolist())
                g = min(gain * dt, 1.0)
                noisy = None if noise is None else noise.tolist()
                # (the command ``now + give`` formed here: out of contact it is not read)
                for f, (cf, nw, gv) in enumerate(zip(cl, now.tolist(), self._offset.tolist(),
                                                     strict=True)):
                    for a in range(3):
                        e = tips[3 * f + a] - (nw[a] + gv[a])
                        if noisy is not None:
                            e = e - noisy[f][a]
                        cf[a] = cf[a] - g * e
            # else held: near a torque limit a fingertip presses no harder (an object that
            # does not give is not pushed into up to the limits)
            bound = self.tracking_bound
            for cf in cl:
                x, y, z = cf
                n = math.sqrt(x * x + y * y + z * z)
                if n > bound:
                    s = bound / n
                    cf[0], cf[1], cf[2] = x * s, y * s, z * s
            c[:] = cl
        elif np.count_nonzero(c):  # (``c.any()``: NaN counts, as there)
            c *= math.exp(-self.release_rate * dt)
            if float(_MAX(np.abs(c), axis=None)) < 1e-7:
                c[:] = 0.0
        return targets + c

    def _correct_by_normal(self, now: FloatArray, noise: FloatArray | None,
                            g: float) -> list[list[float]]:
        """The contact correction's update split by the object's outward normal at each
        fingertip (the face normals blended as in :meth:`_tool`, the object where the arm
        believes it): with ``tracking_tangential`` the error's component along the normal
        is left out (below); with a finite ``tracking_surface_bound`` the correction's part
        along the surface is held within that bound, its part along the normal kept.

        One arm pushing: the contact force deflects the stiff servos along the normal (the
        press the correction restores) and, through friction, along the surface. A
        correction along the surface as large as the normal one held the pad sideways
        (+2.4 mm across a roll-pull) and the cube ended its roll-pulls 3-4 degrees turned,
        one more turning push each. Bounded to 0.5 mm along the surface, the 72
        single-finger cube transitions by one arm at nominal physics simulated 336 s
        against 392 s (the roll-pulls 24 end-of-plan corrections against 48, the roll-arcs
        54 against 72) with every one reached and the tracking in contact within 2.8 mm;
        without a surface part at all (the normal only) 318 s, but the push-rolls tracked
        up to 3.2 mm (the friction's drag along the face); a surface part of a quarter of
        the error brought all 48 corrections back (docs/benchmarks.md).

        Pinching, the references put each pad 2-8 mm inside the cube: the normal part of
        the error is what no rigid tip can close, and integrated it squeezed the cube
        harder (up to 70 N). The part along the surface is the arm's lag as it carries the
        cube: 3.5 mm at 0.45 m/s in the tumble-lift's tumble (measured), which the
        correction takes out as it does for one arm's pushes. Each update is projected, not
        the correction kept: as the pinched faces turn (a twist), part of what was
        integrated along them comes to lie along their normals, up to the bound (projecting
        the whole correction at every update was measured worse: docs/benchmarks.md).
        The bound along the surface applies to the correction itself, after the update.

        Raises
        ------
        InputError
            No object faces (:meth:`set_shape`) to take the normals from.
        """
        planes = self._planes
        if planes is None:
            raise InputError("the contact correction split by the object's normal "
                             "(tracking_tangential, tracking_surface_bound) needs the "
                             "object's faces: call RobotArms.set_shape first "
                             "(RobotSimulator does)")
        tips = self.tips(self.data)
        e = tips - (now + self._offset)
        if noise is not None:
            e = e - noise
        normals, offsets = planes
        t, rot = self._believed_pose()
        dist = ((tips - t) @ rot) @ normals.T - offsets  # (n_fingers, faces), m
        nrm, _ = self._blended_normals(dist, rot)
        if self.tracking_tangential:
            e -= _SUM(e * nrm, axis=1)[:, None] * nrm
        c = self._corr - g * e
        sb = self.tracking_surface_bound
        if sb < math.inf:  # the part along the surface within its bound, the normal kept
            cn = _SUM(c * nrm, axis=1)[:, None] * nrm
            ct = c - cn
            n = np.sqrt(_SUM(ct * ct, axis=1))
            big = n > sb
            if _ANY(big):
                ct[big] *= (sb / n[big])[:, None]
                c = cn + ct
        out: list[list[float]] = c.tolist()
        return out

    def _tip_forces(self) -> FloatArray:
        """The contact force on each fingertip (world, N; from the object and the table),
        shape (n_fingers, 3)."""
        return np.array(self._tip_force_rows(), dtype=np.float64)

    def _tip_force_rows(self) -> list[list[float]]:
        """:meth:`_tip_forces` as a list of ``[x, y, z]`` per fingertip (what :meth:`_cap`
        reads every physics step while a fingertip touches: no array made and read back)."""
        nf = self.n_fingers
        out = [[0.0, 0.0, 0.0]] if nf == 1 else [[0.0, 0.0, 0.0] for _ in range(nf)]
        d = self.data
        if d.ncon == 0:
            return out
        con = d.contact
        index = self._tip_index
        m, buf, f3 = self.scene.model, self._fbuf, self._f3
        frames = None
        # plain Python over the handful of contacts, in their order (two np.isin over them
        # cost more than the whole loop); the same sums in the same order. The force in the
        # world frame is ``f3 . frame`` (the frame's rows are its axes): the same BLAS
        # product, bit for bit, as ``frame.T @ f3``, in two numpy calls fewer (``np.dot``:
        # ``@``'s product with less dispatch); the sums are
        # plain floats, the same IEEE additions as the array's (``0.0 + x`` first)
        for i, (a, b) in enumerate(con.geom.tolist()):
            on2 = b in index
            if not on2 and a not in index:
                continue
            o = out[index[b if on2 else a]]
            mujoco.mj_contactForce(m, d, i, buf)
            if frames is None:
                frames = con.frame.reshape(-1, 3, 3)
            # the force geom1 exerts on geom2, in the contact frame (normal: 1 -> 2)
            x, y, z = np.dot(f3, frames[i]).tolist()
            if on2:
                o[0] += x
                o[1] += y
                o[2] += z
            else:
                o[0] += -x
                o[1] += -y
                o[2] += -z
        return out

    def _contacts(self, d: Any) -> tuple[bool, bool, bool]:
        """Whether a fingertip touches the object, whether a link or the rod touches the
        object or the table, and whether a fingertip touches anything (the force cap's
        gate), by the judge's rule (contacts within 0.1 mm), in one pass."""
        con = d.contact
        # the fields read in bulk, then plain Python over a handful of contacts (numpy
        # masks over them cost more than the loop); MuJoCo's contact arrays are ``ncon``
        # long (their length is ``ncon``, without reading it or slicing to it)
        geoms = con.geom.tolist()
        if not geoms:
            return False, False, False
        obj, tips, links = self._obj_geom, self._tip_set, self._link_set
        touch = other = tip = False
        for (a, b), dd in zip(geoms, con.dist.tolist(), strict=True):
            if dd > 1e-4:
                continue
            if a in links or b in links:
                other = True
            elif a in tips or b in tips:
                tip = True
                if a == obj or b == obj:
                    touch = True
        return touch, other, tip

    def record(self, seg: _Segment, j: int) -> None:
        """Log the robot's state before physics step ``j`` (row ``j`` of ``seg``); the
        period's set points and targets were logged at its solve."""
        d, log = self.data, self.log
        if self._n % CONTACT_EVERY == 0:  # as often as the judge reads contacts
            self._touch, self._other, self._tip_contact = self._contacts(d)
        self._n += 1
        self._last = (seg, j)
        n = log.n
        if n >= len(log._time):
            log.reserve(1)
        src = self._sources
        if src is not None:  # (every robot scene built here: its joints and tips in a row)
            t, q, qd, tau, tips, touch, other = log._mv
            nj, nt = self._widths
            a, b = n * nj, n * nt
            q[a:a + nj], qd[a:a + nj], tau[a:a + nj], tips[b:b + nt] = src
            t[n] = d.time
            touch[n] = self._touch
            other[n] = self._other
            log.n = n + 1
            return
        log._time[n] = d.time
        log._q[n] = d.qpos[self._qsl]
        log._qd[n] = d.qvel[self._dsl]
        log._tau[n] = d.qfrc_actuator[self._dsl]
        log._tips[n] = d.site_xpos[self._tip_sites]
        log._touch[n] = self._touch
        log._other[n] = self._other
        log.n = n + 1
