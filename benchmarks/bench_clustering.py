"""Trajectory clustering: the paper's recipe and ours against scikit-learn, in one run.

Quality: ARI and NMI against the true classes on the bundled cube demonstrations (when the
package ships them) and on three real public motion datasets bundled inside PyPI wheels, read
offline from their package data (a dataset is skipped with a note when its package is absent):

* GunPoint (sktime or aeon): the x-position of an actor's hand drawing a gun or pointing
  (2 classes, 200).
* BasicMotions (sktime or aeon): smartwatch accelerometer and gyroscope, 3 + 3 axes, while
  standing, walking, running or playing badminton (4 classes, 80).
* PickupGestureWiimoteZ (aeon): a Wiimote's z-acceleration during 10 gestures (10 classes,
  100, unequal lengths resampled to 100 points).

Batch: KMeans, GaussianMixture, Birch, ours (``fit``) and the paper's (``fit``). Streams: ours,
the paper's and MiniBatchKMeans (``partial_fit`` in chunks of 10) on a shuffled stream and on
a stream ordered by class, the first batch being 10 % of the stream (at least 20 samples).
Every number is the mean over ``SEEDS`` seeds (shuffles and random states).

Cost: per-registration time of ours with 10^3 .. 10^6 samples stored (synthetic vectors, 32
features, 8 clusters), in memory and in SQLite, against re-running a batch KMeans on each
arrival, timed in the same run.
"""

from __future__ import annotations

import importlib.util
import math
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from sklearn.cluster import Birch, KMeans, MiniBatchKMeans
from sklearn.metrics import adjusted_rand_score, normalized_mutual_info_score
from sklearn.mixture import GaussianMixture

from nonprehensile.motion.clustering import HilbertClusterer, Method
from nonprehensile.motion.store import SQLiteStore

SEEDS = (0, 1, 2, 3, 4)
METHODS: tuple[tuple[Method, str], ...] = (("runs", "ours"), ("paper", "paper"))
CHUNK = 10
COST_SIZES = (10**3, 10**4, 10**5, 10**6)
COST_SQLITE_SIZES = (10**3, 10**4, 10**5, 10**6)
COST_FEATURES = 32
COST_CLUSTERS = 8
COST_PROBES = 320

Dataset = tuple[str, NDArray[np.float64], NDArray[np.int64]]


# --------------------------------------------------------------------------- datasets


def _to_length(values: NDArray[np.float64], n: int | None) -> NDArray[np.float64]:
    if n is None:
        return values
    # unequal-length series are resampled in normalised time, as the motion model resamples
    # every demonstration to the same number of points (linear: accelerometer data is noisy)
    return np.interp(np.linspace(0, 1, n), np.linspace(0, 1, values.size), values)


def read_ts(path: Path, length: int | None = None
            ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """A ``.ts`` file (UEA/UCR time-series format), each series flattened into one row.

    Read by hand rather than through sktime's or aeon's loader, which need pandas (and aeon
    numba): the format is plain text, one series a line, channels separated by ``:``, the
    class label last. ``length``: resample every channel to this many points.
    """
    rows, labels = [], []
    in_data = False
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if not in_data:
            in_data = line.lower().startswith("@data")
            continue
        *channels, label = line.split(":")
        rows.append(np.concatenate([_to_length(np.array(c.split(","), dtype=np.float64),
                                               length) for c in channels]))
        labels.append(label)
    _, y = np.unique(labels, return_inverse=True)
    return np.array(rows), y.astype(np.int64)


def packaged_dataset(name: str, packages: tuple[str, ...], length: int | None = None
                     ) -> Dataset | None:
    """A dataset from the package data of the first of ``packages`` installed (not imported:
    only its files are read, so none of its dependencies is needed)."""
    for package in packages:
        spec = importlib.util.find_spec(package)
        if spec is None or not spec.submodule_search_locations:
            continue
        folder = Path(next(iter(spec.submodule_search_locations))) / "datasets" / "data" / name
        if not folder.is_dir():
            continue
        parts = [read_ts(folder / f"{name}_{split}.ts", length) for split in ("TRAIN", "TEST")]
        return (f"{name} ({package})", np.vstack([p[0] for p in parts]),
                np.concatenate([p[1] for p in parts]))
    print(f"   {name}: skipped (install {' or '.join(packages)}, the 'bench' extra, for its "
          "bundled data)")
    return None


def cube_dataset() -> Dataset | None:
    try:
        from nonprehensile.demonstrations.dataset import dataset_path, load_dataset
        from nonprehensile.motion.trajectory import preprocess

        root = dataset_path("cube")
        if not root.exists():
            raise FileNotFoundError(root)
        ds = load_dataset(root)
    except Exception as exc:  # the bundled demonstrations may not be generated yet
        print(f"   cube demonstrations: skipped ({type(exc).__name__}: {exc})")
        return None
    rows, labels = [], []
    for d in ds.demonstrations:
        t = d.trajectory
        rows.append(preprocess(t.positions, t.rate, t_start=d.events[0].time,
                               t_end=d.events[-1].time, max_gap=ds.gap_limit))
        labels.append(d.skill.name)
    _, y = np.unique(labels, return_inverse=True)
    return "cube demonstrations", np.array(rows), y.astype(np.int64)


# --------------------------------------------------------------------------- quality


def _scores(y: NDArray[np.int64], lab: NDArray[np.int64]) -> tuple[float, float]:
    return adjusted_rand_score(y, lab), normalized_mutual_info_score(y, lab)


def _stream(c: HilbertClusterer, x: NDArray[np.float64]) -> None:
    for s in range(0, x.shape[0], CHUNK):
        c.partial_fit(x[s : s + CHUNK])


def _init_size(n: int) -> int:
    return max(20, n // 10)


def quality(name: str, x: NDArray[np.float64], y: NDArray[np.int64]) -> dict[str, float]:
    k = int(y.max()) + 1
    n = x.shape[0]
    res: dict[str, list[tuple[float, float]]] = {}

    def add(label: str, truth: NDArray[np.int64], lab: NDArray[np.int64]) -> None:
        res.setdefault(label, []).append(_scores(truth, lab))

    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        add("KMeans", y, KMeans(k, n_init=10, random_state=seed).fit_predict(x))
        add("GaussianMixture", y, GaussianMixture(k, covariance_type="diag",
                                                  random_state=seed).fit_predict(x))
        add("Birch", y, Birch(n_clusters=k).fit_predict(x))
        for method, label in METHODS:
            add(f"{label} batch", y,
                HilbertClusterer(k, method=method, random_state=seed).fit_predict(x))
        shuffled = rng.permutation(n)
        # ordered by class, shuffled within each class
        ordered = shuffled[np.argsort(y[shuffled], kind="stable")]
        for order_name, idx in (("shuffled", shuffled), ("class-ordered", ordered)):
            for method, label in METHODS:
                c = HilbertClusterer(k, method=method, init_size=_init_size(n),
                                     random_state=seed)
                _stream(c, x[idx])
                add(f"{label} stream {order_name}", y[idx], c.labels_)
            mbk = MiniBatchKMeans(k, random_state=seed, n_init=3)
            first = _init_size(n)
            mbk.partial_fit(x[idx[:first]])
            for s in range(first, n, CHUNK):
                mbk.partial_fit(x[idx[s : s + CHUNK]])
            add(f"MiniBatchKMeans stream {order_name}", y[idx], mbk.predict(x[idx]))
    print(f"   {name}: {n} samples, {x.shape[1]} features, {k} classes "
          f"(mean of {len(SEEDS)} seeds)")
    print(f"   {'method':<36} {'ARI':>6} {'NMI':>6}")
    means = {}
    for label, vals in res.items():
        ari = statistics.fmean(v[0] for v in vals)
        nmi = statistics.fmean(v[1] for v in vals)
        means[label] = ari
        print(f"   {label:<36} {ari:6.3f} {nmi:6.3f}")
    best = max(means[m] for m in ("KMeans", "GaussianMixture", "Birch"))
    ours = means["ours batch"]
    print(f"   ours batch - best of KMeans/GMM/Birch: {ours - best:+.3f} ARI "
          f"({'ok' if ours >= best - 1e-9 else 'BELOW GOAL'}); "
          f"class-ordered stream - ours batch: "
          f"{means['ours stream class-ordered'] - ours:+.3f} ARI "
          f"({'ok' if means['ours stream class-ordered'] >= ours - 0.05 else 'BELOW GOAL'}); "
          f"paper batch - best: {means['paper batch'] - best:+.3f}", flush=True)
    return means


# --------------------------------------------------------------------------- cost


def _synthetic(n: int, seed: int) -> NDArray[np.float64]:
    rng = np.random.default_rng(seed)
    centers = rng.normal(scale=4.0, size=(COST_CLUSTERS, COST_FEATURES))
    return centers[rng.integers(0, COST_CLUSTERS, n)] + rng.normal(size=(n, COST_FEATURES))


def _time_one(c: HilbertClusterer, row: NDArray[np.float64]) -> float:
    t0 = time.perf_counter()
    c.partial_fit(row[None, :])
    return time.perf_counter() - t0


def cost() -> None:
    """Per-registration time at each size, measured in interleaved rounds.

    Every clusterer is built first; then each round registers ``COST_PROBES // ROUNDS``
    samples into each size in turn, so that a burst of load from other processes on a small
    machine hits every size alike. A size's time is the least of its rounds' medians; the
    mean over all probes includes any recalibration that falls in.
    """
    rounds = 6
    probes = _synthetic(COST_PROBES, 99)
    per = (COST_PROBES - 20) // rounds
    print(f"   per-registration cost, {COST_FEATURES} features, {COST_CLUSTERS} clusters: "
          f"least median of {rounds} interleaved rounds of {per} single-sample partial_fit "
          "calls (mean of all)")
    # imports and first-call costs (scikit-learn, lookup tables) outside the timings
    HilbertClusterer(COST_CLUSTERS, random_state=0).fit(_synthetic(2000, 1))
    with tempfile.TemporaryDirectory() as tmp:
        built: list[tuple[str, int, HilbertClusterer, float]] = []
        for backend, sizes in (("memory", COST_SIZES), ("sqlite", COST_SQLITE_SIZES)):
            for n in sizes:
                store = (SQLiteStore(os.path.join(tmp, f"s{n}.db")) if backend == "sqlite"
                         else None)
                c = HilbertClusterer(COST_CLUSTERS, init_size=1000, random_state=0,
                                     store=store)
                t0 = time.perf_counter()
                c.partial_fit(_synthetic(n, n))
                build = time.perf_counter() - t0
                for row in probes[:20]:  # warm the caches (SQLite's pages, numpy's)
                    c.partial_fit(row[None, :])
                built.append((backend, n, c, build))
        times: list[list[list[float]]] = [[] for _ in built]
        for r in range(rounds):
            rows = probes[20 + r * per : 20 + (r + 1) * per]
            for i, (_, _, c, _) in enumerate(built):
                times[i].append([_time_one(c, row) for row in rows])
        base: dict[str, float] = {}
        for (backend, n, c, build), ts in zip(built, times, strict=True):
            med = min(statistics.median(t) for t in ts)
            mean = statistics.fmean(v for t in ts for v in t)
            base.setdefault(backend, med)
            print(f"   {backend:>6} n={n:>8}: {med * 1e3:7.3f} ms ({mean * 1e3:7.3f} ms), "
                  f"x{med / base[backend]:.2f} of n=1e3; built in {build:.1f} s "
                  f"({build / n * 1e6:.1f} us/sample amortised, "
                  f"{c.n_recalibrations_} recalibrations)", flush=True)
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
              f"({km / base['memory']:.0f}x ours in memory at n=1e3)", flush=True)


def main() -> None:
    datasets = [
        cube_dataset(),
        packaged_dataset("GunPoint", ("sktime", "aeon")),
        packaged_dataset("BasicMotions", ("sktime", "aeon")),
        packaged_dataset("PickupGestureWiimoteZ", ("aeon",), length=100),
    ]
    for ds in datasets:
        if ds is not None:
            quality(*ds)
    cost()


if __name__ == "__main__":
    main()
