"""PostgresStore: the SampleStore conformance suite on both backends, PostgreSQL's own
guarantees (schema, indexes, locks, COPY, batched re-keys), and the same clustering results
from SQLite and PostgreSQL on the bundled dataset."""

from __future__ import annotations

import json
import threading
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings, strategies as st

from nonprehensile.cli import main
from nonprehensile.errors import InputError
from nonprehensile.motion import HilbertClusterer
from nonprehensile.motion.store import SampleStore
from nonprehensile.motion.stores import is_postgres_url, open_store

psycopg = pytest.importorskip("psycopg", reason="the pg extra (psycopg) is not installed")

from nonprehensile.motion import pgstore  # noqa: E402
from nonprehensile.motion.pgstore import PostgresStore  # noqa: E402

Factory = Callable[[], SampleStore]


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread() -> Iterator[None]:
    # a loaded 2-core machine runs an SVD 10x slower with several BLAS threads than with one
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        yield


@pytest.fixture(params=["sqlite", "postgres"])
def make_store(request: pytest.FixtureRequest, tmp_path: Path) -> Factory:
    """A factory of fresh, empty stores of one backend."""
    if request.param == "sqlite":
        return lambda: open_store(tmp_path / f"{uuid.uuid4().hex}.db")
    url = request.getfixturevalue("pg_url")
    return lambda: open_store(url, name=uuid.uuid4().hex)


batches = st.lists(
    st.lists(st.tuples(st.integers(0, 2**63 - 1), st.integers(-1, 3)), min_size=1,
             max_size=6),
    min_size=1, max_size=4,
)


@settings(max_examples=15, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(batches=batches, upd=st.lists(st.tuples(st.integers(0, 40), st.integers(0, 3)),
                                     max_size=5))
def test_conformance(make_store: Factory, batches: list[list[tuple[int, int]]],
                     upd: list[tuple[int, int]]) -> None:
    store = make_store()
    assert isinstance(store, SampleStore)
    rows = [kc for b in batches for kc in b]
    ref_keys = [k for k, _ in rows]
    ref_labels = [c for _, c in rows]
    vecs = np.random.default_rng(len(rows)).normal(size=(len(rows), 5))
    assert store.n_samples == 0 and store.n_features is None
    pos = 0
    for b in batches:
        store.add(vecs[pos : pos + len(b)], [k for k, _ in b], np.array([c for _, c in b]))
        pos += len(b)
    start = len(rows) // 2
    u = upd[: len(rows) - start]
    if u:
        store.update(start, [k for k, _ in u], np.array([c for _, c in u], dtype=np.int64))
        for i, (k, c) in enumerate(u):
            ref_keys[start + i], ref_labels[start + i] = k, c
    assert store.n_samples == len(rows) and store.n_features == 5
    assert store.keys() == ref_keys
    assert store.labels().tolist() == ref_labels
    # float64 round trip is bit-exact
    np.testing.assert_array_equal(store.vectors(1, len(rows)), vecs[1:])
    for c in range(-1, 4):
        ids, ks = store.cluster(c)
        want = sorted((ref_keys[i], i) for i in range(len(rows)) if ref_labels[i] == c)
        assert list(zip(ks, ids.tolist(), strict=True)) == want
    lo, hi = sorted(ref_keys)[0], sorted(ref_keys)[len(rows) // 2]
    ids, ks = store.key_range(lo, hi)
    want = sorted((k, i) for i, k in enumerate(ref_keys) if lo <= k <= hi)
    assert list(zip(ks, ids.tolist(), strict=True)) == want
    store.put_meta("m", b"\x00abc")
    store.put_meta("m", b"\x00abcd")
    assert store.get_meta("m") == b"\x00abcd" and store.get_meta("x") is None
    with pytest.raises(InputError, match="shape"):
        store.add(np.zeros((1, 4)), [1], np.array([0]))
    with pytest.raises(InputError, match="2\\*\\*63"):
        store.add(np.zeros((1, 5)), [2**63], np.array([0]))
    store.clear()
    assert store.n_samples == 0 and store.keys() == [] and store.get_meta("m") is None
    getattr(store, "close", lambda: None)()


def test_transaction_rolls_back_everything(make_store: Factory) -> None:
    store = make_store()
    store.add(np.ones((2, 3)), [5, 6], np.array([0, 1]))
    with pytest.raises(RuntimeError), store.transaction():
        store.add(np.ones((3, 3)), [1, 2, 3], np.array([0, 0, 0]))
        store.update(0, [9], np.array([7]))
        store.put_meta("state", b"half")
        raise RuntimeError("killed mid-registration")
    assert store.n_samples == 2 and store.keys() == [5, 6] and store.get_meta("state") is None


def test_schema_created_on_first_use_and_versioned(pg_url: str) -> None:
    with psycopg.connect(pg_url, autocommit=True) as conn:
        assert conn.execute("SELECT to_regclass('np_samples')").fetchone() == (None,)
    with PostgresStore(pg_url) as store:
        assert store.info()["schema_version"] == pgstore.SCHEMA_VERSION
        store.add(np.zeros((1, 2)), [0], np.array([0]))
    with psycopg.connect(pg_url, autocommit=True) as conn:
        assert conn.execute("SELECT version FROM np_schema").fetchall() == [(3,)]
        # a version-1 database (no micro-cluster column, inserts vacuum the vectors' TOAST
        # table) is migrated when opened
        conn.execute("ALTER TABLE np_samples DROP COLUMN micro")
        conn.execute("ALTER TABLE np_samples RESET (toast.autovacuum_vacuum_insert_threshold)")
        conn.execute("UPDATE np_schema SET version = 1")
    with PostgresStore(pg_url) as store:
        assert store.micro_ids().tolist() == [-1]
        store.add(np.ones((2, 2)), [1, 2], np.array([0, 0]), micro=np.array([5, 6]))
        store.update(1, [3], np.array([1]), micro=np.array([7]))
        assert store.micro_ids().tolist() == [-1, 7, 6] and store.keys() == [0, 3, 2]
        with pytest.raises(InputError, match="micro-cluster"):
            store.add(np.ones((2, 2)), [1, 2], np.array([0, 0]), micro=np.array([5]))
    with psycopg.connect(pg_url, autocommit=True) as conn:
        assert conn.execute("SELECT version FROM np_schema").fetchall() == [(3,)]
        assert conn.execute(
            "SELECT t.reloptions FROM pg_class c JOIN pg_class t ON t.oid = c.reltoastrelid "
            "WHERE c.relname = 'np_samples'").fetchone() == (
                ["autovacuum_vacuum_insert_threshold=-1"],)
        conn.execute("UPDATE np_schema SET version = 99")
    with pytest.raises(InputError, match=r"schema version 99.*upgrade"):
        PostgresStore(pg_url)


def test_deleted_rows_are_caught(pg_url: str) -> None:
    with PostgresStore(pg_url, "a") as store:
        store.add(np.zeros((3, 2)), [0, 1, 2], np.array([0, 0, 0]))
    with psycopg.connect(pg_url, autocommit=True) as conn:
        conn.execute("DELETE FROM np_samples WHERE id = 1")
    with pytest.raises(InputError, match="deleted outside"):
        PostgresStore(pg_url, "a")


def test_bad_url_and_no_server() -> None:
    assert is_postgres_url("postgresql://x@/db") and not is_postgres_url("store.db")
    with pytest.raises(pgstore.StoreError, match="cannot connect"):
        PostgresStore("postgresql://nobody:secret@/nodb?host=/nonexistent-dir", timeout=1)
    try:
        PostgresStore("postgresql://nobody:secret@/nodb?host=/nonexistent-dir", timeout=1)
    except pgstore.StoreError as exc:
        assert "secret" not in str(exc)


def test_scans_use_the_key_indexes(pg_url: str) -> None:
    with PostgresStore(pg_url, "s") as store:
        store.add(np.zeros((50, 2)), list(range(50)), np.arange(50) % 3)
        conn = store.connection
        conn.execute("ANALYZE np_samples")
        conn.execute("SET enable_seqscan = off")

        def plan(sql: str) -> str:
            return " ".join(r[0] for r in conn.execute("EXPLAIN " + sql).fetchall())

        p = plan("SELECT id, key FROM np_samples WHERE store = 's' AND key BETWEEN 3 AND 9 "
                 "ORDER BY key, id")
        assert "np_samples_key" in p and "Sort" not in p
        p = plan("SELECT id, key FROM np_samples WHERE store = 's' AND label = 1 "
                 "ORDER BY key, id")
        assert "np_samples_label_key" in p and "Sort" not in p


def test_rekey_in_batches(pg_url: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(pgstore, "UPDATE_BATCH", 7)
    with PostgresStore(pg_url) as store:
        store.add(np.zeros((30, 2)), [0] * 30, np.zeros(30, dtype=np.int64))
        store.update(2, list(range(100, 125)), np.arange(25) % 4)
        assert store.keys() == [0, 0, *range(100, 125), 0, 0, 0]
        assert store.labels().tolist() == [0, 0, *(np.arange(25) % 4).tolist(), 0, 0, 0]


def test_concurrent_writers_get_contiguous_ids(pg_url: str) -> None:
    errors: list[BaseException] = []

    def writer(w: int) -> None:
        try:
            with PostgresStore(pg_url, "shared") as store:
                for i in range(10):
                    store.add(np.full((3, 2), float(w)), [w, w, w], np.array([i, i, i]))
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(w,)) for w in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    with PostgresStore(pg_url, "shared") as store:
        assert store.n_samples == 120
        x = store.vectors(0, 120)
        # each add is one block of 3 rows of one writer: never interleaved
        assert (x[::3, 0] == x[1::3, 0]).all() and (x[::3, 0] == x[2::3, 0]).all()
        assert sorted(np.bincount(x[:, 0].astype(int)).tolist()) == [30, 30, 30, 30]


def test_clusterer_state_round_trip(pg_url: str) -> None:
    x = np.random.default_rng(0).normal(size=(60, 8)) + np.repeat(np.eye(8)[:3] * 6, 20, 0)
    store = PostgresStore(pg_url, "c")
    c = HilbertClusterer(3, init_size=40, store=store, random_state=0).fit(x[:40])
    store.put_meta("state", c.save_state())
    store.close()
    again = PostgresStore(pg_url, "c")
    c2 = HilbertClusterer.load_state(again.get_meta("state") or b"", again)
    c2.partial_fit(x[40:])
    ref = HilbertClusterer(3, init_size=40, random_state=0).fit(x)
    assert c2.labels_.tolist() == ref.labels_.tolist()
    assert again.keys() == ref.store.keys()


@pytest.fixture(scope="module")
def cube_arrays(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled dataset's demonstrations, flattened, as the CLI's --arrays file."""
    from nonprehensile.cli.cluster import _load_dataset

    x, y = _load_dataset("cube", True)
    path = tmp_path_factory.mktemp("cube") / "cube.npz"
    np.savez(path, X=x, y=np.array(y))
    return path


def test_same_clusters_from_sqlite_and_postgres(pg_url: str, tmp_path: Path,
                                                cube_arrays: Path) -> None:
    runner = CliRunner()
    docs = []
    for store in (str(tmp_path / "c.db"), pg_url):
        r = runner.invoke(main, ["cluster", "fit", store, "--arrays", str(cube_arrays),
                                 "--n-clusters", "6", "--init-size", "120", "--json"])
        assert r.exit_code == 0, r.output
        fit = json.loads(r.stdout)
        r = runner.invoke(main, ["cluster", "show", store, "--json"])
        assert r.exit_code == 0, r.output
        show = json.loads(r.stdout)
        assert show["store"] == store
        docs.append([{k: v for k, v in d.items() if k != "store"} for d in (fit, show)])
    # labels of every sample, keys' ranges, recalibrations: identical
    assert docs[0] == docs[1]
    assert docs[0][0]["n_samples"] == 180 and len(docs[0][0]["labels"]) == 180
    assert docs[0][0]["ari_vs_classes"] > 0.3
