"""Skill names from motion: the motion model breaks the ties of automatic annotation.

Two skills may have the same contact events and states and differ only in the finger motion
(the paper's Fig. 5, skills 2 and 3: roll-arc and roll-pull; Fig. 9: tumble-lift and
tumble-twist). Contact events cannot tell them apart; the motion model can (Section VI: the
clusters of Fig. 12). :class:`MotionNamer` holds a motion library (a dataset whose
demonstrations name their skill: the bundled ``cube`` or any folder), segmented and
clustered as the main job clusters it (:func:`~nonprehensile.pipeline.cluster_segments`, one
incremental Hilbert-curve clusterer per arc, asked for as many clusters as skills share the
arc). A recording whose annotation is tied is cut at the events found, each piece registered
to its arc of the skill graph, flattened as the library's pieces are, and placed by the arc's
clusterer (``predict``: the cluster its key falls in). Each arc votes for the tied skills in
proportion to their share of the library's pieces in that cluster (a cluster holding only
roll-pull pieces gives roll-pull one vote; a cluster both skills share, half each); the skill
with the most votes is named when it leads the next by ``margin`` votes or more, otherwise the
tie stays, with the scores, as a doubt: the motion is ambiguous too.

Before the pieces are compared the recording is brought into the library's frame: the
object's pose at the start (tracked: the annotation needs it) is moved onto the skill's
initial state as ``state_pose`` puts it (centre of mass above the origin), the frame every
dataset's recordings are calibrated to (``docs/dataset.md``), and its markers are those of
the library (by name), in the library's units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from nonprehensile.demonstrations.annotate import RecordingAnnotation, canonical_recording
from nonprehensile.demonstrations.dataset import Dataset, Demonstration
from nonprehensile.demonstrations.record import MarkerTrajectory, PoseTrajectory
from nonprehensile.demonstrations.segment import ArcRef, segment_dataset, segment_demonstration
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.pipeline import cluster_segments
from nonprehensile.references import flatten_segments
from nonprehensile.skills.contacts import ContactEvent

__all__ = ["TIE_DOUBT", "MotionNamer"]

FloatArray = NDArray[np.float64]

#: The words of the doubt :func:`~nonprehensile.demonstrations.annotate.annotate_recording`
#: lists for skills tied on their events and states.
TIE_DOUBT = "differ in their finger motion only"


@dataclass(frozen=True)
class _ArcClusters:
    clusterer: Any
    labels: NDArray[np.int64]  # the clusterer's own ids of the library's pieces
    skills: tuple[str, ...]  # the skill of each piece


class MotionNamer:
    """Names the skill of a tied annotation from the motion (see the module notes).

    Parameters
    ----------
    library : Dataset
        Demonstrations naming their skill (the bundled ``cube``, or a folder).
    seed : int
        The clusterers' seed (the main job's default).
    margin : float
        Votes by which the named skill must lead the next (one vote: one arc whose cluster
        holds that skill's pieces only).

    Attributes
    ----------
    skills : tuple of str
        The skills the library demonstrates.
    markers : tuple of str
        The markers its pieces are flattened from (a recording must have them).
    """

    def __init__(self, library: Dataset, *, seed: int = 0, margin: float = 0.5) -> None:
        if not library.demonstrations:
            raise InputError("the motion library has no demonstrations")
        self.library = library
        self.margin = float(margin)
        self.graphs, segments = segment_dataset(library)
        _, arcs = cluster_segments(segments, seed=seed)
        first = segments[0].trajectory
        self.units = first.units
        self.markers: tuple[str, ...] = tuple(first.marker_names)
        self.skills: tuple[str, ...] = tuple(dict.fromkeys(s.skill for s in segments))
        self._arcs: dict[ArcRef | tuple[Any, ...], _ArcClusters] = {}
        for a in arcs:
            if a["clusterer"] is None:  # too few pieces on the arc to cluster
                continue
            rows = a["rows"]
            ref = segments[rows[0]].arc
            self._arcs[(ref.group, ref.source, ref.target)] = _ArcClusters(
                a["clusterer"], np.asarray(a["clusterer"].labels_, dtype=np.int64),
                tuple(segments[i].skill for i in rows))

    def votes(
        self, poly: Polyhedron, traj: MarkerTrajectory, pose: PoseTrajectory,
        result: RecordingAnnotation, scale: float, gap: int,
    ) -> dict[str, float]:
        """Each tied skill's votes from the arcs of the recording.

        Raises
        ------
        InputError
            The library lacks a tied skill or a marker, or the recording cannot be cut.
        """
        cands = list(result.candidates)
        missing = [c for c in cands if c not in self.skills]
        if missing:
            raise InputError(f"the motion library has no demonstrations of {missing}")
        absent = [m for m in self.markers if m not in traj.marker_names]
        if absent:
            raise InputError(f"the recording lacks the library's marker(s) {absent}")
        skill = self.library.skill(cands[0])
        assert result.initial is not None
        moved = canonical_recording(poly, traj, pose, result.initial, scale, gap,
                                    self.markers).to_units(self.units)
        demo = Demonstration("take", skill, "take", skill.initial, skill.final, result.events,
                             moved)
        segs = segment_demonstration(demo, self.graphs, max_gap=gap)
        vectors = flatten_segments(segs)
        score = dict.fromkeys(cands, 0.0)
        for seg, v in zip(segs, vectors, strict=True):
            arc = self._arcs.get((seg.arc.group, seg.arc.source, seg.arc.target))
            if arc is None:
                continue
            c = int(arc.clusterer.predict(v[None, :])[0])
            members = [s for s, lab in zip(arc.skills, arc.labels.tolist(), strict=True)
                       if lab == c and s in score]
            for s in set(members):
                score[s] += members.count(s) / len(members)
        return score

    def name(
        self, poly: Polyhedron, skills: Sequence[Any], traj: MarkerTrajectory,
        pose: PoseTrajectory, result: RecordingAnnotation, scale: float, gap: int,
    ) -> RecordingAnnotation:
        """The annotation with its tie broken by the motion, or kept with a doubt saying why.

        ``skills`` are the dataset's skills (the named one's events become the chain).
        """
        if len(result.candidates) < 2 or result.initial is None:
            return result
        try:
            score = self.votes(poly, traj, pose, result, scale, gap)
        except InputError as exc:
            return replace(result, doubts=(*result.doubts,
                                           f"the motion model could not be asked: {exc}"))
        ranked = sorted(score.items(), key=lambda kv: -kv[1])
        shown = ", ".join(f"{k} {v:.2f}" for k, v in ranked)
        best, top = ranked[0]
        second = ranked[1][1]
        if top - second < self.margin:
            return replace(result, doubts=(*result.doubts,
                                           f"the motion model does not tell them apart either "
                                           f"(votes: {shown})"))
        sk = next(s for s in skills if s.name == best)
        doubts = tuple(d for d in result.doubts if TIE_DOUBT not in d)
        return replace(result, chain=tuple(ContactEvent(e.id, e.pairs) for e in sk.events),
                       skill=best, initial=sk.initial, final=sk.final, doubts=doubts)
