"""Trajectory clustering: the cost of one registration and of batched registration (issue 14).

One registration (single-sample ``partial_fit``, in memory and in SQLite) with 10^3 .. 10^6
samples stored (synthetic: 8 fixed Gaussian clusters in 32 features, a stationary stream),
median and 99th percentile; batched registration (one ``partial_fit`` of 5000 samples) in
samples per second; against re-running a batch KMeans on each arrival.

The quality half (ARI on six real datasets, batch and streaming anchors) is
``bench_clustering_quality`` (``python -m benchmarks clustering_quality`` runs it alone;
``python -m benchmarks clustering`` runs both).
"""

from __future__ import annotations

import math
import os
import statistics
import sys
import tempfile
import time

import numpy as np
from numpy.typing import NDArray
from sklearn.cluster import KMeans

from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.store import SQLiteStore

COST_SIZES = (10**3, 10**4, 10**5, 10**6)
COST_SQLITE_SIZES = (10**3, 10**4, 10**5, 10**6)
COST_FEATURES = 32
COST_CLUSTERS = 8
COST_PROBES = 1220
COST_BATCH = 5000


# --------------------------------------------------------------------------- cost

_CENTERS = np.random.default_rng(0).normal(scale=4.0, size=(COST_CLUSTERS, COST_FEATURES))


def _synthetic(n: int, seed: int) -> NDArray[np.float64]:
    """A stationary stream: the same 8 clusters whatever the seed."""
    rng = np.random.default_rng(seed)
    return _CENTERS[rng.integers(0, COST_CLUSTERS, n)] + rng.normal(size=(n, COST_FEATURES))


def _steps(c: HilbertClusterer) -> tuple[int, int, int]:
    """Heavy steps done so far: compactions, macro steps, calibrations of the summary."""
    m = c._micro
    return m.n_compactions, m.n_macro_steps, m.n_calibrations


def _time_one(c: HilbertClusterer, row: NDArray[np.float64]) -> tuple[float, float, bool]:
    """Wall and CPU seconds of one single-sample ``partial_fit``, and whether it ran a heavy
    step (a compaction, a macro step or a calibration)."""
    before = _steps(c)
    t0, p0 = time.perf_counter(), time.process_time()
    c.partial_fit(row[None, :])
    wall, cpu = time.perf_counter() - t0, time.process_time() - p0
    return wall, cpu, _steps(c) != before


def _load() -> str:
    return "load average {:.1f} {:.1f} {:.1f}".format(*os.getloadavg())


def cost(sizes: tuple[int, ...] = COST_SIZES,
         sqlite_sizes: tuple[int, ...] = COST_SQLITE_SIZES) -> None:
    """Per-registration time at each size, measured in interleaved rounds; batched rate.

    Every clusterer is built first (``partial_fit`` in batches of 10 000); then each round
    registers ``COST_PROBES // ROUNDS`` single samples into each size in turn, so that a
    burst of load from other processes on a small machine hits every size alike. A size's
    median is the least of its rounds' medians; its p99 is over all its probes. Each call's
    wall time and CPU time (``time.process_time``) are both kept: on a shared machine the wall
    tail is time spent off the CPU. Then one ``partial_fit`` of ``COST_BATCH`` samples per
    size gives the batched rate (wall and CPU).
    """
    rounds = 6
    probes = _synthetic(COST_PROBES, 99)
    per = (COST_PROBES - 20) // rounds
    print(f"   one registration, {COST_FEATURES} features, {COST_CLUSTERS} clusters: least "
          f"median of {rounds} interleaved rounds of {per} single-sample partial_fit calls, "
          f"p99 of all; batched: one partial_fit of {COST_BATCH} samples; {_load()}")
    # imports and first-call costs (lookup tables, threadpoolctl) outside the timings
    HilbertClusterer(COST_CLUSTERS, random_state=0).fit(_synthetic(2000, 1))
    with tempfile.TemporaryDirectory() as tmp:
        built: list[tuple[str, int, HilbertClusterer, float, float]] = []
        for backend, backend_sizes in (("memory", sizes), ("sqlite", sqlite_sizes)):
            for n in backend_sizes:
                store = (SQLiteStore(os.path.join(tmp, f"s{n}.db")) if backend == "sqlite"
                         else None)
                c = HilbertClusterer(COST_CLUSTERS, init_size=1000, random_state=0,
                                     store=store)
                x = _synthetic(n, n)
                t0, p0 = time.perf_counter(), time.process_time()
                for s in range(0, n, 10_000):
                    c.partial_fit(x[s : s + 10_000])
                build, build_cpu = time.perf_counter() - t0, time.process_time() - p0
                for row in probes[:20]:  # warm the caches (SQLite's pages, numpy's)
                    c.partial_fit(row[None, :])
                built.append((backend, n, c, build, build_cpu))
                print(f"   built {backend} n={n}: {build:.1f} s ({build_cpu:.1f} s CPU, "
                      f"{n / build_cpu:,.0f} samples/s CPU); {_load()}", flush=True)
        times: list[list[list[tuple[float, float, bool]]]] = [[] for _ in built]
        for r in range(rounds):
            rows = probes[20 + r * per : 20 + (r + 1) * per]
            for i, (_, _, c, _, _) in enumerate(built):
                times[i].append([_time_one(c, row) for row in rows])
        print(f"   timed; {_load()}")
        base: dict[str, tuple[float, float]] = {}
        batch = _synthetic(COST_BATCH, 7)
        for (backend, n, c, _, build_cpu), ts in zip(built, times, strict=True):
            med = min(statistics.median(t[0] for t in r) for r in ts)
            med_cpu = min(statistics.median(t[1] for t in r) for r in ts)
            flat = [t for r in ts for t in r]
            p99 = float(np.quantile([t[0] for t in flat], 0.99))
            p99_cpu = float(np.quantile([t[1] for t in flat], 0.99))
            slow = [t for t in flat if t[0] > 2e-3]
            heavy = sum(t[2] for t in slow)
            off_cpu = sum(not t[2] and t[1] < 0.5 * t[0] for t in slow)
            before = _steps(c)
            t0, p0 = time.perf_counter(), time.process_time()
            c.partial_fit(batch)
            wall, cpu = time.perf_counter() - t0, time.process_time() - p0
            steps = [a - b for a, b in zip(_steps(c), before, strict=True)]
            rate, rate_cpu = COST_BATCH / wall, COST_BATCH / cpu
            base.setdefault(backend, (med, rate))
            ratio = med / base[backend][0]
            print(f"   {backend:>6} n={n:>8}: one {med * 1e3:6.3f} ms (x{ratio:.2f} of n=1e3; "
                  f"CPU {med_cpu * 1e3:.3f} ms), p99 {p99 * 1e3:6.2f} ms (CPU "
                  f"{p99_cpu * 1e3:.2f} ms; {len(slow)} calls over 2 ms: {heavy} ran a heavy "
                  f"step, {off_cpu} were mostly off the CPU); batched {rate:8,.0f} samples/s "
                  f"(x{base[backend][1] / rate:.2f} of n=1e3 in time; CPU {rate_cpu:,.0f} "
                  f"samples/s; {steps[0]} compactions, {steps[1]} macro steps, {steps[2]} "
                  f"calibrations in the batch); built at {build_cpu / n * 1e6:.0f} us/sample "
                  "CPU", flush=True)
            if isinstance(c.store, SQLiteStore):
                c.store.close()
        del built, times
    print(f"   {_load()}")
    for n in sizes:
        x = _synthetic(n, n)
        km = math.inf
        for _ in range(1 if n >= 10**6 else 3):
            t0 = time.perf_counter()
            KMeans(COST_CLUSTERS, n_init=1, random_state=0).fit(x)
            km = min(km, time.perf_counter() - t0)
        print(f"   KMeans re-run on each arrival, n={n:>8}: {km * 1e3:9.1f} ms per arrival "
              f"({km / base['memory'][0]:.0f}x ours in memory at n=1e3)", flush=True)


def main(argv: list[str] | None = None) -> None:
    """The cost part (``python -m benchmarks.bench_clustering``, a few minutes; ``--cost`` is
    accepted and changes nothing: the quality half moved to ``bench_clustering_quality``)."""
    del argv
    cost()


if __name__ == "__main__":
    main(sys.argv[1:])
