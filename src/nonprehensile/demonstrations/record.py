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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nonprehensile.errors import DemonstrationError

__all__ = ["UNITS", "LengthUnits", "MarkerTrajectory"]

FloatArray = NDArray[np.float64]

#: Length units a trajectory may be stated in.
LengthUnits = Literal["m", "mm"]

#: Metres per unit, for each accepted unit.
UNITS: dict[str, float] = {"m": 1.0, "mm": 1e-3}


def _check_units(units: object, what: str) -> LengthUnits:
    if not isinstance(units, str) or units not in UNITS:
        raise DemonstrationError(
            f"{what}: units must be one of {sorted(UNITS)} (metres or millimetres), "
            f"got {units!r}; convert the data or state its units"
        )
    return cast(LengthUnits, units)


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
        if not (math.isfinite(float(rate)) and float(rate) > 0):
            raise DemonstrationError(
                f"marker trajectory: rate must be finite and positive (Hz), got {rate!r}"
            )
        object.__setattr__(self, "rate", float(rate))
        object.__setattr__(self, "units", _check_units(self.units, "marker trajectory"))

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
        )

    def __hash__(self) -> int:
        return hash((self.marker_names, self.rate, self.units, self.positions.shape))

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
        return MarkerTrajectory(self.positions * scale, self.marker_names, self.rate, target)

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
    ) -> MarkerTrajectory:
        """Build from any array-like and sequence of names (the constructor's typed twin)."""
        return cls(
            np.asarray(positions, dtype=np.float64),
            tuple(marker_names),
            rate,
            _check_units(units, "marker trajectory"),
        )
