"""How a dataset finds the manipulated object's pose in its recordings.

A motion-capture lab tracks the object one of two ways: as a rigid body that the capture
software solves and exports (OptiTrack Motive CSV), or by markers stuck on it whose positions
on the object are known (any C3D or CSV file). The dataset's annotations say which::

    "rigid_body": "Box"
    "rigid_body": {"name": "Box", "origin": [0.5, 0.5, 0.5], "rotation": [0, 0, 0, 1]}
    "object_markers": {"cube:1": [0.5, 0.3, 1.08], "cube:2": [...], "cube:3": [...]}

A rigid body's own frame is the object model's frame (scaled by the dataset's ``scale``),
unless ``origin`` (where the model's origin is in the body frame, model units) and
``rotation`` (the model frame's orientation in the body frame, a quaternion ``x, y, z, w``)
say otherwise: Motive puts a new rigid body's pivot at its markers' centroid with the
world's axes. Object markers are given in the model's frame, in model units. Either way
:meth:`ObjectSetup.pose` gives the pose of the model frame in metres. When both are given
the rigid body is used.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from nonprehensile.demonstrations.record import MarkerTrajectory, PoseTrajectory
from nonprehensile.errors import DemonstrationError

__all__ = ["ObjectSetup", "object_setup", "parse_object_setup", "parse_rigid_body"]


@dataclass(frozen=True)
class ObjectSetup:
    """Where the object's pose comes from in each recording.

    Attributes
    ----------
    rigid_body : str or None
        Name of the rigid body (its frame is the model frame, scaled).
    markers : tuple of (str, (float, float, float)), or None
        Object markers and their positions in the model frame, model units (three or more).
    origin : (float, float, float) or None
        The model's origin in the rigid body's frame, model units (default: the body's).
    rotation : (float, float, float, float) or None
        The model frame's orientation in the rigid body's frame, quaternion ``x, y, z, w``
        (default: the body's).
    """

    rigid_body: str | None = None
    markers: tuple[tuple[str, tuple[float, float, float]], ...] | None = None
    origin: tuple[float, float, float] | None = None
    rotation: tuple[float, float, float, float] | None = None

    @property
    def marker_names(self) -> tuple[str, ...]:
        """Names of the object markers (none for a rigid body)."""
        return tuple(m for m, _ in self.markers or ())

    def to_dict(self) -> dict[str, Any]:
        """The annotations' keys (``rigid_body`` or ``object_markers``)."""
        if self.rigid_body is not None and self.origin is None and self.rotation is None:
            return {"rigid_body": self.rigid_body}
        if self.rigid_body is not None:
            body: dict[str, Any] = {"name": self.rigid_body}
            if self.origin is not None:
                body["origin"] = list(self.origin)
            if self.rotation is not None:
                body["rotation"] = list(self.rotation)
            return {"rigid_body": body}
        return {"object_markers": {m: list(x) for m, x in self.markers or ()}}

    def pose(self, traj: MarkerTrajectory, scale: float) -> PoseTrajectory:
        """The pose of the object model's frame, in metres, frame by frame.

        A model point ``x`` (model units) is at ``R_i @ (scale * x) + p_i`` metres.

        Raises
        ------
        DemonstrationError
            The rigid body or a marker is not in the recording.
        """
        t = traj.to_units("m")
        if self.rigid_body is not None:
            body = t.rigid_body(self.rigid_body)
            if self.origin is None and self.rotation is None:
                return body
            rot = Rotation.from_quat(self.rotation or (0.0, 0.0, 0.0, 1.0)).as_matrix()
            return body.with_body_frame(rot, np.asarray(self.origin or (0.0, 0.0, 0.0)) * scale)
        layout = {m: np.asarray(x) * scale for m, x in self.markers or ()}
        return t.pose_from_markers("object", layout)


def parse_rigid_body(raw: object) -> ObjectSetup:
    """Read the annotations' ``rigid_body``: a name, or ``{"name", "origin", "rotation"}``.

    Raises
    ------
    DemonstrationError
        Naming what is wrong.
    """
    if isinstance(raw, str) and raw.strip():
        return ObjectSetup(rigid_body=raw)
    form = ('a name, or {"name": "<name>", "origin": [x, y, z], "rotation": [x, y, z, w]} '
            "(the model's origin, model units, and orientation in the body's frame)")
    if not isinstance(raw, Mapping) or not set(raw) <= {"name", "origin", "rotation"} or not (
            isinstance(raw.get("name"), str) and raw["name"].strip()):
        raise DemonstrationError(f"'rigid_body' must be {form}, got {raw!r:.120}")

    def numbers(key: str, n: int) -> tuple[float, ...] | None:
        v = raw.get(key)
        if v is None:
            return None
        if not (isinstance(v, (list, tuple)) and len(v) == n and all(
                isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c)
                for c in v)):
            raise DemonstrationError(f"'rigid_body': {key!r} must be {n} finite numbers, got "
                                     f"{v!r}")
        return tuple(float(c) for c in v)

    origin = numbers("origin", 3)
    rotation = numbers("rotation", 4)
    if rotation is not None and math.hypot(*rotation) < 1e-9:
        raise DemonstrationError("'rigid_body': 'rotation' is a quaternion of zero length")
    return ObjectSetup(
        rigid_body=str(raw["name"]),
        origin=None if origin is None else (origin[0], origin[1], origin[2]),
        rotation=None if rotation is None else (rotation[0], rotation[1], rotation[2],
                                                rotation[3]),
    )


def object_setup(
    rigid_body: str | Mapping[str, Any] | None, object_markers: Mapping[str, Any] | None
) -> ObjectSetup | None:
    """The set-up from the annotations' ``rigid_body`` and ``object_markers``; None if neither.

    Raises
    ------
    DemonstrationError
        Object markers that cannot give a pose (fewer than three, or on one line).
    """
    if rigid_body:
        return parse_rigid_body(rigid_body)
    if object_markers:
        return parse_object_setup({"markers": dict(object_markers)})
    return None


def parse_object_setup(raw: object) -> ObjectSetup:
    """Read ``{"rigid_body": name}`` or ``{"markers": {name: [x, y, z], ...}}``.

    Raises
    ------
    DemonstrationError
        Anything else, or fewer than three finite points, or points on one line.
    """
    hint = ('expected "rigid_body": "<name>" or "object_markers": {"<name>": [x, y, z], ...} '
            "(positions in the model frame, model units)")
    if not isinstance(raw, Mapping) or len(raw) != 1 or not set(raw) <= {"rigid_body",
                                                                         "markers"}:
        raise DemonstrationError(f"object tracking: {hint}, got {raw!r:.120}")
    if "rigid_body" in raw:
        return parse_rigid_body(raw["rigid_body"])
    layout = raw["markers"]
    if not isinstance(layout, Mapping) or len(layout) < 3:
        raise DemonstrationError(
            f"'object_markers' must map three or more marker names to their positions on "
            f"the object to give its pose; {hint}, got {layout!r:.120}"
        )
    out: list[tuple[str, tuple[float, float, float]]] = []
    for name, x in layout.items():
        ok = (isinstance(x, (list, tuple)) and len(x) == 3 and all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c)
            for c in x))
        if not isinstance(name, str) or not name or not ok:
            raise DemonstrationError(
                f"'object_markers': {name!r} must have a position [x, y, z] of three finite "
                f"numbers, got {x!r}"
            )
        out.append((name, (float(x[0]), float(x[1]), float(x[2]))))
    pts = np.array([x for _, x in out])
    if np.linalg.matrix_rank(pts - pts.mean(axis=0), tol=1e-9 * (1 + np.abs(pts).max())) < 2:
        raise DemonstrationError(
            "'object_markers' lie on one line, which leaves the object's rotation about "
            "it unknown; use three markers not in a line"
        )
    return ObjectSetup(markers=tuple(out))
