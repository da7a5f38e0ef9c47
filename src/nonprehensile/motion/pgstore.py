"""Samples, keys and cluster ids in PostgreSQL: the server twin of :class:`SQLiteStore`.

A :class:`PostgresStore` implements :class:`~nonprehensile.motion.store.SampleStore` on a
PostgreSQL database (psycopg 3), so that many processes and machines feed one archive. One
database holds any number of named stores (the service keeps one per arc of a skill graph),
in three tables created on first use:

``np_schema``
    the schema version (:data:`SCHEMA_VERSION`); a newer one is refused, not misread.
``np_samples (store, id, key, label, vector)``
    one row a sample: ``id`` runs ``0 .. n_samples - 1`` per store, ``vector`` is the sample's
    float64 values (little-endian bytes). Indexes ``(store, key, id)`` for key range scans and
    ``(store, label, key, id)`` for reading one cluster in key order.
``np_meta (store, name, value)``
    named blobs (the clusterer's state).

Bulk loads use ``COPY ... FROM STDIN (FORMAT BINARY)``; re-keying after a recalibration
updates keys and labels in batches of :data:`UPDATE_BATCH` rows (``UPDATE ... FROM unnest``)
inside the caller's transaction. A transaction takes the store's advisory lock (as SQLite's
``BEGIN IMMEDIATE`` takes the write lock): a read-modify-write of the clusterer's state is
never interleaved with another writer's, and readers are never blocked (MVCC).

Keys are signed 64-bit integers (``bigint``), as in SQLite.
"""

from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Iterator
from typing import Any

import psycopg
from psycopg import errors as pg_errors, pq

from nonprehensile.errors import InputError, LockTimeout, StoreError
from nonprehensile.motion.stores import display_name, is_postgres_url
from nonprehensile.motion.tablestore import TableStore, check_store_name

__all__ = ["SCHEMA_VERSION", "UPDATE_BATCH", "PostgresStore", "is_postgres_url"]

#: Version of the tables' layout; a database written by a newer layout is refused, an older
#: one is migrated (2: the micro-cluster id column; 3: no insert-triggered vacuum of the
#: vectors' TOAST table).
SCHEMA_VERSION = 3
#: Rows per UPDATE statement when keys and labels are rewritten (a recalibration).
UPDATE_BATCH = 10_000
#: Advisory lock that serialises creating the tables (any constant, ours).
_DDL_LOCK = 0x6E6F6E70  # "nonp"

_DDL = (
    "CREATE TABLE IF NOT EXISTS np_schema (version integer NOT NULL)",
    """CREATE TABLE IF NOT EXISTS np_samples (
        store text NOT NULL,
        id bigint NOT NULL,
        key bigint NOT NULL,
        label bigint NOT NULL,
        vector bytea NOT NULL,
        PRIMARY KEY (store, id)
    )""",
    # a vector is 8 bytes a value of noise-like floats: compressing it gains nothing and
    # costs the server time on every insert, so it is stored out of line uncompressed
    "ALTER TABLE np_samples ALTER COLUMN vector SET STORAGE EXTERNAL",
    # version 2: each sample's micro-cluster id (-1: none), as the clusterer registered it
    "ALTER TABLE np_samples ADD COLUMN IF NOT EXISTS micro bigint NOT NULL DEFAULT -1",
    # version 3: the vectors' TOAST chunks are written once and never changed (a re-keying
    # rewrites the small row and keeps its TOAST pointer), and are read by pointer only: a
    # vacuum triggered by inserts would only set visibility bits nobody reads, after reading
    # the whole TOAST table, again each time it grows by a fifth (at 2 000 samples/s, a
    # vacuum of gigabytes every few minutes). Deleted samples still trigger one, and
    # anti-wraparound freezing still runs.
    "ALTER TABLE np_samples SET (toast.autovacuum_vacuum_insert_threshold = -1)",
    "CREATE INDEX IF NOT EXISTS np_samples_key ON np_samples (store, key, id)",
    "CREATE INDEX IF NOT EXISTS np_samples_label_key ON np_samples (store, label, key, id)",
    """CREATE TABLE IF NOT EXISTS np_meta (
        store text NOT NULL,
        name text NOT NULL,
        value bytea NOT NULL,
        PRIMARY KEY (store, name)
    )""",
    # the clusterer's state is megabytes of floats: pglz would spend seconds on each save
    "ALTER TABLE np_meta ALTER COLUMN value SET STORAGE EXTERNAL",
)


def _lock_id(name: str) -> int:
    """A signed 64-bit advisory lock id for a store name (stable across processes)."""
    return int.from_bytes(hashlib.blake2b(name.encode(), digest_size=8).digest(), "little",
                          signed=True)


def connect(url: str, *, timeout: float = 30.0) -> psycopg.Connection[Any]:
    """An autocommit connection to ``url``, or :class:`StoreError` saying why not."""
    try:
        return psycopg.connect(url, autocommit=True, connect_timeout=max(1, int(timeout)))
    except psycopg.ProgrammingError as exc:
        # the URL itself is malformed: the user's input
        raise InputError(f"{display_name(url)}: not a valid PostgreSQL URL ({exc})") from None
    except psycopg.OperationalError as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise StoreError(
            f"{display_name(url)}: cannot connect to PostgreSQL ({msg}); check that the server "
            "runs and the URL's host, port, user and database"
        ) from None


def ensure_schema(conn: psycopg.Connection[Any]) -> None:
    """Create the tables on first use; refuse a database of a newer layout."""
    # the usual case, a database already set up, costs one query and takes no lock (the DDL
    # path's advisory lock would be held to the end of a caller's transaction)
    if conn.execute("SELECT to_regclass('np_schema') IS NOT NULL").fetchone() == (True,):
        row = conn.execute("SELECT max(version) FROM np_schema").fetchone()
        version = None if row is None else row[0]
        if version == SCHEMA_VERSION:
            return
        if version is not None and version > SCHEMA_VERSION:
            raise InputError(
                f"the database holds nonprehensile stores of schema version {version}; this "
                f"version reads {SCHEMA_VERSION}: upgrade nonprehensile"
            )
    with conn.transaction():
        conn.execute("SELECT pg_advisory_xact_lock(%s)", (_DDL_LOCK,))
        for stmt in _DDL:
            conn.execute(stmt)
        row = conn.execute("SELECT max(version) FROM np_schema").fetchone()
        version = None if row is None else row[0]
        if version is None:
            conn.execute("INSERT INTO np_schema (version) VALUES (%s)", (SCHEMA_VERSION,))
        elif version < SCHEMA_VERSION:
            # the statements above brought an older layout up to date
            conn.execute("UPDATE np_schema SET version = %s", (SCHEMA_VERSION,))
        elif version > SCHEMA_VERSION:
            raise InputError(
                f"the database holds nonprehensile stores of schema version {version}; this "
                f"version reads {SCHEMA_VERSION}: upgrade nonprehensile"
            )


class PostgresStore(TableStore):
    """Samples, keys and cluster ids in a PostgreSQL database.

    Parameters
    ----------
    url : str or psycopg.Connection
        A ``postgresql://`` URL (libpq's URI form, e.g.
        ``postgresql://user@localhost:5432/db`` or ``postgresql://user@/db?host=/run/sock``),
        or an open connection in autocommit mode (from a pool: it is not closed by
        :meth:`close`).
    name : str
        Which store of the database (one database holds many).
    timeout : float
        Seconds to wait for the connection, and for another writer's lock, before giving up
        with :class:`~nonprehensile.errors.StoreError`.

    Notes
    -----
    A transaction that joins one the caller opened on the same connection (``with
    conn.transaction(): ...``) commits with it: several stores and the caller's own rows
    change together or not at all.
    """

    schema_version = SCHEMA_VERSION

    def __init__(self, url: str | psycopg.Connection[Any], name: str = "default", *,
                 timeout: float = 30.0) -> None:
        check_store_name(name)
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or timeout <= 0:
            raise InputError(f"timeout must be a positive number of seconds, got {timeout!r}")
        self.name = name
        self._own = isinstance(url, str)
        if isinstance(url, str):
            if not is_postgres_url(url):
                raise InputError(f"{url}: a PostgreSQL store needs a postgresql:// URL")
            self.url = display_name(url)
            self._conn = connect(url, timeout=timeout)
        else:
            self.url = "<connection>"
            self._conn = url
        self._lock = _lock_id(name)
        self._depth = 0
        self._d: int | None = None
        try:
            self._conn.execute(f"SET lock_timeout = {int(timeout * 1000)}")
            ensure_schema(self._conn)
            self._check_ids()
        except psycopg.Error as exc:
            self.close()
            raise StoreError(f"{self.url}: cannot open store {name!r} ({exc})") from None
        except InputError:
            self.close()
            raise

    # ------------------------------------------------------------------ connection

    @property
    def connection(self) -> psycopg.Connection[Any]:
        """The connection (to join a transaction with the caller's own rows)."""
        return self._conn

    def close(self) -> None:
        """Close the connection if the store opened it (committed data stays)."""
        if self._own:
            self._conn.close()

    def __enter__(self) -> PostgresStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _lock_now(self) -> None:
        try:
            self._conn.execute("SELECT pg_advisory_xact_lock(%s)", (self._lock,))
        except pg_errors.LockNotAvailable:
            raise LockTimeout(
                f"{self.url}: could not take store {self.name!r}'s write lock in time; another "
                "writer holds it for too long: retry, or raise timeout"
            ) from None

    @contextlib.contextmanager
    def transaction(self) -> Iterator[None]:
        """Commit everything inside together; nested uses join the outer transaction.

        The store's advisory lock is taken first, so that a read-modify-write is never
        interleaved with another writer's.
        """
        if self._depth:
            with self._joined():
                yield
            return
        joined = self._conn.info.transaction_status != pq.TransactionStatus.IDLE
        with contextlib.ExitStack() as stack:
            if not joined:
                stack.enter_context(self._conn.transaction())
            self._lock_now()
            self._depth = 1
            try:
                yield
            finally:
                self._depth = 0

    # ------------------------------------------------------------------ writes

    def _insert(self, rows: list[tuple[Any, ...]]) -> None:
        with self._conn.cursor() as cur, cur.copy(
            "COPY np_samples (store, id, key, label, micro, vector) FROM STDIN (FORMAT BINARY)"
        ) as cp:
            cp.set_types(["text", "int8", "int8", "int8", "int8", "bytea"])
            for row in rows:
                cp.write_row(row)

    def _rekey(self, start: int, keys: list[int], labels: list[int],
               micro: list[int] | None) -> None:
        for s in range(0, len(keys), UPDATE_BATCH):
            ks = keys[s : s + UPDATE_BATCH]
            ids = list(range(start + s, start + s + len(ks)))
            if micro is None:
                self._conn.execute(
                    "UPDATE np_samples AS t SET key = u.key, label = u.label FROM "
                    "unnest(%s::bigint[], %s::bigint[], %s::bigint[]) AS u(id, key, label) "
                    "WHERE t.store = %s AND t.id = u.id",
                    (ids, ks, labels[s : s + UPDATE_BATCH], self.name),
                )
            else:
                self._conn.execute(
                    "UPDATE np_samples AS t SET key = u.key, label = u.label, micro = u.micro "
                    "FROM unnest(%s::bigint[], %s::bigint[], %s::bigint[], %s::bigint[]) "
                    "AS u(id, key, label, micro) WHERE t.store = %s AND t.id = u.id",
                    (ids, ks, labels[s : s + UPDATE_BATCH], micro[s : s + UPDATE_BATCH],
                     self.name),
                )
