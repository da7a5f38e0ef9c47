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

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.inference import Expansion, expand
from nonprehensile.planning import NoPlanError, Plan, SearchLimitError, plan
from nonprehensile.skills.skill import Skill
from nonprehensile.states import State
from nonprehensile.step_paths import fingers_of

__all__ = ["fingers_needed", "plan_with_fingers", "skills_within"]


def fingers_needed(skill: Skill) -> int:
    """The fingertips a skill takes: its highest finger number (``R2``: 2; none named: 1)."""
    return max(fingers_of(skill), default=1)


def skills_within(skills: Sequence[Skill], n_fingers: int) -> list[Skill]:
    """The skills an agent with ``n_fingers`` fingertips can run, in their order.

    Raises
    ------
    InputError
        If it can run none of them: the message gives the fewest fingertips any needs.
    """
    kept = [s for s in skills if fingers_needed(s) <= n_fingers]
    if not kept and skills:
        fewest = min(fingers_needed(s) for s in skills)
        raise InputError(f"every skill needs more than the robot's {n_fingers} fingertip(s) "
                         f"(the fewest any needs: {fewest}): give {fewest} arms (--arms "
                         f"{fewest}, one fingertip each) or a hand with {fewest} tip sites")
    return kept


def plan_with_fingers(poly: Polyhedron, expansion: Expansion, start: State, goal: State, *,
                      n_fingers: int, skills: Sequence[Skill], states: Sequence[State],
                      **plan_kw: Any) -> Plan:
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
    **plan_kw
        :func:`~nonprehensile.planning.plan`'s keywords (``position``, ``angle_tol``,
        ``motions``, ``scale``, ...).

    Raises
    ------
    NoPlanError
        No plan with the agent's skills; where every skill makes one, the message names its
        steps that need more fingertips and how many there must be (the search over every
        skill is made only then, without reference motions).
    SearchLimitError
        The search gave up, and every skill makes no plan either (or the agent runs them all).
    """
    try:
        return plan(poly, expansion, start, goal, **plan_kw)
    except (NoPlanError, SearchLimitError) as exc:
        if all(fingers_needed(s) <= n_fingers for s in skills):
            raise
        if isinstance(exc, SearchLimitError) and exc.drift is not None:
            raise  # (the angle tolerance first: every skill's search would drift as well)
        angle_tol = plan_kw.get("angle_tol")
        extra = {} if angle_tol is None else {"angle_tol": angle_tol}
        # (the route only: no reference motions, no measured rates)
        keep = {k: v for k, v in plan_kw.items()
                if k in ("position", "angle_tol", "costs", "default_cost", "relocation_cost")}
        try:
            full = plan(poly, expand(poly, list(skills), list(states), **extra), start, goal,
                        **keep)
        except (NoPlanError, SearchLimitError):
            raise exc from None
        over = [(k, s.transition.skill.name, fingers_needed(s.transition.skill))
                for k, s in enumerate(full.steps, 1)
                if fingers_needed(s.transition.skill) > n_fingers]
        if not over:  # (the other skills add no route: the search's own error stands)
            raise exc from None
        need = max(n for _, _, n in over)
        steps = ", ".join(f"step {k} {name} ({n} fingertips)" for k, name, n in over)
        raise NoPlanError(
            f"no plan from {start} to {goal} with the skills the robot's {n_fingers} "
            f"fingertip(s) can run; with every skill the plan takes {len(full.steps)} "
            f"step(s), {steps}: give {need} arms (--arms {need}, one fingertip each) or a "
            f"hand with {need} tip sites",
            exc.reachable if isinstance(exc, NoPlanError) else []) from None
