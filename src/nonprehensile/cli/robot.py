"""Robot options shared by ``plan`` and ``simulate plan``: ``--robot``, ``--robot-xml``,
``--tip-site``, ``--base`` (see ``docs/robot.md``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import click
from rich.table import Table

from nonprehensile.checks import MAX_ARMS, Range
from nonprehensile.cli.options import Number, count, number
from nonprehensile.errors import InputError

__all__ = [
    "auto_switch_of",
    "compliance_option",
    "control_every",
    "direction_option",
    "force_feedforward_option",
    "load_robot",
    "placement_doc",
    "placement_note",
    "press_option",
    "radius_offset_option",
    "robot_arms",
    "robot_options",
    "robot_table",
    "wants_robot",
]

F = Callable[..., Any]

#: --base: a place on the table within an arm's reach of the object, and a heading.
_BASE_XY = number(-10.0, 10.0, unit="m")
_BASE_YAW = number(-360.0, 360.0, unit="degrees")
#: --control-rate: how often the IK runs (the library checks that it divides the physics rate).
#: The default is the library's (``robot_driver.DEFAULT_CONTROL_EVERY`` = 10 steps of 1 ms; a
#: test holds them equal).
DEFAULT_CONTROL_RATE = 100.0
_RATE = number(0.0, 1e5, low_open=True, unit="Hz")


def robot_options(fn: F) -> F:
    """Add the robot options to a command (keyword arguments ``robot``, ``robot_xml``,
    ``tip_sites``, ``base``, ``control_rate``)."""
    for opt in reversed([
        click.option("--robot", "robot", default=None, metavar="NAME",
                     help="Execute with a bundled robot arm: `panda` (Franka Panda with a "
                          "finger rod). Needs the `robot` extra."),
        click.option("--robot-xml", "robot_xml", default=None,
                     type=click.Path(dir_okay=False),
                     help="Execute with your MJCF robot (give --tip-site too)."),
        click.option("--tip-site", "tip_sites", multiple=True, metavar="NAME",
                     help="A fingertip site of --robot-xml, one per finger R1, R2, ... "
                          "(repeatable)."),
        click.option("--control-rate", "control_rate", type=_RATE, default=DEFAULT_CONTROL_RATE,
                     show_default=True, metavar="HZ",
                     help="Robot: how often the IK runs (a divisor of the 1 kHz physics "
                          "rate); the joint servos get interpolated set points every step."),
        click.option("--arms", "n_arms", type=count(1, MAX_ARMS), default=1,
                     show_default=True,
                     help="How many copies of the robot (two-finger skills by two one-finger "
                          "arms); their tip sites are fingers R1, R2, ... arm by arm."),
        click.option("--base", "base", type=(_BASE_XY, _BASE_XY, _BASE_YAW), multiple=True,
                     metavar="X Y YAW",
                     help="A robot base on the table: x, y (m) and heading (degrees), one per "
                          "arm (repeatable); default: searched for reach and joint-limit "
                          "margin, arm by arm."),
    ]):
        fn = opt(fn)
    return fn


def _auto_switch(flag: str, key: str, help_: str) -> Callable[[F], F]:
    """A ``--flag/--no-flag`` option (keyword argument ``key``) whose default, None, leaves
    the choice to the library (``"auto"``: :func:`auto_switch_of`)."""

    def add(fn: F) -> F:
        return click.option(f"--{flag}/--no-{flag}", key, default=None, help=help_)(fn)

    return add


#: ``--force-feedforward/--no-force-feedforward`` (keyword ``force_feedforward``).
force_feedforward_option = _auto_switch(
    "force-feedforward", "force_feedforward",
    "Robot, one stiff arm: feed the measured contact force (clipped at the force cap) "
    "forward to the joint servos, so the fingertip holds its command under load "
    "(docs/robot.md). Default: on with one stiff arm's fingertip, off with --compliance, "
    "--arms 2 or a hand.")

#: ``--radius-offset/--no-radius-offset`` (keyword ``radius_offset``).
radius_offset_option = _auto_switch(
    "radius-offset", "radius_offset",
    "Robot: move each target near the object out along its normal by the robot's fingertip "
    "radius minus the references' 6 mm (a tool radius compensation for a larger fingertip; "
    "a smaller one is not moved; docs/robot.md). Default: on with one fingertip, off with "
    "--arms 2 or a hand.")


def auto_switch_of(kw: dict[str, Any], key: str) -> bool | str:
    """The switch ``key`` the options ask for: ``"auto"`` unless one was given."""
    given = kw.get(key)
    return "auto" if given is None else bool(given)


def compliance_option(fn: F) -> F:
    """Add ``--compliance/--stiff`` (keyword argument ``compliance``) to a command that
    simulates a robot."""
    return click.option(
        "--compliance/--stiff", "compliance", default=False, show_default=True,
        help="Robot: the force-limited finger command (each fingertip gives way along the "
             "measured contact force as the free fingertip's spring and force limit would; "
             "docs/robot.md); default --stiff, the position-controlled arm.")(fn)


class _PressDepth(Number):
    """``--press-depth``: ``auto``, ``off``, or a depth in millimetres (returned in metres)."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None
                ) -> Any:
        if isinstance(value, str) and value.strip().lower() in ("auto", "off"):
            return "auto" if value.strip().lower() == "auto" else None
        if value is None or value == "auto":  # (the default, or a value converted before)
            return value
        return float(super().convert(value, param, ctx)) / 1000.0


def press_option(fn: F) -> F:
    """Add ``--press-depth`` (keyword argument ``press_depth``: ``"auto"``, None or metres)
    to a command that simulates a robot."""
    return click.option(
        "--press-depth", "press_depth", type=_PressDepth(Range(0.0, 20.0, low_open=True,
                                                                unit="mm")),
        default="auto", show_default=True, metavar="MM|auto|off",
        help="Robot: the contact-consistent command: the deepest (mm) a fingertip's command "
             "may put the arm's fingertip inside the object as observed (a deeper one is "
             "pushed out along the object's normal); `auto`: 2 mm when several fingertips "
             "pinch, none for one arm pushing; `off`: none (docs/robot.md).")(fn)


def direction_option(fn: F) -> F:
    """Add ``--finger-direction`` (keyword argument ``finger_direction``: ``"lean"`` or
    ``"recorded"``) to a command that moves a robot along a plan."""
    return click.option(
        "--finger-direction", "finger_direction",
        type=click.Choice(["lean", "recorded"]), default="lean", show_default=True,
        help="Robot: how each finger tool points during a step: `lean`, the IK's rule "
             "(down, leaning out of a side face); `recorded`, along the demonstrators' "
             "fingers (knuckle marker to tip marker, `<finger>_knuckle` beside "
             "`<finger>_tip`), where the references carry them (docs/robot.md).")(fn)


def wants_robot(kw: dict[str, Any]) -> bool:
    """Whether a robot option was given (and they agree)."""
    robot, xml, sites, base = (kw.get("robot"), kw.get("robot_xml"), kw.get("tip_sites"),
                               kw.get("base"))
    if robot is not None and xml is not None:
        raise InputError("give --robot NAME or --robot-xml FILE, not both")
    if sites and xml is None:
        raise InputError("--tip-site names sites of --robot-xml FILE: give the file too")
    if xml is not None and not sites:
        raise InputError("--robot-xml needs --tip-site NAME (the fingertip's site; one per "
                         "finger)")
    if base and robot is None and xml is None:
        raise InputError("--base places a robot: give --robot NAME or --robot-xml FILE")
    n_arms = int(kw.get("n_arms", 1))
    if base and len(base) != n_arms:  # refused now, before planning writes anything
        raise InputError(f"--base given {len(base)} time(s) for {n_arms} arm(s): give one "
                         "X Y YAW per arm, or none to search them")
    if kw.get("press_depth", "auto") != "auto" and robot is None and xml is None:
        raise InputError("--press-depth is a robot's finger command: give --robot NAME or "
                         "--robot-xml FILE")
    if kw.get("finger_direction", "lean") != "lean" and robot is None and xml is None:
        raise InputError("--finger-direction points a robot's finger tool: give --robot NAME "
                         "or --robot-xml FILE")
    if kw.get("force_feedforward") and robot is None and xml is None:
        raise InputError("--force-feedforward is a robot's finger command: give --robot NAME "
                         "or --robot-xml FILE")
    if kw.get("radius_offset") is not None and robot is None and xml is None:
        raise InputError("--radius-offset/--no-radius-offset is a robot's finger command: "
                         "give --robot NAME or --robot-xml FILE")
    if kw.get("compliance") and robot is None and xml is None:
        raise InputError("--compliance is a robot's finger command: give --robot NAME or "
                         "--robot-xml FILE")
    if kw.get("force_feedforward") and (kw.get("compliance") or int(kw.get("n_arms", 1)) > 1):
        raise InputError("--force-feedforward goes with one stiff arm's force cap: drop it, "
                         "or --compliance, or --arms")
    return robot is not None or xml is not None


def control_every(kw: dict[str, Any], timestep: float) -> int:
    """Physics steps per IK solve from ``--control-rate`` (one line and exit 2 unless it
    divides the physics rate)."""
    import math

    rate = kw.get("control_rate", DEFAULT_CONTROL_RATE)
    physics = 1.0 / timestep
    if not (isinstance(rate, float) and math.isfinite(rate) and 0 < rate <= physics):
        raise InputError(f"--control-rate must be a rate in (0, {physics:g}] Hz, got {rate!r}")
    every = round(physics / rate)
    if abs(every * rate - physics) > 1e-6 * physics or every > 100:
        raise InputError(f"--control-rate must divide the physics rate {physics:g} Hz by a "
                         f"whole number up to 100 (e.g. 1000, 250, 125, 100), got {rate:g}")
    return every


def load_robot(kw: dict[str, Any]) -> Any:
    """The :class:`~nonprehensile.sim.robot.Robot` the options name (checked now, before any
    planning: a bad file fails at once)."""
    try:
        from nonprehensile.sim.ik import import_mink
        from nonprehensile.sim.robot import Robot
    except ImportError as exc:
        raise InputError(f"robots need MuJoCo and mink: pip install 'nonprehensile[robot]' "
                         f"({exc})") from None
    import_mink()
    robot = (Robot.builtin(kw["robot"]) if kw.get("robot") is not None
             else Robot.from_file(kw["robot_xml"], kw["tip_sites"]))
    if kw.get("force_feedforward") and len(robot.tip_sites) > 1:  # a hand: no force cap
        raise InputError(f"--force-feedforward goes with one stiff arm's force cap: the robot "
                         f"has {len(robot.tip_sites)} fingertip sites; drop it")
    return robot


def robot_skills(robot: Any, kw: dict[str, Any], skills: Sequence[Any]
                 ) -> tuple[list[Any], dict[str, int]]:
    """The skills the robot has fingertips for (its tip sites times ``--arms``), and the
    keywords of :func:`~nonprehensile.finger_budget.plan_with_fingers` that say how many
    (``n_fingers``, ``per_arm``); without a robot, every skill and the most fingertips any
    takes. A robot plans and re-plans with those skills only."""
    from nonprehensile.finger_budget import fingers_needed, skills_within

    if robot is None:
        return list(skills), {"n_fingers": max((fingers_needed(s) for s in skills),
                                               default=1), "per_arm": 1}
    per_arm = len(robot.tip_sites)
    n_tips = per_arm * int(kw["n_arms"])
    return skills_within(skills, n_tips, per_arm), {"n_fingers": n_tips, "per_arm": per_arm}


def robot_arms(kw: dict[str, Any], poly: Any, scale: float, plan: Any, fingers: Any,
               params: Any, robot: Any = None) -> tuple[list[Any], Any]:
    """The arm(s) the options ask for, at ``--base`` or at searched bases (arm by arm, each
    for its first fingertip's path, away from the arms placed before); returns the arms and
    the placement (a list with several arms; None when ``--base`` was given)."""
    try:
        from nonprehensile.sim.ik import import_mink
        from nonprehensile.sim.placement import place_base, plan_targets
        from nonprehensile.sim.robot import BasePose
        from nonprehensile.sim.robot_scene import Arm
    except ImportError as exc:
        raise InputError(f"robots need MuJoCo and mink: pip install 'nonprehensile[robot]' "
                         f"({exc})") from None
    import_mink()
    if robot is None:
        robot = load_robot(kw)
    n_arms = int(kw.get("n_arms", 1))
    bases = list(kw.get("base") or ())
    if bases and len(bases) != n_arms:
        raise InputError(f"--base given {len(bases)} time(s) for {n_arms} arm(s): give one "
                         "X Y YAW per arm, or none to search them")
    if bases:
        return [Arm(robot, BasePose(x, y, yaw)) for x, y, yaw in bases], None
    per_arm = len(robot.tip_sites)
    paths = plan_targets(plan, fingers, per_arm * n_arms)
    placements: list[Any] = []
    for i in range(n_arms):
        placements.append(place_base(robot, poly, scale, paths, params=params,
                                     finger=i * per_arm,
                                     avoid=[p.base for p in placements]))
    arms = [Arm(robot, p.base) for p in placements]
    return arms, placements[0] if n_arms == 1 else placements


def robot_table(records: list[dict[str, Any]], extra: dict[str, Any]) -> Table:
    """The robot's records per step, as a person reads them."""
    robots = extra["robot"]["robots"]
    where = "; ".join(f"({r['base']['x']:.3f}, {r['base']['y']:.3f}) m, "
                      f"{r['base']['yaw_deg']:.1f} deg" for r in robots)
    t = Table(title=f"robot {robots[0]['robot']['name']}"
                    + (f" x{len(robots)}" if len(robots) > 1 else "") + f" at {where}"
                    + ((" (searched, out of reach: see the note)"
                        if placement_note(extra["placement"]) else " (searched)")
                       if extra.get("placement") else ""))
    for c in ("step", "tracking in contact (max)", "tracking (max)", "longest at a limit",
              "link/rod contact", "joint margin", "IK median"):
        t.add_column(c)
    for r in records:
        m = r["robot"]
        c = m["tracking_error_contact_max_m"]
        at = m["longest_at_limit_s"]
        worst = max(at, key=lambda k: at[k]) if at else "-"
        t.add_row(str(r["step"]), "-" if c is None else f"{1000 * c:.1f} mm",
                  f"{1000 * m['tracking_error_max_m']:.1f} mm",
                  f"{1000 * at.get(worst, 0.0):.0f} ms ({worst})" if at else "-",
                  f"{1000 * m['other_contact_s']:.0f} ms",
                  f"{m['position_margin_min_rad']:.2f} rad",
                  f"{m['ik_median_ms']:.3f} ms")
    return t


def placement_doc(placement: Any) -> Any:
    """JSON form of :func:`robot_arms`' placement (None, one, or one per arm)."""
    if placement is None:
        return None
    if isinstance(placement, list):
        return [p.to_dict() for p in placement]
    return placement.to_dict()


def placement_note(doc: Any) -> str | None:
    """A line saying that the searched base(s) do not reach the whole plan (``doc``:
    :func:`placement_doc`'s form), or None when every one does (or the bases were given).
    The search then keeps the base with the least reach error, and the arm runs from there:
    its records say what failed, the person is told why."""
    if doc is None:
        return None
    found = doc if isinstance(doc, list) else [doc]
    off = [(i, p) for i, p in enumerate(found) if not p.get("feasible", True)]
    if not off:
        return None
    which = ", ".join((f"arm {i + 1}: " if len(found) > 1 else "")
                      + f"{1000 * p['reach_error_m']:.1f} mm" for i, p in off)
    return (f"note: no base searched reaches the whole plan (the best of "
            f"{off[0][1]['candidates']} candidates leaves the fingertip {which} from its "
            "targets; reaching is within 5 mm); the arm runs from that base: give --base X Y "
            "YAW, or a robot that reaches")
