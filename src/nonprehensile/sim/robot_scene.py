"""The robot scene: the project's own scene with robot arms attached (MuJoCo MjSpec).

:func:`build_robot_scene` starts from :func:`~nonprehensile.sim.scene.scene_xml` without free
fingertips (same object, table, contact softness and frictions), attaches each arm at its base
pose under the prefix ``arm{i}/``, and puts a fingertip sphere ``finger{k}`` (the scene's
``finger_radius``) at each tip site, so the judge reads fingers exactly as it reads the free
fingertips. Every contact stays an explicit pair, as in the scene:

* ``finger{k}``-object (the finger's friction, the pad's torsional friction) and
  ``finger{k}``-table, as for the free fingertips;
* each collision geom of an arm (the link capsules and the rod; for a user's file, every geom
  that collides in it) against the object and the table, so a link or the rod that touches
  either is physics, and the judge records it (``other_contact``). Geoms that rest on the
  table at the home pose (the base) are not paired with the table.

Arms do not collide with themselves or each other (the IK keeps joints within limits).
Gravity is compensated on every robot body through the actuators. A joint whose position servo
has its own damping gets it moved to a velocity servo added beside it, so the set points can
carry velocity feed-forward: ``tau = kp (q_ref - q) + kv (qd_ref - qd)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.sim.robot import BasePose, Robot
from nonprehensile.sim.scene import DEFAULT_PARAMS, SimParams, scene_xml

__all__ = ["Arm", "RobotScene", "build_robot_scene"]

IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class Arm:
    """A robot at a base pose."""

    robot: Robot
    base: BasePose


@dataclass
class RobotScene:
    """A compiled robot scene and the indices a driver needs.

    Attributes
    ----------
    model : mujoco.MjModel
    arms : tuple of Arm
    joint_names : tuple of str
        Every driven joint, with its arm's prefix, in a fixed order (arm by arm).
    qadr, dadr : ndarray of int, shape (n_joints,)
        Their ``qpos`` and ``qvel`` addresses.
    pos_act, vel_act : ndarray of int, shape (n_joints,)
        Their position and velocity servos.
    lower, upper, velocity, torque : ndarray, shape (n_joints,)
    tip_sites : ndarray of int, shape (n_fingers,)
        The fingertip sites, fingers R1.. in order.
    collision_geoms : tuple of str
        The arms' geoms paired with the object and the table.
    table_geoms : tuple of str
        Those of them paired with the table (not the base).
    """

    model: Any
    arms: tuple[Arm, ...]
    joint_names: tuple[str, ...]
    qadr: IntArray
    dadr: IntArray
    pos_act: IntArray
    vel_act: IntArray
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    velocity: NDArray[np.float64]
    torque: NDArray[np.float64]
    tip_sites: IntArray
    collision_geoms: tuple[str, ...]
    table_geoms: tuple[str, ...]
    home: NDArray[np.float64]

    @property
    def n_fingers(self) -> int:
        """Fingertips over all arms."""
        return len(self.tip_sites)


def _is_collision(g: Any) -> bool:
    return bool(g.contype or g.conaffinity or g.group == 3)


def build_robot_scene(
    poly: Polyhedron, *, scale: float, arms: Sequence[Arm],
    params: SimParams = DEFAULT_PARAMS, mocap_object: bool = False,
) -> RobotScene:
    """Compile the project's scene with ``arms`` attached.

    Parameters
    ----------
    poly : Polyhedron
    scale : float
        Metres per model unit.
    arms : sequence of Arm
    params : SimParams
    mocap_object : bool
        Make the object a mocap body (no free joint): the IK's kinematic copy of the scene,
        whose object pose is set from the simulation, never moved by the solver.
    """
    if not arms:
        raise InputError("a robot scene needs at least one arm")
    spec = mujoco.MjSpec.from_string(scene_xml(poly, scale=scale, n_fingers=0, params=params))
    # a user's robot may give some bodies their inertia through their geoms only
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
    if mocap_object:
        obj = spec.body("object")
        for j in list(obj.joints):
            spec.delete(j)
        obj.mocap = True
    solref = [params.contact_timeconst, 1.0]
    ff = params.friction_finger
    ft = params.friction_table
    k = 0
    collision: list[str] = []
    tips: list[str] = []
    vel_added: dict[str, tuple[str, float]] = {}
    for i, arm in enumerate(arms):
        prefix = f"arm{i}/"
        child = arm.robot.spec()
        for key in list(child.keys):
            child.delete(key)
        # every robot geom collides only through the explicit pairs below
        names = []
        for n_geom, g in enumerate(child.geoms):
            if _is_collision(g):
                if not g.name:
                    g.name = f"geom#{n_geom}"
                names.append(g.name)
            g.contype = 0
            g.conaffinity = 0
        for b in child.bodies:
            if b.name != "world":
                b.gravcomp = 1.0
        for j in arm.robot.joints:
            jt = child.joint(j.name)
            jt.actgravcomp = 1
            if j.velocity_actuator is None:  # move the servo's damping to a velocity servo
                pa = child.actuator(j.position_actuator)
                pa.biasprm = [pa.biasprm[0], pa.biasprm[1], 0.0, *list(pa.biasprm[3:])]
                va = child.add_actuator()
                va.name = f"{j.name}_vff"
                va.target = j.name
                va.trntype = mujoco.mjtTrn.mjTRN_JOINT
                va.gaintype = mujoco.mjtGain.mjGAIN_FIXED
                va.biastype = mujoco.mjtBias.mjBIAS_AFFINE
                kv = max(j.kv, 1e-6)
                va.gainprm = [kv] + [0.0] * 9
                va.biasprm = [0.0, 0.0, -kv] + [0.0] * 7
                vel_added[prefix + j.name] = (prefix + va.name, kv)
        frame = spec.worldbody.add_frame(pos=[arm.base.x, arm.base.y, 0.0],
                                         quat=list(arm.base.quat()))
        spec.attach(child, prefix=prefix, frame=frame)
        collision += [prefix + n for n in names]
        for s in arm.robot.tip_sites:
            k += 1
            site = spec.site(prefix + s)
            body = site.parent
            g = body.add_geom()
            g.name = f"finger{k}"
            g.type = mujoco.mjtGeom.mjGEOM_SPHERE
            g.size = [params.finger_radius, 0, 0]
            g.pos = site.pos
            g.contype = 0
            g.conaffinity = 0
            g.rgba = [0.9, 0.6, 0.5, 1.0]
            tips.append(prefix + s)
            for other, fr, cond in (("object", [ff, ff, params.torsional_friction, 1e-4, 1e-4],
                                     4), ("table", [ft, ft, 0.005, 1e-4, 1e-4], 3)):
                p = spec.add_pair()
                p.geomname1 = other
                p.geomname2 = f"finger{k}"
                p.condim = cond
                p.solref = solref
                p.friction = fr
    try:
        model = spec.compile()
    except ValueError as exc:
        raise InputError(f"MuJoCo cannot build the robot scene: {str(exc).splitlines()[0]}"
                         ) from None
    # the home pose, to find the geoms that rest on the table (the base)
    joint_names, qadr, dadr, pa, va = [], [], [], [], []
    lower, upper, vel, torque, home = [], [], [], [], []
    for i, arm in enumerate(arms):
        prefix = f"arm{i}/"
        r = arm.robot
        for j, q0 in zip(r.joints, r.home, strict=True):
            name = prefix + j.name
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            joint_names.append(name)
            qadr.append(model.jnt_qposadr[jid])
            dadr.append(model.jnt_dofadr[jid])
            pa.append(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR,
                                        prefix + j.position_actuator))
            vname = vel_added[name][0] if j.velocity_actuator is None \
                else prefix + j.velocity_actuator
            va.append(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, vname))
            lower.append(j.lower)
            upper.append(j.upper)
            vel.append(j.velocity)
            torque.append(np.inf if j.torque is None else j.torque)
            home.append(q0)
    d = mujoco.MjData(model)
    d.qpos[qadr] = home
    mujoco.mj_kinematics(model, d)
    table_geoms = []
    for name in collision:
        gid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)
        if model.geom_bodyid[gid] in _arm_roots(model, arms):
            continue
        low = _lowest_z(model, d, gid)
        if low > 0.002:
            table_geoms.append(name)
    # the arm-object and arm-table pairs: compiled again with them (the base decided above)
    for name in collision:
        for other, fr, ok in (("object", [ff, ff, 0.005, 1e-4, 1e-4], True),
                              ("table", [ft, ft, 0.005, 1e-4, 1e-4], name in table_geoms)):
            if not ok:
                continue
            p = spec.add_pair()
            p.geomname1 = other
            p.geomname2 = name
            p.condim = 3
            p.solref = solref
            p.friction = fr
    model = spec.compile()
    tip_ids = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, s) for s in tips],
                       dtype=np.int64)
    return RobotScene(
        model, tuple(arms), tuple(joint_names), np.array(qadr, dtype=np.int64),
        np.array(dadr, dtype=np.int64), np.array(pa, dtype=np.int64),
        np.array(va, dtype=np.int64), np.array(lower), np.array(upper), np.array(vel),
        np.array(torque, dtype=float), tip_ids, tuple(collision), tuple(table_geoms),
        np.array(home))


def _arm_roots(model: Any, arms: Sequence[Arm]) -> set[int]:
    """Bodies attached directly to the world: the arms' bases."""
    return {b for b in range(1, model.nbody) if model.body_parentid[b] == 0
            and model.body(b).name.startswith("arm")}


def _lowest_z(model: Any, data: Any, gid: int) -> float:
    """The lowest point of a geom above the table now (bounding sphere for meshes)."""
    c = data.geom_xpos[gid]
    t = int(model.geom_type[gid])
    size = model.geom_size[gid]
    if t == int(mujoco.mjtGeom.mjGEOM_CAPSULE):
        axis = data.geom_xmat[gid].reshape(3, 3)[:, 2]
        return float(c[2] - abs(axis[2]) * size[1] - size[0])
    if t == int(mujoco.mjtGeom.mjGEOM_SPHERE):
        return float(c[2] - size[0])
    return float(c[2] - model.geom_rbound[gid])
