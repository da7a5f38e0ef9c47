"""Cutting demonstrations into motion segments and registering them to skill-graph arcs.

The paper uses contact events to segment manipulation skills (Section IV) and registers the
proprioceptive trajectories to the arcs of the contact-based graph models (Section VI). Each
demonstration is cut at its event times; the piece between events ``i`` and ``i + 1`` is the
finger motion of the skill's ``i``-th motion arc. The arc is looked up in the skill graph of the
skill's maneuver group (:func:`~nonprehensile.skills.skill.group_by_maneuver`), so segments of
skills with the same events and different motions (the paper's Fig. 5 skills 2 and 3, the two
skills of Fig. 9) land on parallel arcs of one graph, and segments of skills that share
events land on the same nodes.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass

import networkx as nx
import numpy as np

from nonprehensile.demonstrations.dataset import Dataset, Demonstration
from nonprehensile.demonstrations.record import MarkerTrajectory
from nonprehensile.errors import InputError, NonprehensileError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.motion.trajectory import fill_gaps
from nonprehensile.skills.skill import Motion, Skill, group_by_maneuver, skill_graph

__all__ = [
    "ArcRef",
    "Segment",
    "SkillGraphs",
    "segment_dataset",
    "segment_demonstration",
    "segments_by_arc",
    "skill_graphs",
]

# Annotated times are written with finitely many decimals; a time within a millionth of a
# frame of a frame's time is taken to be on it, so that the frame is not lost to rounding.
_FRAME_SLACK = 1e-6


@dataclass(frozen=True)
class ArcRef:
    """An arc of one of a dataset's skill graphs.

    Attributes
    ----------
    group : int
        Index of the maneuver group (and its graph) in :class:`SkillGraphs`.
    source, target : hashable
        The arc's nodes (contact events keyed as in
        :func:`~nonprehensile.skills.skill.skill_graph`).
    key : str
        The arc's key: the name of the skill whose motion it is.
    """

    group: int
    source: Hashable
    target: Hashable
    key: str


@dataclass(frozen=True)
class SkillGraphs:
    """The skill graphs of a set of skills, one per maneuver (paper Fig. 5(b)).

    Attributes
    ----------
    groups : tuple of tuple of Skill
        Skills grouped by the maneuver they realise.
    graphs : tuple of networkx.MultiDiGraph
        ``graphs[g]`` is the skill graph of ``groups[g]``.
    """

    groups: tuple[tuple[Skill, ...], ...]
    graphs: tuple[nx.MultiDiGraph, ...]

    def group_of(self, skill: str) -> int:
        """Index of the group holding the skill named ``skill``.

        Raises
        ------
        InputError
            If no group has it.
        """
        for g, grp in enumerate(self.groups):
            if any(s.name == skill for s in grp):
                return g
        raise InputError(f"no skill graph holds skill {skill!r}")

    def arc_of(self, skill: Skill, step: int) -> ArcRef:
        """The arc of ``skill``'s motion number ``step`` (0-based).

        Raises
        ------
        InputError
            If the skill is in no graph or has no such motion.
        """
        if not 0 <= step < len(skill.motions):
            raise InputError(
                f"skill {skill.name!r} has motions 0..{len(skill.motions) - 1}, not {step}"
            )
        g = self.group_of(skill.name)
        motion: Motion = skill.motions[step]
        for u, v, key, data in self.graphs[g].edges(keys=True, data=True):
            if key == skill.name and data["motion"] == motion:
                return ArcRef(g, u, v, key)
        # skill_graph adds one arc per motion, so this is a broken graph, not bad input
        raise NonprehensileError(
            f"the skill graph of {skill.name!r} has no arc for its motion {step} "
            f"({motion.source} -> {motion.target})"
        )


def skill_graphs(poly: Polyhedron, skills: Sequence[Skill]) -> SkillGraphs:
    """Group ``skills`` by maneuver and build each group's skill graph."""
    groups = tuple(tuple(g) for g in group_by_maneuver(poly, skills))
    return SkillGraphs(groups, tuple(skill_graph(poly, g) for g in groups))


@dataclass(frozen=True, eq=False)
class Segment:
    """The finger motion of one demonstration between two consecutive contact events.

    Attributes
    ----------
    demonstration : Demonstration
        Where it was cut from.
    step : int
        Which motion of the skill (0-based): it joins events ``step`` and ``step + 1``.
    motion : Motion
        That motion of the skill.
    arc : ArcRef
        The skill-graph arc it is registered to.
    t_start, t_end : float
        The event times that bound it, seconds from the recording's start.
    trajectory : MarkerTrajectory
        The frames at times ``t_start <= t <= t_end``, shape (n_frames, n_markers, 3); its
        frame 0 is the first of them.
    """

    demonstration: Demonstration
    step: int
    motion: Motion
    arc: ArcRef
    t_start: float
    t_end: float
    trajectory: MarkerTrajectory

    @property
    def skill(self) -> str:
        """The demonstrated skill's name."""
        return self.demonstration.skill.name

    @property
    def mentor(self) -> str:
        """Who demonstrated it."""
        return self.demonstration.mentor


def _frames(t0: float, t1: float, rate: float, n: int) -> tuple[int, int]:
    i0 = max(math.ceil(t0 * rate - _FRAME_SLACK), 0)
    i1 = min(math.floor(t1 * rate + _FRAME_SLACK), n - 1)
    return i0, i1


def segment_demonstration(
    demo: Demonstration, graphs: SkillGraphs, *, max_gap: int | None = None
) -> list[Segment]:
    """Cut one demonstration at its event times and register each piece to its arc.

    Parameters
    ----------
    demo : Demonstration
    graphs : SkillGraphs
        Skill graphs holding the demonstration's skill.
    max_gap : int, optional
        If given, dropouts of up to ``max_gap`` frames are filled
        (:func:`~nonprehensile.motion.trajectory.fill_gaps`) from the first to the last event
        before cutting, so that a gap at a cut is interpolated from both sides.

    Returns
    -------
    list of Segment
        One per motion of the skill, in order.

    Raises
    ------
    InputError
        If the skill is in no graph, two events fall between the same two frames, or a gap is
        longer than ``max_gap``.
    """
    traj = demo.trajectory
    pos = traj.positions
    if max_gap is not None:
        # only the frames from the first to the last event are cut into segments (and checked
        # by the loader): a marker that enters the view late does not matter before that
        w0, _ = _frames(demo.events[0].time, demo.events[0].time, traj.rate, traj.n_frames)
        _, w1 = _frames(demo.events[-1].time, demo.events[-1].time, traj.rate, traj.n_frames)
        w0, w1 = min(w0, w1), max(w0, w1)
        try:
            pos = np.array(pos)
            pos[w0:w1 + 1] = fill_gaps(pos[w0:w1 + 1], max_gap)
        except InputError as exc:
            raise InputError(f"{demo.file}: {exc}") from None
    out = []
    for step in demo.skill.steps():
        a, b = demo.events[step.index], demo.events[step.index + 1]
        i0, i1 = _frames(a.time, b.time, traj.rate, traj.n_frames)
        if i1 - i0 < 1:
            raise InputError(
                f"{demo.file}: events {a.id!r} ({a.time:g} s) and {b.id!r} ({b.time:g} s) are "
                f"less than two frames apart at {traj.rate:g} Hz; no motion to cut between them"
            )
        piece = MarkerTrajectory(np.array(pos[i0:i1 + 1]), traj.marker_names, traj.rate,
                                 traj.units)
        out.append(Segment(demo, step.index, step.motion, graphs.arc_of(demo.skill, step.index),
                           a.time, b.time, piece))
    return out


def segment_dataset(dataset: Dataset, *, fill: bool = True) -> tuple[SkillGraphs, list[Segment]]:
    """Segment every demonstration of a dataset and register the pieces to arcs.

    Parameters
    ----------
    dataset : Dataset
    fill : bool
        Fill dropouts up to the dataset's gap limit before cutting.

    Returns
    -------
    graphs : SkillGraphs
        The skill graphs of the dataset's skills.
    segments : list of Segment
        Every segment, demonstration by demonstration, in motion order.
    """
    graphs = skill_graphs(dataset.poly, dataset.skills)
    segments: list[Segment] = []
    for d in dataset.demonstrations:
        segments.extend(segment_demonstration(
            d, graphs, max_gap=dataset.gap_limit if fill else None
        ))
    return graphs, segments


def segments_by_arc(segments: Sequence[Segment]) -> dict[ArcRef, list[Segment]]:
    """The segments registered to each arc, arcs in order of first appearance."""
    out: dict[ArcRef, list[Segment]] = {}
    for s in segments:
        out.setdefault(s.arc, []).append(s)
    return out
