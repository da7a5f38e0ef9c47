"""The micro-cluster summary (method="micro"): its numerics against independent tools, the
per-sample record, deterministic keys, compaction, persistence."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.cluster.hierarchy import fcluster, linkage
from sklearn.decomposition import PCA
from sklearn.metrics import adjusted_rand_score
from sklearn.mixture import GaussianMixture

from nonprehensile.errors import InputError
from nonprehensile.motion import microcluster
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.microcluster import (
    COVARIANCE_TYPES,
    fit_mixture,
    fit_mixtures,
    one_thread,
    pca,
    project,
    ward_merges,
    ward_partition,
)
from nonprehensile.motion.store import MemoryStore, SQLiteStore


def _blobs(n: int, k: int, d: int, seed: int, sep: float = 6.0) -> tuple[np.ndarray,
                                                                         np.ndarray]:
    rng = np.random.default_rng(seed)
    centers = rng.normal(scale=sep, size=(k, d))
    y = rng.integers(0, k, n)
    return centers[y] + rng.normal(size=(n, d)), y


# --------------------------------------------------------------------------- numerics


def test_weighted_ward_equals_scipy_and_weights_equal_copies() -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(40, 3))
    merges = ward_merges(pts, np.ones(40))
    ref = linkage(pts, method="ward")
    for c in (2, 3, 5, 8):
        ours = ward_partition(merges, 40, c)
        theirs = fcluster(ref, c, criterion="maxclust")
        assert adjusted_rand_score(theirs, ours) == 1.0
    # a point of weight 3 merges as three coincident points do
    w = np.ones(40)
    w[:5] = 3.0
    copies = np.vstack([pts, pts[:5], pts[:5]])
    heavy = ward_partition(ward_merges(pts, w), 40, 4)
    same = ward_partition(ward_merges(copies, np.ones(50)), 50, 4)[:40]
    assert adjusted_rand_score(same, heavy) == 1.0


def test_mixture_on_single_samples_matches_scikit_learn() -> None:
    x, y = _blobs(300, 3, 4, seed=1, sep=8.0)
    for cov in ("spherical", "diag", "tied", "full"):
        ours = fit_mixture(x, np.ones(300), np.zeros((300, 4, 4)), y.astype(np.int64),
                           cov, reg=1e-6, tol=1e-12, max_iter=300)  # type: ignore[arg-type]
        means = np.array([x[y == j].mean(axis=0) for j in range(3)])
        ref = GaussianMixture(3, covariance_type=cov, means_init=means, reg_covar=1e-6,
                              tol=1e-9, max_iter=300, random_state=0).fit(x)
        assert adjusted_rand_score(ref.predict(x), ours.labels) == 1.0
        np.testing.assert_allclose(ours.log_likelihood, ref.score(x) * 300, rtol=1e-7)
        np.testing.assert_allclose(ours.bic, ref.bic(x), rtol=1e-7)


def test_mixture_counts_the_scatter_of_a_summarised_point() -> None:
    # two samples summarised as one point of weight 2 (mean and scatter) give the same
    # spherical model as the two samples
    rng = np.random.default_rng(2)
    x = rng.normal(size=(20, 2))
    pairs = x.reshape(10, 2, 2)
    cent = pairs.mean(axis=1)
    dev = pairs - cent[:, None, :]
    scatter = np.einsum("pia,pib->pab", dev, dev)
    one = fit_mixture(x, np.ones(20), np.zeros((20, 2, 2)), np.zeros(20, dtype=np.int64),
                      "full", reg=0.0)
    summ = fit_mixture(cent, np.full(10, 2.0), scatter, np.zeros(10, dtype=np.int64), "full",
                       reg=0.0)
    np.testing.assert_allclose(summ.covariances, one.covariances, rtol=1e-10)
    np.testing.assert_allclose(summ.log_likelihood, one.log_likelihood, rtol=1e-10)


def test_mixtures_side_by_side_equal_one_by_one() -> None:
    # summarised points (weights and scatter), starts of different cluster counts, each
    # stopping at its own convergence: the stacked EM gives every start's own fit
    rng = np.random.default_rng(21)
    x, y = _blobs(60, 3, 3, seed=21, sep=3.0)
    w = rng.integers(1, 5, 60).astype(float)
    dev = rng.normal(size=(60, 4, 3))
    scatter = np.einsum("pia,pib->pab", dev, dev) * (w / 4.0)[:, None, None]
    starts = [y.astype(np.int64), rng.integers(0, 3, 60), rng.integers(0, 2, 60),
              np.zeros(60, dtype=np.int64), rng.integers(0, 4, 60)]
    for cov in COVARIANCE_TYPES:
        for max_iter in (3, 100):
            together = fit_mixtures(x, w, scatter, starts, cov, max_iter=max_iter)
            for init, fit in zip(starts, together, strict=True):
                alone = fit_mixture(x, w, scatter, init, cov, max_iter=max_iter)
                np.testing.assert_array_equal(fit.labels, alone.labels)
                np.testing.assert_allclose(fit.log_likelihood, alone.log_likelihood,
                                           rtol=1e-12)
                np.testing.assert_allclose(fit.covariances, alone.covariances, rtol=1e-10,
                                           atol=1e-14)
                assert fit.means.shape == (int(init.max()) + 1, 3)
                assert fit.converged == alone.converged
            # a hundred steps stop every start on its tolerance; three leave some running
            assert all(f.converged for f in together) == (max_iter == 100)


def test_diagonal_densities_equal_the_general_ones() -> None:
    # the elementwise path for spherical and diagonal covariances against Cholesky + inverse
    rng = np.random.default_rng(22)
    z = rng.normal(size=(30, 4))
    dev = rng.normal(size=(30, 5, 4))
    inner = np.einsum("pia,pib->pab", dev, dev).reshape(30, 16) / 5.0
    means = rng.normal(size=(2, 3, 4))
    covs = rng.uniform(0.5, 2.0, size=(2, 3, 4))[..., None] * np.eye(4)
    diag = microcluster._log_prob(z, inner, np.ascontiguousarray(inner[:, ::5]), means, covs,
                                  True)
    general = microcluster._log_prob(z, inner, inner[:, ::5], means, covs, False)
    np.testing.assert_allclose(diag, general, rtol=1e-12)


def test_gram_pca_equals_the_svd() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(30, 200)) @ np.diag(np.linspace(3, 0.1, 200))
    _, comp, explained = pca(x, variance=0.9, min_k=1, max_k=30)
    ref = PCA(n_components=comp.shape[0], svd_solver="full").fit(x)
    np.testing.assert_allclose(np.abs(comp @ ref.components_.T), np.eye(comp.shape[0]),
                               atol=1e-8)
    assert explained == pytest.approx(ref.explained_variance_ratio_.sum())
    assert explained >= 0.9


def test_projection_is_the_same_whatever_the_chunks() -> None:
    rng = np.random.default_rng(4)
    x = rng.normal(size=(257, 333)) * 1e3
    mean, comp, _ = pca(x, variance=0.95, min_k=1, max_k=20)
    whole = project(x, mean, comp)
    rows = np.vstack([project(x[i : i + 1], mean, comp) for i in range(257)])
    np.testing.assert_array_equal(whole, rows)
    np.testing.assert_allclose(whole, (x - mean) @ comp.T, rtol=1e-9, atol=1e-6)


# --------------------------------------------------------------------------- the model


def test_records_stay_and_current_labels_follow_the_summary() -> None:
    x, y = _blobs(1500, 4, 12, seed=5)
    c = HilbertClusterer(4, init_size=100, capacity=32, random_state=0)
    c.partial_fit(x[:100])  # the first batch gets its keys and labels when it completes
    for s in range(100, 1500, 50):
        keys_before = c.store.keys()
        reg_before = c.labels_registered_
        c.partial_fit(x[s : s + 50])
        # a stored record is written once: keys and labels as registered never move
        assert c.store.keys()[: len(keys_before)] == keys_before
        np.testing.assert_array_equal(c.labels_registered_[: reg_before.size], reg_before)
    m = c._micro
    assert m.n_live <= 32 and m.n_compactions > 5
    assert adjusted_rand_score(y, c.labels_) == 1.0
    # current labels are those of the live micro-cluster a sample's own was merged into
    roots = m.roots(c.store.micro_ids())
    assert (m.slot_uid[m.uid_slot[roots]] == roots).all()
    np.testing.assert_array_equal(c.predict(x[:200]), c.labels_[:200])
    # the map from micro-cluster ids to current clusters (the service's "cluster now"): the
    # current labels from the stored ids alone, merged and compacted ids included
    micro = c.store.micro_ids()
    np.testing.assert_array_equal(c.micro_labels_[micro], c.labels_)
    assert c.micro_labels_.size >= len(set(micro.tolist())) > m.n_live
    with pytest.raises(InputError, match="method 'micro' only"):
        _ = HilbertClusterer(2, method="runs").micro_labels_
    np.testing.assert_array_equal(c.transform(x[-50:]),
                                  np.array(c.store.keys()[-50:], dtype=np.uint64))


def test_far_samples_share_one_new_cluster() -> None:
    x, y = _blobs(200, 2, 5, seed=10)
    c = HilbertClusterer(2, random_state=0).fit(x)
    far = x[y == 0][:3] + 1000.0
    assert c.outside(far).all()
    c.partial_fit(far)
    new = c.labels_registered_[-3:]
    assert len(set(new.tolist())) == 1 and new[0] not in set(c.labels_[:200].tolist())
    assert c.n_novel_ >= 1


def test_batched_sqlite_registration_resumes_exactly(tmp_path: Path) -> None:
    x, _ = _blobs(900, 3, 10, seed=12)
    ref = HilbertClusterer(3, init_size=60, capacity=40, random_state=1)
    for s in range(0, 900, 7):
        ref.partial_fit(x[s : s + 7])
    path = tmp_path / "c.db"
    store = SQLiteStore(path)
    c = HilbertClusterer(3, init_size=60, capacity=40, random_state=1, store=store)
    c.partial_fit(x[:500])
    store.put_meta("model", c.save_state())
    store.close()
    store = SQLiteStore(path)
    state = store.get_meta("model")
    assert state is not None
    again = HilbertClusterer.load_state(state, store)
    again.partial_fit(x[500:])
    np.testing.assert_array_equal(again.labels_, ref.labels_)
    np.testing.assert_array_equal(again.labels_registered_, ref.labels_registered_)
    np.testing.assert_array_equal(store.micro_ids(), ref.store.micro_ids())
    assert store.keys() == ref.store.keys()
    # the whole summary, its schedule included (when the next search and refit are due)
    arrays, scalars = again._micro.state()
    ref_arrays, ref_scalars = ref._micro.state()
    assert scalars == ref_scalars and ref_scalars["n_refits"] > 0
    for name, arr in arrays.items():
        np.testing.assert_array_equal(arr, ref_arrays[name], err_msg=name)


def test_memory_store_micro_ids_are_checked() -> None:
    from nonprehensile.errors import InputError

    s = MemoryStore()
    s.add(np.zeros((2, 3)), [1, 2], np.zeros(2, dtype=np.int64), micro=np.array([4, 5]))
    np.testing.assert_array_equal(s.micro_ids(), [4, 5])
    s.add(np.zeros((1, 3)), [3], np.zeros(1, dtype=np.int64))
    np.testing.assert_array_equal(s.micro_ids(), [4, 5, -1])
    with pytest.raises(InputError, match="micro-cluster ids"):
        s.add(np.zeros((2, 3)), [1, 2], np.zeros(2, dtype=np.int64), micro=np.array([1]))


def test_one_thread_limits_every_pool_and_restores_it() -> None:
    from threadpoolctl import threadpool_info

    before = [i["num_threads"] for i in threadpool_info()]
    for _ in range(2):  # the second use goes through the cached controller
        with one_thread():
            assert all(i["num_threads"] == 1 for i in threadpool_info())
        assert [i["num_threads"] for i in threadpool_info()] == before
