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
import math
import random
import sqlite3
import struct
import time
import urllib.parse
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nonprehensile.bounds import check_path
from nonprehensile.errors import InputError, NonprehensileError, StoreError

__all__ = ["MemoryStore", "SQLiteStore", "SampleStore", "StoreError", "StoreFileError"]

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

        This is the batched registration path: ``HilbertClusterer.partial_fit(X)`` calls it
        once per batch (once per stretch between two calibrations), inside one
        :meth:`transaction`, with every row of the stretch. An implementation should write
        the rows with one statement (SQLite: one ``executemany``; PostgreSQL: one ``COPY``)
        and never commit per row: the per-row cost then sets the batched rate (issue 14's
        bar: 20 000 samples a second into SQLite).
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
    if v.ndim != 2 or v.shape[1] == 0 or (n_features is not None
                                           and v.shape[1] != n_features):
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


#: Bytes of one block of :class:`MemoryStore` rows: appending never copies more than this.
_BLOCK_BYTES = 1 << 20


class _Blocks:
    """Rows of ``width`` values of one dtype in blocks of ``rows`` rows: an append copies at
    most one block.

    A single growing array would double when full and copy everything stored (256 MB at a
    million 32-feature samples): a registration then pays hundreds of milliseconds. Blocks
    of ``rows`` rows are allocated as needed; only the last one grows (by doubling, up to
    ``rows``), so an append costs O(1) in the worst case, not only on average.
    """

    def __init__(self, width: int, dtype: type, rows: int) -> None:
        self.width, self.dtype, self.rows = width, dtype, rows
        self.blocks: list[NDArray[Any]] = []
        self.n = 0

    def _shape(self, m: int) -> tuple[int, int]:
        return (m, self.width)

    def append(self, values: NDArray[Any]) -> None:
        m, done = values.shape[0], 0
        if self.blocks:  # room in the last block (nearly always for one registration)
            used = self.n - self.rows * (len(self.blocks) - 1)
            last = self.blocks[-1]
            if used + m <= last.shape[0]:
                last[used : used + m] = values
                self.n += m
                return
        while done < m:
            full = self.rows * (len(self.blocks) - 1) if self.blocks else 0
            used = self.n - full
            if not self.blocks or used == self.rows:
                self.blocks.append(np.empty(self._shape(min(self.rows, max(64, m - done))),
                                            dtype=self.dtype))
                used = 0
            last = self.blocks[-1]
            if used == last.shape[0]:  # the last block is short: double it (at most a block)
                grown: NDArray[Any] = np.empty(self._shape(min(self.rows, 2 * used)),
                                               dtype=self.dtype)
                grown[:used] = last[:used]
                self.blocks[-1] = last = grown
            take = min(m - done, last.shape[0] - used)
            last[used : used + take] = values[done : done + take]
            done += take
            self.n += take

    def _parts(self, start: int, stop: int) -> Iterator[tuple[int, int, int]]:
        """(block, first row in it, end row in it) covering rows ``start..stop-1``."""
        stop = min(stop, self.n)
        while start < stop:
            b, r = divmod(start, self.rows)
            e = min(self.rows, r + stop - start)
            yield b, r, e
            start += e - r

    def get(self, start: int, stop: int) -> NDArray[Any]:
        parts = [self.blocks[b][r:e] for b, r, e in self._parts(start, stop)]
        if not parts:
            return np.empty(self._shape(0), dtype=self.dtype)
        return np.concatenate(parts) if len(parts) > 1 else parts[0].copy()

    def set(self, start: int, values: NDArray[Any]) -> None:
        done = 0
        for b, r, e in self._parts(start, start + values.shape[0]):
            self.blocks[b][r:e] = values[done : done + e - r]
            done += e - r


class MemoryStore:
    """Samples, keys and cluster ids in numpy arrays, kept in fixed-size blocks.

    Appending one sample costs O(1) in the worst case whatever the number already stored:
    blocks of about 1 MiB are added as needed, and nothing stored is ever copied whole.
    """

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self._n = 0
        self._x = _Blocks(0, np.float64, 1)
        # key, label as registered, micro-cluster id: one int64 row per sample
        self._ints = _Blocks(3, np.int64, max(1, _BLOCK_BYTES // 24))
        self._meta: dict[str, bytes] = {}

    @property
    def n_samples(self) -> int:
        return self._n

    @property
    def n_features(self) -> int | None:
        return self._x.width if self._n else None

    def add(self, vectors: FloatArray, keys: list[int], labels: IntArray,
            micro: IntArray | None = None) -> None:
        v, lab = _check_batch(vectors, keys, labels, self.n_features)
        m = v.shape[0]
        mic = _check_micro(micro, m)
        if not self._n:
            d = v.shape[1]
            self._x = _Blocks(d, np.float64, max(1, _BLOCK_BYTES // (8 * max(d, 1))))
        ints = np.empty((m, 3), dtype=np.int64)
        ints[:, 0] = keys
        ints[:, 1] = lab
        ints[:, 2] = mic
        self._x.append(v)
        self._ints.append(ints)
        self._n += m

    def vectors(self, start: int, stop: int) -> FloatArray:
        return self._x.get(start, stop)

    def update(self, start: int, keys: list[int], labels: IntArray,
               micro: IntArray | None = None) -> None:
        m = len(keys)
        ints = self._ints.get(start, start + m)
        ints[:, 0] = keys
        ints[:, 1] = labels
        if micro is not None:
            ints[:, 2] = _check_micro(micro, m)
        self._ints.set(start, ints)

    def _column(self, j: int) -> IntArray:
        return np.ascontiguousarray(self._ints.get(0, self._n)[:, j])

    def keys(self) -> list[int]:
        return [int(k) for k in self._column(0).tolist()]

    def labels(self) -> IntArray:
        return self._column(1)

    def micro_ids(self) -> IntArray:
        return self._column(2)

    def cluster(self, label: int) -> tuple[IntArray, list[int]]:
        ints = self._ints.get(0, self._n)
        return self._sorted(ints[:, 0], np.flatnonzero(ints[:, 1] == label))

    def key_range(self, low: int, high: int) -> tuple[IntArray, list[int]]:
        k = self._column(0)
        return self._sorted(k, np.flatnonzero((k >= low) & (k <= high)))

    @staticmethod
    def _sorted(keys: IntArray, ids: NDArray[np.intp]) -> tuple[IntArray, list[int]]:
        ids = ids[np.argsort(keys[ids], kind="stable")]
        return ids.astype(np.int64), [int(k) for k in keys[ids].tolist()]

    def get_meta(self, name: str) -> bytes | None:
        return self._meta.get(name)

    def put_meta(self, name: str, value: bytes) -> None:
        self._meta[name] = bytes(value)

    def transaction(self) -> contextlib.AbstractContextManager[None]:
        # one process, no concurrent writer: the arrays change in place
        return contextlib.nullcontext()


_SCHEMA = """
CREATE TABLE IF NOT EXISTS samples (
    id INTEGER PRIMARY KEY,
    key INTEGER NOT NULL,
    label INTEGER NOT NULL,
    vector BLOB NOT NULL,
    micro INTEGER NOT NULL DEFAULT -1,
    crc INTEGER,
    kcrc INTEGER
);
CREATE INDEX IF NOT EXISTS samples_key ON samples (key);
CREATE INDEX IF NOT EXISTS samples_label_key ON samples (label, key);
CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, value BLOB NOT NULL, crc INTEGER);
"""

#: Longest wait for the write lock, seconds, before a transaction gives up: writers take
#: turns, and a turn is one registration, so this is generous.
DEFAULT_LOCK_WAIT = 3600.0


def _crc(blob: bytes) -> int:
    """The checksum stored with each vector and blob (CRC-32, as zlib computes it)."""
    return zlib.crc32(blob)


def _kcrc(key: int, label: int) -> int:
    """The checksum of a sample's key and cluster id (they change at a recalibration, the
    vector never does, so each has its own)."""
    return zlib.crc32(struct.pack("<qq", key, label))


class StoreFileError(StoreError, InputError):
    """The store file is damaged, read-only, or its disk is full; the message names the file.

    Nothing half-written is committed: SQLite rolls the transaction back.
    """


def _end_transaction(db: sqlite3.Connection, path: str, ok: bool) -> None:
    """COMMIT (``ok``) or ROLLBACK an explicit transaction of ``db``; a failed COMMIT (a full
    disk) is rolled back, leaving the file as it was before the transaction, and raised as one
    line naming ``path``."""
    if ok:
        try:
            db.execute("COMMIT")
            return
        except sqlite3.Error as exc:
            with contextlib.suppress(sqlite3.Error):
                db.execute("ROLLBACK")
            raise _explain(path, exc) from None
    with contextlib.suppress(sqlite3.Error):
        db.execute("ROLLBACK")


def _explain(path: str, exc: sqlite3.Error) -> NonprehensileError:
    """One line for a SQLite error, naming the store file and what to do."""
    text = str(exc)
    low = text.lower()
    if "locked" in low or "busy" in low:
        return StoreError(f"{path}: the store is locked by another process ({text}); retry")
    if "full" in low or "too big" in low:
        return StoreFileError(
            f"{path}: the disk is full ({text}); nothing of this change was written and the "
            "store is intact: free some space and run the command again"
        )
    if "readonly" in low or "read-only" in low:
        return StoreFileError(
            f"{path}: the store is read-only ({text}); commands that change it need write "
            "access to the file and its folder (`cluster show` only reads)"
        )
    damaged = not isinstance(exc, sqlite3.OperationalError)
    if damaged or any(w in low for w in ("malformed", "not a database", "corrupt")):
        return StoreFileError(
            f"{path}: the store file is damaged ({text}); restore it from a copy or fit it "
            "again"
        )
    return StoreFileError(f"{path}: the store cannot be used ({text})")


class SQLiteStore:
    """Samples, keys and cluster ids in an embedded SQLite database.

    Parameters
    ----------
    path : str or Path
        Database file (created if absent, unless ``readonly``), or ``":memory:"``.
    timeout : float
        Seconds SQLite waits for a lock in one attempt (its busy timeout).
    synchronous : {"NORMAL", "FULL"}
        SQLite's ``synchronous`` pragma in WAL mode: ``NORMAL`` survives a killed process,
        ``FULL`` also a power loss, at the cost of an fsync per commit.
    cache_mib : int
        SQLite's page cache, in MiB.
    readonly : bool
        Open an existing store for reading only: no lock is taken, and a store on a read-only
        file system (or a read-only file) can be read.
    check : bool
        Run SQLite's ``PRAGMA quick_check`` on opening an existing store, so that a damaged
        file is reported before anything is read from it.
    lock_wait : float
        Longest total wait, seconds, for the write lock: a transaction retries ``BEGIN
        IMMEDIATE`` with growing pauses until it gets the lock (writers take turns).

    Notes
    -----
    Ids are SQLite rowids minus one; rows are never deleted (except by :meth:`clear`), so
    ids run ``0 .. n_samples - 1`` in the order of the commits that added them, also with
    several writing processes. Each vector, each (key, cluster id) pair and each named blob
    is stored with its CRC-32, checked whenever it is read: a damaged page that SQLite does
    not notice is still reported, never returned as data. Every SQLite error becomes a
    :class:`StoreFileError` (damaged file, full disk, read-only file) or a
    :class:`StoreError` (lock) naming the file.
    """

    def __init__(self, path: str | Path = ":memory:", *, timeout: float = 30.0,
                 synchronous: Literal["NORMAL", "FULL"] = "NORMAL",
                 cache_mib: int = 64, readonly: bool = False, check: bool = True,
                 lock_wait: float = DEFAULT_LOCK_WAIT) -> None:
        if synchronous not in ("NORMAL", "FULL"):
            raise InputError(f"synchronous must be 'NORMAL' or 'FULL', got {synchronous!r}")
        if isinstance(cache_mib, bool) or not isinstance(cache_mib, int) or cache_mib < 1:
            raise InputError(f"cache_mib must be a positive integer, got {cache_mib!r}")
        for name, value in (("timeout", timeout), ("lock_wait", lock_wait)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) and value >= 0):
                raise InputError(f"{name} must be a number of seconds >= 0, got {value!r}")
        self.path = str(path)
        if self.path != ":memory:":
            check_path(self.path, "store")
        self.readonly = readonly
        self._timeout = float(timeout)
        self._lock_wait = float(lock_wait)
        self._depth = 0
        self._d: int | None = None
        existed = self.path != ":memory:" and Path(self.path).exists()
        if self.path != ":memory:" and Path(self.path).is_dir():
            raise InputError(f"{self.path}: is a folder; give the store's file name")
        if readonly and not existed:
            raise InputError(f"{self.path}: no such store; create it with `nonprehensile "
                             "cluster fit`")
        try:
            self._db = self._connect(synchronous, cache_mib)
        except (sqlite3.Error, UnicodeDecodeError) as exc:
            # (SQLite's message about a damaged schema may itself be invalid UTF-8)
            # the user named a file that is not a store (or a folder it cannot write): bad input
            raise StoreFileError(
                f"{self.path}: cannot open as a sample store ({exc}); give a SQLite database "
                "written by nonprehensile, or a new file name in a writable folder"
            ) from None
        try:
            if existed and check:
                self._quick_check()
            if existed and self._row(
                    "SELECT COUNT(*) FROM sqlite_master WHERE name = 'np_samples'")[0]:
                # the service's own database: `cluster` would add its tables beside the
                # service's and the two would then disagree about the samples
                raise StoreFileError(
                    f"{self.path}: is a `nonprehensile serve` database, not a cluster store; "
                    "give `cluster` another file, or read the service's clusters by GET "
                    "/clusters"
                )
            if not readonly:
                self._migrate()
            # sample ids run 1..n with no gap (n_samples reads MAX(id) in constant time): a
            # row deleted by another program is caught once, when the store is opened
            count, top = self._row("SELECT COUNT(*), MAX(id) FROM samples")
        except BaseException:
            self._db.close()
            raise
        if count != (top or 0):
            self._db.close()
            raise StoreFileError(
                f"{self.path}: the store holds {count} samples but its ids run to {top}: rows "
                "were deleted outside nonprehensile; fit the store again"
            )

    def _connect(self, synchronous: str, cache_mib: int) -> sqlite3.Connection:
        db = self._open(synchronous, cache_mib)
        # text a damaged file holds must not raise UnicodeDecodeError deep in a query
        db.text_factory = lambda b: b.decode("utf-8", "replace")
        return db

    def _open(self, synchronous: str, cache_mib: int) -> sqlite3.Connection:
        if self.readonly:
            uri = "file:" + urllib.parse.quote(str(Path(self.path).resolve()))
            try:
                db = sqlite3.connect(uri + "?mode=ro", uri=True, timeout=self._timeout,
                                     isolation_level=None)
                db.execute("SELECT COUNT(*) FROM sqlite_master WHERE 0").fetchone()
            except sqlite3.OperationalError:
                # a WAL store on a read-only file system: SQLite cannot make its shared-memory
                # file there; nobody can write the file either, so read it as immutable
                db = sqlite3.connect(uri + "?mode=ro&immutable=1", uri=True,
                                     timeout=self._timeout, isolation_level=None)
            db.execute(f"PRAGMA cache_size=-{cache_mib * 1024}")
            return db
        # isolation_level=None: we issue BEGIN / COMMIT ourselves (see transaction)
        db = sqlite3.connect(self.path, timeout=self._timeout, isolation_level=None)
        try:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute(f"PRAGMA synchronous={synchronous}")
            # the key indexes' pages stay in memory: a registration then touches the disk
            # (the WAL) only to write, at any size (SQLite's default cache is 2 MiB)
            db.execute(f"PRAGMA cache_size=-{cache_mib * 1024}")
        except BaseException:
            db.close()
            raise
        return db

    def _quick_check(self) -> None:
        result = self._rows("PRAGMA quick_check")
        # one problem per line; SQLite heads them "*** in database main ***"
        problems = [line.strip() for r in result if r[0] != "ok"
                    for line in str(r[0]).splitlines()
                    if line.strip() and not line.startswith("***")]
        if problems:
            more = f" (and {len(problems) - 1} more problems)" if len(problems) > 1 else ""
            raise StoreFileError(
                f"{self.path}: the store file is damaged (SQLite's integrity check: "
                f"{problems[0]}{more}); restore it from a copy or fit it again"
            )

    def _migrate(self) -> None:
        """Create the tables; give a store written before checksums its checksums."""
        with self.transaction():
            for stmt in _SCHEMA.split(";"):
                if stmt.strip():
                    self._exec(stmt)
            for table, col in (("samples", "crc"), ("samples", "kcrc"), ("meta", "crc")):
                cols = [r[1] for r in self._rows(f"PRAGMA table_info({table})")]
                if col not in cols:
                    self._exec(f"ALTER TABLE {table} ADD COLUMN {col} INTEGER")
            # stores written before the micro-cluster record: add its column (-1: none)
            cols = [r[1] for r in self._rows("PRAGMA table_info(samples)")]
            if "micro" not in cols:
                self._exec("ALTER TABLE samples ADD COLUMN micro INTEGER NOT NULL DEFAULT -1")
            self._db.create_function("np_crc", 1, lambda b: _crc(bytes(b)), deterministic=True)
            self._db.create_function("np_kcrc", 2, _kcrc, deterministic=True)
            self._exec("UPDATE samples SET crc = np_crc(vector) WHERE crc IS NULL")
            self._exec("UPDATE samples SET kcrc = np_kcrc(key, label) WHERE kcrc IS NULL")
            self._exec("UPDATE meta SET crc = np_crc(value) WHERE crc IS NULL")

    # ------------------------------------------------------------------ SQLite, with errors
    @contextlib.contextmanager
    def _errors(self) -> Iterator[None]:
        try:
            yield
        except sqlite3.Error as exc:
            raise _explain(self.path, exc) from None
        except UnicodeDecodeError as exc:  # a damaged schema, or SQLite's message about it
            raise StoreFileError(f"{self.path}: the store file is damaged ({exc}); restore it "
                                 "from a copy or fit it again") from None

    def _exec(self, sql: str, args: Any = ()) -> None:
        with self._errors():
            self._db.execute(sql, args)

    def _rows(self, sql: str, args: tuple[Any, ...] = ()) -> list[Any]:
        with self._errors():
            return self._db.execute(sql, args).fetchall()

    def _row(self, sql: str, args: tuple[Any, ...] = ()) -> Any:
        with self._errors():
            return self._db.execute(sql, args).fetchone()

    def _one(self, sql: str, args: tuple[Any, ...] = ()) -> Any:
        row = self._row(sql, args)
        return None if row is None else row[0]

    def close(self) -> None:
        """Close the connection (committed data stays)."""
        self._db.close()

    def __enter__(self) -> SQLiteStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _begin(self) -> None:
        """``BEGIN IMMEDIATE``, retried with growing, jittered pauses until ``lock_wait``."""
        deadline = time.monotonic() + self._lock_wait
        pause = 0.05
        while True:
            try:
                self._db.execute("BEGIN IMMEDIATE")
                return
            except sqlite3.OperationalError as exc:
                low = str(exc).lower()
                if "locked" not in low and "busy" not in low:
                    raise _explain(self.path, exc) from None
                if time.monotonic() >= deadline:
                    raise StoreError(
                        f"{self.path}: could not take the write lock in {self._lock_wait:g} s "
                        f"({exc}); another process holds it for too long: retry, or raise "
                        "lock_wait"
                    ) from None
            # jitter: waiting writers do not retry in lock step
            time.sleep(min(pause * (0.5 + random.random()), max(0.0, deadline - time.monotonic())))
            pause = min(pause * 2, 1.0)

    @contextlib.contextmanager
    def transaction(self) -> Iterator[None]:
        """Commit everything inside together; nested uses join the outer transaction.

        ``BEGIN IMMEDIATE`` takes the write lock at once, so that a read-modify-write (load
        the clusterer's state, register samples, save it) is not interleaved with another
        process's; a writer that finds the lock taken waits its turn (see ``lock_wait``).
        """
        if self.readonly:
            raise StoreFileError(f"{self.path}: the store was opened read-only; it cannot be "
                                 "changed")
        if self._depth:
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
            return
        self._begin()
        self._depth = 1
        try:
            yield
        except BaseException:
            self._depth = 0
            _end_transaction(self._db, self.path, ok=False)
            raise
        self._depth = 0
        _end_transaction(self._db, self.path, ok=True)

    @property
    def n_samples(self) -> int:
        n = self._one("SELECT MAX(id) FROM samples")
        return 0 if n is None else int(n)

    @property
    def n_features(self) -> int | None:
        if self._d is None:
            blob = self._one("SELECT vector FROM samples ORDER BY id LIMIT 1")
            if blob is not None:
                if len(blob) % 8 or not blob:
                    raise StoreFileError(
                        f"{self.path}: sample 0: its stored vector has {len(blob)} bytes, not "
                        "a whole number of float64 values; the store is damaged: fit it again"
                    )
                self._d = len(blob) // 8
        return self._d

    def add(self, vectors: FloatArray, keys: list[int], labels: IntArray,
            micro: IntArray | None = None) -> None:
        v, lab = _check_batch(vectors, keys, labels, self.n_features)
        m = v.shape[0]
        mic = _check_micro(micro, m)
        # the batch's bytes built at once, then cut per row: each vector's blob, and each
        # (key, label) pair as _kcrc packs it (two little-endian int64), for the checksums
        width = 8 * v.shape[1]
        raw = np.ascontiguousarray(v, dtype=np.float64).tobytes()
        kc = np.empty((m, 2), dtype="<i8")
        kc[:, 0] = keys
        kc[:, 1] = lab
        kc_raw = kc.tobytes()
        blobs = [raw[i : i + width] for i in range(0, m * width, width)]
        pairs = [kc_raw[i : i + 16] for i in range(0, 16 * m, 16)]
        rows = list(zip(kc[:, 0].tolist(), kc[:, 1].tolist(), blobs, mic.tolist(),
                        map(_crc, blobs), map(_crc, pairs), strict=True))
        # one executemany in one transaction: the batch costs one commit
        with self.transaction(), self._errors():
            self._db.executemany(
                "INSERT INTO samples (key, label, vector, micro, crc, kcrc) "
                "VALUES (?, ?, ?, ?, ?, ?)", rows)
        self._d = v.shape[1]

    def vectors(self, start: int, stop: int) -> FloatArray:
        d = self.n_features
        rows = self._rows(
            "SELECT id, vector, crc FROM samples WHERE id > ? AND id <= ? ORDER BY id",
            (start, stop),
        )
        if not rows or d is None:
            return np.zeros((0, d or 0))
        for i, blob, crc in rows:
            if len(blob) != 8 * d or (crc is not None and _crc(blob) != crc):
                what = (f"has {len(blob)} bytes for {d} features" if len(blob) != 8 * d
                        else "does not match its checksum")
                raise StoreFileError(
                    f"{self.path}: sample {i - 1}: its stored vector {what}; the store is "
                    "damaged: restore it from a copy or fit it again"
                )
        return np.frombuffer(b"".join(r[1] for r in rows), dtype=np.float64).reshape(-1, d)

    def update(self, start: int, keys: list[int], labels: IntArray,
               micro: IntArray | None = None) -> None:
        rows: list[tuple[int, ...]]
        if micro is None:
            rows = [(int(k), int(c), _kcrc(int(k), int(c)), start + i + 1)
                    for i, (k, c) in enumerate(zip(keys, labels.tolist(), strict=True))]
            sql = "UPDATE samples SET key = ?, label = ?, kcrc = ? WHERE id = ?"
        else:
            mic = _check_micro(micro, len(keys))
            rows = [(int(k), int(c), _kcrc(int(k), int(c)), int(u), start + i + 1)
                    for i, (k, c, u) in
                    enumerate(zip(keys, labels.tolist(), mic.tolist(), strict=True))]
            sql = "UPDATE samples SET key = ?, label = ?, kcrc = ?, micro = ? WHERE id = ?"
        with self.transaction(), self._errors():
            self._db.executemany(sql, rows)

    def _checked(self, sql: str, args: tuple[Any, ...] = ()) -> list[Any]:
        """Rows ``(id, key, label, kcrc)``, each checked against its checksum."""
        rows = self._rows(sql, args)
        for i, k, c, kc in rows:
            if kc is not None and _kcrc(k, c) != kc:
                raise StoreFileError(
                    f"{self.path}: sample {i - 1}: its stored key and cluster id do not match "
                    "their checksum; the store is damaged: restore it from a copy or fit it "
                    "again"
                )
        return rows

    def keys(self) -> list[int]:
        return [r[1] for r in self._checked(
            "SELECT id, key, label, kcrc FROM samples ORDER BY id")]

    def labels(self) -> IntArray:
        rows = self._checked("SELECT id, key, label, kcrc FROM samples ORDER BY id")
        return np.array([r[2] for r in rows], dtype=np.int64)

    def micro_ids(self) -> IntArray:
        rows = self._rows("SELECT micro FROM samples ORDER BY id")
        return np.array([r[0] for r in rows], dtype=np.int64)

    def _ids_keys(self, sql: str, args: tuple[Any, ...]) -> tuple[IntArray, list[int]]:
        rows = self._checked(sql, args)
        return (np.array([r[0] - 1 for r in rows], dtype=np.int64), [r[1] for r in rows])

    def cluster(self, label: int) -> tuple[IntArray, list[int]]:
        # a range scan of the (label, key) index, already in key order
        return self._ids_keys(
            "SELECT id, key, label, kcrc FROM samples WHERE label = ? ORDER BY key, id",
            (int(label),),
        )

    def key_range(self, low: int, high: int) -> tuple[IntArray, list[int]]:
        return self._ids_keys(
            "SELECT id, key, label, kcrc FROM samples WHERE key BETWEEN ? AND ? "
            "ORDER BY key, id",
            (int(low), int(high)),
        )

    def get_meta(self, name: str) -> bytes | None:
        row = self._row("SELECT value, crc FROM meta WHERE name = ?", (name,))
        if row is None:
            return None
        value = bytes(row[0])
        if row[1] is not None and _crc(value) != row[1]:
            raise StoreFileError(
                f"{self.path}: the stored {name!r} does not match its checksum; the store is "
                "damaged: restore it from a copy or fit it again"
            )
        return value

    def put_meta(self, name: str, value: bytes) -> None:
        blob = bytes(value)
        with self.transaction():
            self._exec("INSERT OR REPLACE INTO meta (name, value, crc) VALUES (?, ?, ?)",
                       (name, blob, _crc(blob)))

    def clear(self) -> None:
        with self.transaction():
            self._exec("DELETE FROM samples")
            self._exec("DELETE FROM meta")
        self._d = None

    def integrity(self) -> str:
        """SQLite's ``PRAGMA integrity_check`` (``"ok"`` for a sound database)."""
        return str(self._one("PRAGMA integrity_check"))

    def verify(self) -> int:
        """Check every stored vector and blob against its checksum (a full read).

        Returns
        -------
        int
            The number of samples checked.

        Raises
        ------
        StoreFileError
            Naming the first damaged sample or blob.
        """
        n = self.n_samples
        for s in range(0, n, 4096):
            self.vectors(s, min(n, s + 4096))
        self.labels()
        for (name,) in self._rows("SELECT name FROM meta"):
            self.get_meta(name)
        return n

    def info(self) -> dict[str, Any]:
        """Path, journal mode and counts, for the command line."""
        return {"path": self.path, "journal_mode": self._one("PRAGMA journal_mode"),
                "n_samples": self.n_samples, "n_features": self.n_features,
                "meta": [r[0] for r in self._rows("SELECT name FROM meta ORDER BY name")]}
