"""One arm's contact bars (issue 22): tracking in contact, time at a joint limit, the IK's
fallback when its QP has no solution, and the tracking error's reference (the command)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")
pytest.importorskip("mink", reason="the robot extra (mink) is not installed: "
                                   "pip install 'nonprehensile[robot]'")

from nonprehensile.geometry.build import cube  # noqa: E402
from nonprehensile.sim.ik import FingertipIK, IKConfig  # noqa: E402
from nonprehensile.sim.robot import BasePose, Robot  # noqa: E402
from nonprehensile.sim.robot_run import (  # noqa: E402
    DEFAULT_TRACKING_GAIN,
    PINCH_TRACKING_GAIN,
    ROBOT_MAX_ACCEL,
    ROBOT_TRANSIT_ACCEL,
    RobotSimulator,
    robot_control,
)
from nonprehensile.sim.robot_scene import Arm, build_robot_scene  # noqa: E402

CUBE = cube()
SCALE = 0.05
SKILLS = str(Path(__file__).resolve().parents[1] / "src/nonprehensile/data/cube_skills.json")
#: The base the one-arm transition sweep found for the 72 single-finger transitions
#: (``NP_PARTS=transitions NP_ROBOT_ARMS=1 python -m benchmarks robot``).
SWEEP_BASE = BasePose(-0.023566, 0.648373, -90.0)


def test_infeasible_ik_brakes_the_joints_instead_of_stopping_them() -> None:
    """When the QP has no solution the joints slow down from their last velocities at the
    acceleration bound (truth: v - a dt, per joint), never jump to rest: a jump to zero is a
    step of ``kv v`` in every servo's torque (measured: the shoulder and the wrist at their
    torque limits for 18 ms in a roll-arc)."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.53, -0.51, 112.5))],
                         scale=SCALE)
    ik: FingertipIK = sim.robot_driver.ik
    prev = np.array([0.3, -0.2, 0.01, 0.5, -0.02, 0.25, 0.0])
    ik._box.prev = prev.copy()
    target = ik.tips()
    ik._solve = lambda: None  # type: ignore[method-assign]  # the QP has no solution
    _, qd = ik.step(target)
    a_dt = ik.config.joint_accel * ik.dt
    want = np.sign(prev) * np.maximum(np.abs(prev) - a_dt, 0.0)
    np.testing.assert_allclose(qd, want, atol=1e-12)
    assert np.abs(qd).max() > 0.2  # still moving, slowing down
    assert ik.infeasible == 1


def _roll_arc_unit():  # type: ignore[no-untyped-def]
    from nonprehensile.cli.options import state_set
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.sim.execute import fingers_of
    from nonprehensile.sim.robustness import transition_units

    poly, skills = read_skills(SKILLS)
    skills = [s for s in skills if max(fingers_of(s), default=1) <= 1]
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    units = transition_units(poly, exp, motions, scale=ds.scale, angle_tol=1e-6,
                             sources=("roll-arc",))
    unit = next(u for u in units if u.label["from"] == {"face": "a", "theta": 270.0})
    return poly, ds, unit


def test_roll_arc_by_one_arm_meets_the_contact_bars() -> None:
    """A roll-arc (``a:270 -> e:90``) at nominal physics by the Panda at the one-arm sweep's
    base, closed loop: the cube reaches its state, the fingertip tracks its command within
    3 mm while it touches, no joint holds a limit for more than 10 ms, nothing but the
    fingertip touches. Before the contact correction and the IK's braking fallback: 3.4 mm
    and 18 ms at the shoulder's torque limit (the let-go, when the QP had no solution)."""
    from nonprehensile.sim.closed_loop import execute_plan

    poly, ds, unit = _roll_arc_unit()
    sim = RobotSimulator(poly, [Arm(Robot.builtin(), SWEEP_BASE)], scale=ds.scale)
    ex = execute_plan(sim, unit.plan, fingers=ds.fingers, loop="closed",
                      config=robot_control(n_fingers=sim.n_fingers))
    assert ex.success, ex.reason
    # one arm's transits run at its motions' bound, not half of it (the commanded samples'
    # own second differences)
    assert ROBOT_MAX_ACCEL / 2 + 0.5 < ex.transit_accel <= ROBOT_TRANSIT_ACCEL + 1e-6
    met = sim.robot_log.metrics()
    assert met.tracking_error_contact_max_m is not None
    assert met.tracking_error_contact_max_m <= 0.003
    assert max(met.longest_at_limit_s.values()) <= 0.010
    assert met.other_contact_s == 0.0
    # no fingertip noise here: the command is the noise-free target
    assert met.reference_error_contact_max_m == met.tracking_error_contact_max_m


def test_tracking_error_is_measured_against_the_command_with_its_noise() -> None:
    """The distribution's fingertip noise is part of an arm's command (on its servos' set
    points): a fingertip that follows target + noise tracks its command, and its error
    against the noise-free target is the noise (truth: the noise given, 2 mm here)."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                         scale=SCALE)
    drv = sim.robot_driver
    d, m = sim.data, sim.model
    mujoco.mj_resetData(m, d)
    d.qpos[sim.judge.qadr:sim.judge.qadr + 3] = [2.0, 2.0, 0.5]  # the cube far away
    x = np.array([[0.0, 0.0, 0.10]])
    targets = np.repeat(x[None], 1000, axis=0)
    noise = np.zeros_like(targets)
    s = np.clip(np.arange(len(targets)) / 300.0, 0.0, 1.0)
    noise[:, 0, 0] = 0.002 * s * s * (3.0 - 2.0 * s)  # eased in over 0.3 s
    drv.reset()
    drv.place(d, targets[0])
    ctl = drv.controls(drv.with_noise(targets, noise))
    for i in range(len(targets)):
        d.ctrl[:] = ctl[i]
        mujoco.mj_step(m, d)
    err, ref = np.array(drv.log.error[-100:]), np.array(drv.log.error_ref[-100:])
    assert err.max() < 0.0005  # at rest on its command
    np.testing.assert_allclose(ref, 0.002, atol=0.0005)


@pytest.mark.parametrize("every", [10, 1])
def test_the_arm_follows_the_smoothed_noise_with_its_velocity_fed_forward(every: int) -> None:
    """The distribution's fingertip noise (1 mm, 50 ms), smoothed as the executor gives it
    to an arm (``noise_smoothing``) and realised with its velocity fed forward, at 100 Hz
    and 1 kHz: the fingertip stays on its command within 1 mm in free space while the
    noise moves it several millimetres (truth: the command, target + noise), so its
    distance to the noise-free target has the noise's spread within 10 %. On the position
    set points alone, the same noise leaves the fingertip 3 times as far off its command
    (4 here) and realises a quarter less of it."""
    from nonprehensile.sim.closed_loop import FingerNoise

    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                         scale=SCALE, control_every=every)
    drv = sim.robot_driver
    d, m = sim.data, sim.model
    x = np.array([[0.0, 0.0, 0.10]])
    targets = np.repeat(x[None], 3000, axis=0)
    assert drv.noise_smoothing > 0.0
    _, noise, velocity = FingerNoise(np.random.default_rng(4), 0.001, m.opt.timestep,
                                     1).rows(len(targets), drv.noise_smoothing)
    assert noise is not None and velocity is not None
    worst, realised = {}, {}
    spread = float(np.sqrt((noise[500:3000] ** 2).sum(axis=2).mean()))
    for fed in (True, False):
        mujoco.mj_resetData(m, d)
        d.qpos[sim.judge.qadr:sim.judge.qadr + 3] = [2.0, 2.0, 0.5]  # the cube far away
        drv.reset()
        drv.place(d, targets[0])
        ctl = drv.controls(drv.with_noise(targets, noise, velocity if fed else None))
        for i in range(len(targets)):
            d.ctrl[:] = ctl[i]
            mujoco.mj_step(m, d)
        worst[fed] = float(np.max(drv.log.error[-2500:]))
        ref = np.array(drv.log.error_ref[-2500:])
        realised[fed] = float(np.sqrt((ref ** 2).mean())) / spread
    assert worst[True] < 0.001, worst
    assert worst[False] > 3.0 * worst[True], worst
    assert abs(realised[True] - 1.0) < 0.1, realised
    assert realised[False] < 0.9 * realised[True], realised


def test_the_executor_gives_the_arm_one_smooth_noise_process() -> None:
    """Closed loop with the distribution's fingertip noise (1 mm) on a roll-arc by one arm:
    the noise on the arm's command (the log's, row by row) is one smooth process over the
    whole run, through every replaced segment, hold and transit: its largest change in a
    physics step is under 0.2 mm (0.06 mm here; 4.9 mm when each new segment restarted from
    the end of the previous segment's rows) and its second difference under 10 um, an
    acceleration of 10 m/s^2 (3.8 um here; 41 um when the noise's velocity was cut to none
    at a segment's end); and the velocity set points the servos get never step by more
    than 0.05 rad/s from one physics step to the next (0.031 here, the spline's own; 0.095
    when the noise's velocity was cut at the targets' end, a review's mutant)."""
    from nonprehensile.sim.closed_loop import execute_plan
    from nonprehensile.sim.distribution import Perturbation

    poly, ds, unit = _roll_arc_unit()
    sim = RobotSimulator(poly, [Arm(Robot.builtin(), SWEEP_BASE)], scale=ds.scale)
    vel_cols = sim.robot_driver._vel_cols
    sent: list[np.ndarray] = []
    step = mujoco.mj_step

    def stepped(m: object, d: object) -> None:  # the velocity set points each step gets
        sent.append(np.array(d.ctrl[vel_cols]))  # type: ignore[attr-defined]
        step(m, d)

    mujoco.mj_step = stepped  # (the executor binds it at each drive's start)
    try:
        ex = execute_plan(sim, unit.plan, fingers=ds.fingers, loop="closed",
                          config=robot_control(n_fingers=sim.n_fingers),
                          perturbation=Perturbation(finger_noise=0.001, noise_seed=3))
    finally:
        mujoco.mj_step = step
    assert ex.success, ex.reason
    jumps = np.abs(np.diff(np.array(sent), axis=0)).max()
    assert jumps < 0.05, jumps
    log = sim.robot_log
    noise = np.asarray(log._noise[:log.n, 0])
    assert float(np.sqrt((noise ** 2).sum(axis=1)).max()) > 0.001  # the noise is there
    step = np.sqrt((np.diff(noise, axis=0) ** 2).sum(axis=1))
    bend = np.sqrt((np.diff(noise, 2, axis=0) ** 2).sum(axis=1))
    assert step.max() < 0.0002, step.max()
    assert bend.max() < 1e-5, bend.max()


@pytest.mark.parametrize("every", [10, 1])
def test_the_noise_past_the_targets_end_goes_on_the_servos_as_given(every: int) -> None:
    """Noise longer than the targets (the smoothed noise's tail) with its velocity, held
    past its own end: the position servos get ``J^+ noise[min(j, len - 1)]`` and the
    velocity servos ``J^+ velocity[j]``, none past the noise's end, at 100 Hz and 1 kHz
    (truth: the rows handed in, read back from what the driver puts on its servos), and
    the log's noise is what went on the position servos."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                         scale=SCALE, control_every=every)
    drv, d, m = sim.robot_driver, sim.data, sim.model
    mujoco.mj_resetData(m, d)
    d.qpos[sim.judge.qadr:sim.judge.qadr + 3] = [2.0, 2.0, 0.5]  # the cube far away
    n, tail, held = 53, 240, 300
    targets = np.repeat(np.array([[[0.0, 0.0, 0.10]]]), n, axis=0)
    noise = np.cumsum(np.random.default_rng(1).normal(size=(n + tail, 1, 3)) * 1e-5, axis=0)
    vel = np.diff(noise, axis=0, prepend=np.zeros((1, 1, 3))) / m.opt.timestep
    drv.reset()
    drv.place(d, targets[0])
    calls: list[np.ndarray] = []
    offset = drv._noise_offset
    drv._noise_offset = lambda a: (calls.append(np.array(a)), offset(a))[1]  # type: ignore
    ctl = drv.controls(drv.with_noise(targets, noise, vel))
    t0 = drv.log.n
    for i in range(n + tail + held):
        d.ctrl[:] = ctl[i] if i < len(ctl) else ctl.hold()
        mujoco.mj_step(m, d)
    pos, v = np.concatenate(calls[0::2]), np.concatenate(calls[1::2])  # (per period)
    rows = np.arange(len(pos))
    np.testing.assert_array_equal(pos, noise[np.minimum(rows, n + tail - 1)])
    want = np.where((rows >= n + tail)[:, None, None], 0.0,
                    vel[np.minimum(rows, n + tail - 1)])
    np.testing.assert_array_equal(v, want)
    logged = np.asarray(drv.log._noise[t0:drv.log.n])
    np.testing.assert_array_equal(logged, pos[:len(logged)])
    assert len(pos) >= n + tail + held - every


def test_the_arms_ik_avoids_the_object_where_it_is_observed_not_where_it_is() -> None:
    """Closed loop, the IK's object (its collision avoidance and finger pointing) is the
    controller's: each pose handed to the IK is the planned start or an observation's (the
    tracker's samples, 2 mm of noise here), never the simulation's true pose (truth: the
    observer's own samples, collected beside the run)."""
    from nonprehensile.control import ControlConfig
    from nonprehensile.observation import ObservationModel
    from nonprehensile.sim import closed_loop
    from nonprehensile.sim.closed_loop import execute_plan

    poly, ds, unit = _roll_arc_unit()
    sim = RobotSimulator(poly, [Arm(Robot.builtin(), SWEEP_BASE)], scale=ds.scale)
    ik = sim.robot_driver.ik
    given: list[tuple[np.ndarray, np.ndarray]] = []  # (IK's object, true object) per solve
    set_object = ik.set_object

    def spy(position, quat):  # type: ignore[no-untyped-def]
        given.append((np.array(position), np.array(sim.data.xpos[sim.judge.body])))
        set_object(position, quat)

    ik.set_object = spy  # type: ignore[method-assign]
    # the driver hands an unchanged observed pose again through set_object_kept (which
    # writes the rows it wrote last): those solves are checked too, by the rows written
    set_object_kept = ik.set_object_kept
    written: list[tuple[np.ndarray, np.ndarray]] = []  # (IK data's object, pose handed)

    def spy_kept(position, quat):  # type: ignore[no-untyped-def]
        given.append((np.array(position), np.array(sim.data.xpos[sim.judge.body])))
        set_object_kept(position, quat)
        written.append((np.array(ik.configuration.data.xpos[ik._obj]), np.array(position)))

    ik.set_object_kept = spy_kept  # type: ignore[method-assign]
    seen: list[np.ndarray] = [np.asarray(unit.plan.steps[0].start_pose.translation)]
    sample = closed_loop.SimObserver.sample

    def observed(self, now):  # type: ignore[no-untyped-def]
        got = sample(self, now)
        if got is not None:
            seen.append(np.asarray(got.pose.translation))
        return got

    closed_loop.SimObserver.sample = observed  # type: ignore[method-assign]
    try:
        execute_plan(sim, unit.plan, fingers=ds.fingers, loop="closed",
                     observation=ObservationModel(position_noise=0.002),
                     config=ControlConfig(max_accel=ROBOT_MAX_ACCEL))
    finally:
        closed_loop.SimObserver.sample = sample  # type: ignore[method-assign]
    assert len(given) > 100 and len(written) > 100
    for row, pos in written:
        np.testing.assert_array_equal(row, pos)
    known = np.array(seen)
    for pos, _ in given:
        assert np.abs(known - pos).max(axis=1).min() < 1e-12  # an observation's, exactly
    off = np.array([np.linalg.norm(pos - true) for pos, true in given])
    assert np.median(off) > 0.001  # the tracker's noise: not the truth


def test_robot_control_bounds_and_bad_values() -> None:
    """One fingertip's transits at :data:`ROBOT_TRANSIT_ACCEL` (never above the motions'
    bound), several fingertips' at half the motions' bound, the free fingertips' rule; a
    transit bound that is not a positive finite number is refused naming it."""
    from nonprehensile.control import ControlConfig
    from nonprehensile.errors import InputError

    one = robot_control(n_fingers=1)
    assert one.max_accel == ROBOT_MAX_ACCEL and one.transit_bound == ROBOT_TRANSIT_ACCEL
    assert robot_control(n_fingers=1, max_accel=5.0).transit_bound == 5.0
    two = robot_control(ControlConfig(angle_tol=4.0), n_fingers=2)
    assert two.angle_tol == 4.0 and two.transit_bound == ROBOT_MAX_ACCEL / 2
    # a caller's own transit bound is kept (at most the motions' bound), never dropped
    assert robot_control(ControlConfig(transit_accel=3.0), n_fingers=2).transit_bound == 3.0
    assert robot_control(ControlConfig(transit_accel=30.0), n_fingers=1).transit_bound == \
        ROBOT_MAX_ACCEL
    for bad_n in (0, -1, True, 1.5):
        with pytest.raises(InputError, match="n_fingers"):
            robot_control(n_fingers=bad_n)  # type: ignore[arg-type]
    assert ControlConfig().transit_bound == ControlConfig().max_accel / 2
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="transit_accel"):
            ControlConfig(transit_accel=bad)


def _pinch(gain: float | None, **extra: object) -> tuple[float, float, RobotSimulator]:
    """Two arms pinch the resting cube (its corner at the origin, 50 mm) on its -y and +y
    faces, each fingertip's target held 4 mm into the face for 0.8 s; the mean normal
    force of the fingertips' contacts with the cube over the last 0.1 s (MuJoCo's
    ``mj_contactForce``) and the fingertips' mean distance outside the faces' planes."""
    arms = [Arm(Robot.builtin(), BasePose(0.025, -0.5, 90.0)),
            Arm(Robot.builtin(), BasePose(0.025, 0.55, -90.0))]
    kw: dict[str, object] = ({} if gain is None else {"tracking_gain": gain}) | extra
    # the contact-consistent command off: this pinch is the correction's (its bound, on by
    # default for several fingertips, would hold the commands 4 mm outside the faces)
    sim = RobotSimulator(CUBE, arms, scale=SCALE, press_depth=None,
                         **kw)  # type: ignore[arg-type]
    drv, d, m = sim.robot_driver, sim.data, sim.model
    mujoco.mj_resetData(m, d)
    # 6 mm fingertips, centres 2 mm outside the faces y = 0 and y = 0.05: 4 mm into them
    x = np.array([[0.025, -0.002, 0.025], [0.025, 0.052, 0.025]])
    targets = np.repeat(x[None], 800, axis=0)
    drv.reset()
    drv.place(d, targets[0])
    ctl = drv.controls(targets)
    tips = {m.geom(f"finger{k}").id for k in (1, 2)}
    obj = m.geom("object").id
    buf = np.zeros(6)
    forces = []
    for i in range(len(targets)):
        d.ctrl[:] = ctl[i]
        mujoco.mj_step(m, d)
        total = 0.0
        for j in range(d.ncon):
            pair = {int(d.contact[j].geom[0]), int(d.contact[j].geom[1])}
            if obj in pair and pair & tips:
                mujoco.mj_contactForce(m, d, j, buf)
                total += abs(buf[0])
        forces.append(total)
    y = d.site_xpos[drv._tip_sites][:, 1]
    outside = float(np.mean([-y[0], y[1] - 0.05]))
    return float(np.mean(forces[-100:])), outside, sim


def test_two_arms_pinch_squeezes_no_harder_with_the_surface_correction() -> None:
    """Several fingertips run the contact tracking correction along the object's surface
    only by default (one arm integrates its whole error): two arms pinching a cube with
    targets inside it press with the servos' equilibrium force, as without any correction,
    where the whole error integrated drives the tips further in and squeezes harder
    (truth: MuJoCo's contact forces and the fingertips' positions)."""
    one = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                         scale=SCALE)
    assert one.robot_driver.tracking_gain == DEFAULT_TRACKING_GAIN > 0.0
    assert not one.robot_driver.tracking_tangential
    f_def, out_def, sim = _pinch(None)
    assert sim.robot_driver.tracking_gain == PINCH_TRACKING_GAIN > 0.0
    assert sim.robot_driver.tracking_tangential
    assert sim.describe()["finger_command"]["tracking_gain_per_s"] == PINCH_TRACKING_GAIN
    f_off, out_off, _ = _pinch(0.0)
    f_on, out_on, sim_on = _pinch(DEFAULT_TRACKING_GAIN, tracking_tangential=False,
                                  tracking_bound=0.004)
    assert not sim_on.robot_driver.tracking_tangential
    assert f_off > 5.0  # a pinch: both tips press the cube
    assert f_off < 0.8 * f_on  # measured 25.5 N against 40.1 N
    assert abs(f_def - f_off) < 0.1 * f_off  # along the surface: no harder squeeze
    # without the correction each tip stops where the servos and the contact balance,
    # short of its target (2 mm outside); with the whole error integrated, closer to it
    assert out_off > out_on + 0.001 and out_on > 0.0015
    assert abs(out_def - out_off) < 2e-4


#: The bases the two-arm transition sweep found for the 96 two-finger transitions
#: (``NP_PARTS=transitions NP_ROBOT_ARMS=2 python -m benchmarks robot``).
SWEEP_BASES_2 = (BasePose(0.611572, -0.269299, 157.5), BasePose(-0.547628, 0.536875, -45.0))


def test_two_arms_tumble_twist_without_rod_contact() -> None:
    """The two-arm sweep's tumble-twist ``a:0 -> d:90`` at nominal physics, closed loop,
    without a re-planner: the first attempt reaches ``d:90`` and nothing but the fingertips
    touches the cube or the table. With the rods leaning 30 degrees as in a twist, the lift
    onto the vertex tilted the first arm's face 19 degrees over its finger and the rod's
    lower end touched it (60 ms), the attempt ended with the cube held on its vertex, and
    the retry put the second arm's rod on the cube's edge for 1.1 s (docs/benchmarks.md,
    two23)."""
    from nonprehensile.cli.options import state_set
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.sim.closed_loop import execute_plan
    from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION
    from nonprehensile.sim.robustness import transition_units

    poly, skills = read_skills(SKILLS)
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    units = transition_units(poly, exp, motions, scale=ds.scale, angle_tol=1e-6,
                             sources=("tumble-twist",))
    unit = next(u for u in units if u.label["from"] == {"face": "a", "theta": 0.0})
    params = DEFAULT_DISTRIBUTION.for_object(poly, ds.scale).base
    sim = RobotSimulator(poly, [Arm(Robot.builtin(), b) for b in SWEEP_BASES_2],
                         scale=ds.scale, params=params)
    ex = execute_plan(sim, unit.plan, fingers=ds.fingers, loop="closed",
                      config=robot_control(n_fingers=sim.n_fingers))
    assert ex.success, ex.reason
    assert not ex.replans  # no retry
    assert sim.robot_log.metrics().other_contact_s == 0.0
    # the corrections after the tumble (a turn and a slide here) are each pushed by the arm
    # standing behind the push (truth: the bases' positions as given, and the cosine of the
    # angle between the push and the way from each base to the push's start: the pusher's
    # is positive and the larger), not always by the first arm, which reached the far faces
    # over the cube's top edge (docs/benchmarks.md, 2026-12-03)
    np.testing.assert_allclose(sim.robot_driver.finger_origins,
                               [(b.x, b.y) for b in SWEEP_BASES_2], atol=1e-9)
    assert {c["finger"] for c in ex.corrections} == {1, 2}  # (this run's two corrections)
    for c in ex.corrections:
        d = np.array(c["direction"][:2])
        cos = []
        for base in SWEEP_BASES_2:
            way = np.array(c["start"][:2]) - (base.x, base.y)
            cos.append(float(way @ d) / float(np.linalg.norm(way) * np.linalg.norm(d)))
        assert cos[c["finger"] - 1] > 0.0, (c, cos)
        assert cos[c["finger"] - 1] == max(cos), (c, cos)


def test_tumbling_pinch_leans_further_out_one_finger_never() -> None:
    """``set_tumbling``: with several fingertips the side lean's goal is ``tumble_tilt_deg``
    (36) instead of ``side_tilt_deg`` (30) for a target on a side face, back to 30 when off
    and at a new start; one fingertip keeps 30 (truth: the pointing goals' angle from
    straight down, the targets level with the faces' middles, the bases straight out of
    them: the lean full, outward)."""
    v = np.asarray(CUBE.vertices, dtype=float) * SCALE
    c = v.mean(axis=0)
    pose = (np.array([-c[0], -c[1], -v[:, 2].min()]), np.array([1.0, 0.0, 0.0, 0.0]))
    on_face = np.array([[0.025 + 0.006, 0.0, 0.025], [-0.025 - 0.006, 0.0, 0.025]])

    def lean(ik: FingertipIK, targets: np.ndarray) -> list[float]:
        axes = ik.pointing(targets)
        return [math.degrees(math.acos(-float(a[2]))) for a in axes]

    two = build_robot_scene(CUBE, scale=SCALE, mocap_object=True,
                            arms=[Arm(Robot.builtin(), BasePose(0.5, 0.0, 180.0)),
                                  Arm(Robot.builtin(), BasePose(-0.5, 0.0, 0.0))])
    ik = FingertipIK(two, 0.01, IKConfig(collisions=False))
    ik.set_object(*pose)
    assert lean(ik, on_face) == pytest.approx([30.0, 30.0], abs=1e-6)
    ik.set_tumbling(True)
    assert lean(ik, on_face) == pytest.approx([36.0, 36.0], abs=1e-6)
    ik.set_tumbling(False)
    assert lean(ik, on_face) == pytest.approx([30.0, 30.0], abs=1e-6)
    ik.set_tumbling(True)
    ik.reset(two.home)
    assert lean(ik, on_face) == pytest.approx([30.0, 30.0], abs=1e-6)
    one = build_robot_scene(CUBE, scale=SCALE, mocap_object=True,
                            arms=[Arm(Robot.builtin(), BasePose(0.5, 0.0, 180.0))])
    ik1 = FingertipIK(one, 0.01, IKConfig(collisions=False))
    ik1.set_object(*pose)
    ik1.set_tumbling(True)
    assert lean(ik1, on_face[:1]) == pytest.approx([30.0], abs=1e-6)


def test_the_contact_consistent_command_is_on_for_a_pinch_and_off_for_one_arm() -> None:
    """``press_depth="auto"`` (the default): no bound with one fingertip (an arm pushing),
    :data:`PINCH_PRESS_DEPTH` with two arms' fingertips; an explicit value or None wins."""
    from nonprehensile.sim.robot_run import PINCH_PRESS_DEPTH

    one = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                         scale=SCALE)
    assert one.robot_driver.press_depth is None
    arms = [Arm(Robot.builtin(), BasePose(0.025, -0.5, 90.0)),
            Arm(Robot.builtin(), BasePose(0.025, 0.55, -90.0))]
    two = RobotSimulator(CUBE, arms, scale=SCALE)
    assert two.robot_driver.press_depth == PINCH_PRESS_DEPTH == 0.002
    assert RobotSimulator(CUBE, arms, scale=SCALE, press_depth=None).robot_driver.press_depth \
        is None
    assert RobotSimulator(CUBE, arms[:1], scale=SCALE,
                          press_depth=0.003).robot_driver.press_depth == 0.003
