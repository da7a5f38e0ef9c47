"""Incremental clustering of flattened trajectories on a Hilbert-curve index (paper Section VI).

Three methods share one scikit-learn style class, :class:`HilbertClusterer`:

``method="micro"`` (the default, ours): the Hilbert keys index a bounded summary of
micro-clusters, clustered by Gaussian mixtures chosen by BIC; see
:mod:`nonprehensile.motion.summary` for the design. Stored records (key, label as
registered, micro-cluster id) are written once; :attr:`HilbertClusterer.labels_` derives the
current labels from the summary.

``method="paper"``: the paper's recipe, exactly. PCA with 2 components fitted on a first batch,
components scaled to the batch's range and cut into ``2**5 = 32`` levels, the 5th-order Hilbert
index of the grid cell as the one key of a sample, clusters as runs of the sorted keys cut at
the largest gaps. A new sample is registered without reclustering (its key falls in a run);
every ``recalibration_period`` samples the principal components are refitted on a fixed-size
random sample of the stored ones, every stored sample is re-keyed and the keys re-cut.

``method="runs"`` (our earlier method). It keeps the paper's promise (one sortable key per
sample, a per-sample cost that does not grow with the data) and fixes its quality:

* More components (enough for 90 % of the variance, 2..6) and a higher order (``62 // k``
  bits per component), so the key keeps most of the geometry, still one ``int64``.
* At a recalibration, the sorted keys are cut into many short runs (at most ``max_runs``: equal
  counts, plus cuts where consecutive samples in key order are far apart in component space),
  each summarised by its centroid in the full feature space, and the runs are merged into
  clusters by Ward's agglomeration of the centroids (``merge="ward"``, Birch's final step), or
  a weighted k-means followed by one assignment step over the data (``"kmeans"``), or the
  better of the two by the silhouette (``"auto"``). Runs are split where their samples
  disagree. The cost is a few linear passes over the store and a clustering of a few hundred
  points.
* A new sample is registered by locality on the Hilbert order: its key is searched among the
  runs' centroid keys on ``n_curves`` curves (the stored key's and coarser shifted copies; a
  range scan of ``2 * window`` runs around it on each), and the real distance (full feature
  space) to those few runs decides its cluster. The cost depends on ``max_runs``, ``window``,
  ``n_curves`` and the dimension, never on the number stored.
* Drift and new skills: a sample farther from every run than ``novelty`` times the 99th
  percentile of the within-cluster distances at the last recalibration, or outside the scale
  bounds, is *novel*. Novel samples are never clipped silently: they gather in new
  provisional runs and clusters (leader clustering), and once they make ``drift_fraction`` of
  the data seen at the last recalibration, a recalibration follows. A stream ordered by skill
  thus gets its new skill as a new cluster, then a recalibrated subspace that sees it.
* Recalibration re-keys every stored sample, so it runs on a schedule that grows with the data
  (when the count reaches ``growth`` times that of the last one) or on drift (which needs
  ``drift_fraction`` times as many new samples): the re-keying work per sample is bounded by a
  constant (about ``growth / (growth - 1)`` re-keys per sample on the schedule, at most
  ``1 / drift_fraction`` under constant drift). The principal components are refitted on a
  fixed-size uniform sample of everything seen (a reservoir sample), so their cost is flat.
* Cluster ids are kept stable across recalibrations: new clusters are matched to old ids by
  their overlap (the Hungarian method on the contingency table); a cluster that splits keeps
  its id on its larger part, clusters that merge keep the id of the larger.

Scale bounds are fixed at a recalibration from every stored sample, widened by ``margin`` of
the range on each side: new data never changes stored keys until the next recalibration.

Both methods process a stream sample by sample in effect: the model is frozen between
recalibrations, which happen at fixed sample counts, and the random choices derive from the
sample's index. So ``partial_fit(A); partial_fit(B)`` gives exactly what ``partial_fit(A + B)``
gives, however the stream is chunked (when ``init_size`` is an int), and ``fit(X)`` is a
reset followed by ``partial_fit(X)``.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from collections.abc import Iterator
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nonprehensile.errors import InputError
from nonprehensile.motion.hilbert import encode, key_to_int, quantize
from nonprehensile.motion.microcluster import one_thread, pca, project
from nonprehensile.motion.store import MemoryStore, SampleStore
from nonprehensile.motion.summary import MicroSummary, match_ids

__all__ = ["HilbertClusterer", "Method", "project"]

Method = Literal["micro", "runs", "paper"]
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Keys = NDArray[np.uint64]

_METHODS = ("micro", "runs", "paper")
#: Largest key width: SQLite stores signed 64-bit integers.
_KEY_BITS = 62
#: Largest magnitude of a sample's value: squared distances must stay finite.
_MAX_ABS = 1e150
#: Rows re-keyed per step of a recalibration (bounds the memory of a pass over the store).
_BATCH = 65536
#: Smallest number of novel samples that may trigger a recalibration (a few outliers do not).
_MIN_DRIFT = 5
#: Quantile of the within-cluster squared distances that scales the novelty threshold.
_NOVEL_QUANTILE = 0.99
_GOLDEN = 0x9E3779B97F4A7C15
_MASK = (1 << 64) - 1


# --------------------------------------------------------------------------- helpers


def _hash_index(seed: int, idx: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """SplitMix64 of ``seed`` and sample indices: per-sample random numbers that do not
    depend on how the stream was chunked (a Generator's stream would)."""
    mix = np.uint64((seed * _GOLDEN) & _MASK)
    with np.errstate(over="ignore"):
        z = idx * np.uint64(_GOLDEN) + mix
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def _hash_int(seed: int, i: int) -> int:
    """:func:`_hash_index` of one index, on Python ints (the same value)."""
    z = (i * _GOLDEN + ((seed * _GOLDEN) & _MASK)) & _MASK
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK
    return z ^ (z >> 31)


def _pca(x: FloatArray, n_components: int | None, *, min_k: int = 2,
         max_k: int = 6, variance: float = 0.9) -> tuple[FloatArray, FloatArray]:
    """Mean and principal directions of ``x``, shape (n, d), by SVD.

    Returns the mean, shape (d,), and the components, shape (k, d), orthonormal rows. Each
    component's sign makes its largest-magnitude loading positive, so the result does not
    depend on the SVD routine. ``n_components=None``: the fewest explaining ``variance`` of
    the variance, clipped to ``min_k..max_k``.
    """
    # fewer samples (or features) than components: zero directions pad the rank, whose
    # coordinate is 0 for every sample, so the key stays well defined
    mean, comp, _ = pca(x, variance=variance, min_k=min_k, max_k=max_k,
                        n_components=n_components)
    return mean, comp


def _bounds(z: FloatArray, margin: float) -> tuple[FloatArray, FloatArray]:
    lo, hi = z.min(axis=0), z.max(axis=0)
    width = hi - lo
    # a constant component gets a unit-free nonzero width, so quantize accepts it
    width = np.where(width > 0, width, np.maximum(np.abs(hi), 1.0))
    return lo - margin * width, hi + margin * width


def _gap_cuts(sorted_keys: Keys, k: int) -> Keys:
    """Start keys of the runs cut at the ``k - 1`` largest gaps between sorted keys.

    Returns the sorted start keys, shape (n_runs,), the first being 0, ``n_runs <= k``.
    Ties among equal gaps go to the earliest, by a stable sort.
    """
    if k <= 1 or sorted_keys.size < 2:
        return np.zeros(1, dtype=np.uint64)
    gaps = np.diff(sorted_keys)
    pos = np.argsort(-gaps.astype(np.float64), kind="stable")[: k - 1]
    pos = np.sort(pos[gaps[pos] > 0])
    return np.concatenate(([np.uint64(0)], sorted_keys[pos + 1])).astype(np.uint64)


def _match_ids(old: IntArray, new: IntArray, next_id: int) -> tuple[IntArray, int]:
    """Rename new cluster numbers ``0..c-1`` to ids that keep the old ones stable: the
    Hungarian matching of :func:`~nonprehensile.motion.summary.match_ids`, one sample each."""
    return match_ids(old, new, np.ones(new.size), next_id)


def _kmeans(points: FloatArray, weights: FloatArray, k: int, seed: int) -> FloatArray:
    """Centres of a weighted k-means (scikit-learn's, k-means++ with 10 starts)."""
    try:
        from sklearn.cluster import KMeans
    except ImportError:  # pragma: no cover - depends on the environment
        raise InputError(
            "method='runs' needs scikit-learn for its k-means step: "
            "pip install 'nonprehensile[motion]'"
        ) from None
    k = min(k, points.shape[0])
    km = KMeans(n_clusters=k, n_init=10, random_state=seed)
    km.fit(points, sample_weight=weights)
    return np.asarray(km.cluster_centers_, dtype=np.float64)


def _ward(points: FloatArray, k: int) -> IntArray:
    """Ward's agglomeration of points into ``k`` clusters (scikit-learn's)."""
    try:
        from sklearn.cluster import AgglomerativeClustering
    except ImportError:  # pragma: no cover - depends on the environment
        raise InputError(
            "method='runs' needs scikit-learn: pip install 'nonprehensile[motion]'"
        ) from None
    k = min(k, points.shape[0])
    if k < 2:
        return np.zeros(points.shape[0], dtype=np.int64)
    return np.asarray(AgglomerativeClustering(n_clusters=k, linkage="ward").fit_predict(points),
                      dtype=np.int64)


def _nearest(z: FloatArray, centers: FloatArray) -> tuple[IntArray, FloatArray]:
    d2 = ((z[:, None, :] - centers[None, :, :]) ** 2).sum(axis=2)
    j = np.argmin(d2, axis=1)
    return j.astype(np.int64), d2[np.arange(z.shape[0]), j]


def _silhouette(z: FloatArray, labels: IntArray, seed: int) -> float:
    """Silhouette score (scikit-learn), ``-1`` when it is undefined (one cluster)."""
    n_lab = np.unique(labels).size
    if n_lab < 2 or n_lab >= z.shape[0]:
        return -1.0
    try:
        from sklearn.metrics import silhouette_score
    except ImportError:  # pragma: no cover - depends on the environment
        raise InputError(
            "n_clusters=None (automatic) needs scikit-learn: pip install 'nonprehensile[motion]'"
        ) from None
    return float(silhouette_score(z, labels, sample_size=min(1000, z.shape[0]),
                                  random_state=seed))


def _check_int(value: object, name: str, low: int, allow_none: bool = False) -> int | None:
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        none = " or None" if allow_none else ""
        raise InputError(f"{name} must be an integer >= {low}{none}, got {value!r}")
    if int(value) < low:
        raise InputError(f"{name} must be >= {low}, got {value}")
    return int(value)


def _check_float(value: object, name: str, low: float, strict: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < low or (strict and v == low):
        rel = ">" if strict else ">="
        raise InputError(f"{name} must be a finite number {rel} {low}, got {value!r}")
    return v


# --------------------------------------------------------------------------- the clusterer


class HilbertClusterer:
    """Incremental clustering of flattened trajectories on a Hilbert-curve key.

    Parameters
    ----------
    n_clusters : int or None
        Number of clusters; ``None`` chooses it: micro, by the lowest BIC at each search of
        the macro step (1, 2, ... clusters until two numbers in a row do not lower it, at most
        ``max_auto_clusters``); runs and paper, by the silhouette score (2..
        ``max_auto_clusters``) at every recalibration.
    method : {"micro", "runs", "paper"}
        ``"micro"`` (ours, the default), ``"runs"`` (our earlier method) or ``"paper"``
        (the paper's recipe); see the module notes.
    n_components : int or None
        Principal components ``k``. Paper: 2. Runs: ``None`` picks the fewest explaining
        90 % of the variance, 2..6.
    order : int or None
        Hilbert order (bits per component). Paper: 5. Runs: ``None`` gives ``62 // k``
        (at most 16), so a key fits a signed 64-bit integer.
    init_size : int or None
        Samples in the first batch, on which the model is first fitted. ``None``: the whole
        first call to :meth:`partial_fit` (at least enough samples for the clusters).
    recalibration_size : int or None
        Samples on which the principal components are refitted. Runs: the size of the
        reservoir sample (default 1000). Paper: a random sample of this size (default
        ``init_size``).
    recalibration_period : int or None
        Paper only: samples between recalibrations (default: the first batch's size).
    growth : float
        Runs only: a recalibration is due when the count reaches ``growth`` times the count
        at the last one (> 1).
    drift_fraction : float
        Runs only: novel samples, as a fraction of the count at the last recalibration, that
        bring the next one forward.
    novelty : float or None
        Runs: a sample farther than ``novelty`` times the 99th percentile of the
        within-cluster distances (at the last recalibration) from every run is novel.
        Micro: farther than ``novelty`` times the 90th percentile of the distances between
        neighbouring micro-clusters (at the last macro step). ``None``: 1 (runs), 2 (micro).
    margin : float
        Runs only: fraction of the range added on each side of the scale bounds.
    max_runs : int
        Runs only: most runs the key order is cut into.
    window : int
        Runs only: runs scanned on each side of a new key, on each curve.
    n_curves : int
        Runs only: Hilbert curves (the stored key's, and shifted copies) scanned for
        neighbours.
    max_new_runs : int
        Runs only: most provisional runs opened by novel samples between recalibrations.
    max_auto_clusters : int
        Largest number of clusters considered when ``n_clusters=None``.
    merge : {"ward", "kmeans", "auto"}
        Runs only: how runs are merged into clusters (see the module notes).
    variance : float
        Micro: fraction of the variance the principal components keep (0.95).
    max_components : int
        Micro: most principal components (24).
    capacity : int
        Micro: most micro-clusters in the summary (256); a full summary is compacted to half.
    macro_growth : float
        Micro: a macro step is due when the count reaches ``macro_growth`` times the count
        at the last one (> 1).
    search_growth : float
        Micro: a macro step searches the number of clusters, the covariance type and the
        partition afresh when the count has reached ``search_growth`` times the count at the
        last search (>= 1), after every recalibration and when novel micro-clusters brought
        it forward; the steps between refit the chosen mixture from the current partition.
        ``1.0`` searches at every step.
    residual_drift : float
        Micro: the projection is recalibrated when the mean reconstruction residual of the
        samples since the last calibration exceeds ``residual_drift`` times the reservoir's.
    store : SampleStore or None
        Where samples, keys and cluster ids are kept (default: a new :class:`MemoryStore`).
    random_state : int, numpy Generator or None
        Seed of every random choice.

    Notes
    -----
    If :meth:`partial_fit` raises (for instance :class:`~nonprehensile.errors.StoreError` on a
    lock timeout), the store rolls the batch back but this object may already count it:
    rebuild it with :meth:`load_state` from the last saved state before registering again.

    Attributes
    ----------
    labels_ : array of int, shape (n_samples_seen_,)
        The cluster id of every sample seen, in the order seen.
    n_samples_seen_ : int
    n_features_in_ : int
    mean_ : array, shape (n_features,)
        Mean of the samples the components were fitted on.
    components_ : array, shape (k, n_features)
        Principal directions (orthonormal rows).
    lower_, upper_ : array, shape (k,)
        Scale bounds of the components: ``2**order_`` cells per dimension between them.
    order_ : int
    cluster_ids_ : array of int, shape (n_clusters_,)
    cluster_centers_ : array, shape (n_clusters_, k)
        Centres in component space (mean of each cluster's samples at the last
        recalibration).
    n_recalibrations_ : int
    n_outside_ : int
        Samples registered outside the scale bounds (each was flagged novel).
    n_novel_ : int
        Samples registered as novel since the last recalibration.
    """

    def __init__(
        self,
        n_clusters: int | None = None,
        *,
        method: Method = "micro",
        n_components: int | None = None,
        order: int | None = None,
        init_size: int | None = None,
        recalibration_size: int | None = None,
        recalibration_period: int | None = None,
        growth: float = 2.0,
        drift_fraction: float = 0.05,
        novelty: float | None = None,
        margin: float = 0.1,
        max_runs: int = 256,
        window: int = 4,
        n_curves: int = 3,
        max_new_runs: int = 64,
        max_auto_clusters: int = 10,
        merge: Literal["kmeans", "ward", "auto"] = "ward",
        variance: float = 0.95,
        max_components: int = 24,
        capacity: int = 256,
        macro_growth: float = 1.1,
        search_growth: float = 2.0,
        residual_drift: float = 1.5,
        store: SampleStore | None = None,
        random_state: np.random.Generator | int | None = None,
    ) -> None:
        if method not in _METHODS:
            raise InputError(f"method must be one of {_METHODS}, got {method!r}")
        self.method: Method = method
        self.n_clusters = _check_int(n_clusters, "n_clusters", 1, allow_none=True)
        self.n_components = _check_int(n_components, "n_components", 1, allow_none=True)
        self.order = _check_int(order, "order", 1, allow_none=True)
        # the most components the key may have to hold: checked now, not at the first
        # recalibration, where a failure would leave samples half registered
        k_max = self.n_components or (2 if method == "paper" else 6)
        if method != "micro" and self.order is not None and k_max * self.order > _KEY_BITS:
            given = (f"{self.n_components}" if self.n_components is not None
                     else f"up to {k_max} (n_components=None)")
            raise InputError(
                f"n_components * order must be <= {_KEY_BITS} (a key is a signed 64-bit "
                f"integer), got {given} * {self.order}; lower the order or fix n_components"
            )
        self.init_size = _check_int(init_size, "init_size", 2, allow_none=True)
        self.recalibration_size = _check_int(recalibration_size, "recalibration_size", 2,
                                             allow_none=True)
        self.recalibration_period = _check_int(recalibration_period, "recalibration_period",
                                               1, allow_none=True)
        self.growth = _check_float(growth, "growth", 1.0, strict=True)
        self.drift_fraction = _check_float(drift_fraction, "drift_fraction", 0.0, strict=True)
        if novelty is None:
            novelty = 2.0 if method == "micro" else 1.0
        self.novelty = _check_float(novelty, "novelty", 0.0, strict=True)
        self.margin = _check_float(margin, "margin", 0.0)
        self.max_runs = int(_check_int(max_runs, "max_runs", 2) or 2)
        self.window = int(_check_int(window, "window", 1) or 1)
        self.n_curves = int(_check_int(n_curves, "n_curves", 1) or 1)
        self.max_new_runs = int(_check_int(max_new_runs, "max_new_runs", 0) or 0)
        self.max_auto_clusters = int(_check_int(max_auto_clusters, "max_auto_clusters", 2) or 2)
        if merge not in ("kmeans", "ward", "auto"):
            raise InputError(f"merge must be 'kmeans', 'ward' or 'auto', got {merge!r}")
        self.merge = merge
        self.variance = _check_float(variance, "variance", 0.0, strict=True)
        if self.variance > 1.0:
            raise InputError(f"variance must be a fraction in (0, 1], got {variance!r}")
        self.max_components = int(_check_int(max_components, "max_components", 1) or 1)
        self.capacity = int(_check_int(capacity, "capacity", 2) or 2)
        self.macro_growth = _check_float(macro_growth, "macro_growth", 1.0, strict=True)
        self.search_growth = _check_float(search_growth, "search_growth", 1.0)
        self.residual_drift = _check_float(residual_drift, "residual_drift", 1.0, strict=True)
        if store is not None and not isinstance(store, SampleStore):
            raise InputError(
                f"store must implement SampleStore (MemoryStore, SQLiteStore), got "
                f"{type(store).__name__}"
            )
        if store is not None and store.n_samples:
            raise InputError(
                f"store already holds {store.n_samples} samples; a new clusterer starts from an "
                "empty store: load the saved model with HilbertClusterer.load_state(data, "
                "store), or clear the store first"
            )
        self.store: SampleStore = store if store is not None else MemoryStore()
        self.random_state = random_state
        self._reset()

    # ------------------------------------------------------------------ state

    def _reset(self) -> None:
        rs = self.random_state
        if isinstance(rs, np.random.Generator):
            self._seed = int(rs.integers(0, 2**63))
        elif rs is None:
            self._seed = int(np.random.default_rng().integers(0, 2**63))
        else:
            self._seed = int(_check_int(rs, "random_state", 0) or 0)
        self._initialised = False
        self._target_init: int | None = None
        self.n_samples_seen_ = 0
        self.n_features_in_ = 0
        self.n_recalibrations_ = 0
        self.n_outside_ = 0
        self.n_novel_ = 0
        self.order_ = 0
        self.mean_ = np.zeros(0)
        self.components_ = np.zeros((0, 0))
        self.lower_ = np.zeros(0)
        self.upper_ = np.zeros(0)
        self.cluster_ids_ = np.zeros(0, dtype=np.int64)
        self.cluster_centers_ = np.zeros((0, 0))
        self._next_id = 0
        self._n_last = 0
        self._next_recal = 0
        # paper: start keys of the key runs and their cluster ids
        self._cuts = np.zeros(0, dtype=np.uint64)
        self._cut_ids = np.zeros(0, dtype=np.int64)
        # runs: centroids, cluster ids, shifted-curve indexes, provisional runs
        self._run_centroids = np.zeros((0, 0))
        self._run_full = np.zeros((0, 0))
        self._run_ids = np.zeros(0, dtype=np.int64)
        self._shifts = np.zeros((0, 0))
        self._curve_keys = np.zeros((0, 0), dtype=np.uint64)
        self._curve_runs = np.zeros((0, 0), dtype=np.int64)
        self._new_centroids: list[FloatArray] = []
        self._new_ids: list[int] = []
        self._threshold2 = math.inf
        self._reservoir = np.zeros((0, 0))
        self._micro = MicroSummary(
            n_clusters=self.n_clusters, n_components=self.n_components,
            variance=self.variance, max_components=self.max_components,
            capacity=self.capacity, window=self.window, n_curves=self.n_curves,
            growth=self.growth, macro_growth=self.macro_growth,
            search_growth=self.search_growth,
            drift_fraction=self.drift_fraction, novelty=self.novelty,
            residual_drift=self.residual_drift, margin=self.margin,
            max_auto_clusters=self.max_auto_clusters, seed=self._seed)
        self.store.clear()

    @property
    def labels_(self) -> IntArray:
        """Current cluster id of every sample seen, shape (n_samples_seen_,), in the order seen.

        ``method="micro"``: the id of the cluster the sample's micro-cluster belongs to now
        (after later compactions and macro steps; no stored row is rewritten for it).
        ``"runs"`` and ``"paper"``: the stored ids, rewritten at every recalibration.
        """
        if self.method == "micro":
            return self._micro.current_labels(self.store.micro_ids())
        return self.store.labels()

    @property
    def micro_labels_(self) -> IntArray:
        """Current cluster id of every micro-cluster id given so far, shape (n_micro_ids,).

        ``method="micro"`` only: a sample registered to micro-cluster ``u`` is in cluster
        ``micro_labels_[u]`` now (what :attr:`labels_` computes for every stored sample), so a
        store's samples are mapped to the current clusters from their micro-cluster ids alone,
        without the model.

        Raises
        ------
        InputError
            For the other methods (their stored ids are rewritten at each recalibration).
        """
        if self.method != "micro":
            raise InputError(f"micro_labels_ is of method 'micro' only, not {self.method!r}; "
                             "the stored cluster ids are current")
        return self._micro.current_labels(np.arange(self._micro.next_uid, dtype=np.int64))

    @property
    def labels_registered_(self) -> IntArray:
        """Cluster id of every sample as it was registered, shape (n_samples_seen_,).

        What :meth:`partial_fit` answered for the sample when it arrived (the first batch:
        the ids of the first macro step). ``"runs"`` and ``"paper"`` rewrite them at a
        recalibration: there they equal :attr:`labels_`.
        """
        return self.store.labels()

    @property
    def key_bits_(self) -> int:
        """Bits of a stored key."""
        if self.method == "micro":
            return self._micro.key_bits
        return int(self.components_.shape[0]) * self.order_

    @property
    def n_clusters_(self) -> int:
        """Number of clusters at the last recalibration."""
        return int(self.cluster_ids_.size)

    def _res_size(self) -> int:
        if self.method != "paper":
            return self.recalibration_size or 1000
        return self.recalibration_size or self.init_size or max(self._n_last, 2)

    # ------------------------------------------------------------------ input

    def check_samples(self, X: ArrayLike, what: str = "X", fix: str | None = None
                      ) -> FloatArray:
        """Check samples as :meth:`partial_fit` checks them, without registering them.

        Parameters
        ----------
        X : array_like, shape (n_samples, n_features)
            The samples.
        what : str
            What the samples are, for the message (a file, a dataset).
        fix : str, optional
            How to fix samples whose width is not the fitted model's (default: resample the
            trajectories to the same number of points).

        Returns
        -------
        array, shape (n_samples, n_features)
            ``X`` as float64.

        Raises
        ------
        InputError
            Not a 2-D array of finite numbers, or not as wide as the fitted model's samples.
        """
        return self._check_X(X, what, fix=fix)

    def _check_X(self, X: ArrayLike, what: str = "X", *, fresh: bool = False,
                 fix: str | None = None) -> FloatArray:
        try:
            x = np.asarray(X, dtype=np.float64)
        except (ValueError, TypeError) as exc:
            raise InputError(
                f"{what} must be an array of numbers, shape (n_samples, n_features): one "
                f"flattened trajectory per row; could not read it ({exc})"
            ) from None
        if x.ndim == 1 and x.size:
            raise InputError(
                f"{what} must have shape (n_samples, n_features), got one vector of shape "
                f"{x.shape}; use X.reshape(1, -1) for a single sample"
            )
        if x.ndim != 2 or x.shape[1] == 0:
            raise InputError(
                f"{what} must have shape (n_samples, n_features) with n_features >= 1, got "
                f"shape {x.shape}; flatten each trajectory (nonprehensile.motion.flatten) "
                "into one row"
            )
        # squared distances of values beyond ~1e150 overflow to inf: refuse them as non-finite
        # (one pass first: the largest magnitude is NaN when any value is NaN)
        if x.size and not float(np.abs(x).max()) <= _MAX_ABS:
            bad = ~np.isfinite(x) | (np.abs(x) > _MAX_ABS)
            r, c = (int(v) for v in np.argwhere(bad)[0])
            raise InputError(
                f"{what}: sample {r}, feature {c} is {x[r, c]}; every value must be finite and "
                f"below {_MAX_ABS:g} in magnitude: fill gaps in the trajectories (fill_gaps), "
                "rescale, or drop the sample"
            )
        d = 0 if fresh else self.n_features_in_ or (self.store.n_features or 0)
        if d and x.shape[1] != d:
            kind = "shorter" if x.shape[1] < d else "longer"
            raise InputError(
                f"{what} has {x.shape[1]} features per sample, {kind} than the {d} the model "
                "was fitted on; " + (fix or "resample every trajectory to the same number of "
                                     "points (nonprehensile.motion.preprocess) before "
                                     "clustering")
            )
        return x

    def min_fit_samples(self) -> int:
        """The fewest samples the first batch takes: ``n_clusters + 1``, at least 3.

        Returns
        -------
        int
        """
        return self._min_init()

    def _min_init(self) -> int:
        k = self.n_clusters or 2
        return max(3, k + 1, (self.n_components or 2) + 1)

    # ------------------------------------------------------------------ public API

    def fit(self, X: ArrayLike, y: object = None) -> HilbertClusterer:
        """Reset, then :meth:`partial_fit` on ``X``, shape (n_samples, n_features).

        Raises
        ------
        InputError
            If ``X`` is not 2-D, holds NaN or infinity, or has fewer samples than the first
            batch needs (``n_clusters + 1``, at least 3).
        """
        x = self._check_X(X, fresh=True)
        if x.shape[0] < self._min_init():
            raise InputError(
                f"fit needs at least {self._min_init()} samples (n_clusters + 1, at least 3), "
                f"got {x.shape[0]}"
            )
        self._reset()
        return self.partial_fit(x)

    def fit_predict(self, X: ArrayLike, y: object = None) -> IntArray:
        """:meth:`fit`, then :attr:`labels_`: shape (n_samples,)."""
        return self.fit(X).labels_

    def partial_fit(self, X: ArrayLike, y: object = None) -> HilbertClusterer:
        """Register samples, shape (n_samples, n_features), one flattened trajectory a row.

        Until the first batch is complete, samples are stored without a cluster (id ``-1``);
        the batch completes the model. Afterwards each sample is keyed and labelled without
        reclustering the others, and recalibrations run when due.
        """
        x = self._check_X(X)
        if x.shape[0] == 0:
            return self
        self.n_features_in_ = x.shape[1]
        start = 0
        while start < x.shape[0]:
            if not self._initialised:
                start += self._collect(x[start:])
            elif self.method == "micro":
                start += self._register_micro(x[start:])
            else:
                start += self._register(x[start:])
        return self

    def transform(self, X: ArrayLike) -> Keys:
        """Hilbert keys of samples under the current model, shape (n_samples,), ``uint64``.

        Samples outside the scale bounds get the key of the nearest end cell; use
        :meth:`outside` to find them.
        """
        x = self._require(X)
        if self.method == "micro":
            return self._micro.keys(x)
        keys, _ = self._keys(self._project(x))
        return keys

    def outside(self, X: ArrayLike) -> NDArray[np.bool_]:
        """Whether each sample falls outside the scale bounds, shape (n_samples,)."""
        x = self._require(X)
        if self.method == "micro":
            m = self._micro
            z = project(x, m.mean, m.comp)
            u = np.add.reduce(z[:, None, :] * m.rot[None, : m.ki, :], axis=2)
            return np.asarray(np.any((u < m.lo[: m.ki]) | (u > m.hi[: m.ki]), axis=1))
        return quantize(self._project(x), self.lower_, self.upper_, self.order_)[1]

    def predict(self, X: ArrayLike) -> IntArray:
        """Cluster ids of samples, shape (n_samples,), without registering them.

        Paper: the id of the key run the key falls in. Runs: the id of the nearest run among
        the neighbours found on the curves (and the provisional runs).
        """
        x = self._require(X)
        if self.method == "micro":
            return self._micro.predict(x)
        z = self._project(x)
        if self.method == "paper":
            keys, _ = self._keys(z)
            return self._cut_ids[np.searchsorted(self._cuts, keys, side="right") - 1]
        keys, _ = self._keys(z)
        j, d2 = self._nearest_runs(z, keys, x)
        labels = self._run_ids[j]
        if self._new_centroids:
            nj, nd2 = _nearest(x, np.array(self._new_centroids))
            closer = nd2 < d2
            labels = np.where(closer, np.array(self._new_ids)[nj], labels)
        return labels

    def recalibrate(self) -> HilbertClusterer:
        """Recalibrate now: refit the components, re-key every sample, recluster.

        Also completes a first batch smaller than ``init_size``.
        """
        if self.store.n_samples < self._min_init():
            raise InputError(
                f"recalibration needs at least {self._min_init()} samples, "
                f"{self.store.n_samples} are stored; add more first"
            )
        with self.store.transaction():
            self._recalibrate()
        return self

    def _require(self, X: ArrayLike) -> FloatArray:
        if not self._initialised:
            raise InputError(
                "the clusterer is not fitted yet: call fit or partial_fit with at least "
                f"{self._min_init()} samples first"
            )
        return self._check_X(X)

    # ------------------------------------------------------------------ first batch

    def _collect(self, x: FloatArray) -> int:
        """Store samples of the first batch; fit the model when it is complete."""
        n = self.store.n_samples
        if self.init_size is not None:
            target = self.init_size
        else:
            if self._target_init is None:
                self._target_init = max(self._min_init(), x.shape[0])
            target = self._target_init
        target = max(target, self._min_init())
        take = min(target - n, x.shape[0])
        with self.store.transaction():
            self._store(x[:take], [0] * take, np.full(take, -1, dtype=np.int64))
            if self.store.n_samples >= target:
                self._recalibrate()
        return int(take)

    def _store(self, x: FloatArray, keys: list[int], labels: IntArray) -> None:
        n0 = self.n_samples_seen_
        self.store.add(x, keys, labels)
        self._update_reservoir(x, n0)
        self.n_samples_seen_ = n0 + x.shape[0]

    def _update_reservoir(self, x: FloatArray, n0: int) -> None:
        """Reservoir sampling (Vitter's algorithm R) with per-index random numbers."""
        if self.method == "paper":
            return
        size = self._res_size()
        if self._reservoir.shape[1] != x.shape[1]:
            self._reservoir = np.zeros((0, x.shape[1]))
        fill = max(0, min(size - self._reservoir.shape[0], x.shape[0]))
        if fill:
            self._reservoir = np.vstack([self._reservoir, x[:fill]])
        if fill == x.shape[0]:
            return
        if x.shape[0] - fill == 1:
            # one sample: the same hash on a Python int, without array temporaries
            i = n0 + fill
            one = _hash_int(self._seed, i) % (i + 1)
            if one < size:
                self._reservoir[one] = x[fill]
            return
        idx = np.arange(n0 + fill, n0 + x.shape[0], dtype=np.uint64)
        slot = _hash_index(self._seed, idx) % (idx + np.uint64(1))
        for i in np.flatnonzero(slot < np.uint64(size)):
            # in order: a later sample replacing the same slot wins, as in the serial loop
            self._reservoir[int(slot[i])] = x[fill + i]

    # ------------------------------------------------------------------ projection, keys

    def _project(self, x: FloatArray) -> FloatArray:
        """Principal components of samples, shape (m, k), deterministically (:func:`project`:
        the same bits whatever the BLAS threads and the chunking)."""
        return project(x, self.mean_, self.components_)

    def _keys(self, z: FloatArray) -> tuple[Keys, NDArray[np.bool_]]:
        grid, out = quantize(z, self.lower_, self.upper_, self.order_)
        return np.asarray(encode(grid, self.order_, validate=False), dtype=np.uint64), out

    def _curve_key(self, z: FloatArray, t: int) -> Keys:
        if t == 0:
            return self._keys(z)[0]
        width = self.upper_ - self.lower_
        # the shifted curves only look up a few hundred run centroids: a coarse grid of at
        # most 24 bits is enough, and costs a fraction of the stored key's encoding
        order = max(2, min(self.order_, 24 // max(1, width.size)))
        grid, _ = quantize(z + self._shifts[t], self.lower_, self.upper_ + width / 2, order)
        return np.asarray(encode(grid, order, validate=False), dtype=np.uint64)

    # ------------------------------------------------------------------ registration

    def _register(self, x: FloatArray) -> int:
        """Register a prefix of ``x`` with the model frozen; recalibrate when due.

        Returns how many samples were registered (the prefix ends where a recalibration is
        due, so that later samples meet the recalibrated model).
        """
        room = max(1, self._next_recal - self.n_samples_seen_)
        x = x[:room]
        z = self._project(x)
        keys, out = self._keys(z)
        if self.method == "paper":
            labels = self._cut_ids[np.searchsorted(self._cuts, keys, side="right") - 1]
            novel = np.zeros(x.shape[0], dtype=bool)
        else:
            j, d2 = self._nearest_runs(z, keys, x)
            labels = self._run_ids[j]
            novel = out | (d2 > self._threshold2)
            need = max(_MIN_DRIFT, math.ceil(self.drift_fraction * self._n_last)) - self.n_novel_
            hits = np.flatnonzero(np.cumsum(novel) >= need)
            if hits.size:
                # the sample that completes the drift is the last before the recalibration
                cut = int(hits[0]) + 1
                x, z, keys, out = x[:cut], z[:cut], keys[:cut], out[:cut]
                labels, novel = labels[:cut], novel[:cut]
            for i in np.flatnonzero(novel):
                labels[i] = self._place_novel(x[i], float(d2[i]), int(labels[i]))
        m = x.shape[0]
        with self.store.transaction():
            self._store(x, key_to_int(keys), labels.astype(np.int64))
            self.n_outside_ += int(out.sum())
            self.n_novel_ += int(novel.sum())
            due = self.n_samples_seen_ >= self._next_recal
            if self.method == "runs":
                need = max(_MIN_DRIFT, math.ceil(self.drift_fraction * self._n_last))
                due = due or self.n_novel_ >= need
            if due:
                self._recalibrate()
        return int(m)

    def _nearest_runs(self, z: FloatArray, keys: Keys, x: FloatArray
                      ) -> tuple[IntArray, FloatArray]:
        """Nearest run among those near each sample's key on the curves (range scans).

        The candidates come from the keys (component space); the distance that decides is
        the real one, in the full feature space. Returns the run, shape (m,), and its squared
        distance, shape (m,).
        """
        n_runs = self._run_centroids.shape[0]
        w = min(self.window, n_runs)
        cand = []
        for t in range(self._curve_keys.shape[0]):
            ck = keys if t == 0 else self._curve_key(z, t)
            pos = np.searchsorted(self._curve_keys[t], ck)
            lo = np.clip(pos - w, 0, max(n_runs - 2 * w, 0))
            idx = np.minimum(lo[:, None] + np.arange(2 * w)[None, :], n_runs - 1)
            cand.append(self._curve_runs[t][idx])
        runs = np.concatenate(cand, axis=1)
        best_run = np.empty(x.shape[0], dtype=np.int64)
        best_d2 = np.empty(x.shape[0])
        # blocks bound the (m, candidates, n_features) temporary
        step = max(1, 2**22 // max(1, runs.shape[1] * x.shape[1]))
        for s in range(0, x.shape[0], step):
            r = runs[s : s + step]
            d2 = ((self._run_full[r] - x[s : s + step, None, :]) ** 2).sum(axis=2)
            b = np.argmin(d2, axis=1)
            rows = np.arange(r.shape[0])
            best_run[s : s + step] = r[rows, b]
            best_d2[s : s + step] = d2[rows, b]
        return best_run, best_d2

    def _place_novel(self, x: FloatArray, d2_old: float, old_id: int) -> int:
        """Leader clustering of novel samples into provisional runs; returns the cluster id.

        ``d2_old`` is the squared distance to the nearest run, of cluster ``old_id``. A sample
        near a provisional run joins it; one only mildly novel (within twice the novelty
        distance of its nearest run) keeps that run's cluster; a far one opens a provisional
        run, in the cluster of a provisional run within twice the distance (a new skill
        spreads wider than one run) or in a new cluster.
        """
        thr2 = self._threshold2
        near_new, nd2 = -1, math.inf
        if self._new_centroids:
            d2 = ((np.array(self._new_centroids) - x) ** 2).sum(axis=1)
            near_new = int(np.argmin(d2))
            nd2 = float(d2[near_new])
        if nd2 <= thr2 and nd2 <= d2_old:
            return self._new_ids[near_new]
        if d2_old <= 4.0 * thr2 and d2_old <= nd2:
            return old_id
        if len(self._new_centroids) >= self.max_new_runs:
            return self._new_ids[near_new] if nd2 < d2_old else old_id
        cid = self._new_ids[near_new] if nd2 <= 4.0 * thr2 else self._fresh_id()
        self._new_centroids.append(x.copy())
        self._new_ids.append(cid)
        return cid

    def _fresh_id(self) -> int:
        self._next_id += 1
        return self._next_id - 1

    # ------------------------------------------------------------------ recalibration

    # ------------------------------------------------------------------ micro

    def _register_micro(self, x: FloatArray) -> int:
        """Register a prefix of ``x`` in the summary; recalibrate when due (no re-keying)."""
        m = self._micro
        n0 = self.n_samples_seen_
        steps = m.n_macro_steps
        done, keys, labels, uids, due = m.register(x)
        with self.store.transaction():
            self.store.add(x[:done], keys.tolist(), labels, micro=uids)
            self._update_reservoir(x[:done], n0)
            self.n_samples_seen_ = n0 + done
            if due:
                with one_thread():
                    m.calibrate(self._reservoir)
                    m.macro()
                self.n_recalibrations_ += 1
        self.n_novel_ = m.n_novel
        if due or m.n_macro_steps != steps:
            self._sync_micro()
        return done

    def _recalibrate_micro(self) -> None:
        """Refit the projection on the reservoir and run the macro step; the first time,
        register the first batch into the summary (its samples get their first keys)."""
        m = self._micro
        with one_thread():
            m.calibrate(self._reservoir)
            if not self._initialised:
                n = self.store.n_samples
                _, keys, _, uids, _ = m.register(self.store.vectors(0, n), triggers=False)
                m.n_cal = m.n_macro = n
                m.res_sum, m.res_cnt = 0.0, 0
                m.macro()
                self.store.update(0, keys.tolist(), m.current_labels(uids), micro=uids)
                self._initialised = True
            else:
                m.macro()
        self.n_recalibrations_ += 1
        self._sync_micro()

    def _sync_micro(self) -> None:
        """The public attributes from the summary (after a calibration or a macro step)."""
        m = self._micro
        self.mean_, self.components_ = m.mean, m.comp
        self.order_ = m.oi
        self.lower_, self.upper_ = m.lo[: m.ki].copy(), m.hi[: m.ki].copy()
        self.cluster_ids_, _, self.cluster_centers_ = m.live_clusters()
        self.n_novel_ = m.n_novel

    def _recalibrate(self) -> None:
        if self.method == "micro":
            self._recalibrate_micro()
            return
        n = self.store.n_samples
        old = self.store.labels()
        if self.method == "runs":
            x_fit = self._reservoir
            mean, comp = _pca(x_fit, self.n_components)
        else:
            mean, comp = _pca(self._paper_sample(n), self.n_components or 2)
        self.mean_, self.components_ = mean, comp
        k = comp.shape[0]
        if self.order is not None:
            self.order_ = self.order
        elif self.method == "paper":
            self.order_ = 5
        else:
            self.order_ = max(1, min(16, _KEY_BITS // k))
        if k * self.order_ > _KEY_BITS:
            raise InputError(
                f"n_components * order must be <= {_KEY_BITS}, got {k} * {self.order_}"
            )
        z = np.empty((n, k))
        for s in range(0, n, _BATCH):
            z[s : s + _BATCH] = self._project(
                self.store.vectors(s, min(n, s + _BATCH)))
        margin = 0.0 if self.method == "paper" else self.margin
        self.lower_, self.upper_ = _bounds(z, margin)
        keys, _ = self._keys(z)
        if self.method == "paper":
            labels = self._paper_cluster(z, keys)
        else:
            labels = self._runs_cluster(z, keys)
        ids, self._next_id = _match_ids(old, labels, self._next_id)
        final = ids[labels]
        if self.method == "paper":
            self._cut_ids = ids[self._cut_ids]
        else:
            self._run_ids = ids[self._run_ids]
        self.cluster_ids_ = ids
        self.cluster_centers_ = np.array(
            [z[labels == c].mean(axis=0) for c in range(ids.size)]).reshape(ids.size, k)
        key_list = key_to_int(keys)
        for s in range(0, n, _BATCH):
            self.store.update(s, key_list[s : s + _BATCH], final[s : s + _BATCH])
        self._initialised = True
        self.n_recalibrations_ += 1
        self.n_novel_ = 0
        self._new_centroids, self._new_ids = [], []
        self._n_last = n
        if self.method == "paper":
            period = self.recalibration_period or self.init_size or n
            self._next_recal = n + period
        else:
            self._next_recal = max(n + 1, math.ceil(n * self.growth))

    def _paper_sample(self, n: int) -> FloatArray:
        """The paper's fitting set: the first batch, then a random sample of fixed size."""
        if not self._initialised:
            return self.store.vectors(0, n)
        size = min(self._res_size(), n)
        rng = np.random.default_rng([self._seed, n])
        pick = np.sort(rng.choice(n, size=size, replace=False))
        rows = []
        for s in range(0, n, _BATCH):
            sel = pick[(pick >= s) & (pick < s + _BATCH)]
            if sel.size:
                rows.append(self.store.vectors(s, min(n, s + _BATCH))[sel - s])
        return np.vstack(rows)

    def _choose(self, z: FloatArray, options: list[tuple[int, IntArray]]) -> IntArray:
        """The labelling with the best silhouette among ``(k, labels)`` options."""
        best, best_s = options[0][1], -math.inf
        for _, lab in options:
            s = _silhouette(z, lab, self._seed % (2**32))
            if s > best_s:
                best, best_s = lab, s
        return best

    def _k_options(self, n: int) -> list[int]:
        if self.n_clusters is not None:
            return [min(self.n_clusters, n)]
        return list(range(2, min(self.max_auto_clusters, n - 1) + 1)) or [1]

    def _paper_cluster(self, z: FloatArray, keys: Keys) -> IntArray:
        """Clusters by 1-D sorting: runs of sorted keys cut at the largest gaps."""
        srt = np.sort(keys)
        options = []
        for k in self._k_options(keys.size):
            cuts = _gap_cuts(srt, k)
            options.append((k, np.searchsorted(cuts, keys, side="right") - 1))
        labels = self._choose(z, options).astype(np.int64)
        k_best = int(labels.max()) + 1
        self._cuts = _gap_cuts(srt, k_best)
        self._cut_ids = np.arange(self._cuts.size, dtype=np.int64)
        return labels

    def _pass(self, n: int) -> Iterator[tuple[int, FloatArray]]:
        """The stored vectors in blocks: (first id, block, shape (m, n_features))."""
        for s in range(0, n, _BATCH):
            yield s, self.store.vectors(s, min(n, s + _BATCH))

    def _runs_cluster(self, z: FloatArray, keys: Keys) -> IntArray:
        """Cut the key order into runs, merge runs into clusters, index the runs.

        Runs are summarised by their centroids in the full feature space; the merge is a
        weighted k-means or Ward's agglomeration of those centroids (the Birch recipe), the
        better by the silhouette of a sample of the data. Passes over the store are linear.
        """
        n, k = z.shape
        d = self.n_features_in_
        order = np.argsort(keys, kind="stable")
        zs = z[order]
        k_max = max(self._k_options(n))
        half = max(1, self.max_runs // 2)
        size = max(1, min(math.ceil(n / half), n // max(2 * k_max, 1)))
        starts = set(range(0, n, size))
        if n > 1:
            jump = np.sqrt(((zs[1:] - zs[:-1]) ** 2).sum(axis=1))
            big = np.argsort(-jump, kind="stable")[:half]
            big = big[jump[big] > 3.0 * float(np.median(jump))]
            starts.update((big + 1).tolist())
        start_arr = np.array(sorted(starts))
        run = np.empty(n, dtype=np.int64)
        run[order] = np.searchsorted(start_arr, np.arange(n), side="right") - 1
        n_runs = start_arr.size
        counts = np.bincount(run, minlength=n_runs).astype(np.float64)
        # evenly spaced samples score the options (silhouette), at most 1000 of them
        probe = np.unique(np.linspace(0, n - 1, min(n, 1000)).astype(np.int64))
        probe_x = np.empty((probe.size, d))
        sums = np.zeros((n_runs, d))
        for s, xb in self._pass(n):
            np.add.at(sums, run[s : s + xb.shape[0]], xb)
            sel = probe[(probe >= s) & (probe < s + xb.shape[0])]
            probe_x[np.searchsorted(probe, sel)] = xb[sel - s]
        cents = sums / counts[:, None]
        seed = self._seed % (2**32)
        options: list[tuple[int, IntArray]] = []
        for kk in self._k_options(n_runs):
            if self.merge in ("kmeans", "auto"):
                centers = _kmeans(cents, counts, kk, seed)
                lab = np.empty(n, dtype=np.int64)
                for s, xb in self._pass(n):
                    lab[s : s + xb.shape[0]] = _nearest(xb, centers)[0]
                options.append((kk, np.unique(lab, return_inverse=True)[1].astype(np.int64)))
            if self.merge in ("ward", "auto"):
                options.append((kk, _ward(cents, kk)[run]))
        best, best_s = options[0][1], -math.inf
        for _, lab in options:
            score = _silhouette(probe_x, lab[probe], seed)
            if score > best_s:
                best, best_s = lab, score
        labels = best
        n_lab = int(labels.max()) + 1
        # split runs whose samples disagree: every run is then pure
        uniq, new_run = np.unique(run * n_lab + labels, return_inverse=True)
        counts = np.bincount(new_run).astype(np.float64)
        zsum = np.zeros((uniq.size, k))
        np.add.at(zsum, new_run, z)
        full = np.zeros((uniq.size, d))
        for s, xb in self._pass(n):
            np.add.at(full, new_run[s : s + xb.shape[0]], xb)
        self._run_centroids = zsum / counts[:, None]
        self._run_full = full / counts[:, None]
        self._run_ids = (uniq % n_lab).astype(np.int64)
        self._index_runs()
        # the novelty scale: a high quantile of the squared distances of the stored samples
        # to their cluster's mean, so that about 1 % of samples like those seen is novel
        # whatever the dimension and the shape of the clusters
        c_n = np.bincount(self._run_ids, weights=counts, minlength=n_lab)
        c_sum = np.zeros((n_lab, d))
        np.add.at(c_sum, self._run_ids, full)
        means = c_sum / np.maximum(c_n, 1.0)[:, None]
        dist2 = np.empty(n)
        for s, xb in self._pass(n):
            dist2[s : s + xb.shape[0]] = ((xb - means[labels[s : s + xb.shape[0]]]) ** 2).sum(1)
        self._threshold2 = self.novelty**2 * max(float(np.quantile(dist2, _NOVEL_QUANTILE)),
                                                 1e-300)
        return labels

    def _index_runs(self) -> None:
        """Sort the run centroids' keys on each curve: the locality index of registration."""
        k = self._run_centroids.shape[1]
        rng = np.random.default_rng([self._seed, self.n_recalibrations_, 7])
        width = self.upper_ - self.lower_
        self._shifts = np.vstack(
            [np.zeros(k)] + [rng.uniform(0, 0.5, size=k) * width
                             for _ in range(self.n_curves - 1)]
        )
        keys, runs = [], []
        for t in range(self.n_curves):
            ck = self._curve_key(self._run_centroids, t)
            o = np.argsort(ck, kind="stable")
            keys.append(ck[o])
            runs.append(o)
        self._curve_keys = np.array(keys, dtype=np.uint64)
        self._curve_runs = np.array(runs, dtype=np.int64)

    # ------------------------------------------------------------------ persistence

    _ARRAYS = ("mean_", "components_", "lower_", "upper_", "cluster_ids_", "cluster_centers_",
               "_cuts", "_cut_ids", "_run_centroids", "_run_full", "_run_ids", "_shifts",
               "_curve_keys", "_curve_runs", "_reservoir")
    _SCALARS = ("_seed", "_initialised", "_target_init", "n_samples_seen_", "n_features_in_",
                "n_recalibrations_", "n_outside_", "n_novel_", "order_", "_next_id", "_n_last",
                "_next_recal", "_threshold2")

    def params(self) -> dict[str, Any]:
        """The constructor's parameters (without ``store`` and ``random_state``)."""
        return {
            "n_clusters": self.n_clusters, "method": self.method,
            "n_components": self.n_components, "order": self.order,
            "init_size": self.init_size, "recalibration_size": self.recalibration_size,
            "recalibration_period": self.recalibration_period, "growth": self.growth,
            "drift_fraction": self.drift_fraction, "novelty": self.novelty,
            "margin": self.margin, "max_runs": self.max_runs, "window": self.window,
            "n_curves": self.n_curves, "max_new_runs": self.max_new_runs,
            "max_auto_clusters": self.max_auto_clusters, "merge": self.merge,
            "variance": self.variance, "max_components": self.max_components,
            "capacity": self.capacity, "macro_growth": self.macro_growth,
            "search_growth": self.search_growth,
            "residual_drift": self.residual_drift,
        }

    def save_state(self) -> bytes:
        """The model (parameters and learned state, not the samples) as bytes (``.npz``)."""
        arrays = {name: getattr(self, name) for name in self._ARRAYS}
        scalars = {name: getattr(self, name) for name in self._SCALARS}
        scalars["_threshold2"] = None if math.isinf(self._threshold2) else self._threshold2
        micro_arrays, micro_scalars = self._micro.state()
        arrays.update({f"micro__{k}": v for k, v in micro_arrays.items()})
        micro_meta = {k: (v.item() if isinstance(v, np.generic) else v)
                      for k, v in micro_scalars.items()}
        if math.isinf(micro_meta["nov2"]):
            micro_meta["nov2"] = None
        meta = {"params": self.params(), "scalars": scalars,
                "new_centroids": [c.tolist() for c in self._new_centroids],
                "new_ids": self._new_ids, "micro": micro_meta}
        buf = io.BytesIO()
        np.savez(buf, __meta__=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8),
                 **arrays)
        return buf.getvalue()

    @classmethod
    def load_state(cls, data: bytes, store: SampleStore) -> HilbertClusterer:
        """A clusterer from :meth:`save_state`'s bytes, on the store that holds its samples."""
        try:
            npz = np.load(io.BytesIO(data), allow_pickle=False)
            meta = json.loads(bytes(npz["__meta__"]).decode())
            arrays = {name: np.asarray(npz[name]) for name in cls._ARRAYS}
            # states saved before the micro method have no summary (runs and paper need none)
            micro_arrays = ({name: np.asarray(npz[f"micro__{name}"])
                             for name in MicroSummary.ARRAYS} if "micro" in meta else {})
            micro_scalars = dict(meta.get("micro", {}))
        except (ValueError, KeyError, OSError, zipfile.BadZipFile, UnicodeDecodeError) as exc:
            raise InputError(
                f"not a saved HilbertClusterer state ({exc}); the store's model is damaged: "
                "fit the store again"
            ) from None
        # build without resetting: the store already holds the samples
        obj = cls.__new__(cls)
        try:
            probe = cls(**meta["params"], random_state=0)
        except (TypeError, InputError) as exc:
            raise InputError(
                f"the saved HilbertClusterer's parameters are not valid ({exc}); the store's "
                "model is damaged: fit the store again"
            ) from None
        obj.__dict__.update(probe.__dict__)
        obj.store = store
        obj.random_state = None
        for name, arr in arrays.items():
            setattr(obj, name, arr)
        for name, value in meta["scalars"].items():
            setattr(obj, name, value)
        if obj._threshold2 is None:
            obj._threshold2 = math.inf
        obj._micro.seed = obj._seed
        if micro_scalars:
            obj._micro.restore(micro_arrays, micro_scalars)
        obj._new_centroids = [np.array(c) for c in meta["new_centroids"]]
        obj._new_ids = [int(i) for i in meta["new_ids"]]
        if store.n_samples != obj.n_samples_seen_:
            raise InputError(
                f"the store holds {store.n_samples} samples, the saved model has seen "
                f"{obj.n_samples_seen_}; the store was changed outside the clusterer"
            )
        return obj
