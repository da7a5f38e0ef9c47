"""Demonstrations: marker trajectories and the motion-capture files they come from (Section VI).

:class:`MarkerTrajectory` is a recording of named markers at a constant rate (NaN where a marker
is occluded); :func:`read_c3d` / :func:`write_c3d` and :func:`read_motive_csv` /
:func:`write_motive_csv` convert it from and to C3D and OptiTrack Motive CSV files.
"""

from __future__ import annotations

from nonprehensile.demonstrations.formats import (
    C3D_MAX_FRAMES,
    MOTIVE_LENGTH_UNITS,
    MOTIVE_MARKER_TYPES,
    MOTIVE_ROTATION_TYPES,
    read_c3d,
    read_motive_csv,
    write_c3d,
    write_motive_csv,
)
from nonprehensile.demonstrations.record import (
    UNITS,
    LengthUnits,
    MarkerTrajectory,
    PoseTrajectory,
    kabsch_poses,
)

__all__ = [
    "C3D_MAX_FRAMES",
    "MOTIVE_LENGTH_UNITS",
    "MOTIVE_MARKER_TYPES",
    "MOTIVE_ROTATION_TYPES",
    "UNITS",
    "LengthUnits",
    "MarkerTrajectory",
    "PoseTrajectory",
    "kabsch_poses",
    "read_c3d",
    "read_motive_csv",
    "write_c3d",
    "write_motive_csv",
]
