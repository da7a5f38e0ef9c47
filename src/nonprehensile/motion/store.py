"""Storage of clustered trajectories: a small interface and its two implementations.

The motion model keeps every registered sample (a flattened trajectory, paper Section VI), its
Hilbert key and its cluster id, because a recalibration of the principal components re-keys
the stored samples. :class:`SampleStore` is the interface the clusterer needs, and nothing
more, so that a server database can replace SQLite later:

* :class:`MemoryStore` keeps numpy arrays in memory (the default of
  :class:`~nonprehensile.motion.clustering.HilbertClusterer`).
* :class:`SQLiteStore` keeps them in an embedded SQLite database (a file, or ``":memory:"``),
  indexed on the key and on (cluster, key), so that registering a sample is one insert into a
  B-tree and reading a cluster is one index range scan, returned in key order. The database
  runs in WAL mode: readers never block the writer, several processes may add at once (each
  waits its turn for the write lock, up to ``timeout`` seconds), and a transaction that has
  committed survives the writer being killed (SQLite's WAL is written before the commit
  returns; ``synchronous=NORMAL`` skips only the fsync that protects against power loss, pass
  ``synchronous="FULL"`` for that).

Samples are numbered ``0, 1, 2, ...`` in the order they were added (``id``); keys are Python
ints below ``2**63`` (SQLite's INTEGER); cluster ids are ints (``-1``: none yet).
"""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nonprehensile.errors import InputError, StoreError

__all__ = ["MemoryStore", "SQLiteStore", "SampleStore", "StoreError"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Largest key a store accepts: SQLite integers are signed 64-bit.
MAX_KEY = 2**63 - 1


@runtime_checkable
class SampleStore(Protocol):
    """What the clusterer needs from a store of samples, keys and cluster ids."""

    @property
    def n_samples(self) -> int:
        """Number of stored samples."""

    @property
    def n_features(self) -> int | None:
        """Length of a stored vector, ``None`` while the store is empty."""

    def add(self, vectors: FloatArray, keys: list[int], labels: IntArray,
            micro: IntArray | None = None) -> None:
        """Append samples, shape (m, n_features), with their keys and cluster ids.

        ``micro``: each sample's micro-cluster id (``method="micro"``), ``-1`` when absent.
        The cluster id stored is the label *as registered*; the clusterer derives the
        current one from the micro-cluster id, so a stored row is written once.
        """

    def vectors(self, start: int, stop: int) -> FloatArray:
        """Stored vectors ``start <= id < stop``, shape (stop - start, n_features)."""

    def update(self, start: int, keys: list[int], labels: IntArray,
               micro: IntArray | None = None) -> None:
        """Replace keys and cluster ids (and micro-cluster ids, when given) of samples
        ``start, start + 1, ...``."""

    def keys(self) -> list[int]:
        """Keys of all samples, in the order added."""

    def labels(self) -> IntArray:
        """Cluster ids of all samples, shape (n_samples,), in the order added."""

    def micro_ids(self) -> IntArray:
        """Micro-cluster ids of all samples, shape (n_samples,), in the order added."""

    def cluster(self, label: int) -> tuple[IntArray, list[int]]:
        """Ids and keys of the samples of one cluster, in key order."""

    def key_range(self, low: int, high: int) -> tuple[IntArray, list[int]]:
        """Ids and keys of the samples with ``low <= key <= high``, in key order."""

    def get_meta(self, name: str) -> bytes | None:
        """A named blob (the clusterer's state), ``None`` if absent."""

    def put_meta(self, name: str, value: bytes) -> None:
        """Store a named blob."""

    def transaction(self) -> contextlib.AbstractContextManager[None]:
        """A context in which every change is committed together, or none."""

    def clear(self) -> None:
        """Remove every sample and blob."""


def _check_batch(vectors: ArrayLike, keys: list[int], labels: ArrayLike,
                 n_features: int | None) -> tuple[FloatArray, IntArray]:
    v = np.asarray(vectors, dtype=np.float64)
    lab = np.asarray(labels, dtype=np.int64)
    if v.ndim != 2 or (n_features is not None and v.shape[1] != n_features):
        want = f"(m, {n_features})" if n_features is not None else "(m, n_features)"
        raise InputError(f"store: vectors must have shape {want}, got shape {v.shape}")
    if len(keys) != v.shape[0] or lab.shape != (v.shape[0],):
        raise InputError(
            f"store: {v.shape[0]} vectors need as many keys and labels, got {len(keys)} keys "
            f"and labels of shape {lab.shape}"
        )
    for k in keys:
        if not 0 <= k <= MAX_KEY:
            raise InputError(f"store: keys must be in 0..2**63 - 1, got {k}")
    return v, lab


def _check_micro(micro: ArrayLike | None, m: int) -> IntArray:
    if micro is None:
        return np.full(m, -1, dtype=np.int64)
    mic = np.asarray(micro, dtype=np.int64)
    if mic.shape != (m,):
        raise InputError(f"store: {m} samples need as many micro-cluster ids, got shape "
                         f"{mic.shape}")
    return mic


class MemoryStore:
    """Samples, keys and cluster ids in growing numpy arrays (amortised O(1) append).

    Capacity doubles when full, so appending one sample costs O(1) on average whatever the
    number already stored.
    """

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self._n = 0
        self._x: FloatArray = np.zeros((0, 0))
        self._keys: NDArray[np.int64] = np.zeros(0, dtype=np.int64)
        self._labels: IntArray = np.zeros(0, dtype=np.int64)
        self._micro: IntArray = np.zeros(0, dtype=np.int64)
        self._meta: dict[str, bytes] = {}

    @property
    def n_samples(self) -> int:
        return self._n

    @property
    def n_features(self) -> int | None:
        return self._x.shape[1] if self._n else None

    def _grow(self, need: int, d: int) -> None:
        cap = self._x.shape[0]
        if need <= cap and self._x.shape[1] == d:
            return
        new = max(need, 2 * cap, 64)
        x = np.empty((new, d))
        if self._n:
            x[: self._n] = self._x[: self._n]
        k = np.empty(new, dtype=np.int64)
        k[: self._n] = self._keys[: self._n]
        lab = np.empty(new, dtype=np.int64)
        lab[: self._n] = self._labels[: self._n]
        mic = np.empty(new, dtype=np.int64)
        mic[: self._n] = self._micro[: self._n]
        self._x, self._keys, self._labels, self._micro = x, k, lab, mic

    def add(self, vectors: FloatArray, keys: list[int], labels: IntArray,
            micro: IntArray | None = None) -> None:
        v, lab = _check_batch(vectors, keys, labels, self.n_features)
        m = v.shape[0]
        mic = _check_micro(micro, m)
        self._grow(self._n + m, v.shape[1])
        self._x[self._n : self._n + m] = v
        self._keys[self._n : self._n + m] = keys
        self._labels[self._n : self._n + m] = lab
        self._micro[self._n : self._n + m] = mic
        self._n += m

    def vectors(self, start: int, stop: int) -> FloatArray:
        return self._x[start:stop].copy()

    def update(self, start: int, keys: list[int], labels: IntArray,
               micro: IntArray | None = None) -> None:
        m = len(keys)
        self._keys[start : start + m] = keys
        self._labels[start : start + m] = labels
        if micro is not None:
            self._micro[start : start + m] = _check_micro(micro, m)

    def keys(self) -> list[int]:
        return [int(k) for k in self._keys[: self._n].tolist()]

    def labels(self) -> IntArray:
        return self._labels[: self._n].copy()

    def micro_ids(self) -> IntArray:
        return self._micro[: self._n].copy()

    def cluster(self, label: int) -> tuple[IntArray, list[int]]:
        ids = np.flatnonzero(self._labels[: self._n] == label)
        return self._sorted(ids)

    def key_range(self, low: int, high: int) -> tuple[IntArray, list[int]]:
        k = self._keys[: self._n]
        return self._sorted(np.flatnonzero((k >= low) & (k <= high)))

    def _sorted(self, ids: NDArray[np.intp]) -> tuple[IntArray, list[int]]:
        order = np.argsort(self._keys[ids], kind="stable")
        ids = ids[order]
        return ids.astype(np.int64), [int(k) for k in self._keys[ids].tolist()]

    def get_meta(self, name: str) -> bytes | None:
        return self._meta.get(name)

    def put_meta(self, name: str, value: bytes) -> None:
        self._meta[name] = bytes(value)

    @contextlib.contextmanager
    def transaction(self) -> Iterator[None]:
        # one process, no concurrent writer: the arrays change in place
        yield


_SCHEMA = """
CREATE TABLE IF NOT EXISTS samples (
    id INTEGER PRIMARY KEY,
    key INTEGER NOT NULL,
    label INTEGER NOT NULL,
    vector BLOB NOT NULL,
    micro INTEGER NOT NULL DEFAULT -1
);
CREATE INDEX IF NOT EXISTS samples_key ON samples (key);
CREATE INDEX IF NOT EXISTS samples_label_key ON samples (label, key);
CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, value BLOB NOT NULL);
"""


class SQLiteStore:
    """Samples, keys and cluster ids in an embedded SQLite database.

    Parameters
    ----------
    path : str or Path
        Database file (created if absent), or ``":memory:"``.
    timeout : float
        Seconds to wait for another process's write lock before giving up.
    synchronous : {"NORMAL", "FULL"}
        SQLite's ``synchronous`` pragma in WAL mode: ``NORMAL`` survives a killed process,
        ``FULL`` also a power loss, at the cost of an fsync per commit.
    cache_mib : int
        SQLite's page cache, in MiB.

    Notes
    -----
    Ids are SQLite rowids minus one; rows are never deleted (except by :meth:`clear`), so
    ids run ``0 .. n_samples - 1`` in the order of the commits that added them, also with
    several writing processes.
    """

    def __init__(self, path: str | Path = ":memory:", *, timeout: float = 30.0,
                 synchronous: Literal["NORMAL", "FULL"] = "NORMAL",
                 cache_mib: int = 64) -> None:
        if synchronous not in ("NORMAL", "FULL"):
            raise InputError(f"synchronous must be 'NORMAL' or 'FULL', got {synchronous!r}")
        if isinstance(cache_mib, bool) or not isinstance(cache_mib, int) or cache_mib < 1:
            raise InputError(f"cache_mib must be a positive integer, got {cache_mib!r}")
        self.path = str(path)
        self._depth = 0
        try:
            # isolation_level=None: we issue BEGIN / COMMIT ourselves (see transaction)
            self._db = sqlite3.connect(self.path, timeout=timeout, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute(f"PRAGMA synchronous={synchronous}")
            # the key indexes' pages stay in memory: a registration then touches the disk
            # (the WAL) only to write, at any size (SQLite's default cache is 2 MiB)
            self._db.execute(f"PRAGMA cache_size=-{cache_mib * 1024}")
            with self.transaction():
                for stmt in _SCHEMA.split(";"):
                    if stmt.strip():
                        self._db.execute(stmt)
                # stores written before the micro-cluster record: add its column (-1: none)
                cols = {r[1] for r in self._db.execute("PRAGMA table_info(samples)")}
                if "micro" not in cols:
                    self._db.execute(
                        "ALTER TABLE samples ADD COLUMN micro INTEGER NOT NULL DEFAULT -1")
        except sqlite3.DatabaseError as exc:
            # the user named a file that is not a store (or a folder it cannot write): bad input
            raise InputError(
                f"{self.path}: cannot open as a sample store ({exc}); give a SQLite database "
                "written by nonprehensile, or a new file name in a writable folder"
            ) from None
        self._d: int | None = None
        # sample ids run 1..n with no gap (n_samples reads MAX(id) in constant time): a row
        # deleted by another program is caught once, when the store is opened
        count, top = self._db.execute("SELECT COUNT(*), MAX(id) FROM samples").fetchone()
        if count != (top or 0):
            self._db.close()
            raise InputError(
                f"{self.path}: the store holds {count} samples but its ids run to {top}: rows "
                "were deleted outside nonprehensile; fit the store again"
            )

    def close(self) -> None:
        """Close the connection (committed data stays)."""
        self._db.close()

    def __enter__(self) -> SQLiteStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextlib.contextmanager
    def transaction(self) -> Iterator[None]:
        """Commit everything inside together; nested uses join the outer transaction.

        ``BEGIN IMMEDIATE`` takes the write lock at once, so that a read-modify-write (load
        the clusterer's state, register samples, save it) is not interleaved with another
        process's.
        """
        if self._depth:
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
            return
        try:
            self._db.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError as exc:
            raise StoreError(
                f"{self.path}: could not take the write lock ({exc}); another process holds "
                "it for too long: retry, or raise timeout"
            ) from None
        self._depth = 1
        try:
            yield
        except BaseException:
            self._depth = 0
            self._db.execute("ROLLBACK")
            raise
        self._depth = 0
        self._db.execute("COMMIT")

    def _one(self, sql: str, args: tuple[Any, ...] = ()) -> Any:
        row = self._db.execute(sql, args).fetchone()
        return None if row is None else row[0]

    @property
    def n_samples(self) -> int:
        n = self._one("SELECT MAX(id) FROM samples")
        return 0 if n is None else int(n)

    @property
    def n_features(self) -> int | None:
        if self._d is None:
            blob = self._one("SELECT vector FROM samples LIMIT 1")
            if blob is not None:
                self._d = len(blob) // 8
        return self._d

    def add(self, vectors: FloatArray, keys: list[int], labels: IntArray,
            micro: IntArray | None = None) -> None:
        v, lab = _check_batch(vectors, keys, labels, self.n_features)
        mic = _check_micro(micro, v.shape[0])
        rows = [(int(k), int(c), row.tobytes(), u) for k, c, row, u in
                zip(keys, lab.tolist(), v, mic.tolist(), strict=True)]
        # one executemany in one transaction: the batch costs one commit
        with self.transaction():
            self._db.executemany(
                "INSERT INTO samples (key, label, vector, micro) VALUES (?, ?, ?, ?)", rows)
        self._d = v.shape[1]

    def vectors(self, start: int, stop: int) -> FloatArray:
        d = self.n_features
        rows = self._db.execute(
            "SELECT vector FROM samples WHERE id > ? AND id <= ? ORDER BY id", (start, stop)
        ).fetchall()
        if not rows or d is None:
            return np.zeros((0, d or 0))
        return np.frombuffer(b"".join(r[0] for r in rows), dtype=np.float64).reshape(-1, d)

    def update(self, start: int, keys: list[int], labels: IntArray,
               micro: IntArray | None = None) -> None:
        rows: list[tuple[int, ...]]
        if micro is None:
            rows = [(int(k), int(c), start + i + 1)
                    for i, (k, c) in enumerate(zip(keys, labels.tolist(), strict=True))]
            sql = "UPDATE samples SET key = ?, label = ? WHERE id = ?"
        else:
            mic = _check_micro(micro, len(keys))
            rows = [(int(k), int(c), int(u), start + i + 1) for i, (k, c, u) in
                    enumerate(zip(keys, labels.tolist(), mic.tolist(), strict=True))]
            sql = "UPDATE samples SET key = ?, label = ?, micro = ? WHERE id = ?"
        with self.transaction():
            self._db.executemany(sql, rows)

    def keys(self) -> list[int]:
        return [r[0] for r in self._db.execute("SELECT key FROM samples ORDER BY id")]

    def labels(self) -> IntArray:
        rows = self._db.execute("SELECT label FROM samples ORDER BY id").fetchall()
        return np.array([r[0] for r in rows], dtype=np.int64)

    def micro_ids(self) -> IntArray:
        rows = self._db.execute("SELECT micro FROM samples ORDER BY id").fetchall()
        return np.array([r[0] for r in rows], dtype=np.int64)

    def _ids_keys(self, sql: str, args: tuple[Any, ...]) -> tuple[IntArray, list[int]]:
        rows = self._db.execute(sql, args).fetchall()
        return (np.array([r[0] - 1 for r in rows], dtype=np.int64), [r[1] for r in rows])

    def cluster(self, label: int) -> tuple[IntArray, list[int]]:
        # a range scan of the (label, key) index, already in key order
        return self._ids_keys(
            "SELECT id, key FROM samples WHERE label = ? ORDER BY key, id", (int(label),)
        )

    def key_range(self, low: int, high: int) -> tuple[IntArray, list[int]]:
        return self._ids_keys(
            "SELECT id, key FROM samples WHERE key BETWEEN ? AND ? ORDER BY key, id",
            (int(low), int(high)),
        )

    def get_meta(self, name: str) -> bytes | None:
        value = self._one("SELECT value FROM meta WHERE name = ?", (name,))
        return None if value is None else bytes(value)

    def put_meta(self, name: str, value: bytes) -> None:
        with self.transaction():
            self._db.execute("INSERT OR REPLACE INTO meta (name, value) VALUES (?, ?)",
                             (name, value))

    def clear(self) -> None:
        with self.transaction():
            self._db.execute("DELETE FROM samples")
            self._db.execute("DELETE FROM meta")
        self._d = None

    def integrity(self) -> str:
        """SQLite's ``PRAGMA integrity_check`` (``"ok"`` for a sound database)."""
        return str(self._one("PRAGMA integrity_check"))

    def info(self) -> dict[str, Any]:
        """Path, journal mode and counts, for the command line."""
        return {"path": self.path, "journal_mode": self._one("PRAGMA journal_mode"),
                "n_samples": self.n_samples, "n_features": self.n_features,
                "meta": [r[0] for r in self._db.execute("SELECT name FROM meta ORDER BY name")]}
