"""ROS 2 bags as recordings: rosbag2 folders (sqlite3 or mcap storage) read with ``rosbags``.

Labs that record motion capture through ROS 2 (mocap4r2, vrpn_mocap, optitrack drivers)
have bags, not C3D files: each tracked thing is a topic of ``geometry_msgs/PoseStamped``,
``geometry_msgs/PointStamped`` or ``geometry_msgs/TransformStamped``, or a frame of ``/tf``
(``tf2_msgs/TFMessage``). The dataset's annotations say, in ``ros``, which topic or frame is
which marker and which is the object's rigid body::

    "rigid_body": "cube",
    "ros": {
      "topics": {
        "index_tip": "/mocap/index_tip/pose",          # PoseStamped / PointStamped / ...
        "thumb_tip": "/mocap/thumb_tip/point",
        "cube": {"tf": "cube", "parent": "world"}      # a frame of /tf (and /tf_static)
      },
      "rate": 120,                                     # optional (default: the messages')
      "clock": "bag"                                   # or "header"
    }

A marker takes the position of its source; the rigid body (the entry named as the
annotations' ``rigid_body``) its position and orientation (a ``PointStamped`` has none and is
refused for it). Times come from the bag's clock: each message's receive time recorded in the
bag (``"clock": "bag"``, default), or its ``header.stamp`` (``"header"``: the capture time,
where the driver stamps it). Time zero is the earliest message of the mapped sources, so
event times are seconds from the recording's start, as for C3D and CSV.

A recording has one rate: every source is resampled at ``t_k = k / rate`` (``rate``, or the
median rate of the first source's messages, rounded to a whole number of Hz when within
0.01 % of one): positions linearly between the two messages around ``t_k``, orientations
spherically. Where two consecutive messages of a source are more than 1.5 periods apart (the
tracker lost it), the frames between them are missing (NaN), as an occluded marker in C3D is,
and so are frames before its first message or after its last. Messages on the grid are taken
as they are. Lengths are metres (ROS's unit) and axes as ROS's REP 103 (z up): the
annotations' ``axes`` and ``units`` apply as to any recording.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from nonprehensile.demonstrations.record import (
    MAX_RATE_HZ,
    MIN_RATE_HZ,
    MarkerTrajectory,
    PoseTrajectory,
    rate_in_range,
)
from nonprehensile.errors import DemonstrationError, InputError

__all__ = ["MESSAGE_TYPES", "RosSetup", "RosSource", "is_rosbag", "parse_ros_setup",
           "read_rosbag"]

FloatArray = NDArray[np.float64]

#: The message types a source may have (ROS 2 names).
MESSAGE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PointStamped",
                 "geometry_msgs/msg/TransformStamped", "tf2_msgs/msg/TFMessage")
_TF_TOPICS = ("/tf", "/tf_static")
#: A frame farther than this many periods from a message on either side is missing.
_MAX_GAP_PERIODS = 1.5


@dataclass(frozen=True)
class RosSource:
    """Where one marker or rigid body is in a bag.

    Attributes
    ----------
    name : str
        The marker's (or rigid body's) name in the dataset.
    topic : str or None
        A topic of PoseStamped, PointStamped or TransformStamped messages; None for a tf frame.
    frame : str or None
        The child frame of ``/tf`` (and ``/tf_static``) transforms.
    parent : str or None
        Only transforms from this parent frame (any when None).
    """

    name: str
    topic: str | None = None
    frame: str | None = None
    parent: str | None = None

    def describe(self) -> str:
        """``topic '/x'`` or ``tf frame 'cube' (parent 'world')``."""
        if self.topic is not None:
            return f"topic {self.topic!r}"
        par = f" (parent {self.parent!r})" if self.parent else ""
        return f"tf frame {self.frame!r}{par}"


@dataclass(frozen=True)
class RosSetup:
    """The annotations' ``ros`` key, read.

    Attributes
    ----------
    sources : tuple of RosSource
    rate : float or None
        Frames per second of the recording; None: the messages' own rate.
    clock : {"bag", "header"}
    """

    sources: tuple[RosSource, ...]
    rate: float | None = None
    clock: Literal["bag", "header"] = "bag"

    def to_dict(self) -> dict[str, Any]:
        """The annotations' form."""
        topics: dict[str, Any] = {}
        for s in self.sources:
            if s.topic is not None:
                topics[s.name] = s.topic
            else:
                topics[s.name] = {"tf": s.frame, **({"parent": s.parent} if s.parent else {})}
        doc: dict[str, Any] = {"topics": topics, "clock": self.clock}
        if self.rate is not None:
            doc["rate"] = self.rate
        return doc


def parse_ros_setup(raw: object) -> RosSetup:
    """Read the annotations' ``ros``: ``{"topics": {name: topic | {"tf": frame, "parent":
    frame}}, "rate": Hz, "clock": "bag" | "header"}``.

    Raises
    ------
    DemonstrationError
        Naming the key that is wrong.
    """
    form = ('{"topics": {"<marker or rigid body>": "/topic" or {"tf": "<child frame>", '
            '"parent": "<frame>"}}, "rate": <Hz>, "clock": "bag" or "header"}')
    if not isinstance(raw, Mapping) or not set(raw) <= {"topics", "rate", "clock"}:
        raise DemonstrationError(f"'ros' must be {form}, got {raw!r:.120}")
    topics = raw.get("topics")
    if not isinstance(topics, Mapping) or not topics:
        raise DemonstrationError(f"'ros': 'topics' must map each marker and the rigid body to "
                                 f"its topic or tf frame, got {topics!r:.120}")
    sources = []
    for name, spec in topics.items():
        if not isinstance(name, str) or not name:
            raise DemonstrationError(f"'ros': topic names must map from marker names, got "
                                     f"{name!r}")
        if isinstance(spec, str) and spec.startswith("/"):
            sources.append(RosSource(name, topic=spec))
        elif isinstance(spec, Mapping) and set(spec) <= {"tf", "parent"} and isinstance(
                spec.get("tf"), str) and spec["tf"] and (
                spec.get("parent") is None or isinstance(spec.get("parent"), str)):
            sources.append(RosSource(name, frame=spec["tf"].lstrip("/"),
                                     parent=(spec.get("parent") or "").lstrip("/") or None))
        else:
            raise DemonstrationError(
                f"'ros': {name!r} must be a topic ('/...') or {{\"tf\": \"<child frame>\", "
                f"\"parent\": \"<frame>\"}}, got {spec!r:.80}")
    rate = raw.get("rate")
    if rate is not None and (isinstance(rate, bool) or not isinstance(rate, (int, float))
                             or not rate_in_range(rate)):
        raise DemonstrationError(f"'ros': 'rate' must be a number of Hz from {MIN_RATE_HZ:g} "
                                 f"to {MAX_RATE_HZ:g} (every recording's range), got {rate!r}")
    clock = raw.get("clock", "bag")
    if clock not in ("bag", "header"):
        raise DemonstrationError(f"'ros': 'clock' must be 'bag' (the bag's receive times) or "
                                 f"'header' (the messages' header stamps), got {clock!r}")
    return RosSetup(tuple(sources), None if rate is None else float(rate), clock)


def is_rosbag(path: Path) -> bool:
    """Whether ``path`` is a rosbag2 folder (it holds ``metadata.yaml``)."""
    return path.is_dir() and (path / "metadata.yaml").is_file()


@dataclass
class _Series:
    times: list[int]  # nanoseconds: seconds since 1970 as floats would lose 0.2 us
    pos: list[tuple[float, float, float]]
    quat: list[tuple[float, float, float, float]] | None


def _stamp(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def read_rosbag(
    path: str | Path, setup: RosSetup, rigid_body: str | None = None
) -> MarkerTrajectory:
    """Read a rosbag2 folder as a recording: markers, and the rigid body named
    ``rigid_body`` (from the source of that name), in metres at one rate.

    Raises
    ------
    InputError
        Not a rosbag2 folder, unreadable, a source that is not in the bag (the message lists
        the topics and frames it has), a message type that cannot give what is asked, no
        messages.
    """
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as exc:  # the extra is missing
        raise InputError(f"{path}: reading ROS 2 bags needs rosbags: pip install "
                         f"'nonprehensile[ros]' ({exc})") from None
    root = Path(path)
    if not is_rosbag(root):
        raise InputError(f"{root}: not a rosbag2 folder (no metadata.yaml in it)")
    names = [s.name for s in setup.sources]
    if rigid_body is not None and rigid_body not in names:
        raise InputError(f"{root}: the rigid body {rigid_body!r} has no source in 'ros' "
                         f"'topics' (which names {names})")
    series = {s.name: _Series([], [], [] if s.name == rigid_body else None)
              for s in setup.sources}
    try:
        with AnyReader([root], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            conns = {c.topic: c for c in reader.connections}
            wanted = []
            for s in setup.sources:
                topic = s.topic
                if topic is None:
                    tf = [t for t in _TF_TOPICS if t in conns]
                    if not tf:
                        raise InputError(f"{root}: no /tf topic for the {s.describe()} of "
                                         f"{s.name!r}; the bag has topics {sorted(conns)}")
                    wanted += [conns[t] for t in tf]
                    continue
                if topic not in conns:
                    raise InputError(f"{root}: no topic {topic!r} (the {s.name!r} of 'ros' "
                                     f"'topics'); the bag has {sorted(conns)}")
                c = conns[topic]
                if c.msgtype not in MESSAGE_TYPES[:3]:
                    raise InputError(f"{root}: topic {topic!r} ({s.name!r}) has messages of "
                                     f"type {c.msgtype}; read are {list(MESSAGE_TYPES[:3])}")
                if s.name == rigid_body and c.msgtype.endswith("PointStamped"):
                    raise InputError(f"{root}: topic {topic!r} of the rigid body {s.name!r} "
                                     "is PointStamped, which has no orientation; give a "
                                     "PoseStamped or TransformStamped topic or a tf frame")
                wanted.append(c)
            by_topic = {s.topic: s for s in setup.sources if s.topic is not None}
            tf_sources = [s for s in setup.sources if s.topic is None]
            seen_frames: set[tuple[str, str]] = set()
            unique = list({c.id: c for c in wanted}.values())  # /tf may serve several
            for conn, bag_ns, raw in reader.messages(connections=unique):
                msg: Any = reader.deserialize(raw, conn.msgtype)
                t_bag = int(bag_ns)
                if conn.msgtype == "tf2_msgs/msg/TFMessage":
                    for tr in msg.transforms:
                        child = tr.child_frame_id.lstrip("/")
                        parent = tr.header.frame_id.lstrip("/")
                        seen_frames.add((parent, child))
                        for s in tf_sources:
                            if s.frame == child and (s.parent is None or s.parent == parent):
                                t = t_bag if setup.clock == "bag" else _stamp(tr.header)
                                _add(series[s.name], t, tr.transform.translation,
                                     tr.transform.rotation)
                    continue
                s = by_topic[conn.topic]
                t = t_bag if setup.clock == "bag" else _stamp(msg.header)
                if conn.msgtype.endswith("PoseStamped"):
                    _add(series[s.name], t, msg.pose.position, msg.pose.orientation)
                elif conn.msgtype.endswith("TransformStamped"):
                    _add(series[s.name], t, msg.transform.translation, msg.transform.rotation)
                else:
                    _add(series[s.name], t, msg.point, None)
    except InputError:
        raise
    except Exception as exc:  # rosbags' own errors: a damaged or foreign bag
        raise InputError(f"{root}: cannot read the bag: {type(exc).__name__}: {exc}") from None
    for s in tf_sources:
        if not series[s.name].times:
            frames = sorted(f"{p}->{c}" for p, c in seen_frames)
            raise InputError(f"{root}: no transform to the {s.describe()} of {s.name!r} in "
                             f"/tf; the bag's transforms are {frames[:20]}")
    for s in setup.sources:
        if not series[s.name].times:
            raise InputError(f"{root}: the {s.describe()} of {s.name!r} has no messages")
    return _resample(root, setup, series, rigid_body)


def _add(series: _Series, t: int, p: Any, q: Any) -> None:
    series.times.append(t)
    series.pos.append((float(p.x), float(p.y), float(p.z)))
    if series.quat is not None:
        series.quat.append((float(q.x), float(q.y), float(q.z), float(q.w)))


def _grid_rate(setup: RosSetup, series: Mapping[str, _Series]) -> float:
    if setup.rate is not None:
        return setup.rate
    t = np.sort(np.asarray(series[setup.sources[0].name].times, dtype=np.int64))
    dt = np.diff(t) * 1e-9
    dt = dt[dt > 0]
    if not len(dt):
        raise InputError(f"the {setup.sources[0].describe()} has one message: give 'rate'")
    rate = 1.0 / float(np.median(dt))
    return float(round(rate)) if abs(rate - round(rate)) <= 1e-4 * rate else rate


def _sample(t: FloatArray, at: FloatArray, period: float) -> tuple[NDArray[np.int64], FloatArray,
                                                                  NDArray[np.bool_]]:
    """For each time of ``at``: the message before it, the weight of the one after, and
    whether it is covered (between two messages at most 1.5 periods away, or on one)."""
    j = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 1)
    tol = 1e-6 * period  # a message on the grid (to the bag's nanosecond) is on it
    # a message just after the frame time (by less than the tolerance) is on it too
    after = np.minimum(j + 1, len(t) - 1)
    j = np.where(np.abs(t[after] - at) <= tol, after, j)
    nxt = np.minimum(j + 1, len(t) - 1)
    span = t[nxt] - t[j]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(span > 0, (at - t[j]) / span, 0.0)
    on = np.abs(at - t[j]) <= tol
    u = np.where(on, 0.0, np.clip(u, 0.0, 1.0))
    inside = (at >= t[0] - tol) & (at <= t[-1] + tol)
    # between two consecutive messages no more than 1.5 periods apart: a longer silence is a
    # frame (or more) the tracker did not deliver, missing as an occluded marker is
    near = span <= _MAX_GAP_PERIODS * period + tol
    return j, u, inside & (on | near)


def _resample(root: Path, setup: RosSetup, series: Mapping[str, _Series],
              rigid_body: str | None) -> MarkerTrajectory:
    rate = _grid_rate(setup, series)
    period = 1.0 / rate
    t0 = min(min(s.times) for s in series.values())
    t1 = max(max(s.times) for s in series.values())
    n = math.floor((t1 - t0) * 1e-9 * rate + 1e-6) + 1
    at = np.arange(n) / rate  # seconds from the first message
    markers: list[str] = []
    cols: list[FloatArray] = []
    bodies: list[PoseTrajectory] = []
    for s in setup.sources:
        ser = series[s.name]
        order = np.argsort(np.asarray(ser.times), kind="stable")
        t = (np.asarray(ser.times, dtype=np.int64)[order] - t0) * 1e-9
        pos = np.asarray(ser.pos)[order]
        keep = np.concatenate([[True], np.diff(t) > 0])  # one message per instant
        t, pos = t[keep], pos[keep]
        j, u, ok = _sample(t, at, period)
        nxt = np.minimum(j + 1, len(t) - 1)
        p = pos[j] + u[:, None] * (pos[nxt] - pos[j])
        p[~ok] = np.nan
        if ser.quat is None:
            markers.append(s.name)
            cols.append(p)
            continue
        quat = np.asarray(ser.quat)[order][keep]
        norm = np.linalg.norm(quat, axis=1)
        if (norm < 1e-9).any() or not np.isfinite(quat).all():
            k = int(np.flatnonzero((norm < 1e-9) | ~np.isfinite(quat).all(axis=1))[0])
            raise InputError(f"{root}: the {s.describe()} of {s.name!r} has a quaternion of "
                             f"zero length or not finite at {t[k]:.3f} s")
        quat = quat / norm[:, None]
        a, b = quat[j], quat[nxt]
        dot = np.einsum("ij,ij->i", a, b)
        b = np.where(dot[:, None] < 0, -b, b)
        ang = np.arccos(np.clip(np.abs(dot), -1.0, 1.0))
        s_ang = np.sin(ang)
        small = ang < 1e-9
        with np.errstate(invalid="ignore", divide="ignore"):
            wa = np.where(small, 1.0 - u, np.sin((1.0 - u) * ang) / s_ang)
            wb = np.where(small, u, np.sin(u * ang) / s_ang)
        q = wa[:, None] * a + wb[:, None] * b
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        q[~ok] = np.nan
        bodies.append(PoseTrajectory(s.name, p, q, rate, "m"))
    positions = np.stack(cols, axis=1) if markers else np.zeros((n, 0, 3))
    try:
        return MarkerTrajectory(positions, tuple(markers), rate, "m", tuple(bodies))
    except InputError as exc:
        raise InputError(f"{root}: {exc}") from None
