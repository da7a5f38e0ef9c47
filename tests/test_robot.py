"""Robot arms (issue 22): the bundled Panda against Franka's DH table, robot files and their
checks, the robot scene, the IK, a short robot-executed step, the CLI outputs."""

from __future__ import annotations

import csv
import functools
import json
import math
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

if not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
mujoco = pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")
pytest.importorskip("mink", reason="the robot extra (mink) is not installed: "
                                   "pip install 'nonprehensile[robot]'")

from click.testing import CliRunner  # noqa: E402
from hypothesis import (  # noqa: E402
    given,
    settings,
    strategies as st,
)

from nonprehensile.cli import main  # noqa: E402
from nonprehensile.cli.robot import DEFAULT_CONTROL_RATE  # noqa: E402
from nonprehensile.errors import InputError  # noqa: E402
from nonprehensile.geometry.build import cube  # noqa: E402
from nonprehensile.sim import panda  # noqa: E402
from nonprehensile.sim.ik import FingertipIK, IKConfig  # noqa: E402
from nonprehensile.sim.placement import place_base  # noqa: E402
from nonprehensile.sim.robot import BasePose, Robot  # noqa: E402
from nonprehensile.sim.robot_driver import (  # noqa: E402
    CONTACT_VELOCITY_FULL,
    DEFAULT_CONTROL_EVERY,
    GIVE_ACCEL,
)
from nonprehensile.sim.robot_run import (  # noqa: E402
    PINCH_PRESS_DEPTH,
    ROBOT_FORCE_CAP,
    RobotSimulator,
)
from nonprehensile.sim.robot_scene import Arm, build_robot_scene  # noqa: E402
from nonprehensile.sim.robustness import SweepRobot  # noqa: E402
from nonprehensile.sim.scene import DEFAULT_PARAMS  # noqa: E402

CUBE = cube()
SCALE = 0.05
SKILLS = str(Path(__file__).resolve().parents[1] / "src/nonprehensile/data/cube_skills.json")


def _dh_flange(q: np.ndarray) -> np.ndarray:
    """Franka's published modified-DH chain, multiplied out directly (independent of the
    MJCF): the flange's homogeneous transform."""
    t = np.eye(4)
    for i, (a, d, alpha) in enumerate(panda.DH):
        th = q[i] if i < 7 else 0.0
        ca, sa, ct, st_ = math.cos(alpha), math.sin(alpha), math.cos(th), math.sin(th)
        t = t @ np.array([[ct, -st_, 0, a],
                          [st_ * ca, ct * ca, -sa, -d * sa],
                          [st_ * sa, ct * sa, ca, d * ca],
                          [0, 0, 0, 1]])
    return t


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7))
def test_panda_kinematics_match_franka_dh_table(u: list[float]) -> None:
    m = mujoco.MjModel.from_xml_string(panda.panda_xml())
    d = mujoco.MjData(m)
    q = np.array(panda.Q_MIN) + np.array(u) * (np.array(panda.Q_MAX) - np.array(panda.Q_MIN))
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    t = _dh_flange(q)
    rod = m.body("rod").id
    np.testing.assert_allclose(d.xpos[rod], t[:3, 3], atol=1e-9)
    # the tip lies ROD_LENGTH along the flange's z axis
    np.testing.assert_allclose(d.site("tip").xpos, t[:3, 3] + panda.ROD_LENGTH * t[:3, 2],
                               atol=1e-9)


@pytest.mark.parametrize("length", [0.02, 0.066 + 1e-7, 0.0665, 0.0675, 0.12, 0.5])
def test_the_finger_tool_is_a_rod_and_a_pin_at_every_length(length: float) -> None:
    """Every tool length :meth:`Robot.builtin` takes compiles: the pin is the tool's last
    ``PIN_LENGTH`` above the fingertip (the whole tool when the rod left would be under
    1 mm), the rod the rest; together they run from the flange to 16 mm above the tip site.
    Truth: the compiled capsules' end points along the flange axis."""
    m = mujoco.MjModel.from_xml_string(Robot.builtin(rod_length=length).xml)
    rod_body = m.body("rod").id
    geoms = {m.geom(g).name: g for g in range(m.ngeom) if m.geom_bodyid[g] == rod_body}
    pin = geoms["pin"]
    assert m.geom_size[pin][0] == panda.PIN_RADIUS
    ends = {}
    for name, g in geoms.items():  # a capsule's segment: its frame's z axis, +- half length
        c, half = m.geom_pos[g][2], m.geom_size[g][1]
        ends[name] = (c - half, c + half)
    assert ends["pin"][1] == pytest.approx(length - 0.016, abs=1e-9)
    if "rod" in geoms:
        assert m.geom_size[geoms["rod"]][0] == panda.ROD_RADIUS
        assert ends["rod"][0] == pytest.approx(0.0, abs=1e-9)
        assert ends["rod"][1] == pytest.approx(ends["pin"][0], abs=1e-9)
        assert ends["rod"][1] >= 0.001 - 1e-9
        assert ends["pin"][1] - ends["pin"][0] == pytest.approx(panda.PIN_LENGTH, abs=1e-9)
    else:
        assert length - 0.016 < panda.PIN_LENGTH + 0.001
        assert ends["pin"][0] == pytest.approx(0.0, abs=1e-9)


def test_panda_limits_masses_and_gravity_compensation() -> None:
    r = Robot.builtin("panda")
    np.testing.assert_array_equal(r.lower, panda.Q_MIN)
    np.testing.assert_array_equal(r.upper, panda.Q_MAX)
    np.testing.assert_array_equal(r.velocity, panda.DQ_MAX)
    np.testing.assert_array_equal(r.torque, [87, 87, 87, 87, 12, 12, 12])
    m = mujoco.MjModel.from_xml_string(panda.panda_xml())
    masses = [m.body(f"link{i}").mass[0] for i in range(1, 8)]
    np.testing.assert_allclose(masses, [p[0] for p in panda.INERTIAL], rtol=1e-6)
    # held at home by the servos with gravity compensation: no sag, no drift
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    for _ in range(500):
        mujoco.mj_step(m, d)
    assert np.abs(d.qpos - np.array(panda.Q_HOME)).max() < 1e-4
    # the wrist's gravity torque counts against its 12 N m limit (actuatorgravcomp)
    assert np.abs(d.qfrc_actuator).max() > 1.0


def _write(tmp_path: Path, body: str, actuators: str = "") -> Path:
    p = tmp_path / f"arm{len(list(tmp_path.glob('arm*.xml')))}.xml"
    p.write_text(f"""<mujoco><worldbody><body name="base"><geom type="sphere" size="0.05"/>
      <body name="l1" pos="0 0 0.3">{body}</body></body></worldbody>
      <actuator>{actuators}</actuator></mujoco>""")
    return p


def test_robot_file_checks_one_line(tmp_path: Path) -> None:
    ok = _write(tmp_path, '<joint name="j1" axis="0 0 1" range="-1 1"/><geom type="capsule" '
                'fromto="0 0 0 0.3 0 0" size="0.02"/><site name="tip" pos="0.3 0 0"/>',
                '<position joint="j1" kp="100" kv="5"/>')
    r = Robot.from_file(ok, ["tip"])
    assert r.joint_names == ("j1",) and r.velocity[0] == 2.0
    with pytest.raises(InputError, match="no site 'nope'"):
        Robot.from_file(ok, ["nope"])
    no_act = _write(tmp_path, '<joint name="j1" range="-1 1"/><geom size="0.02"/>'
                    '<site name="tip"/>')
    with pytest.raises(InputError, match="no actuators"):
        Robot.from_file(no_act, ["tip"])
    unlimited = _write(tmp_path, '<joint name="j1" limited="false"/><geom size="0.02"/>'
                       '<site name="tip"/>', '<motor joint="j1"/><position joint="j1" kp="1"/>')
    with pytest.raises(InputError, match="joint 'j1' has no limits"):
        Robot.from_file(unlimited, ["tip"])
    motor = _write(tmp_path, '<joint name="j1" range="-1 1"/><geom size="0.02"/>'
                   '<site name="tip"/>', '<motor joint="j1"/>')
    with pytest.raises(InputError, match="no position servo"):
        Robot.from_file(motor, ["tip"])
    with pytest.raises(InputError, match="does not exist"):
        Robot.from_file(tmp_path / "missing.xml", ["tip"])
    # the CLI: one line, exit 2, before any planning
    runner = CliRunner()
    for path, site, what in ((ok, "nope", "no site"), (no_act, "tip", "no actuators"),
                             (unlimited, "tip", "no limits")):
        res = runner.invoke(main, ["simulate", "plan", SKILLS, "--from", "b:200", "--to",
                                   "a:290", "--step", "90", "--robot-xml", str(path),
                                   "--tip-site", site])
        assert res.exit_code == 2, res.output
        assert what in res.stderr and "Traceback" not in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1
    res = runner.invoke(main, ["simulate", "plan", SKILLS, "--from", "b:200", "--to", "a:290",
                               "--step", "90", "--robot", "panda", "--base", "nan", "0", "0"])
    assert res.exit_code == 2 and "--base" in res.stderr  # the option checker names it
    res = runner.invoke(main, ["plan", SKILLS, "--from", "b:200", "--to", "a:290", "--step",
                               "90", "--tip-site", "tip"])
    assert res.exit_code == 2 and "--robot-xml" in res.stderr
    res = runner.invoke(main, ["simulate", "plan", SKILLS, "--from", "b:200", "--to", "a:290",
                               "--step", "90", "--robot", "panda", "--control-rate", "300"])
    assert res.exit_code == 2 and "--control-rate" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1  # refused before loading and planning
    res = runner.invoke(main, ["plan", SKILLS, "--from", "b:200", "--to", "a:290", "--step",
                               "90", "--robot", "panda", "--control-rate", "300", "--dataset",
                               "cube", "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and "--control-rate" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "out").exists()


def test_user_robot_gets_velocity_servo_and_pairs(tmp_path: Path) -> None:
    arm = _write(tmp_path, '<joint name="j1" axis="0 1 0" range="-1 1"/><geom type="capsule" '
                 'fromto="0 0 0 0.3 0 0" size="0.02"/><site name="tip" pos="0.3 0 0"/>',
                 '<position joint="j1" kp="100" kv="5"/>')
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.from_file(arm, ["tip"]),
                                                        BasePose(-0.3, 0.0, 0.0))])
    m = sc.model
    # the servo's damping moved to a velocity servo beside it: kp (q_ref - q) + kv (v_ref - v)
    assert m.actuator_biasprm[sc.pos_act[0], 2] == 0.0
    assert m.actuator_gainprm[sc.vel_act[0], 0] == pytest.approx(5.0)
    pairs = {(m.geom(int(a)).name, m.geom(int(b)).name)
             for a, b in zip(m.pair_geom1, m.pair_geom2, strict=True)}
    assert ("object", "finger1") in pairs and ("table", "finger1") in pairs
    assert ("object", "arm0/geom#1") in pairs
    # the base rests on the table: not paired with it; every robot geom collides by pairs only
    assert ("table", "arm0/geom#0") not in pairs
    assert all(m.geom_contype[g] == 0 for g in range(m.ngeom))


def test_ik_tracks_a_line_within_limits() -> None:
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(),
                                                        BasePose(-0.25, 0.1, 0.0))],
                           mocap_object=True)
    ik = FingertipIK(sc, 0.001, IKConfig())
    ik.set_object(np.array([0.3, 0.1, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    x0 = np.array([[0.2, 0.1, 0.04]])
    assert ik.converge(x0) < 1e-4
    m, d = sc.model, mujoco.MjData(sc.model)
    worst = 0.0
    q_prev = ik.q
    v_prev = np.zeros_like(q_prev)
    for i in range(1, 301):  # 3 cm along y in 0.3 s
        x = x0 + np.array([[0.0, 0.1 * i / 1000, 0.0]])
        q, _ = ik.step(x)
        v = (q - q_prev) / 0.001
        # the IK's margins: 90 % of the velocity limits, 30 rad/s^2 (from rest)
        assert np.all(np.abs(v) <= 0.9 * sc.velocity + 1e-6)
        assert np.all(np.abs(v - v_prev) <= 1.05 * 30.0 * 0.001)  # the QP solver's tolerance
        v_prev = v
        assert np.all(q >= sc.lower - 1e-9) and np.all(q <= sc.upper + 1e-9)
        q_prev = q
        # the truth: MuJoCo's forward kinematics at the IK's joints, in a fresh data
        d.qpos[sc.qadr] = q
        mujoco.mj_kinematics(m, d)
        worst = max(worst, float(np.linalg.norm(d.site_xpos[sc.tip_sites[0]] - x[0])))
    assert worst < 1e-3


def test_ik_converge_settles_on_the_damped_iterations_fixed_point() -> None:
    """A placement's iterations run with a smaller damping (the null space settles in about
    90 iterations instead of 340): their fixed point does not depend on it, so the posture is
    that of the run's own damping iterated to rest (3,000 iterations, no early stop)."""
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(),
                                                        BasePose(-0.25, 0.1, 0.0))],
                           mocap_object=True)
    x0 = np.array([[0.2, 0.12, 0.06]])
    ik = FingertipIK(sc, 0.001, IKConfig())
    ik.set_object(np.array([0.3, 0.1, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    calls = []
    step = ik.step
    ik.step = lambda t: calls.append(1) or step(t)  # type: ignore[method-assign]
    assert ik.converge(x0) < 1e-4
    q_fast = ik.q
    assert len(calls) < 150
    assert ik._damping is None  # the run's damping (config.damping) is back
    # the truth: the same iterations at the run's damping, run to rest
    slow = FingertipIK(sc, 0.001, IKConfig())
    slow.set_object(np.array([0.3, 0.1, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    slow.dt, slow.posture.gain, slow._deadbeat = 0.02, 0.2, True
    for _ in range(3000):
        slow.step(x0)
    assert np.abs(slow.q - q_fast).max() < 2e-4
    assert np.linalg.norm(slow.tips() - x0) < 1e-5


def test_ik_fast_qp_equals_mink_solve_ik_near_the_object() -> None:
    """The IK's own QP assembly (daqp called directly, the joint box as simple bounds, only
    the collision pairs in range as rows) gives mink's ``solve_ik`` step, solve by solve,
    along a descent onto the cube's side face where the rod comes within the collision
    limit's detection distance and the joint box is active (two Pandas: two tasks)."""
    path = np.tile(np.array([[[0.27, 0.1, 0.03], [0.33, 0.1, 0.03]]]), (2, 1, 1))
    bases = [BasePose(-0.25, 0.1, 0.0), BasePose(0.85, 0.1, 180.0)]
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(), b) for b in bases],
                           mocap_object=True)
    ik = FingertipIK(sc, 0.004, IKConfig())
    v = np.asarray(CUBE.vertices, dtype=float) * SCALE
    c = v.mean(axis=0)
    ik.set_object(np.array([0.3 - c[0], 0.1 - c[1], -v[:, 2].min()]),
                  np.array([1.0, 0.0, 0.0, 0.0]))
    start = path[0] + np.array([[-0.03, 0.0, 0.06], [0.03, 0.0, 0.06]])
    assert ik.converge(start) < 1e-3
    rows = box_active = held = 0
    for i in range(120):  # down and in onto the faces, then pressing 1 cm past them
        s = min(1.0, i / 80)
        x = (1 - s) * start + s * (path[0] + np.array([[0.01, 0.0, 0.0], [-0.01, 0.0, 0.0]]))
        ik.position_tasks[0].target, ik.position_tasks[1].target = x[0], x[1]
        ref = ik.solve_mink()
        fast = ik._solve()
        assert (ref is None) == (fast is None)  # infeasible for both, or solved by both
        if ref is None:
            held += 1
            ik.step(x)
            continue
        assert np.abs(fast - ref).max() <= 1e-7 * max(1.0, float(np.abs(ref).max()))
        got = ik._collision_rows(ik.configuration, ik.dt)
        rows += got is not None
        upper, lower = ik._box.bounds(ik.configuration.q, ik.dt)
        box_active += bool(np.any(np.isclose(fast * ik.dt, upper, atol=1e-9)
                                  | np.isclose(fast * ik.dt, lower, atol=1e-9)))
        ik.step(x)
    assert rows > 10 and box_active > 0  # both kinds of constraint were in the QP
    assert held < 60


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-0.3, 0.3), min_size=3, max_size=3),
       st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(
           lambda q: sum(x * x for x in q) > 1e-3))
def test_ik_set_object_poses_the_object_as_mujoco_kinematics(pos: list[float],
                                                             quat: list[float]) -> None:
    """The IK's collision rows read the object's geom pose: ``set_object`` poses the body
    and its geoms at once, exactly as MuJoCo's own kinematics does from the mocap pose
    (before, the geoms kept the previous solve's pose until the step's integration)."""
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(), BasePose(-0.3, 0.1,
                                                                                  0.0))],
                           mocap_object=True)
    ik = FingertipIK(sc, 0.01, IKConfig())
    q = np.asarray(quat) / np.linalg.norm(quat)
    ik.set_object(np.asarray(pos), q)
    d, m = ik.configuration.data, ik.configuration.model
    got = (d.geom_xpos.copy(), d.geom_xmat.copy(), d.xpos.copy(), d.xmat.copy())
    mujoco.mj_kinematics(m, d)
    for a, b in zip(got, (d.geom_xpos, d.geom_xmat, d.xpos, d.xmat), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    obj = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    np.testing.assert_allclose(d.xpos[obj], pos, atol=1e-12)  # the pose really moved


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-0.02, 0.02), min_size=6, max_size=6),
       st.lists(st.floats(-0.17, 0.17), min_size=6, max_size=6))
def test_ik_pointing_follows_every_object_pose(shift: list[float], tilts: list[float]) -> None:
    """The finger's lean reads the object's top where the object is now: an IK that pointed
    at one pose and then at another gives the pointing of an IK that saw only the second
    (the top is derived once per pose, not per solve), and that top is the highest vertex
    of the mesh as MuJoCo's own kinematics poses it."""
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(), BasePose(-0.3, 0.1,
                                                                                  0.0))],
                           mocap_object=True)
    moved, fresh = FingertipIK(sc, 0.01, IKConfig()), FingertipIK(sc, 0.01, IKConfig())
    # the cube on the table near (0.3, 0.1), tilted by up to 20 degrees (its body origin is
    # a vertex: it spans 5 cm from there)
    origin = np.array([0.3, 0.1, 0.0])
    poses = []
    for i in range(2):
        quat = np.array([1.0, *tilts[3 * i:3 * i + 3]])
        poses.append((origin + np.asarray(shift[3 * i:3 * i + 3]), quat / np.linalg.norm(quat)))
    # beside the object on the arm's side, from far above its top (a transit: the top is not
    # derived) down to its lower half: not leaning, partly, fully
    targets = [np.array([0.28, 0.125, z]) for z in (0.25, 0.08, 0.06, 0.04, 0.01)]
    for t in targets:
        moved.pointing(t[None])
    moved.set_object(*poses[0])
    for t in targets:
        moved.pointing(t[None])
    moved.set_object(*poses[1])
    fresh.set_object(*poses[1])
    for t in targets:
        np.testing.assert_array_equal(moved.pointing(t[None]), fresh.pointing(t[None]))
    np.testing.assert_array_equal(moved.pointing(targets[0][None]), [[0.0, 0.0, -1.0]])
    assert not np.array_equal(moved.pointing(targets[-1][None]), [[0.0, 0.0, -1.0]])
    d, m = fresh.configuration.data, fresh.configuration.model
    mujoco.mj_kinematics(m, d)
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object")
    mesh = int(m.geom_dataid[g])
    verts = m.mesh_vert[m.mesh_vertadr[mesh]:m.mesh_vertadr[mesh] + m.mesh_vertnum[mesh]]
    world = verts @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
    assert moved._pose_top[0] == pytest.approx(float(world[:, 2].max()), abs=1e-12)
    assert fresh._pose_top[0] == moved._pose_top[0]


def test_robot_executes_a_push_roll_step() -> None:
    """Step 1 of the main plan's skill, by the bundled Panda at a fixed base: the cube rolls
    onto the predicted face; the judge's records are those of the free fingertips."""
    from nonprehensile.cli.options import state_set
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.sim.execute import simulate_step
    from nonprehensile.states import State

    poly, skills = read_skills(SKILLS)
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    p = plan(poly, exp, State("b", 200), State("a", 290), position=(0.3, 0.1),
             motions=motions, scale=ds.scale)
    sim = RobotSimulator(poly, [Arm(Robot.builtin(), BasePose(0.53, -0.51, 112.5))],
                         scale=ds.scale)
    out = simulate_step(sim, p.steps[0], fingers=ds.fingers)
    assert out.result.final_state is not None and out.result.final_state.face == "a"
    assert out.comparison.chain_ok
    met = sim.robot_log.metrics()
    assert met.tracking_error_contact_max_m is not None
    assert met.tracking_error_contact_max_m < 0.005
    assert met.other_contact_s == 0.0 and met.position_margin_min_rad > 0.1
    # the default control rate, the library's and the CLI's: 100 Hz
    assert sim.describe()["rates"] == {"control_hz": 100.0, "servo_hz": 1000.0,
                                       "physics_hz": 1000.0}
    assert DEFAULT_CONTROL_EVERY == 10 and DEFAULT_CONTROL_RATE * 10 == 1000.0
    assert SweepRobot((Arm(Robot.builtin(), BasePose(0.53, -0.51, 112.5)),)).control_every \
        == DEFAULT_CONTROL_EVERY
    # the IK at 1 kHz: the same outcome, 8-10 times the solves (a trajectory's last
    # control period is shorter)
    fast = RobotSimulator(poly, [Arm(Robot.builtin(), BasePose(0.53, -0.51, 112.5))],
                          scale=ds.scale, control_every=1)
    out1 = simulate_step(fast, p.steps[0], fingers=ds.fingers)
    assert out1.result.final_state is not None and out1.result.final_state.face == "a"
    met1 = fast.robot_log.metrics()
    assert met.n_solves * 8 < met1.n_solves <= met.n_solves * 10
    assert met1.tracking_error_contact_max_m is not None
    assert met1.tracking_error_contact_max_m < 0.005
    assert fast.describe()["rates"]["control_hz"] == 1000.0


def test_place_base_and_cli_joint_trajectories(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    # a short path 0.5 m out: a feasible base faces it
    path = np.tile(np.array([[0.3, 0.1, 0.04]]), (20, 1, 1))
    path[:, 0, 0] += np.linspace(0.0, 0.03, 20)
    pl = place_base(Robot.builtin(), CUBE, SCALE, [(path, 20.0)], radii=(0.5,),
                    n_directions=4)
    assert pl.feasible and pl.tried == 4 and pl.reach_error_m < 0.002
    out = tmp_path / "out"
    # the base searched (no --base): the joints are the searched base's, and the search is
    # drawn as a reachability map beside them (a search of 4 candidates, not the default
    # 144: the command's plumbing is what this checks; tests/test_reachability.py the search)
    import functools

    import nonprehensile.sim.placement as placement_module

    monkeypatch.setattr(placement_module, "place_base", functools.partial(
        place_base, radii=(0.5,), n_directions=4))
    res = CliRunner().invoke(main, [
        "plan", SKILLS, "--from", "b:200", "--at", "0.3", "0.1", "--to", "a:290", "--step",
        "90", "--dataset", "cube", "--robot", "panda", "--out", str(out), "--json"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    meta = json.loads((out / "joints_plan.json").read_text())
    placement = doc["robot"]["placement"]
    assert placement["feasible"] and placement["candidates"] == 4
    assert meta["robots"][0]["base"] == placement["base"]
    png = out / "reachability.png"
    assert str(png) in doc["files"] and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert meta["rates"]["control_hz"] == 100.0 and len(meta["joints"]) == 7
    with (out / "joints_step1.csv").open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0][:2] == ["time", "arm0/joint1"] and rows[0][-1] == "arm0/joint7_vel"
    arr = np.array(rows[1:], dtype=float)
    assert np.all(np.diff(arr[:, 0]) > 0)
    q = arr[:, 1:8]
    assert np.all(q >= np.array(panda.Q_MIN) - 1e-9) and np.all(q <= np.array(panda.Q_MAX))
    assert np.all(np.abs(arr[:, 8:]) <= np.array(panda.DQ_MAX) + 1e-9)
    assert meta["ik_tip_error_max_m"] < 0.005


def test_closed_loop_main_plan_by_the_panda() -> None:
    """The main plan, closed loop with transits, by the bundled Panda at a fixed base: the
    goal is reached and nothing but the fingertip touches the cube or the table."""
    res = CliRunner().invoke(main, [
        "simulate", "plan", SKILLS, "--from", "b:200", "--at", "0.3", "0.1", "--to", "e:110",
        "--step", "90", "--dataset", "cube", "--robot", "panda", "--base", "0.53", "-0.51",
        "112.5", "--json"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["success"] and doc["loop"] == "closed"
    assert doc["robot"]["robots"][0]["base"]["yaw_deg"] == 112.5
    whole = doc["robot_metrics"]
    assert whole["other_contact_s"] == 0.0
    for r in doc["records"]:
        assert r["robot"]["tracking_error_contact_max_m"] < 0.004
    assert doc["execution"]["limits"]["transit_finger_object_contact_s"] == 0.0


def test_ik_neither_rings_on_a_step_nor_lags_a_moving_target() -> None:
    """A dead-beat IK (the whole error in one step) under the joint acceleration bound
    at 1 kHz overshoots a 5 mm step of its target by half of it and rings; with the default
    task time constant (8 ms) and the target's motion fed forward it settles without
    overshoot, and follows a target moving at 0.1 m/s within 0.2 mm (a 10 ms first-order
    task without the feed-forward lags 0.9 mm). Truth: MuJoCo's kinematics at the IK's
    joints."""
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(),
                                                        BasePose(-0.25, 0.1, 0.0))],
                           mocap_object=True)
    m, d = sc.model, mujoco.MjData(sc.model)

    def tip(q: np.ndarray) -> np.ndarray:
        d.qpos[sc.qadr] = q
        mujoco.mj_kinematics(m, d)
        return np.array(d.site_xpos[sc.tip_sites[0]])

    x0 = np.array([[0.2, 0.1, 0.04]])
    step = x0 + np.array([[0.0, 0.005, 0.0]])
    overshoot = {}
    tau_default = IKConfig().task_time_constant
    for tau in (0.0, tau_default):
        ik = FingertipIK(sc, 0.001, IKConfig(task_time_constant=tau))
        ik.set_object(np.array([0.3, 0.1, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))
        assert ik.converge(x0) < 1e-4
        dy = np.array([tip(ik.step(step)[0])[1] - step[0, 1] for _ in range(300)])
        overshoot[tau] = float(dy.max())
        assert abs(dy[-1]) < 1e-4
    assert overshoot[0.0] > 2e-3  # dead-beat: more than 2 mm past a 5 mm step
    assert overshoot[tau_default] < 1e-4
    ik = FingertipIK(sc, 0.001, IKConfig())
    ik.set_object(np.array([0.3, 0.1, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    assert ik.converge(x0) < 1e-4
    worst = 0.0
    for i in range(1, 301):  # from rest to 0.1 m/s along y in 50 ms, then on
        t = i * 0.001
        s = 0.1 * (t * t / 0.1 if t < 0.05 else t - 0.025)
        x = x0 + np.array([[0.0, s, 0.0]])
        q, _ = ik.step(x)
        if t > 0.1:
            worst = max(worst, float(np.linalg.norm(tip(q) - x[0])))
    assert worst < 2e-4


def test_two_arms_one_finger_each() -> None:
    """Two Pandas are fingers R1 and R2; the base search places the second away from the
    first; each fingertip follows its own target."""
    path = np.tile(np.array([[[0.28, 0.1, 0.03], [0.32, 0.1, 0.03]]]), (10, 1, 1))
    first = place_base(Robot.builtin(), CUBE, SCALE, [(path, 20.0)], radii=(0.5,),
                       n_directions=4, finger=0)
    second = place_base(Robot.builtin(), CUBE, SCALE, [(path, 20.0)], radii=(0.5,),
                        n_directions=4, finger=1, avoid=[first.base])
    assert first.feasible and second.feasible
    assert math.hypot(first.base.x - second.base.x, first.base.y - second.base.y) >= 0.4
    with pytest.raises(InputError, match="far enough"):
        place_base(Robot.builtin(), CUBE, SCALE, [(path, 20.0)], radii=(0.5,),
                   n_directions=1, avoid=[BasePose(0.8, 0.1, 0.0)])
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), first.base),
                                Arm(Robot.builtin(), second.base)], scale=SCALE)
    assert sim.n_fingers == 2 and len(sim.scene.joint_names) == 14
    m = sim.model
    assert m.body(m.geom("finger2").bodyid[0]).name.startswith("arm1/")
    ik = sim.robot_driver.ik
    ik.set_object(np.array([0.3, 0.1, -1.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    assert ik.converge(path[0]) < 1e-3


def test_the_smallest_fingertip_presses_a_side_face_clear_of_the_tool() -> None:
    """The physics distribution's smallest fingertip (5 mm) on the bundled tool, pointing
    straight down beside the cube, pressed 0.9 mm into a side face 15 mm below its top (the
    tool's lower end level with the face's top edge, where a push-roll pushes): the IK puts
    it there with its collision limit on, the tool standing off the cube by at least the
    limit's margin.
    Truth: MuJoCo's own distance between each tool geom and the cube at the converged joints.
    An 8 mm rod down to the tip stood 1 mm from the face before any press, and the limit held
    the fingertip 0.6 mm short of such a target (1 mm margin; 0.9 mm at 1.5 mm)."""
    params = replace(DEFAULT_PARAMS, finger_radius=0.005)
    # the base to the side of the pushed (+x) face: no lean towards it (cos_b = 0)
    sc = build_robot_scene(CUBE, scale=SCALE, params=params, mocap_object=True,
                           arms=[Arm(Robot.builtin(), BasePose(0.3, 0.75, -90.0))])
    cfg = IKConfig(side_tilt_deg=0.0)
    ik = FingertipIK(sc, 0.001, cfg)
    v = np.asarray(CUBE.vertices, dtype=float) * SCALE
    c = v.mean(axis=0)
    ik.set_object(np.array([0.3 - c[0], 0.1 - c[1], -v[:, 2].min()]),
                  np.array([1.0, 0.0, 0.0, 0.0]))
    face = 0.3 + SCALE / 2
    target = np.array([[face + 0.005 - 0.0009, 0.1, 0.035]])
    # from straight above the target, as an approach comes
    assert ik.converge(target + np.array([0.0, 0.0, 0.03]), iterations=1000) < 1e-3
    assert ik.converge(target, iterations=1000) < 1e-4
    m, d = sc.model, mujoco.MjData(sc.model)
    d.qpos[sc.qadr] = ik.q
    d.mocap_pos[:] = ik.configuration.data.mocap_pos
    d.mocap_quat[:] = ik.configuration.data.mocap_quat
    mujoco.mj_kinematics(m, d)
    z = d.site_xmat[sc.tip_sites[0]].reshape(3, 3)[:, 2]
    assert z[2] < -0.99  # straight down
    obj = m.geom("object").id
    tool = [m.geom(n).id for n in ("arm0/rod", "arm0/pin")]
    fromto = np.zeros(6)
    gaps = [mujoco.mj_geomDistance(m, d, g, obj, 0.05, fromto) for g in tool]
    assert min(gaps) >= cfg.collision_margin - 1e-4


def test_finger_leans_back_beside_the_object_and_arms_stand_on_their_side() -> None:
    """Beside the cube (target below its top) the finger leans towards its own base, by the
    configured angle, so the rod above the tip stands off the face; over the cube it points
    down; the angle's truth is MuJoCo's own site frame at the converged joints."""
    base = BasePose(0.8, 0.1, 180.0)
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(), base)],
                           mocap_object=True)
    ik = FingertipIK(sc, 0.001, IKConfig(side_tilt_deg=30.0, collisions=False))
    # the cube's body placed so that its centre is at (0.3, 0.1), resting on the table
    v = np.asarray(CUBE.vertices, dtype=float) * SCALE
    c = v.mean(axis=0)
    ik.set_object(np.array([0.3 - c[0], 0.1 - c[1], -v[:, 2].min()]),
                  np.array([1.0, 0.0, 0.0, 0.0]))
    m, d = sc.model, mujoco.MjData(sc.model)
    beside = np.array([[0.3 + 0.025 + 0.006, 0.1, 0.03]])  # on the +x face, the base's side
    over = np.array([[0.3, 0.1, 0.08]])
    for x, want in ((beside, 30.0), (over, 0.0)):
        ik.reset(sc.home)
        assert ik.converge(x, iterations=1000) < 1e-3
        d.qpos[sc.qadr] = ik.q
        mujoco.mj_kinematics(m, d)
        z = d.site_xmat[sc.tip_sites[0]].reshape(3, 3)[:, 2]
        tilt = math.degrees(math.acos(-z[2]))
        assert abs(tilt - want) < 3.0
        if want:  # the flange sits towards the base (+x), away from the face
            assert z[0] < -0.4
            rod = d.geom_xpos[m.geom("arm0/rod").id]
            assert rod[0] > x[0, 0] + 0.005
            pin = d.geom_xpos[m.geom("arm0/pin").id]  # (the tool's part nearest the face)
            assert pin[0] > x[0, 0] + 0.005
    # two fingers pinching along x: each arm stands on its own finger's side
    path = np.tile(np.array([[[0.27, 0.1, 0.03], [0.33, 0.1, 0.03]]]), (10, 1, 1))
    for finger, sign in ((0, -1.0), (1, 1.0)):
        pl = place_base(Robot.builtin(), CUBE, SCALE, [(path, 20.0)], radii=(0.5,),
                        n_directions=8, finger=finger)
        assert sign * (pl.base.x - 0.3) > 0.5 * 0.5  # within 60 degrees of its side
        assert pl.tried <= 3


def _table_force(m, d, tip: int) -> float:
    """The contact force on geom ``tip`` (norm, N), summed from MuJoCo's contacts here (not
    through the driver's force reading)."""
    f = np.zeros(6)
    total = np.zeros(3)
    for i in range(d.ncon):
        c = d.contact[i]
        if tip in (c.geom1, c.geom2):
            mujoco.mj_contactForce(m, d, i, f)
            total += c.frame.reshape(3, 3).T @ f[:3] * (1.0 if c.geom2 == tip else -1.0)
    return float(np.linalg.norm(total))


def _press_table(compliance: bool, stiffness: float, force_limit: float | None,
                 force_cap: float | str | None = None, depth: float = 0.02,
                 force_feedforward: bool | str = False):
    """A target ``depth`` (2 cm) inside the table for 1.5 s (the fingertip's centre rests
    6 mm above it): the contact forces on the fingertip at every physics step, and the
    driver. The stiff arm without its force cap unless ``force_cap`` is given, and without
    the contact force fed forward unless ``force_feedforward`` says so."""
    params = replace(DEFAULT_PARAMS, stiffness=stiffness)
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                         scale=SCALE, params=params, force_limit=force_limit,
                         compliance=compliance, force_cap=None if compliance else force_cap,
                         force_feedforward=force_feedforward)
    x0 = np.array([[0.0, 0.0, 0.03]])
    x1 = np.array([[0.0, 0.0, -depth]])
    targets = np.concatenate([x0 + (x1 - x0) * np.linspace(0.0, 1.0, 500)[:, None, None],
                              np.repeat(x1[None], 1000, axis=0)])
    return _over_table(sim, targets), sim.robot_driver


def _over_table(sim: RobotSimulator, targets: np.ndarray) -> np.ndarray:
    """Drive the fingertip along ``targets`` (shape (n, 1, 3), one per physics step) with
    the cube far away: the contact forces on the fingertip at every step (N)."""
    drv, d, m = sim.robot_driver, sim.data, sim.model
    mujoco.mj_resetData(m, d)
    d.qpos[sim.judge.qadr:sim.judge.qadr + 3] = [2.0, 2.0, 0.5]  # the cube far away
    drv.reset()
    drv.place(d, targets[0])
    ctl = drv.controls(targets)
    tip = m.geom("finger1").id
    forces = []
    for i in range(len(targets)):
        d.ctrl[:] = ctl[i]
        mujoco.mj_step(m, d)
        forces.append(_table_force(m, d, tip))
    return np.array(forces)


def test_compliant_fingertip_presses_like_the_free_fingertip() -> None:
    """The force-limited finger command: pressed into the table, the arm's fingertip holds
    the free fingertip's force (truth: MuJoCo's contact forces, summed here, not the
    driver's reading): its spring's ``k g`` (``g``: the command's give behind the target)
    below the force limit, the limit above it; the stiff arm presses many times harder. The
    tracking error is measured against the command (target plus give), the reference error
    against the target."""
    # a spring without a limit (300 N/m): the force is k g, steadily (no hopping)
    f, drv = _press_table(True, 300.0, math.inf)
    steady = f[1000:]
    g = drv.log.give[-500:, 0]
    assert steady.min() > 1.0  # always touching
    # (the give has a sideways part: the table's friction on the pressed tip)
    assert np.abs(steady - 300.0 * np.linalg.norm(g, axis=1)).max() < 0.1 * steady.mean()
    assert g[:, 2].min() > 0.01  # upward, out of the table
    # a stiff spring (3000 N/m) would press far harder; the force limit (10 N per axis: the
    # table's push is along z alone) holds it
    f, drv = _press_table(True, 3000.0, 10.0)
    steady = f[1000:]
    assert 0.8 * 10.0 < steady.mean() < 1.25 * 10.0
    log = drv.log
    give = log.give[-1, 0]
    tips = np.asarray(log._tips[log.n - 1, 0])
    cmd = np.asarray(log._target[log.n - 1, 0]) + give
    assert log.error[-1] == pytest.approx(np.linalg.norm(tips - cmd), abs=1e-9)
    assert log.error_ref[-1] == pytest.approx(
        np.linalg.norm(tips - log._target[log.n - 1, 0]), abs=1e-9)
    assert log.error[-1] < log.error_ref[-1] - 0.01  # the give is most of the distance
    # the stiff arm (no compliance) at the same target
    f_stiff, _ = _press_table(False, 3000.0, None)
    assert f_stiff[1000:].mean() > 3.0 * steady.mean()


def test_the_stiff_arms_force_cap_holds_its_force_at_the_cap() -> None:
    """The stiff arm's force cap (one fingertip's default, 40 N): pressed 2 cm into the
    table, the fingertip's command gives way upwards until the force is the cap, and holds
    it there (truth: MuJoCo's contact forces, summed here, not the driver's reading); the
    arm without a cap presses several times harder. The tracking error is against the
    command, the give included. Without the force fed forward, a light press (under the
    cap) keeps no give; with it (the default) the arm reaches the light press's depth, the
    table's stiffness past the cap, and the give holds the cap there too."""
    f, drv = _press_table(False, 600.0, None, force_cap="auto")
    assert drv.force_cap == ROBOT_FORCE_CAP == 40.0
    steady = f[1000:]
    assert abs(steady.mean() - 40.0) < 2.0 and steady.max() < 44.0 and steady.min() > 36.0
    log = drv.log
    g = log.give[-1, 0]
    assert g[2] > 0.005  # up, out of the table
    tips = np.asarray(log._tips[log.n - 1, 0])
    cmd = np.asarray(log._target[log.n - 1, 0]) + g
    assert log.error[-1] == pytest.approx(np.linalg.norm(tips - cmd), abs=1e-9)
    f_free, _ = _press_table(False, 600.0, None, force_cap=None)
    assert f_free[1000:].mean() > 3.0 * steady.mean()
    # a light press: only its first touch's impact goes past the cap; the give is back to
    # none within a few tenths of a second and the press is the uncapped one's
    f_light, drv = _press_table(False, 600.0, None, force_cap="auto", depth=-0.0055)
    f_plain, _ = _press_table(False, 600.0, None, force_cap=None, depth=-0.0055)
    assert 1.0 < f_light[1000:].mean() < 0.9 * 40.0
    assert not drv.log.give[-500:].any()
    assert f_light[-1] == pytest.approx(f_plain[-1], rel=0.02)
    f_fed, drv = _press_table(False, 600.0, None, force_cap="auto", depth=-0.0055,
                              force_feedforward="auto")
    assert drv.force_feedforward
    assert abs(f_fed[1000:].mean() - 40.0) < 2.0 and drv.log.give[-1, 0, 2] > 0.0


def test_pressed_past_the_cap_the_velocity_set_points_go_no_faster_into_the_object() -> None:
    """One stiff arm's fingertip on the cube's top face, at rest, its velocity set points
    driving it 10 cm/s down into the face and 2 cm/s along it: pressed past the force cap
    (40 N) their part into the object is taken down to the fingertip's own motion (none),
    the part along the face kept; ramped (``contact_velocity`` 2), in proportion to the
    force's excess from the cap to twice it, in full beyond. Set points leaving the object,
    a fingertip off the object (the table's contact) and the switch off leave the row as it
    is."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))], scale=SCALE)
    drv, d, m = sim.robot_driver, sim.data, sim.model
    assert drv.contact_velocity == CONTACT_VELOCITY_FULL == 1.0 and drv.force_cap == 40.0
    assert sim.describe()["finger_command"]["contact_velocity_full_caps"] == 1.0
    mujoco.mj_resetData(m, d)
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(d.xmat[drv._obj].reshape(3, 3), np.eye(3), atol=1e-12)
    # the fingertip on the top face's middle (the cube's body origin is a corner), normal +z
    on_top = d.xpos[drv._obj] + np.array([0.5 * SCALE, 0.5 * SCALE, SCALE + drv.finger_radius])
    drv.reset()
    drv.place(d, on_top[None])
    d.qvel[:] = 0.0  # the fingertip at rest
    mujoco.mj_forward(m, d)
    drv._touch = True  # (the judge's contact reading: on the object)
    pinv = drv._tip_pinv()
    jac = drv._jac_c
    vc = drv.scene.vel_act

    def tip_velocity(v: list[float], force: float) -> np.ndarray:
        row = np.zeros(m.nu)
        row[vc] = pinv @ np.array(v)
        out = drv._velocity_in_contact(row, [(0, force)], 40.0)
        return np.asarray(jac @ out[vc])

    # (atol: the give's damped least-squares inverse, J J^+ within 2e-5 of the identity)
    v = [0.02, 0.0, -0.1]
    for force in (40.5, 200.0):  # past the cap: no faster than the tip (at rest)
        np.testing.assert_allclose(tip_velocity(v, force), [0.02, 0.0, 0.0], atol=1e-5)
    drv.contact_velocity = 2.0  # ramped: none at the cap, half at 1.5 caps, in full from 2
    np.testing.assert_allclose(tip_velocity(v, 40.0), v, atol=1e-5)
    np.testing.assert_allclose(tip_velocity(v, 60.0), [0.02, 0.0, -0.05], atol=1e-5)
    np.testing.assert_allclose(tip_velocity(v, 80.0), [0.02, 0.0, 0.0], atol=1e-5)
    drv.contact_velocity = CONTACT_VELOCITY_FULL
    np.testing.assert_allclose(tip_velocity([0.02, 0.0, 0.1], 200.0), [0.02, 0.0, 0.1],
                               atol=1e-5)  # leaving the object
    drv._touch = False  # a press on the table only
    np.testing.assert_allclose(tip_velocity(v, 200.0), v, atol=1e-5)
    drv._touch = True
    # the fingertip moving 5 cm/s into the face: set points faster into it are taken down
    # to its speed, slower ones and those leaving it are kept (a sign error, or the tip's
    # own velocity left out, fails here)
    d.qvel[drv._dsl] = pinv @ np.array([0.0, 0.0, -0.05])
    for into, want in ((-0.1, -0.05), (-0.03, -0.03), (0.02, 0.02)):
        np.testing.assert_allclose(tip_velocity([0.02, 0.0, into], 200.0), [0.02, 0.0, want],
                                   atol=1e-5)
    d.qvel[:] = 0.0
    # the switch: off, _cap leaves the velocity set points to the spline (the force as
    # _cap reads it: _tip_force_rows)
    drv._tip_force_rows = lambda: [[0.0, 0.0, 200.0]]  # type: ignore[method-assign]
    row = np.zeros(m.nu)
    row[vc] = pinv @ np.array(v)
    assert not np.allclose(drv._cap(row)[vc], row[vc])
    drv.reset()
    drv.contact_velocity = None
    np.testing.assert_array_equal(drv._cap(row)[vc], row[vc])
    assert sim.describe()["finger_command"]["contact_velocity_full_caps"] is None


def test_pressed_past_the_cap_on_the_table_a_fingertip_keeps_its_velocity_set_points(
) -> None:
    """Two arms with a force cap: fingertip 1 presses the table past the cap beside the cube
    while fingertip 0 touches the cube (the driver's contact flag is any fingertip's): only
    a fingertip touching the object has its set points into the object taken out; fingertip
    1's motion towards the cube along the table is kept. Truth: the contacts MuJoCo reports
    after placing the fingertips in (not the flag)."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0)),
                                Arm(Robot.builtin(), BasePose(0.0, 0.45, -90.0))],
                         scale=SCALE, force_cap=40.0)
    drv, d, m = sim.robot_driver, sim.data, sim.model
    assert drv.n_fingers == 2 and drv.force_cap == 40.0
    mujoco.mj_resetData(m, d)
    mujoco.mj_forward(m, d)
    o = d.xpos[drv._obj].copy()
    r = drv.finger_radius
    # fingertip 0 a hair into the cube's top face, fingertip 1 a hair into the table 4 cm
    # beside the cube's +x face
    on_top = o + np.array([0.5 * SCALE, 0.5 * SCALE, SCALE + r - 2e-4])
    on_table = o + np.array([SCALE + 0.04, 0.5 * SCALE, r - 2e-4])
    drv.reset()
    drv.place(d, np.array([on_top, on_table]))
    d.qvel[:] = 0.0
    mujoco.mj_forward(m, d)
    assert drv._tips_on_object() == {0}
    drv._touch = True  # (the flag: some fingertip on the object)
    pinv = drv._tip_pinv()
    jac = drv._jac_c
    vc = drv.scene.vel_act
    row = np.zeros(m.nu)
    v = np.array([0.0, 0.0, 0.0, -0.1, 0.0, -0.02])  # fingertip 1 towards the cube, down
    row[vc] = pinv @ v
    out = drv._velocity_in_contact(row, [(1, 200.0)], 40.0)
    np.testing.assert_array_equal(out, row)
    # fingertip 0 pressed past the cap into the top: its part into the cube goes
    v0 = np.array([0.02, 0.0, -0.1, 0.0, 0.0, 0.0])
    row[vc] = pinv @ v0
    got = jac @ drv._velocity_in_contact(row, [(0, 200.0), (1, 200.0)], 40.0)[vc]
    np.testing.assert_allclose(got, [0.02, 0.0, 0.0, 0.0, 0.0, 0.0], atol=1e-4)


def test_the_force_caps_give_comes_back_after_the_contact() -> None:
    """Pressed 2 cm into the table, then the target lifted 3 cm above it: once the fingertip
    is off the table the give keeps coming back, at most ``give_speed`` a step, to none (not
    dropped off the set points at once, nor left on the command), and the command is the
    target again. Truth: the logged give against the driver's bound, MuJoCo's contact forces."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))], scale=SCALE)
    drv = sim.robot_driver
    down, up = np.array([[0.0, 0.0, -0.02]]), np.array([[0.0, 0.0, 0.03]])
    targets = np.concatenate([up + (down - up) * np.linspace(0.0, 1.0, 500)[:, None, None],
                              np.repeat(down[None], 700, axis=0),
                              down + (up - down) * np.linspace(0.0, 1.0, 300)[:, None, None],
                              np.repeat(up[None], 700, axis=0)])
    forces = _over_table(sim, targets)
    g = np.linalg.norm(drv.log.give[:, 0], axis=1)
    assert g[1150] > 0.005  # pressing: the give holds the cap
    free = int(np.flatnonzero(forces > 0.0).max()) + 1  # off the table from here
    assert g[free] > 0.0  # a give left when the contact ends ...
    assert np.abs(np.diff(g[free:])).max() <= drv.give_speed * drv.dt * (1 + 1e-9)
    assert g[-1] == 0.0 and not drv._cap_on  # ... comes back to none


def _held_against(force: np.ndarray, feedforward: bool,
                  every: int = DEFAULT_CONTROL_EVERY) -> tuple[np.ndarray, Any]:
    """The fingertip held on a target in free space for 1 s while a known force ``force``
    (N, world) pushes it (MuJoCo's ``xfrc_applied`` on the tip's body, at the tip site),
    the force sensor reading that force (the driver's contact reading replaced by it, the
    contact gate held open), the IK every ``every`` physics steps: the fingertip's
    tracking error of each row, and the driver."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                         scale=SCALE, force_feedforward=feedforward, control_every=every)
    drv, d, m = sim.robot_driver, sim.data, sim.model
    # (the reading every force of the driver comes from: _tip_forces is its array)
    row = np.asarray(force, dtype=np.float64).tolist()
    drv._tip_force_rows = lambda: [row]  # type: ignore[method-assign]
    drv._contacts = lambda data: (False, False, True)  # type: ignore[method-assign]
    mujoco.mj_resetData(m, d)
    d.qpos[sim.judge.qadr:sim.judge.qadr + 3] = [2.0, 2.0, 0.5]  # the cube far away
    targets = np.repeat(np.array([[[0.0, 0.0, 0.12]]]), 1000, axis=0)
    drv.reset()
    drv.place(d, targets[0])
    ctl = drv.controls(targets)
    site = drv._tip_sites[0]
    body = int(m.site_bodyid[site])
    for i in range(len(targets)):
        d.ctrl[:] = ctl[i]
        mujoco.mj_forward(m, d)
        # the force at the tip site: its moment about the body's centre of mass too
        arm = d.site_xpos[site] - d.xipos[body]
        d.xfrc_applied[body, :3] = force
        d.xfrc_applied[body, 3:] = np.cross(arm, force)
        mujoco.mj_step(m, d)
    return drv.log.error, drv


def test_the_contact_force_feedforward_holds_the_fingertip_on_its_command() -> None:
    """``force_feedforward``: a known 35 N on the fingertip (under the cap; MuJoCo's own
    dynamics, the force applied to the tip's body) deflects the stiff arm by 2.3 mm from
    its command; with the force fed forward to the servos (``-J^T F`` on their set points,
    averaged over each control period) the fingertip holds its command within a few
    micrometres, at 100 Hz and at 1 kHz. A force over the cap is fed forward as the cap's;
    each joint's offset stays within its torque limit."""
    f = np.array([20.0, -15.0, 25.0])
    off, _ = _held_against(f, False)
    on, drv = _held_against(f, True)
    fast, _ = _held_against(f, True, every=1)
    assert off[-200:].min() > 1.5e-3  # the servos give under 35 N: millimetres
    # (a force averaged over one step too many, 9 % short, leaves 0.2 mm)
    assert on[-100:].max() < 3e-5 and fast[-100:].max() < 3e-5
    # a force over the cap is summed for the feed-forward as the cap's along it
    drv._push_sum = [0.0, 0.0, 0.0]
    drv._tip_force_rows = lambda: [(2.0 * f).tolist()]  # type: ignore[method-assign]
    drv._cap(np.zeros(drv.scene.model.nu))
    np.testing.assert_allclose(drv._push_sum, f * (40.0 / np.linalg.norm(f)), rtol=1e-12)
    # whatever comes (here 100 kN, past the clip in _cap), no joint's offset torque passes
    # its limit
    drv._push_sum = [*(2500.0 * f)]
    drv._push_any, drv._push_n0 = True, drv._n - 1
    push = drv._pushed()
    assert push is not None
    lim = drv._torque_max / drv._kp_joint
    assert np.all(np.abs(push) <= lim * (1 + 1e-12))
    assert np.sum(np.isclose(np.abs(push), lim, rtol=1e-12)) >= 4  # (clipped, not scaled)


def _press_and_lift(sim: RobotSimulator) -> tuple[np.ndarray, np.ndarray]:
    """Pressed 2 cm into the table, then lifted 3 cm above it (the cube far away): the
    contact forces on the fingertip and the give's norm at every physics step."""
    down, up = np.array([[0.0, 0.0, -0.02]]), np.array([[0.0, 0.0, 0.03]])
    targets = np.concatenate([
        up + (down - up) * np.linspace(0.0, 1.0, 500)[:, None, None],
        np.repeat(down[None], 700, axis=0),
        down + (up - down) * np.linspace(0.0, 1.0, 300)[:, None, None],
        np.repeat(up[None], 700, axis=0)])
    forces = _over_table(sim, targets)
    return forces, np.linalg.norm(sim.robot_driver.log.give[:, 0], axis=1)


def _record_give_velocity(drv: Any, fed: list[np.ndarray]) -> Any:
    """Have ``drv`` append the physics step's count and the give's velocity fed forward
    (``[n, vx, vy, vz]``) to ``fed`` after each update; returns its own method, to put
    back."""
    velocity = drv._give_velocity

    def spy(flags: list[bool]) -> Any:
        out = velocity(flags)
        fed.append(np.concatenate([[drv._n], drv._give_vel.ravel()]))
        return out

    drv._give_velocity = spy
    return velocity


def test_the_force_caps_give_comes_back_as_a_motion_with_the_feedforward() -> None:
    """With ``force_feedforward``, pressed 2 cm into the table and lifted: off the table the
    cap's give comes back with its acceleration bounded (``give_accel``) and its velocity
    fed forward (taken up at that rate too), so the fingertip tracks its command within
    2.5 mm as the give comes back at up to 0.1 m/s, where without it the velocity servos
    held it back by 7-8 mm. (2.3 mm measured with the bundled tool's pin; 1.0 mm with the
    8 mm rod down to the tip, whose IK, held 1 mm higher by its collision margin against the
    table, asked for a smaller give; 2.45 mm with either tool and the IK's collisions off.)
    The same run again on the same simulator gives the same rows (nothing of the
    feed-forward carried over)."""
    errors = {}
    for ff in (False, True):
        sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                             scale=SCALE, force_feedforward=ff)
        drv = sim.robot_driver
        fed: list[np.ndarray] = []
        velocity = _record_give_velocity(drv, fed) if ff else None
        forces, g = _press_and_lift(sim)
        free = int(np.flatnonzero(forces > 0.0).max()) + 1  # off the table from here
        end = int(np.flatnonzero(g > 0.0).max())  # the give's last step
        assert g[free] > 0.01 and g[-1] == 0.0 and not drv._cap_on
        # (from 20 ms after the fingertip leaves the table: the let-go itself aside)
        errors[ff] = drv.log.error[free + 20:end + 2].max()
        if ff:  # started and stopped at give_accel, onto none
            d2 = np.abs(np.diff(g[free - 1:end + 2], 2))
            u = drv.give_accel * drv.dt ** 2
            # (the last step, onto none, takes what is left: its change at most 9/8 of u)
            assert d2[:-2].max() <= u * (1 + 1e-9) and d2.max() <= 1.125 * u * (1 + 1e-9)
            rec = np.array(fed)
            w = np.linalg.norm(np.diff(rec[:, 1:], axis=0), axis=1)
            assert w.max() <= drv.give_accel * drv.dt * (1 + 1e-9) and rec[:, 1:].any()
            # held at the cap the give's velocity is not fed forward (its loop's own; the
            # first half second's bounces off the table are full-speed returns, fed)
            steady = (rec[:, 0] > 650) & (rec[:, 0] < 1150)
            assert not rec[steady, 1:].any() and steady.sum() > 400
            assert not drv._give_vel.any()  # (the give back to none: nothing fed forward)
            first = np.array(drv.log.error)
            # stopped mid-press (a give and a force sum left), then the run again
            drv._give_velocity = velocity  # type: ignore[method-assign]
            half = np.repeat(np.array([[[0.0, 0.0, -0.02]]]), 900, axis=0)
            _over_table(sim, half)
            assert drv._cap_on and drv._push_any
            drv._give_vel[:] = 0.01
            drv._give_speed_now[0] = 1e-5
            drv.reset()  # (what _over_table does first: the state it clears, here)
            assert not (drv._cap_on or drv._push_any or any(drv._push_sum)
                        or drv._give_vel.any() or drv._give_last.any()
                        or any(drv._give_speed_now)) and drv._push_n0 == 0
            _press_and_lift(sim)
            np.testing.assert_array_equal(drv.log.error, first)
    assert errors[True] < 2.5e-3 < 5e-3 < errors[False]


def test_the_force_feedforward_needs_the_force_cap() -> None:
    """The switch is a bool or ``"auto"`` (the default: on with the stiff arm's force cap
    and one fingertip, off otherwise), and True goes with the force cap (the force fed
    forward is clipped at it): with the compliance, several fingertips or no cap it is
    refused in one line, never dropped; the JSON (the scene's and a sweep's) says whether
    it runs."""
    one = [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))]
    two = [*one, Arm(Robot.builtin(), BasePose(0.05, 0.55, -80.0))]
    doc = RobotSimulator(CUBE, one, scale=SCALE).describe()["finger_command"]
    assert doc["force_feedforward"] is True and doc["give_accel_m_per_s2"] == GIVE_ACCEL
    doc = RobotSimulator(CUBE, one, scale=SCALE, force_feedforward=False).describe()[
        "finger_command"]
    assert doc["force_feedforward"] is False and doc["give_accel_m_per_s2"] is None
    for kw in ({"compliance": True}, {"force_cap": None}):  # "auto": off there
        assert RobotSimulator(CUBE, one, scale=SCALE, **kw).describe()["finger_command"][
            "force_feedforward"] is False
    assert RobotSimulator(CUBE, two, scale=SCALE).describe()["finger_command"][
        "force_feedforward"] is False
    for kw in ({"compliance": True}, {"force_cap": None}):
        with pytest.raises(InputError, match="force_feedforward needs the stiff arm's"):
            RobotSimulator(CUBE, one, scale=SCALE, force_feedforward=True, **kw)
    for cap in ("auto", 40.0):  # several fingertips: refused, a cap given or not
        with pytest.raises(InputError, match="force_feedforward needs the stiff arm's"):
            RobotSimulator(CUBE, two, scale=SCALE, force_cap=cap, force_feedforward=True)
    with pytest.raises(InputError, match="force_feedforward is True, False or 'auto'"):
        RobotSimulator(CUBE, one, scale=SCALE, force_feedforward=1)  # type: ignore[arg-type]
    assert SweepRobot(tuple(one), force_feedforward=True).to_dict()["force_feedforward"]
    assert SweepRobot(tuple(one)).to_dict()["force_feedforward"] is True
    assert SweepRobot(tuple(one), force_feedforward=False).to_dict()[
        "force_feedforward"] is False
    assert SweepRobot(tuple(two)).to_dict()["force_feedforward"] is False
    assert SweepRobot(tuple(one), force_cap=None).to_dict()["force_feedforward"] is False
    for bad in ({"arms": tuple(two)}, {"arms": tuple(two), "force_cap": 40.0},
                {"arms": tuple(one), "force_cap": None}):
        with pytest.raises(InputError, match="force_feedforward needs the stiff arm's"):
            SweepRobot(force_feedforward=True, **bad)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="force_feedforward is True, False or 'auto'"):
        SweepRobot(tuple(one), force_feedforward="yes")


@pytest.mark.parametrize("bad", [0.0, -5.0, math.inf, math.nan, True, "40", "off",
                                 np.array([40.0, 50.0])])
def test_the_force_cap_is_checked(bad: object) -> None:
    with pytest.raises(InputError, match="force_cap is a force"):
        RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                       scale=SCALE, force_cap=bad)  # type: ignore[arg-type]


def test_the_force_cap_runs_for_one_stiff_arm_only() -> None:
    """``"auto"``: the cap for one stiff arm, none with the force-limited command (its own
    limit) or with several fingertips (a pinch's squeeze); a number with the compliance is
    refused; the JSON (the scene's and a sweep's) says which runs."""
    one = [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))]
    two = [*one, Arm(Robot.builtin(), BasePose(0.05, 0.55, -80.0))]
    assert RobotSimulator(CUBE, one, scale=SCALE).describe()["finger_command"][
        "force_cap_n"] == 40.0
    assert RobotSimulator(CUBE, one, scale=SCALE, compliance=True).robot_driver.force_cap is None
    assert RobotSimulator(CUBE, two, scale=SCALE).robot_driver.force_cap is None
    assert RobotSimulator(CUBE, one, scale=SCALE, force_cap=25).robot_driver.force_cap == 25.0
    assert RobotSimulator(CUBE, one, scale=SCALE, force_cap=None).robot_driver.force_cap is None
    with pytest.raises(InputError, match="pass force_limit instead"):
        RobotSimulator(CUBE, one, scale=SCALE, compliance=True, force_cap=30.0)
    assert SweepRobot(tuple(one)).to_dict()["force_cap_n"] == 40.0
    assert SweepRobot(tuple(two)).to_dict()["force_cap_n"] is None
    assert SweepRobot(tuple(one), compliance=True).to_dict()["force_cap_n"] is None
    assert SweepRobot(tuple(one), force_cap=None).to_dict()["force_cap_n"] is None
    with pytest.raises(InputError, match="force_cap is a force"):
        SweepRobot(tuple(one), force_cap=-1.0)


def test_compliance_refuses_a_finger_that_is_not_one() -> None:
    with pytest.raises(InputError, match="stiffness"):
        RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))], scale=SCALE,
                       params=replace(DEFAULT_PARAMS, stiffness=float("nan")),
                       compliance=True)


def test_finger_leans_out_of_the_face_when_its_base_stands_to_the_side() -> None:
    """A base 45 degrees off the face's normal: half the lean's direction is the face's
    outward one (``side_tilt_outward`` 0.5), so the flange stands further out of the face
    than when leaning towards the base alone, and by the blend's own angle (truth: MuJoCo's
    site frame at the converged joints; the blend of +x and the base's direction)."""
    base = BasePose(0.3 + 0.6, 0.1 + 0.6, -135.0)  # diagonal to the +x face
    v = np.asarray(CUBE.vertices, dtype=float) * SCALE
    c = v.mean(axis=0)
    beside = np.array([[0.3 + 0.025 + 0.006, 0.1, 0.03]])  # on the +x face
    out = {}
    for w in (0.0, 0.5):
        sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(), base)],
                               mocap_object=True)
        ik = FingertipIK(sc, 0.001, IKConfig(collisions=False, side_tilt_outward=w))
        ik.set_object(np.array([0.3 - c[0], 0.1 - c[1], -v[:, 2].min()]),
                      np.array([1.0, 0.0, 0.0, 0.0]))
        assert ik.converge(beside, iterations=1000) < 1e-3
        d = mujoco.MjData(sc.model)
        d.qpos[sc.qadr] = ik.q
        mujoco.mj_kinematics(sc.model, d)
        out[w] = d.site_xmat[sc.tip_sites[0]].reshape(3, 3)[:, 2].copy()
    # the flange side of the finger (-z) along the face's outward normal (+x)
    assert -out[0.5][0] > -out[0.0][0] + 0.05
    b = np.array([base.x - beside[0, 0], base.y - beside[0, 1]])
    lean = 0.5 * np.array([1.0, 0.0]) + 0.5 * b / np.linalg.norm(b)
    lean /= np.linalg.norm(lean)
    got = -out[0.5][:2] / np.linalg.norm(out[0.5][:2])
    assert float(got @ lean) > math.cos(math.radians(8.0))


def test_ik_keeps_the_joints_a_margin_inside_their_ranges() -> None:
    """The IK's joint box keeps each joint ``position_margin_deg`` (1 degree) inside its
    range, outside the 0.5-degree band that counts as at a limit: a joint 1.5 degrees from
    its end may step 0.95 of the 0.5 degrees left; one 0.3 degrees from it (inside the
    margin) must step back out, at 0.2 rad/s at most (truth: the scene's joint ranges)."""
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(),
                                                        BasePose(0.0, 0.0, 0.0))],
                           mocap_object=True)
    # (no acceleration bound: it would cap the step from rest)
    ik = FingertipIK(sc, 0.01, IKConfig(collisions=False, joint_accel=math.inf))
    dt, j = 0.01, 3  # the elbow: its upper end is the stretched arm
    for inside, want in ((1.5, 0.95 * math.radians(0.5)), (0.3, -0.2 * dt)):
        q = np.array(sc.home, dtype=float)
        q[j] = sc.upper[j] - math.radians(inside)
        ik._box.prev = np.zeros(len(q))
        upper, lower = ik._box.bounds(q, dt)
        assert upper[j] == pytest.approx(want, abs=1e-9)
        assert lower[j] < upper[j]
    # no margin: the joint may go to its end
    ik0 = FingertipIK(sc, 0.01, IKConfig(collisions=False, position_margin_deg=0.0,
                                         joint_accel=math.inf))
    q = np.array(sc.home, dtype=float)
    q[j] = sc.upper[j] - math.radians(0.3)
    assert ik0._box.bounds(q, dt)[0][j] == pytest.approx(0.95 * math.radians(0.3), abs=1e-9)


@functools.lru_cache(maxsize=2)
def _ik_scene(mocap: bool = True) -> Any:
    """The bundled Panda's scene beside the cube (built once): kinematic (``mocap``: its
    joints are its degrees of freedom, in order) or the physical one (the object's free
    joint first: the box's joints sit at an offset, the scatter path)."""
    return build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(),
                                                          BasePose(0.0, 0.0, 0.0))],
                             mocap_object=mocap)


def _box_bounds_on_arrays(box: Any, q: np.ndarray, dt: float, gain: float, accel: float
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The joint box of :func:`nonprehensile.sim.ik._joint_box_limit` written from its
    docstring on whole arrays (the form the per-joint code replaced): ``min(v dt, gain
    (hi - q), sqrt(2 a (hi - q)) dt)`` up and the same down, within ``[-back dt, v dt]``, then
    the acceleration bounds ``(prev +- a dt) dt`` where they leave room; scattered onto the
    scene's degrees of freedom."""
    room = np.vstack([box.upper - q, q - box.lower])
    vdt = np.vstack([box.velocity, box.velocity]) * dt
    step = room * gain
    if math.isfinite(accel):
        stop = np.sqrt(np.maximum(room, 0.0) * (2.0 * accel)) * dt
        step = np.minimum(step, stop)
    step = np.clip(step, -box.back * dt, vdt)
    if math.isfinite(accel):
        acc = np.vstack([(box.prev + accel * dt) * dt, (-box.prev + accel * dt) * dt])
        acc = np.minimum(step, acc)
        step = np.where(acc.sum(axis=0) >= 0.0, acc, step)
    upper = np.zeros(box.n)
    lower = np.zeros(box.n)
    upper[box.dadr] = step[0]
    lower[box.dadr] = -step[1]
    return upper, lower


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), accel=st.sampled_from([30.0, 5.0, 0.0, math.inf]),
       margin=st.sampled_from([0.0, 1.0]), mocap=st.booleans())
def test_ik_joint_box_per_joint_equals_the_array_form(seed: int, accel: float, margin: float,
                                                       mocap: bool) -> None:
    """The IK's joint box, computed joint by joint in plain Python (a sixth of a solve's time
    on arrays), gives the same numbers, bit for bit, as the whole-array form of its
    docstring, inside the ranges, near their ends, inside the margin and past the ends, with
    and without an acceleration bound (0 included), where the acceleration bounds give way (a
    joint moving fast towards the end it is near), at three periods on one box, on the IK's
    scene and on one whose joints sit after the object's (the scatter onto its degrees of
    freedom)."""
    import mink

    from nonprehensile.sim.ik import _joint_box_limit

    sc = _ik_scene(mocap)
    box = _joint_box_limit(mink, sc, 0.95, 1.0, accel, math.radians(margin), 0.2)
    assert box.identity == mocap
    rng = np.random.default_rng(seed)
    span = sc.upper - sc.lower
    for k in range(24):
        dt = (0.001, 0.004, 0.01)[k % 3]
        q = sc.lower + span * rng.uniform(-0.02, 1.02, size=len(span))
        j = int(rng.integers(len(span)))  # one joint within a few degrees of an end
        q[j] = (sc.upper[j] if rng.random() < 0.5 else sc.lower[j]) + rng.normal(0.0, 0.03)
        box.prev = rng.normal(0.0, 2.0, size=len(span))
        qpos = q
        if not mocap:  # the scene's qpos: the object's free joint, then the joints
            qpos = np.zeros(sc.model.nq)
            qpos[sc.qadr] = q
        up, down = box.bounds(qpos, dt)
        up_ref, down_ref = _box_bounds_on_arrays(box, q, dt, 0.95, accel)
        assert np.array_equal(up, up_ref) and np.array_equal(down, down_ref)


def test_ik_approaches_a_range_end_no_faster_than_it_can_stop() -> None:
    """Near a joint's range end the IK's step is at most ``dt sqrt(2 A d)`` (``A`` its
    acceleration bound, ``d`` the room to the margin): from that velocity the joint stops
    within the room at ``A``. Before, the step could take 0.95 of the room: across the
    distribution the wrist came to its margin at 1.5 rad/s, braked at 100 rad/s^2 and held
    its 12 N m for 11 ms (34 ms past its end before the torque budget kept the braking).
    Truth: the stopping distance ``v^2 / (2 A)`` from the scene's joint range; far from the
    end the box is the velocity and acceleration bounds as before."""
    sc = build_robot_scene(CUBE, scale=SCALE, arms=[Arm(Robot.builtin(),
                                                        BasePose(0.0, 0.0, 0.0))],
                           mocap_object=True)
    cfg = IKConfig(collisions=False)
    ik = FingertipIK(sc, 0.01, cfg)
    dt, j, acc = 0.01, 5, cfg.joint_accel  # the wrist
    margin = math.radians(cfg.position_margin_deg)
    v_max = cfg.velocity_fraction * sc.velocity[j]
    for room in (0.002, 0.01, 0.02, 0.04):
        q = np.array(sc.home, dtype=float)
        q[j] = sc.upper[j] - margin - room
        prev = np.zeros(len(q))
        prev[j] = 1.5
        ik._box.prev = prev
        upper, _ = ik._box.bounds(q, dt)
        v = upper[j] / dt
        assert v > 0.0
        assert v * v / (2.0 * acc) <= room * (1.0 + 1e-9)
    q = np.array(sc.home, dtype=float)
    q[j] = sc.upper[j] - margin - 0.5
    ik._box.prev = prev
    upper, _ = ik._box.bounds(q, dt)
    assert upper[j] == pytest.approx(min(v_max * dt, (1.5 + acc * dt) * dt), abs=1e-12)


def test_compliance_is_off_by_default_and_a_sweep_says_which() -> None:
    """The stiff arm is the default (the measured choice, docs/robot.md); an explicit choice
    wins; a sweep's robot says which."""
    one = [Arm(Robot.builtin(), BasePose(0.5, 0.0, 180.0))]
    two = [*one, Arm(Robot.builtin(), BasePose(-0.5, 0.0, 0.0))]
    assert not RobotSimulator(CUBE, two, scale=SCALE).robot_driver.compliance
    # the records say which command ran, with its virtual finger
    doc = RobotSimulator(CUBE, two, scale=SCALE, compliance=True, force_limit=math.inf).describe()
    assert doc["finger_command"]["compliance"] is True
    assert doc["finger_command"]["force_limit_n"] is None  # inf: JSON has none
    assert doc["finger_command"]["stiffness_n_per_m"] == DEFAULT_PARAMS.stiffness
    assert json.loads(json.dumps(doc, allow_nan=False))["ik_object_pose"].startswith("closed")
    stiff = RobotSimulator(CUBE, two, scale=SCALE).describe()["finger_command"]
    assert stiff["compliance"] is False and stiff["force_limit_n"] == DEFAULT_PARAMS.max_force
    # the contact-consistent command's bound: on for a pinch, off for one arm (press24)
    assert stiff["press_depth_m"] == PINCH_PRESS_DEPTH
    assert RobotSimulator(CUBE, one, scale=SCALE).describe()["finger_command"][
        "press_depth_m"] is None
    assert RobotSimulator(CUBE, two, scale=SCALE, compliance=True).robot_driver.compliance
    assert SweepRobot(tuple(two), compliance=True).to_dict()["compliance"] is True
    assert SweepRobot(tuple(one)).to_dict()["compliance"] is False
    # the sweep's records say which contact-consistent bound ran: "auto" resolved
    assert SweepRobot(tuple(one)).to_dict()["press_depth_m"] is None
    assert SweepRobot(tuple(two)).to_dict()["press_depth_m"] == PINCH_PRESS_DEPTH
    assert SweepRobot(tuple(one), press_depth=0.003).to_dict()["press_depth_m"] == 0.003
    # ... and which contact tracking correction: the scene's own, by the fingertips
    for arms in (one, two):
        fc = RobotSimulator(CUBE, arms, scale=SCALE).describe()["finger_command"]
        d = SweepRobot(tuple(arms)).to_dict()
        keys = ("tracking_gain_per_s", "tracking_tangential", "tracking_bound_m",
                "tracking_surface_bound_m")
        assert [d[k] for k in keys] == [fc[k] for k in keys]
    # ... and whether the servos get the acceleration feed-forward: as the scene says it
    # runs, below the physics rate only
    for every in (10, 1):
        d = SweepRobot(tuple(one), control_every=every).to_dict()
        ctl = RobotSimulator(CUBE, one, scale=SCALE, control_every=every).describe()[
            "controller"]
        assert d["acceleration_feedforward"] is ctl["acceleration_feedforward"] is (every > 1)
    assert SweepRobot(tuple(two)).to_dict()["tracking_tangential"] is True
    assert SweepRobot(tuple(one)).to_dict()["tracking_tangential"] is False
    assert SweepRobot(tuple(one)).to_dict()["tracking_surface_bound_m"] == 0.0005
    assert SweepRobot(tuple(two)).to_dict()["tracking_surface_bound_m"] is None
    sim = SweepRobot(tuple(one), compliance=True).simulator(CUBE, SCALE, DEFAULT_PARAMS)
    assert sim.robot_driver.compliance  # type: ignore[attr-defined]
    # a sample's physics sets the virtual finger
    sim.params = replace(DEFAULT_PARAMS, stiffness=2000.0, max_force=12.0)
    assert sim.robot_driver.finger_stiffness == 2000.0  # type: ignore[attr-defined]
    assert sim.robot_driver.force_limit == 12.0  # type: ignore[attr-defined]


@pytest.mark.parametrize(("name", "bad"), [
    ("position_margin_deg", float("nan")), ("position_margin_deg", -1.0),
    ("position_margin_deg", 45.0), ("side_tilt_outward", 1.5), ("side_tilt_outward", -0.1),
    ("collision_gain", 0.0), ("velocity_fraction", 2.0), ("damping", float("inf")),
    ("joint_accel", float("nan")), ("collisions", 1), ("posture_cost", True)])
def test_ik_config_refuses_a_bad_setting_naming_it(name: str, bad: object) -> None:
    """A bad IK setting (NaN, negative, out of its range, the wrong type) is refused in one
    line naming it, before it reaches the QP; the defaults and the edge values pass."""
    with pytest.raises(InputError, match=name):
        IKConfig(**{name: bad})  # type: ignore[arg-type]
    IKConfig(side_tilt_outward=0.0, position_margin_deg=0.0, joint_accel=math.inf,
             collision_gain=1.0, velocity_fraction=1.0)


def test_force_limit_without_the_compliance_is_refused() -> None:
    """``force_limit`` is the force-limited command's limit: alone (as it was once used to make
    the tip yield) it is refused, never ignored."""
    with pytest.raises(InputError, match="compliance=True"):
        RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.9, 0.1, 180.0))], scale=SCALE,
                       force_limit=12.0)


def test_cli_simulate_plan_with_the_force_limited_command() -> None:
    """``simulate plan --robot panda --compliance``: the first step runs with the
    force-limited finger command, and the JSON says so with its virtual finger (the
    distribution's nominal spring); without a robot the flag is refused in one line. The
    contact force feed-forward and the fingertip radius offset: on by default with one arm,
    off when asked, the JSON saying which ran; robot options only."""
    args = ["simulate", "plan", SKILLS, "--from", "b:200", "--at", "0.3", "0.1", "--to",
            "a:290", "--step", "90", "--dataset", "cube", "--json"]
    res = CliRunner().invoke(main, [*args, "--robot", "panda", "--base", "0.53", "-0.51",
                                    "112.5", "--compliance", "--press-depth", "3",
                                    "--no-force-feedforward"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    cmd = doc["robot"]["finger_command"]
    assert cmd["compliance"] is True and cmd["stiffness_n_per_m"] == DEFAULT_PARAMS.stiffness
    assert cmd["force_feedforward"] is False
    assert cmd["press_depth_m"] == pytest.approx(0.003)  # --press-depth is in millimetres
    assert doc["robot"]["ik_object_pose"].startswith("closed loop: each observation")
    bad = CliRunner().invoke(main, [*args, "--compliance"])
    assert bad.exit_code == 2 and "--compliance is a robot's" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
    # the contact force fed forward: by default with one stiff arm's force cap; the JSON
    # says it runs
    res = CliRunner().invoke(main, [*args, "--robot", "panda", "--base", "0.53", "-0.51",
                                    "112.5"])
    assert res.exit_code == 0, res.stderr
    cmd = json.loads(res.stdout)["robot"]["finger_command"]
    assert cmd["force_feedforward"] is True and cmd["force_cap_n"] == 40.0
    bad = CliRunner().invoke(main, [*args, "--robot", "panda", "--base", "0.53", "-0.51",
                                    "112.5", "--compliance", "--force-feedforward"])
    assert bad.exit_code == 2 and "--force-feedforward goes with one" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
    # the fingertip radius offset: on by default with one arm (above), off when asked; a
    # robot's option only
    assert cmd["radius_offset"] is True
    res = CliRunner().invoke(main, [*args, "--robot", "panda", "--base", "0.53", "-0.51",
                                    "112.5", "--no-radius-offset"])
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["robot"]["finger_command"]["radius_offset"] is False
    for flag in ("--radius-offset", "--no-radius-offset"):
        bad = CliRunner().invoke(main, [*args, flag])
        assert bad.exit_code == 2 and "--radius-offset/--no-radius-offset is a robot's" in \
            bad.stderr
        assert len(bad.stderr.strip().splitlines()) == 1


def test_the_radius_offset_runs_with_one_fingertip_and_a_sweep_says_which() -> None:
    """``radius_offset="auto"`` (the default) is on with one fingertip and off with several,
    as the simulator's driver, its JSON and a sweep's robot say; an explicit choice wins;
    anything but True, False or "auto" is refused in one line naming it."""
    one = [Arm(Robot.builtin(), BasePose(0.5, 0.0, 180.0))]
    two = [*one, Arm(Robot.builtin(), BasePose(-0.5, 0.0, 0.0))]
    for arms, want in ((one, True), (two, False)):
        sim = RobotSimulator(CUBE, arms, scale=SCALE)
        assert sim.robot_driver.radius_offset is want
        assert sim.describe()["finger_command"]["radius_offset"] is want
        assert SweepRobot(tuple(arms)).to_dict()["radius_offset"] is want
        for chosen in (True, False):
            assert RobotSimulator(CUBE, arms, scale=SCALE, radius_offset=chosen
                                  ).robot_driver.radius_offset is chosen
            assert SweepRobot(tuple(arms), radius_offset=chosen).to_dict()[
                "radius_offset"] is chosen
    # the sweep's simulator gets the switch
    sim = SweepRobot(tuple(one), radius_offset=False).simulator(CUBE, SCALE, DEFAULT_PARAMS)
    assert sim.robot_driver.radius_offset is False  # type: ignore[attr-defined]
    for bad in (1, "yes", None):
        with pytest.raises(InputError, match="radius_offset is True, False or 'auto'"):
            RobotSimulator(CUBE, one, scale=SCALE, radius_offset=bad)  # type: ignore[arg-type]
        with pytest.raises(InputError, match="radius_offset is True, False or 'auto'"):
            SweepRobot(tuple(one), radius_offset=bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(("kw", "what"), [
    ({"compliance": "false"}, "compliance is True or False"),
    ({"compliance": 1}, "compliance is True or False")])
def test_compliance_refuses_what_is_not_its_type(kw: dict[str, object], what: str) -> None:
    """A string or a number for the switch: refused naming it (``bool("false")`` is
    True), where it once ran the force-limited command; True and False pass."""
    arm = [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))]
    with pytest.raises(InputError, match=what):
        RobotSimulator(CUBE, arm, scale=SCALE, **kw)  # type: ignore[arg-type]
    for ok in (True, False):
        assert RobotSimulator(CUBE, arm, scale=SCALE, compliance=ok).robot_driver.compliance \
            is ok


def test_metrics_give_the_longest_time_at_each_limit_while_touching() -> None:
    """``RobotLog.metrics`` gives, per kind of limit, the longest run at it while a
    fingertip touches the object. Truth: a log written by hand, its runs counted by hand."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.0, -0.45, 90.0))],
                         scale=SCALE)
    sc, log = sim.scene, sim.robot_log
    dt = log.dt
    n = 100
    log.clear()
    log.reserve(n)
    log.n = n
    log._time[:n] = np.arange(n) * dt
    log._q[:n] = sc.home  # mid-range: no position limit but where set below
    log._qd[:n] = 0.0
    log._tau[:n] = 0.0
    log._touch[15:41] = True  # touching from row 15 to row 40
    log._tau[10:30, 0] = sc.torque[0]  # 20 rows at a torque limit, 15 of them touching
    log._q[50:62, 1] = sc.upper[1]  # 12 rows at a position limit, none touching
    log._qd[35:40, 2] = sc.velocity[2]  # 5 rows at a velocity limit, all touching
    m = log.metrics()
    assert m.longest_at_limit_s == pytest.approx(
        {"position": 12 * dt, "velocity": 5 * dt, "torque": 20 * dt})
    assert m.longest_at_limit_contact_by_kind_s == pytest.approx(
        {"position": 0.0, "velocity": 5 * dt, "torque": 15 * dt})
    assert m.longest_at_limit_contact_s == pytest.approx(15 * dt)  # the union's longest
    doc = m.to_dict()["longest_at_limit_contact_by_kind_s"]
    assert doc == {"position": 0.0, "velocity": round(5 * dt, 4), "torque": round(15 * dt, 4)}


def test_the_plans_joint_trajectory_runs_the_transits_between_steps() -> None:
    """`plan --robot --out`'s joint trajectory of the main plan (two steps): the fingertips go
    from step 1's end to step 2's start by the executor's transit, clear of the cube, and
    the joints move continuously. Without the transit step 2's IK started 61 mm from its
    first target (its fingertip error 60 mm, the joints at 1.5 rad/s on the jump). The
    fingertips are checked by MuJoCo's forward kinematics of the written joints, not the
    IK's own tips."""
    from nonprehensile.cli.options import state_set
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.observation import hull_distance
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.sim.placement import joint_trajectory
    from nonprehensile.states import State

    poly, skills = read_skills(SKILLS)
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    p = plan(poly, exp, State("b", 200), State("e", 110), position=(0.3, 0.1),
             motions=motions, scale=ds.scale)
    assert len(p.steps) == 2
    arms = [Arm(Robot.builtin(), BasePose(0.53, -0.51, 112.5))]
    got = {t.name: t for t in joint_trajectory(arms, poly, ds.scale, p, ds.fingers)}
    assert list(got) == ["step1", "transit2", "step2", "plan"]
    dt = 0.001 * DEFAULT_CONTROL_EVERY
    whole = got["plan"]
    assert np.allclose(np.diff(whole.time), dt)  # one clock, no gap, no overlap
    assert np.array_equal(whole.positions, np.concatenate(
        [got[k].positions for k in ("step1", "transit2", "step2")]))
    step = np.abs(np.diff(whole.positions, axis=0))
    assert np.all(step <= np.array(panda.DQ_MAX) * dt + 1e-9)  # no jump between rows
    for name in ("step1", "transit2", "step2"):
        assert got[name].tip_error_m < 0.005, name  # step 2: 0.060 without the transit
        assert np.all(got[name].velocities[-1] == 0.0)
        assert np.abs(got[name].positions[-1] - got[name].positions[-2]).max() < 1e-3 * dt
    # the transit's fingertips, by forward kinematics: clear of the cube posed at step 2's
    # start until the approach, and never inside it
    scene = build_robot_scene(poly, scale=ds.scale, arms=arms, mocap_object=True)
    m, d = scene.model, mujoco.MjData(scene.model)
    tips = []
    for q in got["transit2"].positions:
        d.qpos[scene.qadr] = q
        mujoco.mj_kinematics(m, d)
        tips.append(np.array(d.site_xpos[int(scene.tip_sites[0])]))
    clear = hull_distance(poly, p.steps[1].start_pose, np.array(tips))
    radius = DEFAULT_PARAMS.finger_radius
    assert clear.min() > radius - 0.002  # (the approach ends on the reference's start)
    assert clear.max() > radius + 0.01  # it went round, not through
