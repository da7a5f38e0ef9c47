"""Reference finger motions from clustered demonstrations (paper Section VII, step 4).

Segments of the demonstrations (:mod:`nonprehensile.demonstrations.segment`) are registered to
the arcs of the skill graphs and clustered by their motion. For a skill's arc the reference
motion is the medoid of the cluster that holds most of that skill's segments on that arc: a
real demonstration, not an average, so it is a motion a mentor actually made.

This module is the edge that joins the motion model (:mod:`nonprehensile.motion`, which knows
trajectories and clusters only), the demonstrations and the planner: neither the motion model
nor the planner imports the other.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nonprehensile.demonstrations.dataset import Dataset
from nonprehensile.demonstrations.segment import Segment
from nonprehensile.errors import InputError
from nonprehensile.motion.trajectory import preprocess_many
from nonprehensile.planning import ReferenceMotion

__all__ = ["ClusteredMotions", "flatten_demonstrations", "flatten_segments", "medoid"]

FloatArray = NDArray[np.float64]


def flatten_segments(segments: Sequence[Segment], n_points: int = 400) -> FloatArray:
    """The paper's flattened vectors of segments (resampled to ``n_points``).

    Returns
    -------
    array, shape (n_segments, n_points * n_markers * 3)
    """
    if not segments:
        raise InputError("no segment to flatten")
    trajs = [s.trajectory for s in segments]
    return preprocess_many([t.positions for t in trajs], [t.rate for t in trajs],
                           max_gap=[t.n_frames for t in trajs], n_points=n_points)


def flatten_demonstrations(ds: Dataset) -> tuple[FloatArray, list[str]]:
    """The flattened vectors of whole demonstrations, first to last event, and their skills.

    Returns
    -------
    rows : array, shape (n_demonstrations, n_features)
        One row per demonstration (:func:`~nonprehensile.motion.trajectory.preprocess`, with
        the dataset's gap limit).
    skills : list of str, length n_demonstrations
        The skill each demonstration shows.
    """
    if not ds.demonstrations:
        raise InputError("the dataset has no demonstration")
    demos = ds.demonstrations
    rows = preprocess_many([d.trajectory.positions for d in demos],
                           [d.trajectory.rate for d in demos],
                           windows=[(d.events[0].time, d.events[-1].time) for d in demos],
                           max_gap=ds.gap_limit)
    return rows, [d.skill.name for d in demos]


def medoid(x: FloatArray) -> int:
    """Index of the row with the least total Euclidean distance to the others.

    Parameters
    ----------
    x : array, shape (n_samples, n_features)
    """
    sq = np.einsum("ij,ij->i", x, x)
    d2 = np.maximum(sq[:, None] + sq[None, :] - 2.0 * (x @ x.T), 0.0)
    return int(np.argmin(np.sqrt(d2).sum(axis=1)))


@dataclass(frozen=True)
class ClusteredMotions:
    """Segments with their cluster labels; a :class:`~nonprehensile.planning.MotionLibrary`.

    Attributes
    ----------
    segments : sequence of Segment
    labels : array of int, shape (n_segments,)
        Cluster of each segment (clusters are per arc of the skill graph: the same number on
        two arcs names two clusters).
    vectors : array, shape (n_segments, n_features)
        The flattened vectors the clusters were computed on (for the medoid).
    """

    segments: Sequence[Segment]
    labels: NDArray[np.int64]
    vectors: FloatArray

    def __post_init__(self) -> None:
        if not len(self.segments) == len(self.labels) == len(self.vectors):
            raise InputError(
                f"segments, labels and vectors must have the same length, got "
                f"{len(self.segments)}, {len(self.labels)}, {len(self.vectors)}"
            )

    def _rows(self, skill: str, source: str, target: str) -> list[int]:
        return [
            i for i, s in enumerate(self.segments)
            if s.skill == skill and (s.motion.source, s.motion.target) == (source, target)
        ]

    def clusters_of(self, skill: str, source: str, target: str) -> Mapping[int, int]:
        """How many of the skill's segments on that arc fall in each cluster."""
        return dict(Counter(int(self.labels[i]) for i in self._rows(skill, source, target)))

    def reference(self, skill: str, source: str, target: str) -> ReferenceMotion | None:
        """The medoid of the skill's main cluster on the arc ``source -> target``.

        Positions are in metres, in the frame of the skill's demonstrated initial state.
        Each arc's reference is computed once and kept (a medoid costs a distance matrix, and
        a closed loop's re-plans ask for the same arcs again and again).
        """
        # (in the instance's __dict__, not a field: a value is equal to another whatever it
        # has been asked, and a library unpickled from an older cache has no memo yet)
        memo: dict[tuple[str, str, str], ReferenceMotion | None] = \
            self.__dict__.setdefault("_reference_memo", {})
        key = (skill, source, target)
        if key not in memo:
            memo[key] = self._reference(skill, source, target)
        return memo[key]

    def _reference(self, skill: str, source: str, target: str) -> ReferenceMotion | None:
        rows = self._rows(skill, source, target)
        if not rows:
            return None
        counts = Counter(int(self.labels[i]) for i in rows)
        top = max(counts, key=lambda c: (counts[c], -c))
        members = [i for i in rows if self.labels[i] == top]
        best = members[medoid(self.vectors[members])]
        traj = self.segments[best].trajectory.to_units("m")
        return ReferenceMotion(
            np.asarray(traj.positions), tuple(traj.marker_names), traj.rate, top, len(members)
        )
