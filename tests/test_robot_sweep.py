"""Robot arms in robustness sweeps (issue 22): ``simulate robustness --robot`` and
``SweepSpec(robot=...)``, the robot scene retuned per sample, the fingertip noise on an arm."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")
pytest.importorskip("mink", reason="the robot extra (mink) is not installed: "
                                   "pip install 'nonprehensile[robot]'")

from click.testing import CliRunner  # noqa: E402

from nonprehensile.cli import main  # noqa: E402
from nonprehensile.errors import InputError  # noqa: E402
from nonprehensile.geometry.build import cube  # noqa: E402
from nonprehensile.sim.robot import BasePose, Robot  # noqa: E402
from nonprehensile.sim.robot_run import (  # noqa: E402
    ROBOT_MAX_ACCEL,
    RobotSimulator,
    robot_control,
)
from nonprehensile.sim.robot_scene import Arm  # noqa: E402
from nonprehensile.sim.scene import DEFAULT_PARAMS, SceneTuner  # noqa: E402

CUBE = cube()
SCALE = 0.05
SKILLS = str(Path(__file__).resolve().parents[1] / "src/nonprehensile/data/cube_skills.json")
BASE = BasePose(0.53, -0.51, 112.5)  # reaches the main plan's first step at (0.3, 0.1)
STEP1 = ["--from", "b:200", "--to", "a:290", "--at", "0.3", "0.1", "--step", "90"]

TUNED = ("body_mass", "body_inertia", "pair_friction", "pair_solref", "geom_size",
         "geom_rbound", "dof_damping", "actuator_gainprm", "actuator_biasprm",
         "actuator_forcerange", "body_invweight0", "dof_invweight0")


def _arrays(m: object) -> dict[str, np.ndarray]:
    return {k: np.array(getattr(m, k)) for k in TUNED}


def test_tuned_robot_scene_is_the_scene_built_with_the_new_parameters() -> None:
    """A worker's robot scene retuned to a sample equals the robot scene compiled with the
    sample's parameters: object, pairs (fingertip, links, rod), the tip sphere, and nothing
    of the arm's own bodies, joints or servos."""
    arms = [Arm(Robot.builtin(), BASE)]
    new = replace(DEFAULT_PARAMS, mass=0.27, friction_table=0.35, friction_finger=1.1,
                  finger_radius=0.0105, contact_timeconst=0.007, stiffness=2500.0,
                  max_force=14.0)
    sim = RobotSimulator(CUBE, arms, scale=SCALE)
    SceneTuner(sim.model, sim.data, sim.params).tune(new)
    # the free fingertips' stiffness and force limit do not apply to an arm: build with the
    # defaults' ones (the tuner must leave the arm alone)
    built = RobotSimulator(CUBE, arms, scale=SCALE,
                           params=replace(new, stiffness=DEFAULT_PARAMS.stiffness,
                                          max_force=DEFAULT_PARAMS.max_force))
    got, want = _arrays(sim.model), _arrays(built.model)
    for k in TUNED:
        np.testing.assert_allclose(got[k], want[k], rtol=2e-6, atol=1e-9, err_msg=k)
    # and back: the default scene again
    SceneTuner(sim.model, sim.data, new).tune(DEFAULT_PARAMS)
    fresh = _arrays(RobotSimulator(CUBE, arms, scale=SCALE).model)
    for k in TUNED:
        np.testing.assert_allclose(_arrays(sim.model)[k], fresh[k], rtol=2e-6, atol=1e-9,
                                   err_msg=k)


def test_sweep_spec_robot_checks() -> None:
    from nonprehensile.cli.options import state_set
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.planning import plan
    from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION
    from nonprehensile.sim.robustness import SweepRobot, SweepSpec, plan_unit
    from nonprehensile.states import State

    poly, skills = read_skills(SKILLS)
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    # a two-finger skill's transition: one arm has too few fingertips
    two = next(t for t in exp.transitions if t.source.name == "twist")
    p = plan(poly, exp, two.start, two.end)
    one_arm = SweepRobot((Arm(Robot.builtin(), BASE),))
    assert one_arm.max_accel == ROBOT_MAX_ACCEL and one_arm.n_fingers == 1
    dist = DEFAULT_DISTRIBUTION.for_object(poly, SCALE)
    with pytest.raises(InputError, match="need 2 fingers; the robot has 1"):
        SweepSpec(poly, SCALE, (plan_unit(p),), dist, 0, 1, robot=one_arm)
    p1 = plan(poly, exp, State("b", 200), State("a", 290))
    with pytest.raises(InputError, match="does not record"):
        SweepSpec(poly, SCALE, (plan_unit(p1),), dist, 0, 1, robot=one_arm, record_fps=30.0)
    with pytest.raises(InputError, match="control_every"):
        SweepRobot((Arm(Robot.builtin(), BASE),), control_every=0)
    with pytest.raises(InputError, match="at least one arm"):
        SweepRobot(())


def test_cli_robustness_bad_robot_options_one_line(tmp_path: Path) -> None:
    bad_xml = tmp_path / "arm.xml"
    bad_xml.write_text('<mujoco><worldbody><body name="l1"><joint name="j1" range="-1 1"/>'
                       '<geom size="0.02"/><site name="tip"/></body></worldbody></mujoco>')
    runner = CliRunner()
    for extra, what in ((["--robot", "nope"], "nope"),
                        (["--robot-xml", str(bad_xml), "--tip-site", "tip"], "no actuators"),
                        (["--robot-xml", str(bad_xml), "--tip-site", "x"], "no site"),
                        (["--tip-site", "tip"], "--robot-xml"),
                        (["--robot", "panda", "--control-rate", "300"], "--control-rate"),
                        (["--robot", "panda", "--record", str(tmp_path / "rec")], "--record"),
                        (["--robot", "panda", "--arms", "2", "--base", "0.5", "0", "180"],
                         "--base given 1 time(s) for 2 arm(s)"),
                        (["--compliance"], "--compliance is a robot's finger command"),
                        (["--force-feedforward"],
                         "--force-feedforward is a robot's finger command"),
                        (["--robot", "panda", "--arms", "2", "--force-feedforward"],
                         "--force-feedforward goes with one stiff arm's force cap"),
                        (["--press-depth", "3"], "--press-depth is a robot's finger command"),
                        (["--radius-offset"],
                         "--radius-offset/--no-radius-offset is a robot's finger command"),
                        (["--no-radius-offset"],
                         "--radius-offset/--no-radius-offset is a robot's finger command"),
                        (["--robot", "panda", "--press-depth", "nan"], "--press-depth"),
                        (["--robot", "panda", "--press-depth", "0"], "above 0"),
                        (["--robot", "panda", "--press-depth", "25"], "at most 20 (mm)")):
        res = runner.invoke(main, ["simulate", "robustness", SKILLS, *STEP1, "--samples", "1",
                                   "--workers", "1", *extra])
        assert res.exit_code == 2, (extra, res.output)
        assert what in res.stderr and "Traceback" not in res.stderr, (extra, res.stderr)
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_cli_robustness_by_the_panda_equals_the_robot_simulator() -> None:
    """``simulate robustness --robot panda``: a sample's execution by a worker's retuned
    robot scene is the one a robot scene built with the sample's parameters gives (the
    same executor, the sample's perturbation: start error, tracker and fingertip noise)."""
    from nonprehensile.cli.options import state_set
    from nonprehensile.control import replanner
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.sim.closed_loop import execute_plan
    from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION
    from nonprehensile.sim.execute import fingers_of
    from nonprehensile.states import State

    res = CliRunner().invoke(main, [
        "simulate", "robustness", SKILLS, *STEP1, "--samples", "1", "--seed", "3",
        "--loop", "closed", "--workers", "1", "--robot", "panda", "--base", str(BASE.x),
        str(BASE.y), str(BASE.yaw), "--control-rate", "125", "--json"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["robot"]["robots"][0]["base"] == BASE.to_dict()
    assert doc["robot"]["control_every"] == 8 and doc["placement"] is None
    assert doc["robot"]["radius_offset"] is True  # ("auto": one fingertip)
    (rec,) = doc["records"]
    assert rec["robot"]["ik_solves"] > 0 and doc["robot_metrics"]["executions"] == 1
    # the same execution by hand: a robot scene compiled with the sample's parameters
    poly, skills = read_skills(SKILLS)
    # as the CLI does for one fingertip: plan and re-plan with single-finger skills only
    skills = [s for s in skills if max(fingers_of(s), default=1) <= 1]
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    p = plan(poly, exp, State("b", 200), State("a", 290), position=(0.3, 0.1),
             motions=motions, scale=ds.scale)
    sample = DEFAULT_DISTRIBUTION.for_object(poly, ds.scale).sample(3, index=0, stream=0)
    assert rec["values"] == pytest.approx(sample.values(), rel=1e-6)
    # the worker's scene: compiled with the distribution's base and retuned to the sample
    # (a scene compiled with the sample's parameters equals it to ~1e-6, see the test above,
    # and a closed-loop execution's thresholds can turn that into another path)
    dist = DEFAULT_DISTRIBUTION.for_object(poly, ds.scale)
    sim = RobotSimulator(poly, [Arm(Robot.builtin(), BASE)], scale=ds.scale,
                         params=dist.base, control_every=8)
    SceneTuner(sim.model, sim.data, sim.params).tune(sample.params)
    sim.params = sim.judge.params = sample.params
    ex = execute_plan(sim, p, fingers=ds.fingers, loop="closed",
                      replan=replanner(poly, exp, p.goal, motions=motions, scale=ds.scale,
                                       angle_tol=5.0),
                      config=robot_control(n_fingers=sim.n_fingers),
                      perturbation=sample.perturbation)
    assert rec["success"] == ex.success and ex.final_state is not None
    # the document rounds the compiled scene's parameters to 6 digits: the same end within a
    # hundredth of a degree and a millimetre, the same path within a few steps
    assert rec["final"]["face"] == ex.final_state.face
    assert rec["final"]["theta"] == pytest.approx(ex.final_state.theta, abs=0.01)
    assert abs(rec["physics_steps"] - ex.n_steps) <= max(20, ex.n_steps // 100)
    assert rec["position_error_m"] == pytest.approx(ex.position_error, abs=1e-3)


def test_place_sweep_arms_reaches_every_unit() -> None:
    """One base for a sweep's units: from it the IK (an independent solve, converged from
    home at every sampled target) reaches each unit's fingertip targets."""
    from nonprehensile.cli.options import state_set
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.sim.ik import FingertipIK, IKConfig
    from nonprehensile.sim.placement import plan_targets
    from nonprehensile.sim.robot_scene import build_robot_scene
    from nonprehensile.sim.robustness import place_sweep_arms, transition_units

    poly, skills = read_skills(SKILLS)
    skills = [s for s in skills if s.name == "push-roll"]
    exp = expand(poly, skills, state_set(poly, 90.0, None, 1e-6))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    units = transition_units(poly, exp, motions, scale=ds.scale, angle_tol=1e-6)[:3]
    arms, (found,) = place_sweep_arms(Robot.builtin(), units, poly, ds.scale, ds.fingers,
                                      max_units=3)
    assert found.feasible and arms[0].base == found.base
    scene = build_robot_scene(poly, scale=ds.scale, arms=arms, mocap_object=True)
    ik = FingertipIK(scene, 0.02, IKConfig(collisions=False))
    ik.set_object(np.array([0.0, 0.0, -10.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    for u in units:
        for arr, _ in plan_targets(u.plan, ds.fingers):
            for x in arr[:: max(1, len(arr) // 5)]:
                ik.reset(scene.home)
                assert ik.converge(x, iterations=300) < 0.005
    with pytest.raises(InputError, match="n_arms"):
        place_sweep_arms(Robot.builtin(), units, poly, ds.scale, ds.fingers, n_arms=0)


def test_robot_contact_flags_match_a_plain_reading() -> None:
    """The driver's contact flags (fingertip on the object; a link or the rod on the object
    or the table) equal a plain reading of MuJoCo's contact list, over random arm poses with
    the cube put under the fingertip."""
    sim = RobotSimulator(CUBE, [Arm(Robot.builtin(), BasePose(0.5, 0.0, 180.0))], scale=SCALE)
    m, d, drv, sc = sim.model, sim.data, sim.robot_driver, sim.scene
    obj = m.geom("object").id
    tips = {m.geom("finger1").id}
    links = {m.geom(g).id for g in sc.collision_geoms}
    rng = np.random.default_rng(7)
    qadr = int(m.jnt_qposadr[m.body("object").jntadr[0]])
    seen = set()
    for i in range(40):
        d.qpos[sc.qadr] = rng.uniform(sc.lower, sc.upper)
        mujoco.mj_kinematics(m, d)
        tip = d.site_xpos[sc.tip_sites[0]]
        # every other pose: the cube's top face just under the fingertip
        d.qpos[qadr:qadr + 3] = (tip - [0, 0, 0.025 + DEFAULT_PARAMS.finger_radius - 2e-4]
                                 if i % 2 else [0.0, 0.0, 0.025])
        d.qpos[qadr + 3:qadr + 7] = [1.0, 0.0, 0.0, 0.0]
        mujoco.mj_forward(m, d)
        touch = other = any_tip = False
        for c in d.contact[:d.ncon]:
            if c.dist > 1e-4:
                continue
            pair = {int(c.geom1), int(c.geom2)}
            touch |= obj in pair and bool(pair & tips)
            other |= bool(pair & links)
            any_tip |= bool(pair & tips) and not pair & links  # (the force cap's gate)
        assert drv._contacts(d) == (touch, other, any_tip)
        seen.add((touch, other))
    assert (True, False) in seen or (True, True) in seen
    assert any(o for _, o in seen)


def test_cli_robustness_turns_the_radius_offset_off_and_says_so() -> None:
    """``simulate robustness --robot panda --no-radius-offset``: the sweep's JSON says the
    offset did not run."""
    res = CliRunner().invoke(main, [
        "simulate", "robustness", SKILLS, *STEP1, "--samples", "1", "--seed", "3",
        "--loop", "closed", "--workers", "1", "--robot", "panda", "--base", str(BASE.x),
        str(BASE.y), str(BASE.yaw), "--no-radius-offset", "--json"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["robot"]["radius_offset"] is False
    assert doc["robot_metrics"]["executions"] == 1
