"""The bundled robot: a mesh-free Franka Emika Panda with a rigid finger rod, written as MJCF.

Nothing here is copied from a third-party model file; the MJCF is generated from published
numbers, each with its source:

* **Kinematics** (:data:`DH`): Franka's documentation of the robot's Denavit-Hartenberg
  parameters (Craig's modified convention), "Robot and interface specifications", Franka
  Control Interface documentation (frankaemika.github.io/docs/control_parameters.html): joint
  ``i`` is ``RotX(alpha_{i-1}) TransX(a_{i-1}) RotZ(q_i) TransZ(d_i)``; flange ``d = 0.107``.
* **Limits** (:data:`Q_MIN`, :data:`Q_MAX`, :data:`DQ_MAX`, :data:`TAU_MAX`): the same page's
  joint-space limits table (position, velocity, torque).
* **Inertial parameters** of links 1-7 (:data:`INERTIAL`: mass, centre of mass and inertia
  tensor in the link's DH frame): the physically feasible set identified by C. Gaz,
  M. Cognetti, A. Oliva, P. Robuffo Giordano, A. De Luca, "Dynamic Identification of the
  Franka Emika Panda Robot With Retrieval of Feasible Parameters Using Penalty-Based
  Optimization", IEEE Robotics and Automation Letters 4(4):4147-4154, 2019, as the authors
  distribute it with the paper's dynamic model (``franka_model.h``); link 1's centre-of-mass
  height is the -0.04762 m of Franka's own ``franka_description`` (the identification leaves it
  unobservable: the first joint's axis is vertical). The inertia tensors are taken about the
  centre of mass, axes along the DH frame, as URDF and MJCF state them.

Modelling choices that are not published numbers (documented in ``docs/robot.md``):
collision **capsules** along the segments between joint centres (radii 45-70 mm, the housings'
size), a joint **armature** of 0.1 kg m^2 (the reflected rotor inertia of a harmonic drive is of
that order; it keeps the 1 kHz position loop stable on the light wrist links), a viscous
damping of 0.5 N m s/rad, and the tool: an aluminium rod, 8 mm across, 80 g, along the flange
axis, whose tip site ``tip`` lies :data:`ROD_LENGTH` beyond the flange (the scene puts the
fingertip sphere there); its last :data:`PIN_LENGTH` above the fingertip sphere is a steel pin
5 mm across (:data:`PIN_RADIUS`), so that a 5 mm fingertip still stands out of it.
The actuators are joint position servos (``kp``) with a velocity feed-forward servo (``kv``)
on each joint, their sum clamped to the datasheet's torque (``actuatorfrcrange``), gravity
compensated through the actuators (``actuatorgravcomp``: it counts against the torque limit).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "DH",
    "DQ_MAX",
    "INERTIAL",
    "JOINT_NAMES",
    "KP",
    "KV",
    "PIN_LENGTH",
    "PIN_RADIUS",
    "Q_HOME",
    "Q_MAX",
    "Q_MIN",
    "ROD_LENGTH",
    "TAU_MAX",
    "panda_xml",
]

FloatArray = NDArray[np.float64]

#: Modified DH parameters ``(a_{i-1}, d_i, alpha_{i-1})`` of joints 1-7 and the flange (m, rad).
DH = (
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -math.pi / 2),
    (0.0, 0.316, math.pi / 2),
    (0.0825, 0.0, math.pi / 2),
    (-0.0825, 0.384, -math.pi / 2),
    (0.0, 0.0, math.pi / 2),
    (0.088, 0.0, math.pi / 2),
    (0.0, 0.107, 0.0),  # flange
)
#: Joint position limits, rad (Franka's joint-space limits table).
Q_MIN = (-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973)
Q_MAX = (2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973)
#: Joint velocity limits, rad/s.
DQ_MAX = (2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100)
#: Joint torque limits, N m.
TAU_MAX = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
#: A home configuration (Franka's "ready" pose), rad.
Q_HOME = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)

#: Link 1-7 inertial parameters: ``(mass kg, centre of mass (m, DH frame),
#: (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) kg m^2 about the centre of mass)`` (Gaz et al. 2019).
INERTIAL = (
    (4.970684, (3.875e-03, 2.081e-03, -4.762e-02),
     (7.0337e-01, 7.0661e-01, 9.1170e-03, -1.3900e-04, 6.7720e-03, 1.9169e-02)),
    (0.646926, (-3.141e-03, -2.872e-02, 3.495e-03),
     (7.9620e-03, 2.8110e-02, 2.5995e-02, -3.9250e-03, 1.0254e-02, 7.0400e-04)),
    (3.228604, (2.7518e-02, 3.9252e-02, -6.6502e-02),
     (3.7242e-02, 3.6155e-02, 1.0830e-02, -4.7610e-03, -1.1396e-02, -1.2805e-02)),
    (3.587895, (-5.317e-02, 1.04419e-01, 2.7454e-02),
     (2.5853e-02, 1.9552e-02, 2.8323e-02, 7.7960e-03, -1.3320e-03, 8.6410e-03)),
    (1.225946, (-1.1953e-02, 4.1065e-02, -3.8437e-02),
     (3.5549e-02, 2.9474e-02, 8.6270e-03, -2.1170e-03, -4.0370e-03, 2.2900e-04)),
    (1.666555, (6.0149e-02, -1.4117e-02, -1.0517e-02),
     (1.9640e-03, 4.3540e-03, 5.4330e-03, 1.0900e-04, -1.1580e-03, 3.4100e-04)),
    (7.35522e-01, (1.0517e-02, -4.252e-03, 6.1597e-02),
     (1.2516e-02, 1.0027e-02, 4.8150e-03, -4.2800e-04, -1.1960e-03, -7.4100e-04)),
)
#: Position gains, N m/rad, and velocity gains, N m s/rad, of the joint servos: the shoulder
#: and elbow stiff enough that a 10 N push at 0.6 m deflects the tip < 1 mm, the wrist softer
#: (its 12 N m limit); damping ratio about 1 with the armature.
KP = (4500.0, 4500.0, 3500.0, 3500.0, 2000.0, 2000.0, 2000.0)
KV = (450.0, 450.0, 350.0, 350.0, 200.0, 200.0, 200.0)
ARMATURE = 0.1
DAMPING = 0.5
#: Flange to the tip site along the flange's z axis, m.
ROD_LENGTH = 0.12
ROD_RADIUS = 0.004
ROD_MASS = 0.08
#: The tool's lower end, a pin thinner than the rod (radius, length, m; the pin ends 16 mm
#: above the tip site, as the rod did). The physics distribution gives the fingertip sphere a
#: radius of 5-12 mm: an 8 mm rod straight down over a 5 mm sphere pushing a side face stood
#: 1 mm from it, the IK's collision margin held the fingertip at its first touch while its
#: command moved on, and 6 of the 18 runs with a 5-6 mm tip of the main plan's 100 samples
#: tracked worse than 3 mm (none with the pin, before the radius offset). Under 40 N at the
#: fingertip, 66 mm below the pin's top, a 5 mm steel pin bends about 0.6 mm (``F L^3 / 3 E
#: I``; the 8 mm aluminium rod over the same length: 0.3 mm); the simulation keeps the tool
#: rigid, as it kept the rod.
PIN_RADIUS = 0.0025
PIN_LENGTH = 0.05
JOINT_NAMES = tuple(f"joint{i}" for i in range(1, 8))

# collision capsules as world segments at q = 0 (arm straight up, the flange pointing down),
# owned by the body they move with: (body index 0..7, p, q, radius); 0 is the base
_CAPSULES = (
    (0, (0.0, 0.0, 0.03), (0.0, 0.0, 0.20), 0.07),
    (1, (0.0, 0.0, 0.21), (0.0, 0.0, 0.333), 0.065),
    (2, (0.0, -0.06, 0.333), (0.0, 0.06, 0.333), 0.06),
    (2, (0.0, 0.0, 0.333), (0.0, 0.0, 0.50), 0.06),
    (3, (0.0, 0.0, 0.50), (0.0, 0.0, 0.649), 0.06),
    (3, (0.0, 0.0, 0.649), (0.0825, 0.0, 0.649), 0.055),
    (4, (0.0825, -0.055, 0.649), (0.0825, 0.055, 0.649), 0.055),
    (4, (0.0825, 0.0, 0.649), (0.0, 0.0, 0.76), 0.055),
    (5, (0.0, 0.0, 0.76), (0.0, 0.0, 0.98), 0.05),
    (6, (0.0, -0.05, 1.033), (0.0, 0.05, 1.033), 0.05),
    (6, (0.0, 0.0, 1.033), (0.088, 0.0, 1.033), 0.05),
    (7, (0.088, 0.0, 1.033), (0.088, 0.0, 0.95), 0.045),
)


def _rot_x(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _quat_x(a: float) -> tuple[float, float, float, float]:
    return (math.cos(a / 2), math.sin(a / 2), 0.0, 0.0)


def _frames_at_zero() -> list[tuple[FloatArray, FloatArray]]:
    """World rotation and origin of bodies 0 (base) .. 8 (flange) at q = 0."""
    r, p = np.eye(3), np.zeros(3)
    out = [(r, p)]
    for a, d, alpha in DH:
        rx = _rot_x(alpha)
        p = p + r @ (np.array([a, 0.0, 0.0]) + rx @ np.array([0.0, 0.0, d]))
        r = r @ rx
        out.append((r, p))
    return out


def _f(values: object) -> str:
    return " ".join(f"{float(v):.6g}" for v in np.ravel(np.asarray(values, dtype=float)))


def panda_xml(*, rod_length: float = ROD_LENGTH, prefix: str = "") -> str:
    """The MJCF document of the Panda with its finger rod (base frame at the origin).

    Parameters
    ----------
    rod_length : float
        Flange to the tip site, m.
    prefix : str
        Prepended to every name (several arms in one scene are attached with MjSpec prefixes
        instead; this is for a standalone file).

    Returns
    -------
    str
        Bodies ``link0 .. link7``, ``rod`` (the tool: geoms ``rod`` and ``pin``, or ``pin``
        alone for a tool whose rod would be under 1 mm); joints ``joint1 .. joint7``; site
        ``tip``; actuators ``joint{i}`` (position) and ``joint{i}_v`` (velocity
        feed-forward).
    """
    frames = _frames_at_zero()
    geoms: dict[int, list[str]] = {i: [] for i in range(8)}
    for k, (owner, p, q, radius) in enumerate(_CAPSULES):
        r, o = frames[owner]
        pa = r.T @ (np.array(p) - o)
        pb = r.T @ (np.array(q) - o)
        geoms[owner].append(f'<geom name="{prefix}link{owner}_c{k}" type="capsule" '
                            f'fromto="{_f(pa)} {_f(pb)}" size="{radius:g}" '
                            f'class="{prefix}link"/>')

    def body(i: int, inner: str) -> str:
        if i == 0:
            return (f'<body name="{prefix}link0">'
                    '<inertial pos="-0.041 0 0.05" mass="0.63" '
                    'diaginertia="0.00315 0.00388 0.00429"/>'
                    f'{"".join(geoms[0])}{inner}</body>')
        a, d, alpha = DH[i - 1]
        pos = np.array([a, -d * math.sin(alpha), d * math.cos(alpha)])
        mass, com, (ixx, iyy, izz, ixy, ixz, iyz) = INERTIAL[i - 1]
        j = i - 1
        return (f'<body name="{prefix}link{i}" pos="{_f(pos)}" quat="{_f(_quat_x(alpha))}" '
                f'gravcomp="1">'
                f'<inertial pos="{_f(com)}" mass="{mass:.7g}" '
                f'fullinertia="{ixx:.6g} {iyy:.6g} {izz:.6g} {ixy:.6g} {ixz:.6g} {iyz:.6g}"/>'
                f'<joint name="{prefix}joint{i}" range="{Q_MIN[j]:g} {Q_MAX[j]:g}" '
                f'actuatorfrcrange="{-TAU_MAX[j]:g} {TAU_MAX[j]:g}"/>'
                f'{"".join(geoms[i])}{inner}</body>')

    fa, fd, _ = DH[7]
    rod_r = ROD_RADIUS
    # the tool's capsules stop short of the tip so that only the fingertip sphere touches;
    # the pin is its last PIN_LENGTH, and all of a tool whose rod would be under 1 mm (MuJoCo
    # refuses a capsule whose ends nearly coincide)
    rod_end = rod_length - 0.016
    pin_top = rod_end - PIN_LENGTH
    if pin_top < 0.001:
        pin_top = 0.0
    i_rod = ROD_MASS * rod_length**2 / 12.0
    rod = (f'<body name="{prefix}rod" pos="{fa:g} 0 {fd:g}" gravcomp="1">'
           f'<inertial pos="0 0 {rod_length / 2:.6g}" mass="{ROD_MASS:g}" '
           f'diaginertia="{i_rod:.6g} {i_rod:.6g} 1e-6"/>'
           + (f'<geom name="{prefix}rod" type="capsule" fromto="0 0 0 0 0 {pin_top:.6g}" '
              f'size="{rod_r:g}" class="{prefix}link" rgba="0.7 0.7 0.72 1"/>'
              if pin_top > 0.0 else '')
           + f'<geom name="{prefix}pin" type="capsule" '
           f'fromto="0 0 {pin_top:.6g} 0 0 {rod_end:.6g}" '
           f'size="{PIN_RADIUS:g}" class="{prefix}link" rgba="0.6 0.6 0.62 1"/>'
           f'<site name="{prefix}tip" pos="0 0 {rod_length:.6g}" size="0.003"/></body>')
    tree = rod
    for i in range(7, -1, -1):
        tree = body(i, tree)
    acts = []
    for i in range(1, 8):
        j = i - 1
        acts.append(f'<position name="{prefix}joint{i}" joint="{prefix}joint{i}" '
                    f'kp="{KP[j]:g}" ctrlrange="{Q_MIN[j]:g} {Q_MAX[j]:g}"/>')
        acts.append(f'<velocity name="{prefix}joint{i}_v" joint="{prefix}joint{i}" '
                    f'kv="{KV[j]:g}" ctrlrange="{-DQ_MAX[j]:g} {DQ_MAX[j]:g}"/>')
    home = " ".join(f"{v:g}" for v in Q_HOME)
    return f"""<mujoco model="{prefix}panda-finger">
  <!-- Written by nonprehensile (sim/panda.py) from published parameters: kinematics and
       joint position, velocity and torque limits from Franka's documentation of the Panda
       (Franka Control Interface, "Robot and interface specifications": Denavit-Hartenberg
       parameters and joint-space limits); inertial parameters of links 1-7 from C. Gaz et
       al., "Dynamic Identification of the Franka Emika Panda Robot With Retrieval of Feasible
       Parameters Using Penalty-Based Optimization", IEEE RA-L 4(4), 2019. Collision capsules,
       armature, damping and the finger rod are the project's modelling choices
       (docs/robot.md). -->
  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>
  <option integrator="implicitfast"/>
  <default>
    <default class="{prefix}link">
      <geom contype="0" conaffinity="0" rgba="0.92 0.92 0.92 1" group="3"/>
    </default>
    <joint axis="0 0 1" armature="{ARMATURE:g}" damping="{DAMPING:g}"
           actuatorgravcomp="true"/>
  </default>
  <worldbody>{tree}</worldbody>
  <actuator>{"".join(acts)}</actuator>
  <keyframe><key name="home" qpos="{home}" ctrl="{" ".join(f"{v:g} 0" for v in Q_HOME)}"/>
  </keyframe>
</mujoco>
"""
