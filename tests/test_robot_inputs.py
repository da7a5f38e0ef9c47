"""Robot inputs refused as the project refuses bad input (one line on stderr naming the
culprit, exit 2, nothing written), and what the robot commands tell a person (docs/robot.md):
regressions found by reading docs/robot.md and trying it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

mujoco = pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")
pytest.importorskip("mink", reason="the robot extra (mink) is not installed: "
                                   "pip install 'nonprehensile[robot]'")

from click.testing import CliRunner  # noqa: E402

from nonprehensile.cli import main  # noqa: E402

SKILLS = str(Path(__file__).resolve().parents[1] / "src/nonprehensile/data/cube_skills.json")


def _one_line_exit_2(res: object, culprit: str) -> None:
    stderr = res.stderr  # type: ignore[attr-defined]
    assert res.exit_code == 2, (res.exit_code, stderr)  # type: ignore[attr-defined]
    assert culprit in stderr and "Traceback" not in stderr
    assert len(stderr.strip().splitlines()) == 1, stderr


def test_plan_refuses_a_base_count_before_writing_anything(tmp_path: Path) -> None:
    # two arms, one --base: refused before the plan's reference files are written (they were
    # written, then the joint trajectories refused, leaving a half-written folder)
    out = tmp_path / "out"
    res = CliRunner().invoke(main, [
        "plan", SKILLS, "--from", "a:0", "--at", "0.3", "0.1", "--to", "a:90", "--step", "90",
        "--dataset", "cube", "--robot", "panda", "--arms", "2", "--base", "0.5", "0", "0",
        "--out", str(out)])
    _one_line_exit_2(res, "--base")
    assert not out.exists()
    # the same in simulate plan and simulate robustness: at once, before any planning
    for cmd in (["simulate", "plan", SKILLS, "--from", "a:0", "--to", "a:90"],
                ["simulate", "robustness", SKILLS, "--samples", "1"]):
        res = CliRunner().invoke(main, [*cmd, "--step", "90", "--robot", "panda", "--arms",
                                        "2", "--base", "0.5", "0", "0"])
        _one_line_exit_2(res, "--base given 1 time(s) for 2 arm(s)")


def _arm(tmp_path: Path, name: str, joint: str) -> Path:
    p = tmp_path / name
    p.write_text(f"""<mujoco><worldbody><body name="base"><geom type="sphere" size="0.05"/>
      <body name="l1" pos="0 0 0.3">{joint}<geom size="0.02"/><site name="tip"/></body>
      </body></worldbody><actuator><position joint="j1" kp="100"/></actuator></mujoco>""")
    return p


def test_an_unreadable_robot_file_says_why(tmp_path: Path) -> None:
    # MuJoCo's first line alone was "XML parse error 13:": the reason and line follow it
    empty = tmp_path / "empty.xml"
    empty.write_text("\n")
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody>\n")
    for path, why in ((empty, "XML_ERROR_EMPTY_DOCUMENT"), (broken, "Line number=")):
        res = CliRunner().invoke(main, ["simulate", "plan", SKILLS, "--from", "b:200", "--to",
                                        "a:290", "--step", "90", "--robot-xml", str(path),
                                        "--tip-site", "tip"])
        _one_line_exit_2(res, "not a MuJoCo model file")
        assert why in res.stderr


def test_an_empty_joint_range_is_named_as_such(tmp_path: Path) -> None:
    # range="1 -1" compiles as a joint without limits: it was refused as "has no limits"
    bad = _arm(tmp_path, "inverted.xml", '<joint name="j1" range="1 -1"/>')
    res = CliRunner().invoke(main, ["simulate", "plan", SKILLS, "--from", "b:200", "--to",
                                    "a:290", "--step", "90", "--robot-xml", str(bad),
                                    "--tip-site", "tip"])
    _one_line_exit_2(res, "joint 'j1' has an empty range")
    # a joint without any range still says so
    free = _arm(tmp_path, "unlimited.xml", '<joint name="j1"/>')
    res = CliRunner().invoke(main, ["simulate", "plan", SKILLS, "--from", "b:200", "--to",
                                    "a:290", "--step", "90", "--robot-xml", str(free),
                                    "--tip-site", "tip"])
    _one_line_exit_2(res, "joint 'j1' has no limits")


def test_a_base_search_that_reaches_nothing_says_so(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    # a one-joint arm 0.3 m tall reaches no fingertip target: the search keeps its least bad
    # base and the arm ran from there with only "(searched)" printed (feasible: false in the
    # JSON alone)
    import functools

    import nonprehensile.sim.placement as placement_module

    monkeypatch.setattr(placement_module, "place_base", functools.partial(
        placement_module.place_base, radii=(0.5,), n_directions=4))
    arm = _arm(tmp_path, "short.xml", '<joint name="j1" range="-1 1"/>')
    out = tmp_path / "out"
    res = CliRunner().invoke(main, [
        "plan", SKILLS, "--from", "b:200", "--to", "a:290", "--step", "90", "--dataset",
        "cube", "--robot-xml", str(arm), "--tip-site", "tip", "--out", str(out), "--json"])
    assert res.exit_code == 0, res.stderr
    assert "no base searched reaches the whole plan" in res.stderr
    assert "best of 4 candidates" in res.stderr
    assert (out / "joints_plan.csv").exists()
    placement = json.loads(res.stdout)["robot"]["placement"]
    assert placement["feasible"] is False
    # the robot table says it too; a reaching base and given bases say nothing
    from nonprehensile.cli.robot import placement_note, robot_table

    extra = {"robot": {"robots": [{"robot": {"name": "short"},
                                   "base": {"x": 0.0, "y": 0.5, "yaw_deg": -90.0}}]},
             "placement": placement}
    assert "out of reach" in str(robot_table([], extra).title)
    assert placement_note(None) is None
    assert placement_note([{**placement, "feasible": True}]) is None
    two = placement_note([{**placement, "feasible": True}, placement])
    assert two is not None and "arm 2: " in two and "arm 1" not in two


def test_a_swept_skill_the_robot_has_no_fingertips_for_says_how_many(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # one arm, --skill twist (two fingertips): it was refused as a skill of no transition,
    # listing the one-finger skills, without saying why or that --arms 2 runs it
    res = CliRunner().invoke(main, ["simulate", "robustness", SKILLS, "--step", "90",
                                    "--robot", "panda", "--samples", "1", "--skill", "twist"])
    _one_line_exit_2(res, "--skill ['twist']: needs 2 fingertips and the robot has 1")
    assert "--arms 2" in res.stderr
    res = CliRunner().invoke(main, ["simulate", "robustness", SKILLS, "--step", "90",
                                    "--robot", "panda", "--samples", "1", "--skill", "nosuch"])
    _one_line_exit_2(res, "no transition of that skill")


def test_robot_from_file_names_a_directory_and_takes_one_site_name(tmp_path: Path) -> None:
    from nonprehensile.errors import InputError
    from nonprehensile.sim.robot import Robot

    with pytest.raises(InputError, match="is a directory"):  # it said "does not exist"
        Robot.from_file(tmp_path, ["tip"])
    arm = _arm(tmp_path, "arm.xml", '<joint name="j1" range="-1 1"/>')
    # a str is one site (it was split into its letters: "no site 't'")
    assert Robot.from_file(arm, "tip").tip_sites == ("tip",)


def test_a_one_sided_torque_limit_is_refused(tmp_path: Path) -> None:
    # actuatorfrcrange="0 87" made a torque limit of 0: the run crashed with a
    # ZeroDivisionError traceback in the robot's log (torque margins)
    for name, joint, servo in (
            ("joint.xml", '<joint name="j1" range="-1 1" actuatorfrcrange="0 87"/>', ""),
            ("servo.xml", '<joint name="j1" range="-1 1"/>', ' forcerange="-10 0"')):
        p = _arm(tmp_path, name, joint)
        p.write_text(p.read_text().replace('kp="100"/>', f'kp="100"{servo}/>'))
        res = CliRunner().invoke(main, ["simulate", "plan", SKILLS, "--from", "b:200", "--to",
                                        "a:290", "--step", "90", "--robot-xml", str(p),
                                        "--tip-site", "tip"])
        _one_line_exit_2(res, "does not drive it both ways")


def test_a_geared_servo_is_refused(tmp_path: Path) -> None:
    # the set points are joint positions: a position servo with gear="2" held the joint at
    # half of them, and the arm missed every contact of the plan without a word
    p = _arm(tmp_path, "geared.xml", '<joint name="j1" range="-1 1"/>')
    p.write_text(p.read_text().replace('kp="100"/>', 'kp="100" gear="2"/>'))
    res = CliRunner().invoke(main, ["simulate", "plan", SKILLS, "--from", "b:200", "--to",
                                    "a:290", "--step", "90", "--robot-xml", str(p),
                                    "--tip-site", "tip", "--base", "0.5", "0", "180"])
    _one_line_exit_2(res, "has gear \"2\"")


@pytest.mark.parametrize("value", ["abc", True, object(), [1.0] * 6 + ["x"], float("nan"), 0.0])
def test_a_bad_velocity_limit_is_named(value: object) -> None:
    # text, a bool or an object raised a bare ValueError or TypeError from float()
    from nonprehensile.errors import InputError
    from nonprehensile.sim import panda
    from nonprehensile.sim.robot import Robot

    with pytest.raises(InputError, match="velocity"):
        Robot("p", xml=panda.panda_xml(), tip_sites=["tip"], velocity_limit=value)  # type: ignore[arg-type]


def test_a_velocity_limit_may_be_any_real_numbers() -> None:
    import numpy as np

    from nonprehensile.sim import panda
    from nonprehensile.sim.robot import Robot

    for value in (np.float32(2.0), np.asarray(panda.DQ_MAX), list(panda.DQ_MAX), 2):
        r = Robot("p", xml=panda.panda_xml(), tip_sites=["tip"], velocity_limit=value)  # type: ignore[arg-type]
        assert np.allclose(r.velocity, np.broadcast_to(np.asarray(value, dtype=float), 7))


def test_a_robot_file_that_is_a_folder_is_one_line(tmp_path: Path) -> None:
    # click's own check of the path (a folder): its usage text made four lines
    res = CliRunner().invoke(main, [
        "simulate", "plan", SKILLS, "--from", "b:200", "--to", "e:110", "--step", "90",
        "--robot-xml", str(tmp_path), "--tip-site", "tip"])
    _one_line_exit_2(res, "--robot-xml")
