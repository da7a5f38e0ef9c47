"""A bounded summary of micro-clusters, indexed by Hilbert keys (issue 14, ``method="micro"``).

The stream is summarised by at most ``capacity`` micro-clusters. Each keeps its count ``n``,
its centroid in the full feature space (the linear sum over ``n``), its within sum of squares
``W = sum |x - c|^2`` (the squared norms, kept about the centroid: no cancellation), and its
centroid and within scatter in the principal-component space (``k x k``). A new sample

1. is projected (:func:`~nonprehensile.motion.microcluster.project`, deterministic) and keyed
   on ``n_curves`` Hilbert curves of the leading components: curve 0 on the first components
   as they are (its key is the sample's stored key), the others on randomly rotated and
   shifted copies, so that cells the first curve puts far apart along the order are near on
   another;
2. finds its candidate micro-clusters by a range scan of ``2 * window`` entries around its key
   in each curve's sorted index, plus the few created since the index was last sorted;
3. joins the nearest candidate (real distance, full feature space) when within the absorb
   radius, else opens a micro-cluster of its own. The sample's label is its micro-cluster's;
   a new micro-cluster farther than the novelty radius from every candidate starts a
   provisional cluster (a new skill or mentor, seen at once).

When the summary holds more than ``capacity`` micro-clusters it is compacted by weighted Ward
merges to half, and the absorb radius grows to the typical radius of what was merged
(Birch's threshold rule). The macro step clusters the micro-clusters: a weighted Ward
agglomeration gives the starts, Gaussian mixtures with spherical, diagonal, tied and full
covariances are fitted by EM (each micro-cluster's scatter counts), the lowest BIC wins, and
its clusters are matched to the previous ids by the Hungarian method on the samples they
share. Only some macro steps search (the first, those after a recalibration, those novel
micro-clusters bring forward, and one each time the count has grown by ``search_growth``);
the others refit the chosen mixture by EM from the current partition. The projection is
recalibrated on a reservoir sample when the count has grown by
``growth`` or when the reconstruction residual of recent samples drifts above the one at the
calibration; micro-clusters are re-projected from their full-space centroids, never sample
by sample.

Every sample's record (key, label as registered, micro-cluster id) is kept by the store; the
current label of a sample is that of the micro-cluster its own was merged into.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from nonprehensile.motion.hilbert import LUT_MAX_BITS, lookup_table
from nonprehensile.motion.microcluster import (
    COVARIANCE_TYPES,
    Mixture,
    fit_mixture,
    fit_mixtures,
    one_thread,
    pca,
    project,
    ward_merges,
    ward_partition,
)

__all__ = ["MicroSummary", "match_ids"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Micro-clusters created since the last sort of the index before it is sorted again.
_PENDING = 16
#: Dimensions of the index curves (the leading components): keys of <= 16 bits, table-served.
_INDEX_DIMS = 4
#: EM steps from each start before the most likely one is run to convergence.
_SHORT_EM = 10
#: Smallest number of novel micro-clusters that brings a macro step forward.
_MIN_NOVEL = 3
#: The largest double below 1: the upper bound falls in the last cell.
_TOP = math.nextafter(1.0, 0.0)
#: Samples whose mean residual is compared with the calibration's.
_MIN_RESIDUAL = 5
#: Samples per principal component, at least: a mixture's covariances need about ten
#: samples a dimension (the usual rule of thumb), and with fewer samples than features the
#: trailing components of a 95 % cut are fitted to noise.
_PER_COMPONENT = 10
#: Numbers of clusters in a row that do not lower the best BIC before the search for the
#: number of clusters stops (when it is not given).
_PATIENCE = 2
#: Starts of each covariance type run on to convergence (the most likely after the short EM).
_CONVERGE = 2

try:  # einsum's C routine: np.einsum without its Python dispatch (same values)
    from numpy._core.multiarray import c_einsum as _einsum
except ImportError:  # pragma: no cover - other numpy layouts
    _einsum = np.einsum


def _rows(arr: FloatArray, idx: IntArray) -> FloatArray:
    """``arr[idx]`` for strictly increasing ``idx``, as a view when the rows are consecutive
    (the live slots of a summary that was never compacted): the feature space is wide, and a
    copy of a few hundred of its rows costs a page fault per 4 KiB."""
    if idx.size and int(idx[-1]) - int(idx[0]) == idx.size - 1:
        return arr[int(idx[0]) : int(idx[-1]) + 1]
    return arr[idx]


def match_ids(old: IntArray, new: IntArray, weight: FloatArray,
              next_id: int) -> tuple[IntArray, int]:
    """Ids for new clusters ``0..c-1`` that keep the old ids where they overlap most.

    ``old``: previous id of each point (``-1``: none), ``new``: its new cluster, ``weight``:
    the samples it stands for. The contingency table is matched by the Hungarian method
    (maximum shared samples); an unmatched new cluster gets ``next_id, next_id + 1, ...``.
    """
    c = int(new.max()) + 1 if new.size else 0
    ids = np.full(c, -1, dtype=np.int64)
    known = old >= 0
    if known.any():
        old_ids, old_idx = np.unique(old[known], return_inverse=True)
        table = np.zeros((c, old_ids.size))
        np.add.at(table, (new[known], old_idx), weight[known])
        rows, cols = linear_sum_assignment(-table)
        for r, col in zip(rows, cols, strict=True):
            if table[r, col] > 0:
                ids[r] = old_ids[col]
    for r in range(c):
        if ids[r] < 0:
            ids[r] = next_id
            next_id += 1
    return ids, next_id


def _kmeans_starts(z: FloatArray, w: FloatArray, c: int, n: int, seed: int) -> list[IntArray]:
    """Partitions by weighted k-means (k-means++ seeding, 20 Lloyd steps), one per seed.

    Written out in numpy rather than through scikit-learn's KMeans, whose per-call overhead
    (tens of milliseconds) would dominate a macro step on a few hundred points.
    """
    m = z.shape[0]
    if n <= 0 or c < 2 or m <= c:
        return []
    rng = np.random.default_rng([seed, 11])
    sq = np.einsum("ij,ij->i", z, z)
    out = []
    for _ in range(n):
        # k-means++: each next centre drawn in proportion to weight x squared distance
        centres = [int(rng.choice(m, p=w / w.sum()))]
        d2 = np.maximum(sq - 2.0 * z @ z[centres[0]] + sq[centres[0]], 0.0)
        trials = 2 + int(math.log(c))
        for _ in range(c - 1):
            # greedy k-means++ (as scikit-learn's): of a few candidates drawn, the one that
            # lowers the weighted potential most
            p = w * d2
            tot = float(p.sum())
            cands = (rng.choice(m, size=trials, p=p / tot) if tot > 0
                     else rng.integers(m, size=trials))
            d2c = np.minimum(d2[None, :], np.maximum(
                sq[None, :] - 2.0 * z[cands] @ z.T + sq[cands][:, None], 0.0))
            pick = int(np.argmin(d2c @ w))
            centres.append(int(cands[pick]))
            d2 = d2c[pick]
        cent = z[centres].copy()
        lab = np.zeros(m, dtype=np.int64)
        for it in range(20):
            dist = sq[:, None] - 2.0 * z @ cent.T + np.einsum("ij,ij->i", cent, cent)[None, :]
            new = np.argmin(dist, axis=1).astype(np.int64)
            if it and np.array_equal(new, lab):
                break
            lab = new
            for j in range(c):
                sel = lab == j
                if sel.any():
                    cent[j] = (w[sel, None] * z[sel]).sum(axis=0) / w[sel].sum()
        out.append(np.unique(lab, return_inverse=True)[1].astype(np.int64))
    return out


class MicroSummary:
    """The micro-cluster summary and its Hilbert index; see the module notes.

    Holds no samples: the caller stores each sample's record (:meth:`register` returns it)
    and feeds the reservoir sample to :meth:`calibrate`.
    """

    ARRAYS = ("mean", "comp", "count", "cent", "wss", "zc", "zs", "slot_uid", "slot_label",
              "slot_novel", "uid_parent", "uid_slot", "rot", "lo", "hi", "idx_keys",
              "idx_slots", "pending")
    SCALARS = ("d", "k", "ki", "oi", "n_live", "n_seen", "next_uid", "next_id", "thr2", "nov2",
               "n_cal", "res_ref", "res_sum", "res_cnt", "n_macro", "n_novel", "explained",
               "n_calibrations", "n_macro_steps", "n_compactions", "covariance_type",
               "n_refit_clusters", "n_searches", "n_refits", "n_search")

    def __init__(self, *, n_clusters: int | None, n_components: int | None, variance: float,
                 max_components: int, capacity: int, window: int, n_curves: int,
                 growth: float, macro_growth: float, search_growth: float,
                 drift_fraction: float, novelty: float,
                 residual_drift: float, margin: float, max_auto_clusters: int,
                 seed: int, n_starts: int = 4) -> None:
        self.n_clusters = n_clusters
        self.n_components = n_components
        self.variance = variance
        self.max_components = max_components
        self.capacity = capacity
        self.window = window
        self.n_curves = n_curves
        self.growth = growth
        self.macro_growth = macro_growth
        self.search_growth = search_growth
        self.drift_fraction = drift_fraction
        self.novelty = novelty
        self.residual_drift = residual_drift
        self.margin = margin
        self.max_auto_clusters = max_auto_clusters
        self.seed = seed
        self.n_starts = n_starts
        self.d = self.k = self.ki = self.oi = 0
        self.n_live = self.n_seen = self.next_uid = self.next_id = 0
        self.thr2 = 0.0
        self.nov2 = math.inf
        self.n_cal = self.res_cnt = self.n_macro = self.n_novel = 0
        self.res_ref = self.res_sum = 0.0
        self.explained = 1.0
        self.n_calibrations = self.n_macro_steps = self.n_compactions = 0
        self.n_refit_clusters = self.n_searches = self.n_refits = self.n_search = 0
        self.covariance_type = ""
        self.mean = np.zeros(0)
        self.comp = np.zeros((0, 0))
        cap = capacity + 1
        self.count = np.zeros(cap)
        self.cent = np.zeros((cap, 0))
        self.wss = np.zeros(cap)
        self.zc = np.zeros((cap, 0))
        self.zs = np.zeros((cap, 0, 0))
        self.slot_uid = np.full(cap, -1, dtype=np.int64)
        self.slot_label = np.full(cap, -1, dtype=np.int64)
        self.slot_novel = np.zeros(cap, dtype=bool)
        self.uid_parent = np.zeros(0, dtype=np.int64)
        self.uid_slot = np.zeros(0, dtype=np.int64)
        self.rot = np.zeros((0, 0))
        self.lo = np.zeros(0)
        self.hi = np.zeros(1)
        self.idx_keys = np.zeros((0, 0), dtype=np.uint64)
        self.idx_slots = np.zeros((0, 0), dtype=np.int64)
        self.pending = np.zeros(0, dtype=np.int64)
        self._table = np.zeros(0, dtype=np.uint64)
        self._weights = np.zeros(0, dtype=np.int64)

    # ------------------------------------------------------------------ persistence

    def state(self) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
        """Arrays and scalars that restore the summary exactly (:meth:`restore`)."""
        return ({name: getattr(self, name) for name in self.ARRAYS},
                {name: getattr(self, name) for name in self.SCALARS})

    def restore(self, arrays: dict[str, NDArray[Any]], scalars: dict[str, Any]) -> None:
        for name, arr in arrays.items():
            setattr(self, name, arr)
        for name, value in scalars.items():
            setattr(self, name, value)
        if self.nov2 is None:
            self.nov2 = math.inf
        self.pending = np.asarray(self.pending, dtype=np.int64)
        if self.ki:
            self._set_table()

    # ------------------------------------------------------------------ keys

    def _set_table(self) -> None:
        self._table = lookup_table(self.ki, self.oi)
        self._weights = (np.int64(1) << (self.oi * np.arange(self.ki - 1, -1, -1))).astype(
            np.int64)

    @property
    def key_bits(self) -> int:
        """Bits of a stored key (curve 0): ``index dimensions * order``."""
        return self.ki * self.oi

    def curve_keys(self, z: FloatArray) -> NDArray[np.uint64]:
        """Keys of points on every index curve, shape (m, n_curves); column 0: stored key.

        Elementwise arithmetic and numpy's reduction only: deterministic like the projection.
        """
        m = z.shape[0]
        c, ki = self.n_curves, self.ki
        # rot: (n_curves * ki, k); coordinates on each curve's axes
        u = np.add.reduce(z[:, None, :] * self.rot[None, :, :], axis=2)
        # np.minimum / np.maximum rather than np.clip: the same values, without clip's
        # per-call dtype checks (a tenth of a single registration)
        frac = np.minimum(np.maximum((u - self.lo) / (self.hi - self.lo), 0.0), _TOP)
        cell = np.floor(frac * float(1 << self.oi)).astype(np.int64)
        rm = np.add.reduce(cell.reshape(m, c, ki) * self._weights, axis=2)
        return np.asarray(self._table[rm], dtype=np.uint64)

    def keys(self, x: FloatArray) -> NDArray[np.uint64]:
        """Stored keys of samples, shape (m,), ``uint64``."""
        return self.curve_keys(project(x, self.mean, self.comp))[:, 0]

    # ------------------------------------------------------------------ calibration

    def calibrate(self, sample: FloatArray) -> None:
        """Refit the projection on ``sample`` (the reservoir), re-project the micro-clusters
        from their full-space centroids, reset the index curves and the drift signal."""
        n = sample.shape[0]
        old_comp = self.comp
        mean, comp, explained = pca(
            sample, variance=self.variance, min_k=1,
            max_k=max(1, min(self.max_components, n - 1, n // _PER_COMPONENT)),
            n_components=self.n_components)
        self.d = sample.shape[1]
        k = comp.shape[0]
        if self.cent.shape[1] != self.d:
            cap = self.capacity + 1
            self.cent = np.zeros((cap, self.d))
        live = np.flatnonzero(self.slot_uid >= 0)
        zs = np.zeros((self.capacity + 1, k, k))
        if live.size and old_comp.shape[0]:
            # the within scatter in the new basis: the part inside the old subspace rotates
            # exactly; the rest (unknown without the samples) is spread evenly over the new
            # directions, in proportion to the variance they explain
            r = comp @ old_comp.T
            inside = np.einsum("ab,ibc,dc->iad", r, self.zs[live], r)
            tr_in = np.einsum("iaa->i", inside)
            rest = np.maximum(explained * self.wss[live] - tr_in, 0.0) / k
            zs[live] = inside + rest[:, None, None] * np.eye(k)[None]
        self.mean, self.comp, self.k, self.explained = mean, comp, k, explained
        self.zs = zs
        self.zc = np.zeros((self.capacity + 1, k))
        if live.size:
            self.zc[live] = project(_rows(self.cent, live), mean, comp)
        # index curves: the leading components, then random rotations of all k, shifted
        ki = min(k, _INDEX_DIMS)
        self.ki, self.oi = ki, max(1, LUT_MAX_BITS // ki)
        rng = np.random.default_rng([self.seed, self.n_calibrations, 7])
        rots = [np.eye(k)[:ki]]
        for _ in range(self.n_curves - 1):
            q, _ = np.linalg.qr(rng.normal(size=(k, k)))
            rots.append(q[:, :ki].T)
        self.rot = np.ascontiguousarray(np.vstack(rots))
        zsample = project(sample, mean, comp)
        u = np.add.reduce(zsample[:, None, :] * self.rot[None, :, :], axis=2)
        lo, hi = u.min(axis=0), u.max(axis=0)
        width = np.where(hi > lo, hi - lo, np.maximum(np.abs(hi), 1.0))
        shift = np.zeros_like(lo)
        shift[ki:] = rng.uniform(0.0, 0.5, size=lo.size - ki) * width[ki:]
        # a shifted grid: the cell borders move by a fraction of the range
        self.lo = lo - self.margin * width - shift
        self.hi = hi + self.margin * width + (width * 0.5 - shift) * (shift > 0)
        self._set_table()
        xc = sample - mean
        res = np.maximum(_einsum("ij,ij->i", xc, xc) - _einsum("ij,ij->i", zsample, zsample),
                         0.0)
        self.res_ref = float(res.mean()) if res.size else 0.0
        self.res_sum, self.res_cnt = 0.0, 0
        self.n_cal = self.n_seen
        self.n_calibrations += 1
        self._rebuild_index()

    def _rebuild_index(self) -> None:
        live = np.flatnonzero(self.slot_uid >= 0)
        if live.size == 0:
            self.idx_keys = np.zeros((self.n_curves, 0), dtype=np.uint64)
            self.idx_slots = np.zeros((self.n_curves, 0), dtype=np.int64)
        else:
            ck = self.curve_keys(self.zc[live])  # (L, n_curves)
            order = np.argsort(ck, axis=0, kind="stable")
            self.idx_keys = np.ascontiguousarray(np.take_along_axis(ck, order, axis=0).T)
            self.idx_slots = np.ascontiguousarray(live[order].T)
        self.pending = np.zeros(0, dtype=np.int64)

    def _candidates(self, ck: NDArray[np.uint64]) -> IntArray:
        """Index slots near each point's keys, shape (m, n_curves * 2 * window)."""
        m = ck.shape[0]
        n_idx = self.idx_keys.shape[1]
        if n_idx == 0:
            return np.zeros((m, 0), dtype=np.int64)
        w = min(self.window, n_idx)
        if m == 1:
            # one sample (a single registration): Python ints, no temporaries
            top = max(n_idx - 2 * w, 0)
            parts = []
            for t in range(self.n_curves):
                pos = int(self.idx_keys[t].searchsorted(ck[0, t]))
                lo = min(max(pos - w, 0), top)
                parts.append(self.idx_slots[t][lo : lo + 2 * w])
            return np.concatenate(parts)[None, :]
        off = np.arange(2 * w)
        out = []
        for t in range(self.n_curves):
            at = np.searchsorted(self.idx_keys[t], ck[:, t])
            first = np.minimum(np.maximum(at - w, 0), max(n_idx - 2 * w, 0))
            out.append(self.idx_slots[t][np.minimum(first[:, None] + off, n_idx - 1)])
        return np.concatenate(out, axis=1)

    # ------------------------------------------------------------------ registration

    def register(self, x: FloatArray, *, triggers: bool = True
                 ) -> tuple[int, NDArray[np.uint64], IntArray, IntArray, bool]:
        """Register a prefix of ``x`` (shape (m, d)), sample by sample.

        Returns the number registered, their keys, labels as registered and micro-cluster
        ids, and whether a recalibration of the projection is due (the prefix then ends with
        the sample that made it due: the caller adds the samples to its reservoir, then
        calls :meth:`calibrate` and :meth:`macro`). ``triggers=False`` (the first batch)
        registers everything without scheduled steps.
        """
        m = x.shape[0]
        z = project(x, self.mean, self.comp)
        ck = self.curve_keys(z)
        xc = x - self.mean
        res = np.maximum(_einsum("ij,ij->i", xc, xc) - _einsum("ij,ij->i", z, z), 0.0)
        cand = self._candidates(ck)
        base = 0
        labels = np.empty(m, dtype=np.int64)
        uids = np.empty(m, dtype=np.int64)
        res_list = res.tolist()
        buf = np.empty((0, self.d))
        stale = False
        due = False
        i = 0
        # the loop is the per-sample cost of a batch: array methods (argmin, take) rather than
        # numpy's module functions, and einsum's C routine without its Python wrapper, save a
        # few microseconds a sample with the same values bit for bit
        while i < m:
            if stale:
                cand, base = self._candidates(ck[i:]), i
                stale = False
            c = cand[i - base]
            if self.pending.size:
                c = np.concatenate((c, self.pending))
            xi = x[i]
            if c.size:
                if buf.shape[0] < c.size:
                    buf = np.empty((2 * c.size, self.d))
                # the candidates' centroids into one reused buffer: a fresh (c, d) array a
                # sample costs a page fault per 4 KiB on wide features (issue 16); "clip" as
                # the indices are valid: take buffers its output in the default mode
                diff = self.cent.take(c, axis=0, out=buf[: c.size], mode="clip")
                diff -= xi
                d2 = _einsum("ij,ij->i", diff, diff)
                j = int(d2.argmin())
                best, bd2 = int(c[j]), float(d2[j])
            else:
                best, bd2 = -1, math.inf
            # Birch's rule: absorb when the micro-cluster's radius (root mean squared distance
            # of its samples to the centroid) stays within the threshold after the absorption
            n_best = float(self.count[best]) + 1.0 if best >= 0 else 1.0
            if best >= 0 and (float(self.wss[best]) + bd2 * (n_best - 1.0) / n_best
                              <= self.thr2 * n_best):
                # dx = x - c = -(c - x) exactly
                self._absorb(best, np.negative(diff[j]), z[i])
                slot = best
            else:
                if best < 0:
                    label = self._fresh_id()
                elif bd2 > self.nov2:
                    # novel: a provisional cluster, shared with a provisional micro-cluster
                    # within twice the radius (a new skill spreads wider than one sample)
                    near_new = self.slot_novel[best] and bd2 <= 4.0 * self.nov2
                    label = int(self.slot_label[best]) if near_new else self._fresh_id()
                    self.n_novel += 1
                else:
                    label = int(self.slot_label[best])
                slot = self._open(xi, z[i], label, novel=bd2 > self.nov2)
            # the record before a compaction may merge the new micro-cluster away
            labels[i] = self.slot_label[slot]
            uids[i] = self.slot_uid[slot]
            if self.n_live > self.capacity:
                self._compact()
                stale = True
            elif self.pending.size >= _PENDING:
                self._rebuild_index()
                stale = True
            self.n_seen += 1
            self.res_sum += res_list[i]
            self.res_cnt += 1
            i += 1
            if not triggers:
                continue
            if self._calibration_due():
                due = True
                break
            if self._macro_due():
                # a search when novel micro-clusters brought the step forward (a new class
                # may need a cluster of its own) or the count grew by search_growth since
                # the last one; a refit of the chosen mixture otherwise
                self.macro(search=self.n_novel >= _MIN_NOVEL
                           or self.n_seen >= self.search_growth * self.n_search)
                stale = True
        return i, ck[:i, 0].copy(), labels[:i], uids[:i], due

    def _calibration_due(self) -> bool:
        if self.n_seen >= self.growth * self.n_cal:
            return True
        need = max(_MIN_RESIDUAL, math.ceil(self.drift_fraction * self.n_cal))
        return (self.res_cnt >= need
                and self.res_sum / self.res_cnt > self.residual_drift * self.res_ref + 1e-300)

    def _macro_due(self) -> bool:
        if self.n_seen >= self.macro_growth * self.n_macro:
            return True
        since = self.n_seen - self.n_macro
        return (self.n_novel >= _MIN_NOVEL
                and since >= max(_MIN_NOVEL, math.ceil(self.drift_fraction * self.n_macro)))

    def _fresh_id(self) -> int:
        self.next_id += 1
        return self.next_id - 1

    def _absorb(self, s: int, dx: FloatArray, z: FloatArray) -> None:
        """Add one sample to slot ``s``; ``dx``: the sample minus the slot's centroid."""
        n = float(self.count[s]) + 1.0
        dz = z - self.zc[s]
        f = (n - 1.0) / n
        # Welford: the within sums grow by (n - 1) / n times the squared deviation
        self.wss[s] += f * float(dx @ dx)
        fdz = f * dz
        self.zs[s] += fdz[:, None] * dz
        dx /= n
        self.cent[s] += dx
        dz /= n
        self.zc[s] += dz
        self.count[s] = n

    def _open(self, x: FloatArray, z: FloatArray, label: int, novel: bool) -> int:
        free = np.flatnonzero(self.slot_uid < 0)
        s = int(free[0])
        uid = self.next_uid
        self.next_uid += 1
        if uid >= self.uid_parent.size:
            grow = max(64, self.uid_parent.size)
            self.uid_parent = np.concatenate((self.uid_parent,
                                              np.arange(uid, uid + grow, dtype=np.int64)))
            self.uid_slot = np.concatenate((self.uid_slot, np.full(grow, -1, dtype=np.int64)))
        self.uid_slot[uid] = s
        self.slot_uid[s] = uid
        self.slot_label[s] = label
        self.slot_novel[s] = novel
        self.count[s] = 1.0
        self.cent[s] = x
        self.wss[s] = 0.0
        self.zc[s] = z
        self.zs[s] = 0.0
        self.n_live += 1
        self.pending = np.append(self.pending, s)
        return s

    def _merge(self, a: int, b: int) -> None:
        """Merge slot ``b`` into slot ``a`` (the larger keeps its label)."""
        na, nb = self.count[a], self.count[b]
        n = na + nb
        dx = self.cent[b] - self.cent[a]
        dz = self.zc[b] - self.zc[a]
        f = na * nb / n
        self.wss[a] += self.wss[b] + f * float(dx @ dx)
        self.zs[a] += self.zs[b] + f * np.outer(dz, dz)
        self.cent[a] += dx * (nb / n)
        self.zc[a] += dz * (nb / n)
        self.count[a] = n
        if nb > na:
            self.slot_label[a] = self.slot_label[b]
        self.slot_novel[a] &= self.slot_novel[b]
        ub = int(self.slot_uid[b])
        self.uid_parent[ub] = self.slot_uid[a]
        self.uid_slot[ub] = -1
        self.slot_uid[b] = -1
        self.count[b] = 0.0
        self.n_live -= 1

    def _compact(self) -> None:
        """Weighted Ward merges (full space) down to half the capacity; the absorb radius
        grows to the median within radius of the merged micro-clusters."""
        live = np.flatnonzero(self.slot_uid >= 0)
        target = max(1, self.capacity // 2)
        with one_thread():
            merges = ward_merges(self.cent[live], self.count[live], stop=target)
        merged = set()
        for a, b in merges.tolist():
            self._merge(int(live[a]), int(live[b]))
            merged.add(int(live[a]))
        idx = np.array(sorted(merged), dtype=np.int64)
        idx = idx[self.slot_uid[idx] >= 0]
        if idx.size:
            # the threshold grows at every compaction (Birch): to the median radius of what
            # was merged, and by at least a tenth, so that compactions grow rarer
            rad2 = self.wss[idx] / self.count[idx]
            self.thr2 = max(1.21 * self.thr2, float(np.median(rad2)))
        self.n_compactions += 1
        self._rebuild_index()

    # ------------------------------------------------------------------ macro step

    def macro(self, *, search: bool = True) -> None:
        """Cluster the micro-clusters, keep ids by the Hungarian method; a search also resets
        the novelty scale.

        ``search=True``: the number of clusters, the covariance type and the partition are
        chosen afresh (Ward and k-means starts, GMMs by BIC). ``search=False``: the mixture the
        last search chose is refitted by EM from the current partition (one fit instead of
        hundreds); it falls back to a search when there is nothing to refit (no search yet,
        or provisional clusters opened since, so the partition no longer has the chosen
        number of clusters) or when the refit leaves a cluster empty.
        """
        with one_thread():
            self._macro(search)

    def _macro(self, search: bool) -> None:
        live = np.flatnonzero(self.slot_uid >= 0)
        self.n_macro = self.n_seen
        self.n_novel = 0
        self.n_macro_steps += 1
        if live.size == 0:
            return
        w = self.count[live]
        z = self.zc[live]
        scatter = self.zs[live]
        n_pts = live.size
        _, previous = np.unique(self.slot_label[live], return_inverse=True)
        c_prev = int(previous.max()) + 1
        if (not search and self.covariance_type and c_prev == self.n_refit_clusters
                and n_pts > c_prev):
            mix = fit_mixture(z, w, scatter, previous.astype(np.int64),
                              self.covariance_type)  # type: ignore[arg-type]
            # every cluster must keep a micro-cluster: one left empty would lower the number
            # of clusters (a given n_clusters included) until the next search
            if np.unique(mix.labels).size == c_prev:
                self.n_refits += 1
                self._relabel(live, w, mix, spacing=False)
                return
        self.n_searches += 1
        self.n_search = self.n_seen
        if self.n_clusters is not None:
            options = [min(self.n_clusters, n_pts)]
        else:
            options = list(range(1, min(self.max_auto_clusters, n_pts) + 1))
        merges = ward_merges(z, w)
        best: Mixture | None = None
        worse = 0
        for c in options:
            if worse >= _PATIENCE:
                # the criterion rose at the last _PATIENCE numbers of clusters: past its
                # minimum (fitting every number up to max_auto_clusters cost a chosen-k
                # search ten times over: issue 16)
                break
            best_before = best.bic if best is not None else math.inf
            starts = [ward_partition(merges, n_pts, c)]
            if c_prev == c:
                starts.append(previous.astype(np.int64))  # the last macro step's clusters
            starts += _kmeans_starts(z, w, c, self.n_starts, self.seed + self.n_macro_steps)
            # a start equal to an earlier one gives the same fit, which can never be chosen
            # before the earlier one (max keeps the first): fit it once (a fifth of the demo's
            # short fits were repeats: issue 16)
            starts = list({s.tobytes(): s for s in starts}.values())  # first-seen order
            for cov in COVARIANCE_TYPES:
                # a few EM steps from every start, the _CONVERGE most likely run on to
                # convergence, the most likely kept; then the best model by BIC
                short = fit_mixtures(z, w, scatter, starts, cov, max_iter=_SHORT_EM)
                ranked = sorted(short, key=lambda f: -f.log_likelihood)[:_CONVERGE]
                # (a lead that converged within the short run is kept as it is: EM rerun
                # from its own partition ends at or next to the same optimum, with the same
                # labels on the six benchmark sets and the demo, and cost a fifth of the
                # demo's clustering: issue 16)
                todo = [lead for lead in ranked if not lead.converged]
                long = iter(fit_mixtures(z, w, scatter, [lead.labels for lead in todo], cov)
                            if todo else ())
                mix = max((lead if lead.converged
                           else max(next(long), lead, key=lambda f: f.log_likelihood)
                           for lead in ranked), key=lambda f: f.log_likelihood)
                # the converged partition starts the next covariance types too: a simpler
                # type's optimum is often near a richer type's, whose own starts (Ward,
                # k-means) may all lie in a poorer basin
                if int(mix.labels.max()) + 1 == c:
                    starts.append(mix.labels)
                if best is None or mix.bic < best.bic - 1e-9:
                    best = mix
            worse = 0 if best is not None and best.bic < best_before else worse + 1
        assert best is not None
        self.covariance_type = best.covariance_type
        self._relabel(live, w, best)

    def _relabel(self, live: IntArray, w: FloatArray, best: Mixture,
                 spacing: bool = True) -> None:
        """The chosen mixture's clusters as the live micro-clusters' labels (ids kept by the
        Hungarian method), and with ``spacing`` the novelty radius from the micro-clusters'
        spacing (at searches only: its distances in the full feature space were half of a
        refit's cost, and the scale moves little between searches)."""
        n_pts = live.size
        _, new = np.unique(best.labels, return_inverse=True)
        self.n_refit_clusters = int(new.max()) + 1
        ids, self.next_id = match_ids(self.slot_label[live], new.astype(np.int64), w,
                                      self.next_id)
        self.slot_label[live] = ids[new]
        self.slot_novel[live] = False
        # the novelty radius: a high quantile of the distances between neighbouring
        # micro-clusters (a quantile, so a few outliers do not inflate it)
        if not spacing:
            return
        if n_pts >= 2:
            cent = _rows(self.cent, live)
            sq = _einsum("ij,ij->i", cent, cent)
            d2 = np.maximum(sq[:, None] + sq[None, :] - 2.0 * cent @ cent.T, 0.0)
            np.fill_diagonal(d2, np.inf)
            nn = d2.min(axis=1) + self.wss[live] / w
            self.nov2 = self.novelty**2 * max(float(np.quantile(nn, 0.9)), self.thr2, 1e-300)
        else:
            self.nov2 = math.inf

    # ------------------------------------------------------------------ labels

    def roots(self, uids: IntArray) -> IntArray:
        """The live micro-cluster each micro-cluster id was merged into."""
        r = self.uid_parent[uids]
        while True:
            nxt = self.uid_parent[r]
            if np.array_equal(nxt, r):
                return r
            r = nxt

    def current_labels(self, uids: IntArray) -> IntArray:
        """Current labels of samples from their micro-cluster ids (``-1`` stays ``-1``)."""
        out = np.full(uids.shape, -1, dtype=np.int64)
        ok = uids >= 0
        if ok.any():
            out[ok] = self.slot_label[self.uid_slot[self.roots(uids[ok])]]
        return out

    def predict(self, x: FloatArray) -> IntArray:
        """Labels of the nearest micro-clusters (through the index), without registering."""
        z = project(x, self.mean, self.comp)
        cand = self._candidates(self.curve_keys(z))
        if self.pending.size:
            cand = np.concatenate((cand, np.broadcast_to(self.pending,
                                                         (x.shape[0], self.pending.size))),
                                  axis=1)
        out = np.empty(x.shape[0], dtype=np.int64)
        for i in range(x.shape[0]):
            diff = self.cent[cand[i]] - x[i]
            out[i] = self.slot_label[cand[i][int(np.argmin(np.einsum("ij,ij->i", diff,
                                                                     diff)))]]
        return out

    def live_clusters(self) -> tuple[IntArray, FloatArray, FloatArray]:
        """Ids of the current clusters, their counts and centroids in component space."""
        live = np.flatnonzero(self.slot_uid >= 0)
        lab = self.slot_label[live]
        ids = np.unique(lab)
        counts = np.array([self.count[live][lab == i].sum() for i in ids])
        cents = np.array([(self.count[live][lab == i, None] * self.zc[live][lab == i]).sum(0)
                          for i in ids]).reshape(ids.size, self.k) / np.maximum(counts, 1)[:, None]
        return ids.astype(np.int64), counts, cents
