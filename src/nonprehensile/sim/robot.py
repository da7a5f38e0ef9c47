"""Robots as data: an MJCF model, its fingertip sites, its joints and their limits.

:meth:`Robot.builtin` gives the bundled Panda with a finger rod
(:mod:`nonprehensile.sim.panda`); :meth:`Robot.from_file` loads any MJCF robot by path, with
one site per finger (``R1``, ``R2``, ... in the order given). A robot file is checked when it is
loaded, and refused with one line naming the culprit: a missing site, no actuators, a joint
without limits, a joint that no position servo drives.
"""

from __future__ import annotations

import contextlib
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.sim import panda

__all__ = ["BUILTIN_ROBOTS", "DEFAULT_VELOCITY_LIMIT", "BasePose", "Robot"]

FloatArray = NDArray[np.float64]

#: Names :meth:`Robot.builtin` knows.
BUILTIN_ROBOTS = ("panda",)
#: Joint velocity limit (rad/s, or m/s for a slide joint) of a user's robot: MJCF has no
#: field for it (override with ``velocity_limit``).
DEFAULT_VELOCITY_LIMIT = 2.0


def _one_line(exc: BaseException) -> str:
    """MuJoCo's message of a file it cannot read or compile, on one line (its first line
    alone said only ``XML parse error 13:``: the reason and the line number follow it)."""
    lines = [" ".join(ln.split()).rstrip(":") for ln in str(exc).splitlines() if ln.strip()]
    return "; ".join(lines) if lines else repr(exc)


@dataclass(frozen=True)
class BasePose:
    """Where a robot's base frame stands on the table: ``(x, y)`` metres, heading ``yaw``
    degrees counterclockwise seen from above."""

    x: float
    y: float
    yaw: float = 0.0

    def __post_init__(self) -> None:
        for name in ("x", "y", "yaw"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"the robot base {name} must be a finite number, got {v!r}")
        if abs(self.x) > 10 or abs(self.y) > 10:
            raise InputError(f"the robot base ({self.x:g}, {self.y:g}) is more than 10 m from "
                             "the origin: give it in metres")

    def quat(self) -> FloatArray:
        """The base frame's orientation as a unit quaternion ``(w, x, y, z)``."""
        h = math.radians(self.yaw) / 2
        return np.array([math.cos(h), 0.0, 0.0, math.sin(h)])

    def to_dict(self) -> dict[str, float]:
        """JSON form."""
        return {"x": round(self.x, 6), "y": round(self.y, 6), "yaw_deg": round(self.yaw, 4)}


@dataclass(frozen=True)
class _Joint:
    name: str
    lower: float
    upper: float
    velocity: float
    torque: float | None  # None: the file sets no torque limit
    position_actuator: str
    velocity_actuator: str | None  # None: the scene adds one (velocity feed-forward)
    kv: float  # the position servo's own damping gain (moved to the feed-forward servo)


class Robot:
    """A robot model with fingertip sites.

    Parameters
    ----------
    name : str
        For records and outputs.
    xml : str, optional
        The MJCF document (the bundled robots).
    path : path, optional
        An MJCF file (a user's robot; its meshes are found relative to it).
    tip_sites : sequence of str
        One site per finger: the fingertip's centre, its +z axis pointing out of the finger
        (the IK points it down). Fingers ``R1``, ``R2``, ... in this order.
    velocity_limit : float or sequence of float, optional
        Joint velocity limits (MJCF has no field for them); default the datasheet's for a
        bundled robot, :data:`DEFAULT_VELOCITY_LIMIT` for a file.

    Attributes
    ----------
    joint_names : tuple of str
    lower, upper, velocity : ndarray, shape (n_joints,)
        Position limits (rad or m) and velocity limits.
    torque : ndarray, shape (n_joints,)
        Torque (force) limits; ``inf`` where the file sets none.

    Raises
    ------
    InputError
        The file cannot be read, a tip site is missing, the robot has no actuators, a joint
        has no limits or is not driven by a position servo.
    """

    def __init__(self, name: str, *, xml: str | None = None, path: str | Path | None = None,
                 tip_sites: Sequence[str] = ("tip",),
                 velocity_limit: float | Sequence[float] | None = None) -> None:
        if (xml is None) == (path is None):
            raise InputError("a Robot needs exactly one of xml= and path=")
        self.name = name
        self.xml = xml
        self.path = Path(path) if path is not None else None
        # one site's name is one site, not its letters ("tip": sites 't', 'i', 'p')
        self.tip_sites = (tip_sites,) if isinstance(tip_sites, str) else tuple(tip_sites)
        if not self.tip_sites:
            raise InputError("a robot needs at least one fingertip site (--tip-site NAME)")
        if len(set(self.tip_sites)) != len(self.tip_sites):
            raise InputError(f"the tip sites repeat: {list(self.tip_sites)}")
        self._where = str(self.path) if self.path is not None else f"the bundled {name}"
        spec = self.spec()
        try:
            model = spec.compile()
        except ValueError as exc:
            raise InputError(f"{self._where}: MuJoCo cannot compile the robot: "
                             f"{_one_line(exc)}") from None
        self._joints = self._check(model, velocity_limit)
        self.joint_names = tuple(j.name for j in self._joints)
        self.lower = np.array([j.lower for j in self._joints])
        self.upper = np.array([j.upper for j in self._joints])
        self.velocity = np.array([j.velocity for j in self._joints])
        self.torque = np.array([math.inf if j.torque is None else j.torque
                                for j in self._joints])
        home = next((k for k in range(model.nkey)), None)
        d = mujoco.MjData(model)
        if home is not None:
            mujoco.mj_resetDataKeyframe(model, d, home)
        else:  # the middle of the joint ranges
            for j in self._joints:
                jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j.name)
                d.qpos[model.jnt_qposadr[jid]] = (j.lower + j.upper) / 2
        self.home = np.array([d.qpos[model.jnt_qposadr[
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]] for n in self.joint_names])

    # ------------------------------------------------------------------ constructors
    @classmethod
    def builtin(cls, name: str = "panda", *, rod_length: float = panda.ROD_LENGTH) -> Robot:
        """A bundled robot: ``"panda"``, the Franka Panda with a finger tool ``rod_length``
        long (m, flange to tip site): an 8 mm rod (geom ``rod``) ending in a 5 mm pin (geom
        ``pin``, its last 50 mm above the fingertip; all of a tool under 67 mm, which then has
        no ``rod`` geom: :mod:`~nonprehensile.sim.panda`)."""
        if name != "panda":
            raise InputError(f"unknown robot {name!r}: the bundled robots are "
                             f"{list(BUILTIN_ROBOTS)} (or give --robot-xml FILE --tip-site S)")
        if not (isinstance(rod_length, (int, float)) and 0.02 <= rod_length <= 0.5):
            raise InputError(f"the finger rod length must be in [0.02, 0.5] m, got "
                             f"{rod_length!r}")
        return cls("panda", xml=panda.panda_xml(rod_length=rod_length), tip_sites=("tip",),
                   velocity_limit=panda.DQ_MAX)

    @classmethod
    def from_file(cls, path: str | Path, tip_sites: Sequence[str], *,
                  velocity_limit: float | Sequence[float] | None = None) -> Robot:
        """A user's MJCF robot by path, one site per finger."""
        p = Path(path)
        if p.is_dir():
            raise InputError(f"robot file {str(p)!r} is a directory: give the MJCF file in it")
        if not p.is_file():
            raise InputError(f"robot file {str(p)!r} does not exist")
        return cls(p.stem, path=p, tip_sites=tip_sites, velocity_limit=velocity_limit)

    # ------------------------------------------------------------------------- data
    def spec(self) -> Any:
        """A fresh :class:`mujoco.MjSpec` of the robot (edit it freely)."""
        try:
            if self.path is not None:
                spec = mujoco.MjSpec.from_file(str(self.path))
            else:
                spec = mujoco.MjSpec.from_string(self.xml)
        except (ValueError, OSError) as exc:
            raise InputError(f"{self._where}: not a MuJoCo model file: "
                             f"{_one_line(exc)}") from None
        # unnamed joints and actuators get names, so a scene can find them after attaching
        for i, j in enumerate(spec.joints):
            if not j.name:
                j.name = f"joint#{i}"
        for i, a in enumerate(spec.actuators):
            if not a.name:
                a.name = f"actuator#{i}"
        return spec

    def to_dict(self) -> dict[str, Any]:
        """JSON form: the robot, its sites and joint limits."""
        return {
            "name": self.name,
            "source": str(self.path) if self.path is not None else "builtin",
            "tip_sites": list(self.tip_sites),
            "joints": [
                {"name": j.name, "lower": round(j.lower, 6), "upper": round(j.upper, 6),
                 "velocity_limit": round(j.velocity, 6),
                 "torque_limit": None if j.torque is None else round(j.torque, 6),
                 "position_actuator": j.position_actuator,
                 "velocity_actuator": j.velocity_actuator}
                for j in self._joints],
        }

    @property
    def joints(self) -> tuple[_Joint, ...]:
        """The driven joints and their servos."""
        return self._joints

    # ----------------------------------------------------------------------- checks
    def _check(self, m: Any, velocity_limit: float | Sequence[float] | None) -> tuple[
            _Joint, ...]:
        where = self._where
        for s in self.tip_sites:
            if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, s) < 0:
                names = [m.site(i).name for i in range(m.nsite)]
                raise InputError(f"{where}: no site {s!r} for a fingertip (the file's sites: "
                                 f"{names or 'none'}); add one at the fingertip's centre")
        if m.nu == 0:
            raise InputError(f"{where}: the robot has no actuators; give every joint a "
                             "position servo (<position joint=... kp=...>)")
        pos_act: dict[int, int] = {}
        vel_act: dict[int, int] = {}
        for a in range(m.nu):
            if int(m.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
                continue
            j = int(m.actuator_trnid[a, 0])
            gain, bias = m.actuator_gainprm[a], m.actuator_biasprm[a]
            affine = int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE)
            if affine and bias[1] < 0 \
                    and abs(bias[1] + gain[0]) <= 1e-9 * max(1.0, gain[0]):
                pos_act[j] = a
            elif affine and bias[1] == 0 \
                    and bias[2] < 0:
                vel_act[j] = a
        joints = []
        hinge_slide = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
        n = sum(1 for j in range(m.njnt) if int(m.jnt_type[j]) in hinge_slide)
        if isinstance(velocity_limit, numbers.Real) and not isinstance(velocity_limit,
                                                                        (bool, np.bool_)):
            vlims = [float(velocity_limit)] * n
        elif velocity_limit is None:
            vlims = [DEFAULT_VELOCITY_LIMIT] * n
        else:
            # a number or one per joint: anything else (a bool, text, a bare object) is the
            # caller's mistake, named, not a TypeError or ValueError from float()
            items: list[Any] | None = None
            if not isinstance(velocity_limit, (str, bytes)):
                with contextlib.suppress(TypeError):
                    items = list(velocity_limit)  # type: ignore[arg-type]
            if items is None or any(isinstance(v, (bool, np.bool_))
                                    or not isinstance(v, numbers.Real) for v in items):
                raise InputError(f"{where}: velocity_limit must be a number of rad/s (m/s) or "
                                 f"one per joint ({n}), got {velocity_limit!r}")
            vlims = [float(v) for v in items]
            if len(vlims) != n:
                raise InputError(f"{where}: {len(vlims)} velocity limits for {n} joints")
        if any(not math.isfinite(v) or v <= 0 for v in vlims):
            raise InputError(f"{where}: velocity limits must be finite and positive, got "
                             f"{vlims}")
        for j in range(m.njnt):
            jname = m.joint(j).name
            t = int(m.jnt_type[j])
            if t not in hinge_slide:
                raise InputError(f"{where}: joint {jname!r} is a "
                                 f"{'free' if t == int(mujoco.mjtJoint.mjJNT_FREE) else 'ball'} "
                                 "joint; a robot's joints are hinges or slides with limits "
                                 "(fix the base: remove its freejoint)")
            lo_hi = (float(m.jnt_range[j, 0]), float(m.jnt_range[j, 1]))
            if lo_hi != (0.0, 0.0) and lo_hi[0] >= lo_hi[1]:
                # (MuJoCo compiles it as a joint without limits: "has no limits" misled)
                raise InputError(f"{where}: joint {jname!r} has an empty range (lower "
                                 f"{lo_hi[0]:g} >= upper {lo_hi[1]:g} as compiled); give it "
                                 "range=\"lo hi\" with lo < hi")
            if not m.jnt_limited[j]:
                raise InputError(f"{where}: joint {jname!r} has no limits; give it range=\"lo "
                                 "hi\" (the IK keeps every joint within its range)")
            if j not in pos_act:
                raise InputError(f"{where}: joint {jname!r} is driven by no position servo "
                                 "(<position joint=... kp=...> or a general actuator with "
                                 "biasprm=\"0 -kp -kv\")")
            lo, hi = (float(v) for v in m.jnt_range[j])
            torque = None
            if m.jnt_actfrclimited[j]:
                fr, attr = m.jnt_actfrcrange[j], "the joint's actuatorfrcrange"
            elif m.actuator_forcelimited[pos_act[j]]:
                fr, attr = m.actuator_forcerange[pos_act[j]], "its servo's forcerange"
            else:
                fr = None
            if fr is not None:
                torque = float(min(abs(fr[0]), abs(fr[1])))
                if not (fr[0] < 0 < fr[1]):  # a torque limit of 0 one way: no servo holds it
                    raise InputError(f"{where}: joint {jname!r}: {attr} \"{fr[0]:g} "
                                     f"{fr[1]:g}\" does not drive it both ways; give "
                                     "\"-limit limit\" (lower < 0 < upper)")
            pa = pos_act[j]
            va = vel_act.get(j)
            for act in (pa, va):
                # the set points are joint positions and velocities: a servo with a gear
                # holds the joint at ctrl / gear (the arm missed the plan by centimetres)
                if act is not None and float(m.actuator_gear[act, 0]) != 1.0:
                    raise InputError(f"{where}: joint {jname!r}: its servo "
                                     f"{m.actuator(act).name!r} has gear "
                                     f"\"{float(m.actuator_gear[act, 0]):g}\"; the set points "
                                     "are joint positions and velocities: give gear=\"1\" "
                                     "(scale kp and kv instead)")
            joints.append(_Joint(
                jname, lo, hi, vlims[j], torque, m.actuator(pa).name,
                None if va is None else m.actuator(va).name,
                float(-m.actuator_biasprm[pa, 2])))
        return tuple(joints)
