"""Motion-capture files: C3D and OptiTrack Motive CSV exports, read into marker trajectories.

The paper captures demonstrations with an OptiTrack V120:Duo (Section VI); its software, Motive,
exports takes as CSV or C3D. Both readers return a
:class:`~nonprehensile.demonstrations.record.MarkerTrajectory` in this library's world frame
(``z`` up) with NaN where a marker was occluded, and both writers produce files that read back
to the same trajectory (within the files' number formatting).

Axes. Motive's global frame is right-handed with ``y`` up. The readers turn a ``y``-up file
into our ``z``-up frame by the proper rotation of +90 degrees about ``x``::

    (x, y, z)_file  ->  (x, -z, y)_ours        and back:  (x, y, z)_ours -> (x, z, -y)_file

so the file's up axis becomes ours and handedness is kept. ``up="z"`` reads the file's axes as
they are (C3D files from biomechanics software, or Motive exports made with a ``z``-up axis
convention); it is the default for C3D, and ``up="y"`` the default for Motive CSV.

C3D is read and written with ezc3d, imported only when needed (the ``mocap`` extra). The Motive
CSV layout is parsed by hand with :mod:`csv`: no library reads it, and its header rows must be
checked cell by cell to give the user a precise message.
"""

from __future__ import annotations

import csv
import math
import warnings
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from nonprehensile.bounds import check_path
from nonprehensile.demonstrations.c3d_safe import parse_c3d
from nonprehensile.demonstrations.record import (
    MAX_RATE_HZ,
    MIN_RATE_HZ,
    MarkerTrajectory,
    PoseTrajectory,
    rate_in_range,
)
from nonprehensile.errors import DemonstrationError
from nonprehensile.geometry.build import face_name

__all__ = [
    "C3D_MAX_FRAMES",
    "MOTIVE_LENGTH_UNITS",
    "MOTIVE_MARKER_TYPES",
    "MOTIVE_ROTATION_TYPES",
    "read_c3d",
    "read_motive_csv",
    "write_c3d",
    "write_motive_csv",
]

FloatArray = NDArray[np.float64]
UpAxis = Literal["y", "z"]

#: Motive's "Length Units" values: our units and the factor that converts to them.
MOTIVE_LENGTH_UNITS: dict[str, tuple[str, float]] = {
    "Meters": ("m", 1.0),
    "Millimeters": ("mm", 1.0),
    "Centimeters": ("mm", 10.0),
}
_MOTIVE_UNIT_NAME = {"m": "Meters", "mm": "Millimeters"}

#: Motive column types that hold marker positions (X, Y, Z under "Position").
MOTIVE_MARKER_TYPES = ("Marker", "Rigid Body Marker", "Bone Marker")

#: Motive's "Rotation Type" values: quaternions, or Euler angles in degrees about the body's
#: own (moving) axes in the order named (Motive's "relative" Euler angles, right-handed).
MOTIVE_ROTATION_TYPES = ("Quaternion", "XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")

#: Most frames a C3D file can count: its header and POINT:FRAMES are 16-bit, and ezc3d (1.7)
#: reads no further even when more were written (ezc3d issue #372).
C3D_MAX_FRAMES = 65535

#: C3D POINT:UNITS values: our units and the factor that converts to them.
_C3D_UNITS: dict[str, tuple[str, float]] = {"m": ("m", 1.0), "mm": ("mm", 1.0), "cm": ("mm", 10.0)}

# Motive 2.3 has been seen writing "Time (Seconds)" truncated to whole milliseconds (frame 1 at
# 120 Hz written 0.008000), so the time check tolerates that much besides a quarter period.
_MOTIVE_TIME_TRUNCATION = 1.1e-3
# header rows sit between the metadata row and the "Frame" row; more than this is not Motive's
_MAX_HEADER_ROWS = 12


def _check_up(up: object) -> UpAxis:
    if up not in ("y", "z"):
        raise DemonstrationError(
            f"up must be 'y' (the file's y axis points up, Motive's default) or 'z', got {up!r}"
        )
    return "y" if up == "y" else "z"


def _to_ours(p: FloatArray, up: UpAxis) -> FloatArray:
    """File axes -> ours: ``(x, y, z) -> (x, -z, y)`` when the file is ``y``-up."""
    if up == "z":
        return p
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def _from_ours(p: FloatArray, up: UpAxis) -> FloatArray:
    """Ours -> file axes: ``(x, y, z) -> (x, z, -y)`` when the file is ``y``-up."""
    if up == "z":
        return p
    return np.stack([p[..., 0], p[..., 2], -p[..., 1]], axis=-1)


def _col(j: int) -> str:
    """1-based column number and spreadsheet letter of 0-based column ``j``."""
    return f"column {j + 1} ({face_name(j).upper()})"


def _format_number(x: float) -> str:
    """Six decimals as Motive writes, or ``repr`` where six decimals would change the value."""
    s = f"{x:.6f}"
    return s if float(s) == x else repr(x)


# --------------------------------------------------------------------------------------------
# C3D


def _import_ezc3d(path: Path) -> Any:
    try:
        import ezc3d  # optional dependency: only C3D files need it
    except ImportError:
        raise DemonstrationError(
            f"{path}: C3D files need ezc3d; install it with `pip install 'nonprehensile[mocap]'`"
        ) from None
    return ezc3d


def _c3d_param(c3d: Any, name: str) -> Any:
    try:
        return c3d["parameters"]["POINT"][name]["value"]
    except (KeyError, TypeError):
        return None


def read_c3d(path: str | Path, *, up: UpAxis = "z") -> MarkerTrajectory:
    """Read the 3-D points of a C3D file as a marker trajectory.

    Reads the point data, ``POINT:LABELS`` (and ``LABELS2``, ``LABELS3``, ... when a file has
    more than 255 points), ``POINT:RATE`` (else the header's frame rate) and ``POINT:UNITS``.
    A point whose residual is negative (C3D's mark of an invalid, occluded point) or whose
    coordinates are NaN becomes NaN.

    Parameters
    ----------
    path : str or Path
        The C3D file.
    up : {"z", "y"}
        Which of the file's axes points up; ``"y"`` rotates a ``y``-up file (Motive's default
        C3D axes) into our ``z``-up frame, see the module notes.

    Returns
    -------
    MarkerTrajectory
        Positions, shape (n_frames, n_points, 3), in ``"m"`` or ``"mm"`` as the file states
        (centimetres are converted to millimetres).

    Raises
    ------
    DemonstrationError
        Missing ezc3d, missing or unreadable file, no points, missing or bad rate, unknown
        units, missing, blank or repeated labels; the message names the file.
    """
    path = check_path(path)
    _import_ezc3d(path)
    if not path.is_file():
        raise DemonstrationError(f"{path}: no such C3D file")
    up = _check_up(up)
    # checked, then parsed in a worker process: a damaged file can crash or hang ezc3d
    c3d = parse_c3d(path)

    points = np.asarray(c3d["data"]["points"], dtype=np.float64)
    if points.ndim != 3 or points.shape[1] == 0 or points.shape[2] == 0:
        raise DemonstrationError(
            f"{path}: the file holds no 3-D point data (points array of shape {points.shape}); "
            "export the markers as points"
        )
    n_points = points.shape[1]
    positions = np.transpose(points[:3], (2, 1, 0)).copy()  # (frames, points, xyz)
    residuals = c3d["data"].get("meta_points", {}).get("residuals")
    if residuals is not None:
        res = np.asarray(residuals, dtype=np.float64)
        if res.shape == (1, n_points, positions.shape[0]):
            positions[res[0].T < 0] = np.nan

    rate_value = _c3d_param(c3d, "RATE")
    rate = float(np.ravel(rate_value)[0]) if rate_value is not None and np.size(rate_value) else 0
    if not (math.isfinite(rate) and rate > 0):
        rate = float(c3d["header"]["points"].get("frame_rate", 0.0) or 0.0)
    if not (math.isfinite(rate) and rate > 0):
        raise DemonstrationError(
            f"{path}: no valid point rate (POINT:RATE is {rate_value!r}, the header's frame rate "
            "is missing); set POINT:RATE to the capture rate in Hz"
        )
    if not rate_in_range(rate):
        raise DemonstrationError(
            f"{path}: the point rate is {rate:g} Hz, outside {MIN_RATE_HZ:g} to "
            f"{MAX_RATE_HZ:g} Hz (a damaged or wrong POINT:RATE); set POINT:RATE to the "
            "capture rate in Hz"
        )

    units_value = _c3d_param(c3d, "UNITS")
    if not units_value:
        raise DemonstrationError(
            f"{path}: POINT:UNITS is missing; set it to 'mm' or 'm' in the capture software"
        )
    raw_units = str(units_value[0]).strip()
    if raw_units.lower() not in _C3D_UNITS:
        raise DemonstrationError(
            f"{path}: POINT:UNITS is {raw_units!r}; expected one of {sorted(_C3D_UNITS)}"
        )
    units, scale = _C3D_UNITS[raw_units.lower()]

    labels: list[str] = []
    group = c3d["parameters"]["POINT"]
    for key in ["LABELS", *(f"LABELS{k}" for k in range(2, 100))]:
        if key not in group:
            break
        labels.extend(str(s).strip() for s in group[key]["value"])
    labels = labels[:n_points]
    if len(labels) < n_points:
        raise DemonstrationError(
            f"{path}: {n_points} points but only {len(labels)} labels in POINT:LABELS; label "
            "every marker in the capture software"
        )
    blank = [k + 1 for k, s in enumerate(labels) if not s]
    if blank:
        raise DemonstrationError(f"{path}: point {blank[0]} has a blank label; label it")
    for k, s in enumerate(labels):
        if labels.index(s) != k:
            raise DemonstrationError(
                f"{path}: label {s!r} names points {labels.index(s) + 1} and {k + 1}; marker "
                "labels must be unique, rename one"
            )
    if np.isinf(positions).any():
        raise DemonstrationError(f"{path}: the point data holds infinite coordinates")

    return MarkerTrajectory.from_arrays(_to_ours(positions * scale, up), labels, rate, units)


def write_c3d(traj: MarkerTrajectory, path: str | Path, *, up: UpAxis = "z") -> None:
    """Write a marker trajectory as a C3D file (float point data, no analogs).

    Occluded markers are written as C3D's invalid points: residual ``-1`` and coordinates 0,
    so every C3D reader sees them as missing. ``POINT:UNITS`` is the trajectory's units.

    Parameters
    ----------
    traj : MarkerTrajectory
        The trajectory.
    path : str or Path
        The file to write (overwritten).
    up : {"z", "y"}
        Which of the file's axes is to point up (see :func:`read_c3d`).

    Raises
    ------
    DemonstrationError
        Missing ezc3d, more than :data:`C3D_MAX_FRAMES` frames, or the file cannot be written.
    """
    path = Path(path)
    ezc3d = _import_ezc3d(path)
    up = _check_up(up)
    if traj.n_frames > C3D_MAX_FRAMES:
        # writing would succeed, but every reader (ezc3d included) stops at 65535 frames, so
        # the rest of the take would be lost without a word
        raise DemonstrationError(
            f"{path}: {traj.n_frames} frames do not fit a C3D file, which counts at most "
            f"{C3D_MAX_FRAMES} ({C3D_MAX_FRAMES / traj.rate:.0f} s at {traj.rate:g} Hz); split "
            "the trajectory or write it as Motive CSV"
        )
    pos = _from_ours(np.asarray(traj.positions), up)  # (frames, markers, 3)
    occluded = traj.occluded
    n_frames, n_markers = occluded.shape
    points = np.ones((4, n_markers, n_frames))
    points[:3] = np.transpose(np.where(np.isnan(pos), 0.0, pos), (2, 1, 0))
    residuals = np.where(occluded.T, -1.0, 0.0)[np.newaxis]

    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [traj.rate]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(traj.marker_names)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = [traj.units]
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {
        "residuals": residuals,
        "camera_masks": np.zeros((7, n_markers, n_frames), dtype=bool),
    }
    try:
        c3d.write(str(path))
    except Exception as exc:  # ezc3d reports I/O failures as bare RuntimeError
        raise DemonstrationError(f"{path}: cannot write the C3D file: {exc}") from None


# --------------------------------------------------------------------------------------------
# Motive CSV


def _read_rows(path: Path) -> list[list[str]]:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DemonstrationError(f"{path}: cannot read the file: {exc.strerror}") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        # Motive writes the capture start time in the Windows locale (e.g. a Chinese "PM"),
        # which only the metadata row holds; latin-1 decodes any byte and numbers are ASCII
        text = data.decode("latin-1")
    try:
        return list(csv.reader(text.splitlines()))
    except csv.Error as exc:
        raise DemonstrationError(f"{path}: not a readable CSV file: {exc}") from None


def _metadata(row: Sequence[str]) -> dict[str, str]:
    """Motive's first row: ``key, value, key, value, ...``."""
    return {row[i].strip(): row[i + 1].strip() for i in range(0, len(row) - 1, 2)}


def _cell(row: Sequence[str], j: int) -> str:
    return row[j].strip() if j < len(row) else ""


def read_motive_csv(
    path: str | Path,
    *,
    marker_types: Sequence[str] = ("Marker",),
    up: UpAxis = "y",
    time_tol: float | None = None,
) -> MarkerTrajectory:
    """Read the marker positions of an OptiTrack Motive CSV export.

    The layout (Motive 1.x to 3.x, CSV format versions 1.21 to 1.25): row 1 holds metadata
    pairs (``Format Version``, ``Take Name``, ``Capture Frame Rate``, ``Export Frame Rate``,
    ``Capture Start Time``, ``Total Frames in Take``, ``Rotation Type``, ``Length Units``,
    ``Coordinate Space``, ...); a blank row; the header rows ``Type`` (Marker, Rigid Body,
    Rigid Body Marker, Bone, Bone Marker), ``Name``, ``ID`` (labelled in column 2; unlabelled,
    in that order, in format 1.21), the row of ``Position`` / ``Rotation`` / quality columns,
    and the row ``Frame, Time (Seconds), X, Y, Z, ...``; then one row per frame. Data
    columns start at column 3. A blank cell is an occluded marker.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    marker_types : sequence of str
        Column types to read markers from: ``"Marker"`` (measured markers; the default),
        ``"Rigid Body Marker"`` / ``"Bone Marker"`` (where the solved asset expects them).
        Motive names a rigid body's measured and expected markers alike, so reading both
        types from one file fails on the repeated names; read one type at a time.
    up : {"y", "z"}
        Which of the file's axes points up: ``"y"`` (Motive's global frame) is rotated to our
        ``z``-up frame by ``(x, y, z) -> (x, -z, y)``; ``"z"`` keeps the axes (exports made
        with a ``z``-up axis convention).
    time_tol : float, optional
        Largest accepted difference, in seconds, between a row's time and
        ``t_0 + (frame - frame_0) / rate``. Default: a quarter of a frame period, and at least
        1.1 ms because Motive 2.3 has been seen truncating times to whole milliseconds.

    Returns
    -------
    MarkerTrajectory
        Positions, shape (n_frames, n_markers, 3), in ``"mm"`` or ``"m"`` as the file's
        ``Length Units`` (centimetres are converted to millimetres); rate from
        ``Export Frame Rate`` (``Capture Frame Rate`` in files without it); marker names from
        the ``Name`` row, in column order.

    Raises
    ------
    DemonstrationError
        Missing file; a layout that is not Motive's (the message names the row and column);
        no columns of ``marker_types``; a non-numeric cell (row, column, marker and axis);
        unknown ``Length Units``; a missing or invalid frame rate; frames that are not
        consecutive or times that do not follow the rate (the row).
    """
    path = Path(path)
    up = _check_up(up)
    if isinstance(marker_types, str):
        marker_types = (marker_types,)
    if not path.is_file():
        raise DemonstrationError(f"{path}: no such Motive CSV file")
    rows = _read_rows(path)
    if not rows or _cell(rows[0], 0) != "Format Version":
        first = rows[0][:2] if rows else []
        raise DemonstrationError(
            f"{path}: row 1 should be Motive's metadata row starting 'Format Version', got "
            f"{first!r}; is this a CSV file exported from OptiTrack Motive?"
        )
    meta = _metadata(rows[0])

    # --- header rows ---
    axis_r = next(
        (r for r in range(1, min(len(rows), _MAX_HEADER_ROWS + 2)) if _cell(rows[r], 0) == "Frame"),
        None,
    )
    if axis_r is None:
        raise DemonstrationError(
            f"{path}: no header row starting 'Frame' (the 'Frame, Time (Seconds), X, Y, Z' row) "
            f"in rows 2-{min(len(rows), _MAX_HEADER_ROWS + 1)}; the file is not a Motive export "
            "or its header was edited"
        )
    axis_row = rows[axis_r]
    if not _cell(axis_row, 1).startswith("Time"):
        raise DemonstrationError(
            f"{path}: row {axis_r + 1}, {_col(1)}: expected 'Time (Seconds)', got "
            f"{_cell(axis_row, 1)!r}"
        )
    if not any(c.strip() for c in axis_row[2:]):
        # (Motive writes the header rows of a take exported with nothing selected: its
        # frames and times, no data column)
        raise DemonstrationError(
            f"{path}: row {axis_r + 1}: no marker or rigid-body column after 'Frame' and "
            "'Time (Seconds)': the take was exported without markers or rigid bodies; export "
            "it again with them selected (Motive's CSV export: Markers, Rigid Bodies)"
        )
    header = [r for r in range(1, axis_r) if any(c.strip() for c in rows[r])]
    if not header or _cell(rows[header[-1]], 1) != "":
        raise DemonstrationError(
            f"{path}: row {axis_r}: expected the row naming each column's data "
            "('Position', 'Rotation', ...) just above the 'Frame' row"
        )
    prop_row = rows[header[-1]]
    labelled = {_cell(rows[r], 1): rows[r] for r in header[:-1] if _cell(rows[r], 1)}
    if labelled:
        missing = [k for k in ("Type", "Name") if k not in labelled]
        if missing:
            raise DemonstrationError(
                f"{path}: no {missing[0]!r} row among header rows {header[0] + 1}-"
                f"{header[-1] + 1} (column 2 of each names the row); the header was edited"
            )
        type_row, name_row = labelled["Type"], labelled["Name"]
        name_r = next(r for r in header if _cell(rows[r], 1) == "Name")
    elif len(header) >= 4:
        # format 1.21 leaves the label cells empty: Type, Name, ID come in that order
        type_row, name_row, name_r = rows[header[0]], rows[header[1]], header[1]
    else:
        raise DemonstrationError(
            f"{path}: expected the header rows 'Type', 'Name', 'ID' and 'Position' above row "
            f"{axis_r + 1}, found {len(header)} non-blank rows there"
        )

    # --- marker columns ---
    width = max(len(type_row), len(name_row), len(prop_row), len(axis_row))
    columns: dict[tuple[str, str], dict[str, int]] = {}
    for j in range(2, width):
        kind = _cell(type_row, j)
        if kind not in marker_types or _cell(prop_row, j) != "Position":
            continue
        name, axis = _cell(name_row, j), _cell(axis_row, j)
        if not name:
            raise DemonstrationError(
                f"{path}: row {name_r + 1}, {_col(j)}: a {kind} column without a name"
            )
        axes = columns.setdefault((kind, name), {})
        if axis not in ("X", "Y", "Z") or axis in axes:
            raise DemonstrationError(
                f"{path}: row {axis_r + 1}, {_col(j)}: {kind} {name!r} has a Position column "
                f"labelled {axis!r}; expected one X, one Y and one Z"
            )
        axes[axis] = j
    bodies = _rigid_body_columns(path, type_row, name_row, prop_row, axis_row, axis_r, width)
    if not columns:
        present = sorted({_cell(type_row, j) for j in range(2, width)} - {""})
        raise DemonstrationError(
            f"{path}: no marker positions of type {' or '.join(map(repr, marker_types))}; the "
            f"Type row has {present}. Export with 'Markers' enabled, or choose marker_types "
            f"among {list(MOTIVE_MARKER_TYPES)}"
        )
    names: list[str] = []
    cols: list[list[int]] = []
    for (kind, name), axes in columns.items():
        if set(axes) != {"X", "Y", "Z"}:
            lacking = sorted({"X", "Y", "Z"} - set(axes))
            raise DemonstrationError(
                f"{path}: {kind} {name!r} has no Position {'/'.join(lacking)} column "
                f"(row {axis_r + 1}); the header was edited or the export is truncated"
            )
        if name in names:
            raise DemonstrationError(
                f"{path}: the name {name!r} is used by more than one of the marker types "
                f"{list(marker_types)}; read one type at a time"
            )
        names.append(name)
        cols.append([axes["X"], axes["Y"], axes["Z"]])

    # --- metadata: units and rate ---
    raw_units = meta.get("Length Units")
    if raw_units is None:
        raise DemonstrationError(
            f"{path}: row 1 has no 'Length Units'; re-export from Motive (CSV format 1.2 or "
            "later states them)"
        )
    if raw_units not in MOTIVE_LENGTH_UNITS:
        raise DemonstrationError(
            f"{path}: row 1: unknown Length Units {raw_units!r}; expected one of "
            f"{sorted(MOTIVE_LENGTH_UNITS)}"
        )
    units, scale = MOTIVE_LENGTH_UNITS[raw_units]
    rate_key = "Export Frame Rate" if "Export Frame Rate" in meta else "Capture Frame Rate"
    try:
        rate = float(meta[rate_key])
    except KeyError:
        raise DemonstrationError(
            f"{path}: row 1 has neither 'Export Frame Rate' nor 'Capture Frame Rate'; the frame "
            "rate is needed to time the samples"
        ) from None
    except ValueError:
        rate = math.nan
    if not rate_in_range(rate):
        raise DemonstrationError(
            f"{path}: row 1: {rate_key} is {meta[rate_key]!r}; expected a number of Hz from "
            f"{MIN_RATE_HZ:g} to {MAX_RATE_HZ:g}"
        )

    rotation_type = meta.get("Rotation Type", "Quaternion")
    if any(len(rot) == 3 for rot, _ in bodies.values()) and rotation_type not in \
            MOTIVE_ROTATION_TYPES[1:]:
        raise DemonstrationError(
            f"{path}: row 1: Rotation Type is {rotation_type!r} but rigid bodies have three "
            f"rotation columns (Euler angles); expected one of {list(MOTIVE_ROTATION_TYPES[1:])}"
        )

    # --- data rows ---
    flat = [j for c in cols for j in c]
    what = [f"marker {names[k // 3]!r}, {'XYZ'[k % 3]}" for k in range(len(flat))]
    for bname, (rot, posc) in bodies.items():
        flat += rot + posc
        what += [f"rigid body {bname!r}, rotation {'XYZW'[i]}" for i in range(len(rot))]
        what += [f"rigid body {bname!r}, position {'XYZ'[i]}" for i in range(3)]
    last = max(flat)
    frames: list[int] = []
    times: list[float] = []
    values: list[list[float]] = []
    line_of: list[int] = []
    for r in range(axis_r + 1, len(rows)):
        row = rows[r]
        if not any(c.strip() for c in row):
            continue
        if len(row) <= last:
            raise DemonstrationError(
                f"{path}: row {r + 1} has {len(row)} cells but the header has marker columns up "
                f"to {_col(last)}; the file is truncated or was edited"
            )
        try:
            frames.append(int(row[0]))
        except ValueError:
            raise DemonstrationError(
                f"{path}: row {r + 1}, {_col(0)} (Frame): expected a whole frame number, got "
                f"{row[0]!r}"
            ) from None
        try:
            times.append(float(row[1]))
        except ValueError:
            raise DemonstrationError(
                f"{path}: row {r + 1}, {_col(1)} (Time): expected a number of seconds, got "
                f"{row[1]!r}"
            ) from None
        out: list[float] = []
        for j in flat:
            s = row[j].strip()
            try:
                v = float(s) if s else math.nan
            except ValueError:
                v = math.inf  # reported below, with the marker's name
            if math.isinf(v):
                raise DemonstrationError(
                    f"{path}: row {r + 1}, {_col(j)} ({what[flat.index(j)]}): expected a "
                    f"number or a blank cell, got {row[j]!r}"
                )
            out.append(v)
        values.append(out)
        line_of.append(r + 1)
    if not values:
        raise DemonstrationError(f"{path}: no data rows below the header (row {axis_r + 1})")

    f = np.asarray(frames)
    bad = np.flatnonzero(np.diff(f) != 1)
    if bad.size:
        i = int(bad[0]) + 1
        raise DemonstrationError(
            f"{path}: row {line_of[i]}: frame {frames[i]} follows frame {frames[i - 1]}; frames "
            "must be consecutive (export the take without gaps or edits)"
        )
    tol = max(0.25 / rate, _MOTIVE_TIME_TRUNCATION) if time_tol is None else float(time_tol)
    expected = times[0] + (f - f[0]) / rate
    off = np.abs(np.asarray(times) - expected)
    if (off > tol).any():
        i = int(np.argmax(off > tol))
        raise DemonstrationError(
            f"{path}: row {line_of[i]}: time {times[i]!r} s of frame {frames[i]} does not match "
            f"{rate_key} {rate:g} Hz (expected {expected[i]:.6f} s, tolerance {tol:.2g} s); "
            "the rate in row 1 is wrong or rows are missing"
        )

    table = np.asarray(values, dtype=np.float64)
    n_mark = 3 * len(names)
    file_xyz = table[:, :n_mark].reshape(len(values), len(names), 3)
    poses: list[PoseTrajectory] = []
    at = n_mark
    for bname, (rot, _) in bodies.items():
        k = len(rot)
        q_file = _file_quaternions(table[:, at:at + k], rotation_type, path, bname)
        p_file = table[:, at + k:at + k + 3] * scale
        at += k + 3
        poses.append(PoseTrajectory(bname, _to_ours(p_file, up), _quat_to_ours(q_file, up),
                                    rate, "m" if units == "m" else "mm"))
    return MarkerTrajectory.from_arrays(_to_ours(file_xyz * scale, up), names, rate, units,
                                        poses)


def _rigid_body_columns(
    path: Path, type_row: Sequence[str], name_row: Sequence[str], prop_row: Sequence[str],
    axis_row: Sequence[str], axis_r: int, width: int,
) -> dict[str, tuple[list[int], list[int]]]:
    """Rigid body name -> (rotation columns X, Y, Z[, W], position columns X, Y, Z)."""
    found: dict[str, dict[str, dict[str, int]]] = {}
    for j in range(2, width):
        if _cell(type_row, j) != "Rigid Body":
            continue
        prop = _cell(prop_row, j)
        if prop not in ("Rotation", "Position"):
            continue  # Mean Marker Error, Marker Quality, ...
        name, axis = _cell(name_row, j), _cell(axis_row, j)
        if not name:
            raise DemonstrationError(
                f"{path}: {_col(j)}: a Rigid Body column without a name"
            )
        axes = found.setdefault(name, {}).setdefault(prop, {})
        if axis not in ("X", "Y", "Z", "W") or axis in axes or (prop == "Position"
                                                               and axis == "W"):
            raise DemonstrationError(
                f"{path}: row {axis_r + 1}, {_col(j)}: rigid body {name!r} has a {prop} "
                f"column labelled {axis!r}; expected X, Y, Z (and W for a quaternion)"
            )
        axes[axis] = j
    out: dict[str, tuple[list[int], list[int]]] = {}
    for name, props in found.items():
        rot, pos = props.get("Rotation", {}), props.get("Position", {})
        if set(pos) != {"X", "Y", "Z"} or set(rot) not in ({"X", "Y", "Z"}, {"X", "Y", "Z", "W"}):
            raise DemonstrationError(
                f"{path}: rigid body {name!r} needs Rotation X, Y, Z (and W) and Position X, Y, "
                f"Z columns, got Rotation {sorted(rot)} and Position {sorted(pos)} (row "
                f"{axis_r + 1}); export rigid bodies whole"
            )
        out[name] = ([rot[a] for a in "XYZW" if a in rot], [pos[a] for a in "XYZ"])
    return out


def _file_quaternions(
    cells: FloatArray, rotation_type: str, path: Path, name: str
) -> FloatArray:
    """Rotation cells of one rigid body (quaternion or Euler degrees) -> quaternions (x,y,z,w)."""
    ok = ~np.isnan(cells).any(axis=1)
    out = np.full((len(cells), 4), np.nan)
    if cells.shape[1] == 4:
        out[ok] = cells[ok]
        zero = ok & (np.linalg.norm(np.nan_to_num(cells), axis=1) < 1e-9)
        if zero.any():
            raise DemonstrationError(
                f"{path}: rigid body {name!r}: data row {int(np.argmax(zero)) + 1} has a "
                "quaternion of zero length"
            )
    elif ok.any():
        # columns hold the angles about X, Y, Z; the type names the order of the rotations
        angles = cells[ok][:, ["XYZ".index(a) for a in rotation_type]]
        out[ok] = Rotation.from_euler(rotation_type, angles, degrees=True).as_quat()
    return out


def _quat_to_ours(q: FloatArray, up: UpAxis) -> FloatArray:
    """A body rotation in file axes -> ours: ``C R C^T``, i.e. the vector part turned by C."""
    return np.concatenate([_to_ours(q[:, :3], up), q[:, 3:]], axis=1)


def _quat_from_ours(q: FloatArray, up: UpAxis) -> FloatArray:
    return np.concatenate([_from_ours(q[:, :3], up), q[:, 3:]], axis=1)


def write_motive_csv(
    traj: MarkerTrajectory,
    path: str | Path,
    *,
    take_name: str | None = None,
    start_time: datetime | None = None,
    up: UpAxis = "y",
    decimals: int = 6,
    rotation_type: str = "Quaternion",
) -> None:
    """Write a marker trajectory in Motive's CSV export layout (format version 1.23).

    Each rigid body of ``traj.rigid_bodies`` comes first, as Motive writes them: ``Rigid
    Body`` columns ``Rotation X, Y, Z, W`` (or ``X, Y, Z`` Euler degrees) and ``Position X,
    Y, Z``, blank where untracked. Every marker is a ``Marker`` column triple ``X, Y, Z``
    under ``Position``; occluded frames are blank cells; frames are numbered from 0 and timed
    ``frame / rate``. :func:`read_motive_csv` reads the file back to ``traj`` within
    ``0.5 * 10**-decimals`` (quaternions as written; Euler angles give the same rotations).

    Parameters
    ----------
    traj : MarkerTrajectory
        The trajectory.
    path : str or Path
        The file to write (overwritten).
    take_name : str, optional
        Motive's take name; default the file's stem.
    start_time : datetime, optional
        The capture start time; left blank when unknown.
    up : {"y", "z"}
        Which of the file's axes is to point up (see :func:`read_motive_csv`).
    decimals : int
        Decimals of positions and rotations (Motive writes 6).
    rotation_type : str
        One of :data:`MOTIVE_ROTATION_TYPES`: ``"Quaternion"`` (Motive's default) or an
        Euler order such as ``"XYZ"``.

    Raises
    ------
    DemonstrationError
        The file cannot be written, ``decimals`` is negative or the rotation type unknown.
    """
    path = Path(path)
    up = _check_up(up)
    if rotation_type not in MOTIVE_ROTATION_TYPES:
        raise DemonstrationError(
            f"rotation_type must be one of {list(MOTIVE_ROTATION_TYPES)}, got {rotation_type!r}"
        )
    if isinstance(decimals, bool) or not isinstance(decimals, int) or decimals < 0:
        raise DemonstrationError(f"decimals must be a whole number >= 0, got {decimals!r}")
    rate = _format_number(traj.rate)
    start = ""
    if start_time is not None:
        start = start_time.strftime("%Y-%m-%d %I.%M.%S.") + f"{start_time.microsecond // 1000:03d}"
        start += start_time.strftime(" %p")
    n = traj.n_frames
    meta = [
        "Format Version", "1.23",
        "Take Name", path.stem if take_name is None else take_name,
        "Take Notes", "",
        "Capture Frame Rate", rate,
        "Export Frame Rate", rate,
        "Capture Start Time", start,
        "Capture Start Frame", "0",
        "Total Frames in Take", str(n),
        "Total Exported Frames", str(n),
        "Rotation Type", rotation_type,
        "Length Units", _MOTIVE_UNIT_NAME[traj.units],
        "Coordinate Space", "Global",
    ]  # fmt: skip
    rot_axes = "XYZW" if rotation_type == "Quaternion" else "XYZ"
    cols: list[tuple[str, str, str, str, str]] = []  # type, name, id, property, axis
    body_values: list[FloatArray] = []
    for b, body in enumerate(traj.rigid_bodies):
        bid = f"RB{b + 1}"
        cols += [("Rigid Body", body.name, bid, "Rotation", a) for a in rot_axes]
        cols += [("Rigid Body", body.name, bid, "Position", a) for a in "XYZ"]
        q = _quat_from_ours(np.asarray(body.quaternions), up)
        if rotation_type != "Quaternion":
            ok = ~np.isnan(q[:, 0])
            e = np.full((n, 3), np.nan)
            if ok.any():
                with warnings.catch_warnings():
                    # at gimbal lock scipy warns that the third angle is set to zero; the
                    # angles still give the same rotation, which is all a reader needs
                    warnings.simplefilter("ignore", UserWarning)
                    seq = Rotation.from_quat(q[ok]).as_euler(rotation_type, degrees=True)
                e[ok] = seq[:, [rotation_type.index(a) for a in "XYZ"]]
            q = e
        body_values.append(np.concatenate([q, _from_ours(np.asarray(body.positions), up)],
                                          axis=1))
    for k, name in enumerate(traj.marker_names):
        cols += [("Marker", name, str(k + 1), "Position", a) for a in "XYZ"]
    header = [
        meta,
        [],
        ["", "Type", *(c[0] for c in cols)],
        ["", "Name", *(c[1] for c in cols)],
        ["", "ID", *(c[2] for c in cols)],
        ["", "", *(c[3] for c in cols)],
        ["Frame", "Time (Seconds)", *(c[4] for c in cols)],
    ]
    pos = np.concatenate(
        [*body_values, _from_ours(np.asarray(traj.positions), up).reshape(n, -1)], axis=1
    )
    times = traj.times
    fmt = f"{{:.{decimals}f}}"
    try:
        with path.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerows(header)
            for i in range(n):
                cells = ["" if math.isnan(v) else fmt.format(v) for v in pos[i].tolist()]
                writer.writerow([str(i), f"{times[i]:.6f}", *cells])
    except OSError as exc:
        raise DemonstrationError(f"{path}: cannot write the file: {exc.strerror}") from None
