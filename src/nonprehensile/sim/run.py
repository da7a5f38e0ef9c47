"""Run fingertips along reference trajectories in MuJoCo and read back what happened.

:class:`Simulator` holds a compiled scene, its finger driver (:mod:`nonprehensile.sim.driver`)
and its judge (:mod:`nonprehensile.sim.judge`); :meth:`Simulator.run` places the object,
drives the fingertips open loop through pre-interpolated targets with ``mj_step`` in a tight
loop, lets the judge read the contacts every few steps, lets the object settle and returns a
:class:`SimResult`: the final pose, the final state
(:func:`~nonprehensile.states.state_of_pose`), and the debounced contact events as the
project's own :class:`~nonprehensile.skills.contacts.ContactEvent` values. The closed loop is
:mod:`nonprehensile.sim.closed_loop`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.geometry.units import UNIT_METRES
from nonprehensile.planning import ObjectPose
from nonprehensile.sim.driver import FingerDriver, FreeFingertips
from nonprehensile.sim.judge import (
    CONTACT_EVERY,
    REST_TILT_DEG,
    STILL_TIME,
    EventLog,
    Judge,
    SimEvent,
)
from nonprehensile.sim.scene import DEFAULT_PARAMS, SimParams, scene_xml
from nonprehensile.states import State, state_pose

__all__ = [
    "SimEvent",
    "SimResult",
    "Simulator",
    "control_columns",
    "default_scale",
    "pose_of_state",
    "signal_columns",
]

FloatArray = NDArray[np.float64]


def default_scale(poly: Polyhedron) -> float:
    """Metres per model unit from the model's ``units``."""
    try:
        return UNIT_METRES[poly.units]
    except KeyError:
        raise InputError(
            f"model {poly.name!r} has units {poly.units!r}; the simulation knows "
            f"{sorted(UNIT_METRES)}: give the scale (metres per model unit) explicitly"
        ) from None


def signal_columns(n_fingers: int) -> dict[str, slice]:
    """Where a trace kept with ``signals=True`` (:meth:`Simulator.run`) holds them:
    ``"error"`` (m) and ``"force"`` (N), one column per finger, and ``"slip"`` (m/s)."""
    first = 8 + 3 * n_fingers
    return {"error": slice(first, first + n_fingers),
            "force": slice(first + n_fingers, first + 2 * n_fingers),
            "slip": slice(first + 2 * n_fingers, first + 2 * n_fingers + 1)}


def control_columns(nu: int) -> slice:
    """Where a trace row (:meth:`Simulator.trace_row`) holds the actuators' set points: its
    last ``nu`` (``model.nu``) columns."""
    return slice(-nu, None)


def pose_of_state(poly: Polyhedron, state: State, position: Sequence[float] = (0.0, 0.0),
                  scale: float = 1.0) -> ObjectPose:
    """The pose of a resting state with its centre of mass above ``position`` (metres)."""
    r, t = state_pose(poly, state)
    tw = scale * t + np.array([float(position[0]), float(position[1]), 0.0])
    return ObjectPose(r, tw, scale * (r @ poly.com) + tw, scale)


@dataclass(frozen=True)
class SimResult:
    """What one simulated motion produced.

    Attributes
    ----------
    final_pose : ObjectPose
        The object's pose after settling.
    final_state : State or None
        The state it rests in, or None if it rests on no face of the model (still moving, or
        on an edge held by nothing).
    events : tuple of SimEvent
        Debounced contact events, in time order.
    settled : bool
        Whether the object came to rest within ``SimParams.settle``.
    sim_time : float
        Simulated seconds (motion and settling).
    wall_time : float
        Wall-clock seconds spent (building the targets and stepping).
    n_steps : int
        Physics steps taken.
    finger_table_contact : bool
        Whether a fingertip touched the table.
    """

    final_pose: ObjectPose
    final_state: State | None
    events: tuple[SimEvent, ...]
    settled: bool
    sim_time: float
    wall_time: float
    n_steps: int
    finger_table_contact: bool = False
    trace: FloatArray | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "final_state": self.final_state.to_dict() if self.final_state is not None else None,
            "final_position": [round(v, 6) for v in self.final_pose.position],
            "final_pose": self.final_pose.to_dict(),
            "events": [e.to_dict() for e in self.events],
            "settled": self.settled,
            "sim_seconds": round(self.sim_time, 4),
            "wall_seconds": round(self.wall_time, 4),
            "steps": self.n_steps,
            "finger_table_contact": self.finger_table_contact,
        }


class Simulator:
    """A compiled MuJoCo scene of one object and ``n_fingers`` fingertips.

    The simulation is split in two: the **driver** moves the fingertips
    (:class:`~nonprehensile.sim.driver.FreeFingertips` here; any
    :class:`~nonprehensile.sim.driver.FingerDriver`), the **judge**
    (:class:`~nonprehensile.sim.judge.Judge`) reads contacts, settling and the resting state,
    the same way whatever the driver.

    Parameters
    ----------
    poly : Polyhedron
        A convex object model.
    scale : float, optional
        Metres per model unit; default from the model's ``units``.
    n_fingers : int
        Fingertips ``R1 .. Rn``.
    params : SimParams
    """

    def __init__(self, poly: Polyhedron, *, scale: float | None = None, n_fingers: int = 2,
                 params: SimParams = DEFAULT_PARAMS) -> None:
        if isinstance(n_fingers, bool) or not isinstance(n_fingers, int) or not \
                1 <= n_fingers <= 10:
            raise InputError(f"n_fingers must be a whole number in 1..10, got {n_fingers!r}")
        self.poly = poly
        self.scale = float(scale) if scale is not None else default_scale(poly)
        self.n_fingers = n_fingers
        self.params = params
        self.xml = scene_xml(poly, scale=self.scale, n_fingers=n_fingers, params=params)
        try:
            self.model = mujoco.MjModel.from_xml_string(self.xml)
        except ValueError as exc:  # MuJoCo's compiler refuses the mesh
            raise InputError(f"MuJoCo cannot build a scene of {poly.name!r}: {exc}") from None
        self.data = mujoco.MjData(self.model)
        self.driver: FingerDriver = FreeFingertips(self.model, n_fingers)
        self.judge = Judge(poly, self.scale, params, self.model, n_fingers)
        # kept for the renderer and the executors
        self._body = self.judge.body
        self._qadr = self.judge.qadr
        self._dadr = self.judge.dadr
        self._finger_qadr = self.driver.qpos_indices()

    # ------------------------------------------------------------------------ state access
    def pose(self) -> ObjectPose:
        """The object's current pose."""
        return self.judge.pose(self.data)

    def set_pose(self, pose: ObjectPose) -> None:
        """Put the object at ``pose`` (at rest)."""
        q = np.empty(4)
        mujoco.mju_mat2Quat(q, np.ascontiguousarray(pose.rotation, dtype=np.float64).ravel())
        self.data.qpos[self._qadr:self._qadr + 3] = pose.translation
        self.data.qpos[self._qadr + 3:self._qadr + 7] = q
        self.data.qvel[:] = 0.0

    def state(self, tol_deg: float = REST_TILT_DEG) -> State | None:
        """The state the object rests in now, or None."""
        return self.judge.state(self.data, tol_deg)

    def park(self) -> FloatArray:
        """Where fingers not in use wait, far above the table, shape (n_fingers, 3)."""
        park = self.scale * self.poly.diameter * 3.0 + 0.05
        return np.array([[park * k, park, park] for k in range(1, self.n_fingers + 1)])

    def trace_row(self, now: float, target: FloatArray | None = None) -> FloatArray:
        """``[t, x, y, z, qw, qx, qy, qz, finger qpos ...]`` now (see :meth:`run`); given
        the fingertips' commanded ``target`` (shape (n_fingers, 3)), followed by the signals
        of :func:`signal_columns`; last, the actuators' set points (``data.ctrl``, the
        ``model.nu`` columns of :func:`control_columns`: what a recorded execution's action
        is)."""
        d = self.data
        row = np.concatenate(([now], d.qpos[self._qadr:self._qadr + 7],
                              d.qpos[self._finger_qadr]))
        if target is None:
            return np.concatenate((row, d.ctrl))
        error = np.linalg.norm(self.driver.tips(d) - target, axis=1)
        force, slip = self.judge.forces_and_slip(d, self.n_fingers)
        return np.concatenate((row, error, force, [slip], d.ctrl))

    def check_targets(self, targets: Mapping[int, FloatArray], rate: float) -> int:
        """Validate fingertip targets (see :meth:`run`); returns their number of frames."""
        if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
            raise InputError(f"the trajectory rate must be a finite positive number of Hz, "
                             f"got {rate!r}")
        lengths = set()
        for k, tr in targets.items():
            if k not in range(1, self.n_fingers + 1):
                raise InputError(f"finger R{k} is not in the scene (R1..R{self.n_fingers})")
            arr = np.asarray(tr, dtype=float)
            if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) < 2:
                raise InputError(f"the trajectory of R{k} must have shape (n_frames >= 2, 3), "
                                 f"got {arr.shape}")
            if not np.isfinite(arr).all():
                bad = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
                raise InputError(f"the trajectory of R{k} has NaN or infinite values (first at "
                                 f"frame {bad}); fill the gaps before simulating")
            if np.abs(arr).max() > 100.0:
                raise InputError(f"the trajectory of R{k} goes {np.abs(arr).max():.3g} m from "
                                 "the origin: give it in metres")
            lengths.add(len(arr))
        if len(lengths) > 1:
            raise InputError(f"the fingers' trajectories differ in length: {sorted(lengths)}")
        return lengths.pop() if lengths else 2

    def resample(self, targets: Mapping[int, FloatArray], rate: float, n_frames: int,
                 rest: FloatArray | None = None) -> FloatArray:
        """Targets interpolated to the physics step, shape (n_steps + 1, n_fingers, 3);
        fingers not given stay at ``rest`` (default :meth:`park`)."""
        p = self.params
        duration = (n_frames - 1) / rate
        n_move = max(1, round(duration / p.timestep))
        t_move = np.arange(n_move + 1) * p.timestep
        t_ref = np.arange(n_frames) / rate
        out = np.empty((n_move + 1, self.n_fingers, 3))
        rest = self.park() if rest is None else rest
        for k in range(1, self.n_fingers + 1):
            if k in targets:
                arr = np.asarray(targets[k], dtype=float)
                for j in range(3):
                    out[:, k - 1, j] = np.interp(t_move, t_ref, arr[:, j])
            else:
                out[:, k - 1] = rest[k - 1]
        return out

    # --------------------------------------------------------------------------------- run
    def run(
        self,
        start: ObjectPose | None,
        targets: Mapping[int, FloatArray],
        rate: float,
        *,
        settle: float | None = None,
        keep_trace: int = 0,
        signals: bool = False,
    ) -> SimResult:
        """Drive the fingertips through ``targets`` with the object starting at ``start``,
        open loop.

        Parameters
        ----------
        start : ObjectPose or None
            The object's pose at rest before the motion (metres); None: carry on from the
            object's current pose and velocity (the fingertips jump to their first targets).
        targets : mapping of int to array, shape (n_frames, 3)
            Finger number -> its centre's trajectory in the world (metres), sampled at
            ``rate``; fingers not given stay parked away from the object. NaN is refused.
        rate : float
            Sample rate of the targets, Hz (interpolated linearly to the physics step).
        settle : float, optional
            Longest time to let the object come to rest after the motion (default the
            parameters').
        keep_trace : int
            If > 0, keep the object's and fingers' poses every this many steps in
            ``SimResult.trace`` (for rendering): rows ``[t, x, y, z, qw, qx, qy, qz,
            finger xyz ...]``.
        signals : bool
            With ``keep_trace``, each trace row also holds, after the finger positions
            (columns :func:`signal_columns`): each fingertip's tracking error (m, from its
            commanded target), its normal contact force on the object (N), and the object's
            slip (m/s: the largest horizontal speed of its points touching the table; NaN
            when it touches none).

        Raises
        ------
        InputError
            Targets with NaN or infinities, of the wrong shape, naming unknown fingers.
        """
        wall0 = time.perf_counter()
        p = self.params
        n_frames = self.check_targets(targets, rate)
        resampled = self.resample(targets, rate, n_frames)
        ctrl = self.driver.controls(resampled)
        n_move = len(ctrl) - 1
        m, d = self.model, self.data
        if start is not None:
            mujoco.mj_resetData(m, d)
            self.set_pose(start)
        d.time = 0.0
        self.driver.place(d, ctrl[0])
        mujoco.mj_forward(m, d)

        log = EventLog(self.judge)
        trace: list[FloatArray] = []
        step = mujoco.mj_step
        ctrl_view = d.ctrl
        log.observe(d, 0.0)
        for i in range(1, n_move + 1):
            ctrl_view[:] = ctrl[i]
            step(m, d)
            if i % CONTACT_EVERY == 0:
                log.observe(d, i * p.timestep)
            if keep_trace and i % keep_trace == 0:
                trace.append(self.trace_row(i * p.timestep,
                                            resampled[i] if signals else None))
        # settle: the fingers hold their last targets; stop once the object is still
        settle_s = p.settle if settle is None else float(settle)
        j, settled = self.settle(settle_s, log, n_move * p.timestep, keep_trace, trace,
                                 resampled[-1] if signals else None)
        now = (n_move + j) * p.timestep
        log.close(d, now)
        return SimResult(
            self.pose(), self.state(), tuple(log.events), settled, now,
            time.perf_counter() - wall0, n_move + j, log.finger_table,
            np.array(trace) if trace else None,
        )

    def settle(self, seconds: float, log: EventLog, t0: float, keep_trace: int = 0,
               trace: list[FloatArray] | None = None,
               target: FloatArray | None = None) -> tuple[int, bool]:
        """Step with the controls held until the object is still for
        :data:`~nonprehensile.sim.judge.STILL_TIME` (at most ``seconds``); returns the steps
        taken and whether it came to rest. ``target``: the held targets, for the trace's
        signals (:meth:`trace_row`)."""
        p = self.params
        m, d, judge = self.model, self.data, self.judge
        n_settle = round(seconds / p.timestep)
        still = 0
        j = 0
        step = mujoco.mj_step
        # a robot's driver gives the rows that hold the last targets (the free fingertips'
        # held controls do)
        hold_row = getattr(self.driver, "hold_row", None)
        ctrl_view = d.ctrl
        for j in range(1, n_settle + 1):
            if hold_row is not None:
                ctrl_view[...] = hold_row()
            step(m, d)
            now = t0 + j * p.timestep
            if j % CONTACT_EVERY == 0:
                log.observe(d, now)
                if judge.is_still(d):
                    still += 1
                    if still * CONTACT_EVERY * p.timestep >= STILL_TIME:
                        return j, True
                else:
                    still = 0
            if keep_trace and trace is not None and j % keep_trace == 0:
                trace.append(self.trace_row(now, target))
        return j, False
