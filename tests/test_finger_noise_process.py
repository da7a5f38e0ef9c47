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

from nonprehensile.sim.closed_loop import _Runner
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


def _runner(seed: int, driver: Any = None) -> _Runner:
    """A runner with only what its noise reads (no scene: the process is plain arithmetic)."""
    r = _Runner.__new__(_Runner)
    r.sim = SimpleNamespace(driver=driver if driver is not None else object())
    r.dt = DT
    r.rng = np.random.default_rng(seed)
    r.finger_noise = SIGMA
    z = np.zeros((1, 3))
    r._noise_state = (z, z, z)
    r._noise_from = r._noise_state
    r._noise_rows = None
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
    r._cut_noise(cut)
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
    r._cut_noise(80)  # held 30 steps past the end
    np.testing.assert_array_equal(r._noise_state[0], seg1[-1])


def test_an_arm_gets_the_noise_smoothed_with_its_velocity() -> None:
    """An arm that asks for the noise smoothed (``noise_smoothing`` tau) gets the process
    through two first-order low-passes in series and that result's velocity: integrated,
    the velocity gives the smoothed error back (truth: the sum of the velocities against
    the positions, across a cut); scaled, it keeps the raw process's standard deviation
    (within 10 % over 60 s; unscaled the smoothing at 20 ms keeps 78 %) and follows it,
    20-30 ms behind (correlation 0.6-0.7); the free fingertips (no ``with_noise``) get the
    raw process, added to their targets."""
    arm = _Arm(0.02)
    r = _runner(11, arm)
    targets = np.zeros((60_000, 1, 3))
    assert r._noisy(targets) is targets  # an arm's targets stay the targets
    noise, vel = arm.got[-1]
    assert vel is not None
    raw = r._noise_rows[0] if r._noise_rows is not None else None
    assert raw is not None
    ratio = noise[2000:].std() / raw[2000:].std()
    assert 0.9 < ratio < 1.1, ratio
    corr = np.corrcoef(noise[2000:, 0, 0], raw[2000:, 0, 0])[0, 1]
    assert 0.6 < corr < 0.7, corr
    # the velocity integrates to the position (from rest: the process starts at zero)
    pos = np.cumsum(vel, axis=0) * DT
    np.testing.assert_allclose(pos, noise, rtol=0, atol=1e-12)
    # across a cut: the next segment's first rows continue the smoothed rows applied
    r._cut_noise(1000)
    r._noisy(np.zeros((10, 1, 3)))
    noise2, vel2 = arm.got[-1]
    assert vel2 is not None
    np.testing.assert_allclose(noise2[0], noise[999] + vel2[0] * DT, rtol=0, atol=1e-15)
    step = np.abs(noise2[0] - noise[999]).max()
    assert step < 2.0 * DT * np.abs(vel[990:1000]).max() + 1e-9, step

    free = _runner(11)
    out = free._noisy(np.zeros((100, 1, 3)))
    assert free._noise_rows is not None and len(free._noise_rows) == 1
    np.testing.assert_array_equal(out, free._noise_rows[0])
