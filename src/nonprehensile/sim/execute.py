"""Execute demonstrations, transitions and plans in the simulation.

* :func:`replay_demonstration`: a recorded demonstration, open loop: the fingertips follow
  the recorded tip markers of the fingers the skill names (gaps filled), the object starts in
  the annotated initial state with its centre of mass above the origin (the recordings'
  frame); the result is compared with the annotated final state and event times.
* :func:`simulate_step`: one plan step (or one transition made a step with
  :func:`~nonprehensile.planning.step_for`): the fingertips follow the step's reference
  motions, placed where the plan says the object is.
* :func:`simulate_plan`: every step of a plan in one continuous simulation, open loop: the
  object carries on from where physics left it, each step's reference motion is placed where
  the plan predicted the object would be.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from nonprehensile.demonstrations.dataset import DEFAULT_FINGERS, Dataset, Demonstration
from nonprehensile.demonstrations.segment import Segment
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.motion.trajectory import fill_gaps
from nonprehensile.planning import Plan, PlanStep, ReferenceMotion
from nonprehensile.references import flatten_segments, medoid
from nonprehensile.sim.compare import (
    DEFAULT_ANGLE_TOL_DEG,
    DEFAULT_POSITION_TOL,
    Comparison,
    compare,
)
from nonprehensile.sim.distribution import NO_PERTURBATION, Perturbation
from nonprehensile.sim.run import SimResult, Simulator, pose_of_state
from nonprehensile.step_paths import fingers_of, marker_index, smooth_markers, step_targets

__all__ = [
    "DemonstrationLibrary",
    "Outcome",
    "fingers_of",
    "replay_demonstration",
    "simulate_plan",
    "simulate_step",
    "smooth_markers",
    "step_targets",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Outcome:
    """One simulated transition: what ran, what physics did, and the comparison."""

    label: dict[str, Any]
    result: SimResult
    comparison: Comparison

    @property
    def success(self) -> bool:
        """Ended as predicted."""
        return self.comparison.success

    def to_dict(self) -> dict[str, Any]:
        """One JSON record: ``success`` beside the details."""
        return {"success": self.success, **self.label, **self.comparison.to_dict(),
                "simulation": self.result.to_dict()}


def replay_demonstration(
    sim: Simulator, dataset: Dataset, demo: Demonstration, *,
    angle_tol: float = DEFAULT_ANGLE_TOL_DEG, smooth: int = 9,
    perturbation: Perturbation = NO_PERTURBATION, noise_stream: str = "finger",
) -> Outcome:
    """Replay one demonstration open loop and compare with its annotations.

    The recorded tip markers (gaps filled) are smoothed by a centred moving average of
    ``smooth`` frames, as a tracking controller filters measurement noise, before they drive
    the fingertips. ``perturbation`` moves the object's start and adds the finger's noise
    (stream ``noise_stream``).
    """
    traj = demo.trajectory.to_units("m")
    pos = fill_gaps(traj.positions, max(dataset.gap_limit, 1) * 4)
    pos = np.asarray(pos)
    if not np.isfinite(pos).all():  # gaps longer than fill_gaps bridges: hold the last value
        for j in range(pos.shape[1]):
            for a in range(3):
                col = pos[:, j, a]
                ok = np.isfinite(col)
                if ok.any():
                    pos[:, j, a] = np.interp(np.arange(len(col)), np.flatnonzero(ok), col[ok])
    if smooth > 1:
        pos = smooth_markers(pos, smooth)
    targets = {k: pos[:, marker_index(dataset.fingers, k, traj.marker_names)]
               for k in fingers_of(demo.skill)}
    targets = perturbation.finger_targets(targets, traj.rate, noise_stream)
    start = perturbation.start_pose(pose_of_state(dataset.poly, demo.initial, (0.0, 0.0),
                                                  sim.scale))
    result = sim.run(start, targets, traj.rate)
    t0 = 0.0
    cmp = compare(dataset.poly, demo.skill, result, predicted=demo.final,
                  event_times=[e.time - t0 for e in demo.events], angle_tol=angle_tol)
    label = {"file": demo.file, "skill": demo.skill.name, "mentor": demo.mentor,
             "from": demo.initial.to_dict(), "to": demo.final.to_dict()}
    return Outcome(label, result, cmp)


def simulate_step(
    sim: Simulator, step: PlanStep, *, fingers: Mapping[str, str] = DEFAULT_FINGERS,
    continue_from_current: bool = False, check_position: bool = True,
    angle_tol: float = DEFAULT_ANGLE_TOL_DEG, position_tol: float = DEFAULT_POSITION_TOL,
    label: Mapping[str, Any] | None = None, keep_trace: int = 0,
    perturbation: Perturbation = NO_PERTURBATION, noise_stream: str = "finger",
    signals: bool = False,
) -> Outcome:
    """Simulate one step: the object starts at the step's planned pose (or, with
    ``continue_from_current``, wherever the previous simulation left it). ``keep_trace``
    and ``signals``: as :meth:`Simulator.run`.

    ``perturbation`` moves the object's start away from the planned pose (not when
    continuing) and adds the finger's noise (stream ``noise_stream``)."""
    targets, rate, times = step_targets(step, fingers)
    if step.start_pose is None or step.end_pose is None:
        raise InputError("the step carries no object pose: make it with plan() or step_for()")
    targets = perturbation.finger_targets(targets, rate, noise_stream)
    result = sim.run(None if continue_from_current else perturbation.start_pose(
        step.start_pose), targets, rate, keep_trace=keep_trace, signals=signals)
    t = step.transition
    cmp = compare(sim.poly, t.skill, result, predicted=step.end_world,
                  predicted_pose=step.end_pose if check_position else None,
                  event_times=times, angle_tol=angle_tol, position_tol=position_tol)
    info = {"skill": t.skill.name, "source": t.source.name, "demonstrated": t.demonstrated,
            "from": step.start_world.to_dict(), "to": step.end_world.to_dict(),
            "predicted_position": [round(v, 6) for v in step.end_pose.position],
            **(label or {})}
    return Outcome(info, result, cmp)


def simulate_plan(
    poly: Polyhedron, plan: Plan, *, scale: float, fingers: Mapping[str, str] = DEFAULT_FINGERS,
    sim: Simulator | None = None, progress: Progress | None = None, **kw: Any,
) -> list[Outcome]:
    """Execute a plan's steps one after the other in one simulation, open loop."""
    if not plan.steps:
        return []
    n = max(max(fingers_of(s.transition.skill), default=1) for s in plan.steps)
    sim = sim or Simulator(poly, scale=scale, n_fingers=max(n, 1))
    out = []
    for i, step in enumerate(plan.steps):
        out.append(simulate_step(sim, step, fingers=fingers, continue_from_current=i > 0,
                                 label={"step": i + 1}, noise_stream=f"finger/step{i + 1}",
                                 **kw))
        if progress is not None:
            progress(i + 1, len(plan.steps))
    return out


class DemonstrationLibrary:
    """Reference motions taken whole from one demonstration per skill.

    A plan's :class:`~nonprehensile.references.ClusteredMotions` gives each arc the medoid
    of its own cluster, so a step's arcs may come from different demonstrations: fine for a
    controller that tracks contacts, but an open-loop replay then runs a motion nobody made.
    Here every arc of a skill comes from the same demonstration: the medoid of the skill's
    demonstrations (least total distance between their whole resampled finger paths).

    Parameters
    ----------
    segments : sequence of Segment
        From :func:`~nonprehensile.demonstrations.segment.segment_dataset`.
    """

    def __init__(self, segments: Sequence[Segment]) -> None:
        by_demo: dict[str, dict[tuple[str, str], Segment]] = {}
        skill_of: dict[str, str] = {}
        for s in segments:
            key = s.demonstration.file
            by_demo.setdefault(key, {})[(s.motion.source, s.motion.target)] = s
            skill_of[key] = s.skill
        self._chosen: dict[str, dict[tuple[str, str], Segment]] = {}
        self._count: dict[str, int] = {}
        for skill in sorted(set(skill_of.values())):
            demos = [d for d in by_demo if skill_of[d] == skill]
            arcs = sorted(set.intersection(*(set(by_demo[d]) for d in demos)))
            if not arcs:
                continue
            x = np.hstack([flatten_segments([by_demo[d][a] for d in demos], n_points=50)
                           for a in arcs])
            best = demos[medoid(x)]
            self._chosen[skill] = by_demo[best]
            self._count[skill] = len(demos)

    def demonstration(self, skill: str) -> str | None:
        """The file of the demonstration chosen for ``skill``."""
        arcs = self._chosen.get(skill)
        return next(iter(arcs.values())).demonstration.file if arcs else None

    def reference(self, skill: str, source: str, target: str) -> ReferenceMotion | None:
        """The chosen demonstration's segment on the arc ``source -> target``, metres."""
        seg = self._chosen.get(skill, {}).get((source, target))
        if seg is None:
            return None
        traj = seg.trajectory.to_units("m")
        return ReferenceMotion(np.asarray(traj.positions), tuple(traj.marker_names),
                               traj.rate, 0, self._count[skill])
