"""Preprocessing of marker trajectories for the motion model (paper Section VI).

A trajectory is the positions of markers on the hand (fingertips, knuckles) over time: an
array, shape (n_frames, n_markers, 3), sampled at ``rate`` Hz, frame ``i`` at time
``i / rate`` seconds. NaN marks an occluded marker sample; a sample with any NaN coordinate is
missing as a whole, since a tracker reports a marker's three coordinates together.

The paper crops each demonstrated trajectory, interpolates it to a consistent length of 400
points, and flattens it into one vector ``P = [p(t1), p(t2), ...]``, where ``p(t)`` holds the
coordinates of every marker at time ``t`` (several fingers combined). Those vectors are then
reduced by PCA and a Hilbert curve (:mod:`nonprehensile.motion.hilbert`).

Interpolation (gap filling and resampling) is a cubic spline by default: hand motion is smooth,
and a cubic spline keeps the velocity continuous where a linear one leaves a kink at every
sample, a kink that would survive into the flattened vector. ``method="linear"`` is available
for data too noisy for a spline to be trusted between samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline, make_interp_spline

from nonprehensile.errors import InputError

__all__ = [
    "DEFAULT_N_POINTS",
    "Method",
    "crop",
    "fill_gaps",
    "flatten",
    "preprocess",
    "preprocess_many",
    "resample",
    "unflatten",
]

#: The paper's length of a preprocessed trajectory, in points.
DEFAULT_N_POINTS = 400

FloatArray = NDArray[np.float64]
Method = Literal["cubic", "linear"]

_METHODS = ("cubic", "linear")
# Slack, in frames, on times converted to frame numbers: 0.29 s at 100 Hz is frame
# 28.999999999999996 in floating point, which must count as frame 29.
_FRAME_SLACK = 1e-9


# --------------------------------------------------------------------------- validation


def _as_traj(traj: ArrayLike, *, allow_nan: bool = True) -> FloatArray:
    """``traj`` as a float array, shape (n_frames, n_markers, 3), checked."""
    try:
        arr = np.asarray(traj, dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise InputError(
            "a trajectory must be an array of numbers, shape (n_frames, n_markers, 3), with "
            f"the same number of markers in every frame; could not read it ({exc})"
        ) from None
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[1] == 0 or arr.shape[0] == 0:
        hint = ""
        if arr.ndim == 2 and arr.shape[1] == 3:
            hint = "; for one marker use traj[:, None, :]"
        raise InputError(
            "a trajectory must have shape (n_frames, n_markers, 3) with at least one frame "
            f"and one marker, got shape {arr.shape}{hint}"
        )
    inf = np.isinf(arr)
    if inf.any():
        f, m, c = (int(v) for v in np.argwhere(inf)[0])
        raise InputError(
            f"marker {m}, frame {f}: coordinate {c} is {arr[f, m, c]}; positions must be "
            "finite (NaN marks an occluded sample)"
        )
    if not allow_nan:
        missing = np.isnan(arr).any(axis=2)
        if missing.any():
            f, m = (int(v) for v in np.argwhere(missing)[0])
            n = int(missing.sum())
            raise InputError(
                f"marker {m}, frame {f}: the sample is missing (NaN), {n} missing samples in "
                "all; fill the gaps first (fill_gaps) or crop them out"
            )
    return arr


def _check_rate(rate: object) -> float:
    if isinstance(rate, bool) or not isinstance(rate, (int, float, np.integer, np.floating)):
        raise InputError(f"rate must be a number of frames per second (Hz), got {rate!r}")
    r = float(rate)
    if not (math.isfinite(r) and r > 0):
        raise InputError(f"rate must be a finite positive number of Hz, got {rate!r}")
    return r


def _check_count(value: object, name: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if v < low:
        raise InputError(f"{name} must be >= {low}, got {v}")
    return v


def _check_method(method: object) -> Method:
    if method not in _METHODS:
        raise InputError(f"method must be one of {_METHODS}, got {method!r}")
    return method  # type: ignore[return-value]


def _check_time(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} must be a time in seconds, got {value!r}")
    t = float(value)
    if not math.isfinite(t):
        raise InputError(f"{name} must be finite, got {value!r}")
    return t


def _interpolant(x: FloatArray, y: FloatArray, method: Method) -> Any:
    """A callable interpolating ``y`` (shape (n, k)) at ``x`` (shape (n,), increasing).

    Cubic: scipy's not-a-knot cubic spline (a line through 2 points, a parabola through 3);
    linear: a degree-1 B-spline, the same as ``np.interp`` column by column.
    """
    if method == "cubic":
        return CubicSpline(x, y, axis=0)
    return make_interp_spline(x, y, k=1, axis=0)


# --------------------------------------------------------------------------- operations


def crop(traj: ArrayLike, t_start: float, t_end: float, rate: float) -> FloatArray:
    """The frames of a trajectory between two times.

    Parameters
    ----------
    traj : array_like, shape (n_frames, n_markers, 3)
        Marker positions; frame ``i`` is at time ``i / rate`` seconds.
    t_start, t_end : float
        Times in seconds, ``0 <= t_start <= t_end <= n_frames / rate``; the frames at times
        ``t_start <= t <= t_end`` are kept.
    rate : float
        Sample rate in Hz.

    Returns
    -------
    array, shape (n_kept, n_markers, 3)
        A copy.

    Raises
    ------
    InputError
        If the rate is not finite and positive, the times are not finite, out of order, or
        outside the recording (a hint of a unit mix-up), or no frame falls between them.
    """
    arr = _as_traj(traj)
    r = _check_rate(rate)
    t0 = _check_time(t_start, "t_start")
    t1 = _check_time(t_end, "t_end")
    n = arr.shape[0]
    duration = n / r
    if t0 > t1:
        raise InputError(f"t_start must be <= t_end, got t_start={t0} s, t_end={t1} s")
    if t0 < 0 or t1 > duration * (1 + _FRAME_SLACK):
        raise InputError(
            f"the window {t0}..{t1} s is outside the recording, 0..{duration:g} s "
            f"({n} frames at {r:g} Hz); times are in seconds from the first frame"
        )
    i0 = max(math.ceil(t0 * r - _FRAME_SLACK), 0)
    i1 = min(math.floor(t1 * r + _FRAME_SLACK), n - 1)
    if i0 > i1:
        raise InputError(
            f"no frame lies in {t0}..{t1} s at {r:g} Hz (frames are {1 / r:g} s apart); "
            "widen the window"
        )
    return arr[i0 : i1 + 1].copy()


def _runs(mask: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Starts and (exclusive) ends of the runs of True in a 1-D mask."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def fill_gaps(traj: ArrayLike, max_gap: int, *, method: Method = "cubic") -> FloatArray:
    """Fill short runs of missing (NaN) samples, marker by marker.

    A gap between two recorded samples is interpolated through all the marker's recorded
    samples (a cubic spline by default, see the module notes). A gap at the start or the end
    of the recording has a recorded sample on one side only; it is filled by holding that
    sample, since extrapolating a spline beyond its data diverges (and a demonstration
    begins and ends with the hand nearly at rest).

    Parameters
    ----------
    traj : array_like, shape (n_frames, n_markers, 3)
        Marker positions; NaN marks a missing sample (any NaN coordinate: the whole sample).
    max_gap : int
        Longest run of missing frames to fill, per marker; ``0`` allows none.
    method : {"cubic", "linear"}
        Interpolation of interior gaps.

    Returns
    -------
    array, shape (n_frames, n_markers, 3)
        A copy without NaN.

    Raises
    ------
    InputError
        If a marker misses more than ``max_gap`` consecutive frames (at the start, the end or
        inside), or every frame; the message names the marker and the frame range.
    """
    arr = _as_traj(traj)
    gap = _check_count(max_gap, "max_gap", 0)
    how = _check_method(method)
    out = arr.copy()
    missing: NDArray[np.bool_] = np.any(np.isnan(arr), axis=2)
    n = arr.shape[0]
    frames = np.arange(n, dtype=np.float64)
    for m in np.flatnonzero(missing.any(axis=0)):
        if missing[:, m].all():
            raise InputError(
                f"marker {m}: missing in every frame (0..{n - 1}); drop the marker or check "
                "its labelling"
            )
        starts, ends = _runs(missing[:, m])
        long = np.flatnonzero(ends - starts > gap)
        if long.size:
            s, e = int(starts[long[0]]), int(ends[long[0]])
            where = "at the start" if s == 0 else "at the end" if e == n else "in the middle"
            more = f" (and {long.size - 1} more too long)" if long.size > 1 else ""
            raise InputError(
                f"marker {m}: frames {s}..{e - 1} are missing {where}, {e - s} frames, more "
                f"than max_gap={gap}{more}; raise max_gap, crop the gap out, or drop the marker"
            )
        valid = ~missing[:, m]
        known = arr[valid, m, :]
        interior = missing[:, m].copy()
        # runs touching either end are held constant, not interpolated
        first, last = int(np.argmax(valid)), n - 1 - int(np.argmax(valid[::-1]))
        out[:first, m, :] = known[0]
        out[last + 1 :, m, :] = known[-1]
        interior[:first] = False
        interior[last + 1 :] = False
        if interior.any():
            f = _interpolant(frames[valid], known, how)
            out[interior, m, :] = f(frames[interior])
    return out


def resample(
    traj: ArrayLike, n_points: int = DEFAULT_N_POINTS, *, method: Method = "cubic"
) -> FloatArray:
    """Interpolate a trajectory to ``n_points`` samples evenly spaced in time.

    The first and last samples are kept; time is normalised, so demonstrations of different
    durations come out the same length (the paper: 400 points each).

    Parameters
    ----------
    traj : array_like, shape (n_frames, n_markers, 3)
        Marker positions without missing samples, ``n_frames >= 2``.
    n_points : int
        Number of samples out, ``>= 2``.
    method : {"cubic", "linear"}
        Interpolation between frames.

    Returns
    -------
    array, shape (n_points, n_markers, 3)

    Raises
    ------
    InputError
        If a sample is missing (NaN: fill or crop the gaps first), ``n_frames < 2`` or
        ``n_points < 2``.
    """
    arr = _as_traj(traj, allow_nan=False)
    n_out = _check_count(n_points, "n_points", 2)
    how = _check_method(method)
    n, n_markers, _ = arr.shape
    if n < 2:
        raise InputError(
            f"resampling needs at least 2 frames, got {n}; crop a wider window or check the "
            "recording"
        )
    f = _interpolant(np.arange(n, dtype=np.float64), arr.reshape(n, n_markers * 3), how)
    # linspace hits both ends exactly: the first and last frames are kept as they are
    t = np.linspace(0.0, n - 1.0, n_out)
    out: FloatArray = np.asarray(f(t), dtype=np.float64).reshape(n_out, n_markers, 3)
    return out


def flatten(traj: ArrayLike) -> FloatArray:
    """The paper's vector ``P = [p(t1), p(t2), ...]`` of a trajectory.

    ``p(t)`` is ``[x, y, z]`` of marker 0, then of marker 1, ... at time ``t``: all markers at
    one time before the next time.

    Parameters
    ----------
    traj : array_like, shape (n_points, n_markers, 3)
        Marker positions without missing samples.

    Returns
    -------
    array, shape (n_points * n_markers * 3,)

    Raises
    ------
    InputError
        If ``traj`` is not of that shape or has a missing (NaN) sample.
    """
    arr = _as_traj(traj, allow_nan=False)
    return np.ascontiguousarray(arr).reshape(-1).copy()


def unflatten(vector: ArrayLike, n_markers: int) -> FloatArray:
    """Inverse of :func:`flatten`: shape (n_points * n_markers * 3,) -> (n_points, n_markers, 3).

    Useful to look at a flattened vector (a cluster mean, a principal direction) as motion.

    Raises
    ------
    InputError
        If ``vector`` is not 1-D or its length is not a multiple of ``3 * n_markers``.
    """
    k = _check_count(n_markers, "n_markers", 1)
    try:
        v = np.asarray(vector, dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise InputError(f"a flattened trajectory must be a 1-D array of numbers ({exc})") from None
    if v.ndim != 1 or v.size == 0 or v.size % (3 * k):
        raise InputError(
            f"a flattened trajectory of {k} markers must be 1-D with a length that is a "
            f"positive multiple of {3 * k}, got shape {v.shape}"
        )
    return v.reshape(-1, k, 3).copy()


def preprocess(
    traj: ArrayLike,
    rate: float,
    *,
    t_start: float | None = None,
    t_end: float | None = None,
    max_gap: int = 0,
    n_points: int = DEFAULT_N_POINTS,
    method: Method = "cubic",
) -> FloatArray:
    """Crop, fill gaps, resample and flatten one demonstration: the paper's preprocessing.

    Cropping comes first, so that gaps outside the window do not matter.

    Parameters
    ----------
    traj : array_like, shape (n_frames, n_markers, 3)
        Marker positions at ``rate`` Hz; NaN marks a missing sample.
    rate : float
        Sample rate in Hz.
    t_start, t_end : float, optional
        Window in seconds from the first frame (default: the whole recording).
    max_gap : int
        Longest run of missing frames to fill per marker (default 0: none may be missing).
    n_points : int
        Samples per trajectory after resampling (the paper: 400).
    method : {"cubic", "linear"}
        Interpolation for gap filling and resampling.

    Returns
    -------
    array, shape (n_points * n_markers * 3,)
        The flattened vector ``P``.

    Raises
    ------
    InputError
        From :func:`crop`, :func:`fill_gaps`, :func:`resample`: bad rate or window, a gap
        longer than ``max_gap`` (naming the marker and frames), fewer than 2 frames.
    """
    arr = _crop_and_fill(traj, rate, t_start, t_end, max_gap, method)
    return flatten(resample(arr, n_points, method=method))


def _crop_and_fill(traj: ArrayLike, rate: float, t_start: float | None, t_end: float | None,
                   max_gap: int, method: Method) -> FloatArray:
    """:func:`preprocess` before the resampling."""
    arr = _as_traj(traj)
    r = _check_rate(rate)
    if t_start is not None or t_end is not None:
        t0 = 0.0 if t_start is None else t_start
        t1 = (arr.shape[0] - 1) / r if t_end is None else t_end
        arr = crop(arr, t0, t1, r)
    return fill_gaps(arr, max_gap, method=method)


def preprocess_many(
    trajs: Sequence[ArrayLike],
    rates: Sequence[float],
    *,
    windows: Sequence[tuple[float | None, float | None]] | None = None,
    max_gap: int | Sequence[int] = 0,
    n_points: int = DEFAULT_N_POINTS,
    method: Method = "cubic",
) -> FloatArray:
    """:func:`preprocess` of several demonstrations, the same vectors bit for bit, faster.

    Trajectories with the same number of frames (after cropping) are resampled by one
    spline through all their markers: a spline's coefficients and values are computed column
    by column, so each column comes out as alone, and a demonstration set has far fewer
    distinct lengths than trajectories (the bundled cube's 660 segments have 142), which saves
    most of the splines' set-up (issue 16).

    Parameters
    ----------
    trajs : sequence of array_like, each shape (n_frames_i, n_markers, 3)
    rates : sequence of float
        Each trajectory's sample rate in Hz.
    windows : sequence of (t_start, t_end), optional
        Each trajectory's window (default: whole recordings).
    max_gap : int or sequence of int
        One gap limit for all, or one per trajectory.

    Returns
    -------
    array, shape (n_trajectories, n_points * n_markers * 3)
        Row ``i`` equals ``preprocess(trajs[i], rates[i], ...)``.

    Raises
    ------
    InputError
        As :func:`preprocess`, or if the trajectories do not all have the same number of
        markers, or the sequences differ in length.
    """
    n = len(trajs)
    if isinstance(max_gap, (int, np.integer)):
        gaps = [max_gap] * n  # each checked by fill_gaps, as preprocess does
    elif isinstance(max_gap, Sequence) and not isinstance(max_gap, str):
        gaps = list(max_gap)
    else:
        raise InputError(f"max_gap must be an integer or one per trajectory, got {max_gap!r}")
    spans = list(windows) if windows is not None else [(None, None)] * n
    if not len(rates) == len(gaps) == len(spans) == n:
        raise InputError(f"one rate, gap limit and window per trajectory: {n} trajectories, "
                         f"{len(rates)} rates, {len(gaps)} gap limits, {len(spans)} windows")
    n_out = _check_count(n_points, "n_points", 2)
    how = _check_method(method)
    arrs = [_crop_and_fill(t, r, a, b, g, how)
            for t, r, (a, b), g in zip(trajs, rates, spans, gaps, strict=True)]
    markers = {a.shape[1] for a in arrs}
    if len(markers) > 1:
        raise InputError(f"the trajectories have different numbers of markers {sorted(markers)}"
                         "; their vectors would have different lengths")
    k = markers.pop() if markers else 0
    out = np.empty((n, n_out * k * 3))
    by_length: dict[int, list[int]] = {}
    for i, a in enumerate(arrs):
        by_length.setdefault(a.shape[0], []).append(i)
    for rows in by_length.values():
        together = resample(np.concatenate([arrs[i] for i in rows], axis=1), n_out,
                            method=how)
        for j, i in enumerate(rows):
            out[i] = flatten(together[:, j * k : (j + 1) * k])
    return out
