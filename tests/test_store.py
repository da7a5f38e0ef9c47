"""The sample store: both implementations against a plain reference, SQLite's durability."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, strategies as st

from nonprehensile.errors import InputError
from nonprehensile.motion import store as store_module
from nonprehensile.motion.store import MemoryStore, SampleStore, SQLiteStore, StoreError

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _stores(tmp_path: Path) -> list[SampleStore]:
    return [MemoryStore(), SQLiteStore(":memory:"), SQLiteStore(tmp_path / "s.db")]


batches = st.lists(
    st.lists(st.tuples(st.integers(0, 40), st.integers(-1, 3)), min_size=1, max_size=6),
    min_size=1, max_size=4,
)


@given(batches=batches, upd=st.lists(st.tuples(st.integers(0, 40), st.integers(0, 3)),
                                     max_size=5))
def test_store_matches_reference(tmp_path_factory: pytest.TempPathFactory,
                                 batches: list[list[tuple[int, int]]],
                                 upd: list[tuple[int, int]]) -> None:
    tmp = tmp_path_factory.mktemp("s")
    rows = [kc for b in batches for kc in b]
    # reference: plain lists
    keys = [k for k, _ in rows]
    labels = [c for _, c in rows]
    vecs = np.arange(len(rows) * 3, dtype=float).reshape(-1, 3)
    for store in _stores(tmp):
        assert store.n_features is None
        pos = 0
        for b in batches:
            store.add(vecs[pos : pos + len(b)], [k for k, _ in b],
                      np.array([c for _, c in b]))
            pos += len(b)
        ref_keys, ref_labels = list(keys), list(labels)
        start = len(rows) // 2
        if upd:
            u = upd[: len(rows) - start]
            store.update(start, [k for k, _ in u], np.array([c for _, c in u], dtype=np.int64))
            for i, (k, c) in enumerate(u):
                ref_keys[start + i], ref_labels[start + i] = k, c
        assert store.n_samples == len(rows) and store.n_features == 3
        assert store.keys() == ref_keys
        assert store.labels().tolist() == ref_labels
        np.testing.assert_array_equal(store.vectors(1, len(rows)), vecs[1:])
        for c in range(-1, 4):
            ids, ks = store.cluster(c)
            want = sorted((ref_keys[i], i) for i in range(len(rows)) if ref_labels[i] == c)
            assert list(zip(ks, ids.tolist(), strict=True)) == want
        ids, ks = store.key_range(10, 20)
        want = sorted((k, i) for i, k in enumerate(ref_keys) if 10 <= k <= 20)
        assert list(zip(ks, ids.tolist(), strict=True)) == want
        store.put_meta("m", b"\x00abc")
        assert store.get_meta("m") == b"\x00abc" and store.get_meta("x") is None
        store.clear()
        assert store.n_samples == 0 and store.keys() == []


def test_sqlite_is_wal_and_uses_the_indexes(tmp_path: Path) -> None:
    store = SQLiteStore(tmp_path / "s.db")
    assert store.info()["journal_mode"] == "wal"
    db = store._db
    plan = " ".join(str(r) for r in db.execute(
        "EXPLAIN QUERY PLAN SELECT id, key FROM samples WHERE label = ? ORDER BY key, id", (1,)))
    # reading a cluster is a range scan of the (label, key) index
    assert "INDEX samples_label_key (label=?)" in plan
    plan = " ".join(str(r) for r in db.execute(
        "EXPLAIN QUERY PLAN SELECT id, key FROM samples WHERE key BETWEEN ? AND ? "
        "ORDER BY key, id", (1, 2)))
    assert "INDEX samples_key (key>? AND key<?)" in plan


def test_store_rejects_bad_input(tmp_path: Path) -> None:
    for store in _stores(tmp_path):
        store.add(np.zeros((2, 3)), [1, 2], np.zeros(2, dtype=np.int64))
        with pytest.raises(InputError, match=r"shape \(m, 3\)"):
            store.add(np.zeros((1, 4)), [1], np.zeros(1, dtype=np.int64))
        with pytest.raises(InputError, match="as many keys"):
            store.add(np.zeros((2, 3)), [1], np.zeros(2, dtype=np.int64))
        with pytest.raises(InputError, match="2\\*\\*63"):
            store.add(np.zeros((1, 3)), [2**63], np.zeros(1, dtype=np.int64))
    bad = tmp_path / "not.db"
    bad.write_bytes(b"this is not a database" * 100)
    with pytest.raises(InputError, match=r"not\.db: cannot open as a sample store"):
        SQLiteStore(bad)


def test_transaction_rolls_back_on_error(tmp_path: Path) -> None:
    store = SQLiteStore(tmp_path / "s.db")
    store.add(np.ones((1, 2)), [5], np.zeros(1, dtype=np.int64))
    with pytest.raises(RuntimeError), store.transaction():
        store.add(np.ones((2, 2)), [6, 7], np.zeros(2, dtype=np.int64))
        store.put_meta("state", b"x")
        raise RuntimeError("boom")
    assert store.n_samples == 1 and store.get_meta("state") is None
    other = SQLiteStore(tmp_path / "s.db")
    assert other.keys() == [5]


_WRITER = textwrap.dedent("""
    import sys
    import numpy as np
    sys.path.insert(0, {src!r})
    from nonprehensile.motion.store import SQLiteStore
    store = SQLiteStore(sys.argv[1])
    tag = int(sys.argv[2])
    for i in range(int(sys.argv[3])):
        store.add(np.full((1, 4), float(i)), [tag * 100000 + i], np.array([tag]))
        print(i, flush=True)
""")


def _writer(path: Path, tag: int, count: int) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", _WRITER.format(src=SRC), str(path), str(tag), str(count)],
        stdout=subprocess.PIPE, text=True,
    )


def test_killed_writer_loses_no_committed_row(tmp_path: Path) -> None:
    path = tmp_path / "s.db"
    SQLiteStore(path).close()
    proc = _writer(path, 1, 10**6)
    assert proc.stdout is not None
    last = -1
    for line in proc.stdout:
        last = int(line)
        if last >= 60:
            break
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    store = SQLiteStore(path)
    assert store.integrity() == "ok"
    n = store.n_samples
    # every row reported committed is there (and possibly one or two more)
    assert n >= last + 1
    assert store.keys() == [100000 + i for i in range(n)]
    np.testing.assert_array_equal(store.vectors(0, n)[:, 0], np.arange(n, dtype=float))


def test_concurrent_writers(tmp_path: Path) -> None:
    path = tmp_path / "s.db"
    SQLiteStore(path).close()
    procs = [_writer(path, tag, 25) for tag in range(1, 5)]
    for p in procs:
        p.communicate(timeout=60)
        assert p.returncode == 0
    store = SQLiteStore(path)
    keys = store.keys()
    assert len(keys) == 100 and store.n_samples == 100
    assert sorted(keys) == sorted(t * 100000 + i for t in range(1, 5) for i in range(25))
    # each writer's rows kept their order
    for t in range(1, 5):
        mine = [k for k in keys if k // 100000 == t]
        assert mine == sorted(mine)
        _, ks = store.cluster(t)
        assert ks == mine


def test_write_lock_timeout_is_a_store_error(tmp_path: Path) -> None:
    path = tmp_path / "s.db"
    holder = SQLiteStore(path)
    waiter = SQLiteStore(path, timeout=0.05, lock_wait=0.2)
    with holder.transaction():
        holder.add(np.ones((1, 2)), [1], np.zeros(1, dtype=np.int64))
        with pytest.raises(StoreError, match="write lock"):
            waiter.add(np.ones((1, 2)), [2], np.zeros(1, dtype=np.int64))
    waiter.add(np.ones((1, 2)), [2], np.zeros(1, dtype=np.int64))
    assert waiter.keys() == [1, 2]


@given(ops=st.lists(st.tuples(st.integers(0, 9), st.integers(0, 30), st.integers(0, 30)),
                    min_size=1, max_size=12))
def test_memory_store_blocks_match_one_array(ops: list[tuple[int, int, int]]) -> None:
    # tiny blocks (4 samples of 3 features): every read, write and append crosses blocks;
    # the reference is one plain array
    old = store_module._BLOCK_BYTES
    store_module._BLOCK_BYTES = 96
    try:
        store = MemoryStore()
        ref_x = np.zeros((0, 3))
        ref = np.zeros((0, 3), dtype=np.int64)  # key, label, micro-cluster id
        for m, a, b in ops:
            x = np.arange(3 * m, dtype=float).reshape(m, 3) + ref_x.shape[0]
            ints = np.arange(3 * m).reshape(m, 3) % 7 + ref.shape[0]
            store.add(x, ints[:, 0].tolist(), ints[:, 1], micro=ints[:, 2])
            ref_x, ref = np.vstack([ref_x, x]), np.vstack([ref, ints])
            n = ref.shape[0]
            lo, hi = min(a, b, n), min(max(a, b), n)
            np.testing.assert_array_equal(store.vectors(lo, hi), ref_x[lo:hi])
            new = ref[lo:hi, ::-1] + 1
            store.update(lo, new[:, 0].tolist(), new[:, 1], micro=new[:, 2])
            ref[lo:hi] = new
        assert store.keys() == ref[:, 0].tolist()
        np.testing.assert_array_equal(store.labels(), ref[:, 1])
        np.testing.assert_array_equal(store.micro_ids(), ref[:, 2])
        np.testing.assert_array_equal(store.vectors(0, ref.shape[0]), ref_x)
        # no block ever holds more than a block's rows: an append copies at most one block
        assert all(blk.shape[0] <= 4 for blk in store._x.blocks)
    finally:
        store_module._BLOCK_BYTES = old
