"""The MuJoCo scene: a table, the object as a convex mesh, and fingertips as driven spheres.

Choices (documented in ``docs/physics.md``):

* The object is one convex ``mesh`` geom made from the model's vertices (scaled to metres),
  in a free body whose frame is the model's frame: a body pose ``(R, t)`` puts a model point
  ``x`` at ``scale * R @ x + t``, as :class:`~nonprehensile.planning.ObjectPose` does. Its mass
  is ``SimParams.mass`` with the inertia of a uniform solid about the model's centre of mass.
* The table is the plane ``z = 0``.
* Each fingertip is a sphere on three slide joints (x, y, z) driven by position actuators:
  a stiffness ``kp`` (N/m) with critical damping and a force limit per axis, like a compliant
  robot finger under impedance control. The finger's weight is compensated (``gravcomp``), as a
  robot arm's would be. The reference trajectory is the sphere's centre.
* Contacts are explicit pairs, so every friction is exactly what is asked: object-table
  (``friction_table``), object-finger (``friction_finger``) and finger-table (the table's).
  Every pair has the same softness: MuJoCo's ``solref`` time constant ``contact_timeconst``
  (critically damped), and the fingertip pad's torsional friction is ``torsional_friction``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron

__all__ = ["DEFAULT_PARAMS", "SimParams", "convexity_error", "scene_xml", "solid_inertia"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SimParams:
    """Physical parameters of a simulation; every one can be overridden.

    Attributes
    ----------
    mass : float
        Object mass, kg (0.1: a 5 cm wooden cube weighs about 0.08-0.1 kg).
    friction_table : float
        Coulomb friction object-table (wood on a table: ~0.6).
    friction_finger : float
        Coulomb friction object-fingertip (skin or a rubber pad: ~0.8).
    finger_radius : float
        Fingertip sphere radius, m (6 mm: a human fingertip pad, or a 12 mm robot tip).
    stiffness : float
        Position gain of each finger axis, N/m.
    max_force : float
        Force limit of each finger axis, N.
    finger_mass : float
        Mass of each fingertip body, kg (weight compensated).
    timestep : float
        Physics step, s.
    settle : float
        Longest time the object is left to come to rest after the motion, s.
    debounce : float
        A contact set must hold this long to be an event, s.
    contact_tol : float
        Distance (m) within which a contact point or a vertex counts as on a face plane or on
        the table, when naming the touched face, edge or vertex.
    contact_timeconst : float
        Contact softness: the time constant of MuJoCo's contact spring-damper (``solref``,
        damping ratio 1), s, on every contact pair. Smaller is stiffer: at rest a cube sinks
        0.10 mm into the table at 0.02 s (MuJoCo's default), 0.027 mm at 0.01 s, 0.004 mm
        at 0.004 s, whatever its mass (MuJoCo scales the spring with the contact's effective
        mass). At least two physics steps (MuJoCo would otherwise stiffen it silently).
    torsional_friction : float
        Torsional friction of a fingertip pad on the object, m (MuJoCo's torsional
        coefficient: the largest friction torque is this times the normal force). A pinch
        held by two point contacts spins about the pinch line against this torque only.
    """

    mass: float = 0.1
    friction_table: float = 0.6
    friction_finger: float = 0.8
    finger_radius: float = 0.006
    stiffness: float = 600.0
    max_force: float = 8.0
    finger_mass: float = 0.02
    timestep: float = 0.001
    settle: float = 1.5
    debounce: float = 0.01
    contact_tol: float = 0.0015
    contact_timeconst: float = 0.02
    torsional_friction: float = 0.002

    def __post_init__(self) -> None:
        bounds = {
            "mass": (1e-4, 100.0, "kg"),
            "friction_table": (1e-3, 5.0, ""),
            "friction_finger": (1e-3, 5.0, ""),
            "finger_radius": (1e-4, 0.1, "m"),
            "stiffness": (1.0, 1e6, "N/m"),
            "max_force": (1e-3, 1e4, "N"),
            "finger_mass": (1e-4, 10.0, "kg"),
            "timestep": (1e-5, 0.01, "s"),
            "settle": (0.0, 60.0, "s"),
            "debounce": (0.0, 1.0, "s"),
            "contact_tol": (1e-6, 0.05, "m"),
            "contact_timeconst": (1e-4, 1.0, "s"),
            "torsional_friction": (0.0, 0.05, "m"),
        }
        for name, (lo, hi, unit) in bounds.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not lo <= v <= hi:
                raise InputError(
                    f"simulation parameter {name} must be a number in [{lo:g}, {hi:g}]"
                    f"{' ' + unit if unit else ''}, got {v!r}"
                )
            object.__setattr__(self, name, float(v))
        if self.contact_timeconst < 2.0 * self.timestep - 1e-12:
            raise InputError(
                f"simulation parameter contact_timeconst must be at least two physics steps "
                f"({2.0 * self.timestep:g} s at timestep {self.timestep:g} s), got "
                f"{self.contact_timeconst!r}: MuJoCo would stiffen it to that silently")

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return asdict(self)


#: The defaults (see :class:`SimParams`).
DEFAULT_PARAMS = SimParams()


def solid_inertia(poly: Polyhedron, scale: float, mass: float) -> FloatArray:
    """Inertia tensor (kg m^2, shape (3, 3)) of the uniform solid about the model's centre of
    mass, in the model's frame scaled to metres (tetrahedra from the centre of mass)."""
    c = poly.com
    cov = np.zeros((3, 3))
    vol = 0.0
    for loop in poly.faces.values():
        p = poly.vertices[list(loop)] - c
        for i in range(1, len(loop) - 1):
            a, b, d = p[0], p[i], p[i + 1]
            v = abs(float(np.linalg.det(np.stack([a, b, d])))) / 6.0
            # second moment of a tetrahedron with one vertex at the origin
            s = a + b + d
            cov += v / 20.0 * (np.outer(a, a) + np.outer(b, b) + np.outer(d, d) + np.outer(s, s))
            vol += v
    cov *= mass / vol * scale**2
    return np.asarray(np.trace(cov) * np.eye(3) - cov)


def convexity_error(poly: Polyhedron) -> str | None:
    """Why the model is not a convex solid MuJoCo can collide exactly, or None."""
    tol = 1e-6 * poly.diameter + poly.atol
    for f, n in poly.normals.items():
        h = float(n @ poly.vertices[poly.faces[f][0]])
        out = poly.vertices @ n - h
        if out.max() > tol:
            j = int(np.argmax(out))
            return (f"{poly.name!r} is not convex: vertex {j} lies {out[j]:.3g} {poly.units} "
                    f"outside the plane of face {f!r}; simulate its convex hull instead "
                    "(`nonprehensile object from-mesh` makes one)")
    return None


def _fmt(values: Any) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.ravel(values))


def scene_xml(
    poly: Polyhedron,
    *,
    scale: float,
    n_fingers: int,
    params: SimParams = DEFAULT_PARAMS,
) -> str:
    """The MJCF document of the scene.

    Parameters
    ----------
    poly : Polyhedron
        A convex object model (model units).
    scale : float
        Metres per model unit.
    n_fingers : int
        How many fingertips (``finger1``, ``finger2``, ... on joints ``finger1_x``, ...).
    params : SimParams

    Raises
    ------
    InputError
        A non-convex model or a bad scale.
    """
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and 0 < scale < 1e3):
        raise InputError(f"the scale (metres per model unit) must be a finite positive number, "
                         f"got {scale!r}")
    why = convexity_error(poly)
    if why is not None:
        raise InputError(why)
    inertia = solid_inertia(poly, scale, params.mass)
    # the spec's loops run clockwise seen from outside; MuJoCo wants counterclockwise
    # triangles (their normals point out), or it culls the faces when it draws them
    tris = [(loop[0], loop[i + 1], loop[i]) for loop in poly.faces.values()
            for i in range(1, len(loop) - 1)]
    kp = params.stiffness
    kv = 2.0 * math.sqrt(kp * params.finger_mass)  # critical damping
    f = params.max_force
    r = params.finger_radius
    inertia_f = 0.4 * params.finger_mass * r * r
    fingers, actuators, pairs = [], [], []
    solref = f'solref="{params.contact_timeconst:.6g} 1"'
    for k in range(1, n_fingers + 1):
        joints = "".join(
            f'<joint name="finger{k}_{a}" type="slide" axis="{ax}" damping="{kv:.6g}"/>'
            for a, ax in (("x", "1 0 0"), ("y", "0 1 0"), ("z", "0 0 1")))
        fingers.append(
            f'<body name="finger{k}" gravcomp="1">{joints}'
            f'<inertial pos="0 0 0" mass="{params.finger_mass:.6g}" '
            f'diaginertia="{inertia_f:.6g} {inertia_f:.6g} {inertia_f:.6g}"/>'
            f'<geom name="finger{k}" type="sphere" size="{r:.6g}"'
            f' contype="0" conaffinity="0" rgba="0.9 0.6 0.5 1"/></body>')
        actuators += [
            f'<position name="finger{k}_{a}" joint="finger{k}_{a}" kp="{kp:.6g}" '
            f'forcelimited="true" forcerange="{-f:.6g} {f:.6g}"/>' for a in "xyz"]
        pairs += [
            f'<pair geom1="object" geom2="finger{k}" condim="4" {solref} '
            f'friction="{params.friction_finger:.6g} {params.friction_finger:.6g} '
            f'{params.torsional_friction:.6g} 0.0001 0.0001"/>',
            f'<pair geom1="table" geom2="finger{k}" condim="3" {solref} '
            f'friction="{params.friction_table:.6g} {params.friction_table:.6g} 0.005 '
            f'0.0001 0.0001"/>',
        ]
    mt = params.friction_table
    return f"""<mujoco model="nonprehensile-{poly.name}">
  <compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="{params.timestep:.6g}" gravity="0 0 -9.81" integrator="implicitfast"
          cone="elliptic" impratio="10"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <asset>
    <mesh name="object" vertex="{_fmt(poly.vertices * scale)}" face="{_fmt(np.array(tris))}"/>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.85 0.85 0.85" rgb2="0.75 0.75 0.75"
             width="256" height="256"/>
    <material name="grid" texture="grid" texrepeat="20 20"/>
  </asset>
  <worldbody>
    <light pos="0 0 2" dir="0 0 -1" directional="true"/>
    <geom name="table" type="plane" size="0 0 0.05" material="grid" contype="0"
          conaffinity="0"/>
    <body name="object">
      <freejoint name="object"/>
      <inertial pos="{_fmt(poly.com * scale)}" mass="{params.mass:.9g}"
                fullinertia="{_fmt(inertia[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]])}"/>
      <geom name="object" type="mesh" mesh="object" contype="0" conaffinity="0"
            rgba="0.35 0.55 0.85 1"/>
    </body>
    {"".join(fingers)}
  </worldbody>
  <contact>
    <pair geom1="object" geom2="table" condim="4" {solref}
          friction="{mt:.6g} {mt:.6g} 0.002 0.0001 0.0001"/>
    {"".join(pairs)}
  </contact>
  <actuator>{"".join(actuators)}</actuator>
</mujoco>
"""


#: The parameters a :class:`SceneTuner` writes: what differs between two samples of the
#: physics distribution. Everything else (the object's shape, the timestep) needs a new scene.
RETUNABLE = ("mass", "friction_table", "friction_finger", "finger_radius", "stiffness",
             "max_force", "contact_timeconst", "torsional_friction")


class SceneTuner:
    """Write new physical parameters into a compiled scene of :func:`scene_xml`.

    A sweep across the physics distribution keeps one compiled model per worker and retunes
    it per sample instead of compiling a new scene (4-5 ms, a tenth of a transition). Every
    value written is computed from the parameters and what the scene was compiled with, never
    from the previous sample's, so a sample's model is the same whatever ran before it (a
    worker's history cannot change a result). The model equals what :func:`scene_xml` would
    compile with the new parameters, except that the document rounds them to 6 digits.

    Parameters
    ----------
    model, data : mujoco.MjModel, mujoco.MjData
        A compiled scene and its data (the data is scratch for ``mj_setConst``).
    params : SimParams
        What the scene was compiled with.
    """

    def __init__(self, model: Any, data: Any, params: SimParams) -> None:
        import mujoco

        self.model, self.data, self.compiled = model, data, params
        m = model

        def name2id(kind: Any, name: str) -> int:
            return int(mujoco.mj_name2id(m, kind, name))

        g, b = mujoco.mjtObj.mjOBJ_GEOM, mujoco.mjtObj.mjOBJ_BODY
        self._obj = name2id(b, "object")
        # principal moments per kilogram of the uniform solid
        self._inertia_per_kg = np.array(m.body_inertia[self._obj]) / float(
            m.body_mass[self._obj])
        obj_g, table_g = name2id(g, "object"), name2id(g, "table")
        self._fingers: list[tuple[int, int, list[int], list[int]]] = []
        k = 1
        while (geom := name2id(g, f"finger{k}")) >= 0:
            if name2id(mujoco.mjtObj.mjOBJ_JOINT, f"finger{k}_x") < 0:
                # a robot scene's fingertip: a sphere on an arm's link (the arm's own body,
                # joints and servos are the robot's, not retuned)
                self._fingers.append((geom, -1, [], []))
            else:
                dofs = [int(m.jnt_dofadr[name2id(mujoco.mjtObj.mjOBJ_JOINT, f"finger{k}_{a}")])
                        for a in "xyz"]
                acts = [name2id(mujoco.mjtObj.mjOBJ_ACTUATOR, f"finger{k}_{a}") for a in "xyz"]
                self._fingers.append((geom, name2id(b, f"finger{k}"), dofs, acts))
            k += 1
        tips = {f[0] for f in self._fingers}
        self._pair_kind = []
        for i in range(m.npair):
            pair = {int(m.pair_geom1[i]), int(m.pair_geom2[i])}
            # a robot scene also pairs the arms' links and rods with the object and the
            # table (robot_scene.py): low torsional friction, no finger friction
            self._pair_kind.append("table" if pair == {obj_g, table_g} else
                                   ("finger" if pair & tips else "link") if obj_g in pair
                                   else "finger_table" if pair & tips else "link_table")
        self.params = params

    def tune(self, new: SimParams) -> None:
        """Make the scene the one of ``new``.

        Raises
        ------
        InputError
            If ``new`` differs from the compiled parameters in one that is not retunable.
        """
        import mujoco

        old = asdict(self.compiled)
        fixed = [k for k, v in asdict(new).items() if k not in RETUNABLE and old[k] != v]
        if fixed:
            raise InputError(f"parameters {fixed} cannot be changed in a compiled scene: "
                             "build a new one")
        m = self.model
        m.body_mass[self._obj] = new.mass
        m.body_inertia[self._obj] = self._inertia_per_kg * new.mass
        friction = {
            "table": (new.friction_table, new.friction_table, 0.002, 1e-4, 1e-4),
            "finger": (new.friction_finger, new.friction_finger, new.torsional_friction,
                       1e-4, 1e-4),
            "finger_table": (new.friction_table, new.friction_table, 0.005, 1e-4, 1e-4),
            "link": (new.friction_finger, new.friction_finger, 0.005, 1e-4, 1e-4),
            "link_table": (new.friction_table, new.friction_table, 0.005, 1e-4, 1e-4),
        }
        for i, kind in enumerate(self._pair_kind):
            m.pair_solref[i] = (new.contact_timeconst, 1.0)
            m.pair_friction[i] = friction[kind]
        r = new.finger_radius
        kp = new.stiffness
        kv = 2.0 * math.sqrt(kp * new.finger_mass)
        for geom, body, dofs, acts in self._fingers:
            m.geom_size[geom, 0] = r
            m.geom_rbound[geom] = r
            m.geom_aabb[geom] = (0.0, 0.0, 0.0, r, r, r)
            if body < 0:
                continue
            m.body_inertia[body] = 0.4 * new.finger_mass * r * r
            for dof in dofs:
                m.dof_damping[dof] = kv
            for a in acts:
                m.actuator_gainprm[a, 0] = kp
                m.actuator_biasprm[a, 1] = -kp
                m.actuator_forcerange[a] = (-new.max_force, new.max_force)
        # the constants MuJoCo derives from masses and inertias (invweight0, ...)
        mujoco.mj_setConst(m, self.data)
        self.params = new
