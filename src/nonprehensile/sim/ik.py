"""Differential inverse kinematics of the fingertips with mink, one solve per control step.

:class:`FingertipIK` holds a kinematic copy of the robot scene (the object a mocap body, moved
to where the simulation says the object is before each solve) and mink's tasks and limits:

* a position task per fingertip site (the fingertip's centre on its target);
* an axis-alignment task per fingertip: the site's +z (out of the finger) pointing down,
  soft (the recorded finger direction is not used: the motion library keeps tip markers);
  where the target lies below the object's top (a push or a pinch on a side face) the
  finger leans inwards by ``side_tilt_deg``, so that the rod above the fingertip stands
  clear of the face instead of grazing it (a vertical 8 mm rod above a 6 mm tip sphere
  touching a face had 2 mm of clearance, less than the contact's own penetration and
  the collision limit's detection distance: the limit then fought the position task and
  the arm chattered against the object; the bundled tool now ends in a 5 mm pin);
* posture regularisation towards the robot's home configuration;
* limits: joint positions, joint velocities (the datasheet's, or the user's), and collision
  avoidance of every link and the tool (rod, pin) against the object and the table (the
  base against the object only).

The QP is solved by daqp through qpsolvers. mink is imported lazily (extra ``robot``).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.sim.robot_scene import RobotScene

__all__ = ["FingertipIK", "IKConfig", "import_mink"]

FloatArray = NDArray[np.float64]

#: The fastest fingertip target motion (m/s) fed forward; faster is a jump.
_FEED_SPEED = 1.0

#: The cross product ``w x z`` of the pointing task's Jacobian as gathers: the rows of the
#: angular Jacobian and the entries of the site's row-major rotation (z: entries 2, 5, 8)
#: of its two products, the first product's three rows then the second's (one gather each).
_CROSS_ROWS = np.array([1, 2, 0, 2, 0, 1])
_CROSS_Z = np.array([8, 2, 5, 5, 8, 2])

#: The reductions ``ndarray.sum`` and ``max`` call (the same numbers), without the Python
#: wrappers around them: the solve's hot path makes a few each time.
_SUM, _MAX = np.add.reduce, np.maximum.reduce


def import_mink() -> Any:
    """mink, or an :class:`InputError` saying how to install it."""
    try:
        import mink
        import qpsolvers
    except ImportError as exc:
        raise InputError(f"robot arms need mink: pip install 'nonprehensile[robot]' ({exc})"
                         ) from None
    if "daqp" not in qpsolvers.available_solvers:
        raise InputError("robot arms need the daqp QP solver: pip install 'nonprehensile[robot]'")
    return mink


@dataclass(frozen=True)
class IKConfig:
    """Weights, gains and limits of the fingertip IK.

    Attributes
    ----------
    position_cost : float
        Fingertip position task weight (per metre).
    pointing_cost : float
        Weight of the fingertip pointing down (per unit of axis error).
    posture_cost : float
        Posture regularisation weight (per radian).
    posture_gain : float
        Fraction of the posture error corrected per control step (0.001 at 1 kHz: a 1 s
        time constant; at 1 the null space would swing to the home posture at the velocity
        limit). A placement (:meth:`FingertipIK.converge`) settles the posture fully.
    damping : float
        Levenberg-Marquardt damping of the QP.
    collision_margin : float
        Least distance (m) the IK keeps between a link or the tool and the object or the table.
        1.5 mm: the arm's fingertip noise (1 mm standard deviation across the physics
        distribution) moves the whole tool off the IK's solution, and the object tracker's
        noise (0.5 mm) moves the object the IK sees; at 1 mm a pin reaching over the cube's
        top edge to push its far face rested on that edge for 1.2 s in one of the main plan's
        100 samples of seed 0 (none of seed 0 at 1.5 mm, and 96/100 reached the goal against
        94; one of seed 1, 100 ms).
    collision_detection : float
        Distance (m) from which a collision constraint is active.
    collision_gain : float
        How fast geoms may approach each other, in (0, 1].
    collisions : bool
        Whether to avoid collisions at all (the base search skips them for speed).
    side_tilt_deg : float
        How far from vertical the finger leans towards the object's vertical axis where its
        target lies at or below the object's top (a side face).
    side_tilt_outward : float or None
        The lean's direction, between the arm's base (0) and straight out of the object's
        vertical axis at the target (1), normalised; None: 0.5 with several fingertips, 0
        with one. Leaning towards the base alone, a pinch of two diagonally placed arms put
        the rod 5 degrees off a face 15 mm above the tip, against the face's top edge (rod
        contact in all 24 twists of the two-arm sweep); straight out, the wrist follows the
        face round in a twist to its joint limits. One arm keeps 0: at 0.5, 15 of the 24
        single-arm roll-pulls held a torque limit for 11-12 ms (none did at 0).
    tumble_tilt_deg : float
        ``side_tilt_deg`` while several fingertips pinch an object they tumble (a step whose
        start and end faces differ: :meth:`FingertipIK.set_tumbling`). Lifting a cube onto
        its vertex tilts the pinched face over the finger by up to 19 degrees while the pad
        presses 4.6 mm into it (the tip's centre 1.4 mm outside the face), and at 30 degrees
        the rod's lower end, 16 mm above the tip, touched the face in every two-arm
        tumble-twist; the retries that followed put a rod on the cube for up to 1.2 s (the
        arm saturated at its velocity bound, the soft pointing given up by 10-15 degrees).
        A lean that follows the face's tilt comes too late (the pointing's rate bounds) and
        holds the wrists at their limits; the twists keep 30 (at 36 the twist:reverse's
        let-go tracked 6 mm, not 3.5).
    side_tilt_band : float
        The lean grows from none ``side_tilt_band`` m above the top to full at the top (and
        from none on the object's vertical axis to full this far from it).
    joint_accel : float
        The IK's joint acceleration bound, rad/s^2 (``inf``: none): the servos follow set
        points whose velocity changes smoothly (a step ``dv`` in the feed-forward is a torque
        step ``kv dv``; when the velocity margin let a transit's tip catch up, the sudden stop
        held the shoulder, elbow and wrist at their torque limits for 11 ms). It gives way
        where it conflicts with the position or velocity limits.
    velocity_fraction : float
        The IK moves each joint at most this fraction of its velocity limit (a margin for
        the servo's overshoot: a joint asked for its full limit runs at it, and a fast
        transit of an extended arm would hold the elbow there for ~0.1 s).
    position_margin_deg : float
        The IK keeps each joint this far (degrees) inside its range, a joint inside the
        margin coming back out at 0.2 rad/s (a joint within 0.5 degrees of an end counts as
        at its limit, :data:`~nonprehensile.sim.robot_driver.LIMIT_BANDS`): an arm waiting
        at its rest had drifted, along its null space, to its elbow's stretched end and held
        it there for 11.5 s.
    tilt_rate, tilt_accel : float
        The pointing direction's fastest turn, rad/s, and its angular acceleration, rad/s^2.
    task_time_constant : float
        Time constant (s) with which the fingertip tasks correct an error; the target's own
        motion since the last solve is fed forward (``J dq = dx_target - (dt / tau) e``), so
        a moving target is followed without lag. ``0`` is dead-beat (the whole error in one
        step, no feed-forward), as mink's default task gain 1; a control step as long as
        ``tau`` or longer (the default 100 Hz, and 125 Hz) is dead-beat too. Dead-beat with
        the joint acceleration bound rings: a one-step QP asks for whatever velocity closes
        the error now, the bound lets it build up over many steps and cannot brake it in
        time, and
        the wrists swung between +-2.35 rad/s at 30 rad/s^2 (at their 12 N m limit) after a
        two-arm tumble-lift while both tips stayed on target (the other joints compensating).
    """

    position_cost: float = 1.0
    pointing_cost: float = 0.05
    posture_cost: float = 1e-3
    posture_gain: float = 0.001
    damping: float = 1e-5
    collision_margin: float = 0.0015
    collision_detection: float = 0.02
    collision_gain: float = 0.5
    collisions: bool = True
    side_tilt_deg: float = 30.0
    side_tilt_outward: float | None = None
    tumble_tilt_deg: float = 36.0
    side_tilt_band: float = 0.02
    tilt_rate: float = 1.0
    tilt_accel: float = 4.0
    velocity_fraction: float = 0.9
    position_margin_deg: float = 1.0
    joint_accel: float = 30.0
    task_time_constant: float = 0.008

    def __post_init__(self) -> None:
        # a NaN or a sign error here becomes NaN bounds or a flipped lean inside the QP, far
        # from the setting that caused it: refuse it here, naming the setting
        ranges = {"collision_gain": (0.0, 1.0, False), "side_tilt_outward": (0.0, 1.0, True),
                  "velocity_fraction": (0.0, 1.0, False),
                  "position_margin_deg": (0.0, 10.0, True), "side_tilt_deg": (0.0, 90.0, True),
                  "tumble_tilt_deg": (0.0, 90.0, True)}
        for name, value in asdict(self).items():
            if name == "collisions":
                if not isinstance(value, bool):
                    raise InputError(f"IK setting collisions must be True or False, got "
                                     f"{value!r}")
                continue
            if name == "side_tilt_outward" and value is None:
                continue
            ok = (not isinstance(value, bool) and isinstance(value, (int, float))
                  and not math.isnan(value) and value >= 0
                  and (math.isfinite(value) or name == "joint_accel"))
            lo, hi, closed = ranges.get(name, (0.0, math.inf, True))
            if ok and name in ranges:
                ok = value <= hi and (closed or value > lo)
            if not ok:
                kind = ("a number >= 0 (inf: no bound)" if name == "joint_accel"
                        else "a finite number >= 0")
                where = f" in {'[' if closed else '('}{lo:g}, {hi:g}]" if name in ranges else ""
                raise InputError(f"IK setting {name} must be {kind}{where}, got {value!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return asdict(self)


def _joint_box_limit(mink: Any, scene: RobotScene, gain: float = 0.95,
                     velocity_fraction: float = 1.0, accel: float = math.inf,
                     margin: float = 0.0, back_speed: float = 0.2) -> Any:
    """Joint position, velocity and acceleration limits as one box on the step ``dq``:
    ``max(-v dt, gain (lo - q), (v_prev - a dt) dt) <= dq <= min(v dt, gain (hi - q),
    (v_prev + a dt) dt)`` (``v_prev``: the last solve's joint velocities, attribute ``prev``;
    the acceleration rows give way where they conflict with the others), and, with an
    acceleration bound, ``|dq| <= dt sqrt(2 a d)`` towards an end ``d`` away: a joint comes
    no faster to its end than the bound can stop it there. ``lo`` and ``hi``
    are the joint's range narrowed by ``margin`` (rad) at each end; a joint inside that
    margin is brought back out at ``back_speed`` (rad/s) at most, not in one step.

    The same bounds as mink's ``ConfigurationLimit`` (its default gain) and
    ``VelocityLimit`` together, in one constraint of ``2 n`` rows instead of two: a quarter of
    the solve time went to building those two (the IK scene has only the robot's joints, each
    one degree of freedom: mocap object).
    """

    two_a = 2.0 * accel  # (as ``2.0 * accel * x`` evaluates it: the scalar product first)

    class JointBoxLimit(mink.Limit):  # type: ignore[misc]
        def __init__(self) -> None:
            n = scene.model.nv
            # the range narrowed by the margin (never past its middle)
            half = np.maximum((scene.upper - scene.lower) / 2.0 - 1e-6, 0.0)
            self.lower = scene.lower + np.minimum(margin, half)
            self.upper = scene.upper - np.minimum(margin, half)
            self.back = back_speed
            self.velocity = scene.velocity * velocity_fraction
            self.qadr = scene.qadr
            self.dadr = scene.dadr
            self.n = n
            self.G = np.vstack([np.eye(n), -np.eye(n)])
            self.prev = np.zeros(len(self.dadr))
            self.identity = bool(len(self.dadr) == n and np.array_equal(self.dadr, np.arange(n))
                                 and np.array_equal(self.qadr, np.arange(n)))
            self._dt = math.nan  # the period of the products below (bounds)
            self._back_dt = 0.0
            self._vdt: list[float] = []
            # the joints' numbers as lists (bounds: plain Python per joint)
            self._upper_list = self.upper.tolist()
            self._lower_list = self.lower.tolist()
            # the room past which the stopping bound ``sqrt(2 a room)`` exceeds the velocity
            # bound (bounds), with a relative margin far above the rounding of either; no
            # acceleration bound: never (-inf), a bound of 0: always (+inf)
            self._free_list = ((self.velocity * self.velocity / two_a * (1.0 + 1e-9)).tolist()
                               if math.isfinite(accel) and accel > 0.0
                               else [-math.inf if not math.isfinite(accel) else math.inf]
                               * len(self.qadr))

        def bounds(self, qpos: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
            """``(upper, lower)`` bounds on the step ``dq``, shape (nv,) each."""
            up, down = self.steps(qpos, dt)
            if self.identity:  # the IK scene's joints are its degrees of freedom, in order
                return np.array(up), -np.array(down)
            # (a degree of freedom that is not one of the robot's joints, the object's free
            # joint in the physical scene, does not move: before, np.empty left whatever
            # memory held; the IK's own scene has none such)
            upper = np.zeros(self.n)
            lower = np.zeros(self.n)
            upper[self.dadr] = up
            lower[self.dadr] = -np.array(down)
            return upper, lower

        def steps(self, qpos: FloatArray, dt: float) -> tuple[list[float], list[float]]:
            """The bounds of :meth:`bounds` per robot joint (scene order), as lists: the
            largest step up and the largest step down (positive down), rad."""
            q = (qpos if self.identity else qpos[self.qadr]).tolist()
            if dt != self._dt:  # the products with dt, once per control period
                self._dt = dt
                self._back_dt = -self.back * dt
                self._vdt = (self.velocity * dt).tolist()
            # per joint in plain Python (this runs every solve, on a handful of joints:
            # numpy calls on 7 numbers cost more than the arithmetic, a sixth of a solve),
            # the same IEEE operations in the same order as on arrays, so the same numbers.
            # Each joint's up bound, then its down bound (as a positive step down): the room
            # to its end (``hi - q``, ``q - lo``; a joint outside its range may only move
            # back in, as with mink's own limit), times the gain; no faster towards the end
            # than the acceleration bound can stop in the room left, sqrt(2 a room) (the
            # gain alone let the wrist come to its margin at 1.5 rad/s, then brake at
            # 100 rad/s^2 at its torque limit): computed only within the free room of the end,
            # past which it is above the velocity bound, which then decides alone (rounding
            # is monotone and the threshold has a margin); then within ``[-back dt, v dt]``
            # (inside the margin, negative room: back out at ``back_speed`` at most)
            back, gain_ = self._back_dt, gain
            finite = math.isfinite(accel)
            adt = accel * dt
            up: list[float] = []
            down: list[float] = []
            # (the acceleration bounds below; a no-bound's rows are never read)
            au: list[float] = []
            ad: list[float] = []
            squeezed = False
            for x, hi, lo, vdt, free, p in zip(q, self._upper_list, self._lower_list,
                                               self._vdt, self._free_list, self.prev.tolist(),
                                               strict=True):
                u = hi - x
                if not u - free >= 0.0:  # near the end (NaN included)
                    u = min(u * gain_, math.sqrt(max(u, 0.0) * two_a) * dt)
                else:
                    u = u * gain_
                u = vdt if u > vdt else back if u < back else u
                w = x - lo
                if not w - free >= 0.0:
                    w = min(w * gain_, math.sqrt(max(w, 0.0) * two_a) * dt)
                else:
                    w = w * gain_
                w = vdt if w > vdt else back if w < back else w
                up.append(u)
                down.append(w)
                if finite:
                    # the acceleration bounds ``(prev + a dt) dt`` up and ``(a dt - prev)
                    # dt`` down (``min(u, t)`` written out: ``t`` only where ``t < u``, as
                    # the builtin keeps its first argument, NaN included)
                    a = (p + adt) * dt
                    a = a if a < u else u
                    b = (-p + adt) * dt
                    b = b if b < w else w
                    au.append(a)
                    ad.append(b)
                    squeezed = squeezed or not a + b >= 0.0
            if finite:
                # they give way to the others where together they leave no room (their sum
                # negative, NaN included), on the joints where they do if any does
                if not squeezed:
                    up, down = au, ad
                else:
                    for i, (a, b) in enumerate(zip(au, ad, strict=True)):
                        if a + b >= 0.0:
                            up[i], down[i] = a, b
            return up, down

        def compute_qp_inequalities(self, configuration: Any, dt: float) -> Any:
            upper, lower = self.bounds(configuration.q, dt)
            # rows: dq[dof] <= upper, then -dq[dof] <= -lower
            return mink.limits.Constraint(G=self.G, h=np.concatenate([upper, -lower]))

    return JointBoxLimit()


def _fingertip_task(mink: Any, model: Any, site: int, position_cost: float,
                    pointing_cost: float) -> Any:
    """One fingertip's task: its centre on the target and its +z axis pointing down.

    Error ``[p - target, z - (0, 0, -1)]`` (6), Jacobian ``[J_p; -[z]x J_r]`` from one
    ``mj_jacSite`` (the pointing rows have rank 2: the roll about the finger stays free).
    mink's ``FrameTask`` (zero orientation cost) with an ``AxisAlignTask`` give the same
    least-squares problem; this computes it with one Jacobian call instead of three (the
    IK's time per solve went from 0.12 to about 0.09 ms).

    The pointing direction is the task's ``axis`` (unit, world), set before each solve.
    ``feed`` (6: the target's and the axis's change since the last solve) is fed forward:
    mink minimises ``|J dq + gain e|``, so the error returned is ``e - feed / gain`` and the
    step asks for ``J dq = feed - gain e``.
    """

    class FingertipTask(mink.Task):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__(cost=np.array([position_cost] * 3 + [pointing_cost] * 3,
                                           dtype=np.float64))
            self.target = np.zeros(3)
            self.axis = np.array([0.0, 0.0, -1.0])
            self.feed = np.zeros(6)
            self._jr = np.zeros((3, model.nv))
            self._j = np.zeros((6, model.nv))
            # views made once (every solve runs these two methods): the Jacobian's position
            # rows, written by mj_jacSite in place; the gathered rows of the cross product,
            # its two halves, its gathered rotation entries as a column
            self._e = np.zeros(6)
            self._e_p, self._e_z = self._e[:3], self._e[3:]
            self._jp = self._j[:3]
            self._jz = self._j[3:]
            self._cross = np.zeros((6, model.nv))
            self._ca, self._cb = self._cross[:3], self._cross[3:]
            self._z = np.zeros(6)
            self._zcol = self._z[:, None]
            self._data: Any = None  # the data whose site views are below
            self._xpos: FloatArray = np.zeros(3)
            self._xmat: FloatArray = np.zeros(9)
            self._zaxis: FloatArray = np.zeros(3)

        def _views(self, d: Any) -> None:
            """The site's position and rotation in ``d`` as views (MjData's arrays never
            move: made once per data, not every solve)."""
            self._data = d
            self._xpos = d.site_xpos[site]
            self._xmat = d.site_xmat[site]
            self._zaxis = self._xmat[2::3]  # z, the rotation's third column

        def compute_error(self, configuration: Any) -> FloatArray:
            d = configuration.data
            if d is not self._data:
                self._views(d)
            # (a buffer and its halves made once: the error is read at once, by the QP's
            # assembly or mink's)
            e = self._e
            np.subtract(self._xpos, self.target, out=self._e_p)
            np.subtract(self._zaxis, self.axis, out=self._e_z)
            if self.gain < 1.0:
                e -= self.feed / self.gain
            return e

        def compute_jacobian(self, configuration: Any) -> FloatArray:
            d = configuration.data
            if d is not self._data:
                self._views(d)
            jr = self._jr
            mujoco.mj_jacSite(model, d, self._jp, jr, site)
            # d z / dt = w x z: rows jr[1] z2 - jr[2] z1, jr[2] z0 - jr[0] z2,
            # jr[0] z1 - jr[1] z0, as one product of gathered rows and their difference
            # (the same numbers)
            jr.take(_CROSS_ROWS, axis=0, out=self._cross)
            self._xmat.take(_CROSS_Z, out=self._z)
            self._cross *= self._zcol
            np.subtract(self._ca, self._cb, out=self._jz)
            return self._j

    return FingertipTask()


class FingertipIK:
    """mink IK over a kinematic robot scene (from
    :func:`~nonprehensile.sim.robot_scene.build_robot_scene` with ``mocap_object=True``).

    Parameters
    ----------
    scene : RobotScene
    dt : float
        Control period, s (the IK's integration step).
    config : IKConfig

    Attributes
    ----------
    q : ndarray, shape (n_joints,)
        The IK's joint positions (the set points), scene joint order.
    solve_times : list of float
        Seconds per solve, since the last :meth:`reset`.
    """

    def __init__(self, scene: RobotScene, dt: float, config: IKConfig | None = None) -> None:
        mink = import_mink()
        self.mink = mink
        self.scene = scene
        self.dt = float(dt)
        #: The control period (s) the task time constant is compared with: a driver that
        #: solves every ``k`` physics steps sets it to ``k dt`` (a trajectory's last, shorter
        #: segments then stay dead-beat at a rate that is dead-beat).
        self.period = float(dt)
        self.config = config or IKConfig()
        m = scene.model
        if m.nq != len(scene.qadr):
            raise InputError("the IK scene must hold the robot joints only (mocap object)")
        # mink's collision limit honours contype/conaffinity: this copy is never stepped
        for name in (*scene.collision_geoms, "object", "table"):
            gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
            m.geom_contype[gid] = 1
            m.geom_conaffinity[gid] = 1
        self.configuration = mink.Configuration(m)
        cfg = self.config
        self.tip_names = [m.site(int(s)).name for s in scene.tip_sites]
        self._tip_index = np.array([int(s) for s in scene.tip_sites], dtype=np.int64)
        self.position_tasks = [_fingertip_task(mink, m, int(sid), cfg.position_cost,
                                               cfg.pointing_cost)
                               for sid in scene.tip_sites]
        self.posture = mink.PostureTask(m, cost=cfg.posture_cost, gain=cfg.posture_gain)
        q_home = np.zeros(m.nq)
        q_home[scene.qadr] = scene.home
        self.posture.set_target(q_home)
        self.tasks = [*self.position_tasks, self.posture]
        self._box = _joint_box_limit(mink, scene, velocity_fraction=cfg.velocity_fraction,
                                     accel=cfg.joint_accel,
                                     margin=math.radians(cfg.position_margin_deg))
        self.limits: list[Any] = [self._box]
        if cfg.collisions:
            links_obj = list(scene.collision_geoms)
            pairs = [(links_obj, ["object"])]
            if scene.table_geoms:
                pairs.append((list(scene.table_geoms), ["table"]))
            self.limits.append(mink.CollisionAvoidanceLimit(
                m, geom_pairs=pairs, gain=cfg.collision_gain,
                minimum_distance_from_collisions=cfg.collision_margin,
                collision_detection_distance=cfg.collision_detection))
        # the fast QP assembly (:meth:`_solve`)
        import daqp
        from mink.limits.collision_avoidance_limit import compute_contact_normal_jacobian

        self._daqp = daqp
        self._contact_jacobian = compute_contact_normal_jacobian
        self._coll: Any = self.limits[1] if cfg.collisions else None
        self._nv = m.nv
        if m.nq != m.nv or not np.all(np.isin(m.jnt_type, (mujoco.mjtJoint.mjJNT_HINGE,
                                                            mujoco.mjtJoint.mjJNT_SLIDE))):
            raise InputError("the IK handles hinge and slide joints only (a ball or free "
                             "joint in the robot file): give the robot hinge joints")
        rows = sum(len(t.cost) for t in self.position_tasks)
        self._w = np.zeros((rows, m.nv))
        self._wT = self._w.T  # (a view, made once)
        self._we = np.zeros(rows)
        # each fingertip task's rows of ``_w`` and ``_we`` (views) with its weights, as a
        # vector and a column (_solve)
        self._task_rows: list[tuple[Any, FloatArray, FloatArray, FloatArray, FloatArray]] = []
        r = 0
        for t in self.position_tasks:
            k = len(t.cost)
            self._task_rows.append((t, self._w[r:r + k], self._we[r:r + k], t.cost,
                                    t.cost[:, None]))
            r += k
        self._no_rows = np.zeros((0, m.nv))
        # the IK data's joint positions, a view made once (each read of an MjData array
        # attribute builds a new array object; mink's configuration keeps its data)
        self._qpos: FloatArray = self.configuration.data.qpos
        # the usual scene: the robot's joints are its degrees of freedom in order, and no
        # equality constraint (step integrates without mink's wrappers)
        self._plain = bool(m.neq == 0 and np.array_equal(scene.qadr, np.arange(m.nq))
                           and np.array_equal(scene.dadr, np.arange(m.nv)))
        self._post_gain = math.nan  # the posture gain of the two arrays below (_solve)
        #: The QP's Levenberg-Marquardt damping during :meth:`converge` (see there); None:
        #: ``config.damping``, read at every solve
        self._damping: float | None = None
        self._post_damping = math.nan  # the damping of the two arrays below (_solve)
        self._post_diag = self._post_lin = np.zeros(m.nv)
        self._sense: dict[int, NDArray[np.intc]] = {}  # daqp's constraint kinds (all bounds)
        self._no_lower = np.full(len(self.limits[1].geom_id_pairs) if cfg.collisions else 0,
                                 -1e30)  # a collision row's lower bound: none
        self._no_lower_list: list[float] = self._no_lower.tolist()
        self._jac1 = np.empty((3, m.nv))
        self._fromto, self._normal = np.empty(6), np.empty(3)
        self._jac2 = np.empty((3, m.nv))
        self._obj = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
        self._mocap = int(m.body_mocapid[self._obj])
        # the object's geoms with their poses in its body frame (set_object poses them)
        self._obj_rot = np.empty(9)
        # the last set_object's arguments, data, position and the geoms' rows it wrote
        # (set_object_kept)
        self._posed: tuple[Any, Any, Any, FloatArray,
                           list[tuple[FloatArray, FloatArray, FloatArray, FloatArray]]] | None
        self._posed = None
        self._obj_r = self._obj_rot.reshape(3, 3)  # (a view: written by set_object)
        self._pose_data: Any = None  # the data whose views set_object writes (_pose_views)
        self._pose_rows: tuple[FloatArray, ...] = ()
        self._pose_geoms: list[tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = []
        self._obj_geoms = []
        for gid in np.flatnonzero(m.geom_bodyid == self._obj):
            gmat = np.empty(9)
            mujoco.mju_quat2Mat(gmat, m.geom_quat[gid])
            self._obj_geoms.append((int(gid), np.array(m.geom_pos[gid]), gmat.reshape(3, 3)))
        # the object's vertices in its body frame (the mesh is stored about its own frame)
        g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object")
        mesh = int(m.geom_dataid[g])
        verts = m.mesh_vert[m.mesh_vertadr[mesh]:m.mesh_vertadr[mesh] + m.mesh_vertnum[mesh]]
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, m.geom_quat[g])
        self._verts = np.asarray(verts, dtype=np.float64) @ rot.reshape(3, 3).T + m.geom_pos[g]
        self._vmean = self._verts.mean(axis=0)
        self._reach = float(np.linalg.norm(self._verts, axis=1).max())  # (pointing)
        self._rot = np.empty(9)
        # set_object counts the poses it sets; pointing derives the object's top height and
        # centre (x, y) once per pose (a key made of the pose's floats cost more than the
        # rest of the pointing)
        self._pose_version = 0
        self._top_version = -1
        self._pose_top = (0.0, 0.0, 0.0)
        self._band = max(self.config.side_tilt_band, 1e-6)
        self._down = np.tile((0.0, 0.0, -1.0), (len(scene.tip_sites), 1))  # (copied)
        # the recorded finger directions that override the rule (set_pointing): the fingers'
        # indices and a row per finger, or None
        self._override: tuple[list[int], FloatArray] | None = None
        self._tilt = float(np.radians(self.config.side_tilt_deg))
        self._tilt_side = self._tilt  # (set_tumbling switches between the two)
        self._tilt_tumble = float(np.radians(self.config.tumble_tilt_deg))
        w_out = self.config.side_tilt_outward
        self._lean_out = float(w_out if w_out is not None
                               else (0.5 if len(scene.tip_sites) > 1 else 0.0))
        # each fingertip's arm base (the root body below the world), xy
        full = np.zeros(m.nq)
        full[scene.qadr] = scene.home
        self.configuration.update(full)
        bases = []
        for sid in scene.tip_sites:
            body = int(m.site_bodyid[int(sid)])
            while int(m.body_parentid[body]) != 0:
                body = int(m.body_parentid[body])
            bases.append(np.array(self.configuration.data.xpos[body][:2]))
        self._bases = [(float(b[0]), float(b[1])) for b in bases]
        if self._coll is not None:
            self._init_broad_phase()
        self.solve_times: list[float] = []
        #: QPs that had no solution (the step braked, see :meth:`_brake`), since construction
        self.infeasible = 0
        self.reset(scene.home)

    # -------------------------------------------------------------------------- state
    @property
    def bases(self) -> list[tuple[float, float]]:
        """Each fingertip's arm base (the root body below the world), x and y in m, finger
        order: where the lean of :meth:`lean` points back to."""
        return list(self._bases)

    @property
    def q(self) -> FloatArray:
        """The IK's joint positions, scene joint order."""
        # (one gather of the data's qpos: mink's ``q`` is a copy of it first)
        return np.asarray(self.configuration.data.qpos[self.scene.qadr], dtype=np.float64)

    def reset(self, q: FloatArray) -> None:
        """Start from joint positions ``q`` (scene joint order)."""
        full = np.zeros(self.scene.model.nq)
        full[self.scene.qadr] = np.clip(q, self.scene.lower, self.scene.upper)
        self.configuration.update(full)
        self.solve_times = []
        for task in self.position_tasks:  # pointing down again, not turning
            task.axis = np.array([0.0, 0.0, -1.0])
        self._override = None  # no recorded directions left from a previous run
        self._turn = [0.0] * len(self.position_tasks)
        self._box.prev = np.zeros(len(self.scene.dadr))  # at rest
        self._fed = False  # no previous target to feed forward from
        self._deadbeat = False
        self._tilt = self._tilt_side  # a new start leans as on a side face (set_tumbling)

    def set_q(self, q: FloatArray, velocity: FloatArray | None = None) -> None:
        """Carry on from joint positions ``q`` (scene joint order), keeping the timings;
        ``velocity``: the joints' velocity there (the acceleration bound's reference),
        instead of the last step's."""
        full = np.array(self.configuration.q)
        full[self.scene.qadr] = np.clip(q, self.scene.lower, self.scene.upper)
        self.configuration.update(full)
        if velocity is not None:
            self._box.prev = np.array(velocity, dtype=np.float64)

    def set_object(self, position: FloatArray, quat: FloatArray) -> None:
        """Where the object is now (the body's origin and ``(w, x, y, z)`` orientation)."""
        d = self.configuration.data
        if d is not self._pose_data:
            self._pose_views(d)
        mpos, mquat, xpos, xquat, xmat = self._pose_rows
        mpos[:] = position
        mquat[:] = quat
        # the object's body and geoms posed now: the collision rows read the geoms' poses,
        # which MuJoCo's kinematics would derive from the mocap pose only at the next
        # configuration update (after this solve's integration), so the rows saw the
        # object where the previous solve had set it (measured on the main plan: 437 of
        # 1,336 solves, up to 3.95 mm off)
        rot = self._obj_rot
        mujoco.mju_quat2Mat(rot, np.asarray(quat, dtype=np.float64))
        r = self._obj_r
        p = np.asarray(position, dtype=np.float64)
        xpos[:] = p
        xquat[:] = quat
        xmat[:] = rot
        posed = []
        for gx, gm, gpos, gmat in self._pose_geoms:
            gp = p + r @ gpos
            gr = (r @ gmat).ravel()
            gx[:] = gp
            gm[:] = gr
            posed.append((gx, gm, gp, gr))
        self._posed = (position, quat, d, p, posed)
        self._pose_version += 1

    def set_object_kept(self, position: FloatArray, quat: FloatArray) -> None:
        """:meth:`set_object` for a caller that never changes ``position`` and ``quat`` in
        place (a new pair of arrays for each new pose): given the very arrays of the last
        :meth:`set_object`, the rows it wrote are written again as they were (the
        kinematics of each step writes MuJoCo's own products over them), with no rotation
        derived and no new pose counted (the pointing keeps the object's top). The same
        numbers as :meth:`set_object`: the closed loop's solves between two observations
        see the same pose (a third of the main plan's)."""
        got = self._posed
        d = self.configuration.data
        if got is None or got[0] is not position or got[1] is not quat or got[2] is not d:
            self.set_object(position, quat)
            return
        _, _, xpos, xquat, xmat = self._pose_rows
        xpos[:] = got[3]
        xquat[:] = quat
        xmat[:] = self._obj_rot
        for gx, gm, gp, gr in got[4]:
            gx[:] = gp
            gm[:] = gr

    def _pose_views(self, d: Any) -> None:
        """The rows :meth:`set_object` writes, as views into ``d`` (MjData's arrays never
        move: made once per data, not at every solve; each attribute read of the data
        costs about as much as the row's write)."""
        self._pose_data = d
        mo, ob = self._mocap, self._obj
        self._pose_rows = (d.mocap_pos[mo], d.mocap_quat[mo], d.xpos[ob], d.xquat[ob],
                           d.xmat[ob])
        self._pose_geoms = [(d.geom_xpos[g], d.geom_xmat[g], gpos, gmat)
                            for g, gpos, gmat in self._obj_geoms]

    def set_tumbling(self, tumbling: bool) -> None:
        """Whether the fingertips now pinch an object they tumble: the side lean is then
        ``tumble_tilt_deg`` instead of ``side_tilt_deg`` (several fingertips only; one
        fingertip keeps ``side_tilt_deg``). The pointing turns to the new lean at its own
        rate bounds."""
        several = len(self.position_tasks) > 1
        self._tilt = self._tilt_tumble if tumbling and several else self._tilt_side

    def tips(self) -> FloatArray:
        """The IK's fingertip positions, shape (n_fingers, 3)."""
        # one gather (a copy), not an array of per-site views: a placement calls this at
        # every iteration
        return np.asarray(self.configuration.data.site_xpos[self._tip_index],
                          dtype=np.float64)

    def set_pointing(self, directions: FloatArray | None) -> None:
        """Point the fingers along ``directions`` (shape (n_fingers, 3), world; a finger's
        row of zeros, or None for all: :meth:`pointing`'s own rule) from the next solve on:
        the recorded finger directions of the reference being run (the knuckle markers).
        The pointing task still turns towards them at its bounded rate."""
        if directions is None:
            self._override = None
            return
        d = np.asarray(directions, dtype=np.float64)
        n = len(self.position_tasks)
        if d.shape != (n, 3) or not np.isfinite(d).all():
            raise InputError(f"set_pointing takes finite directions of shape ({n}, 3), one "
                             f"row per finger (zeros: the rule), or None; got shape "
                             f"{d.shape}" + ("" if np.isfinite(d).all()
                                             else " with values that are not finite"))
        norm = np.sqrt((d * d).sum(axis=1))
        given = norm > 1e-9
        if not given.any():
            self._override = None
            return
        out = np.zeros_like(d)
        out[given] = d[given] / norm[given, None]
        self._override = (np.flatnonzero(given).tolist(), out)

    def pointing(self, targets: FloatArray) -> FloatArray:
        """The fingers' pointing directions (unit, world) for ``targets`` (shape
        (n_fingers, 3)), shape (n_fingers, 3): those set by :meth:`set_pointing` where
        given, else :meth:`lean`'s."""
        out = self.lean(targets)
        got = self._override
        if got is not None:
            rows, dirs = got
            out = np.array(out)
            for k in rows:  # (set_pointing checked one row per finger)
                out[k] = dirs[k]
        return out

    def lean(self, targets: FloatArray) -> FloatArray:
        """The fingers' pointing directions (unit, world) by the geometric rule, for
        ``targets`` (shape (n_fingers, 3)), shape (n_fingers, 3).

        Down, except where a target lies at or below the object's top beside it (a side
        face): there the rod leans back towards its arm's base by up to ``side_tilt_deg``,
        as far as that direction points away from the object's vertical axis (a lean towards
        the object would put the rod over it; a lean along the face's outward normal alone
        would make the wrist follow the face round in a twist, to its joint limits).
        """
        targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
        out = self._down.copy() if len(targets) == len(self._down) else \
            np.tile((0.0, 0.0, -1.0), (len(targets), 1))
        if self._tilt <= 0.0:
            return out
        # scalar arithmetic: this runs every solve, for one to a few fingers
        rows = targets.tolist()
        if self._top_version != self._pose_version:  # the object moved since the last solve
            d = self.configuration.data
            if d is not self._pose_data:
                self._pose_views(d)
            pos = self._pose_rows[0]
            px, py, pz = pos.tolist()
            # a target above any top the object can have (its farthest vertex from its
            # origin, straight up) gets no lean whatever the top (a transit, an approach
            # from above): the top is derived only when a target may be below it
            ceiling = pz + self._reach + self._band + 1e-6
            if all(r[2] > ceiling for r in rows):
                return out
            if self._pose_version:  # set_object's rotation of this pose
                rot = self._obj_rot
            else:  # the model's own pose: no set_object yet
                rot = self._rot
                mujoco.mju_quat2Mat(rot, self._pose_rows[1])
            self._top_version = self._pose_version
            # (``.dot`` of two vectors: the same BLAS dot as ``@``, in less dispatch)
            self._pose_top = (float(_MAX(self._verts @ rot[6:9])) + pz,
                              float(rot[0:3].dot(self._vmean)) + px,
                              float(rot[3:6].dot(self._vmean)) + py)
        top, cx, cy = self._pose_top
        band = self._band
        for k, (x, y, z) in enumerate(rows):
            hx, hy = x - cx, y - cy
            n = math.hypot(hx, hy)
            bx, by = self._bases[k][0] - x, self._bases[k][1] - y
            nb = math.hypot(bx, by)
            if n < 1e-6 or nb < 1e-6:
                continue
            bx, by = bx / nb, by / nb
            # full lean at the top and below, none ``band`` above it (an approach from
            # above turns the finger gradually), none over the object's vertical axis
            frac = min(max((top + band - z) / band, 0.0), 1.0) * min(n / band, 1.0)
            w = self._lean_out
            if w > 0.0:  # the lean's direction: between the outward one and the base's
                lx, ly = w * hx / n + (1.0 - w) * bx, w * hy / n + (1.0 - w) * by
                nl = math.hypot(lx, ly)
                if nl < 1e-9:
                    continue
                bx, by = lx / nl, ly / nl
            cos_b = (bx * hx + by * hy) / n  # the lean's direction against the outward one
            if frac <= 0.0 or cos_b <= 0.0:
                continue
            ang = self._tilt * frac * cos_b
            sa = math.sin(ang)
            # +z runs from the flange to the tip: the flange sits on the lean's side
            out[k] = (-bx * sa, -by * sa, -math.cos(ang))
        return out

    # -------------------------------------------------------------------------- solve
    def step(self, targets: FloatArray) -> tuple[FloatArray, FloatArray]:
        """One control step towards ``targets`` (shape (n_fingers, 3), world metres).

        Returns
        -------
        q : ndarray, shape (n_joints,)
            Joint position set points.
        qd : ndarray, shape (n_joints,)
            Joint velocities (feed-forward), rad/s.
        """
        t0 = time.perf_counter()
        axes = self.pointing(targets)
        cfg = self.config
        tau = 0.0 if self._deadbeat else cfg.task_time_constant
        gain = max(self.dt, self.period) / tau if tau > 0.0 else 1.0
        if gain >= 1.0 - 1e-9:  # a control step as long as tau: dead-beat, exactly
            gain = 1.0
        # a target that moves faster than this is a jump (a new trajectory), not a motion:
        # only this much of it is fed forward
        cap = _FEED_SPEED * self.dt
        for k, (task, x, a) in enumerate(zip(self.position_tasks, targets, axes,
                                             strict=True)):
            x = np.asarray(x, dtype=np.float64)
            task.gain = gain
            if gain < 1.0 and self._fed:
                dx = x - task.target
                n = math.sqrt(float(dx.dot(dx)))
                task.feed[:3] = dx if n <= cap else dx * (cap / n)
                # (no copy: the axis is only ever replaced by a new array, below)
                axis_prev = task.axis
            else:
                task.feed[:] = 0.0
                axis_prev = None
            task.target = x
            # the pointing turns towards its new direction with a bounded rate and
            # acceleration (stopping in time): a sudden turn of the goal swings the wrist at
            # its velocity limits, a sudden start at its torque limit
            ax = task.axis
            c = min(max(float(ax.dot(a)), -1.0), 1.0)
            ang = math.acos(c)
            w = min(cfg.tilt_rate, self._turn[k] + cfg.tilt_accel * self.dt,
                    math.sqrt(2.0 * cfg.tilt_accel * ang))
            self._turn[k] = w
            turn = w * self.dt
            if ang <= 1e-9:
                if axis_prev is not None:
                    task.feed[3:] = 0.0
                continue
            if ang > turn:
                perp = a - c * ax
                perp /= max(math.sqrt(float(perp.dot(perp))), 1e-12)
                a = math.cos(turn) * ax + math.sin(turn) * perp
            task.axis = a / math.sqrt(float(a.dot(a)))  # (np.linalg.norm's own sum)
            if axis_prev is not None:
                task.feed[3:] = task.axis - axis_prev
        self._fed = True
        v = self._solve()
        if v is None:
            v = self._brake()
        if self._plain:
            # mink's ``integrate_inplace`` (``mj_integratePos``, then ``mj_kinematics`` and
            # ``mj_comPos``: no equality constraints here), without its two Python calls
            m, d = self.scene.model, self.configuration.data
            qpos = self._qpos
            mujoco.mj_integratePos(m, qpos, v, self.dt)
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            # (the robot's joints are the scene's degrees of freedom, in order; ``v`` is the
            # QP's own new array, which nothing else keeps)
            qd = v
            q = qpos.copy()
        else:
            self.configuration.integrate_inplace(v, self.dt)
            qd = v[self.scene.dadr]  # (a new array: v is float64)
            q = self.q
        self._box.prev = qd
        self.solve_times.append(time.perf_counter() - t0)
        return q, qd.copy()

    def _brake(self) -> FloatArray:
        """The joint velocities of a step whose QP has no solution: the last velocities
        slowed down at the acceleration bound (within the joints' ranges), not zero.

        The acceleration bound gives way only where it conflicts with the position and
        velocity bounds; a collision row (a tipping object swinging towards the rod) can
        conflict with it too, and the QP then has no solution. A stop there is a velocity
        step in the servos' feed-forward (a torque step ``kv v``), and the acceleration
        bound then brings the joints back at 30 rad/s^2 each way: measured, the shoulder
        and the wrist of a roll-arc's let-go held their torque limits for 18 ms. Solving
        again without the acceleration bound was worse (the collision rows then threw the
        joints away: 30-46 ms at a torque limit).
        """
        self.infeasible += 1
        v = np.zeros(self.configuration.nv)
        accel = self.config.joint_accel
        if not math.isfinite(accel):
            return v  # no bound to brake at: hold, as before the bound
        prev = self._box.prev
        slow = np.sign(prev) * np.maximum(np.abs(prev) - accel * self.dt, 0.0)
        sc = self.scene
        q = self.q
        # a braking joint near an end of its range stops at it
        hi = np.maximum((sc.upper - q) / self.dt, 0.0)
        lo = np.minimum((sc.lower - q) / self.dt, 0.0)
        v[sc.dadr] = np.clip(slow, lo, hi)
        return v

    def _solve(self) -> FloatArray | None:
        """The QP of one control step, assembled here and handed to daqp directly; the
        joint velocities, or None when the limits admit no step.

        The same problem as ``mink.solve_ik(configuration, tasks, dt, "daqp", damping,
        limits)`` (:meth:`solve_mink`; a test holds them equal), built with fewer Python
        calls, which were most of a solve's time: the tasks' weighted residuals stacked into
        one preallocated matrix, the posture task's identity Jacobian added as a diagonal,
        the joint box as daqp's simple bounds instead of ``2 n`` inequality rows, and only the
        collision pairs within the detection distance as rows (mink's limit writes a row of
        zeros and an infinite bound for every other pair), no ``qpsolvers.Problem``.
        """
        conf, dt = self.configuration, self.dt
        w = self._w
        we = self._we
        for task, w_k, we_k, cost, cost_col in self._task_rows:
            np.multiply(cost_col, task.compute_jacobian(conf), out=w_k)
            # (``gain e``, not ``-gain e``: the linear term below is then ``we @ w``, the
            # same numbers as ``-((-gain e) @ w)``, negation being exact, in one call fewer)
            np.multiply(cost, task.gain * task.compute_error(conf), out=we_k)
        post = self.posture
        damping = self.config.damping if self._damping is None else self._damping
        if post.gain != self._post_gain or damping != self._post_damping:
            # the posture's constant arrays (converge sets another gain and damping):
            # ``cp2 gain (q - q_home)`` evaluates ``cp2 gain`` first
            cp2 = post.cost * post.cost
            self._post_gain = post.gain
            self._post_damping = damping
            # posture: J = I, e = q - q_home (hinge and slide joints only: checked in
            # __init__); its Hessian and the damping as a diagonal matrix, added to ``h``
            # whole (off the diagonal ``x + 0.0`` is ``x``)
            self._post_diag = np.diag(cp2 + damping)
            self._post_lin = cp2 * post.gain
        h = self._wT @ w
        c = we @ w
        qpos = self._qpos  # (read only: mink's ``q`` is a copy)
        h += self._post_diag
        c += self._post_lin * (qpos - post.target_q)
        box = self._box
        rows = None
        if box.identity:
            # the joints' bounds and the collision rows' as lists, made into daqp's two
            # arrays at once (the same numbers as the arrays concatenated: ``-x`` is
            # exact)
            up, down = box.steps(qpos, dt)
            rows = self._collision_rows(conf, dt) if self._coll is not None else None
            if rows is None:
                a = self._no_rows
                bu, bl = np.array(up), -np.array(down)
            else:
                a, hl = rows
                bu = np.array(up + hl)
                bl = np.array([-x for x in down] + self._no_lower_list[:len(hl)])
        else:
            upper, lower = box.bounds(qpos, dt)
            rows = self._collision_rows(conf, dt) if self._coll is not None else None
            if rows is None:
                a = self._no_rows
                bu, bl = upper, lower
            else:
                a, hl = rows
                bu = np.concatenate([upper, hl])
                bl = np.concatenate([lower, self._no_lower[:len(hl)]])
        sense = self._sense.get(len(bu))
        if sense is None:
            sense = self._sense[len(bu)] = np.zeros(len(bu), dtype=np.intc)
        x, _, flag, _ = self._daqp.solve(h, c, a, bu, bl, sense)
        if flag <= 0:
            return None
        return x / dt  # type: ignore[no-any-return]  # (daqp's solution: a float64 array)

    def _collision_rows(self, conf: Any, dt: float) -> tuple[FloatArray, list[float]] | None:
        """mink's ``CollisionAvoidanceLimit`` rows of the pairs within its detection distance
        (its broad phase, then ``mj_geomDistance``), shape (k, nv), and their bounds (k
        floats); None if none."""
        data = conf.data
        near = self._broad_phase(data)
        if not near:  # (most solves: nothing within reach of the detection distance)
            return None
        lim = self._coll
        model = lim.model
        distmax = lim.collision_detection_distance
        min_dist = lim.minimum_distance_from_collisions
        gain, relax = lim.gain, lim.bound_relaxation
        fromto, normal = self._fromto, self._normal
        jac1, jac2 = self._jac1, self._jac2
        g_rows: list[FloatArray] = []
        h_rows: list[float] = []
        pairs = lim.geom_id_pairs
        still = self._pair_still
        for idx in near:
            g1, g2 = pairs[idx]
            dist = mujoco.mj_geomDistance(model, data, g1, g2, distmax, fromto)
            if abs(dist - distmax) < 1e-12:
                continue
            h_rows.append(gain * (dist - min_dist) / dt + relax if dist > min_dist else relax)
            body2 = still[idx]
            if body2 >= 0:
                # the second geom does not move with the joints (a user's scene whose pair
                # lists the moving geom first; the usual scene's pairs take the branch below):
                # its Jacobian is zero and mink's row ``normal @ (jac2 - jac1)`` is
                # ``-(normal @ jac1)``, one ``mj_jac`` fewer
                np.subtract(fromto[3:], fromto[:3], out=normal)
                mujoco.mju_normalize3(normal)
                mujoco.mj_jac(model, data, jac1, None, fromto[:3], body2)
                row = normal.dot(jac1)
                g_rows.append(row if dist >= 0 else -row)
                continue
            body2 = self._pair_still1[idx]
            if body2 >= 0:
                # the first geom does not move (the table or the object: mink puts them
                # first in every pair of the usual scene): its Jacobian is zero, and mink's
                # ``jac2 -= jac1`` leaves ``jac2`` as it is, so its row is ``normal @ jac2``,
                # one ``mj_jac`` and its subtraction fewer
                np.subtract(fromto[3:], fromto[:3], out=normal)
                mujoco.mju_normalize3(normal)
                mujoco.mj_jac(model, data, jac2, None, fromto[3:], body2)
                row = normal @ jac2
                g_rows.append(-row if dist >= 0 else row)
                continue
            row = self._contact_jacobian(model, data, g1, g2, fromto, normal, jac1, jac2)
            g_rows.append(-row if dist >= 0 else row)
        if not g_rows:
            return None
        return np.array(g_rows), h_rows

    def _init_broad_phase(self) -> None:
        """The collision pairs' broad phase, precomputed: mink's (bounding spheres for two
        bounded geoms, the bounded geom's centre against a plane's half-space), with the
        planes' normals and offsets taken once (the IK scene's planes are static: the
        table)."""
        lim, m = self._coll, self.scene.model
        # per pair: the first geom's body when the second geom's body has no degree of
        # freedom on its way to the world (its Jacobian is zero), else -1
        def moves(body: int) -> bool:
            while body > 0:
                if int(m.body_dofnum[body]) > 0:
                    return True
                body = int(m.body_parentid[body])
            return False

        self._pair_still = [-1 if moves(int(m.geom_bodyid[g2])) else int(m.geom_bodyid[g1])
                            for g1, g2 in lim.geom_id_pairs]
        # and the second geom's body when the first geom's does not move (and the second's
        # does), else -1
        self._pair_still1 = [int(m.geom_bodyid[g2]) if still < 0
                             and not moves(int(m.geom_bodyid[g1])) else -1
                             for (g1, g2), still in zip(lim.geom_id_pairs, self._pair_still,
                                                        strict=True)]
        pairs = np.array(lim.geom_id_pairs, dtype=np.int64).reshape(-1, 2)
        g1, g2 = pairs[:, 0], pairs[:, 1]
        rb = m.geom_rbound
        plane = m.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
        margin = lim.collision_detection_distance
        both = (rb[g1] > 0) & (rb[g2] > 0)
        p1 = plane[g1] & (rb[g2] > 0) & ~both
        p2 = plane[g2] & (rb[g1] > 0) & ~both
        self._bp_ss = np.flatnonzero(both)
        self._bp_ss1, self._bp_ss2 = g1[both], g2[both]
        self._bp_ss_bound2 = (rb[g1[both]] + rb[g2[both]] + margin) ** 2
        pg = p1 | p2
        self._bp_pg = np.flatnonzero(pg)
        pl = np.where(p1, g1, g2)[pg]
        self._bp_pg_other = np.where(p1, g2, g1)[pg]
        d = self.configuration.data
        static = bool(np.all(m.body_weldid[m.geom_bodyid[pl]] == 0))
        self._bp_pg_n = np.array(d.geom_xmat[pl][:, [2, 5, 8]])  # each plane's normal
        self._bp_pg_c = np.einsum("ij,ij->i", self._bp_pg_n, d.geom_xpos[pl]) \
            + margin + rb[self._bp_pg_other]
        self._bp_keep = np.flatnonzero(~both & ~pg)
        # a moving plane (a user's robot file) or mink's broad phase off: every pair
        self._bp_all = not static or not getattr(lim, "broadphase", True)
        # the usual case in fewer numpy calls (the same numbers): the sphere pairs' second
        # geoms all one (the object), the planes all the table with its normal +z (the
        # distance along it is then the height itself, exactly), and both sides' positions
        # gathered at once
        ns = len(self._bp_ss)
        self._bp_one = -1
        others = self._bp_ss1
        for one, rest in ((self._bp_ss2, self._bp_ss1), (self._bp_ss1, self._bp_ss2)):
            if ns and bool(np.all(one == one[0])):
                # ``|a - b|^2`` is the same number either way round
                self._bp_one, others = int(one[0]), rest
                break
        self._bp_up = bool(len(pl)) and bool(np.all(self._bp_pg_n == (0.0, 0.0, 1.0)))
        self._bp_gather = np.concatenate([others, self._bp_pg_other])
        self._bp_ns = ns
        # (_broad_phase: the pairs' values, bounds and indices, sphere pairs first)
        self._bp_v = np.empty(ns + len(self._bp_pg))
        self._bp_bound = np.concatenate([self._bp_ss_bound2, self._bp_pg_c])
        self._bp_idx = np.concatenate([self._bp_ss, self._bp_pg])
        self._bp_nothing: list[int] = self._bp_keep.tolist()
        self._bp_data: Any = None
        self._bp_xpos: FloatArray = np.zeros((0, 3))

    def _broad_phase(self, data: Any) -> list[int]:
        """The pairs that may lie within the detection distance (indices into mink's
        ``geom_id_pairs``): the same strict pre-filter as mink's, in fewer numpy calls."""
        if self._bp_all:
            return list(range(len(self._coll.geom_id_pairs)))
        if data is not self._bp_data:  # (a view made once per data: MjData's arrays stay)
            self._bp_data, self._bp_xpos = data, data.geom_xpos
        x = self._bp_xpos
        if self._bp_one >= 0 and (self._bp_up or not len(self._bp_pg)):
            ns = self._bp_ns
            xs = x[self._bp_gather]
            d = xs[:ns] - x[self._bp_one]
            # the sphere pairs' squared distances and the plane pairs' heights in one
            # vector, against their bounds at once (the same numbers, the same order: the
            # sphere pairs, then the plane pairs)
            v = self._bp_v
            _SUM(d * d, axis=1, out=v[:ns])
            v[ns:] = xs[ns:, 2]
            got: list[int] = self._bp_idx[v <= self._bp_bound].tolist()
            return got + self._bp_nothing if self._bp_nothing else got
        d = x[self._bp_ss1] - x[self._bp_ss2]
        out: list[int] = self._bp_ss[(d * d).sum(axis=1) <= self._bp_ss_bound2].tolist()
        if len(self._bp_pg):
            near = (self._bp_pg_n * x[self._bp_pg_other]).sum(axis=1) <= self._bp_pg_c
            out += self._bp_pg[near].tolist()
        if len(self._bp_keep):
            out += self._bp_keep.tolist()
        return out

    def solve_mink(self) -> FloatArray | None:
        """The same QP as :meth:`_solve` through ``mink.solve_ik`` (the reference the fast
        path is tested against); joint velocities, or None."""
        mink = self.mink
        try:
            return np.asarray(mink.solve_ik(self.configuration, self.tasks, self.dt, "daqp",
                                            damping=(self.config.damping
                                                     if self._damping is None
                                                     else self._damping),
                                            limits=self.limits), dtype=np.float64)
        except mink.NoSolutionFound:
            return None

    def converge(self, targets: FloatArray, *, iterations: int = 400,
                 tol: float = 1e-4) -> float:
        """Iterate towards fixed ``targets`` (no time meaning: a placement before a run);
        returns the largest fingertip error left, m."""
        saved = self.dt
        # the null space (where the posture task alone acts) contracts by
        # ``1 - gain cp2 / (cp2 + damping)`` an iteration: at the run's damping (ten times the
        # posture's ``cost^2``) 0.98, and 340 iterations to settle, most of a run's first
        # solve (the main plan's start: 55 to put the fingertip on its target). The
        # iterations' fixed point does not depend on the damping (a step of zero is damped
        # by nothing), so they run with a hundredth of ``cp2``: 0.8 an iteration
        cp2 = float(np.min(self.posture.cost * self.posture.cost))
        try:
            self.dt = 0.02
            self.posture.gain = 0.2  # settle the null space too: the run starts at rest
            self._damping = (min(self.config.damping, 0.01 * cp2) if cp2 > 0.0
                             else self.config.damping)
            # fixed targets: dead-beat iterations (no time meaning, nothing to feed forward)
            self._deadbeat = True
            q_prev = self.q
            for _ in range(iterations):
                self.step(targets)
                # (np.linalg.norm's own sum for real rows, ``sqrt(sum(x x))``, without its
                # Python dispatch: every iteration of a placement reads it)
                e = self.tips() - targets
                err = float(_MAX(np.sqrt(_SUM(e * e, axis=1))))
                q = self.q
                if err < tol and float(np.abs(q - q_prev).max()) < 1e-5:
                    break
                q_prev = q
        finally:
            self.dt = saved
            self._deadbeat = False
            self.posture.gain = self.config.posture_gain
            self._damping = None
            self._fed = False
        self.solve_times = []
        return float(np.linalg.norm(self.tips() - targets, axis=1).max())
