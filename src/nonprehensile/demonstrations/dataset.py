"""Demonstration datasets: a folder of recordings plus an annotations file (paper Section VI).

A dataset is a folder holding one marker-trajectory file per demonstration (C3D or OptiTrack
Motive CSV), the skills file the demonstrations realise, and an annotations file
(``annotations.json`` or ``annotations.yaml``) that says, for each file, which skill was
demonstrated, by which mentor, between which states, and at which times the skill's contact
events happened. The layout is specified in ``docs/dataset.md``.

Loading is all or nothing: :func:`load_dataset` checks every demonstration, collects every
problem (unknown skill, event times out of range or out of order, events that do not match the
skill's chain, markers missing for longer than the gap limit, NaN, unreadable files) and
raises one :class:`~nonprehensile.errors.DemonstrationError` listing them all, by file and
demonstration, so that a user fixes a dataset in one pass and never works on half of it.
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from nonprehensile.demonstrations.axes import (
    AXES_PRESETS,
    DEFAULT_AXES,
    axes_matrix,
    axes_to_dict,
    parse_axes,
)
from nonprehensile.demonstrations.formats import (
    read_c3d,
    read_motive_csv,
    write_c3d,
    write_motive_csv,
)
from nonprehensile.demonstrations.record import MarkerTrajectory, PoseTrajectory
from nonprehensile.demonstrations.rosbag import RosSetup, is_rosbag, parse_ros_setup, read_rosbag
from nonprehensile.demonstrations.tracking import ObjectSetup, object_setup, parse_rigid_body
from nonprehensile.errors import DemonstrationError, InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.io import load_document, read_skills, save_document, skills_to_dict
from nonprehensile.skills.contacts import Finger
from nonprehensile.skills.skill import Skill
from nonprehensile.states import DEFAULT_ANGLE_TOL, State, state_pose

__all__ = [
    "ANNOTATION_FILES",
    "BUNDLED_DATASETS",
    "DATASET_FORMAT",
    "DEFAULT_FINGERS",
    "DEFAULT_GAP_LIMIT",
    "DEFAULT_MARKERS",
    "DEFAULT_TOLERANCE_MM",
    "SCALE_RANGE",
    "Dataset",
    "Demonstration",
    "EventTime",
    "Problem",
    "bundled_path",
    "check_dataset",
    "dataset_path",
    "dataset_summary",
    "headed",
    "load_dataset",
    "not_checked",
    "save_dataset",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int], None]

#: The value of the annotations' ``format`` key.
DATASET_FORMAT = "nonprehensile-demonstrations/1"
#: Farthest a marker may be from the recording's origin, metres: beyond any motion-capture
#: volume (a take read in metres where its numbers are millimetres lands a kilometre away).
MAX_CAPTURE_M = 100.0
#: Fastest a take's markers may move, m/s: the median over its markers of each one's 90th
#: percentile frame-to-frame speed. A hand's markers move at 0.1-3 m/s by it (walking
#: subjects' markers in the C3D files of five vendors: at most 2.7 m/s), read in metres where
#: the numbers are millimetres at 100-3000 m/s. A
#: percentile, not the largest: a marker swapped for a ghost jumps a metre in one frame of a
#: real take; the median over markers: one marker swapping in many frames does not count.
MAX_MARKER_SPEED = 50.0
#: Names the annotations file may have in a dataset folder, tried in this order.
ANNOTATION_FILES = ("annotations.json", "annotations.yaml", "annotations.yml")
#: Datasets shipped inside the package, by name (folder ``data/<name>_demos``).
BUNDLED_DATASETS = ("cube",)
#: The four markers of the paper's Fig. 11: tips and knuckles of index finger and thumb.
DEFAULT_MARKERS = ("index_tip", "index_knuckle", "thumb_tip", "thumb_knuckle")
#: Which marker stands for each finger's contact point: R1 is the index, R2 the thumb.
DEFAULT_FINGERS: Mapping[str, str] = {"R1": "index_tip", "R2": "thumb_tip"}
#: Longest run of missing frames per marker that a loader accepts (0.1 s at 120 Hz); longer
#: dropouts cannot be filled faithfully by interpolation.
DEFAULT_GAP_LIMIT = 12
#: Smallest and largest 'scale', metres per model unit: a model in micrometres to a model whose
#: unit is 100 m (beyond them, positions scaled by it overflow or vanish).
SCALE_RANGE = (1e-6, 100.0)
#: How far (mm) a fingertip marker may dip below the table, or an object marker stray from
#: where the model puts it, before the recording is reported: a marker's own radius and a
#: careful calibration's error.
DEFAULT_TOLERANCE_MM = 10.0
#: Units the annotations' ``units`` may name: our units and the factor that converts to them.
_UNITS: dict[str, tuple[Literal["m", "mm"], float]] = {
    "m": ("m", 1.0), "mm": ("mm", 1.0), "cm": ("mm", 10.0)}

# the readers return the file's own axes (up="z" transforms nothing); the annotations' axes
# are applied after, so that any convention, preset or explicit, is one matrix
_READERS: dict[str, Callable[[Path], MarkerTrajectory]] = {
    ".c3d": lambda p: read_c3d(p, up="z"),
    ".csv": lambda p: read_motive_csv(p, up="z"),
}
_FINGER_RE = re.compile(r"R\d+")
_TOP_KEYS = {"format", "skills", "scale", "gap_limit", "fingers", "markers", "object_markers",
             "rigid_body", "axes", "units", "tolerance_mm", "ros", "demonstrations"}
_DEMO_KEYS = {"file", "skill", "mentor", "initial", "final", "events"}


@dataclass(frozen=True)
class EventTime:
    """When a contact event of a skill happened in a recording.

    Attributes
    ----------
    id : str
        The event's ID in the skill (e.g. ``"pivot"``).
    time : float
        Seconds from the recording's first frame.
    """

    id: str
    time: float


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a dataset.

    Attributes
    ----------
    file : str
        The file at fault (the annotations file, or a trajectory file), relative to the
        dataset folder where it is inside it.
    demonstration : int or None
        Index of the demonstration in the annotations (0-based), None for dataset-wide ones.
    message : str
        What is wrong and how to fix it.
    """

    file: str
    demonstration: int | None
    message: str

    def __str__(self) -> str:
        where = f" (demonstration {self.demonstration})" if self.demonstration is not None else ""
        return f"{self.file}{where}: {self.message}"

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form."""
        return {"file": self.file, "demonstration": self.demonstration, "message": self.message}


@dataclass(frozen=True, eq=False)
class Demonstration:
    """One demonstration: a recording of a mentor performing a skill, cut by its events.

    Attributes
    ----------
    file : str
        The trajectory file, relative to the dataset folder.
    skill : Skill
        The demonstrated skill.
    mentor : str
        Who demonstrated it.
    initial, final : State
        The object's initial and final states (those of the skill).
    events : tuple of EventTime
        The skill's contact events in chain order with the times they happened, strictly
        increasing, within the recording.
    trajectory : MarkerTrajectory
        The named marker trajectories, shape (n_frames, n_markers, 3), NaN where occluded.
    """

    file: str
    skill: Skill
    mentor: str
    initial: State
    final: State
    events: tuple[EventTime, ...]
    trajectory: MarkerTrajectory

    @property
    def event_times(self) -> FloatArray:
        """Event times in seconds, array, shape (n_events,)."""
        return np.array([e.time for e in self.events], dtype=np.float64)

    @property
    def duration(self) -> float:
        """From the first to the last event, seconds."""
        return self.events[-1].time - self.events[0].time

    def to_dict(self) -> dict[str, Any]:
        """The annotations' form of this demonstration."""
        return {
            "file": self.file,
            "skill": self.skill.name,
            "mentor": self.mentor,
            "initial": self.initial.to_dict(),
            "final": self.final.to_dict(),
            "events": [{"id": e.id, "time": e.time} for e in self.events],
        }


@dataclass(frozen=True, eq=False)
class Dataset:
    """A loaded, fully checked demonstration dataset.

    Attributes
    ----------
    poly : Polyhedron
        The object model of the skills file.
    skills : tuple of Skill
        The skills of the skills file.
    demonstrations : tuple of Demonstration
        Every demonstration, in annotations order.
    scale : float
        Metres per model unit: the demonstrated object is ``poly`` scaled by it (the bundled
        cube model has edges of 1; the demonstrated cube, 0.05 m).
    gap_limit : int
        Longest accepted run of missing frames per marker.
    fingers : dict of str to str
        Finger element (``"R1"``, ``"R2"``, ...) to the name of the marker at its tip.
    root : Path or None
        The folder it was loaded from.
    object_markers : dict of str to (float, float, float)
        Markers fixed on the object: name -> position in the model's frame, model units
        (times ``scale``: metres). Empty when the object is not tracked.
    notes : tuple of str
        What the loader noticed without refusing the dataset (markers it ignored).
    rigid_body : str, dict or None
        The annotations' ``rigid_body``: the rigid body (of every recording) that tracks the
        object (:func:`~nonprehensile.demonstrations.tracking.parse_rigid_body`); None when
        the object is not tracked as a rigid body.
    """

    poly: Polyhedron
    skills: tuple[Skill, ...]
    demonstrations: tuple[Demonstration, ...]
    scale: float = 1.0
    gap_limit: int = DEFAULT_GAP_LIMIT
    fingers: Mapping[str, str] = field(default_factory=lambda: dict(DEFAULT_FINGERS))
    root: Path | None = None
    object_markers: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    rigid_body: str | Mapping[str, Any] | None = None

    @property
    def object_setup(self) -> ObjectSetup | None:
        """How the object's pose is found in the recordings; None when it is not tracked."""
        return object_setup(self.rigid_body, self.object_markers)

    def skill(self, name: str) -> Skill:
        """The skill called ``name``.

        Raises
        ------
        InputError
            If there is none; the message lists the skills there are.
        """
        for s in self.skills:
            if s.name == name:
                return s
        raise InputError(
            f"no skill named {name!r} in the dataset; its skills are "
            f"{[s.name for s in self.skills]}"
        )

    @property
    def mentors(self) -> tuple[str, ...]:
        """The mentors, in order of first appearance."""
        return tuple(dict.fromkeys(d.mentor for d in self.demonstrations))

    def of_skill(self, name: str) -> tuple[Demonstration, ...]:
        """The demonstrations of one skill."""
        self.skill(name)
        return tuple(d for d in self.demonstrations if d.skill.name == name)


# ------------------------------------------------------------------------------ locating


def bundled_path(name: str) -> Path:
    """The folder of the bundled dataset ``name`` (one of :data:`BUNDLED_DATASETS`)."""
    # the package is installed as plain files (editable or wheel), so the folder exists
    return Path(str(resources.files("nonprehensile").joinpath("data", f"{name}_demos")))


def dataset_path(spec: str | Path) -> Path:
    """A dataset folder from a path, or a bundled dataset by name (``"cube"``).

    Raises
    ------
    InputError
        Neither an existing folder nor a bundled name.
    """
    path = Path(spec)
    if path.exists():
        return path
    if str(spec) in BUNDLED_DATASETS:
        return bundled_path(str(spec))
    raise InputError(
        f"{spec}: no such dataset folder (bundled datasets: {', '.join(BUNDLED_DATASETS)})"
    )


def _annotations_file(root: Path) -> Path | None:
    for name in ANNOTATION_FILES:
        if (root / name).is_file():
            return root / name
    return None


# ------------------------------------------------------------------------------- checking


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:  # an integer too large for a float: not a usable number
        return None


class _Collector:
    """Gathers problems so that a load reports all of them at once."""

    def __init__(self) -> None:
        self.problems: list[Problem] = []

    def add(self, file: str, index: int | None, message: str) -> None:
        self.problems.append(Problem(file, index, message))


@dataclass(frozen=True)
class _Settings:
    """The dataset-wide keys of the annotations, read (defaults where a key was bad)."""

    poly: Polyhedron | None
    skills: list[Skill]
    scale: float
    gap: int
    fingers: dict[str, str]
    markers: tuple[str, ...]  # every marker that matters: required ones, tips, object markers
    object_markers: dict[str, tuple[float, float, float]]
    axes: tuple[str, str, str] | None  # None: by file suffix (DEFAULT_AXES)
    units: str | None  # None: as the files declare
    tolerance_m: float
    rigid_body: str | Mapping[str, Any] | None = None  # the annotations' value
    rigid_body_name: str | None = None
    ros: RosSetup | None = None  # how rosbag2 recordings map topics to markers


def _top_level(data: Any, ann: Path, root: Path, out: _Collector,
               known: KnownSkills | None = None,
               angle_tol: float = DEFAULT_ANGLE_TOL) -> _Settings:
    """Read the dataset-wide keys; what cannot be read is reported and replaced by a default
    (the skills file from ``known`` when it is the file named)."""
    name = ann.name
    poly: Polyhedron | None = None
    skills: list[Skill] = []
    unknown = sorted({str(k) for k in data} - _TOP_KEYS)
    if unknown:
        out.add(name, None, f"unknown key(s) {unknown}; the annotations have {sorted(_TOP_KEYS)}")
    fmt = data.get("format", DATASET_FORMAT)
    if fmt != DATASET_FORMAT:
        out.add(name, None, f"'format' is {fmt!r}; this version reads {DATASET_FORMAT!r}")
    skills_ref = data.get("skills")
    if not isinstance(skills_ref, str) or not skills_ref:
        out.add(name, None, "'skills' must name the skills file (a path relative to the "
                            f"dataset folder), got {skills_ref!r}")
    else:
        try:
            if known is not None and _same_file(root / skills_ref, known[0]):
                poly, skills = known[1], list(known[2])
            else:
                poly, skills = read_skills(root / skills_ref, angle_tol=angle_tol)
        except InputError as exc:
            out.add(skills_ref, None, f"cannot use the skills file: {exc}")
    scale = _number(data.get("scale", 1.0))
    if scale is None or not math.isfinite(scale) or not SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
        out.add(name, None, f"'scale' (metres per model unit) must be a number from "
                            f"{SCALE_RANGE[0]:g} to {SCALE_RANGE[1]:g}, got "
                            f"{data.get('scale')!r}")
        scale = 1.0
    gap = data.get("gap_limit", DEFAULT_GAP_LIMIT)
    if isinstance(gap, bool) or not isinstance(gap, int) or gap < 0:
        out.add(name, None, f"'gap_limit' must be a whole number of frames >= 0, got {gap!r}")
        gap = DEFAULT_GAP_LIMIT
    fingers_raw = data.get("fingers", dict(DEFAULT_FINGERS))
    fingers: dict[str, str] = {}
    if not isinstance(fingers_raw, Mapping):
        out.add(name, None, "'fingers' must map finger elements to tip markers, e.g. "
                            f'{{"R1": "index_tip"}}, got {fingers_raw!r}')
    else:
        for k, v in fingers_raw.items():
            if not (_FINGER_RE.fullmatch(str(k)) and isinstance(v, str) and v):
                out.add(name, None, f"'fingers': entry {k!r}: {v!r} must map a finger R1, R2, "
                                    "... to the name of its tip marker")
                if str(k) in DEFAULT_FINGERS:  # reported once here, not once per recording
                    fingers[str(k)] = DEFAULT_FINGERS[str(k)]
            else:
                fingers[str(k)] = str(v)
        shared: dict[str, list[str]] = {}
        for k, v in fingers.items():
            shared.setdefault(v, []).append(k)
        for marker, names in shared.items():
            if len(names) > 1:  # two fingers would move as one: a copy-paste slip
                out.add(name, None, f"'fingers': {' and '.join(names)} both name the tip marker "
                                    f"{marker!r}; each finger has its own tip marker")
    markers_raw = data.get("markers", [])
    if not isinstance(markers_raw, list) or not all(isinstance(m, str) for m in markers_raw):
        out.add(name, None, f"'markers' must be a list of marker names, got {markers_raw!r}")
        markers_raw = []
    object_markers = _object_markers(data.get("object_markers", {}), name, out)
    markers = tuple(dict.fromkeys([*markers_raw, *fingers.values(), *object_markers]))
    axes = None
    if "axes" in data:
        try:
            axes = parse_axes(data["axes"])
        except InputError as exc:
            out.add(name, None, str(exc))
    units = data.get("units")
    if units is not None and units not in _UNITS:
        out.add(name, None, f"'units' must be one of {sorted(_UNITS)} (the length unit of the "
                            f"numbers in the recordings), got {units!r}")
        units = None
    tol = _number(data.get("tolerance_mm", DEFAULT_TOLERANCE_MM))
    if tol is None or not math.isfinite(tol) or tol < 0:
        out.add(name, None, f"'tolerance_mm' must be a finite number of millimetres >= 0, got "
                            f"{data.get('tolerance_mm')!r}")
        tol = DEFAULT_TOLERANCE_MM
    rigid_body = data.get("rigid_body")
    body_name = None
    if rigid_body is not None:
        try:
            body_name = parse_rigid_body(rigid_body).rigid_body
        except InputError as exc:
            out.add(name, None, str(exc))
            rigid_body = None
    ros = None
    if "ros" in data:
        try:
            ros = parse_ros_setup(data["ros"])
        except InputError as exc:
            out.add(name, None, str(exc))
    return _Settings(poly, skills, scale, gap, fingers, markers, object_markers, axes, units,
                     tol / 1000.0, rigid_body, body_name, ros)


def _object_markers(
    raw: Any, name: str, out: _Collector
) -> dict[str, tuple[float, float, float]]:
    """``object_markers``: marker name -> position in the model's frame (model units)."""
    if not isinstance(raw, Mapping):
        out.add(name, None, "'object_markers' must map marker names to their positions on the "
                            f'object in model units, e.g. {{"cube_1": [0.5, 0.2, 1.0]}}, got '
                            f"{raw!r:.80}")
        return {}
    got: dict[str, tuple[float, float, float]] = {}
    for k, v in raw.items():
        xyz = [_number(c) for c in v] if isinstance(v, list) else []
        if len(xyz) != 3 or any(c is None or not math.isfinite(c) for c in xyz):
            out.add(name, None, f"'object_markers': {k!r} must be three finite numbers (its "
                                f"position in the model's frame, model units), got {v!r}")
            continue
        got[str(k)] = (float(xyz[0] or 0.0), float(xyz[1] or 0.0), float(xyz[2] or 0.0))
    return got


def _states(
    item: Mapping[str, Any], skill: Skill | None, where: tuple[str, int], out: _Collector,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> tuple[State, State] | None:
    states: list[State] = []
    for key in ("initial", "final"):
        ref = None if skill is None else getattr(skill, key)
        if key not in item:
            if ref is not None:
                states.append(ref)
            continue
        try:
            s = State.from_dict(item[key])
        except InputError as exc:
            out.add(*where, f"'{key}': {exc}")
            continue
        if skill is not None and ref is not None and not s.isclose(ref, angle_tol):
            out.add(*where, f"the {key} state {s.exact()} is not the {key} state "
                            f"{ref.exact()} of skill "
                            f"{skill.name!r}; fix the state or the skill")
            continue
        states.append(s)
    return (states[0], states[1]) if len(states) == 2 else None


def _events(
    item: Mapping[str, Any], skill: Skill | None, where: tuple[str, int], out: _Collector
) -> list[EventTime] | None:
    raw = item.get("events")
    want = [e.id for e in skill.events] if skill is not None else None
    if isinstance(raw, list) and not raw:
        out.add(*where, "'events' is empty: give the time of each event of the skill, in order"
                        + (f" ({want}), e.g. [{{\"id\": \"{want[0]}\", \"time\": 0.0}}, ...]"
                           if want else "") + "; or let `dataset annotate` find them")
        return None
    if not isinstance(raw, list):
        out.add(*where, f"'events' must be a list of {{\"id\": ..., \"time\": ...}}, got {raw!r}")
        return None
    events: list[EventTime] = []
    ok = True
    for j, ev in enumerate(raw):
        if not isinstance(ev, Mapping) or "id" not in ev or "time" not in ev:
            out.add(*where, f'event {j} must be {{"id": ..., "time": seconds}}, got {ev!r}')
            ok = False
            continue
        t = _number(ev["time"])
        if t is None or not math.isfinite(t):
            out.add(*where, f"event {ev['id']!r}: time must be a finite number of seconds, got "
                            f"{ev['time']!r}")
            ok = False
            continue
        events.append(EventTime(str(ev["id"]), t))
    if not ok:
        return None
    # a wrong chain or order is reported, and the times are still checked against the
    # recording, so that one pass lists every problem of the demonstration
    if skill is not None and want is not None:
        got = [e.id for e in events]
        if got != want:
            out.add(*where, f"events {got} do not match the chain of skill {skill.name!r}, "
                            f"which is {want}; annotate every event of the skill, in order")
    bad = [(a, b) for a, b in itertools.pairwise(events) if not b.time > a.time]
    if bad:
        a, b = bad[0]
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        out.add(*where, f"event times out of order: {b.id!r} at {b.time:g} s is not after "
                        f"{a.id!r} at {a.time:g} s{more}; times must increase along the chain")
    return events


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(start, end exclusive) of each run of True in a 1-D mask."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=True))


def _window(traj: MarkerTrajectory, events: list[EventTime] | None) -> tuple[int, int]:
    """Frames ``[i0, i1)`` from the first to the last event (the part segmentation uses), or
    the whole recording when the events cannot be read."""
    n = traj.n_frames
    if not events:
        return 0, n
    i0 = min(max(math.floor(min(e.time for e in events) * traj.rate + 1e-6), 0), n - 1)
    i1 = min(max(math.ceil(max(e.time for e in events) * traj.rate - 1e-6), i0), n - 1)
    return i0, i1 + 1


def _check_trajectory(
    traj: MarkerTrajectory,
    events: list[EventTime] | None,
    settings: _Settings,
    initial: State | None,
    axes_name: str,
    where: tuple[str, int],
    out: _Collector,
) -> bool:
    """Check the markers that matter, between the first and the last event: gaps, fingertips
    above the table, object markers where the model puts them."""
    ok = True
    gap = settings.gap
    if events:
        end = traj.duration
        late = [e for e in events if e.time < 0 or e.time > end + 1e-9]
        if late:
            ev = late[0]
            out.add(*where, f"event {ev.id!r} at {ev.time:g} s is out of the recording's range "
                            f"0..{end:g} s ({traj.n_frames} frames at {traj.rate:g} Hz)"
                            + (f" (and {len(late) - 1} more)" if len(late) > 1 else ""))
            ok = False
    i0, i1 = _window(traj, events if ok else None)
    occluded = traj.occluded[i0:i1]
    span = "" if (i0, i1) == (0, traj.n_frames) else (
        f" between the first and the last event (frames {i0}..{i1 - 1})")
    for k, name in enumerate(traj.marker_names):
        if occluded[:, k].all():
            out.add(*where, f"marker {name!r} is missing (NaN) in every frame{span}; check its "
                            "labelling, or leave it out of 'markers'")
            ok = False
            continue
        long = [(s + i0, e + i0) for s, e in _runs(occluded[:, k]) if e - s > gap]
        if long:
            s, e = long[0]
            more = f" (and {len(long) - 1} more gaps that long)" if len(long) > 1 else ""
            out.add(*where, f"marker {name!r} is missing (NaN) in frames {s}..{e - 1} "
                            f"({e - s} frames, {(e - s) / traj.rate:.3g} s), more than the gap "
                            f"limit of {gap} frames{more}; crop the take or raise 'gap_limit'")
            ok = False
    if not ok:
        return False
    to_m = 0.001 if traj.units == "mm" else 1.0
    pos = traj.positions[i0:i1] * to_m
    tol = settings.tolerance_m
    for finger, tip in sorted(settings.fingers.items()):
        if tip not in traj.marker_names:
            continue
        z = pos[:, traj.marker_names.index(tip), 2]
        if np.nanmin(z) < -tol:
            j = int(np.nanargmin(z))
            out.add(*where, f"fingertip marker {tip!r} ({finger}) goes {-z[j] * 1000:.0f} mm "
                            f"below the table (z = {z[j]:.4g} m at {(i0 + j) / traj.rate:.3g} s, "
                            f"frame {i0 + j}; tolerance {tol * 1000:g} mm); the table is z = 0 "
                            f"with z up, and the file was read as {axes_name!r}: set 'axes' "
                            f"(presets {', '.join(sorted(AXES_PRESETS))}) or recalibrate")
            ok = False
    if settings.object_markers and settings.poly is not None and initial is not None:
        ok = _check_object_markers(traj, events, settings, initial, where, out) and ok
    return ok


def _check_object_markers(
    traj: MarkerTrajectory,
    events: list[EventTime] | None,
    settings: _Settings,
    initial: State,
    where: tuple[str, int],
    out: _Collector,
) -> bool:
    """At the first event the object rests in its initial state: its markers must be where
    the model (scaled, in ``state_pose``) puts them, and as far apart as the model says."""
    assert settings.poly is not None
    names = list(settings.object_markers)
    t0 = events[0].time if events else 0.0
    frame = min(max(round(t0 * traj.rate), 0), traj.n_frames - 1)
    to_m = 0.001 if traj.units == "mm" else 1.0
    got = np.array([traj.positions[frame, traj.marker_names.index(m)] for m in names]) * to_m
    layout = np.array([settings.object_markers[m] for m in names]) * settings.scale
    seen = ~np.isnan(got).any(axis=1)
    tol = settings.tolerance_m
    # distances between markers do not depend on the calibration: a wrong layout or scale
    for a, b in itertools.combinations(np.flatnonzero(seen).tolist(), 2):
        d_rec = float(np.linalg.norm(got[a] - got[b]))
        d_mod = float(np.linalg.norm(layout[a] - layout[b]))
        if abs(d_rec - d_mod) > tol:
            out.add(*where, f"object markers {names[a]!r} and {names[b]!r} are "
                            f"{d_rec * 1000:.1f} mm apart at {t0:g} s but {d_mod * 1000:.1f} mm "
                            f"on the model (scale {settings.scale:g}; tolerance {tol * 1000:g} "
                            "mm): the object markers disagree with the model; check "
                            "'object_markers' and 'scale'")
            return False
    rot, trans = state_pose(settings.poly, initial)
    want = (layout @ rot.T) + trans * settings.scale
    dev = np.linalg.norm(got - want, axis=1)
    dev[~seen] = 0.0
    k = int(np.argmax(dev))
    if dev[k] > tol:
        out.add(*where, f"object marker {names[k]!r} is {dev[k] * 1000:.1f} mm from where the "
                        f"model puts it in the initial state {initial} at {t0:g} s (recorded "
                        f"{np.round(got[k], 4).tolist()} m, expected "
                        f"{np.round(want[k], 4).tolist()} m; tolerance {tol * 1000:g} mm): the "
                        "object markers disagree with the model; check the calibration (centre "
                        "of mass above the origin, edge 1 along theta) and 'axes'")
        return False
    return True


#: A skills file read before: (its path, the object, the skills).
KnownSkills = tuple[Path, Polyhedron, Sequence[Skill]]


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):
        return False


def check_dataset(
    path: str | Path, *, progress: Progress | None = None,
    known_skills: KnownSkills | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> tuple[Dataset | None, list[Problem]]:
    """Read and check a dataset folder, collecting every problem.

    Parameters
    ----------
    path : str or Path
        The dataset folder, or a bundled dataset's name (``"cube"``).
    progress : callable (done, total) -> None, optional
        Called after each trajectory file is read (for a progress bar).
    known_skills : (Path, Polyhedron, sequence of Skill), optional
        A skills file already read, used when the annotations name that file instead of
        reading it again (the service checks every upload against its own, read once).
    angle_tol : float
        Degrees within which the skills file's states must match the model's geometry
        (``read_skills``): a model from a mesh carries its file's rounding.

    Returns
    -------
    dataset : Dataset or None
        The dataset when there is no problem, else None (nothing half-loaded).
    problems : list of Problem
        Every problem found, by file and demonstration, in annotations order.
    """
    root = dataset_path(path)
    out = _Collector()
    if not root.is_dir():
        out.add(str(root), None, "not a folder; a dataset is a folder with an annotations file")
        return None, out.problems
    ann = _annotations_file(root)
    if ann is None:
        out.add(str(root), None, f"no annotations file; expected one of {list(ANNOTATION_FILES)}")
        return None, out.problems
    try:
        data = load_document(ann)
    except InputError as exc:
        out.add(ann.name, None, str(exc))
        return None, out.problems
    if not isinstance(data, Mapping) or not isinstance(data.get("demonstrations"), list):
        out.add(ann.name, None, "the annotations must be an object with a 'demonstrations' list "
                                "(see docs/dataset.md)")
        return None, out.problems
    settings = _top_level(data, ann, root, out, known_skills, angle_tol)
    poly, skills, fingers = settings.poly, settings.skills, settings.fingers
    by_name = {s.name: s for s in skills}
    ignored: dict[str, None] = {}
    items: list[Any] = data["demonstrations"]
    demos: list[Demonstration] = []
    seen: dict[str, int] = {}
    order: list[str] | None = None  # the dataset's marker order (below)
    for i, item in enumerate(items):
        if progress is not None:
            progress(i, len(items))
        if not isinstance(item, Mapping):
            out.add(ann.name, i, f"a demonstration must be an object with keys "
                                 f"{sorted(_DEMO_KEYS)}, got {item!r:.60}")
            continue
        file = item.get("file")
        where = (file if isinstance(file, str) and file else ann.name, i)
        unknown = sorted({str(k) for k in item} - _DEMO_KEYS)
        if unknown:
            out.add(*where, f"unknown key(s) {unknown}; a demonstration has {sorted(_DEMO_KEYS)}")
        skill_name = item.get("skill")
        skill = by_name.get(skill_name) if isinstance(skill_name, str) else None
        if skill is None and poly is not None:
            out.add(*where, f"unknown skill {skill_name!r}; the skills file has "
                            f"{sorted(by_name)}")
        mentor = item.get("mentor")
        if not isinstance(mentor, str) or not mentor.strip():
            out.add(*where, f"'mentor' must be a non-empty name, got {mentor!r}")
        states = _states(item, skill, where, out, angle_tol)
        events = _events(item, skill, where, out)
        traj: MarkerTrajectory | None = None
        if not isinstance(file, str) or not file:
            out.add(ann.name, i, f"'file' must name the trajectory file, got {file!r}")
        elif "\x00" in file:
            # no file system holds such a name (and pathlib raises on it)
            out.add(*where, f"'file' must be a file name, got {file!r} (a NUL character)")
        elif file in seen:
            out.add(*where, f"the file is also demonstration {seen[file]}; one file per "
                            "demonstration")
        elif not (root / file).resolve().is_relative_to(root.resolve()):
            # a dataset is one folder: it moves, copies and archives whole
            out.add(*where, "the file lies outside the dataset folder; copy it in and name "
                            "it by its path relative to the folder")
        else:
            seen[file] = i
            traj = _read(root / file, out, where, settings)
        if traj is None:
            continue
        missing = [m for m in settings.markers if m not in traj.marker_names]
        if missing:
            has = list(traj.marker_names)
            listed = (", ".join(has[:12]) + (f", ... ({len(has) - 12} more)" if len(has) > 12
                                             else "")) if has else "no markers"
            out.add(*where, f"marker(s) {missing} are not in the recording, which has "
                            f"{listed}; rename them in the file or name the recording's own "
                            "markers in 'markers'/'fingers'/'object_markers'")
        if settings.rigid_body_name is not None and settings.rigid_body_name not in [
                b.name for b in traj.rigid_bodies]:
            out.add(*where, f"rigid body {settings.rigid_body_name!r} ('rigid_body') is not in the "
                            f"recording, which has {[b.name for b in traj.rigid_bodies] or 'none'}")
        ignored.update(dict.fromkeys(m for m in traj.marker_names if m not in settings.markers))
        own = [m for m in traj.marker_names if m in settings.markers]
        if not own:
            continue  # none of the annotations' markers: said above; nothing else to check
        if order is None and not missing:
            # the dataset's marker order: the first complete recording's. Every other one is
            # put in it, whatever order its file exports them in, so that the same marker
            # sits at the same place in every flattened vector
            order = own
        traj = _select(traj, order if order is not None else own)
        if skill is not None:
            used = sorted({f"R{p.x.index}" for e in skill.events for p in e.pairs
                           if isinstance(p.x, Finger)})
            unmapped = [r for r in used if r not in fingers]
            if unmapped:
                out.add(*where, f"skill {skill.name!r} uses finger(s) {unmapped} but 'fingers' "
                                f"names no tip marker for them; add them to 'fingers'")
        axes_name = _axes_name(settings.axes, Path(str(file)).suffix.lower())
        initial = states[0] if states is not None else None
        if not _check_trajectory(traj, events, settings, initial, axes_name, where, out) or (
                missing):
            continue
        if skill is None or states is None or events is None or not isinstance(mentor, str):
            continue
        demos.append(Demonstration(str(file), skill, mentor.strip(), states[0], states[1],
                                   tuple(events), traj))
    if progress is not None:
        progress(len(items), len(items))
    if out.problems or poly is None:
        return None, out.problems
    notes: tuple[str, ...] = ()
    if ignored:
        names = list(ignored)
        shown = ", ".join(names[:12]) + (f", ... ({len(names) - 12} more)" if len(names) > 12
                                         else "")
        notes = (f"ignored {len(names)} marker(s) that the annotations do not name in 'fingers', "
                 f"'markers' or 'object_markers': {shown}",)
    return Dataset(poly, tuple(skills), tuple(demos), settings.scale, settings.gap, fingers,
                   root, settings.object_markers, notes, settings.rigid_body), out.problems


def _axes_name(axes: tuple[str, str, str] | None, suffix: str) -> str:
    """How a file was read: a preset's name, or the explicit mapping."""
    if axes is None:
        return DEFAULT_AXES.get(suffix, "zup")
    for name, spec in AXES_PRESETS.items():
        if spec == axes:
            return name
    return str(axes_to_dict(axes))


def _read(
    path: Path, out: _Collector, where: tuple[str, int], settings: _Settings
) -> MarkerTrajectory | None:
    """Read a recording into our axes (z up) and units, as the annotations say."""
    suffix = path.suffix.lower()
    reader = _READERS.get(suffix)
    try:
        bag, present = is_rosbag(path), path.is_file()
    except OSError as exc:  # a name the file system cannot take (too long, ...)
        out.add(*where, f"cannot look for the trajectory file: {exc.strerror or exc}")
        return None
    if bag:
        if settings.ros is None:
            out.add(*where, "a rosbag2 folder, but the annotations have no 'ros' set-up saying "
                            "which topic is which marker (see docs/dataset.md#ros-2-bags)")
            return None
        ros = settings.ros

        def reader(p: Path) -> MarkerTrajectory:
            return read_rosbag(p, ros, settings.rigid_body_name)
        suffix = ""  # ROS is z up (REP 103)
    elif path.is_dir():
        out.add(*where, "a folder, not a trajectory file: a C3D or Motive CSV recording is a "
                        "file, and a rosbag2 folder holds the metadata.yaml that `ros2 bag "
                        "record` writes (this one has none); name the recording's file")
        return None
    elif reader is None:
        out.add(*where, f"unknown trajectory format {path.suffix!r}; use .c3d, a Motive .csv "
                        "or a rosbag2 folder")
        return None
    elif not present:
        out.add(*where, "no such trajectory file in the dataset folder")
        return None
    try:
        traj = reader(path)
    except InputError as exc:
        # the reader's message starts with the full path; the problem already names the file
        out.add(*where, str(exc).removeprefix(f"{path}: "))
        return None
    axes = settings.axes or AXES_PRESETS[DEFAULT_AXES.get(suffix, "zup")]
    rot = axes_matrix(axes)
    units, factor = _UNITS[settings.units] if settings.units else (traj.units, 1.0)
    # a recording read in the wrong unit ('units': 'm' over a file in millimetres) put the
    # hand a kilometre from the table, and nothing said so unless object markers were given
    seen = traj.positions[np.isfinite(traj.positions)]
    far = float(np.abs(seen).max()) * factor * (0.001 if units == "mm" else 1.0) \
        if seen.size else 0.0
    if far > MAX_CAPTURE_M:
        said = (f"'units': {settings.units!r} says" if settings.units
                else "the file says")
        out.add(*where, f"a marker {far:.3g} m from the recording's origin, farther than any "
                        f"capture volume ({MAX_CAPTURE_M:g} m): {said} {units}; if the numbers "
                        "are in another unit, give the annotations' 'units' (mm or m)")
        return None
    # a take in a small volume (every number below 100) read in the wrong unit passes the
    # distance above; its markers then move a thousand times faster than a hand
    cols = [k for k, name in enumerate(traj.marker_names) if name in settings.markers]
    if cols and len(traj.positions) > 1:
        moved = np.diff(traj.positions[:, cols], axis=0)
        steps = np.sqrt((moved * moved).sum(axis=2))  # (frames - 1, markers), NaN: occluded
        # each marker's 90th percentile, then their median: one marker swapping with a ghost
        # in many frames does not make the take fast; a wrong unit makes every marker fast
        seen_steps = [col[np.isfinite(col)] for col in steps.T]
        per = [float(np.percentile(c, 90)) for c in seen_steps if c.size]
        fast = float(np.median(per)) * traj.rate * factor \
            * (0.001 if units == "mm" else 1.0) if per else 0.0
        if fast > MAX_MARKER_SPEED:
            said = (f"'units': {settings.units!r} says" if settings.units
                    else "the file says")
            out.add(*where, f"the markers move at {fast:.3g} m/s (the median over the markers "
                            f"of each one's 90th percentile speed between frames), faster "
                            f"than any hand "
                            f"({MAX_MARKER_SPEED:g} m/s): {said} {units} at {traj.rate:g} Hz; "
                            "if the numbers are in another unit, give the annotations' 'units' "
                            "(mm or m); else check the recording's rate")
            return None
    if np.array_equal(rot, np.eye(3)) and factor == 1.0 and units == traj.units:
        return traj
    # a rigid body turns with the world: R -> M R M^T, whose quaternion has its vector part
    # turned by M (M is a proper rotation)
    bodies = tuple(PoseTrajectory(
        b.name, b.positions @ rot.T * factor,
        np.concatenate([b.quaternions[:, :3] @ rot.T, b.quaternions[:, 3:]], axis=1),
        b.rate, units) for b in traj.rigid_bodies)
    return MarkerTrajectory(traj.positions @ rot.T * factor, traj.marker_names, traj.rate,
                            units, bodies)


def _select(traj: MarkerTrajectory, names: Sequence[str]) -> MarkerTrajectory:
    """The markers of ``names`` the recording has, in the order of ``names``; the others are
    dropped."""
    keep = [traj.marker_names.index(n) for n in dict.fromkeys(names) if n in traj.marker_names]
    if keep == list(range(traj.n_markers)):
        return traj
    return MarkerTrajectory(traj.positions[:, keep], tuple(traj.marker_names[k] for k in keep),
                            traj.rate, traj.units, traj.rigid_bodies)


def load_dataset(path: str | Path, *, progress: Progress | None = None,
                 angle_tol: float = DEFAULT_ANGLE_TOL) -> Dataset:
    """Load a dataset folder, all or nothing.

    Parameters
    ----------
    path : str or Path
        The dataset folder (see ``docs/dataset.md``), or a bundled dataset's name (``"cube"``).
    progress : callable (done, total) -> None, optional
        Called after each trajectory file is read.
    angle_tol : float
        As :func:`check_dataset`'s.

    Returns
    -------
    Dataset

    Raises
    ------
    DemonstrationError
        Listing every problem found (one per line, by file and demonstration); nothing is
        returned half-loaded. :func:`check_dataset` gives the problems as values.
    """
    dataset, problems = check_dataset(path, progress=progress, angle_tol=angle_tol)
    if dataset is None and len(problems) == 1:  # one line naming the culprit
        raise DemonstrationError(f"{headed(path, problems[0])}; nothing was loaded")
    if dataset is None:
        lines = "\n".join(f"  - {p}" for p in problems)
        raise DemonstrationError(
            f"{path}: {len(problems)} problem(s) in the dataset, nothing was loaded; fix them "
            f"all and load again:\n{lines}"
        )
    return dataset


def headed(path: str | Path, problem: Problem) -> str:
    """``PATH: problem``, without naming the path twice when the problem is the folder's own
    (``my_takes: my_takes: no annotations file`` read as a stutter)."""
    text = str(problem)
    # the path as given and as the problem may name it (``empty/`` is named ``empty``)
    names = {str(path), str(Path(path))}
    return text if any(text.startswith(f"{n}: ") for n in names) else f"{path}: {text}"


# -------------------------------------------------------------------------------- writing


def save_dataset(
    dataset: Dataset,
    out_dir: str | Path,
    *,
    trajectory_format: str = "c3d",
    markers: Sequence[str] | None = None,
) -> Path:
    """Write a dataset folder: the trajectories, ``skills.json`` and ``annotations.json``.

    Each demonstration's trajectory is written to its ``file`` (its suffix replaced by the
    chosen format's); the skills file holds the object model inline, so the folder stands
    alone.

    Parameters
    ----------
    dataset : Dataset
        What to write (its ``root`` is ignored).
    out_dir : str or Path
        The folder (created if missing; files of the same names are overwritten).
    trajectory_format : {"c3d", "csv"}
        C3D (compact, needs the ``mocap`` extra) or Motive CSV.
    markers : sequence of str, optional
        The markers every recording must have (the annotations' ``markers``); by default the
        markers of the first demonstration.

    Returns
    -------
    Path
        The annotations file.

    Raises
    ------
    InputError
        An unknown format, or a file that cannot be written.
    """
    if trajectory_format not in ("c3d", "csv"):
        raise InputError(
            f"trajectory_format must be 'c3d' or 'csv', got {trajectory_format!r}"
        )
    root = Path(out_dir)
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{root}: cannot create the dataset folder: {exc}") from None
    save_document(skills_to_dict(dataset.poly, list(dataset.skills)), root / "skills.json")
    entries = []
    for d in dataset.demonstrations:
        name = str(Path(d.file).with_suffix(f".{trajectory_format}"))
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        if trajectory_format == "c3d":
            write_c3d(d.trajectory, root / name)
        else:
            write_motive_csv(d.trajectory, root / name)
        entry = d.to_dict()
        entry["file"] = name
        entries.append(entry)
    if markers is None:
        markers = dataset.demonstrations[0].trajectory.marker_names if entries else ()
    doc = {
        "format": DATASET_FORMAT,
        "skills": "skills.json",
        "scale": dataset.scale,
        "gap_limit": dataset.gap_limit,
        "fingers": dict(dataset.fingers),
        "markers": list(markers),
        **({"object_markers": {k: list(v) for k, v in dataset.object_markers.items()}}
           if dataset.object_markers else {}),
        **({"rigid_body": dataset.rigid_body} if dataset.rigid_body else {}),
        "demonstrations": entries,
    }
    path = root / ANNOTATION_FILES[0]
    save_document(doc, path)
    return path


# -------------------------------------------------------------------------------- summary


def dataset_summary(dataset: Dataset) -> dict[str, Any]:
    """Skills, mentors, counts and durations of a dataset (``dataset show --json``).

    Durations are from the first to the last event of each demonstration, in seconds.
    """
    def stats(values: list[float]) -> dict[str, float]:
        a = np.asarray(values, dtype=np.float64)
        return {"mean": round(float(a.mean()), 4), "min": round(float(a.min()), 4),
                "max": round(float(a.max()), 4)}

    skills = []
    for s in dataset.skills:
        demos = [d for d in dataset.demonstrations if d.skill.name == s.name]
        if not demos:
            skills.append({"name": s.name, "maneuver": s.maneuver, "count": 0, "mentors": {}})
            continue
        mentors: dict[str, int] = {}
        for d in demos:
            mentors[d.mentor] = mentors.get(d.mentor, 0) + 1
        skills.append({
            "name": s.name,
            "maneuver": s.maneuver,
            "initial": s.initial.to_dict(),
            "final": s.final.to_dict(),
            "count": len(demos),
            "mentors": mentors,
            "duration_s": stats([d.duration for d in demos]),
        })
    mentors_doc = []
    for m in dataset.mentors:
        demos = [d for d in dataset.demonstrations if d.mentor == m]
        mentors_doc.append({"name": m, "count": len(demos),
                            "duration_s": stats([d.duration for d in demos])})
    n_occluded = sum(int(d.trajectory.occluded.sum()) for d in dataset.demonstrations)
    n_samples = sum(d.trajectory.occluded.size for d in dataset.demonstrations)
    first = dataset.demonstrations[0].trajectory if dataset.demonstrations else None
    return {
        "root": str(dataset.root) if dataset.root else None,
        "object": dataset.poly.name,
        "scale": dataset.scale,
        "n_demonstrations": len(dataset.demonstrations),
        "rate_hz": first.rate if first else None,
        "units": first.units if first else None,
        "markers": list(first.marker_names) if first else [],
        "fingers": dict(dataset.fingers),
        "gap_limit": dataset.gap_limit,
        "occluded_fraction": round(n_occluded / n_samples, 5) if n_samples else 0.0,
        "object_markers": {k: list(v) for k, v in dataset.object_markers.items()},
        "notes": list(dataset.notes),
        "skills": skills,
        "mentors": mentors_doc,
        "problems": [],
        "not_checked": not_checked(dataset),
    }


def not_checked(dataset: Dataset) -> list[str]:
    """What loading could not check in this dataset (said beside "no problems")."""
    out = []
    if not dataset.object_markers:
        out.append("the initial states against the object's pose (the annotations name no "
                   "'object_markers'" + (", and a rigid body's pose is not compared with "
                                         "the model)" if dataset.rigid_body else ")"))
    out.append("the event times against the object's motion and the fingers' contacts "
               "(`dataset annotate` finds them in recordings that track the object; "
               "`simulate dataset` replays them in physics)")
    return out
