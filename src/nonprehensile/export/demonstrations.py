"""A dataset's demonstrations as learning episodes (:class:`~.episodes.Episode`).

Each demonstration becomes one episode: its frames from the first to the last annotated event
(the part the dataset vouches for: the loader checks the markers there, and segmentation cuts
it into the skill's motions), short dropouts filled as segmentation fills them (a cubic spline
through the marker's samples, at most ``gap_limit`` frames), at the recording's own rate or
resampled to ``fps`` (linear for positions, spherical for the object's orientation; exact at
the recorded instants, so an ``fps`` dividing the rate keeps every value as recorded).

Per frame: the fingertips (the markers ``fingers`` names, ``R1``, ``R2``, ...), the object's
pose where the dataset tracks it (``rigid_body`` or ``object_markers``), every marker that
matters, the action (the next frame's fingertips), and the labels: the skill, the contact
event (its contact pairs, normalised: the same contacts are the same label in every skill)
and the arc ``skill: from -> to`` of the skill graph. The task is ``"skill: initial ->
final"``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from nonprehensile.demonstrations.dataset import Dataset, Demonstration
from nonprehensile.errors import InputError
from nonprehensile.export.episodes import (
    Episode,
    continuous_quaternions,
    episode_meta,
    resample_positions,
    resample_quaternions,
)
from nonprehensile.motion.trajectory import fill_gaps
from nonprehensile.skills.contacts import format_event, normalize_event
from nonprehensile.skills.skill import Skill

__all__ = ["arc_name", "dataset_episodes", "demonstration_episode", "event_name", "task_of"]

FloatArray = NDArray[np.float64]


def task_of(skill: Skill) -> str:
    """The task text of a skill's demonstrations: ``"push-roll: a:0 -> d:0"``."""
    return f"{skill.name}: {skill.initial} -> {skill.final}"


def arc_name(skill: str, source: str, target: str) -> str:
    """The label of an arc of a skill graph: ``"push-roll: touch -> pivot"``."""
    return f"{skill}: {source} -> {target}"


def event_name(poly: object, event: object) -> str:
    """The label of a contact event: its pairs in the paper's notation, normalised
    (``"(R1,f) ∧ (G,a)"``)."""
    return str(format_event(normalize_event(event, poly), "paper"))  # type: ignore[arg-type]


def _finger_order(fingers: Sequence[str]) -> list[str]:
    return sorted(fingers, key=lambda f: int(f[1:]))


def demonstration_episode(
    dataset: Dataset,
    demo: Demonstration,
    *,
    fps: float | None = None,
    with_object: bool = True,
) -> Episode:
    """One demonstration as an episode.

    Parameters
    ----------
    dataset : Dataset
        The dataset holding it (its fingers, scale, gap limit and object tracking).
    demo : Demonstration
    fps : float, optional
        Frame rate of the episode (default: the recording's).
    with_object : bool
        Include the object's pose (the dataset must track the object).

    Raises
    ------
    InputError
        The object is asked for but not tracked, or its pose has gaps longer than the gap
        limit between the first and the last event.
    """
    traj = demo.trajectory.to_units("m")
    rate = traj.rate
    fps = rate if fps is None else float(fps)
    gap = dataset.gap_limit
    t0, t1 = demo.events[0].time, demo.events[-1].time
    # the recorded frames from the first to the last event (events may fall between frames)
    i0 = max(0, math.floor(t0 * rate + 1e-6))
    i1 = min(traj.n_frames - 1, math.ceil(t1 * rate - 1e-6))
    window = slice(i0, i1 + 1)
    rec_t = np.arange(i0, i1 + 1) / rate
    n = max(1, math.floor((rec_t[-1] - rec_t[0]) * fps + 1e-6) + 1)
    at = rec_t[0] + np.arange(n) / fps
    where = f"{demo.file}"
    try:
        filled = fill_gaps(traj.positions[window], gap)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    markers = resample_positions(rec_t, filled, at)
    names = traj.marker_names
    fingers = _finger_order(list(dataset.fingers))
    tips = np.stack([markers[:, names.index(dataset.fingers[f])] for f in fingers], axis=1)
    action = np.concatenate([tips[1:], tips[-1:]], axis=0)
    pose = None
    if with_object:
        setup = dataset.object_setup
        if setup is None:
            raise InputError(
                f"{dataset.root or 'the dataset'}: the object is not tracked (the annotations "
                "have no 'rigid_body' or 'object_markers'), so the export has no object pose "
                "for observation.state; track it, or export the fingertips only (--no-object)")
        body = setup.pose(demo.trajectory, dataset.scale)
        pos_w, quat_w = body.positions[window], body.quaternions[window]
        bad = ~np.isfinite(pos_w).all(axis=1) | ~np.isfinite(quat_w).all(axis=1)
        if bad.any():
            body = body.filled(gap)
            pos_w, quat_w = body.positions[window], body.quaternions[window]
            bad = ~np.isfinite(pos_w).all(axis=1) | ~np.isfinite(quat_w).all(axis=1)
        if bad.any():
            k = int(np.flatnonzero(bad)[0]) + i0
            raise InputError(
                f"{where}: the object's pose ({body.name!r}) is missing at frame {k} "
                f"({k / rate:.3f} s) for longer than the gap limit of {gap} frames; crop the "
                "take, raise 'gap_limit', or export the fingertips only (--no-object)")
        pose = np.concatenate([resample_positions(rec_t, pos_w, at),
                               resample_quaternions(rec_t, continuous_quaternions(quat_w), at)],
                              axis=1)
    skill = demo.skill
    ev_names = tuple(dict.fromkeys(event_name(dataset.poly, e) for e in skill.events))
    ev_of = [ev_names.index(event_name(dataset.poly, e)) for e in skill.events]
    arcs = tuple(arc_name(skill.name, a.id, b.id)
                 for a, b in zip(skill.events[:-1], skill.events[1:], strict=True))
    times = demo.event_times
    j = np.searchsorted(times, at + 1e-9, side="right") - 1  # last event at or before
    event = np.where(j >= 0, np.asarray(ev_of)[np.clip(j, 0, None)], -1)
    arc = np.where((j >= 0) & (j < len(times) - 1), j, -1)
    meta = episode_meta(
        skill=skill.name, mentor=demo.mentor, initial=str(demo.initial),
        final=str(demo.final), maneuver=skill.maneuver, source=demo.file,
        source_frame=i0, source_rate=rate, success=None,
    )
    return Episode(
        task=task_of(skill), fps=fps, fingertips=tips, action=action,
        finger_names=tuple(fingers), object_pose=pose, markers=markers,
        marker_names=tuple(names), skill_names=(skill.name,),
        skill=np.zeros(n, np.int64), event_names=ev_names, event=event.astype(np.int64),
        arc_names=arcs, arc=arc.astype(np.int64), meta=meta,
    )


def dataset_episodes(
    dataset: Dataset,
    *,
    fps: float | None = None,
    with_object: bool | None = None,
) -> list[Episode]:
    """Every demonstration of ``dataset`` as an episode, in annotations order.

    Parameters
    ----------
    dataset : Dataset
    fps : float, optional
        Frame rate (default: the recordings' rate, which must then be one rate for all).
    with_object : bool, optional
        Include the object's pose: True requires it (an untracked dataset is an error), False
        leaves it out, None (default) includes it when the dataset tracks the object.

    Raises
    ------
    InputError
        No demonstration; recordings at several rates without ``fps``; an ``fps`` that makes
        more than :data:`MAX_RESAMPLED_FRAMES` frames (and more than were recorded); the
        object asked for and not tracked.
    """
    if not dataset.demonstrations:  # said of the dataset, not of the export folder
        raise InputError(f"{dataset.root or 'the dataset'}: the dataset has no demonstration, "
                         "so there is no episode to export; add recordings to its annotations")
    if with_object is None:
        with_object = dataset.object_setup is not None
    rates = sorted({d.trajectory.rate for d in dataset.demonstrations})
    if fps is None and len(rates) > 1:
        raise InputError(f"{dataset.root or 'the dataset'}: its recordings have several rates "
                         f"{rates} Hz; give one frame rate for the export (--fps)")
    if fps is not None:
        _check_export_size(dataset, fps)
    return [demonstration_episode(dataset, d, fps=fps, with_object=with_object)
            for d in dataset.demonstrations]


#: The most frames an export resampled above its recordings' frame count may hold: writing
#: takes about 1 kB of memory a frame (measured: 525,674 frames at --fps 20000, 600 MB), and
#: --fps 100000 asked 40 million of the bundled dataset's 45,000 recorded frames.
MAX_RESAMPLED_FRAMES = 5_000_000


def _window_frames(demo: Demonstration, rate: float) -> tuple[int, float]:
    """The recorded frames from the first to the last event, and the time they span."""
    t0, t1 = demo.events[0].time, demo.events[-1].time
    i0 = max(0, math.floor(t0 * rate + 1e-6))
    i1 = min(demo.trajectory.n_frames - 1, math.ceil(t1 * rate - 1e-6))
    return i1 - i0 + 1, (i1 - i0) / rate


def _check_export_size(dataset: Dataset, fps: float) -> None:
    """Refuse an ``fps`` whose frames would exhaust memory (before any is made)."""
    recorded = made = 0
    for d in dataset.demonstrations:
        n, span = _window_frames(d, d.trajectory.rate)
        recorded += n
        made += max(1, math.floor(span * fps + 1e-6) + 1)
    if made > max(MAX_RESAMPLED_FRAMES, recorded):
        rates = sorted({d.trajectory.rate for d in dataset.demonstrations})
        raise InputError(
            f"{dataset.root or 'the dataset'}: --fps {fps:g} makes {made:,} frames of its "
            f"{recorded:,} recorded ones (at {', '.join(f'{r:g}' for r in rates)} Hz), more "
            f"than {MAX_RESAMPLED_FRAMES:,} (writing takes about 1 kB of memory a frame); give "
            "a lower --fps: resampling above the recording rate adds no measurement")
