"""Trajectory clustering: ours (micro-cluster summary), the paper's recipe, batch and streaming
anchors, in one run (issue 14).

Quality: ARI and NMI against the true classes, the true number of clusters given to every
method, on the bundled cube demonstrations (when the package ships them) and on six public
time-series datasets shipped inside PyPI wheels, read offline from their package data (a
dataset is skipped with a note when its package is absent): BasicMotions, GunPoint, ArrowHead,
JapaneseVowels (sktime or aeon), PickupGestureWiimoteZ and OSULeaf (aeon). Unequal lengths
are resampled (linear, normalised time) as the motion model resamples demonstrations.

Batch anchors: KMeans (10 starts), Ward and GaussianMixture (diagonal covariances; also full on
the PCA features), each on the flat vectors, on 2 principal components and on the components
keeping 90 % of the variance; the best of them (mean over seeds) is the bar. Streams: ours
(``partial_fit`` in chunks of 10, the first batch 10 % of the stream, at least 20 samples,
labels as the stream leaves them: no closing recalibration), the paper's, MiniBatchKMeans and
Birch (``partial_fit``), and river's CluStream, STREAMKMeans and DBSTREAM (``learn_one``, when
river is installed), on a shuffled stream and on a stream ordered by class.

Cost: one registration (single-sample ``partial_fit``, in memory and in SQLite) with 10^3 ..
10^6 samples stored (synthetic: 8 fixed Gaussian clusters in 32 features, a stationary
stream), median and 99th percentile; batched registration (one ``partial_fit`` of 5000
samples) in samples per second; against re-running a batch KMeans on each arrival.
"""

from __future__ import annotations

import importlib.util
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from sklearn.cluster import AgglomerativeClustering, Birch, KMeans, MiniBatchKMeans
from sklearn.decomposition import PCA
from sklearn.metrics import adjusted_rand_score, normalized_mutual_info_score
from sklearn.mixture import GaussianMixture

from nonprehensile.motion.clustering import HilbertClusterer, Method
from nonprehensile.motion.store import SQLiteStore

SEEDS = (0, 1, 2)
METHODS: tuple[tuple[Method, str], ...] = (("micro", "ours"), ("paper", "paper"))
CHUNK = 10
COST_SIZES = (10**3, 10**4, 10**5, 10**6)
COST_SQLITE_SIZES = (10**3, 10**4, 10**5, 10**6)
COST_FEATURES = 32
COST_CLUSTERS = 8
COST_PROBES = 1220
COST_BATCH = 5000
RIVER_MAX_FEATURES = 1000
#: (name, packages holding it, resampled length or None)
PUBLIC = (("BasicMotions", ("sktime", "aeon"), None),
          ("PickupGestureWiimoteZ", ("aeon",), 100),
          ("ArrowHead", ("sktime", "aeon"), None),
          ("JapaneseVowels", ("sktime", "aeon"), 25),
          ("GunPoint", ("sktime", "aeon"), None),
          ("OSULeaf", ("aeon",), None))

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


def _init_size(n: int) -> int:
    return max(20, n // 10)


def batch_anchors(x: NDArray[np.float64], k: int, seed: int
                  ) -> dict[str, NDArray[np.int64]]:
    """KMeans, Ward and GMM on flat, PCA-2 and PCA-90 % features."""
    feats = {"flat": x, "PCA-2": PCA(2, random_state=seed).fit_transform(x),
             "PCA-90%": PCA(0.9, svd_solver="full").fit_transform(x)}
    out = {}
    for fname, f in feats.items():
        out[f"KMeans {fname}"] = KMeans(k, n_init=10, random_state=seed).fit_predict(f)
        out[f"Ward {fname}"] = AgglomerativeClustering(k).fit_predict(f)
        for cov in ("diag",) if fname == "flat" else ("diag", "full"):
            out[f"GMM-{cov} {fname}"] = GaussianMixture(
                k, covariance_type=cov, random_state=seed).fit_predict(f)
    return out


def _river_streams(x: NDArray[np.float64], k: int, seed: int
                   ) -> dict[str, NDArray[np.int64]]:
    """river's streaming clusterers on the stream ``x`` (learn_one, then predict_one)."""
    if x.shape[1] > RIVER_MAX_FEATURES:
        return {}  # river works on dicts, one sample at a time: too slow on 4800 features
    try:
        from river import cluster
    except ImportError:
        return {}
    models = {
        "river CluStream": cluster.CluStream(n_macro_clusters=k, max_micro_clusters=100,
                                             time_gap=max(20, x.shape[0] // 4), seed=seed),
        "river STREAMKMeans": cluster.STREAMKMeans(chunk_size=max(20, x.shape[0] // 10),
                                                   n_clusters=k, seed=seed),
        "river DBSTREAM": cluster.DBSTREAM(),
    }
    rows = [dict(enumerate(r.tolist())) for r in x]
    out = {}
    for name, model in models.items():
        for r in rows:
            model.learn_one(r)
        out[name] = np.array([model.predict_one(r) for r in rows], dtype=np.int64)
    return out


def streams(x: NDArray[np.float64], y: NDArray[np.int64], idx: NDArray[np.int64], k: int,
            seed: int) -> dict[str, tuple[NDArray[np.int64], float]]:
    """Every stream on the order ``idx``: labels (in stream order) and seconds per sample."""
    n = idx.size
    xs = x[idx]
    out: dict[str, tuple[NDArray[np.int64], float]] = {}
    for method, label in METHODS:
        c = HilbertClusterer(k, method=method, init_size=_init_size(n), random_state=seed)
        t0 = time.perf_counter()
        for s in range(0, n, CHUNK):
            c.partial_fit(xs[s : s + CHUNK])
        out[label] = (c.labels_, (time.perf_counter() - t0) / n)
    first = _init_size(n)
    for name, model in (("MiniBatchKMeans", MiniBatchKMeans(k, random_state=seed, n_init=3)),
                        ("Birch", Birch(n_clusters=k))):
        t0 = time.perf_counter()
        model.partial_fit(xs[:first])
        for s in range(first, n, CHUNK):
            model.partial_fit(xs[s : s + CHUNK])
        out[name] = (model.predict(xs), (time.perf_counter() - t0) / n)
    t0 = time.perf_counter()
    river = _river_streams(xs, k, seed)
    for name, lab in river.items():
        out[name] = (lab, (time.perf_counter() - t0) / n / len(river))
    return out


def quality(name: str, x: NDArray[np.float64], y: NDArray[np.int64]) -> dict[str, float]:
    k = int(y.max()) + 1
    n = x.shape[0]
    res: dict[str, list[tuple[float, float]]] = {}
    cost: dict[str, list[float]] = {}

    def add(label: str, truth: NDArray[np.int64], lab: NDArray[np.int64]) -> None:
        res.setdefault(label, []).append(_scores(truth, lab))

    anchors: set[str] = set()
    for seed in SEEDS:
        for label, lab in batch_anchors(x, k, seed).items():
            anchors.add(label)
            add(label, y, lab)
        for method, label in METHODS:
            t0 = time.perf_counter()
            c = HilbertClusterer(k, method=method, random_state=seed).fit(x)
            cost.setdefault(f"{label} batch", []).append((time.perf_counter() - t0) / n)
            add(f"{label} batch", y, c.labels_)
        rng = np.random.default_rng(seed)
        shuffled = rng.permutation(n)
        # ordered by class, shuffled within each class
        ordered = shuffled[np.argsort(y[shuffled], kind="stable")]
        for order_name, idx in (("shuffled", shuffled), ("class-ordered", ordered)):
            for label, (lab, sec) in streams(x, y, idx, k, seed).items():
                add(f"{label} stream {order_name}", y[idx], lab)
                cost.setdefault(f"{label} stream {order_name}", []).append(sec)
    print(f"   {name}: {n} samples, {x.shape[1]} features, {k} classes "
          f"(mean of {len(SEEDS)} seeds)")
    print(f"   {'method':<40} {'ARI':>6} {'NMI':>6} {'us/sample':>10}")
    means = {}
    for label, vals in res.items():
        ari = statistics.fmean(v[0] for v in vals)
        nmi = statistics.fmean(v[1] for v in vals)
        means[label] = ari
        us = f"{statistics.fmean(cost[label]) * 1e6:10.0f}" if label in cost else " " * 10
        print(f"   {label:<40} {ari:6.3f} {nmi:6.3f} {us}")
    best_name = max(anchors, key=lambda a: means[a])
    best = means[best_name]
    ours = means["ours batch"]
    ordered_gap = means["ours stream class-ordered"] - ours
    print(f"   bar 1: ours batch {ours:.3f} against the best batch anchor ({best_name}) "
          f"{best:.3f}: {ours - best:+.3f} ({'met' if ours >= best - 0.01 else 'MISSED'}, "
          f"goal >= -0.01); class-ordered stream - ours batch: {ordered_gap:+.3f} "
          f"({'met' if abs(ordered_gap) <= 0.05 else 'MISSED'}, goal within 0.05)", flush=True)
    return means


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
    """Quality, then cost; ``--cost`` (``python -m benchmarks.bench_clustering --cost``): only
    the cost part, the one-command re-run of the registration bars (a few minutes)."""
    if "--cost" not in (argv or []):
        datasets = [*(packaged_dataset(n, p, ln) for n, p, ln in PUBLIC), cube_dataset()]
        for ds in datasets:
            if ds is not None:
                quality(*ds)
    cost()


if __name__ == "__main__":
    main(sys.argv[1:])
