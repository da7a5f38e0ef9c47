"""Archive re-keying on Dask: a pure function over chunks, the same keys whatever the
chunking, the number of BLAS threads, the source (store or Parquet export) and the backend."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dask", reason="the scale extra (dask) is not installed")
pytest.importorskip("pyarrow", reason="the scale extra (pyarrow) is not installed")

from threadpoolctl import threadpool_limits

from nonprehensile.errors import InputError
from nonprehensile.motion import HilbertClusterer
from nonprehensile.motion.hilbert import encode, quantize
from nonprehensile.motion.scale import (
    KeyModel,
    export_parquet,
    project,
    recluster_chunk,
    rekey_chunk,
    rekey_parquet,
    rekey_store,
    write_keys,
)
from nonprehensile.motion.stores import open_store

TRUTH: dict[str, np.ndarray] = {}


@pytest.fixture(scope="module")
def fitted() -> tuple[np.ndarray, KeyModel, HilbertClusterer]:
    rng = np.random.default_rng(3)
    centres = rng.normal(scale=5.0, size=(4, 120))
    y = rng.integers(0, 4, 1500)
    x = centres[y] + rng.normal(size=(1500, 120))
    with threadpool_limits(1):
        c = HilbertClusterer(4, init_size=150, random_state=0).fit(x[:150])
    TRUTH["y"] = y
    return x, KeyModel.from_clusterer(c), c


def test_keys_do_not_depend_on_chunking_or_blas_threads(fitted: tuple) -> None:
    x, model, _ = fitted
    with threadpool_limits(1):
        whole = rekey_chunk(x, model)[0]
    for limit in (1, 2, 4):
        with threadpool_limits(limit):
            for cuts in ([1, 2, 700, 1499], [333, 334, 1000], list(range(0, 1500, 97))):
                parts = [rekey_chunk(p, model)[0] for p in np.split(x, cuts)]
                np.testing.assert_array_equal(np.concatenate(parts), whole)
    # one sample at a time: the same bits as in a batch
    z = project(x[:50], model.mean, model.components)
    for i in range(50):
        np.testing.assert_array_equal(project(x[i : i + 1], model.mean, model.components)[0], z[i])


def test_projection_against_exact_sums(fitted: tuple) -> None:
    # an independent truth: correctly rounded dot products (math.fsum)
    x, model, c = fitted
    z = project(x[:40], model.mean, model.components)
    for i in range(40):
        xc = [a - m for a, m in zip(x[i].tolist(), model.mean.tolist(), strict=True)]
        for j in range(model.components.shape[0]):
            exact = math.fsum(a * b for a, b in zip(xc, model.components[j].tolist(),
                                                  strict=True))
            assert abs(z[i, j] - exact) <= 1e-12 * (1 + abs(exact))
    # the clusterer's own keys of the same samples (a BLAS product): equal but for samples
    # on a cell boundary, where the last bit decides
    grid, _ = quantize(z, model.lower, model.upper, model.order)
    np.testing.assert_array_equal(np.asarray(encode(grid, model.order), dtype=np.uint64),
                                  rekey_chunk(x[:40], model)[0])
    agree = (c.transform(x) == rekey_chunk(x, model)[0]).mean()
    assert agree > 0.99


@pytest.fixture(params=["sqlite", "postgres"])
def store_spec(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    if request.param == "sqlite":
        return str(tmp_path / "a.db")
    pytest.importorskip("psycopg")
    return str(request.getfixturevalue("pg_url"))


def test_rekey_on_a_local_dask_cluster(fitted: tuple, store_spec: str, tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    x, model, _ = fitted
    with threadpool_limits(1):
        want = rekey_chunk(x, model)[0]
    store = open_store(store_spec, name="arc" if store_spec.startswith("postgres") else None)
    store.add(x, [0] * len(x), np.zeros(len(x), dtype=np.int64))
    pq_path = tmp_path / "export.parquet"
    assert export_parquet(store, pq_path, rows_per_group=256) == len(x)
    name = "arc" if store_spec.startswith("postgres") else None
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        from_store = rekey_store(store_spec, model, name=name, chunk=200, scheduler=client)
        from_parquet = rekey_parquet(pq_path, model, scheduler=client)
        k2, labels = rekey_store(store_spec, model, name=name, chunk=333, scheduler=client,
                                 labels=True)
        k3, labels3 = rekey_parquet(pq_path, model, scheduler=client, labels=True)
    np.testing.assert_array_equal(from_store, want)
    np.testing.assert_array_equal(k2, want)
    np.testing.assert_array_equal(k3, want)
    with threadpool_limits(1):
        np.testing.assert_array_equal(labels, recluster_chunk(x, model)[1])
    np.testing.assert_array_equal(labels3, labels)
    # re-clustering finds the four generating clusters (an independent truth)
    from sklearn.metrics import adjusted_rand_score

    assert adjusted_rand_score(TRUTH["y"], labels) == 1.0
    np.testing.assert_array_equal(from_parquet, want)
    # Dask's local threads, other chunks: the same
    np.testing.assert_array_equal(rekey_store(store_spec, model, name=name, chunk=999), want)
    write_keys(store, from_store, batch=300)
    assert store.keys() == [int(k) for k in want.tolist()]
    with pytest.raises(InputError, match="keys for a store"):
        write_keys(store, from_store[:5])
    getattr(store, "close", lambda: None)()
