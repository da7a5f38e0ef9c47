"""Trajectory preprocessing: cropping, gap filling, resampling, flattening.

The truths are trajectories known in closed form (lines and cubic polynomials in time, which
linear and cubic-spline interpolation must reproduce exactly), ``np.interp`` as an
independent linear interpolator, and small hand-worked arrays.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, strategies as st
from hypothesis.extra.numpy import arrays

from nonprehensile.errors import InputError
from nonprehensile.motion.trajectory import (
    DEFAULT_N_POINTS,
    crop,
    fill_gaps,
    flatten,
    preprocess,
    preprocess_many,
    resample,
    unflatten,
)

# per marker and coordinate: p(t) = a + b t + c t^2 + d t^3, t in frames
COEF = np.array(
    [
        [[0.1, 0.2, -0.3], [1.0, -0.5, 0.25], [0.01, 0.02, -0.03], [-1e-3, 2e-4, 5e-4]],
        [[1.0, -2.0, 0.5], [-0.2, 0.3, 0.1], [-0.02, 0.01, 0.04], [3e-4, -1e-3, 2e-4]],
    ]
)  # shape (n_markers, 4, 3)


def cubic_traj(t: np.ndarray) -> np.ndarray:
    """Positions at (fractional) frames t, shape (len(t), 2, 3)."""
    powers = np.stack([t**0, t, t**2, t**3], axis=1)  # (n, 4)
    out: np.ndarray = np.einsum("nk,mkc->nmc", powers, COEF)
    return out


def linear_traj(t: np.ndarray) -> np.ndarray:
    out: np.ndarray = np.einsum("nk,mkc->nmc", np.stack([t**0, t], axis=1), COEF[:, :2])
    return out


# --------------------------------------------------------------------------- crop


def test_crop_keeps_the_frames_in_the_window() -> None:
    traj = cubic_traj(np.arange(10.0))
    np.testing.assert_array_equal(crop(traj, 0.3, 0.6, 10.0), traj[3:7])
    np.testing.assert_array_equal(crop(traj, 0.0, 1.0, 10.0), traj)
    np.testing.assert_array_equal(crop(traj, 0.25, 0.25 + 1e-3, 4.0), traj[1:2])
    # in floating point 0.07 s * 100 Hz is frame 7.000000000000001 and 0.29 s * 100 Hz is
    # frame 28.999999999999996: frames 7 and 29 must both be kept
    long = cubic_traj(np.arange(40.0))
    np.testing.assert_array_equal(crop(long, 0.07, 0.29, 100.0), long[7:30])
    out = crop(traj, 0.0, 0.2, 10.0)
    out[0, 0, 0] = 99.0
    assert traj[0, 0, 0] != 99.0  # a copy


@pytest.mark.parametrize(
    ("t0", "t1", "rate", "words"),
    [
        (0.6, 0.3, 10.0, ["t_start must be <= t_end"]),
        (-0.1, 0.3, 10.0, ["outside the recording", "0..1 s"]),
        (0.0, 5.0, 10.0, ["outside the recording", "10 frames at 10 Hz"]),
        (0.31, 0.39, 10.0, ["no frame"]),
        (0.0, 0.5, float("nan"), ["rate"]),
        (0.0, 0.5, float("inf"), ["rate"]),
        (0.0, 0.5, 0.0, ["rate"]),
        (0.0, 0.5, "120", ["rate"]),
        (float("nan"), 0.5, 10.0, ["t_start", "finite"]),
    ],
)
def test_crop_rejects_bad_windows(t0: float, t1: float, rate: float, words: list[str]) -> None:
    with pytest.raises(InputError) as err:
        crop(cubic_traj(np.arange(10.0)), t0, t1, rate)
    for w in words:
        assert w in str(err.value)


# --------------------------------------------------------------------------- fill_gaps


def test_cubic_fill_recovers_a_cubic_motion_exactly() -> None:
    truth = cubic_traj(np.arange(40.0))
    holed = truth.copy()
    holed[10:14, 0] = np.nan
    holed[25:28, 1] = np.nan
    holed[30, 1, 0] = np.nan  # one coordinate: the whole sample is missing
    holed[30, 1, 1] = 1e6  # ... so its other coordinates are not trusted
    filled = fill_gaps(holed, 4)
    np.testing.assert_allclose(filled, truth, atol=1e-9)
    assert np.isnan(holed[10, 0]).all()  # the input is left alone
    # a straight line between the ends of a gap misses the curve: the test can tell
    linear = fill_gaps(holed, 4, method="linear")
    assert np.abs(linear - truth).max() > 1e-3


def test_linear_fill_equals_np_interp() -> None:
    rng = np.random.default_rng(0)
    traj = rng.normal(size=(30, 3, 3))
    holed = traj.copy()
    holed[5:8, 2] = np.nan
    holed[20, 0] = np.nan
    filled = fill_gaps(holed, 3, method="linear")
    frames = np.arange(30.0)
    for m, gap in ((2, [5, 6, 7]), (0, [20])):
        ok = ~np.isnan(holed[:, m, 0])
        for c in range(3):
            expected = np.interp(frames[gap], frames[ok], traj[ok, m, c])
            np.testing.assert_allclose(filled[gap, m, c], expected, atol=1e-12)
    untouched = ~np.isnan(holed).any(axis=2)
    np.testing.assert_array_equal(filled[untouched], traj[untouched])


def test_gaps_at_the_ends_hold_the_nearest_sample() -> None:
    truth = cubic_traj(np.arange(12.0))
    holed = truth.copy()
    holed[:2, 0] = np.nan
    holed[-3:, 1] = np.nan
    filled = fill_gaps(holed, 3)
    np.testing.assert_array_equal(filled[:2, 0], np.repeat(truth[2:3, 0], 2, axis=0))
    np.testing.assert_array_equal(filled[-3:, 1], np.repeat(truth[-4:-3, 1], 3, axis=0))
    np.testing.assert_array_equal(filled[2:, 0], truth[2:, 0])


def test_one_recorded_sample_is_held_everywhere() -> None:
    traj = np.full((3, 1, 3), np.nan)
    traj[1, 0] = [1.0, 2.0, 3.0]
    np.testing.assert_array_equal(fill_gaps(traj, 1), np.tile([1.0, 2.0, 3.0], (3, 1, 1)))


def test_fill_without_gaps_is_a_copy() -> None:
    traj = cubic_traj(np.arange(5.0))
    out = fill_gaps(traj, 0)
    np.testing.assert_array_equal(out, traj)
    assert out is not traj


@pytest.mark.parametrize(
    ("hole", "max_gap", "words"),
    [
        (
            (slice(4, 9), 1),
            4,
            ["marker 1", "frames 4..8", "in the middle", "5 frames", "max_gap=4"],
        ),
        ((slice(0, 3), 0), 2, ["marker 0", "frames 0..2", "at the start"]),
        ((slice(17, 20), 1), 2, ["marker 1", "frames 17..19", "at the end"]),
        ((slice(0, 20), 0), 30, ["marker 0", "every frame"]),
        ((slice(7, 8), 0), 0, ["marker 0", "frames 7..7", "max_gap=0"]),
    ],
)
def test_long_gaps_are_refused_naming_marker_and_frames(
    hole: tuple[slice, int], max_gap: int, words: list[str]
) -> None:
    traj = cubic_traj(np.arange(20.0))
    traj[hole] = np.nan
    with pytest.raises(InputError) as err:
        fill_gaps(traj, max_gap)
    for w in words:
        assert w in str(err.value)


def test_fill_counts_the_other_long_gaps() -> None:
    traj = cubic_traj(np.arange(20.0))
    traj[3:6, 0] = np.nan
    traj[10:14, 0] = np.nan
    with pytest.raises(InputError, match=r"frames 3\.\.5 .*and 1 more"):
        fill_gaps(traj, 2)


@pytest.mark.parametrize(
    ("traj", "kwargs", "words"),
    [
        ([[[0, 0, 0]], [[1, 1]]], {"max_gap": 1}, ["same number of markers", "could not read"]),
        (np.zeros((5, 3)), {"max_gap": 1}, ["(5, 3)", "traj[:, None, :]"]),
        (np.zeros((5, 2, 2)), {"max_gap": 1}, ["(n_frames, n_markers, 3)"]),
        (np.zeros((0, 2, 3)), {"max_gap": 1}, ["at least one frame"]),
        (np.full((4, 1, 3), np.inf), {"max_gap": 1}, ["marker 0, frame 0", "finite"]),
        (np.zeros((4, 1, 3)), {"max_gap": -1}, ["max_gap", ">= 0"]),
        (np.zeros((4, 1, 3)), {"max_gap": 1.5}, ["max_gap", "integer"]),
        (np.zeros((4, 1, 3)), {"max_gap": 1, "method": "quintic"}, ["method", "cubic"]),
    ],
)
def test_fill_rejects_bad_input(traj: object, kwargs: dict[str, object], words: list[str]) -> None:
    with pytest.raises(InputError) as err:
        fill_gaps(traj, **kwargs)  # type: ignore[arg-type]
    for w in words:
        assert w in str(err.value)


# --------------------------------------------------------------------------- resample


@pytest.mark.parametrize("method", ["cubic", "linear"])
def test_resampling_a_line_is_exact(method: str) -> None:
    traj = linear_traj(np.arange(37.0))
    out = resample(traj, 400, method=method)  # type: ignore[arg-type]
    assert out.shape == (400, 2, 3)
    np.testing.assert_allclose(out, linear_traj(np.linspace(0.0, 36.0, 400)), atol=1e-12)


def test_cubic_resampling_reproduces_a_cubic_motion() -> None:
    traj = cubic_traj(np.arange(25.0))
    out = resample(traj, 61)
    np.testing.assert_allclose(out, cubic_traj(np.linspace(0.0, 24.0, 61)), atol=1e-9)
    # and linear interpolation does not: the test can tell them apart
    lin = resample(traj, 61, method="linear")
    assert np.abs(lin - cubic_traj(np.linspace(0.0, 24.0, 61))).max() > 1e-4


def test_linear_resampling_equals_np_interp() -> None:
    rng = np.random.default_rng(1)
    traj = rng.normal(size=(17, 2, 3))
    out = resample(traj, 50, method="linear")
    t = np.linspace(0.0, 16.0, 50)
    for m in range(2):
        for c in range(3):
            np.testing.assert_allclose(out[:, m, c], np.interp(t, np.arange(17.0), traj[:, m, c]))


@given(
    arrays(
        np.float64,
        st.tuples(st.integers(2, 30), st.integers(1, 3), st.just(3)),
        elements=st.floats(-1e3, 1e3),
    ),
    st.sampled_from(["cubic", "linear"]),
)
def test_resampling_to_the_same_length_changes_nothing(traj: np.ndarray, method: str) -> None:
    out = resample(traj, traj.shape[0], method=method)  # type: ignore[arg-type]
    np.testing.assert_allclose(out, traj, atol=1e-9 * (1 + np.abs(traj).max()))


def test_two_frames_resample_to_a_straight_segment() -> None:
    traj = np.array([[[0.0, 0.0, 0.0]], [[4.0, 2.0, -2.0]]])
    out = resample(traj, 5)
    np.testing.assert_allclose(out[:, 0], np.outer(np.linspace(0, 1, 5), [4.0, 2.0, -2.0]))


@pytest.mark.parametrize(
    ("traj", "n_points", "words"),
    [
        (np.zeros((1, 2, 3)), 400, ["at least 2 frames", "got 1"]),
        (np.zeros((5, 2, 3)), 1, ["n_points", ">= 2"]),
        (np.zeros((5, 2, 3)), 400.0, ["n_points", "integer"]),
    ],
)
def test_resample_rejects_bad_input(traj: np.ndarray, n_points: int, words: list[str]) -> None:
    with pytest.raises(InputError) as err:
        resample(traj, n_points)
    for w in words:
        assert w in str(err.value)


def test_resample_refuses_missing_samples() -> None:
    traj = cubic_traj(np.arange(10.0))
    traj[6, 1, 2] = np.nan
    traj[8, 0, 0] = np.nan
    with pytest.raises(InputError, match=r"marker 1, frame 6.*2 missing.*fill_gaps"):
        resample(traj)


# --------------------------------------------------------------------------- flatten


def test_flatten_puts_all_markers_of_one_time_together() -> None:
    # traj[t, m] = [100 t + 10 m + 0, ... + 1, ... + 2]
    traj = 100 * np.arange(2)[:, None, None] + 10 * np.arange(2)[None, :, None] + np.arange(3)
    p = flatten(traj)
    assert p.tolist() == [0, 1, 2, 10, 11, 12, 100, 101, 102, 110, 111, 112]
    np.testing.assert_array_equal(unflatten(p, 2), traj)


def test_flatten_and_unflatten_reject_bad_input() -> None:
    traj = np.zeros((3, 2, 3))
    traj[1, 0, 1] = np.nan
    with pytest.raises(InputError, match="marker 0, frame 1"):
        flatten(traj)
    with pytest.raises(InputError, match="multiple of 6"):
        unflatten(np.zeros(9), 2)
    with pytest.raises(InputError, match="n_markers"):
        unflatten(np.zeros(6), 0)
    with pytest.raises(InputError, match="shape"):
        unflatten(np.zeros((2, 6)), 2)


# --------------------------------------------------------------------------- preprocess


def test_preprocess_chains_the_steps() -> None:
    rng = np.random.default_rng(2)
    traj = cubic_traj(np.arange(300.0) / 3) + rng.normal(scale=1e-3, size=(300, 2, 3))
    traj[40:43, 1] = np.nan  # inside the window
    traj[290:, 0] = np.nan  # outside it: cropped away before gaps are looked at
    p = preprocess(traj, 120.0, t_start=0.25, t_end=2.0, max_gap=3)
    assert p.shape == (DEFAULT_N_POINTS * 2 * 3,)
    expected = flatten(resample(fill_gaps(crop(traj, 0.25, 2.0, 120.0), 3)))
    np.testing.assert_array_equal(p, expected)
    # the first point is the first frame of the window (frame 30), untouched
    np.testing.assert_array_equal(p[:6], traj[30].ravel())
    # without the window, the long gap at the end is found
    with pytest.raises(InputError, match=r"marker 0: frames 290\.\.299"):
        preprocess(traj, 120.0, max_gap=3)


def test_preprocess_defaults_and_rate_check() -> None:
    traj = linear_traj(np.arange(50.0))
    p = preprocess(traj, 100.0, n_points=10, method="linear")
    np.testing.assert_allclose(p, flatten(linear_traj(np.linspace(0, 49, 10))), atol=1e-12)
    np.testing.assert_array_equal(preprocess(traj, 100.0, t_end=0.2), preprocess(traj[:21], 1.0))
    # read-only input (a MarkerTrajectory's positions) is read, never written
    frozen = traj.copy()
    frozen.flags.writeable = False
    frozen_holed = cubic_traj(np.arange(20.0))
    frozen_holed[3, 0] = np.nan
    frozen_holed.flags.writeable = False
    assert preprocess(frozen, 100.0).shape == (400 * 2 * 3,)
    assert not np.isnan(preprocess(frozen_holed, 100.0, t_start=0.0, max_gap=1)).any()
    for bad in (float("nan"), float("inf"), -5.0, True):
        with pytest.raises(InputError, match="rate"):
            preprocess(traj, bad)


@given(
    lengths=st.lists(st.integers(2, 12), min_size=1, max_size=8),
    method=st.sampled_from(["cubic", "linear"]),
    seed=st.integers(0, 2**16),
)
def test_many_preprocessed_at_once_equal_one_by_one(lengths: list[int], method: str,
                                                     seed: int) -> None:
    # trajectories of repeated lengths share one spline: each comes out bit for bit as alone
    rng = np.random.default_rng(seed)
    trajs = [rng.normal(scale=100.0, size=(n + 4, 2, 3)) for n in lengths]
    for t in trajs[::2]:
        t[2, 1] = np.nan  # a gap inside every window
    windows = [(0.5 if i % 3 else None, (n + 2) / 2) for i, n in enumerate(lengths)]
    rates = [2.0] * len(trajs)
    many = preprocess_many(trajs, rates, windows=windows, max_gap=1, n_points=7, method=method)
    for row, t, (a, b) in zip(many, trajs, windows, strict=True):
        one = preprocess(t, 2.0, t_start=a, t_end=b, max_gap=1, n_points=7, method=method)
        np.testing.assert_array_equal(row, one)


def test_many_preprocessed_refuse_mismatched_input() -> None:
    a = linear_traj(np.arange(10.0))
    with pytest.raises(InputError, match="different numbers of markers"):
        preprocess_many([a, a[:, :1]], [1.0, 1.0])
    with pytest.raises(InputError, match="2 trajectories, 1 rates"):
        preprocess_many([a, a], [1.0])
    with pytest.raises(InputError, match="marker 0"):  # one trajectory's own error, as alone
        holed = a.copy()
        holed[3:6, 0] = np.nan
        preprocess_many([a, holed], [1.0, 1.0], max_gap=1)


def test_many_preprocessed_take_numpy_gap_limits() -> None:
    a = linear_traj(np.arange(10.0))
    holed = a.copy()
    holed[3, 0] = np.nan
    np.testing.assert_array_equal(preprocess_many([holed], [1.0], max_gap=np.int64(1))[0],
                                  preprocess(holed, 1.0, max_gap=1))
    with pytest.raises(InputError, match="max_gap"):
        preprocess_many([a], [1.0], max_gap=1.5)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="max_gap"):
        preprocess_many([a], [1.0], max_gap=True)
