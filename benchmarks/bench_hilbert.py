"""Hilbert encoding: nonprehensile's vectorised encode against ``hilbertcurve``.

Two workloads: the paper's (10**6 points, 2-D, order 5, served by the lookup table) and a
wider one (10**5 points, 8-D, order 10: 80-bit keys, the general path). ``hilbertcurve``
loops over points in Python, so it is timed on a subsample and scaled to the full count;
the output says so. Both are checked to agree on the subsample.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable

import numpy as np
from hilbertcurve.hilbertcurve import HilbertCurve

from nonprehensile.motion.hilbert import encode, key_to_int

# (label, n_points, n_dims, order, hilbertcurve subsample, goal ratio)
CASES = [
    ("2-D order 5 (paper)", 10**6, 2, 5, 20_000, 100.0),
    ("8-D order 10", 10**5, 8, 10, 5_000, 10.0),
]


def _best_of(fn: Callable[[], object], repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    rng = np.random.default_rng(0)
    for label, n_points, n_dims, order, n_sub, goal in CASES:
        pts = rng.integers(0, 2**order, size=(n_points, n_dims))
        encode(pts[:10], order)  # build the lookup table (once per grid) outside the timing
        ours = _best_of(functools.partial(encode, pts, order), 3)

        sub = pts[:n_sub].tolist()
        curve = HilbertCurve(order, n_dims)
        t0 = time.perf_counter()
        ref = curve.distances_from_points(sub)
        theirs = (time.perf_counter() - t0) * n_points / n_sub
        if key_to_int(encode(pts[:n_sub], order)) != list(ref):
            raise AssertionError(f"{label}: encode disagrees with hilbertcurve")

        ratio = theirs / ours
        verdict = "ok" if ratio >= goal else "BELOW GOAL"
        print(
            f"   {label}: {n_points:.0e} points, encode {ours * 1e3:.1f} ms "
            f"({n_points / ours / 1e6:.1f} M points/s); hilbertcurve {theirs:.2f} s "
            f"(timed on {n_sub} points, scaled x{n_points // n_sub}); "
            f"ratio {ratio:.0f}x (goal >= {goal:.0f}x: {verdict})",
            flush=True,
        )
