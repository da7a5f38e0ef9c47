"""Demonstration records: marker trajectories captured from a human demonstrator (Section VI).

The paper records the hand with an OptiTrack V120:Duo at 120 Hz, four retro-reflective markers
on the index finger and thumb. A :class:`MarkerTrajectory` is that recording as a value: the
positions of named markers sampled at a constant rate, with NaN where a marker was occluded.
Positions are in the world frame of this library (``z`` up, the ground is ``z = 0`` once
calibrated); the file readers in :mod:`nonprehensile.demonstrations.formats` convert to it.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation, Slerp

from nonprehensile.bounds import MAX_COORDINATE
from nonprehensile.errors import DemonstrationError

__all__ = ["MAX_RATE_HZ", "MIN_RATE_HZ", "UNITS", "LengthUnits", "MarkerTrajectory",
           "PoseTrajectory", "kabsch_poses", "rate_in_range"]

FloatArray = NDArray[np.float64]

#: Length units a trajectory may be stated in.
LengthUnits = Literal["m", "mm"]

#: Metres per unit, for each accepted unit.
UNITS: dict[str, float] = {"m": 1.0, "mm": 1e-3}

#: The sampling rates a recording may have, Hz: far beyond what motion capture records (a
#: tracker's 25 Hz to a few kHz) on both sides. A rate of 1e-30 Hz read from a damaged header
#: made a recording of 1e31 seconds and a LeRobot export of fps 0.
MIN_RATE_HZ = 0.01
MAX_RATE_HZ = 100_000.0


def rate_in_range(rate: float) -> bool:
    """Whether ``rate`` is a finite number of Hz from :data:`MIN_RATE_HZ` to
    :data:`MAX_RATE_HZ`."""
    return math.isfinite(rate) and MIN_RATE_HZ <= rate <= MAX_RATE_HZ


def _check_units(units: object, what: str) -> LengthUnits:
    if not isinstance(units, str) or units not in UNITS:
        raise DemonstrationError(
            f"{what}: units must be one of {sorted(UNITS)} (metres or millimetres), "
            f"got {units!r}; convert the data or state its units"
        )
    return cast(LengthUnits, units)


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(start, end exclusive) of each run of True in a 1-D mask."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=True))


@dataclass(frozen=True, eq=False)
class PoseTrajectory:
    """The tracked pose of a rigid body (the manipulated object) sampled at a constant rate.

    Frame ``i`` (time ``i / rate``) maps a point ``x`` of the body's own frame to the world
    point ``R_i @ x + p_i``, with ``R_i`` the rotation of the unit quaternion ``q_i``. The
    world frame is this library's (``z`` up), as for :class:`MarkerTrajectory`.

    Parameters
    ----------
    name : str
        The rigid body's name (Motive's asset name, e.g. ``"Box"``).
    positions : array, shape (n_frames, 3)
        ``p_i``, the body origin in the world, in ``units``; NaN where the body is not tracked.
    quaternions : array, shape (n_frames, 4)
        ``q_i`` scalar-last ``(x, y, z, w)`` (Motive's and scipy's order), normalised on
        construction; NaN where the body is not tracked.
    rate : float
        Sampling rate in Hz.
    units : {"m", "mm"}
        Length units of ``positions``.

    Raises
    ------
    DemonstrationError
        A malformed field; a frame with some but not all numbers NaN becomes wholly invalid,
        a quaternion of zero length is an error.
    """

    name: str
    positions: FloatArray
    quaternions: FloatArray
    rate: float
    units: LengthUnits = "m"

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise DemonstrationError(f"pose trajectory: name must be a non-empty string, got "
                                     f"{self.name!r}")
        try:
            pos = np.array(self.positions, dtype=np.float64, copy=True)
            quat = np.array(self.quaternions, dtype=np.float64, copy=True)
        except (TypeError, ValueError) as exc:
            raise DemonstrationError(
                f"pose trajectory {self.name!r}: positions and quaternions must be arrays of "
                f"numbers ({exc})"
            ) from None
        if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] < 1:
            raise DemonstrationError(
                f"pose trajectory {self.name!r}: positions must have shape (n_frames, 3), got "
                f"{pos.shape}"
            )
        if quat.shape != (pos.shape[0], 4):
            raise DemonstrationError(
                f"pose trajectory {self.name!r}: quaternions must have shape ({pos.shape[0]}, 4) "
                f"(x, y, z, w per frame), got {quat.shape}"
            )
        if np.isinf(pos).any() or np.isinf(quat).any():
            raise DemonstrationError(
                f"pose trajectory {self.name!r}: positions and quaternions must be finite "
                "(NaN marks an untracked frame)"
            )
        bad = np.isnan(pos).any(axis=1) | np.isnan(quat).any(axis=1)
        pos[bad] = np.nan
        quat[bad] = np.nan
        # scaled by the largest component first: the norm of (1e300, 1e300, 1e300, 1e300)
        # overflowed to inf and the quaternion was divided down to (0, 0, 0, 0), silently
        rows: NDArray[np.bool_] = np.asarray(bad, dtype=bool)
        peak = np.abs(np.where(rows[:, None], 1.0, quat)).max(axis=1)
        unit = quat / np.where(peak > 0, peak, 1.0)[:, None]  # components within [-1, 1]
        length = np.linalg.norm(unit, axis=1)
        with np.errstate(over="ignore"):  # (1.7e308 components: inf, a length, not zero)
            norm = length * peak  # the quaternion's length
        if (norm[~bad] < 1e-9).any():
            i = int(np.flatnonzero(~bad & (norm < 1e-9))[0])
            raise DemonstrationError(
                f"pose trajectory {self.name!r}: frame {i} has a quaternion of zero length; "
                "mark an untracked frame with NaN (blank cells)"
            )
        quat[~bad] = unit[~bad] / length[~bad, None]
        pos.setflags(write=False)
        quat.setflags(write=False)
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "quaternions", quat)
        rate = self.rate
        if isinstance(rate, bool) or not isinstance(rate, (int, float, np.integer, np.floating)) \
                or not rate_in_range(float(rate)):
            raise DemonstrationError(
                f"pose trajectory {self.name!r}: rate must be a number of Hz from "
                f"{MIN_RATE_HZ:g} to {MAX_RATE_HZ:g}, got {rate!r}"
            )
        object.__setattr__(self, "rate", float(rate))
        object.__setattr__(self, "units", _check_units(self.units, f"pose {self.name!r}"))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PoseTrajectory):
            return NotImplemented
        return (
            self.name == other.name and self.rate == other.rate and self.units == other.units
            and self.positions.shape == other.positions.shape
            and bool(np.array_equal(self.positions, other.positions, equal_nan=True))
            and bool(np.array_equal(self.quaternions, other.quaternions, equal_nan=True))
        )

    def __hash__(self) -> int:
        return hash((self.name, self.rate, self.units, self.positions.shape))

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return int(self.positions.shape[0])

    @property
    def valid(self) -> NDArray[np.bool_]:
        """Where the body is tracked, array of bool, shape (n_frames,)."""
        return ~np.isnan(self.positions[:, 0])

    @property
    def times(self) -> FloatArray:
        """Sample times ``i / rate``, seconds, shape (n_frames,)."""
        return np.arange(self.n_frames, dtype=np.float64) / self.rate

    @property
    def rotations(self) -> FloatArray:
        """Rotation matrices ``R_i``, shape (n_frames, 3, 3); NaN where not tracked."""
        out = np.full((self.n_frames, 3, 3), np.nan)
        ok = self.valid
        if ok.any():
            out[ok] = Rotation.from_quat(self.quaternions[ok]).as_matrix()
        return out

    def to_units(self, units: str) -> PoseTrajectory:
        """The same poses with positions in ``units`` (``"m"`` or ``"mm"``)."""
        target = _check_units(units, "to_units")
        if target == self.units:
            return self
        k = UNITS[self.units] / UNITS[target]
        return PoseTrajectory(self.name, self.positions * k, self.quaternions, self.rate, target)

    def transform(self, points: ArrayLike) -> FloatArray:
        """World positions of body-frame points in every frame.

        Parameters
        ----------
        points : array, shape (m, 3)
            Points in the body frame, in ``units``.

        Returns
        -------
        array, shape (n_frames, m, 3)
            ``R_i @ x + p_i``; NaN in frames where the body is not tracked.
        """
        x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.asarray(np.einsum("nij,mj->nmi", self.rotations, x)
                          + self.positions[:, None, :])

    def with_body_frame(self, rotation: ArrayLike, translation: ArrayLike) -> PoseTrajectory:
        """The pose of another frame fixed to the body.

        Parameters
        ----------
        rotation : array, shape (3, 3)
            Orientation of the new frame in the body frame (new-to-body rotation).
        translation : array, shape (3,)
            Origin of the new frame in the body frame, in ``units``.

        Returns
        -------
        PoseTrajectory
            Poses mapping the new frame to the world: ``R_i @ rotation``,
            ``R_i @ translation + p_i``.
        """
        rb = Rotation.from_matrix(np.asarray(rotation, dtype=np.float64))
        tb = np.asarray(translation, dtype=np.float64).reshape(3)
        quat = np.full_like(self.quaternions, np.nan)
        pos = np.full_like(self.positions, np.nan)
        ok = self.valid
        if ok.any():
            r = Rotation.from_quat(self.quaternions[ok])
            quat[ok] = (r * rb).as_quat()
            pos[ok] = r.apply(tb) + self.positions[ok]
        return PoseTrajectory(self.name, pos, quat, self.rate, self.units)

    def gaps(self) -> list[tuple[int, int]]:
        """Runs of untracked frames, as (first, end exclusive) frame pairs."""
        return _runs(~self.valid)

    def filled(self, max_gap: int) -> PoseTrajectory:
        """Short gaps filled: positions linearly, rotations by slerp.

        A run of at most ``max_gap`` untracked frames between two tracked ones is filled;
        longer runs, and runs at the start or the end (with a tracked frame on one side
        only), stay invalid, for the caller to report.

        Parameters
        ----------
        max_gap : int
            Longest run of untracked frames to fill (>= 0).
        """
        if isinstance(max_gap, bool) or not isinstance(max_gap, int) or max_gap < 0:
            raise DemonstrationError(f"max_gap must be a whole number >= 0, got {max_gap!r}")
        pos = np.array(self.positions)
        quat = np.array(self.quaternions)
        for s, e in self.gaps():
            if s == 0 or e == self.n_frames or e - s > max_gap:
                continue
            a, b = s - 1, e
            frac = (np.arange(s, e) - a) / (b - a)
            pos[s:e] = pos[a] + np.outer(frac, pos[b] - pos[a])
            slerp = Slerp([0.0, 1.0], Rotation.from_quat(quat[[a, b]]))
            quat[s:e] = slerp(frac).as_quat()
        return PoseTrajectory(self.name, pos, quat, self.rate, self.units)


def kabsch_poses(
    world: ArrayLike, layout: ArrayLike, *, min_markers: int = 3
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Best-fit rigid poses of a marker layout, frame by frame (Kabsch / Umeyama without scale).

    For each frame, finds the rotation ``R`` and translation ``p`` minimising
    ``sum_k |R @ l_k + p - w_k|^2`` over the markers ``k`` seen in that frame.

    Parameters
    ----------
    world : array, shape (n_frames, m, 3)
        Measured marker positions in the world; NaN where a marker is occluded.
    layout : array, shape (m, 3)
        The same markers in the body's frame, same units.
    min_markers : int
        Fewest markers (not all on one line) a frame needs; fewer leave it invalid.

    Returns
    -------
    positions : array, shape (n_frames, 3)
    quaternions : array, shape (n_frames, 4)
        Scalar-last; NaN rows where the frame has too few markers.
    rms : array, shape (n_frames,)
        Root mean square residual of the fit (NaN where invalid): a marker that was swapped
        or knocked shows up here.
    """
    w = np.asarray(world, dtype=np.float64)
    lay = np.asarray(layout, dtype=np.float64)
    if w.ndim != 3 or w.shape[2] != 3 or lay.shape != (w.shape[1], 3):
        raise DemonstrationError(
            f"kabsch_poses: world must have shape (n_frames, m, 3) and layout (m, 3), got "
            f"{w.shape} and {lay.shape}"
        )
    seen = np.asarray(~np.isnan(w).any(axis=2), dtype=bool)  # (n, m)
    wt: FloatArray = seen.astype(np.float64)
    count: FloatArray = wt.sum(axis=1)
    safe = np.maximum(count, 1.0)[:, None]
    w0 = np.where(seen[..., None], w, 0.0)
    cw = (w0 * wt[..., None]).sum(axis=1) / safe
    cl = (wt @ lay) / safe
    dl = (lay[None] - cl[:, None]) * wt[..., None]
    dw = (w0 - cw[:, None]) * wt[..., None]
    h = np.einsum("nki,nkj->nij", dl, dw)  # covariance, layout x world
    u, sv, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("nij,njk->nik", u, vt)))
    d[d == 0] = 1.0
    corr = np.ones((len(d), 3))
    corr[:, 2] = d
    rot = np.einsum("nji,nj,nkj->nik", vt, corr, u)  # V diag(1,1,d) U^T
    pos = cw - np.einsum("nij,nj->ni", rot, cl)
    # a layout on one line (or too few markers) leaves the rotation about it undetermined
    ok = (count >= max(3, min_markers)) & (sv[:, 1] > 1e-9 * np.maximum(sv[:, 0], 1e-300))
    res = np.einsum("nij,kj->nki", rot, lay) + pos[:, None] - w0
    rms = np.sqrt((np.square(res).sum(axis=2) * wt).sum(axis=1) / safe[:, 0])
    quat = np.full((len(d), 4), np.nan)
    if ok.any():
        quat[ok] = Rotation.from_matrix(rot[ok]).as_quat()
    pos[~ok] = np.nan
    rms[~ok] = np.nan
    return pos, quat, rms


@dataclass(frozen=True, eq=False)
class MarkerTrajectory:
    """Positions of named markers sampled at a constant rate.

    Frame ``i`` is taken at time ``t_i = i / rate`` seconds; the paper's fingertip trajectory
    ``p(t) = [x(t), y(t), z(t)]`` of a marker is ``positions[:, k, :]``.

    Parameters
    ----------
    positions : array, shape (n_frames, n_markers, 3)
        Marker positions ``p(t_i)`` in the world frame (``z`` up), in ``units``; NaN where a
        marker is occluded (all three coordinates). Stored as a read-only float64 copy.
    marker_names : tuple of str, length n_markers
        Unique, non-empty marker names, in the order of ``positions``' second axis.
    rate : float
        Sampling rate in Hz, finite and positive.
    units : {"m", "mm"}
        Length units of ``positions``.
    rigid_bodies : tuple of PoseTrajectory
        Rigid bodies tracked in the same recording (Motive exports them beside the markers),
        with the same number of frames, rate and units; unique names. Default none.

    Raises
    ------
    DemonstrationError
        (an :class:`~nonprehensile.errors.InputError`) if a field is malformed; the message
        names the field and what is wrong.
    """

    positions: FloatArray
    marker_names: tuple[str, ...]
    rate: float
    units: LengthUnits = "m"
    rigid_bodies: tuple[PoseTrajectory, ...] = ()

    def __post_init__(self) -> None:
        try:
            pos = np.array(self.positions, dtype=np.float64, copy=True)
        except (TypeError, ValueError) as exc:
            raise DemonstrationError(
                f"marker trajectory: positions must be an array of numbers of shape "
                f"(n_frames, n_markers, 3), got something numpy cannot read as numbers ({exc})"
            ) from None
        if pos.ndim != 3 or pos.shape[2] != 3:
            raise DemonstrationError(
                f"marker trajectory: positions must have shape (n_frames, n_markers, 3), got "
                f"shape {pos.shape}"
            )
        if pos.shape[0] < 1 or pos.shape[1] < 1:
            raise DemonstrationError(
                f"marker trajectory: need at least one frame and one marker, got shape {pos.shape}"
            )
        if np.isinf(pos).any():
            i, k, _ = (int(v) for v in np.argwhere(np.isinf(pos))[0])
            raise DemonstrationError(
                f"marker trajectory: positions must be finite (NaN marks an occluded marker), "
                f"got an infinite value at frame {i}, marker {k}"
            )
        big = np.abs(np.nan_to_num(pos)) > MAX_COORDINATE
        if big.any():
            i, k, c = (int(v) for v in np.argwhere(big)[0])
            raise DemonstrationError(
                f"marker trajectory: frame {i}, marker {k}: coordinate {pos[i, k, c]:g} is "
                f"beyond {MAX_COORDINATE:g} (in any unit, far off a capture volume); the file "
                "is damaged or its units are wrong"
            )
        # a marker is either seen (three numbers) or occluded (three NaNs); a partly-NaN
        # position is not a measurement, so make the whole point NaN
        pos[np.isnan(pos).any(axis=2)] = np.nan
        pos.setflags(write=False)
        object.__setattr__(self, "positions", pos)

        names = self.marker_names
        if isinstance(names, str) or not isinstance(names, Sequence):
            raise DemonstrationError(
                f"marker trajectory: marker_names must be a sequence of strings, got {names!r}"
            )
        bad = [n for n in names if not isinstance(n, str) or not n.strip()]
        if bad:
            raise DemonstrationError(
                f"marker trajectory: marker names must be non-empty strings, got {bad[0]!r}"
            )
        if len(names) != pos.shape[1]:
            raise DemonstrationError(
                f"marker trajectory: {len(names)} marker names for {pos.shape[1]} markers in "
                f"positions (shape {pos.shape}); give one name per marker"
            )
        dup = [n for n, c in Counter(names).items() if c > 1]
        if dup:
            raise DemonstrationError(
                f"marker trajectory: marker names must be unique, {dup[0]!r} appears more than "
                "once; rename the markers"
            )
        object.__setattr__(self, "marker_names", tuple(names))

        rate = self.rate
        if isinstance(rate, bool) or not isinstance(rate, (int, float, np.integer, np.floating)):
            raise DemonstrationError(
                f"marker trajectory: rate must be a number of Hz, got {rate!r}"
            )
        if not rate_in_range(float(rate)):
            raise DemonstrationError(
                f"marker trajectory: rate must be a number of Hz from {MIN_RATE_HZ:g} to "
                f"{MAX_RATE_HZ:g}, got {rate!r}"
            )
        object.__setattr__(self, "rate", float(rate))
        object.__setattr__(self, "units", _check_units(self.units, "marker trajectory"))
        bodies = self.rigid_bodies
        if isinstance(bodies, PoseTrajectory) or not isinstance(bodies, Sequence) or not all(
                isinstance(b, PoseTrajectory) for b in bodies):
            raise DemonstrationError(
                f"marker trajectory: rigid_bodies must be a sequence of PoseTrajectory, got "
                f"{bodies!r:.80}"
            )
        for b in bodies:
            if (b.n_frames, b.rate) != (pos.shape[0], self.rate):
                raise DemonstrationError(
                    f"marker trajectory: rigid body {b.name!r} has {b.n_frames} frames at "
                    f"{b.rate:g} Hz, the markers {pos.shape[0]} at {self.rate:g} Hz; they must "
                    "come from the same recording"
                )
        dup_b = [n for n, c in Counter(b.name for b in bodies).items() if c > 1]
        if dup_b:
            raise DemonstrationError(
                f"marker trajectory: two rigid bodies are called {dup_b[0]!r}; rename one"
            )
        object.__setattr__(self, "rigid_bodies",
                           tuple(b.to_units(self.units) for b in bodies))

    # arrays make the generated __eq__ ambiguous, so equality is written out; NaN (occlusion)
    # equals NaN because two records of the same occlusion are the same record
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MarkerTrajectory):
            return NotImplemented
        return (
            self.marker_names == other.marker_names
            and self.rate == other.rate
            and self.units == other.units
            and self.positions.shape == other.positions.shape
            and bool(np.array_equal(self.positions, other.positions, equal_nan=True))
            and self.rigid_bodies == other.rigid_bodies
        )

    def __hash__(self) -> int:
        return hash((self.marker_names, self.rate, self.units, self.positions.shape))

    def rigid_body(self, name: str) -> PoseTrajectory:
        """The rigid body called ``name``.

        Raises
        ------
        DemonstrationError
            If there is none; the message lists the rigid bodies there are.
        """
        for b in self.rigid_bodies:
            if b.name == name:
                return b
        raise DemonstrationError(
            f"no rigid body named {name!r}; the recording has "
            f"{[b.name for b in self.rigid_bodies] or 'none'}"
        )

    @property
    def n_frames(self) -> int:
        """Number of frames (samples in time)."""
        return int(self.positions.shape[0])

    @property
    def n_markers(self) -> int:
        """Number of markers."""
        return int(self.positions.shape[1])

    @property
    def duration(self) -> float:
        """Time from the first to the last frame, ``(n_frames - 1) / rate`` seconds."""
        return (self.n_frames - 1) / self.rate

    @property
    def times(self) -> FloatArray:
        """Sample times ``t_i = i / rate`` in seconds, array, shape (n_frames,)."""
        t = np.arange(self.n_frames, dtype=np.float64) / self.rate
        t.setflags(write=False)
        return t

    @property
    def occluded(self) -> NDArray[np.bool_]:
        """Where a marker is occluded, array of bool, shape (n_frames, n_markers)."""
        return np.isnan(self.positions[:, :, 0])

    def to_units(self, units: str) -> MarkerTrajectory:
        """The same trajectory with positions in ``units`` (``"m"`` or ``"mm"``).

        Raises
        ------
        DemonstrationError
            If ``units`` is not one of them.
        """
        target = _check_units(units, "to_units")
        if target == self.units:
            return self
        scale = UNITS[self.units] / UNITS[target]
        return MarkerTrajectory(self.positions * scale, self.marker_names, self.rate, target,
                                tuple(b.to_units(target) for b in self.rigid_bodies))

    def marker(self, name: str) -> FloatArray:
        """Positions of one marker, read-only array, shape (n_frames, 3).

        Raises
        ------
        DemonstrationError
            If no marker is called ``name``; the message lists the names there are.
        """
        try:
            k = self.marker_names.index(name)
        except ValueError:
            raise DemonstrationError(
                f"no marker named {name!r}; the trajectory has {list(self.marker_names)}"
            ) from None
        return self.positions[:, k, :]

    @classmethod
    def from_arrays(
        cls,
        positions: ArrayLike,
        marker_names: Sequence[str],
        rate: float,
        units: str = "m",
        rigid_bodies: Sequence[PoseTrajectory] = (),
    ) -> MarkerTrajectory:
        """Build from any array-like and sequence of names (the constructor's typed twin)."""
        return cls(
            np.asarray(positions, dtype=np.float64),
            tuple(marker_names),
            rate,
            _check_units(units, "marker trajectory"),
            tuple(rigid_bodies),
        )

    def pose_from_markers(
        self, name: str, layout: Mapping[str, ArrayLike], *, min_markers: int = 3
    ) -> PoseTrajectory:
        """The pose of a rigid body fitted to its markers frame by frame (Kabsch).

        Parameters
        ----------
        name : str
            The name to give the body.
        layout : mapping of str to array, shape (3,)
            Marker name -> its position in the body's frame, in this trajectory's units.
            Three or more markers, not all on one line.
        min_markers : int
            Fewest markers a frame needs (at least 3); frames with fewer are invalid.

        Raises
        ------
        DemonstrationError
            A marker of the layout is not recorded, or fewer than three are given.
        """
        names = list(layout)
        if len(names) < 3:
            raise DemonstrationError(
                f"rigid body {name!r}: its pose needs at least 3 markers in the layout, got "
                f"{names}"
            )
        missing = [m for m in names if m not in self.marker_names]
        if missing:
            raise DemonstrationError(
                f"rigid body {name!r}: marker(s) {missing} of its layout are not in the "
                f"recording, which has {list(self.marker_names)}"
            )
        idx = [self.marker_names.index(m) for m in names]
        lay = np.array([np.asarray(layout[m], dtype=np.float64).reshape(3) for m in names])
        pos, quat, _ = kabsch_poses(self.positions[:, idx], lay, min_markers=min_markers)
        return PoseTrajectory(name, pos, quat, self.rate, self.units)
