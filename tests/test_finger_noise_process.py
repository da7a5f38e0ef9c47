"""The closed-loop executor's fingertip noise (the physics distribution's ``finger_noise``):
one Gauss-Markov process across the segments the controller replaces, and the smoothed form
with its velocity that an arm realises."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")

from nonprehensile.sim.closed_loop import FingerNoise, _Runner
from nonprehensile.sim.distribution import FINGER_NOISE_TIME

DT = 0.001
SIGMA = 0.001


class _Arm:
    """A driver that takes the noise as an arm does (``with_noise``) and keeps it."""

    def __init__(self, smoothing: float) -> None:
        self.noise_smoothing = smoothing
        self.got: list[tuple[np.ndarray, np.ndarray | None]] = []

    def with_noise(self, targets: np.ndarray, noise: np.ndarray,
                   velocity: np.ndarray | None = None) -> np.ndarray:
        self.got.append((noise, velocity))
        return targets


def _noise(seed: int) -> FingerNoise:
    """One fingertip's noise at 1 kHz, 1 mm, on the generator seeded ``seed``."""
    return FingerNoise(np.random.default_rng(seed), SIGMA, DT, 1)


def _runner(seed: int, driver: Any = None) -> _Runner:
    """A runner with only what :meth:`_Runner._noisy` reads: its driver and its noise (no
    scene: the process is plain arithmetic)."""
    r = _Runner.__new__(_Runner)
    r.sim = SimpleNamespace(driver=driver if driver is not None else object())
    r.noise = _noise(seed)
    return r


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 400), st.integers(0, 400),
       st.integers(1, 300))
def test_a_replaced_segment_continues_the_process_from_the_last_row_applied(
        seed: int, n1: int, cut: int, n2: int) -> None:
    """Segment 1 runs ``cut`` of its ``n1`` rows, then segment 2 replaces it: the rows
    applied are one Gauss-Markov process ``x_k = a x_(k-1) + w_k`` over the draws they used
    (truth: the recursion written out, on the same generator's draws; segment 1's unused
    draws are skipped). Continued from segment 1's last row instead, as the executor did,
    the error jumped at the cut by about ``sqrt(2)`` sigma per axis."""
    cut = min(cut, n1)
    r = _runner(seed)
    seg1 = r._noisy(np.zeros((n1, 1, 3)))
    r.noise.cut(cut)
    seg2 = r._noisy(np.zeros((n2, 1, 3)))
    applied = np.concatenate([seg1[:cut], seg2])

    a = math.exp(-DT / FINGER_NOISE_TIME)
    rng = np.random.default_rng(seed)
    w1 = rng.standard_normal((n1, 1, 3)) * SIGMA * math.sqrt(1.0 - a * a)
    w2 = rng.standard_normal((n2, 1, 3)) * SIGMA * math.sqrt(1.0 - a * a)
    x = np.zeros((1, 3))
    truth = []
    for w in [*w1[:cut], *w2]:
        x = a * x + w
        truth.append(x)
    np.testing.assert_allclose(applied, np.array(truth), rtol=0, atol=1e-15)


def test_a_drive_that_ran_to_its_end_continues_from_its_last_row() -> None:
    """A segment that ran whole (or past its end, held) hands on its last row."""
    r = _runner(3)
    seg1 = r._noisy(np.zeros((50, 1, 3)))
    r.noise.cut(80)  # held 30 steps past the end
    np.testing.assert_array_equal(r.noise.state[0], seg1[-1])


def test_an_arm_gets_the_noise_smoothed_with_its_velocity() -> None:
    """An arm that asks for the noise smoothed (``noise_smoothing``, the shipped 30 ms) gets
    the process through two first-order low-passes in series, and that result's velocity:
    integrated, the velocity gives the smoothed error back exactly (truth: the running sum
    of the velocities against the positions); scaled, it keeps the raw process's standard
    deviation (within 10 % over 60 s; unscaled the smoothing at 30 ms keeps 71 %) and follows
    it 30-60 ms behind (correlation at least 0.8 there, 0.5-0.6 at no lag); its rows run on
    ``NOISE_TAIL`` time constants past the segment's end, the raw error held, and come to
    rest there without a step (the free fingertips, no ``with_noise``, get the raw process
    added to their targets, no tail)."""
    from nonprehensile.sim.closed_loop import NOISE_TAIL
    from nonprehensile.sim.robot_driver import NOISE_SMOOTHING

    arm = _Arm(NOISE_SMOOTHING)
    r = _runner(11, arm)
    n = 60_000
    targets = np.zeros((n, 1, 3))
    assert r._noisy(targets) is targets  # an arm's targets stay the targets
    noise, vel = arm.got[-1]
    assert vel is not None and vel.shape == noise.shape
    tail = math.ceil(NOISE_TAIL * NOISE_SMOOTHING / DT)
    assert len(noise) == n + tail
    raw, smooth, _ = _noise(11).rows(n)  # (the same draws, not smoothed)
    assert smooth is None and len(raw) == n
    ratio = noise[2000:n].std() / raw[2000:].std()
    assert 0.9 < ratio < 1.1, ratio
    x, y = raw[2000:, 0, 0], noise[2000:n, 0, 0]
    assert 0.5 < np.corrcoef(x, y)[0, 1] < 0.6
    lagged = max(np.corrcoef(x[:-lag], y[lag:])[0, 1] for lag in range(30, 61, 5))
    assert lagged > 0.8, lagged
    pos = np.cumsum(vel, axis=0) * DT  # (from rest: the process starts at zero)
    np.testing.assert_allclose(pos, noise, rtol=0, atol=1e-12)
    # past the end: the velocity runs down without a step, to rest
    acc = np.abs(np.diff(vel[n - 200:], axis=0)).max()
    assert acc < np.abs(np.diff(vel[n - 2000:n], axis=0)).max(), acc
    assert np.abs(vel[-1]).max() < 0.01 * np.abs(vel[:n]).max()

    free = _runner(11)
    out = free._noisy(np.zeros((100, 1, 3)))
    raw, smooth, vel = _noise(11).rows(100)
    assert smooth is None and vel is None
    np.testing.assert_array_equal(out, raw)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 300), st.integers(0, 700),
       st.integers(1, 300))
def test_the_smoothed_noise_is_one_process_across_a_cut(seed: int, n1: int, cut: int,
                                                        n2: int) -> None:
    """Segment 1 runs ``cut`` rows (past its end into its tail, or fewer), then segment 2
    follows: the smoothed rows applied equal the two low-passes run once over the raw rows
    applied (truth: one ``lfilter`` pass each over the whole, segment 1's raw error held
    past its end as its targets are), and the velocity handed on is the difference from the
    last row applied."""
    from scipy.signal import lfilter

    from nonprehensile.sim.closed_loop import _smoothing_gain

    tau = 0.03
    f = _noise(seed)
    raw1, y1, _ = f.rows(n1, tau)
    assert y1 is not None
    cut = min(cut, len(y1))
    f.cut(cut)
    raw2, y2, v2 = f.rows(n2, tau)
    assert y2 is not None and v2 is not None
    applied_raw = np.concatenate([raw1[:cut], np.repeat(raw1[-1:], max(0, cut - n1), axis=0),
                                  raw2])
    c = math.exp(-DT / tau)
    one = lfilter([(1.0 - c) * _smoothing_gain(DT, tau)], [1.0, -c], applied_raw, axis=0)
    one = lfilter([1.0 - c], [1.0, -c], one, axis=0)
    applied = np.concatenate([y1[:cut], y2[:n2]])
    np.testing.assert_allclose(applied, one[:cut + n2], rtol=0, atol=1e-13)
    prev = y1[cut - 1] if cut >= 1 else np.zeros((1, 3))
    np.testing.assert_allclose(v2[0], (y2[0] - prev) / DT, rtol=0, atol=1e-9)
