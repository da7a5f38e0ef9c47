"""Many named stores in two SQL tables: what PostgreSQL and the service's SQLite share.

:class:`TableStore` implements the reads and the small writes of
:class:`~nonprehensile.motion.store.SampleStore` in portable SQL over the layout

``np_samples (store, id, key, label, micro, vector)``
    one row a sample: ``id`` runs ``0 .. n_samples - 1`` per store, ``vector`` is the sample's
    float64 values (little-endian bytes), ``micro`` its micro-cluster id (-1: none).
``np_meta (store, name, value)``
    named blobs (the clusterer's state).

so that one database holds any number of named stores (the service keeps one per arc of a
skill graph). Its subclasses bring the connection, the bulk insert, the re-keying update and
the transaction: :class:`~nonprehensile.motion.pgstore.PostgresStore` (COPY, advisory locks)
and the service's SQLite store (:mod:`nonprehensile.service.sqlite`: one file for the whole
service, one writer at a time). Both give the same keys, ids and listings.

The SQL here uses ``%s`` placeholders (psycopg's); a connection that wants another style
overrides :meth:`TableStore._sql`. Nothing here imports a database driver.
"""

from __future__ import annotations

import abc
import contextlib
from collections.abc import Iterator
from typing import Any, Protocol

import numpy as np

from nonprehensile.errors import InputError
from nonprehensile.motion.store import FloatArray, IntArray, _check_batch, _check_micro

__all__ = ["Nesting", "TableStore", "check_store_name"]


class _Connection(Protocol):
    def execute(self, query: Any, params: Any = ..., /) -> Any: ...


def check_store_name(name: object) -> str:
    """A store's name: a non-empty string of at most 200 characters."""
    if not isinstance(name, str) or not name or len(name) > 200:
        raise InputError(f"store name must be a non-empty string of at most 200 "
                         f"characters, got {name!r}")
    return name


class Nesting:
    """Transactions that nested uses join: ``if self._depth: with self._joined(): ...``."""

    _depth: int = 0

    @contextlib.contextmanager
    def _joined(self) -> Iterator[None]:
        """Inside the open transaction: the outermost one commits (or rolls back) it all."""
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1


class TableStore(Nesting, abc.ABC):
    """The portable part of a store of samples, keys and cluster ids in ``np_samples`` and
    ``np_meta`` (see the module notes). Subclasses set ``name``, ``url``, ``_conn`` and
    ``_d`` and implement ``_insert``, ``_rekey`` and ``transaction``."""

    name: str
    url: str
    _d: int | None
    #: Version of the tables' layout written in ``np_schema``.
    schema_version: int = 2

    def _sql(self, sql: str) -> str:
        """The statement in the connection's placeholder style (``%s`` here)."""
        return sql

    def _execute(self, sql: str, args: tuple[Any, ...] = ()) -> Any:
        conn: _Connection = self._conn  # type: ignore[attr-defined]
        return conn.execute(self._sql(sql), args)

    def _one(self, sql: str, args: tuple[Any, ...]) -> Any:
        row = self._execute(sql, args).fetchone()
        return None if row is None else row[0]

    @abc.abstractmethod
    def transaction(self) -> contextlib.AbstractContextManager[None]:
        """Commit everything inside together (the subclass's locking)."""

    @abc.abstractmethod
    def _insert(self, rows: list[tuple[Any, ...]]) -> None:
        """Insert rows ``(store, id, key, label, micro, vector)`` (the subclass's bulk load)."""

    @abc.abstractmethod
    def _rekey(self, start: int, keys: list[int], labels: list[int],
               micro: list[int] | None) -> None:
        """Set keys, labels (and micro-cluster ids) of samples ``start, start + 1, ...`` (the
        subclass's batched update)."""

    # ------------------------------------------------------------------ writes

    def add(self, vectors: FloatArray, keys: list[int], labels: IntArray,
            micro: IntArray | None = None) -> None:
        v, lab = _check_batch(vectors, keys, labels, self.n_features)
        mic = _check_micro(micro, v.shape[0])
        le = np.ascontiguousarray(v, dtype="<f8")
        with self.transaction():
            n0 = self.n_samples
            self._insert([(self.name, n0 + i, int(k), int(c), int(u), le[i].tobytes())
                          for i, (k, c, u) in enumerate(zip(keys, lab.tolist(), mic.tolist(),
                                                            strict=True))])
        self._d = v.shape[1]

    def update(self, start: int, keys: list[int], labels: IntArray,
               micro: IntArray | None = None) -> None:
        lab = [int(c) for c in np.asarray(labels).tolist()]
        if len(lab) != len(keys):
            raise InputError(f"store: {len(keys)} keys need as many labels, got {len(lab)}")
        mic = None if micro is None else _check_micro(micro, len(keys)).tolist()
        with self.transaction():
            self._rekey(int(start), [int(k) for k in keys], lab, mic)

    # ------------------------------------------------------------------ reads

    def _count_and_top(self) -> tuple[int, int | None]:
        row = self._execute("SELECT count(*), max(id) FROM np_samples WHERE store = %s",
                            (self.name,)).fetchone()
        return (0, None) if row is None else (int(row[0]), row[1])

    def _check_ids(self) -> None:
        """Rows deleted behind the store's back (a gap in the ids) are refused on opening."""
        count, top = self._count_and_top()
        if count != (-1 if top is None else top) + 1:
            raise InputError(
                f"{self.url}: store {self.name!r} holds {count} samples but its ids run to "
                f"{top}: rows were deleted outside nonprehensile; fit the store again"
            )

    @property
    def n_samples(self) -> int:
        top = self._one("SELECT max(id) FROM np_samples WHERE store = %s", (self.name,))
        return 0 if top is None else int(top) + 1

    @property
    def n_features(self) -> int | None:
        if self._d is None:
            blob = self._one("SELECT vector FROM np_samples WHERE store = %s AND id = 0",
                             (self.name,))
            if blob is not None:
                self._d = len(blob) // 8
        return self._d

    def vectors(self, start: int, stop: int) -> FloatArray:
        d = self.n_features
        rows = self._execute(
            "SELECT vector FROM np_samples WHERE store = %s AND id >= %s AND id < %s "
            "ORDER BY id", (self.name, int(start), int(stop))
        ).fetchall()
        if not rows or d is None:
            return np.zeros((0, d or 0))
        return np.frombuffer(b"".join(bytes(r[0]) for r in rows), dtype="<f8").reshape(-1, d)

    def _column(self, column: str) -> list[Any]:
        rows = self._execute(f"SELECT {column} FROM np_samples WHERE store = %s ORDER BY id",
                             (self.name,)).fetchall()
        return [r[0] for r in rows]

    def keys(self) -> list[int]:
        return [int(k) for k in self._column("key")]

    def labels(self) -> IntArray:
        return np.array(self._column("label"), dtype=np.int64)

    def micro_ids(self) -> IntArray:
        """Micro-cluster ids of all samples, shape (n_samples,), in the order added."""
        return np.array(self._column("micro"), dtype=np.int64)

    def _ids_keys(self, sql: str, args: tuple[Any, ...]) -> tuple[IntArray, list[int]]:
        rows = self._execute(sql, args).fetchall()
        return np.array([r[0] for r in rows], dtype=np.int64), [int(r[1]) for r in rows]

    def cluster(self, label: int) -> tuple[IntArray, list[int]]:
        # a range scan of the (store, label, key, id) index, already in key order
        return self._ids_keys(
            "SELECT id, key FROM np_samples WHERE store = %s AND label = %s ORDER BY key, id",
            (self.name, int(label)),
        )

    def key_range(self, low: int, high: int) -> tuple[IntArray, list[int]]:
        return self._ids_keys(
            "SELECT id, key FROM np_samples WHERE store = %s AND key BETWEEN %s AND %s "
            "ORDER BY key, id", (self.name, int(low), int(high)),
        )

    def get_meta(self, name: str) -> bytes | None:
        value = self._one("SELECT value FROM np_meta WHERE store = %s AND name = %s",
                          (self.name, name))
        return None if value is None else bytes(value)

    # ------------------------------------------------------------------ small writes

    def put_meta(self, name: str, value: bytes) -> None:
        with self.transaction():
            self._execute(
                "INSERT INTO np_meta (store, name, value) VALUES (%s, %s, %s) "
                "ON CONFLICT (store, name) DO UPDATE SET value = EXCLUDED.value",
                (self.name, name, bytes(value)),
            )

    def clear(self) -> None:
        with self.transaction():
            self._execute("DELETE FROM np_samples WHERE store = %s", (self.name,))
            self._execute("DELETE FROM np_meta WHERE store = %s", (self.name,))
        self._d = None

    # ------------------------------------------------------------------ inspection

    def info(self) -> dict[str, Any]:
        """URL or path (without password), store name and counts, for the command line."""
        names = self._execute(
            "SELECT name FROM np_meta WHERE store = %s ORDER BY name", (self.name,)
        ).fetchall()
        return {"path": self.url, "store": self.name, "n_samples": self.n_samples,
                "n_features": self.n_features, "schema_version": self.schema_version,
                "meta": [r[0] for r in names]}

    def stores(self) -> list[str]:
        """Names of every store in the database that holds samples or blobs."""
        rows = self._execute(
            "SELECT DISTINCT store FROM np_meta UNION SELECT DISTINCT store FROM np_samples "
            "ORDER BY 1"
        ).fetchall()
        return [r[0] for r in rows]
