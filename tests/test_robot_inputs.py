"""Robot inputs refused as the project refuses bad input (one line on stderr naming the
culprit, exit 2, nothing written), and what the robot commands tell a person (docs/robot.md):
regressions found by reading docs/robot.md and trying it."""

from __future__ import annotations

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
