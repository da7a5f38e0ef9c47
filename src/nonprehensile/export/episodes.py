"""Episodes for robot-learning datasets: what was observed at each frame, and its labels.

A learning library (LeRobot, and the policies trained on it: ACT, diffusion policy, pi0) reads
a dataset as *episodes*, each a sequence of frames at a constant rate with an observation, an
action and a task. This module turns what the project has into such episodes, independent of
any file format (:mod:`nonprehensile.export.lerobot` writes them):

* a demonstration of a dataset (:func:`dataset_episodes`): the fingertips' markers, the
  object's pose where the dataset tracks it, every marker that matters, the demonstrated skill
  and the contact event and arc (the skill graph's motion) of every frame;
* a simulated execution (built in :mod:`nonprehensile.sim.episodes` from the simulator's
  trace): the fingertips and the object as physics moved them, the fingertip targets the
  executor sent, and the contact events physics produced.

Conventions
-----------
Positions are metres in the world frame (z up, the table at z = 0). The object's pose is the
pose of the object model's frame (scaled by the dataset's ``scale``): position ``x, y, z`` and
quaternion ``qx, qy, qz, qw`` (scalar last, as scipy and ROS write it), normalised, the
first frame's with ``qw >= 0`` and every next one on the side of its predecessor (q and -q
are the same rotation; a sign jump would look like a large motion to a learner). The action
of frame ``i`` is where the fingertips are sent next: the
fingertips of frame ``i + 1`` for a demonstration (the last frame holds its own), the
executor's targets for a simulated execution.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError

__all__ = [
    "Episode",
    "check_new_folder",
    "continuous_quaternions",
    "resample_positions",
    "resample_quaternions",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Episode metadata values a file format can store: plain scalars (None: unknown).
MetaValue = str | int | float | bool | None


@dataclass(frozen=True, eq=False)
class Episode:
    """One episode: frames at a constant rate, each observed, acted on and labelled.

    Attributes
    ----------
    task : str
        What the episode does, for a person and a task-conditioned policy
        (``"push-roll: a:0 -> d:0"``).
    fps : float
        Frames per second.
    fingertips : array, shape (n_frames, n_fingers, 3)
        The fingertips' positions, metres.
    action : array, shape (n_frames, n_fingers, 3)
        The fingertip targets of each frame, metres.
    finger_names : tuple of str
        The fingers in order (``"R1"``, ``"R2"``: the skill model's names).
    object_pose : array, shape (n_frames, 7), or None
        ``x, y, z, qx, qy, qz, qw``: the object model frame's pose; None when not tracked.
    markers : array, shape (n_frames, n_markers, 3), or None
        Every marker that matters, metres (demonstrations); None for simulated executions.
    marker_names : tuple of str
    skill_names, event_names, arc_names : tuple of str
        The labels this episode uses; ``skill``, ``event`` and ``arc`` index them.
    skill, event, arc : array of int, shape (n_frames,)
        Per frame: the skill being executed, the contact event the frame is in (the last
        one at or before it), the arc (motion between two events) it belongs to; -1: none.
    meta : mapping of str to scalar
        Per-episode facts (skill, mentor, initial and final states, success, source file).
    """

    task: str
    fps: float
    fingertips: FloatArray
    action: FloatArray
    finger_names: tuple[str, ...]
    object_pose: FloatArray | None = None
    markers: FloatArray | None = None
    marker_names: tuple[str, ...] = ()
    skill_names: tuple[str, ...] = ()
    skill: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    event_names: tuple[str, ...] = ()
    event: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    arc_names: tuple[str, ...] = ()
    arc: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    meta: Mapping[str, MetaValue] = field(default_factory=dict)

    def __post_init__(self) -> None:
        tips = np.asarray(self.fingertips, dtype=np.float64)
        n = len(tips)
        if tips.ndim != 3 or tips.shape[2] != 3 or n < 1 or tips.shape[1] != len(
                self.finger_names) or not self.finger_names:
            raise InputError(f"episode {self.task!r}: fingertips must have shape (n_frames >= 1, "
                             f"{len(self.finger_names)} fingers, 3), got {tips.shape}")
        act = np.asarray(self.action, dtype=np.float64)
        if act.shape != tips.shape:
            raise InputError(f"episode {self.task!r}: action must have the fingertips' shape "
                             f"{tips.shape}, got {act.shape}")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise InputError(f"episode {self.task!r}: fps must be positive, got {self.fps!r}")
        arrays: dict[str, Any] = {"fingertips": tips, "action": act}
        if self.object_pose is not None:
            pose = np.asarray(self.object_pose, dtype=np.float64)
            if pose.shape != (n, 7):
                raise InputError(f"episode {self.task!r}: object_pose must have shape ({n}, 7), "
                                 f"got {pose.shape}")
            arrays["object_pose"] = pose
        if self.markers is not None:
            mk = np.asarray(self.markers, dtype=np.float64)
            if mk.shape != (n, len(self.marker_names), 3):
                raise InputError(f"episode {self.task!r}: markers must have shape ({n}, "
                                 f"{len(self.marker_names)}, 3), got {mk.shape}")
            arrays["markers"] = mk
        for name, arr in arrays.items():
            if not np.isfinite(arr).all():
                bad = int(np.flatnonzero(~np.isfinite(arr.reshape(n, -1)).all(axis=1))[0])
                raise InputError(f"episode {self.task!r}: {name} is not finite at frame {bad} "
                                 "(fill or crop the gaps first)")
            object.__setattr__(self, name, arr)
        for key, names in (("skill", self.skill_names), ("event", self.event_names),
                           ("arc", self.arc_names)):
            lab = np.asarray(getattr(self, key), dtype=np.int64)
            if lab.size == 0:
                lab = np.full(n, -1, np.int64)
            if lab.shape != (n,) or (lab < -1).any() or (lab >= len(names)).any():
                raise InputError(f"episode {self.task!r}: {key} labels must be {n} indices into "
                                 f"{len(names)} names (or -1)")
            object.__setattr__(self, key, lab)

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return int(self.fingertips.shape[0])

    @property
    def timestamps(self) -> FloatArray:
        """Seconds from the episode's first frame, shape (n_frames,): ``i / fps``."""
        return np.arange(self.n_frames, dtype=np.float64) / self.fps


def continuous_quaternions(quat: FloatArray) -> FloatArray:
    """Quaternions ``(x, y, z, w)`` normalised, the first with ``w >= 0`` and each next one on
    the same side as its predecessor (shape (n, 4) in and out)."""
    q: FloatArray = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    if len(q) == 0:
        return q
    flip = np.ones(len(q))
    flip[0] = -1.0 if q[0, 3] < 0 else 1.0
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    # the sign of frame i relative to frame i-1, accumulated
    flip[1:] = np.where(dots < 0, -1.0, 1.0)
    out: FloatArray = q * np.cumprod(flip)[:, None]
    return out


def resample_positions(times: FloatArray, values: FloatArray, at: FloatArray) -> FloatArray:
    """Linear interpolation of ``values`` (shape (n, ...)) sampled at ``times`` (increasing)
    at the times ``at``; exact at the sample times."""
    v = np.asarray(values, dtype=np.float64)
    flat = v.reshape(len(v), -1)
    out = np.column_stack([np.interp(at, times, flat[:, j]) for j in range(flat.shape[1])])
    return out.reshape((len(at), *v.shape[1:]))


def resample_quaternions(times: FloatArray, quat: FloatArray, at: FloatArray) -> FloatArray:
    """Spherical linear interpolation of quaternions ``(x, y, z, w)`` (shape (n, 4)) sampled
    at ``times`` at the times ``at`` (clamped to the ends); exact at the sample times."""
    q = continuous_quaternions(quat)
    t = np.asarray(times, dtype=np.float64)
    at = np.clip(np.asarray(at, dtype=np.float64), t[0], t[-1])
    j = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2) if len(t) > 1 else (
        np.zeros(len(at), np.int64))
    if len(t) == 1:
        return np.repeat(q, len(at), axis=0)
    u = (at - t[j]) / (t[j + 1] - t[j])
    a, b = q[j], q[j + 1]
    dot = np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)
    ang = np.arccos(dot)
    small = ang < 1e-9
    s = np.sin(ang)
    with np.errstate(invalid="ignore", divide="ignore"):
        wa = np.where(small, 1.0 - u, np.sin((1.0 - u) * ang) / s)
        wb = np.where(small, u, np.sin(u * ang) / s)
    out = wa[:, None] * a + wb[:, None] * b
    return continuous_quaternions(out)


def label_index(names: Sequence[str]) -> dict[str, int]:
    """Name -> index of a label list."""
    return {n: i for i, n in enumerate(names)}


def episode_meta(**values: Any) -> dict[str, MetaValue]:
    """Metadata with every value a plain scalar (numbers as Python numbers)."""
    out: dict[str, MetaValue] = {}
    for k, v in values.items():
        if isinstance(v, np.generic):
            v = v.item()
        if v is not None and not isinstance(v, (str, int, float, bool)):
            v = str(v)
        out[k] = v
    return out


def summarize(episodes: Sequence[Episode]) -> dict[str, Any]:
    """Counts of a list of episodes (for the command line)."""
    return {"n_episodes": len(episodes), "n_frames": int(sum(e.n_frames for e in episodes)),
            "tasks": sorted({e.task for e in episodes})}


def check_fps(fps: object) -> float | None:
    """``None`` or a positive finite number of frames per second."""
    if fps is None:
        return None
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not np.isfinite(fps) or (
            fps <= 0):
        raise InputError(f"fps must be a positive number of frames per second, got {fps!r}")
    return float(fps)


def check_new_folder(out_dir: str | Path, what: str = "the export folder") -> Path:
    """A folder an export may create: one that does not exist, in a folder that can be written.

    Checked before the slow part (loading a dataset, simulating), so that a bad path costs
    nothing.

    Parameters
    ----------
    out_dir : str or Path
        The folder to create.
    what : str
        What the folder is, for the message (``"the --record folder"``).

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    InputError
        The folder exists, or the nearest existing folder above it is a file or cannot be
        written.
    """
    root = Path(out_dir)
    if os.path.lexists(root):  # (a symbolic link too, even one to nothing)
        raise InputError(f"{root}: {what} exists; give a new folder (a LeRobot dataset is "
                         "written whole, never into or over another)")
    up = root.absolute().parent
    while not up.exists() and up != up.parent:
        up = up.parent
    if not up.is_dir():
        raise InputError(f"{root}: cannot create {what}: {up} is a file, not a folder; give a "
                         "new folder inside a folder")
    if not os.access(up, os.W_OK | os.X_OK):
        raise InputError(f"{root}: cannot create {what}: the folder {up} is not writable; give "
                         "a new folder inside a folder you can write to")
    return root
