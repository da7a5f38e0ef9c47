"""Plans for an agent with a fixed number of fingertips: a robot's arms, one fingertip each,
or a hand.

A skill names its fingers ``R1``, ``R2``, ... in its contact pairs; an agent with ``n``
fingertips runs the skills that name no finger above ``Rn``. Its plans (and re-plans) use
those skills only, so a goal that every skill reaches can be out of its reach: the plan the
other skills would make then says which of its steps need more fingertips, and how many.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from nonprehensile.checks import MAX_ARMS
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.inference import Expansion, expand
from nonprehensile.planning import NoPlanError, Plan, SearchLimitError, plan
from nonprehensile.skills.skill import Skill
from nonprehensile.states import State
from nonprehensile.step_paths import fingers_of

__all__ = ["fingers_needed", "more_fingertips", "plan_with_fingers", "skills_within"]


#: The most search nodes of the plan with every skill that explains a robot's missing plan
#: (a tenth of the planner's own limit: the explanation adds seconds, not half a minute).
EXPLAIN_NODES = 200_000


def fingers_needed(skill: Skill) -> int:
    """The fingertips a skill takes: its highest finger number (``R2``: 2; none named: 1)."""
    return max(fingers_of(skill), default=1)


def more_fingertips(need: int, per_arm: int = 1) -> str:
    """How to get ``need`` fingertips with arms of ``per_arm`` tip sites each (the fix a
    message names)."""
    arms = -(-need // per_arm)
    if arms > MAX_ARMS:
        return f"give a robot with {need} tip sites (--arms takes at most {MAX_ARMS})"
    return (f"give {arms} arms (--arms {arms}, {per_arm} fingertip(s) each) or a robot with "
            f"{need} tip sites")


def skills_within(skills: Sequence[Skill], n_fingers: int, per_arm: int = 1) -> list[Skill]:
    """The skills an agent with ``n_fingers`` fingertips (arms of ``per_arm`` tip sites
    each) can run, in their order.

    Raises
    ------
    InputError
        If it can run none of them: the message gives the fewest fingertips any needs.
    """
    kept = [s for s in skills if fingers_needed(s) <= n_fingers]
    if not kept and skills:
        fewest = min(fingers_needed(s) for s in skills)
        raise InputError(f"every skill needs more than the robot's {n_fingers} fingertip(s) "
                         f"(the fewest any needs: {fewest}): "
                         f"{more_fingertips(fewest, per_arm)}")
    return kept


def plan_with_fingers(poly: Polyhedron, expansion: Expansion, start: State, goal: State, *,
                      n_fingers: int, skills: Sequence[Skill], states: Sequence[State],
                      per_arm: int = 1, atol: float | None = None, **plan_kw: Any) -> Plan:
    """:func:`~nonprehensile.planning.plan` over ``expansion`` (built from the skills an
    agent with ``n_fingers`` fingertips runs, :func:`skills_within`), saying, when it finds
    no plan, whether the other skills would have made one.

    Parameters
    ----------
    poly, expansion, start, goal
        As :func:`~nonprehensile.planning.plan`.
    n_fingers : int
        The agent's fingertips.
    skills : sequence of Skill
        Every skill, those it cannot run included (only read when no plan is found).
    states : sequence of State
        The state set ``expansion`` was built on (the same for the other skills').
    per_arm : int
        Tip sites per arm (the fix the message names: how many arms).
    atol : float, optional
        The length tolerance ``expansion`` was built with (the other skills' too).
    **plan_kw
        :func:`~nonprehensile.planning.plan`'s keywords (``position``, ``angle_tol``,
        ``motions``, ``scale``, ...).

    Raises
    ------
    NoPlanError
        No plan with the agent's skills; where every skill makes one, the message names its
        steps that need more fingertips and how many there must be (the search over every
        skill is made only then, without reference motions or measured rates).
    SearchLimitError
        The search gave up; where every skill makes a plan, the message says so as above
        (the agent's search is not proven empty, only given up). Where the model's states
        drift (``drift``: its rounding), that error as it came: the angle tolerance first.
    """
    try:
        return plan(poly, expansion, start, goal, **plan_kw)
    except (NoPlanError, SearchLimitError) as exc:
        if exc.drift is not None or all(fingers_needed(s) <= n_fingers for s in skills):
            raise
        extra: dict[str, Any] = {"atol": atol}
        if "angle_tol" in plan_kw:
            extra["angle_tol"] = plan_kw["angle_tol"]
        keep = {k: v for k, v in plan_kw.items()
                if k in ("position", "angle_tol", "costs", "default_cost", "relocation_cost")}
        try:
            # (a bounded search: it only explains an error, whose own search may already
            # have run to the limit)
            full = plan(poly, expand(poly, list(skills), list(states), **extra), start, goal,
                        max_nodes=EXPLAIN_NODES, **keep)
        except (NoPlanError, SearchLimitError):
            raise exc from None
        over = [(k, s.transition.skill.name, fingers_needed(s.transition.skill))
                for k, s in enumerate(full.steps, 1)
                if fingers_needed(s.transition.skill) > n_fingers]
        if not over:  # (the other skills add no route: the search's own error stands)
            raise exc from None
        need = max(n for _, _, n in over)
        steps = ", ".join(f"step {k} {name} ({n} fingertips)" for k, name, n in over)
        # (the search's own message first: it may say more, the measured rates it avoided)
        why = (f"{exc}: it searched the skills the robot's {n_fingers} fingertip(s) can run, "
               f"and with every skill the plan takes {len(full.steps)} step(s), {steps}: "
               f"{more_fingertips(need, per_arm)}")
        if isinstance(exc, SearchLimitError):
            raise SearchLimitError(why) from None
        raise NoPlanError(why, exc.reachable) from None
