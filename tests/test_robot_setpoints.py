"""The arm's set points between IK solves (issue 22's contact bars across the physics
distribution): a quadratic spline through the IK's knots whose velocity feed-forward is the
derivative of its positions, continuous across control periods and new trajectories; holds
that bring a moving arm to rest through the spline; the accelerations kept within the
joints' torque limits by the arm's dynamics; the fingertip radius offset of the commands."""

from __future__ import annotations

import dataclasses
import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

mujoco = pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")
pytest.importorskip("mink", reason="the robot extra (mink) is not installed: "
                                   "pip install 'nonprehensile[robot]'")

from nonprehensile.errors import InputError  # noqa: E402
from nonprehensile.geometry.build import cube  # noqa: E402
from nonprehensile.planning import ObjectPose  # noqa: E402
from nonprehensile.sim.robot import BasePose, Robot  # noqa: E402
from nonprehensile.sim.robot_driver import REFERENCE_RADIUS, RobotArms  # noqa: E402
from nonprehensile.sim.robot_run import (  # noqa: E402
    PINCH_TRACKING_BOUND,
    PINCH_TRACKING_GAIN,
    ROBOT_TRACKING_SURFACE_BOUND,
    RobotSimulator,
)
from nonprehensile.sim.robot_scene import Arm  # noqa: E402
from nonprehensile.sim.scene import SimParams  # noqa: E402

CUBE = cube()
SCALE = 0.05
BASE = BasePose(0.53, -0.51, 112.5)


def _sim(radius_offset: bool = False, **params: float) -> RobotSimulator:
    return RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                          params=SimParams(**params), radius_offset=radius_offset)


def _placed() -> tuple[RobotSimulator, RobotArms]:
    """A Panda placed at rest with its fingertip on (0.30, 0.05, 0.12) m, kinematics done."""
    sim = _sim()
    drv: RobotArms = sim.robot_driver
    drv.place(sim.data, np.array([[0.30, 0.05, 0.12]]))
    mujoco.mj_forward(sim.model, sim.data)
    return sim, drv


def _drive(sim: RobotSimulator, targets: np.ndarray, hold: int = 0) -> None:
    """Targets every physics step (the step loop's order: place, then row i before step i),
    then ``hold`` steps of the driver's hold rows, as the closed loop holds a trajectory's
    end."""
    m, d, drv = sim.model, sim.data, sim.robot_driver
    ctl = drv.controls(targets)
    drv.place(d, ctl[0])
    mujoco.mj_forward(m, d)
    for i in range(1, len(targets)):
        d.ctrl[:] = ctl[i]
        mujoco.mj_step(m, d)
    for _ in range(hold):
        d.ctrl[:] = drv.hold_row()
        mujoco.mj_step(m, d)


def _line(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """``n`` targets from ``a`` to ``b`` at constant speed (one finger), shape (n, 1, 3)."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    return np.asarray((a + s * (b - a))[:, None, :])


def test_velocity_feed_forward_is_the_derivative_of_the_position_set_points() -> None:
    """Over motions, a trajectory replaced mid-period, and a hold, the velocity set points
    are the exact derivative of the position set points: between any two rows the position
    moves by the mean of their velocities times the step (the spline's velocity is linear
    over each period; truth: the trapezoid rule, exact for a quadratic). The old linear
    set points broke this at every period boundary (a step of the feed-forward)."""
    sim = _sim()
    a = np.array([0.30, 0.05, 0.12])
    b = np.array([0.36, 0.14, 0.10])
    _drive(sim, _line(a, b, 403))
    # a new trajectory mid-period, moving elsewhere, then held
    _drive(sim, _line(b, np.array([0.27, 0.12, 0.15]), 257), hold=300)
    log = sim.robot_log
    q, qd, dt = log.q_ref, log.qd_ref, sim.params.timestep
    assert len(q) == 403 + 257 - 1 + 300  # every step recorded, the hold's included
    lhs = np.diff(q, axis=0) / dt
    rhs = 0.5 * (qd[1:] + qd[:-1])
    np.testing.assert_allclose(lhs, rhs, atol=1e-9)
    assert np.abs(qd).max() > 0.2  # it did move


def test_no_velocity_step_at_period_boundaries_or_new_trajectories() -> None:
    """The velocity set point changes by at most the IK's joint acceleration bound per
    physics step (truth: ``a dt``), at control-period boundaries and where a trajectory is
    replaced mid-period as well; linear set points stepped it by the whole period's change
    at once (``a dt`` times ``every``) and the velocity servos' ``kv`` turned that into
    torque steps."""
    sim = _sim()
    a = np.array([0.30, 0.05, 0.12])
    b = np.array([0.36, 0.14, 0.10])
    _drive(sim, _line(a, b, 203))
    _drive(sim, _line(b, a, 207), hold=100)
    qd = sim.robot_log.qd_ref
    bound = sim.robot_driver.ik.config.joint_accel * sim.params.timestep
    assert np.abs(np.diff(qd, axis=0)).max() <= bound * (1.0 + 1e-6)


def test_a_hold_after_motion_brings_the_arm_to_rest_within_the_bound() -> None:
    """A trajectory that ends moving (its targets stop at 0.28 m/s, as a drive that the
    closed loop ends mid-motion) is held: the set points decelerate within the
    acceleration bound (no step to zero, which asked ``kv v``, up to 120 N m, of every
    servo), come to rest exactly (zero velocity set point, constant positions, no more IK
    solves), with the fingertip on the held target (truth: MuJoCo's tip site within 1 mm
    of it)."""
    sim = _sim()
    a = np.array([0.30, 0.05, 0.12])
    b = np.array([0.36, 0.14, 0.10])
    n = 401
    _drive(sim, _line(a, b, n), hold=600)
    log, drv = sim.robot_log, sim.robot_driver
    qd = log.qd_ref
    moving = float(np.abs(qd[n - 2]).max())
    assert moving > 0.4  # the arm was moving when its targets stopped
    bound = drv.ik.config.joint_accel * sim.params.timestep
    assert np.abs(np.diff(qd[n - 2:], axis=0)).max() <= bound * (1.0 + 1e-6)
    assert np.all(qd[-50:] == 0.0)
    assert np.all(log.q_ref[-50:] == log.q_ref[-1])
    assert np.all(np.isnan(log.ik[-50:]))  # at rest, the hold solves nothing
    assert float(np.linalg.norm(sim.data.site_xpos[sim.scene.tip_sites[0]] - b)) < 1e-3
    # from the stop on no joint reached a torque limit (the targets' start at full speed
    # from rest, before, does: that is no hold's)
    assert log.metrics(start=n - 2).longest_at_limit_s["torque"] == 0.0


def test_set_point_accelerations_stay_within_the_torque_limits() -> None:
    """The set points' acceleration is scaled down, every joint alike, until the torque it
    takes with the arm's dynamics is within the share of each joint's limit, but never below
    a quarter of it. Truth: MuJoCo's inverse dynamics in discrete time (``mj_inverse`` with
    ``mjENBL_INVDISCRETE``: the force the actuators must give for that acceleration under
    the scene's implicit integrator), computed here."""
    sim, drv = _placed()
    m, d = sim.model, sim.data
    h = drv.every * drv.dt
    v0 = np.zeros(7)
    v1 = np.array([0.0, 0.6, 0.0, -0.6, 0.0, 0.6, 0.0])  # 60 rad/s^2: past the limits
    out = drv._within_torque(v0, v1, h)
    dof = sim.scene.dadr
    acc = (out - v0) / h
    need = _inverse(m, d, dof, acc)
    share = sim.scene.torque * np.where(sim.scene.torque < 30.0, drv.torque_share_light,
                                        drv.torque_share)
    assert np.all(np.abs(need) <= share * (1.0 + 1e-9))
    assert np.abs(need / share).max() > 0.999  # scaled to the limit, not below it
    moved = [1, 3, 5]
    s = (out - v0)[moved] / (v1 - v0)[moved]
    assert np.allclose(s, s[0]) and 0.0 < s[0] < 1.0  # every joint alike
    assert np.all(out[[0, 2, 4, 6]] == 0.0)
    # far past them, the set points keep a quarter of the IK's acceleration (never none)
    huge = 10.0 * v1
    np.testing.assert_allclose(drv._within_torque(v0, huge, h), drv.min_accel_share * huge)
    small = np.full(7, 0.01)  # a small acceleration passes unchanged
    assert np.array_equal(drv._within_torque(v0, small, h), small)


def _inverse(m: object, d: object, dof: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """The joints' forces (``dof``) MuJoCo's discrete-time inverse dynamics gives for the
    accelerations ``acc`` at ``d``'s state (the other dofs not accelerating)."""
    d2 = mujoco.MjData(m)
    d2.qpos[:] = d.qpos
    d2.qvel[:] = d.qvel
    d2.qacc[:] = 0.0
    d2.qacc[dof] = acc
    flags = m.opt.enableflags
    m.opt.enableflags = flags | int(mujoco.mjtEnableBit.mjENBL_INVDISCRETE)
    try:
        mujoco.mj_inverse(m, d2)
    finally:
        m.opt.enableflags = flags
    return np.array(d2.qfrc_inverse[dof])


def _moving() -> tuple[RobotSimulator, RobotArms, np.ndarray]:
    """The placed Panda moving (wrist and shoulder among the joints), kinematics done, and
    joint accelerations to test at (rad/s^2)."""
    sim, drv = _placed()
    d = sim.data
    d.qvel[sim.scene.dadr] = [0.3, -0.2, 0.5, 0.4, 1.5, 2.0, 0.3]
    mujoco.mj_forward(sim.model, d)
    return sim, drv, np.array([3.0, 5.0, -4.0, -5.0, 10.0, 30.0, 2.0])


def test_the_torque_budget_counts_the_implicit_integrators_inertia() -> None:
    """Under the scene's implicit integrator an actuator's force, read at the step's start,
    is ``(M + h D) a + c + g`` (``D``: joint damping and the servos' velocity gains), and
    the budget's model of it is that: at 1 ms the wrist's ``kv`` 200 N m s/rad adds 0.2 kg
    m^2 to its 0.14 (a transit of the main plan at 30 rad/s^2 held the wrist at its 12 N m
    for 17 ms while the mass matrix alone said 6 N m). Truth: MuJoCo's ``mj_inverse`` in
    discrete time, at a moving state with wrist and shoulder accelerations."""
    sim, drv, acc = _moving()
    m, d = sim.model, sim.data
    dof = sim.scene.dadr
    full = np.zeros(m.nv)
    full[dof] = acc
    ma = np.zeros(m.nv)
    mujoco.mj_mulM(m, d, ma, full)
    model = ma[dof] + drv._implicit * acc + d.qfrc_bias[dof] + m.dof_damping[dof] * d.qvel[dof]
    np.testing.assert_allclose(model, _inverse(m, d, dof, acc), rtol=1e-9, atol=1e-9)
    # the wrist: the integrator's share is larger than its own inertia (the mass
    # matrix's diagonal, armature included)
    unit, col = np.zeros(m.nv), np.zeros(m.nv)
    unit[dof[5]] = 1.0
    mujoco.mj_mulM(m, d, col, unit)
    assert drv._implicit[5] > col[dof[5]] > 0.1
    np.testing.assert_allclose(drv._implicit[5], 1e-3 * (200.0 + 0.5))


def test_the_acceleration_feed_forward_is_the_torque_the_acceleration_takes() -> None:
    """The position set points' offset times each servo's stiffness is the force the set
    points' joint acceleration takes under the scene's implicit integrator, ``(M + h D)
    a``. Truth: MuJoCo's discrete-time inverse dynamics at that acceleration less at none
    (the Coriolis, damping and gravity forces cancel), at a moving state, and the bundled
    Panda's published gains (``panda.KP``)."""
    from nonprehensile.sim.panda import KP

    sim, drv, acc = _moving()
    m, d = sim.model, sim.data
    dof = sim.scene.dadr
    torque = _inverse(m, d, dof, acc) - _inverse(m, d, dof, np.zeros(7))
    np.testing.assert_allclose(drv._accel_offset(acc) * np.array(KP), torque, rtol=1e-9,
                               atol=1e-9)


def test_the_feed_forward_is_clipped_and_skips_servos_that_are_not_plain() -> None:
    """An acceleration far past what the joints can give (a thousand times the test's):
    every joint's offset torque is its torque limit exactly (the scene's, the datasheet's).
    A position servo with activation dynamics (a user's ``timeconst``) has no stiffness the
    offset could go through: that joint gets none, the others theirs, and the scene's JSON
    says which joints are fed forward."""
    from nonprehensile.sim.panda import KP
    from nonprehensile.sim.robot_driver import servo_stiffness

    sim, drv, acc = _moving()
    m = sim.model
    got = drv._accel_offset(1000.0 * acc) * np.array(KP)
    np.testing.assert_allclose(got, np.sign(got) * sim.scene.torque, rtol=1e-12)
    assert all(j["acceleration_feedforward"] for j in sim.describe()["joints"])
    before = drv._accel_offset(acc)
    a = int(sim.scene.pos_act[0])
    assert servo_stiffness(m, a) == KP[0]
    saved = int(m.actuator_dyntype[a])
    m.actuator_dyntype[a] = int(mujoco.mjtDyn.mjDYN_FILTER)
    try:
        assert servo_stiffness(m, a) == math.inf
        drv._kp_joint[0] = servo_stiffness(m, a)
        after = drv._accel_offset(acc)
        assert after[0] == 0.0 and np.array_equal(after[1:], before[1:])
        flags = [j["acceleration_feedforward"] for j in sim.describe()["joints"]]
        assert flags == [False] + [True] * 6
    finally:
        m.actuator_dyntype[a] = saved
        drv._kp_joint[0] = servo_stiffness(m, a)


def _smooth(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """``n`` targets from ``a`` to ``b`` from rest to rest (a cosine ramp), shape (n, 1, 3)."""
    s = (0.5 - 0.5 * np.cos(np.pi * np.linspace(0.0, 1.0, n)))[:, None]
    return np.asarray((a + s * (b - a))[:, None, :])


def test_the_acceleration_feed_forward_takes_out_the_servos_lag() -> None:
    """An 18 cm move from rest to rest in half a second (0.57 m/s at its peak, 3.5 m/s^2):
    with the acceleration fed forward the fingertip stays within 1 mm of its command, and
    within half the error of the same servos without it (measured 0.75 against 2.1 mm; the
    servos took the torque from their error, a lag of 4-5 ms). Truth: MuJoCo's tip site
    against the command."""
    worst = {}
    for ff in (True, False):
        sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                             params=SimParams(), accel_feedforward=ff)
        _drive(sim, _smooth(np.array([0.30, 0.05, 0.12]), np.array([0.40, 0.20, 0.10]), 501),
               hold=200)
        worst[ff] = float(sim.robot_log.error.max())
        assert sim.describe()["controller"]["acceleration_feedforward"] is ff
    assert worst[True] < 1e-3
    assert worst[True] < 0.5 * worst[False]


@pytest.mark.parametrize("every", [10, 1])
def test_the_servos_get_the_set_points_plus_the_periods_acceleration_torque(every: int) -> None:
    """Row by row, the position servos' set points sent are the log's set points plus, below
    the physics rate, the torque of the control period's acceleration over each servo's
    stiffness (the acceleration: the spline's, from the logged velocity set points). Truth:
    MuJoCo's discrete-time inverse dynamics at the state the row is sent from, and the
    Panda's published gains. At 1 kHz the rows are the set points themselves."""
    from nonprehensile.sim.panda import KP

    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                         control_every=every)
    m, d, drv = sim.model, sim.data, sim.robot_driver
    targets = _smooth(np.array([0.30, 0.05, 0.12]), np.array([0.38, 0.16, 0.10]), 301)
    ctl = drv.controls(targets)
    drv.place(d, ctl[0])
    mujoco.mj_forward(m, d)
    pos, dof, log = sim.scene.pos_act, sim.scene.dadr, drv.log
    dt = sim.params.timestep
    worst = 0.0
    for i in range(1, len(targets)):
        row = np.array(ctl[i])
        sent = row[pos] - log.q_ref[-1]
        if every == 1:
            assert np.array_equal(row[pos], log.q_ref[-1])
        else:
            n = log.n
            acc = (log._qd_ref[n] - log._qd_ref[n - 1]) / dt  # constant over the period
            if (n - 1) % every == 0:  # the period's first row: the state it was solved at
                want = (_inverse(m, d, dof, acc) - _inverse(m, d, dof, np.zeros(7))) / KP
            # (the driver reads the mass matrix MuJoCo computed at the last step's start, a
            # physics step before this state: a few 1e-4 of the largest term at these speeds)
            np.testing.assert_allclose(sent, want, rtol=0,
                                       atol=2e-3 * float(np.abs(want).max()) + 1e-12)
            worst = max(worst, float(np.abs(sent).max()))
        d.ctrl[:] = row
        mujoco.mj_step(m, d)
    assert every == 1 or worst > 1e-4  # the move did accelerate the set points


@pytest.mark.parametrize("bad", [1, 0, "yes", None])
def test_the_acceleration_feed_forward_switch_is_a_bool(bad: object) -> None:
    with pytest.raises(InputError, match="accel_feedforward is True or False"):
        RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                       accel_feedforward=bad)  # type: ignore[arg-type]


def test_the_torque_budget_lets_a_joint_brake_short_of_its_range() -> None:
    """The wrist runs at 2 rad/s towards its upper end, 60 mrad from the IK's margin
    inside it, and the IK brakes it at 60 rad/s^2: the budget alone would scale that to
    27 rad/s^2 (the wrist's share of its 12 N m), and the set points would run 15 mrad past
    the margin (across the distribution a transit put the wrist 17 mrad past
    its end for 34 ms). The budget keeps enough of the braking to stop short of the margin.
    Truth: the stopping distance ``v^2 / (2 a)`` at the set points' deceleration, from the
    joint's range and margin as the IK configures them."""
    sim, drv = _placed()
    d = sim.data
    h = drv.every * drv.dt
    margin = math.radians(drv.ik.config.position_margin_deg)
    q0 = np.array(d.qpos[sim.scene.qadr])
    q0[5] = sim.scene.upper[5] - margin - 0.06
    v0 = np.zeros(7)
    v0[5] = 2.0
    v1 = v0.copy()
    v1[5] -= 60.0 * h
    alone = drv._within_torque(v0, v1, h)
    braking = (v0[5] - alone[5]) / h
    assert braking < 30.0  # the budget alone scales the braking down
    assert v0[5] ** 2 / (2.0 * braking) > 0.06  # and the joint would not stop in time
    out = drv._within_torque(v0, v1, h, q0)
    braking = (v0[5] - out[5]) / h
    assert v0[5] ** 2 / (2.0 * braking) <= 0.06
    assert out[5] > v1[5]  # still within the budget's scaling, not the IK's whole braking
    # far from the end, the same state is scaled as before
    q0[5] = 0.0
    assert np.array_equal(drv._within_torque(v0, v1, h, q0), alone)


def test_the_log_written_through_memoryviews_equals_numpy_rows() -> None:
    """Each physics step's state (time, joints, torques, tips, contacts) is copied into the
    log through flat memoryviews (``RobotArms.record``): the log equals the one written
    by numpy's row assignments (the path of a scene whose joints or tips are not in a row),
    across the log's growth beyond its first capacity."""
    logs = []
    for memoryviews in (True, False):
        sim = _sim()
        drv: RobotArms = sim.robot_driver
        assert drv._sources is not None
        if not memoryviews:
            drv._sources = None
        drv.log.clear(capacity=64)  # grown four times over the run
        a = np.array([0.30, 0.05, 0.12])
        _drive(sim, _line(a, np.array([0.34, 0.12, 0.09]), 701), hold=300)
        logs.append(drv.log)
    assert logs[0].n == logs[1].n == 700 + 300
    for name in ("time", "q", "qd", "tau", "touch", "other", "error", "error_ref"):
        got, want = getattr(logs[0], name), getattr(logs[1], name)
        assert got.dtype == want.dtype and got.tobytes() == want.tobytes(), name
    # the log pickles (its memoryviews are made again), and the copy records on
    back = pickle.loads(pickle.dumps(logs[0]))
    assert back.n == logs[0].n and back.q.tobytes() == logs[0].q.tobytes()
    back.reserve(5000)
    assert back.q.tobytes() == logs[0].q.tobytes()
    assert len(back._mv[1]) == len(back._q.reshape(-1))


def _range_share_numpy(drv: RobotArms, q0: np.ndarray, v0: np.ndarray, v1: np.ndarray,
                       h: float) -> float:
    """``RobotArms._range_share`` as it was written with numpy arrays (cpu23 wrote it per
    joint in floats): the reference its float form must equal bit for bit."""
    sc = drv.scene
    margin = math.radians(drv.ik.config.position_margin_deg)
    room = np.where(v0 > 0.0, sc.upper - margin - q0, q0 - sc.lower - margin)
    room = room - np.abs(v0) * h
    dv = v1 - v0
    braking = dv * v0 < 0.0
    if not np.any(braking):
        return 0.0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        need = np.where(room > 0.0, v0 * v0 / (2.0 * room), np.inf)
    bound = float(drv.ik.config.joint_accel)
    near = braking & (need >= 0.5 * bound) if math.isfinite(bound) else braking
    if not np.any(near):
        return 0.0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        want = need * h / np.abs(dv)
    return float(min(1.0, float(np.max(np.where(near, want, 0.0)))))


_RANGE_SIM: list[RobotSimulator] = []


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), bound=st.sampled_from([30.0, 0.0, 4.0, math.inf]),
       every=st.sampled_from([1, 10]))
def test_range_share_in_floats_equals_its_numpy_form(seed: int, bound: float,
                                                     every: int) -> None:
    """The braking share a joint needs to stop short of its range (``_range_share``),
    computed per joint in floats: the number of its numpy form, bit for bit, for set points
    anywhere in and near the joints' ranges (past them too), at rest or moving at up to
    twice the velocity limits, braking or not, with the IK's acceleration bound finite,
    zero or infinite."""
    if not _RANGE_SIM:
        _RANGE_SIM.append(_sim())
    drv: RobotArms = _RANGE_SIM[0].robot_driver
    sc = drv.scene
    rng = np.random.default_rng(seed)
    n = len(sc.lower)
    h = every * drv.dt
    saved = drv.ik.config
    drv.ik.config = dataclasses.replace(saved, joint_accel=bound)
    try:
        for _ in range(20):
            span = sc.upper - sc.lower
            q0 = sc.lower - 0.05 * span + rng.random(n) * 1.1 * span
            # a few joints right at the margin's edge or the range's end
            edge = rng.random(n) < 0.2
            margin = math.radians(drv.ik.config.position_margin_deg)
            q0[edge] = np.where(rng.random(int(edge.sum())) < 0.5, sc.upper[edge] - margin,
                                sc.lower[edge])
            v0 = (rng.random(n) * 4.0 - 2.0) * sc.velocity * (rng.random(n) < 0.8)
            v1 = v0 + (rng.random(n) * 2.0 - 1.0) * rng.choice([0.01, 0.3, 3.0]) * h * 100
            got = drv._range_share(q0, v0, v1, h)
            want = _range_share_numpy(drv, q0, v0, v1, h)
            assert np.float64(got).tobytes() == np.float64(want).tobytes()
    finally:
        drv.ik.config = saved


def _correct_numpy(drv: RobotArms, c: np.ndarray, targets: np.ndarray, now: np.ndarray,
                   steps: int, noise: np.ndarray | None) -> np.ndarray:
    """``RobotArms._correct``'s update in contact as it was written with numpy arrays
    (cpu23 wrote it per fingertip in floats), on ``c`` in place: the reference its float
    form must equal bit for bit."""
    dt = steps * drv.dt
    e = drv.data.site_xpos[drv._tip_sites] - (now + drv._offset)
    if noise is not None:
        e = e - noise
    sc = drv.scene
    tau = np.abs(drv.data.qfrc_actuator[drv._dsl])
    finite = np.isfinite(sc.torque)
    guard = bool(finite.any()) and float(
        (tau[finite] / sc.torque[finite]).max()) > drv.torque_guard
    if not guard:
        c -= min(drv.tracking_gain * dt, 1.0) * e
    n = np.sqrt((c * c).sum(axis=1))
    over = n > drv.tracking_bound
    if over.any():
        c[over] *= (drv.tracking_bound / n[over])[:, None]
    return np.asarray(targets + c)


_CORRECT_SIMS: dict[int, RobotSimulator] = {}


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), arms=st.sampled_from([1, 2]),
       steps=st.sampled_from([1, 10]), noisy=st.booleans())
def test_contact_correction_in_floats_equals_its_numpy_form(seed: int, arms: int, steps: int,
                                                            noisy: bool) -> None:
    """The contact tracking correction's update while touching (``_correct``), computed per
    fingertip in floats: the correction and the IK's targets of its numpy form, bit for
    bit, with one arm and two, with and without fingertip noise, for errors from microns to
    centimetres (the bound's scaling included), joint torques below and above the guard,
    and a NaN torque (numpy's maximum is NaN then: the correction grows)."""
    if arms not in _CORRECT_SIMS:
        bases = [BASE, BasePose(0.05, 0.55, -80.0)][:arms]
        # (the whole error, unsplit: two fingertips' default is along the surface only, one
        # fingertip's bounds the part along the surface, below)
        _CORRECT_SIMS[arms] = RobotSimulator(CUBE, [Arm(Robot.builtin(), b) for b in bases],
                                             scale=SCALE, tracking_gain=20.0,
                                             tracking_tangential=False,
                                             tracking_surface_bound=math.inf)
    drv: RobotArms = _CORRECT_SIMS[arms].robot_driver
    d, nf = drv.data, drv.n_fingers
    rng = np.random.default_rng(seed)
    for _ in range(10):
        size = rng.choice([1e-6, 1e-3, 1e-2])
        d.site_xpos[drv._tip_sites] = rng.normal(0.3, 0.1, (nf, 3))
        tau = rng.normal(0.0, 1.0, len(drv.scene.dadr)) * drv.scene.torque * rng.choice(
            [0.3, 1.0])
        if rng.random() < 0.1:
            tau[rng.integers(len(tau))] = math.nan
        d.qfrc_actuator[drv.scene.dadr] = tau
        drv._offset[:] = rng.normal(0.0, size, (nf, 3)) * (rng.random() < 0.5)
        start = rng.normal(0.0, drv.tracking_bound, (nf, 3))
        targets = rng.normal(0.3, 0.1, (nf, 3))
        now = d.site_xpos[drv._tip_sites] + rng.normal(0.0, size, (nf, 3))
        noise = rng.normal(0.0, size, (nf, 3)) if noisy else None
        c = start.copy()
        want = _correct_numpy(drv, c, targets, now, steps, noise)
        drv._corr[:] = start
        drv._touch = True
        got = drv._correct(targets, now, steps, noise)
        assert got.tobytes() == want.tobytes()
        assert drv._corr.tobytes() == c.tobytes()
    drv._corr[:] = 0.0
    drv._offset[:] = 0.0


def _see_yawed_cube(drv: RobotArms) -> tuple[np.ndarray, np.ndarray]:
    """Tell ``drv`` the cube stands yawed 30 degrees with its centre at (0.3, 0.1, 0.025)
    m; its rotation and centre."""
    yaw = math.radians(30.0)
    rot = np.array([[math.cos(yaw), -math.sin(yaw), 0.0],
                    [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    centre = np.array([0.3, 0.1, 0.025])
    mid = 0.5 * (CUBE.vertices.min(axis=0) + CUBE.vertices.max(axis=0))
    drv.see(ObjectPose(rot, centre - SCALE * rot @ mid, centre, SCALE))
    return rot, centre


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_pinch_correction_integrates_the_error_along_the_surface_only(seed: int) -> None:
    """Two fingertips' contact tracking correction (the default for several: along the
    object's surface only) on fingertips pressed into the faces of a cube posed by hand
    (yawed 30 degrees, both pads within a millimetre of a face's centre): each pad's
    correction changes by ``-g`` times its error with the component along its face's
    normal removed. Truth: the face normals from the pose written here, the error from
    the fingertip and command positions written here."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE),
                                Arm(Robot.builtin(), BasePose(0.05, 0.55, -80.0))],
                         scale=SCALE)
    drv = sim.robot_driver
    assert drv.tracking_tangential and drv.tracking_gain == PINCH_TRACKING_GAIN
    assert drv.tracking_bound == PINCH_TRACKING_BOUND
    doc = sim.describe()["finger_command"]
    assert doc["tracking_tangential"] is True and doc["tracking_bound_m"] == 0.002
    rng = np.random.default_rng(seed)
    rot, centre = _see_yawed_cube(drv)
    normals = np.stack([rot @ np.array([0.0, -1.0, 0.0]), rot @ np.array([0.0, 1.0, 0.0])])
    tips = centre + (0.025 - 0.002) * normals + rng.uniform(-1e-3, 1e-3, (2, 3))
    d = sim.data
    d.site_xpos[drv._tip_sites] = tips
    d.qfrc_actuator[:] = 0.0  # far below the torque guard
    now = tips + rng.normal(0.0, 0.002, (2, 3))
    noise = rng.normal(0.0, 0.001, (2, 3)) if rng.random() < 0.5 else None
    start = rng.normal(0.0, 0.0005, (2, 3))
    drv._corr[:] = start
    drv._offset[:] = 0.0
    drv._touch = True
    got = drv._correct(np.zeros((2, 3)), now, 10, noise)
    e = tips - now - (0.0 if noise is None else noise)  # the command is target + noise
    e_t = e - (e * normals).sum(axis=1)[:, None] * normals
    want = start - min(drv.tracking_gain * 10 * drv.dt, 1.0) * e_t
    n = np.linalg.norm(want, axis=1)
    want[n > drv.tracking_bound] *= (drv.tracking_bound / n[n > drv.tracking_bound])[:, None]
    # (the normal blends the faces by a softmax of their planes' distances: the side faces,
    # 22 mm further, weigh e^-11 beside the pad's own, a 1e-8 m difference at most here)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-7)
    drv._corr[:] = 0.0


_SURFACE_SIMS: dict[bool, RobotSimulator] = {}


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_one_arms_correction_bounds_its_part_along_the_surface(seed: int) -> None:
    """One fingertip's contact tracking correction (the default for one: the whole error,
    its part along the object's surface held within ``ROBOT_TRACKING_SURFACE_BOUND``) on a
    fingertip pressed into a face of a cube posed by hand (yawed 30 degrees): the update
    ``start - g e`` keeps its component along the face's normal and has the rest scaled
    down to the bound. Truth: the face normal from the pose written here, the error from
    the fingertip and command positions written here."""
    rng = np.random.default_rng(seed)
    along = bool(rng.random() < 0.25)  # the surface-only rule, with the bound asked for
    if along not in _SURFACE_SIMS:
        kw = {"tracking_tangential": True, "tracking_surface_bound": 0.0005} if along else {}
        _SURFACE_SIMS[along] = RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)],
                                              scale=SCALE, **kw)  # type: ignore[arg-type]
    sim = _SURFACE_SIMS[along]
    drv = sim.robot_driver
    assert drv.tracking_tangential is along
    assert drv.tracking_surface_bound == ROBOT_TRACKING_SURFACE_BOUND == 0.0005
    assert sim.describe()["finger_command"]["tracking_surface_bound_m"] == 0.0005
    rot, centre = _see_yawed_cube(drv)
    normal = rot @ np.array([0.0, -1.0, 0.0])
    tip = centre + (0.025 - 0.002) * normal + rng.uniform(-1e-3, 1e-3, 3)
    d = sim.data
    d.site_xpos[drv._tip_sites] = tip[None]
    d.qfrc_actuator[:] = 0.0  # far below the torque guard
    size = rng.choice([1e-4, 1e-3, 3e-3])
    now = tip[None] + rng.normal(0.0, size, (1, 3))
    start = rng.normal(0.0, 0.0003, (1, 3))
    if rng.random() < 0.3:  # a press already near the whole bound: the 4 mm bound acts
        start[0] -= rng.uniform(0.0035, 0.0045) * normal
    drv._corr[:] = start
    drv._offset[:] = 0.0
    drv._touch = True
    got = drv._correct(np.zeros((1, 3)), now, 10, None)
    e = tip - now[0]
    if along:  # the error's part along the normal left out first
        e = e - (e @ normal) * normal
    c = start[0] - min(drv.tracking_gain * 10 * drv.dt, 1.0) * e
    cn = (c @ normal) * normal
    ct = c - cn
    if np.linalg.norm(ct) > 0.0005:
        ct *= 0.0005 / np.linalg.norm(ct)
    want = cn + ct
    if np.linalg.norm(want) > drv.tracking_bound:
        want *= drv.tracking_bound / np.linalg.norm(want)
    np.testing.assert_allclose(got[0], want, rtol=0, atol=1e-7)
    assert np.linalg.norm(got[0] - (got[0] @ normal) * normal) <= 0.0005 + 1e-7
    drv._corr[:] = 0.0


@pytest.mark.parametrize("bad", [-0.001, 0.06, math.nan, True, "0.001"])
def test_the_surface_bound_is_checked(bad: object) -> None:
    with pytest.raises(InputError, match="tracking_surface_bound is a distance"):
        RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                       tracking_surface_bound=bad)  # type: ignore[arg-type]


def test_the_surface_bound_inf_is_none_and_two_arms_have_none() -> None:
    """``inf`` is no bound, said as None; a correction along the surface only (two arms', or
    one arm's asked for) has none by default: bounded to 0.5 mm it would be nearly off."""
    one = RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                         tracking_surface_bound=math.inf)
    assert one.robot_driver.tracking_surface_bound == math.inf
    assert one.describe()["finger_command"]["tracking_surface_bound_m"] is None
    along = RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                           tracking_tangential=True)
    assert along.robot_driver.tracking_surface_bound == math.inf
    two = RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE),
                                Arm(Robot.builtin(), BasePose(0.05, 0.55, -80.0))],
                         scale=SCALE)
    assert two.robot_driver.tracking_surface_bound == math.inf


def test_tracking_options_are_checked() -> None:
    """The correction's options: a bool, NaN, a negative or absurd number, a tangential
    switch that is not a bool are refused with the project's input error (numpy numbers
    are numbers); one arm keeps its whole-error correction and 4 mm bound."""
    for bad in ({"tracking_tangential": 1}, {"tracking_bound": float("nan")},
                {"tracking_bound": -0.001}, {"tracking_bound": 1.0},
                {"tracking_bound": True}, {"tracking_gain": float("nan")},
                {"tracking_gain": -1.0}, {"tracking_gain": "20"}):
        with pytest.raises(InputError, match="tracking_"):
            RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                           **bad)  # type: ignore[arg-type]
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                         tracking_bound=np.float32(0.003),  # type: ignore[arg-type]
                         tracking_gain=np.int64(10))  # type: ignore[arg-type]
    assert sim.robot_driver.tracking_bound == pytest.approx(0.003)
    assert sim.robot_driver.tracking_gain == 10.0
    one = RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE)
    assert not one.robot_driver.tracking_tangential
    assert one.robot_driver.tracking_bound == 0.004  # one arm: the driver's own
    # a driver asked for the surface-only correction without the object's faces says so
    drv = one.robot_driver
    drv.tracking_tangential, planes, drv._planes = True, drv._planes, None
    drv._touch = True
    try:
        with pytest.raises(InputError, match="set_shape"):
            drv._correct(np.zeros((1, 3)), np.zeros((1, 3)), 10, None)
    finally:
        drv.tracking_tangential, drv._planes, drv._touch = False, planes, False


def test_fingertip_radius_offset_moves_the_command_out_along_the_normal() -> None:
    """A 12 mm fingertip following references recorded with a 6 mm one: a target on or in
    the cube's face is moved out by the 6 mm difference along the face's normal; beyond
    the recorded radius plus the band nothing moves; over an edge, the offset points along
    the edge's bisector; at the references' own radius, or a smaller one, there is no offset
    at all.
    Truth: the cube's faces posed by hand (a yaw of 30 degrees about its centre)."""
    sim = _sim(radius_offset=True, finger_radius=0.012)
    drv = sim.robot_driver
    assert drv.finger_radius == 0.012 and drv.reference_radius == REFERENCE_RADIUS
    yaw = math.radians(30.0)
    rot = np.array([[math.cos(yaw), -math.sin(yaw), 0.0],
                    [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    centre = np.array([0.3, 0.1, 0.025])
    lo = CUBE.vertices.min(axis=0)
    hi = CUBE.vertices.max(axis=0)
    mid = 0.5 * (lo + hi)
    # the body origin such that the cube's centre is at ``centre``
    t = centre - SCALE * rot @ mid
    drv.see(ObjectPose(rot, t, centre, SCALE))
    half = 0.5 * SCALE * (hi - lo)[0]
    nx = rot @ np.array([1.0, 0.0, 0.0])  # the face at +x (model frame)
    on_face = centre + (half + 0.004) * nx  # the recorded 6 mm pad pressing 2 mm
    far = centre + (half + REFERENCE_RADIUS + drv.tool_band + 0.001) * nx
    edge = centre + (half + 0.003) * nx + (half + 0.003) * np.array([0.0, 0.0, 1.0])
    rows = np.array([[on_face], [far]])
    got = drv._tool(rows, edge[None])
    assert got is not None
    np.testing.assert_allclose(got[0, 0], 0.006 * nx, atol=1e-9)
    np.testing.assert_allclose(got[1, 0], 0.0, atol=1e-12)
    bisector = (nx + np.array([0.0, 0.0, 1.0])) / math.sqrt(2.0)
    np.testing.assert_allclose(got[2, 0], 0.006 * bisector, atol=1e-9)
    drv.finger_radius = REFERENCE_RADIUS
    assert drv._tool(rows, edge[None]) is None
    # out only: a tip smaller than the recorded pad is not sent deeper
    drv.finger_radius = 0.005
    assert drv._tool(rows, edge[None]) is None
    drv.finger_radius = 0.012
    drv.radius_offset = False  # (RobotSimulator's default is on for one fingertip)
    assert drv._tool(rows, edge[None]) is None


def test_the_offset_is_part_of_the_command_and_the_reference_error_keeps_the_target() -> None:
    """With a 12 mm fingertip the log's tracking error is measured against the command (the
    target plus the offset), the reference error against the target itself (the planner's
    reference): they differ by the offset the log records."""
    sim = _sim(radius_offset=True, finger_radius=0.012)
    drv = sim.robot_driver
    centre = np.array([0.3, 0.1, 0.025])
    drv.see(ObjectPose(np.eye(3), centre - SCALE * 0.5 * (CUBE.vertices.min(axis=0)
                                                           + CUBE.vertices.max(axis=0)),
                       centre, SCALE))
    top = centre + np.array([0.0, 0.0, 0.5 * SCALE + 0.006])  # the recorded pad on the top
    _drive(sim, _line(top + np.array([0.0, 0.0, 0.03]), top, 301), hold=200)
    log = sim.robot_log
    np.testing.assert_allclose(log.tool[-1, 0], [0.0, 0.0, 0.006], atol=1e-9)
    e = log._tips[:log.n] - log._target[:log.n] - log.tool
    np.testing.assert_allclose(log.error, np.sqrt((e * e).sum(axis=2)).max(axis=1),
                               atol=1e-12)
    # the arm holds the command: its tip centre 12 mm above the face, the target 6 mm
    assert log.error[-1] < 1e-3
    assert abs(log.error_ref[-1] - 0.006) < 1e-3


def test_hold_row_before_any_trajectory_keeps_the_controls() -> None:
    """A step loop that asks for a hold row before the driver has a trajectory gets the
    controls as they are (never a None written into ``data.ctrl``, which MuJoCo reads as
    NaN)."""
    sim = _sim()
    row = sim.robot_driver.hold_row()
    assert row.shape == sim.data.ctrl.shape and np.all(np.isfinite(row))
    np.testing.assert_array_equal(row, sim.data.ctrl)


def _box_distance(points: np.ndarray, centre: np.ndarray, rot: np.ndarray,
                  half: float) -> np.ndarray:
    """Signed distance (m) of ``points`` (shape (n, 3)) to a cube of half-width ``half``
    centred at ``centre`` and turned by ``rot``, by hand: in the cube's frame the excess of
    each coordinate over the half-width; outside, the norm of the positive excesses (the
    nearest face, edge or vertex), inside the largest (negative) excess."""
    e = np.abs((points - centre) @ rot) - half
    out = np.maximum(e, 0.0)
    return np.where(e.max(axis=1) > 0.0, np.sqrt((out * out).sum(axis=1)), e.max(axis=1))


@settings(max_examples=60, deadline=None)
@given(yaw=st.floats(-180.0, 180.0), tilt=st.floats(-40.0, 40.0), roll=st.floats(-40.0, 40.0),
       radius=st.floats(0.005, 0.012), depth=st.sampled_from([0.0, 0.0005, 0.001, 0.002]),
       seed=st.integers(0, 2**31 - 1))
def test_press_bound_keeps_every_command_at_most_depth_inside_the_posed_cube(
        yaw: float, tilt: float, roll: float, radius: float, depth: float,
        seed: int) -> None:
    """The contact-consistent command: every command (rows and the knot's target) whose
    fingertip sphere would sit deeper than ``press_depth`` inside the cube as observed is
    pushed out until it sits exactly that deep (its centre ``radius - depth`` from the
    cube), never out through a face that looks down at the table; a command already far
    enough is not moved at all. Truth: the posed cube's signed distance by hand
    (:func:`_box_distance`), not the driver's planes."""
    from scipy.spatial.transform import Rotation

    sim = _sim(finger_radius=radius)
    drv = sim.robot_driver
    drv.press_depth = depth
    drv.press_rate = None  # the bound itself (its rate limit: the test below)
    rng = np.random.default_rng(seed)
    rot = Rotation.from_euler("zyx", [yaw, tilt, roll], degrees=True).as_matrix()
    lo = CUBE.vertices.min(axis=0)
    hi = CUBE.vertices.max(axis=0)
    centre = np.array([0.3, 0.1, 0.05])
    drv.see(ObjectPose(rot, centre - SCALE * rot @ (0.5 * (lo + hi)), centre, SCALE))
    half = 0.5 * SCALE * float((hi - lo)[0])
    pts = centre + rng.uniform(-half - 0.02, half + 0.02, (11, 3))
    got = drv._tool(pts[:10, None], pts[10][None])
    push = np.zeros((11, 3)) if got is None else got.reshape(11, 3)
    need = radius - depth
    before = _box_distance(pts, centre, rot, half)
    after = _box_distance(pts + push, centre, rot, half)
    far = before >= need
    assert not push[far].any()
    np.testing.assert_allclose(after[~far], need, atol=1e-6)
    # the push goes out along a blend of the normals of faces that do not look down
    world = (np.array([CUBE.normals[f] for f in CUBE.face_ids])) @ rot.T
    usable = world[world[:, 2] >= -math.sqrt(0.5)]
    for p in push[~far]:
        n = float(np.linalg.norm(p))
        if n > 1e-9:
            assert float((usable @ (p / n)).max()) > 0.0
    drv.press_depth = None  # the bound off: nothing moves
    assert drv._tool(pts[:10, None], pts[10][None]) is None


@pytest.mark.parametrize("depth, correction", [(-0.001, True), (math.nan, True), (math.inf, True),
                                               (0.05, True), (True, True), ("1", True),
                                               (0.001, 1)])
def test_press_bound_refuses_what_is_not_one(depth: object, correction: object) -> None:
    """A depth outside 0..20 mm (NaN, inf, a bool, a string) or a correction flag that is
    not a bool is refused with the project's input error, by the arm's scene and by a
    sweep's robot alike."""
    from nonprehensile.errors import InputError
    from nonprehensile.sim.robustness import SweepRobot

    with pytest.raises(InputError):
        RobotSimulator(CUBE, [Arm(Robot.builtin(), BASE)], scale=SCALE,
                       press_depth=depth, press_correction=correction)  # type: ignore[arg-type]
    with pytest.raises(InputError):
        SweepRobot((Arm(Robot.builtin(), BASE),), press_depth=depth,  # type: ignore[arg-type]
                   press_correction=correction)  # type: ignore[arg-type]


def test_press_push_moves_at_most_press_rate_and_reaches_the_bound() -> None:
    """The bound's push changes by at most ``press_rate`` times the physics step from row to
    row (the knot's target ``k // 2 + 1`` steps past the last row), from zero at a new
    start, and settles on the unlimited push (the bound itself) when the command stays: a
    command 8 mm deep in the cube's +x face, a 10 mm tip, a 1 mm bound (a 17 mm push).
    Truth: the cube's distance by hand (:func:`_box_distance`) and the step bound."""
    sim = _sim(finger_radius=0.010)
    drv = sim.robot_driver
    drv.press_depth = 0.001
    rot = np.eye(3)
    lo = CUBE.vertices.min(axis=0)
    hi = CUBE.vertices.max(axis=0)
    centre = np.array([0.3, 0.1, 0.025])
    drv.see(ObjectPose(rot, centre - SCALE * rot @ (0.5 * (lo + hi)), centre, SCALE))
    half = 0.5 * SCALE * float((hi - lo)[0])
    deep = centre + np.array([half - 0.008, 0.0, 0.0])
    k = 10
    rows = np.repeat(deep[None, None], k, axis=0)
    drv.press_rate = None
    full = drv._tool(rows, deep[None])
    assert full is not None
    # the bound itself: the command's centre 9 mm from the cube (its push 17 mm and more:
    # the blended normal leans towards the top face's at 8 mm of blend)
    np.testing.assert_allclose(_box_distance(deep[None] + full[0], centre, rot, half), 0.009,
                               atol=1e-9)
    assert 0.017 <= float(np.linalg.norm(full[0, 0])) < 0.018 and full[0, 0, 0] > 0.0169
    unit = full[0, 0] / np.linalg.norm(full[0, 0])
    drv.press_rate = 0.1
    step = 0.1 * drv.dt
    prev = np.zeros(3)
    for period in range(40):
        got = drv._tool(rows, deep[None])
        assert got is not None
        for i in range(k):
            assert np.linalg.norm(got[i, 0] - prev) <= step + 1e-12
            prev = got[i, 0]
        assert np.linalg.norm(got[k, 0] - got[k - 1, 0]) <= step * (k // 2 + 1) + 1e-12
        if period == 0:
            np.testing.assert_allclose(got[k - 1, 0], k * step * unit, atol=1e-12)
    np.testing.assert_allclose(got, full, atol=1e-12)
    drv.reset()  # a new start: the push starts from zero again
    got = drv._tool(rows, deep[None])
    assert got is not None
    np.testing.assert_allclose(got[0, 0], step * unit, atol=1e-12)


@given(st.lists(st.booleans(), max_size=60))
@settings(max_examples=200)
def test_longest_run_is_the_plain_count(flags: list[bool]) -> None:
    """The records' longest time at a limit: the vectorised run length equals counting the
    flags one by one (the truth: a run grows on True and restarts on False)."""
    from nonprehensile.sim.robot_driver import _longest_run

    best = run = 0
    for f in flags:
        run = run + 1 if f else 0
        best = max(best, run)
    assert _longest_run(np.array(flags, dtype=bool)) == best
