"""Simulated executions as learning episodes (``simulate plan --record``).

Each executed step of a plan (one transition, one skill) is one
:class:`~nonprehensile.export.episodes.Episode`, built from the simulator's trace
(``keep_trace=1``: every physics step) and the fingertip targets the executor sent:

* frame ``k`` is the physics state at ``t = t_1 + k / fps`` of the step's run (``t_1`` its
  first physics step), interpolated linearly between physics steps (spherically for the
  object's orientation): an ``fps`` dividing the physics rate (1000 Hz by default: 100, 125,
  200, 250, 500 Hz) takes every value as physics left it;
* ``observation.state``: the object's pose (the model frame's, metres, ``x y z qx qy qz qw``)
  and the fingertips' centres, as physics moved them;
* ``action``: the actuators' set points at the next frame (free fingertips: the fingertip
  targets the executor sent, open loop the plan's references as the simulator interpolates
  them to its step, closed loop as the controller re-timed and corrected them; held while
  the object settles; a finger the step does not use is parked away from the object, and
  its set point is the parking place);
* labels: the skill of the step, the contact event physics produced (debounced, the
  simulator's own events; -1 before the first), the reference arc being driven;
* per episode: success (ended in the predicted state, where predicted), the simulated final
  state, whether the events came in the skill's order, the plan and the step number.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from nonprehensile.demonstrations.dataset import DEFAULT_FINGERS
from nonprehensile.errors import InputError
from nonprehensile.export.demonstrations import arc_name, event_name
from nonprehensile.export.episodes import (
    Episode,
    episode_meta,
    resample_positions,
    resample_quaternions,
)
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import Plan, PlanStep
from nonprehensile.sim.execute import Outcome, step_targets
from nonprehensile.sim.run import control_columns

__all__ = ["DEFAULT_RECORD_FPS", "plan_episodes", "step_episode"]

FloatArray = NDArray[np.float64]

#: Frame rate of recorded executions: every 10th step of the default 1 ms physics step.
DEFAULT_RECORD_FPS = 100.0


def step_episode(
    poly: Polyhedron,
    step: PlanStep,
    outcome: Outcome,
    *,
    n_fingers: int,
    fingers: Mapping[str, str] = DEFAULT_FINGERS,
    fps: float = DEFAULT_RECORD_FPS,
    meta: Mapping[str, object] | None = None,
    controls: int | None = None,
) -> Episode:
    """One executed step as an episode (the outcome must keep its trace).

    Parameters
    ----------
    poly : Polyhedron
    step : PlanStep
        The step that was executed.
    outcome : Outcome
        Its simulation, run with ``keep_trace=1``.
    n_fingers : int
        Fingers in the scene (the episode has them all).
    fingers : mapping
        Finger -> marker of the reference motions (as given to the executor).
    fps : float
    meta : mapping, optional
        More per-episode facts (the plan, the step number).
    controls : int, optional
        The scene's actuators (``model.nu``; default: free fingertips, three per finger),
        whose set points end each trace row and are the action.

    Raises
    ------
    InputError
        The outcome has no trace.
    """
    res = outcome.result
    trace = res.trace
    if trace is None or len(trace) < 1:
        raise InputError("the simulation kept no trace: run it with keep_trace=1 to record it")
    t = trace[:, 0]
    n = int(np.floor((t[-1] - t[0]) * fps + 1e-6)) + 1
    at = t[0] + np.arange(n) / fps
    pos = resample_positions(t, trace[:, 1:4], at)
    quat = resample_quaternions(t, np.column_stack([trace[:, 5:8], trace[:, 4:5]]), at)
    cols = 8 + 3 * n_fingers
    if trace.shape[1] < cols:
        raise InputError(f"the trace has {trace.shape[1]} columns, {cols} expected for "
                         f"{n_fingers} fingers")
    tips = resample_positions(t, trace[:, 8:cols], at).reshape(n, n_fingers, 3)
    # the action: the actuators' set points (the fingertip targets the executor sent, open
    # or closed loop, re-timed or corrected) at the next frame, held at the end
    nu = 3 * n_fingers if controls is None else controls
    if trace.shape[1] < cols + nu:
        raise InputError(f"the trace has no set points ({trace.shape[1]} columns)")
    nxt = np.minimum(at + 1.0 / fps, t[-1])
    action = resample_positions(t, trace[:, control_columns(nu)], nxt).reshape(n, n_fingers, 3)
    _, _, ev_times = step_targets(step, fingers)
    skill = step.transition.skill
    # observed events: the simulator's debounced contact changes
    seen = [(e.time, event_name(poly, e.event)) for e in res.events]
    ev_names = tuple(dict.fromkeys(name for _, name in seen))
    ev_t = np.array([tt for tt, _ in seen])
    ev_i = np.array([ev_names.index(name) for _, name in seen], dtype=np.int64)
    j = np.searchsorted(ev_t, at + 1e-9, side="right") - 1
    event = np.where(j >= 0, ev_i[np.clip(j, 0, max(len(ev_i) - 1, 0))] if len(ev_i) else -1,
                     -1)
    # the reference arc being driven
    arcs = tuple(arc_name(skill.name, a.id, b.id)
                 for a, b in zip(skill.events[:-1], skill.events[1:], strict=True))
    ref_t = np.asarray(ev_times)
    a = np.searchsorted(ref_t, at + 1e-9, side="right") - 1
    arc = np.where((a >= 0) & (a < len(arcs)), a, -1)
    cmp = outcome.comparison
    info = episode_meta(
        skill=skill.name, source_skill=step.transition.source.name,
        demonstrated=step.transition.demonstrated, initial=str(step.start_world),
        final=str(step.end_world), success=bool(cmp.success), chain_ok=bool(cmp.chain_ok),
        simulated=None if cmp.simulated is None else str(cmp.simulated),
        theta_error_deg=cmp.theta_error, position_error_m=cmp.position_error,
        settled=bool(res.settled), **dict(meta or {}),
    )
    return Episode(
        task=f"{skill.name}: {step.start_world} -> {step.end_world}", fps=fps,
        fingertips=tips, action=action,
        finger_names=tuple(f"R{k}" for k in range(1, n_fingers + 1)),
        object_pose=np.concatenate([pos, quat], axis=1), skill_names=(skill.name,),
        skill=np.zeros(n, np.int64), event_names=ev_names, event=event.astype(np.int64),
        arc_names=arcs, arc=arc.astype(np.int64), meta=info,
    )


def plan_episodes(
    poly: Polyhedron,
    plan: Plan,
    outcomes: Sequence[Outcome],
    *,
    n_fingers: int,
    fingers: Mapping[str, str] = DEFAULT_FINGERS,
    fps: float = DEFAULT_RECORD_FPS,
    meta: Mapping[str, object] | None = None,
) -> list[Episode]:
    """The executed steps of a plan as episodes, in order (``outcomes[i]`` of
    ``plan.steps[i]``; a plan stopped early has fewer outcomes)."""
    text = f"{plan.start} -> {plan.goal}"
    return [step_episode(poly, step, out, n_fingers=n_fingers, fingers=fingers, fps=fps,
                         meta={"plan": text, "step": i + 1, "n_steps": len(plan.steps),
                               **dict(meta or {})})
            for i, (step, out) in enumerate(zip(plan.steps, outcomes, strict=False))]
