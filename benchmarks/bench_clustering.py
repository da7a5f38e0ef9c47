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


def _time_one(c: HilbertClusterer, row: NDArray[np.float64]) -> float:
    t0 = time.perf_counter()
    c.partial_fit(row[None, :])
    return time.perf_counter() - t0


def cost() -> None:
    """Per-registration time at each size, measured in interleaved rounds; batched rate.

    Every clusterer is built first (``partial_fit`` in batches of 10 000); then each round
    registers ``COST_PROBES // ROUNDS`` single samples into each size in turn, so that a
    burst of load from other processes on a small machine hits every size alike. A size's
    median is the least of its rounds' medians; its p99 is over all its probes. Then one
    ``partial_fit`` of ``COST_BATCH`` samples per size gives the batched rate.
    """
    rounds = 6
    probes = _synthetic(COST_PROBES, 99)
    per = (COST_PROBES - 20) // rounds
    print(f"   one registration, {COST_FEATURES} features, {COST_CLUSTERS} clusters: least "
          f"median of {rounds} interleaved rounds of {per} single-sample partial_fit calls, "
          f"p99 of all; batched: one partial_fit of {COST_BATCH} samples")
    # imports and first-call costs (lookup tables, threadpoolctl) outside the timings
    HilbertClusterer(COST_CLUSTERS, random_state=0).fit(_synthetic(2000, 1))
    with tempfile.TemporaryDirectory() as tmp:
        built: list[tuple[str, int, HilbertClusterer, float]] = []
        for backend, sizes in (("memory", COST_SIZES), ("sqlite", COST_SQLITE_SIZES)):
            for n in sizes:
                store = (SQLiteStore(os.path.join(tmp, f"s{n}.db")) if backend == "sqlite"
                         else None)
                c = HilbertClusterer(COST_CLUSTERS, init_size=1000, random_state=0,
                                     store=store)
                x = _synthetic(n, n)
                t0 = time.perf_counter()
                for s in range(0, n, 10_000):
                    c.partial_fit(x[s : s + 10_000])
                build = time.perf_counter() - t0
                for row in probes[:20]:  # warm the caches (SQLite's pages, numpy's)
                    c.partial_fit(row[None, :])
                built.append((backend, n, c, build))
                print(f"   built {backend} n={n}: {build:.1f} s", flush=True)
        times: list[list[list[float]]] = [[] for _ in built]
        for r in range(rounds):
            rows = probes[20 + r * per : 20 + (r + 1) * per]
            for i, (_, _, c, _) in enumerate(built):
                times[i].append([_time_one(c, row) for row in rows])
        base: dict[str, tuple[float, float]] = {}
        batch = _synthetic(COST_BATCH, 7)
        for (backend, n, c, build), ts in zip(built, times, strict=True):
            med = min(statistics.median(t) for t in ts)
            p99 = float(np.quantile([v for t in ts for v in t], 0.99))
            t0 = time.perf_counter()
            c.partial_fit(batch)
            rate = COST_BATCH / (time.perf_counter() - t0)
            base.setdefault(backend, (med, rate))
            ratio = med / base[backend][0]
            print(f"   {backend:>6} n={n:>8}: one {med * 1e3:6.3f} ms (x{ratio:.2f} of n=1e3), "
                  f"p99 {p99 * 1e3:6.2f} ms; batched {rate:8.0f} samples/s "
                  f"(x{base[backend][1] / rate:.2f} of n=1e3 in time); built at "
                  f"{build / n * 1e6:.0f} us/sample ({c.n_recalibrations_} recalibrations)",
                  flush=True)
            if isinstance(c.store, SQLiteStore):
                c.store.close()
    for n in COST_SIZES:
        x = _synthetic(n, n)
        km = math.inf
        for _ in range(1 if n >= 10**6 else 3):
            t0 = time.perf_counter()
            KMeans(COST_CLUSTERS, n_init=1, random_state=0).fit(x)
            km = min(km, time.perf_counter() - t0)
        print(f"   KMeans re-run on each arrival, n={n:>8}: {km * 1e3:9.1f} ms per arrival "
              f"({km / base['memory'][0]:.0f}x ours in memory at n=1e3)", flush=True)


def main() -> None:
    cost()


if __name__ == "__main__":
    main()
