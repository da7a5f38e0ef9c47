"""Execute a plan in MuJoCo, closed loop (event-driven) or open loop, transits included.

:func:`execute_plan` runs a whole plan in one continuous simulation:

* **closed loop** (the default): before each step the fingertips transit (retreat, clear
  the observed object by a margin, approach) to the step's first reference point anchored on
  the observed object; the step runs under a :class:`~nonprehensile.control.StepMonitor`
  (each arc re-anchored at its contact event, run until its end event is observed, aborted
  on an anomaly); the state is read from the observed pose once it is still; a state other
  than the predicted one is re-planned from (:func:`~nonprehensile.control.after_step`); at
  the end, the object is slid onto the goal position if it rests off it
  (:func:`~nonprehensile.control.correction_pushes`);
* **open loop**: the same transits, planned on the poses the plan predicts; each step's
  reference runs for its duration where the plan predicts the object, then the object
  settles; nothing is observed.

The controller sees the scene only through :class:`~nonprehensile.sim.observe.SimObserver`
(noise, latency, rate); the judge (:mod:`nonprehensile.sim.judge`) reads MuJoCo's contacts
and the true final state for the records and the verdict. The inner loop writes the
driver's precomputed controls and calls ``mj_step``; contacts are read every
:data:`~nonprehensile.sim.judge.CONTACT_EVERY` steps and the controller runs only when an
observation arrives.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import mujoco
import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from nonprehensile.control import (
    GO_ON,
    ControlConfig,
    Decision,
    NextAction,
    StepMonitor,
    after_step,
    anchor_transform,
    angular_step,
    correction_pushes,
    observed_state,
    one_finger_push,
    push_finger,
    same_state,
    snap_state,
    step_spec,
    turn_push,
)
from nonprehensile.demonstrations.dataset import DEFAULT_FINGERS
from nonprehensile.errors import NonprehensileError
from nonprehensile.inference import Expansion
from nonprehensile.observation import Observation, ObservationModel
from nonprehensile.planning import ObjectPose, Plan, PlanStep
from nonprehensile.sim.compare import DEFAULT_ANGLE_TOL_DEG, DEFAULT_POSITION_TOL, compare
from nonprehensile.sim.distribution import FINGER_NOISE_TIME, NO_PERTURBATION, Perturbation
from nonprehensile.sim.execute import Outcome
from nonprehensile.sim.judge import CONTACT_EVERY, EventLog, SimEvent
from nonprehensile.sim.observe import SimObserver
from nonprehensile.sim.run import SimResult, Simulator
from nonprehensile.states import State, angle_diff
from nonprehensile.step_paths import fingers_of, resample
from nonprehensile.transit import (
    escape,
    guarded_push,
    hull_distance,
    limit_speed,
    limits_of,
    release,
    transit,
)

__all__ = ["Execution", "execute_plan", "scene_fingers", "transition_record"]

FloatArray = NDArray[np.float64]
Replanner = Callable[[State, tuple[float, float], frozenset[str]], Plan]
#: Cross-fade (s) from the running targets into new ones, so the commanded velocity never
#: jumps.
CROSSFADE = 0.06
#: A fingertip has let go of the object once it is observed this far (m) beyond its radius
#: from the observed object: the executor reads "touching" within ``contact_tol`` (1.5 mm),
#: and the rest covers the pad's own position error (1 mm, a slow Gauss-Markov process) ...
LET_GO_CLEAR = 0.004
#: ... and it lets go along its contact normal aiming this far (m) beyond its radius.
LET_GO_REACH = 0.007
#: With ``ControlConfig.push_approach`` (robots), a correction push (:func:`_push`) crosses
#: its start's clearance to the face quickly and is down to its own speed this far (m)
#: before the face as observed. The face may be nearer by the tracker's and the
#: fingertip's position errors (0.5 and 1 mm in the physics distribution); the pad then
#: touches while still slowing down, below the 0.1 m/s at which every transit's approach
#: lands a pad on the object ...
PUSH_MARGIN = 0.003
#: ... accelerating and braking at this (m/s^2; at most the motions' bound).
PUSH_ACCEL = 2.0
#: A let-go's fingertips are off the object (the judge's contact reading) within this (s)
#: of its start: the bound the benchmark and the tests hold it to. A pad pressed ``D`` into
#: the object by a compliant finger (its command deeper still) comes free once its command
#: has left the face's plane, about ``sqrt(2 D / max_accel)`` plus the pad's lag: 25-40 ms
#: for 5-10 mm at 20 m/s^2.
LET_GO_SEPARATION = 0.05


def scene_fingers(plan: Plan, expansion: Expansion | None = None) -> int:
    """How many fingertips a scene needs for every step of ``plan`` (and, given the
    expansion, for any skill a re-plan may turn to)."""
    skills = [s.transition.skill for s in plan.steps]
    if expansion is not None:
        skills += [t.skill for t in expansion.transitions]
    return max((max(fingers_of(s), default=1) for s in skills), default=1)


@dataclass
class Execution:
    """What an execution did (mutable while it runs; :meth:`to_dict` for JSON).

    ``success`` is the judge's verdict on the true final pose: the goal's face, ``theta``
    within the angle tolerance and the centre of mass within the position tolerance of the
    goal position (the plan's predicted end). With ``keep_trace``, ``executed`` holds every
    executed step (re-planned ones included) with an
    :class:`~nonprehensile.sim.execute.Outcome` whose trace and events start at the step's
    first arc (what ``simulate plan --record`` writes).
    """

    loop: str
    goal: State
    goal_position: tuple[float, float]
    success: bool = False
    reason: str = ""
    final_state: State | None = None
    final_pose: ObjectPose | None = None
    theta_error: float | None = None
    position_error: float | None = None
    steps: list[dict[str, Any]] = field(default_factory=list)
    replans: list[dict[str, Any]] = field(default_factory=list)
    corrections: list[dict[str, Any]] = field(default_factory=list)
    transits: list[dict[str, Any]] = field(default_factory=list)
    commanded_speed: float = 0.0
    commanded_accel: float = 0.0
    tip_speed: float | None = None
    transit_contact_s: float = 0.0
    let_go_contact_s: float = 0.0
    let_go_separation_s: float = 0.0
    let_go_recontacts: int = 0
    let_go_object_moved: float = 0.0
    transit_accel: float = 0.0
    finger_table: bool = False
    sim_time: float = 0.0
    wall_time: float = 0.0
    n_steps: int = 0
    trace: FloatArray | None = None
    step_traces: list[tuple[int, float, float]] = field(default_factory=list)
    executed: list[tuple[PlanStep, Outcome]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "loop": self.loop,
            "success": self.success,
            "reason": self.reason,
            "goal": self.goal.to_dict(),
            "goal_position": [round(v, 6) for v in self.goal_position],
            "final_state": self.final_state.to_dict() if self.final_state else None,
            "final_position": (None if self.final_pose is None
                               else [round(v, 6) for v in self.final_pose.position]),
            "theta_error_deg": None if self.theta_error is None else round(self.theta_error, 3),
            "position_error_m": (None if self.position_error is None
                                 else round(self.position_error, 5)),
            "steps": self.steps,
            "replans": self.replans,
            "retries": sum(1 for r in self.replans if r.get("retry")),
            "corrections": self.corrections,
            "transits": self.transits,
            "limits": {"commanded_max_speed": round(self.commanded_speed, 4),
                       "commanded_max_accel": round(self.commanded_accel, 3),
                       "fingertip_max_speed": (None if self.tip_speed is None
                                               else round(self.tip_speed, 4)),
                       "transit_finger_object_contact_s": round(self.transit_contact_s, 4),
                       "let_go_finger_object_contact_s": round(self.let_go_contact_s, 4),
                       "let_go_max_separation_s": (None if math.isinf(self.let_go_separation_s)
                                                   else round(self.let_go_separation_s, 4)),
                       "let_go_recontacts": self.let_go_recontacts,
                       "let_go_max_object_moved_in_contact_m": round(
                           self.let_go_object_moved, 5),
                       "transit_commanded_max_accel": round(self.transit_accel, 3),
                       "finger_table_contact": self.finger_table},
            "sim_seconds": round(self.sim_time, 4),
            "wall_seconds": round(self.wall_time, 4),
            "physics_steps": self.n_steps,
        }


#: Time constants of the smoothed fingertip noise computed past a segment's end (its rows'
#: tail, :meth:`FingerNoise.rows`): the two low-passes' state decays there as ``(1 + t/tau)
#: e^(-t/tau)``, 0.3 % at 8, and the velocity left when a longer hold holds the tail's last
#: row is under 0.3 mm/s for the distribution's 1 mm noise (up to 2.4 % of its value at the
#: segment's end, a review's 300 segments).
NOISE_TAIL = 8.0


@functools.lru_cache(maxsize=16)
def _smoothing_gain(dt: float, tau: float) -> float:
    """The gain that gives the fingertip noise smoothed at ``tau`` (two first-order
    low-passes in series, :meth:`FingerNoise.rows`) the raw process's standard deviation: one
    over the square root of the smoothed stationary variance per unit of the raw one, summed
    over the chain's impulse response (the stationary Gauss-Markov process of time constant
    ``FINGER_NOISE_TIME`` is ``sqrt(1 - a^2)`` times white noise through ``1 / (1 - a z^-1)``).
    At 1 ms and 20 ms the smoothing alone keeps 78 % of the deviation."""
    a = math.exp(-dt / FINGER_NOISE_TIME)
    c = math.exp(-dt / tau)
    n = math.ceil(40.0 * max(FINGER_NOISE_TIME, tau) / dt) + 1
    h = np.zeros(n)
    h[0] = 1.0
    h = lfilter([1.0], [1.0, -a], h)
    h = lfilter([1.0 - c], [1.0, -c], h)
    h = lfilter([1.0 - c], [1.0, -c], h)
    return 1.0 / math.sqrt((1.0 - a * a) * float(np.dot(h, h)))


class FingerNoise:
    """The fingertip position error of one execution (the physics distribution's
    ``finger_noise``): one Gauss-Markov process per axis and fingertip, time constant
    :data:`~nonprehensile.sim.distribution.FINGER_NOISE_TIME`, drawn segment by segment
    and continued from the last row applied (:meth:`cut`).

    Parameters
    ----------
    rng : numpy.random.Generator
        The execution's finger stream.
    sigma : float
        Standard deviation, m.
    dt : float
        Physics step, s.
    n_fingers : int
    """

    def __init__(self, rng: np.random.Generator, sigma: float, dt: float,
                 n_fingers: int) -> None:
        self.rng = rng
        self.sigma = sigma
        self.dt = dt
        # the state: the error and, smoothed (rows), its two low-passes; the running
        # segment's rows of each, and the state they continued from
        z: FloatArray = np.zeros((n_fingers, 3))
        self.state: tuple[FloatArray, ...] = (z, z, z)
        self._from: tuple[FloatArray, ...] = self.state
        self._rows: tuple[FloatArray, ...] | None = None

    def rows(self, n: int, smoothing: float = 0.0
             ) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
        """The next segment's ``n`` rows of the error, shape (n, n_fingers, 3), and, with
        ``smoothing`` (s > 0), the error smoothed and its velocity (else None, None).

        The smoothed error is the process through two first-order low-passes of time
        constant ``smoothing`` in series (critically damped), scaled to keep the process's
        standard deviation (:func:`_smoothing_gain`), and its velocity each row's difference
        from the row before over the step: the raw process has no derivative, and an arm's
        fingertip follows a command only as far as its velocity is fed forward. Those rows
        run ``NOISE_TAIL`` time constants past the segment's end, the raw error held there
        (as the targets are): a hold comes to rest smoothly, its velocity never cut in one
        step (a cut held joints at their torque limits for a step or two at every hold's
        start and end)."""
        dt = self.dt
        a = math.exp(-dt / FINGER_NOISE_TIME)
        x0, z1, z2 = self.state
        w = self.rng.standard_normal((n, *x0.shape)) * self.sigma * math.sqrt(1.0 - a * a)
        out, _ = lfilter([1.0], [1.0, -a], w, axis=0, zi=(a * x0)[None])
        rows: tuple[FloatArray, ...] = (out,)
        smooth = vel = None
        if smoothing > 0.0:
            c = math.exp(-dt / smoothing)
            g = 1.0 - c
            held = np.concatenate([out, np.repeat(out[-1:], math.ceil(
                NOISE_TAIL * smoothing / dt), axis=0)])
            y1, _ = lfilter([g * _smoothing_gain(dt, smoothing)], [1.0, -c], held, axis=0,
                            zi=(c * z1)[None])
            smooth, _ = lfilter([g], [1.0, -c], y1, axis=0, zi=(c * z2)[None])
            vel = np.diff(smooth, axis=0, prepend=z2[None]) / dt
            rows = (out, y1, smooth)
        self._from = self.state
        self._rows = rows
        self.state = tuple(r[-1] for r in rows) + self.state[len(rows):]
        return out, smooth, vel

    def cut(self, i: int) -> None:
        """The running segment stops after ``i`` rows (replaced, or its drive ended there):
        the next segment's rows continue the process from the last row applied, not from the
        end of rows never run. (Continued from their end, as it was, the error jumped at
        every replacement, by about ``sqrt(2)`` times ``sigma`` per axis from one physics
        step to the next: a step of millimetres in the command, the worst tracking error of
        half the robot's runs across the physics distribution.) A second cut before the next
        rows changes nothing."""
        rows = self._rows
        if rows is None:
            return
        if i < 1:
            self.state = self._from
        else:  # (past the end: the raw error held, the smoothed rows' tail, then its last)
            self.state = tuple(r[min(i, len(r)) - 1] for r in rows) + self.state[len(rows):]
        self._rows = None


class _Runner:
    """The MuJoCo side of one execution: the step loop, the observer and the records."""

    def __init__(self, sim: Simulator, observation: ObservationModel,
                 tracker_rng: np.random.Generator, finger_rng: np.random.Generator,
                 finger_noise: float, keep_trace: int, signals: bool = False,
                 max_speed: float = 0.5) -> None:
        self.sim = sim
        self.m, self.d = sim.model, sim.data
        self.dt = sim.params.timestep
        self.observer = SimObserver(sim, observation, tracker_rng)
        self.noise = FingerNoise(finger_rng, finger_noise, self.dt, sim.n_fingers)
        self.t = 0.0
        self.n = 0
        self.log = EventLog(sim.judge)
        self.command = sim.park()
        self.commanded: list[FloatArray] = []
        self.tip_speed = 0.0
        self.keep_trace = keep_trace
        self.signals = signals
        self.max_speed = max_speed  # every commanded motion is retimed to stay within it
        self.trace: list[FloatArray] = []
        self.contact_reads = 0  # fingertip-object contacts read during watched drives
        # the judge's fingertip-object contact in watched drives (let-gos, holds, transits):
        # (time, touching, object's centre of mass) at every change, for the let-go records
        self.touching = False
        self.touch_log: list[tuple[float, bool, FloatArray]] = []
        self.last_obs: Observation | None = None  # the one the last decision was made on
        # let-go records waiting for the end of the transit after them (re-contacts)
        self.pending: list[tuple[dict[str, Any], int, float, float | None]] = []
        self._tail: FloatArray | None = None
        self._tail_velocity: FloatArray | None = None
        self._cursor: tuple[FloatArray, int] = (self.command[None], 0)

    # ------------------------------------------------------------------------- noise
    def _noisy(self, seg: FloatArray) -> FloatArray:
        """Commanded targets plus the fingertip's position error (:class:`FingerNoise`).

        A robot's driver (``with_noise``) puts the error on its servos' set points, smoothed
        with its velocity where it asks for it (``noise_smoothing``, s > 0:
        :meth:`FingerNoise.rows`); the free fingertips get the raw error on their targets."""
        if self.noise.sigma <= 0:
            return seg
        split = getattr(self.sim.driver, "with_noise", None)
        tau = float(getattr(self.sim.driver, "noise_smoothing", 0.0)) if split else 0.0
        raw, smooth, vel = self.noise.rows(len(seg), tau)
        if split is None:
            return np.asarray(seg + raw)
        if smooth is None:
            return np.asarray(split(seg, raw))
        return np.asarray(split(seg, smooth, vel))

    # -------------------------------------------------------------------------- loop
    def drive(
        self,
        segment: FloatArray,
        *,
        react: Callable[[Observation, FloatArray], Decision] | None = None,
        transit_leg: bool = False,
        max_time: float = 30.0,
        hold: float = 0.0,
    ) -> Decision | None:
        """Drive the fingertips along ``segment`` (targets every physics step).

        Without ``react``: until the segment has run, then ``hold`` more seconds. With it:
        it is called on every new observation and may replace the targets (cross-faded in)
        or end the drive (its :class:`Decision` is returned), at most ``max_time``.
        """
        sim, m, d, dt = self.sim, self.m, self.d, self.dt
        judge, observer, log = sim.judge, self.observer, self.log
        seg = np.asarray(segment, dtype=np.float64)
        if self._tail is not None:  # the last drive stopped mid-motion: fade out of it
            seg = self._crossfade(self._tail, 0, seg)
            self._tail = None
        seg = limit_speed(seg, dt, self.max_speed)
        ctrl = sim.driver.controls(self._noisy(seg))
        self.commanded.append(seg)
        i = 0
        n_extra = round(hold / dt)
        t_end = self.t + max_time
        step = mujoco.mj_step
        # an array of controls is copied row by row between memoryviews (a slice of the
        # rows' buffer into ``d.ctrl``'s): a memcpy of the same doubles, cheaper than
        # numpy's row indexing and assignment; a robot's controls are rows solved as they
        # are read (``rows`` None), read by index
        ctrl_view = d.ctrl
        ctrl_out = memoryview(ctrl_view)
        rows, width = _flat_rows(ctrl)
        at = 0  # i * width
        # the free fingertips' joint velocities are their speeds (a robot's driver has none);
        # a view of them, read as floats (the speed's square is compared: the square root
        # of the largest is the largest square root, bit for bit)
        finger_dofs = getattr(sim.driver, "dadr", None)
        # a robot's IK avoids the object where it is observed (never the true pose)
        see = getattr(sim.driver, "see", None)
        vel = None if finger_dofs is None else _velocity_view(d, finger_dofs)
        triples = range(0, 0 if finger_dofs is None else len(finger_dofs), 3)  # (built once)
        qvel = d.qvel
        speed2 = self.tip_speed * self.tip_speed
        trace_every = self.keep_trace
        next_obs = observer.next_time()
        # the loop keeps its counters in locals (written back before anything that reads
        # them); the contact reading's phase is that of the execution's step count
        t, n = self.t, self.n
        until_read = CONTACT_EVERY - n % CONTACT_EVERY
        n_ctrl = len(ctrl)
        obs_at = next_obs - 1e-9
        # past the segment's end the fingertips hold its last target: a robot's driver gives
        # the rows that do (its arm comes to rest there); the free fingertips' last row does
        hold_row = getattr(sim.driver, "hold_row", None)
        while True:
            if i < n_ctrl:
                if rows is not None:
                    ctrl_out[:] = rows[at:at + width]
                    at += width
                else:
                    ctrl_view[...] = ctrl[i]
            elif hold_row is not None:
                ctrl_view[...] = hold_row()
            step(m, d)
            i += 1
            n += 1
            t += dt
            until_read -= 1
            if until_read == 0:
                until_read = CONTACT_EVERY
                pairs = log.observe(d, t)
                if transit_leg:
                    touch = judge.touches_finger(pairs)
                    if touch:
                        self.contact_reads += 1
                    if touch != self.touching:
                        self.touching = touch
                        self.touch_log.append((t, touch, sim.pose().com))
                if finger_dofs is not None:
                    v = (vel if vel is not None else qvel[finger_dofs]).tolist()
                    for k in triples:
                        x, y, z = v[k], v[k + 1], v[k + 2]
                        s2 = x * x + y * y + z * z
                        if s2 > speed2:
                            speed2 = s2
                            self.tip_speed = math.sqrt(s2)
            if trace_every and n % trace_every == 0:
                self.t, self.n = t, n
                self.trace.append(sim.trace_row(
                    t, seg[min(i - 1, len(seg) - 1)] if self.signals else None))
            if react is not None and t >= obs_at:
                self.t, self.n = t, n
                obs = observer.sample(t)
                next_obs = observer.next_time()
                obs_at = next_obs - 1e-9
                if obs is not None:
                    self.last_obs = obs
                    if see is not None:
                        see(obs.pose)
                    cur = seg[min(i, len(seg) - 1)]
                    self._cursor = (seg, i)
                    dec = react(obs, cur)
                    if dec.segment is not None:
                        new = limit_speed(self._crossfade(seg, i, dec.segment, dec.fade),
                                          dt, self.max_speed)
                        self.commanded[-1] = seg[:i]
                        self.commanded.append(new)
                        self.noise.cut(i)
                        seg, i = new, 0
                        ctrl = sim.driver.controls(self._noisy(seg))
                        n_ctrl = len(ctrl)
                        rows, width = _flat_rows(ctrl)
                        at = 0
                    if dec.done:
                        self._stop(seg, i)
                        return dec
            if react is not None:
                if t >= t_end:
                    self.t, self.n = t, n
                    self._stop(seg, i)
                    return Decision(done=True, outcome="aborted",
                                    reason=f"no decision within {max_time:g} s")
            elif i >= n_ctrl + n_extra:
                self.t, self.n = t, n
                self.command = seg[-1]
                self.noise.cut(i)
                return None

    def _stop(self, seg: FloatArray, i: int) -> None:
        """End a drive at sample ``i`` of ``seg``; the next drive fades out of its rest."""
        self.noise.cut(i)
        self.commanded[-1] = seg[:i]
        j = min(i, len(seg) - 1)
        self.command = seg[j]
        self._tail = seg[j:] if len(seg) - j > 1 else None
        self._tail_velocity = (seg[j] - seg[j - 1]) / self.dt if 1 <= j == i else None

    def velocity(self) -> FloatArray:
        """The commanded velocity (m/s, shape (n_fingers, 3)) at the current command: inside
        a ``react``, of the running targets; after a drive, of the one it stopped (zero at
        rest)."""
        seg, i = self._cursor
        if len(seg) > 1 and 1 <= i < len(seg):
            return np.asarray((seg[i] - seg[i - 1]) / self.dt)
        return np.zeros_like(self.command)

    def take_motion(self) -> tuple[FloatArray, FloatArray]:
        """The current command and its velocity, the stopped drive's rest dropped (what
        follows starts from there, moving)."""
        v = (self._tail_velocity if self._tail is not None and self._tail_velocity is not None
             else np.zeros_like(self.command))
        self._tail = self._tail_velocity = None
        return np.array(self.command), np.array(v)

    def count_recontacts(self) -> None:
        """Fill in the pending let-go records' ``recontacts``: how often a fingertip touched
        the object again after the let-go first separated, up to now (the end of the
        transit after it; the judge's contact, read every
        :data:`~nonprehensile.sim.judge.CONTACT_EVERY` steps in watched drives)."""
        for record, k, t0, sep in self.pending:
            if sep is not None:
                at = [round(t - t0, 4) for t, touch, _ in self.touch_log[k:]
                      if touch and t > sep]
                record["recontacts"] = len(at)
                record["recontacts_at_s"] = at
        self.pending.clear()

    def read_touch(self) -> bool:
        """Read the judge's fingertip-object contact now and log it (a let-go's start)."""
        touch = self.sim.judge.finger_object_contact(self.d)
        if touch != self.touching or not self.touch_log:
            self.touching = touch
            self.touch_log.append((self.t, touch, self.sim.pose().com))
        return touch

    def _crossfade(self, old: FloatArray, i: int, new: FloatArray,
                   fade: float | None = None) -> FloatArray:
        """``new`` with its first ``fade`` (default :data:`CROSSFADE`) seconds faded in from
        ``old``'s continuation (held at its end), so position and velocity stay
        continuous."""
        n = max(2, round((CROSSFADE if fade is None else fade) / self.dt))
        if len(new) < n:  # a short hold: long enough to fade into
            new = np.concatenate([new, np.repeat(new[-1:], n - len(new), axis=0)])
        rest = old[i:i + n]
        if len(rest) < n:
            rest = np.concatenate([rest, np.repeat(old[-1:], n - len(rest), axis=0)])
        s = np.linspace(0.0, 1.0, n)
        w = (s**3 * (10.0 - 15.0 * s + 6.0 * s**2))[:, None, None]
        out = np.array(new, dtype=np.float64)
        out[:n] = (1.0 - w) * rest + w * new[:n]
        return out

    def wait_observation(self, transit_leg: bool = False) -> Observation:
        """Hold the fingertips until an observation arrives (latency included); with
        ``transit_leg``, contact meanwhile counts as a transit's."""
        got: list[Observation] = []

        def react(obs: Observation, cmd: FloatArray) -> Decision:
            got.append(obs)
            return Decision(done=True)

        self.drive(np.array([self.command]), react=react, transit_leg=transit_leg,
                   max_time=5.0)
        if not got:
            # never the simulator's true pose in place of an observation: a controller that
            # sees nothing must not act on what a real one could not know (the observation
            # model's bounds, rate >= 1 Hz and latency <= 1 s, make this unreachable)
            model = self.observer.stream.model
            raise NonprehensileError(
                f"no observation arrived within 5 s at t={self.t:.3f} s; expected one every "
                f"1/{model.rate:g} s after {model.latency:g} s of latency")
        return got[-1]


def _pointed(mon: StepMonitor, point: Callable[[FloatArray | None], None]
             ) -> Callable[[Observation, FloatArray], Decision]:
    """``mon.update`` that also hands ``point`` the recorded finger directions where the
    reference is at each observation (:meth:`StepMonitor.pointing`)."""
    def react(obs: Observation, command: FloatArray) -> Decision:
        dec = mon.update(obs, command)
        point(mon.pointing(obs.time))
        return dec
    return react


def _flat_rows(ctrl: FloatArray) -> tuple[memoryview | None, int]:
    """The rows of ``ctrl`` (shape (n, nu)) as one flat memoryview of doubles, C order,
    and the row's length: row ``i`` is ``[i * nu:(i + 1) * nu]``. None for controls that
    are not an array (a robot's, solved as the loop reads them: every row must be read)."""
    if not isinstance(ctrl, np.ndarray):
        return None, 0
    flat = np.ascontiguousarray(ctrl, dtype=np.float64).reshape(-1)
    return flat.data, int(ctrl.shape[1])


def _velocity_view(d: Any, dofs: NDArray[np.int64]) -> FloatArray | None:
    """A view of ``d.qvel[dofs]`` (it reads the current velocities whenever it is read) when
    the dofs are consecutive, as the free fingertips' slide joints are; else None (the
    caller indexes ``d.qvel`` at each read)."""
    a = int(dofs[0]) if len(dofs) else 0
    if len(dofs) and np.array_equal(dofs, np.arange(a, a + len(dofs))):
        return np.asarray(d.qvel[a:a + len(dofs)])
    return None


def _retreat_target(sim: Simulator, pose: ObjectPose, command: FloatArray,
                    used: tuple[int, ...], clearance: float) -> FloatArray:
    """Where fingertips go to get out of the way: straight up above the object."""
    top = float(pose.to_world(sim.poly.vertices)[:, 2].max())
    out = np.array(command, dtype=np.float64)
    for k in used:
        out[k - 1, 2] = max(out[k - 1, 2], top + sim.params.finger_radius + 3 * clearance)
    return out


def _let_go(sim: Simulator, run: _Runner, cfg: ControlConfig, moving: NDArray[np.bool_], *,
            reach: float = LET_GO_REACH, until_still: bool = False, noise: float = 0.0,
            max_time: float = 1.0) -> tuple[dict[str, Any], Observation]:
    """Let go of the object (closed loop), at once: every moving fingertip observed within
    its radius plus :data:`LET_GO_CLEAR` of the observed object goes out along its contact
    normal (:func:`~nonprehensile.transit.escape`) to its radius plus ``reach``, aimed again
    whenever the object (still moving after an aborted step) comes nearer. It starts on the
    observation the last decision was made on, from the command as it moves (the stopped
    motion's rest is dropped), and leaves as fast as the bounds allow
    (:func:`~nonprehensile.transit.release`: ``cfg.max_speed`` and ``cfg.max_accel``). It
    ends once every moving fingertip is observed clear and at rest (and, with
    ``until_still``, the object has kept still for ``cfg.still_time``, ``noise`` being the
    observations' position noise), or after ``max_time`` s.

    This is where the previous motion's contact ends; the transit begins after it. Returns
    the record (see :func:`_let_go_record`) and the last observation.
    """
    poly, r = sim.poly, sim.params.finger_radius
    idx = np.flatnonzero(moving)
    window: list[tuple[float, FloatArray]] = []
    t0 = run.t
    mark = _let_go_mark(sim, run)
    start, v0 = run.take_motion()
    aim = start.copy()
    # a motion stopped while moving comes to rest where braking at the bound takes it
    speed = np.linalg.norm(v0, axis=1, keepdims=True)
    aim += v0 * speed / (2.0 * 0.8 * cfg.max_accel)
    obs = run.last_obs if run.last_obs is not None else run.wait_observation(
        transit_leg=True)
    last = [obs]

    def clear(o: Observation) -> bool:
        gap = hull_distance(poly, o.pose, o.tips[idx])
        return bool((gap >= r + LET_GO_CLEAR).all())

    def still(o: Observation) -> bool:
        window.append((o.time, o.pose.com.copy()))
        while len(window) > 2 and window[1][0] <= o.time - cfg.still_time:
            window.pop(0)
        if window[-1][0] - window[0][0] < cfg.still_time - 1e-9:
            return False
        coms = np.array([w[1] for w in window])
        spread = float(np.linalg.norm(coms - coms.mean(axis=0), axis=1).max())
        return spread <= cfg.still_tol + 3.0 * noise

    def reaim(o: Observation) -> bool:
        """Aim the fingertips that are near the observed object out along its normals."""
        gap = hull_distance(poly, o.pose, o.tips[idx])
        aimed = hull_distance(poly, o.pose, aim[idx])
        again = idx[(gap < r + LET_GO_CLEAR) & (aimed < r + reach - 0.001)]
        if len(again):
            # out of the plane of the face each pad touches, from its command (which a
            # compliant pad leaves deep in the object, and to the side where friction held
            # it): the shortest way for the command out of that plane, which frees the pad
            aim[again] = escape(poly, o.pose, aim[again], r + reach, faces_of=o.tips[again])
        return bool(len(again))

    def react(o: Observation, cur: FloatArray) -> Decision:
        last[:] = [o]
        is_still = still(o) if until_still else True
        # done once clear and at rest at its aim: the transit starts from rest (a transit
        # faded in from a moving command would leave its acceleration bound)
        if clear(o) and is_still and float(np.abs(cur - aim).max()) < 1e-9:
            return Decision(done=True, outcome="finished")
        if not reaim(o):
            return GO_ON
        # from the running command at its velocity: nothing to fade
        return Decision(segment=release(cur, run.velocity(), aim, dt=run.dt,
                                        max_speed=cfg.max_speed, max_accel=cfg.max_accel),
                        fade=0.0)

    if until_still:
        still(obs)
    reaim(obs)
    if float(np.abs(aim - start).max()) < 1e-12 and clear(obs) and not until_still:
        return _let_go_record(sim, run, t0, mark, "clear"), obs
    first = release(start, v0, aim, dt=run.dt, max_speed=cfg.max_speed,
                    max_accel=cfg.max_accel)
    dec = run.drive(first, react=react, transit_leg=True, max_time=max_time)
    if run._tail is not None and float(np.abs(run._tail - run.command).max()) < 1e-6:
        # at rest: nothing to fade out of (a fade from rest would delay the transit's start
        # and steepen its acceleration)
        run._tail = None
    outcome = "finished" if dec is not None and dec.outcome == "finished" else "timeout"
    return _let_go_record(sim, run, t0, mark, outcome), last[-1]


def _let_go_mark(sim: Simulator, run: _Runner) -> tuple[int, int, FloatArray]:
    """Where a let-go's records start: the contact log's length after reading the judge's
    contact now, the contact reads so far, and the object's centre of mass (the judge's
    truth, for the record only)."""
    run.read_touch()
    return len(run.touch_log) - 1, run.contact_reads, sim.pose().com


def _let_go_record(sim: Simulator, run: _Runner, t0: float,
                   mark: tuple[int, int, FloatArray], outcome: str) -> dict[str, Any]:
    """A let-go's record (the judge's readings): its seconds; the fingertip-object contact
    read while letting go (s); ``separated_s``, from its start to the first reading of no
    fingertip on the object (0 when none touched; None when it never let go), ``free_s``
    to the end of its last contact (None: still touching at its end); how far the
    object's centre of mass moved until then (``object_moved_in_contact_m``) and over the
    whole let-go (``object_moved_m``); how it ended. ``recontacts`` (and
    ``recontacts_at_s``, each one's start from the let-go's) is filled in when the transit
    after it ends (:meth:`_Runner.count_recontacts`)."""
    k, reads, com0 = mark
    log = run.touch_log[k:]
    sep = (t0, com0) if not log[0][1] else next(
        ((t, c) for t, touch, c in log if not touch), None)
    # off for good: the end of the let-go's last contact (a pad that bounced off an object
    # sliding ahead of it touches again while its command is still inside)
    free = None if log[-1][1] else max((t for t, touch, _ in log if not touch), default=t0)
    record: dict[str, Any] = {
        "seconds": round(run.t - t0, 4),
        "finger_object_contact_s": round((run.contact_reads - reads) * CONTACT_EVERY
                                         * run.dt, 4),
        "separated_s": None if sep is None else round(sep[0] - t0, 4),
        "free_s": None if free is None else round(free - t0, 4),
        "object_moved_in_contact_m": round(float(np.linalg.norm(
            (sep[1] if sep is not None else sim.pose().com) - com0)), 5),
        "object_moved_m": round(float(np.linalg.norm(sim.pose().com - com0)), 5),
        "recontacts": None, "recontacts_at_s": [],
        "outcome": outcome}
    run.pending.append((record, k, t0, None if sep is None else sep[0]))
    return record


def execute_plan(
    sim: Simulator,
    plan: Plan,
    *,
    fingers: Mapping[str, str] = DEFAULT_FINGERS,
    loop: Literal["closed", "open"] = "closed",
    replan: Replanner | None = None,
    config: ControlConfig | None = None,
    observation: ObservationModel | None = None,
    perturbation: Perturbation = NO_PERTURBATION,
    angle_tol: float = DEFAULT_ANGLE_TOL_DEG,
    position_tol: float = DEFAULT_POSITION_TOL,
    keep_trace: int = 0,
    signals: bool = False,
) -> Execution:
    """Execute ``plan`` in one continuous simulation (see the module's docstring).

    Parameters
    ----------
    sim : Simulator
        A scene with at least :func:`scene_fingers` fingertips.
    plan : Plan
        From :func:`nonprehensile.planning.plan`, with reference motions.
    fingers : mapping
        Finger name -> tip marker name of the references.
    loop : {"closed", "open"}
    replan : callable, optional
        ``replan(state, position, avoid) -> Plan`` from an observed state and position
        avoiding the named skills; without it a step that ends elsewhere fails the
        execution (closed loop).
    config : ControlConfig, optional
    observation : ObservationModel, optional
        The sensor (closed loop): rate, latency, noise; default a perfect one at 120 Hz.
        A perturbation's tracking noise, when not zero, sets its position noise.
    perturbation : Perturbation
        Where the object really starts (its start error), the tracker's noise and the
        fingertips' position error (a Gauss-Markov process per axis, as
        :func:`~nonprehensile.sim.distribution.finger_noise`), seeded by its noise seed.
    angle_tol, position_tol : float
        The goal's tolerances (degrees, m).
    keep_trace : int
        Keep a trace row every this many physics steps (for rendering, recording).
    signals : bool
        Trace rows carry the tracking error, contact forces and slip too
        (:func:`~nonprehensile.sim.run.signal_columns`).
    """
    wall0 = time.perf_counter()
    cfg = config or ControlConfig(angle_tol=angle_tol, position_tol=position_tol)
    # the model's angular step (from the re-planner's frame, every state of the model; else
    # the plan's own states): a turned object is turned back (``align_tol``) or snapped onto
    # a frame state only when that is the nearest state, within half the step
    step_deg = angular_step(list(getattr(replan, "frame", ())) or [
        x for s in plan.steps for x in (s.start_world, s.end_world)])
    cfg = cfg.for_step(step_deg)
    snap_tol = 180.0 if step_deg is None else step_deg / 2.0
    obs_model = observation or ObservationModel()
    if perturbation.tracking_noise > 0:
        obs_model = replace(obs_model, position_noise=perturbation.tracking_noise,
                            angle_noise_deg=None)
    if not plan.steps:
        raise ValueError("the plan has no step to execute")
    first = plan.steps[0]
    last = plan.steps[-1]
    assert first.start_pose is not None and last.end_pose is not None
    ex = Execution(loop, plan.goal, last.end_pose.position)
    p = sim.params
    run = _Runner(sim, obs_model, perturbation.rng("tracker"), perturbation.rng("finger"),
                  perturbation.finger_noise, keep_trace, signals, cfg.max_speed)
    m, d = sim.model, sim.data
    mujoco.mj_resetData(m, d)
    sim.set_pose(perturbation.start_pose(first.start_pose))
    see = getattr(sim.driver, "see", None)  # a robot's IK: the object's believed pose
    tumbling = getattr(sim.driver, "tumbling", None)  # a robot's IK: the rods' lean
    if see is not None:  # closed loop: planned until observed; open loop: nothing observed
        see(first.start_pose if loop == "closed" else None)
    # the fingertips start out of the way, above the object's start
    home = np.array(sim.park())
    c0 = first.start_pose.com
    top = float(first.start_pose.to_world(sim.poly.vertices)[:, 2].max())
    for k in range(sim.n_fingers):
        home[k] = [c0[0] + 0.03 * k, c0[1], top + p.finger_radius + 0.05]
    sim.driver.place(d, home)
    mujoco.mj_forward(m, d)
    run.command = home
    rest = home.copy()

    def do_transit(pose: ObjectPose, target: FloatArray, used: tuple[int, ...],
                   label: str) -> Observation | None:
        """The transit to ``target``; closed loop, it ends on the observation that what
        follows starts from (returned)."""
        moving = np.zeros(sim.n_fingers, dtype=bool)
        moving[[k - 1 for k in used]] = True
        # fingers the step does not use go home
        goal = np.where(moving[:, None], target, rest)
        moving |= np.linalg.norm(run.command - rest, axis=1) > 1e-9
        # a transit ends clear of the object: a reference recorded with a smaller fingertip
        # may begin within this one's radius; it stops short, out along the normal of the
        # face it approaches, and the step's first arc blends in from there (touching is the
        # step's business)
        need = p.finger_radius + 0.003
        near = np.flatnonzero(moving & (hull_distance(sim.poly, pose, goal) < need))
        goal[near] = escape(sim.poly, pose, goal[near], need)
        entry: dict[str, Any] = {"before": label}
        if loop == "closed":
            # the previous motion's contact ends first (the fingertips observed off the
            # object); the transit is planned on the object as observed then
            let_go, look = _let_go(sim, run, cfg, moving, noise=obs_model.position_noise)
            entry["let_go"] = let_go
            pose = look.pose
        else:
            # open loop nothing is observed: the fingertips let go along the predicted
            # object's normals from where they are commanded, by the same reach
            idx = np.flatnonzero(moving)
            start, v0 = run.take_motion()
            aim = np.array(start)
            aim[idx] = escape(sim.poly, pose, aim[idx], p.finger_radius + LET_GO_REACH)
            if float(np.abs(aim - start).max()) > 1e-9 or float(np.abs(v0).max()) > 0:
                t0, mark = run.t, _let_go_mark(sim, run)
                run.drive(release(start, v0, aim, dt=run.dt, max_speed=cfg.max_speed,
                                  max_accel=cfg.max_accel), transit_leg=True)
                entry["let_go"] = _let_go_record(sim, run, t0, mark, "finished")
        path = transit(sim.poly, pose, run.command, goal, dt=run.dt,
                       clearance=cfg.clearance, finger_radius=p.finger_radius,
                       max_speed=cfg.max_speed, max_accel=cfg.transit_bound,
                       moving=moving)
        before, t0, k0 = run.contact_reads, run.t, len(run.commanded)
        run.drive(path, transit_leg=True)
        # closed loop, held at its end until the observation that what follows starts from
        seen = run.wait_observation(transit_leg=True) if loop == "closed" else None
        run.count_recontacts()
        # on the execution's clock: the transit runs from ``start_s`` (the fingertips let
        # go) to ``end_s``, the first sample of what follows (a step's first arc, a push)
        segs = [c for c in run.commanded[k0:] if len(c)]
        v_max, a_max = limits_of(np.concatenate(segs), run.dt) if segs else (0.0, 0.0)
        entry.update({
            "start_s": round(t0, 4), "end_s": round(run.t, 4),
            "commanded_max_speed": round(v_max, 4), "commanded_max_accel": round(a_max, 3),
            "seconds": round(run.t - t0, 4),
            "length_m": round(float(np.linalg.norm(np.diff(path, axis=0), axis=2)
                                    .sum(axis=0).max()), 4),
            "finger_object_contact_s": round((run.contact_reads - before) * CONTACT_EVERY
                                             * run.dt, 4)})
        ex.transits.append(entry)
        return seen

    steps = list(plan.steps)
    avoid: frozenset[str] = frozenset()
    index = 0
    tries = 0
    slow = 1.0
    higher = False
    while index < len(steps):
        step = steps[index]
        spec = step_spec(sim.poly, step, fingers)
        if loop == "closed":  # a leaning face's roll from the top; a retry: the contact
            # higher on its face (or pressed deeper) ...
            spec = one_finger_push(spec, sim.poly, p.finger_radius, higher=higher)
        if slow != 1.0:  # ... and the reference played slower
            spec = replace(spec, rate=spec.rate / slow)
        if tumbling is not None:  # a pinch that tumbles the object: the rods lean further
            # out of the faces it tilts over them (a robot's IK; from the transit on)
            tumbling(len(spec.used) > 1
                     and step.start_world.face != step.end_world.face)
        number = len(ex.steps) + 1
        t_step = run.t
        n_events = len(run.log.events)
        record: dict[str, Any] = {
            "step": number, "skill": spec.skill,
            "source": step.transition.source.name,
            "demonstrated": step.transition.demonstrated,
            "from": step.start_world.to_dict(), "to": step.end_world.to_dict(),
            "predicted_position": [round(v, 6) for v in spec.end_pose.position]}
        if loop == "open":
            first_pts = np.array(rest)
            for j, k in enumerate(spec.used):
                first_pts[k - 1] = spec.arcs[0].positions[0, j]
            do_transit(spec.start_pose, first_pts, spec.used, f"step {number}")
            t_begin = run.t
            targets = np.repeat(rest[None], len(spec.arcs[0].positions), axis=0)
            ref = np.stack([spec.targets[k] for k in spec.used], axis=1)
            targets = np.repeat(rest[None], len(ref), axis=0)
            targets[:, [k - 1 for k in spec.used]] = ref
            # faded in from rest as the closed loop's first arc is
            run.drive(run._crossfade(np.array([run.command]), 0,
                                     resample(targets, spec.rate, run.dt)))
            j, settled = sim.settle(p.settle, run.log, run.t, keep_trace, run.trace,
                                    run.command if signals else None)
            run.t += j * run.dt
            run.n += j
            record.update(outcome="finished" if settled else "unsettled", reason="",
                          observed=[])
            observed_end: State | None = sim.state()
        else:
            obs = run.wait_observation()
            # the approach's first point, anchored on the object as observed
            tf = anchor_transform(sim.poly, spec.arcs[0].anchor, spec.start_pose, obs.pose)
            first_pts = np.array(rest)
            for j, k in enumerate(spec.used):
                first_pts[k - 1] = tf.apply(spec.arcs[0].positions[0, j])
            seen = do_transit(obs.pose, first_pts, spec.used, f"step {number}")
            assert seen is not None
            obs = seen
            mon = StepMonitor(sim.poly, spec, cfg, dt=run.dt, finger_radius=p.finger_radius,
                              rest=rest, noise=obs_model.position_noise)
            t_begin = run.t
            record["arc_start_s"] = round(t_begin, 4)  # the transit ended here
            dec = mon.begin(obs, run.command)
            assert dec.segment is not None
            budget = mon.expected_duration + 3.0 * cfg.grace + cfg.max_settle + 2.0
            react: Callable[[Observation, FloatArray], Decision] = mon.update
            # a robot's finger tools point as the recorded fingers: the directions are
            # read at every observation only for a driver that follows them
            point = (getattr(sim.driver, "point", None)
                     if getattr(sim.driver, "finger_direction", None) == "recorded" else None)
            if point is not None:
                point(mon.pointing(obs.time))
                react = _pointed(mon, point)
            try:
                end = run.drive(run._crossfade(np.array([run.command]), 0, dec.segment),
                                react=react, max_time=budget)
            finally:  # the recovery, the transits, a next run: the driver's own rule
                if point is not None:
                    point(None)
            reason = end.reason if end is not None else ""
            aborted = end is not None and end.outcome == "aborted"
            if aborted:
                # let go (out along the contact normals from where the pads are observed,
                # fleeing the object while it still moves), watch it come to rest, the
                # fingertips held clear of it, then move away as a transit
                record["let_go"] = _release(sim, run, cfg, mon, spec.used, do_transit,
                                            f"recovery after step {number}", aborted=True,
                                            noise=obs_model.position_noise)
            record.update(outcome=end.outcome if end is not None else "", reason=reason,
                          observed=mon.log)
            observed_end = mon.final_state
            if observed_end is None and not aborted:
                # at rest on no face with the fingers still on it (leaning on a pad, held
                # on an edge): let go, move clear and look again; only an object that rests
                # on no face once free fails the step
                _release(sim, run, cfg, mon, spec.used, do_transit,
                         f"let go after step {number}", aborted=False,
                         noise=obs_model.position_noise)
                observed_end = mon.final_state
                record["looked_again"] = observed_end.to_dict() if observed_end else None
        truth = sim.state()
        record["simulated_events"] = [
            {"time": round(e.time - t_step, 4),
             "contacts": [str(q) for q in e.event.ordered_pairs]}
            for e in run.log.events[n_events:]]
        record["simulated"] = truth.to_dict() if truth else None
        record["observed_state"] = observed_end.to_dict() if observed_end else None
        pos_err = math.dist(sim.pose().position, spec.end_pose.position)
        record["position_error_m"] = round(pos_err, 5)
        record["theta_error_deg"] = (round(angle_diff(truth.theta, spec.end_state.theta), 3)
                                     if truth is not None and truth.face == spec.end_state.face
                                     else None)
        record["success"] = bool(truth is not None and truth.face == spec.end_state.face
                                 and abs(angle_diff(truth.theta, spec.end_state.theta))
                                 <= cfg.angle_tol)
        record["sim_seconds"] = round(run.t - t_step, 4)
        ex.steps.append(record)
        ex.step_traces.append((number, t_step, run.t))
        if keep_trace:
            ex.executed.append((step, _outcome(sim, run, step, spec, record, t_begin,
                                               n_events, cfg)))
        if loop == "open":
            index += 1
            continue
        nxt = after_step(spec, record["reason"], observed_end, plan.goal,
                         replans=len(ex.replans), avoid=avoid,
                         last=index == len(steps) - 1, config=cfg, tries=tries)
        if nxt.action == "align":
            # the predicted face, turned: turned back by pushes off the centre line (toward
            # where the plan predicted the object), then on; a re-plan if that falls short
            assert nxt.target is not None
            target = nxt.target
            _align(sim, run, ex, cfg, rest, do_transit, target.theta,
                   spec.end_pose.position if target != plan.goal
                   else ex.goal_position)
            look = run.wait_observation()
            now = observed_state(sim.poly, look.pose.rotation)
            mon.final_pose = look.pose
            record["aligned"] = {"target": target.to_dict(),
                                 "observed": now.to_dict() if now else None}
            if same_state(now, target, cfg.angle_tol):
                nxt = NextAction("done" if target == plan.goal or index == len(steps) - 1
                                 else "next", nxt.reason + ": turned onto it")
            else:
                observed_end = now
                nxt = after_step(spec, record["reason"] or nxt.reason + ", the turn fell short",
                                 observed_end, plan.goal, replans=len(ex.replans),
                                 avoid=avoid, last=index == len(steps) - 1,
                                 config=replace(cfg, align_tol=0.0), tries=tries)
        record["next"] = nxt.action
        if nxt.action != "retry":
            tries, slow, higher = 0, 1.0, False
        if nxt.action == "replan" and replan is None:
            ex.reason = f"step {number} ({spec.skill}): {nxt.reason} (no re-planner given)"
            break
        if nxt.action == "next":
            index += 1
        elif nxt.action == "retry":
            tries += 1
            slow, higher = nxt.slow, nxt.higher
            ex.replans.append({"after_step": number, "retry": True, "reason": nxt.reason,
                               "slower": round(slow, 3), "higher": higher,
                               "steps": [f"{spec.skill}: {step.start_world} -> "
                                         f"{step.end_world}"]})
        elif nxt.action == "done":
            break
        elif nxt.action == "fail" or replan is None:
            ex.reason = f"step {number} ({spec.skill}): {nxt.reason}"
            break
        else:
            assert observed_end is not None
            avoid = nxt.avoid
            # in the goal's frame: turned onto the nearest of its states on the observed
            # face when it is off by more than the tolerance (a re-plan keeps the agent's
            # frame, so a turned object would miss the goal's theta), then snapped to it;
            # the plan's own states, and every state of the model turned into the goal's
            # frame when the re-planner knows them (an object that tumbled onto a face
            # the plan never visits, turned, is still put back in the frame)
            frame = [x for s in steps for x in (s.start_world, s.end_world)]
            frame += getattr(replan, "frame", ())
            near = snap_state(observed_end, frame, snap_tol)
            turned_onto = None
            if near is not observed_end and abs(angle_diff(
                    observed_end.theta, near.theta)) > cfg.angle_tol / 2:
                turned_onto = near.to_dict()
                # the turn's pushes also move the object toward the goal's position (they
                # pick the side face whose push does most for it)
                _align(sim, run, ex, cfg, rest, do_transit, near.theta, ex.goal_position)
                look = run.wait_observation()
                observed_end = observed_state(sim.poly, look.pose.rotation) or observed_end
                mon.final_pose = look.pose
            observed_end = snap_state(observed_end, frame, cfg.angle_tol)
            here = (mon.final_pose if mon.final_pose is not None
                    else run.wait_observation().pose).position
            entry: dict[str, Any] = {"after_step": number, "reason": nxt.reason,
                                     "from": observed_end.to_dict(),
                                     "position": [round(v, 6) for v in here],
                                     "avoid": sorted(avoid)}
            if turned_onto is not None:  # turned back into the goal's frame first
                entry["turned_onto"] = turned_onto
            try:
                new_plan = replan(observed_end, here, avoid)
            except Exception as exc:  # no plan: reported, never continued
                entry["error"] = str(exc)
                ex.replans.append(entry)
                ex.reason = f"re-plan after step {number} failed: {exc}"
                break
            entry["steps"] = [f"{s.transition.skill.name}: {s.start_world} -> {s.end_world}"
                              for s in new_plan.steps]
            ex.replans.append(entry)
            if not new_plan.steps:
                break
            steps = list(new_plan.steps)
            index = 0
    if tumbling is not None:
        tumbling(False)
    # at the end: slide the object onto the goal position if it rests off it
    if loop == "closed" and not ex.reason and cfg.correct_position:
        for _ in range(3):  # sliding may turn it a little (on a grippy table, 5-8 deg):
            _align(sim, run, ex, cfg, rest, do_transit, plan.goal.theta, ex.goal_position)
            _correct(sim, run, ex, cfg, rest, do_transit)
            # look again: the round is over once the slides left theta within half the
            # tolerance
            err = _yaw_error(sim.poly, run.wait_observation().pose, plan.goal.theta)
            if err is None or abs(err) <= cfg.angle_tol / 2:
                break
    # park the fingers and let everything come to rest before the verdict
    if loop == "closed":
        pose_now = run.wait_observation().pose
        up = _retreat_target(sim, pose_now, run.command, tuple(range(1, sim.n_fingers + 1)),
                             cfg.clearance)
        do_transit(pose_now, up, tuple(range(1, sim.n_fingers + 1)), "end")
    j, _ = sim.settle(p.settle, run.log, run.t)
    run.t += j * run.dt
    run.n += j
    truth = sim.state()
    pose = sim.pose()
    ex.final_state, ex.final_pose = truth, pose
    ex.position_error = math.dist(pose.position, ex.goal_position)
    if truth is not None and truth.face == plan.goal.face:
        ex.theta_error = angle_diff(truth.theta, plan.goal.theta)
    ex.success = bool(truth is not None and truth.face == plan.goal.face
                      and ex.theta_error is not None and abs(ex.theta_error) <= cfg.angle_tol
                      and ex.position_error <= cfg.position_tol)
    if not ex.success and not ex.reason:
        ex.reason = (f"ended in {truth}" if truth is not None else "rests on no face") + (
            f", {1000 * ex.position_error:.1f} mm from the goal position")
    cmd = [c for c in run.commanded if len(c)]
    allcmd = np.concatenate(cmd) if cmd else np.zeros((0, sim.n_fingers, 3))
    ex.commanded_speed, ex.commanded_accel = limits_of(allcmd, run.dt)
    # measured from the free fingertips' joint velocities; a robot's driver has none, and
    # its tips' speed is then not measured (None, never a 0.0 that reads like a pass)
    ex.tip_speed = run.tip_speed if getattr(sim.driver, "dadr", None) is not None else None
    ex.transit_contact_s = sum(t["finger_object_contact_s"] for t in ex.transits)
    ex.transit_accel = max((t["commanded_max_accel"] for t in ex.transits), default=0.0)
    run.count_recontacts()
    let_gos = [t["let_go"] for t in [*ex.transits, *ex.steps, *ex.corrections]
               if t.get("let_go") is not None]
    ex.let_go_contact_s = sum(g["finger_object_contact_s"] for g in let_gos)
    ex.let_go_separation_s = max(
        (math.inf if g["separated_s"] is None else g["separated_s"] for g in let_gos),
        default=0.0)
    ex.let_go_recontacts = sum(g["recontacts"] or 0 for g in let_gos)
    ex.let_go_object_moved = max((g["object_moved_in_contact_m"] for g in let_gos),
                                 default=0.0)
    ex.finger_table = run.log.finger_table
    ex.sim_time, ex.n_steps = run.t, run.n
    ex.wall_time = time.perf_counter() - wall0
    ex.trace = np.array(run.trace) if run.trace else None
    return ex


def _release(sim: Simulator, run: _Runner, cfg: ControlConfig, mon: StepMonitor,
             used: tuple[int, ...], do_transit: Callable[..., Observation | None], label: str,
             *, aborted: bool, noise: float) -> dict[str, Any] | None:
    """Free the object after a step and read its state at rest (``mon.final_state``).

    After an aborted step (the object may still move: sliding, falling back) the fingertips
    let go at once (:func:`_let_go`, out to the clearance), are held clear while the object
    comes to rest and its state is read, and then rise away as a transit (``label``).
    Otherwise (a step that ended at rest on no face, a pad still holding it) they rise away
    first, the transit letting go, and the state is read after. The holds count as the
    let-go's (their contact is a re-contact). Returns the aborted step's let-go record.
    """
    let_go = None
    if aborted:
        moving = np.zeros(sim.n_fingers, dtype=bool)
        moving[[k - 1 for k in used]] = True
        let_go, _ = _let_go(sim, run, cfg, moving, reach=cfg.clearance, until_still=True,
                            noise=noise, max_time=cfg.max_settle + 0.5)
        _watch_rest(run, cfg, mon)
    pose_now = run.wait_observation(transit_leg=True).pose
    up = _retreat_target(sim, pose_now, run.command, used, cfg.clearance)
    do_transit(pose_now, up, used, label)
    if not aborted:
        _watch_rest(run, cfg, mon)
    return let_go


def _watch_rest(run: _Runner, cfg: ControlConfig, mon: StepMonitor) -> None:
    """Hold the fingertips until ``mon`` reads the object's state at rest (or a timeout)."""
    mon.watch_rest(run.t)
    run.drive(np.array([run.command]), react=mon.update, transit_leg=True,
              max_time=cfg.max_settle + 0.5)


def _correct(sim: Simulator, run: _Runner, ex: Execution, cfg: ControlConfig,
             rest: FloatArray, do_transit: Callable[..., Observation | None]) -> None:
    """Slide the object onto the goal position by pushes low on its side faces, each run
    until the observed object has moved as far as asked (or a timeout)."""
    p = sim.params
    for _ in range(cfg.max_corrections):
        obs = run.wait_observation()
        st = observed_state(sim.poly, obs.pose.rotation)
        if st is None or st.face != ex.goal.face:
            return
        pushes = correction_pushes(sim.poly, obs.pose, ex.goal_position,
                                   finger_radius=p.finger_radius, clearance=cfg.clearance,
                                   tol=cfg.correction_tol)
        if not pushes:
            return
        push = max(pushes, key=lambda q: q.distance)  # the largest part first
        k, seen = _to_push(sim, push, rest, do_transit, obs.pose, "correction")
        obs = seen if seen is not None else run.wait_observation()
        origin = obs.pose.com[:2].copy()
        entry = {"kind": "slide", "finger": k, **push.to_dict()}

        def react(o: Observation, cmd: FloatArray, origin: FloatArray = origin,
                  push: Any = push) -> Decision:
            if observed_state(sim.poly, o.pose.rotation, tilt_deg=8.0) is None:
                # tilting (pushed too high for this table): stop before it tips over (8
                # degrees: well above the tracker's noise, far below a prism's 30-degree
                # balance point)
                return Decision(done=True, outcome="aborted", reason="tilted")
            # (``a.dot(b)``: the same BLAS dot as ``a @ b``, without the matmul ufunc's
            # dispatch: asked at every observation)
            moved = float((o.pose.com[:2] - origin).dot(push.direction[:2]))
            if moved >= push.distance - 0.0005:
                return Decision(done=True, outcome="finished")
            return GO_ON

        dec, let_go, obs = _push(sim, run, cfg, push, 0.03,
                                 push.distance + p.finger_radius + cfg.clearance + 0.015,
                                 react, finger=k)
        entry["let_go"] = let_go
        entry["moved_m"] = round(float((obs.pose.com[:2] - origin) @ push.direction[:2]), 5)
        entry["outcome"] = dec.outcome if dec is not None else ""
        entry["error_after_m"] = round(math.dist(obs.pose.com[:2], ex.goal_position), 5)
        ex.corrections.append(entry)


def _push(sim: Simulator, run: _Runner, cfg: ControlConfig, push: Any, speed: float,
          length: float, react: Callable[[Observation, FloatArray], Decision],
          finger: int = 1) -> tuple[Decision | None, dict[str, Any], Observation]:
    """Drive ``finger`` (1-based) ``length`` (m) along ``push.direction`` from ``push.start``
    at ``speed`` (m/s; with ``cfg.push_approach``, faster across the clearance before the
    face: :func:`~nonprehensile.transit.guarded_push`) until ``react`` says done (or a
    timeout), and let go
    (:func:`_let_go`, held clear until the object is still); returns the decision, the
    let-go's record and the last observation.

    The slide and turn corrections differ only in their speeds, lengths and stopping rules.
    """
    # with ``push_approach``, across the clearance to the face quickly (a guarded move: at
    # its own speed through the cross-fade from rest, which a speed change would overshoot;
    # slow again PUSH_MARGIN before the face as observed); without (None or 0), the
    # constant-speed push, which ``guarded_push`` gives when there is nothing to speed up to
    s = guarded_push(length, max(cfg.clearance - PUSH_MARGIN, 0.0), speed, dt=run.dt,
                     fast=cfg.push_approach or 0.0, accel=min(PUSH_ACCEL, cfg.max_accel),
                     hold=CROSSFADE)
    n = len(s)
    # (the constant-speed push's timeout as it always was: the same records)
    max_time = n * run.dt + 0.5 if cfg.push_approach else length / speed + 0.5
    path = np.repeat(run.command[None], n, axis=0)
    path[:, finger - 1] = push.start[None] + s[:, None] * push.direction[None]
    dec = run.drive(run._crossfade(np.array([run.command]), 0, path), react=react,
                    max_time=max_time)
    moving = np.zeros(sim.n_fingers, dtype=bool)
    moving[finger - 1] = True
    # held clear until the object, which may slide on after the push, is still: what
    # follows is decided on the object at rest
    let_go, obs = _let_go(sim, run, cfg, moving, until_still=True,
                          noise=run.observer.stream.model.position_noise,
                          max_time=cfg.max_settle + 0.5)
    return dec, let_go, obs


def _to_push(sim: Simulator, push: Any, rest: FloatArray,
             do_transit: Callable[..., Observation | None], pose: ObjectPose,
             label: str) -> tuple[int, Observation | None]:
    """Pick the finger that runs a correction ``push`` (the one whose arm stands behind it,
    :func:`~nonprehensile.control.push_finger`) and transit it to the push's start, the
    other fingertips to their rest (``rest``, shape (n_fingers, 3)); returns the finger
    (1-based) and the transit's last observation (None if it made none)."""
    k = push_finger(push.start, push.direction, _finger_origins(sim))
    target = np.array(rest)
    target[k - 1] = push.start
    return k, do_transit(pose, target, (k,), label)


def _finger_origins(sim: Simulator) -> list[tuple[float, float]] | None:
    """Where each finger comes from (x, y, m), when the driver says (a robot arm's base:
    :attr:`~nonprehensile.sim.robot_driver.RobotArms.finger_origins`); None for free
    fingertips."""
    got = getattr(sim.driver, "finger_origins", None)
    return None if got is None else list(got)


def _yaw_error(poly: Any, pose: ObjectPose, theta: float) -> float | None:
    """Observed theta minus ``theta`` (degrees), or None when it rests on no face."""
    st = observed_state(poly, pose.rotation)
    return None if st is None else angle_diff(st.theta, theta)


def _align(sim: Simulator, run: _Runner, ex: Execution, cfg: ControlConfig,
           rest: FloatArray, do_transit: Callable[..., Observation | None], theta: float,
           toward: tuple[float, float], tol_deg: float = 1.5) -> None:
    """Turn the object about the vertical onto ``theta`` by pushes off its centre line
    (:func:`~nonprehensile.control.turn_push`), each run until the observed turn is done."""
    p = sim.params
    for _ in range(3):
        obs = run.wait_observation()
        err0 = _yaw_error(sim.poly, obs.pose, theta)
        if err0 is None or abs(err0) <= tol_deg:
            return
        push = turn_push(sim.poly, obs.pose, -err0, toward, finger_radius=p.finger_radius,
                         clearance=cfg.clearance)
        if push is None:
            return
        k, _ = _to_push(sim, push, rest, do_transit, obs.pose, "turn")

        def react(o: Observation, cmd: FloatArray, err0: float = err0) -> Decision:
            e = _yaw_error(sim.poly, o.pose, theta)
            if e is None:
                return Decision(done=True, outcome="aborted", reason="tilted")
            if abs(e) <= 0.3 or e * err0 < 0:
                return Decision(done=True, outcome="finished")
            return GO_ON

        dec, let_go, obs = _push(sim, run, cfg, push, 0.02,
                                 p.finger_radius + cfg.clearance + 0.03, react, finger=k)
        after = _yaw_error(sim.poly, obs.pose, theta)
        ex.corrections.append({"kind": "turn", "finger": k, **push.to_dict(),
                               "theta_error_before_deg": round(err0, 3),
                               "theta_error_after_deg": None if after is None
                               else round(after, 3),
                               "outcome": dec.outcome if dec is not None else "",
                               "let_go": let_go})


def transition_record(ex: Execution, step: PlanStep) -> dict[str, Any]:
    """One transition executed as a one-step plan, as a record of ``simulate infer``: the
    verdict, the comparison's keys (``chain_ok``: every skill event observed in order on
    the first attempt) and the execution in full."""
    events = [e["event"] for e in (ex.steps[0]["observed"] if ex.steps else [])
              if "event" in e]
    want = [e.id for e in step.transition.skill.events][1:]
    it = iter(events)
    missing = [w for w in want if w not in it]
    return {
        "success": ex.success, "skill": step.transition.skill.name,
        "source": step.transition.source.name, "demonstrated": step.transition.demonstrated,
        "from": step.start_world.to_dict(), "to": step.end_world.to_dict(),
        "predicted": step.end_world.to_dict(),
        "simulated": ex.final_state.to_dict() if ex.final_state else None,
        "theta_error_deg": None if ex.theta_error is None else round(ex.theta_error, 3),
        "position_error_m": (None if ex.position_error is None
                             else round(ex.position_error, 5)),
        "chain_ok": not missing, "missing_events": missing,
        "simulation": {"wall_seconds": round(ex.wall_time, 4),
                       "sim_seconds": round(ex.sim_time, 4)},
        "execution": ex.to_dict(),
    }


def _outcome(sim: Simulator, run: _Runner, step: PlanStep, spec: Any, record: dict[str, Any],
             t_begin: float, n_events: int, cfg: ControlConfig) -> Outcome:
    """One executed step as the open-loop executor's :class:`Outcome` (trace and events
    from the step's first arc, times from there; the judge's comparison)."""
    rows = np.array([r for r in run.trace if t_begin - 1e-9 <= r[0] <= run.t + 1e-9])
    if len(rows):
        rows[:, 0] -= t_begin
    before = [e for e in run.log.events if e.time < t_begin - 1e-9]
    # the contact set the step began in (the object at rest: its first event), then the rest
    events = tuple([SimEvent(0.0, before[-1].event)] if before else []) + tuple(
        SimEvent(e.time - t_begin, e.event) for e in run.log.events[n_events:]
        if e.time >= t_begin - 1e-9)
    res = SimResult(sim.pose(), sim.state(), events, record["outcome"] == "finished",
                    run.t - t_begin, 0.0, round((run.t - t_begin) / run.dt),
                    run.log.finger_table, rows if len(rows) else None)
    cmp = compare(sim.poly, step.transition.skill, res, predicted=step.end_world,
                  predicted_pose=step.end_pose, event_times=spec.event_times,
                  angle_tol=cfg.angle_tol, position_tol=cfg.position_tol)
    label = {k: record[k] for k in ("step", "skill", "source", "demonstrated", "from", "to")}
    return Outcome(label, res, cmp)
