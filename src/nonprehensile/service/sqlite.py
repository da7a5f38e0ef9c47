"""The service on one SQLite file: ``serve --store demos.db``.

Everything the service keeps (mentors' tokens, uploads, and every arc's samples, keys, cluster
ids and model) lives in one SQLite database, in the tables PostgreSQL has (``np_samples``,
``np_meta``, ``np_uploads``, ...), so that an upload's rows in all its arcs and in the
service's tables commit together, or not at all, in one transaction.

SQLite has one writer at a time. The file runs in WAL mode: readers (listings, statistics,
the recalibration's snapshot) never wait for the writer, and a committed transaction survives
the process being killed (``synchronous=NORMAL``: SQLite writes the WAL before a commit
returns; only a power loss can take the last commits). Writers take turns: in the server's
process they queue on one lock (uploads in threads never spin on SQLite's busy handler), and
another process (``serve token create`` while the server runs) waits up to the busy timeout.

:class:`SQLitePool` hands out connections like psycopg's pool; :class:`SQLiteConnection`
runs the service's SQL (psycopg's ``%s`` placeholders) on SQLite; :class:`SQLiteArcStore` is
one arc's store (a :class:`~nonprehensile.motion.tablestore.TableStore`).
"""

from __future__ import annotations

import contextlib
import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from nonprehensile.bounds import check_path
from nonprehensile.errors import InputError
from nonprehensile.motion.store import (
    StoreFileError,
    _end_transaction,
    _explain,
)
from nonprehensile.motion.tablestore import Nesting, TableStore, check_store_name

__all__ = ["SQLiteArcStore", "SQLiteConnection", "SQLitePool"]

#: Versions of the layouts. SQLite stays at layout 2: PostgreSQL's layout 3 only turns off the
#: autovacuum of its TOAST table, which SQLite does not have; the tables are the same.
SCHEMA_VERSION = 2
SERVICE_SCHEMA_VERSION = 1

_NOW = "(strftime('%Y-%m-%dT%H:%M:%fZ', 'now'))"
_DDL = f"""
CREATE TABLE IF NOT EXISTS np_schema (version INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS np_samples (
    store TEXT NOT NULL,
    id INTEGER NOT NULL,
    key INTEGER NOT NULL,
    label INTEGER NOT NULL,
    vector BLOB NOT NULL,
    micro INTEGER NOT NULL DEFAULT -1,
    PRIMARY KEY (store, id)
);
CREATE INDEX IF NOT EXISTS np_samples_key ON np_samples (store, key, id);
CREATE INDEX IF NOT EXISTS np_samples_label_key ON np_samples (store, label, key, id);
CREATE TABLE IF NOT EXISTS np_meta (
    store TEXT NOT NULL,
    name TEXT NOT NULL,
    value BLOB NOT NULL,
    PRIMARY KEY (store, name)
);
CREATE TABLE IF NOT EXISTS np_service_schema (version INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS np_tokens (
    token_hash TEXT PRIMARY KEY,
    mentor TEXT NOT NULL,
    created TEXT NOT NULL DEFAULT {_NOW},
    revoked BOOLEAN NOT NULL DEFAULT FALSE
);
CREATE INDEX IF NOT EXISTS np_tokens_mentor ON np_tokens (mentor);
CREATE TABLE IF NOT EXISTS np_uploads (
    hash TEXT PRIMARY KEY,
    mentor TEXT NOT NULL,
    file TEXT NOT NULL,
    skill TEXT NOT NULL,
    kind TEXT NOT NULL,
    created TEXT NOT NULL DEFAULT {_NOW},
    withdrawn BOOLEAN NOT NULL DEFAULT FALSE,
    reply TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS np_uploads_mentor ON np_uploads (mentor);
CREATE TABLE IF NOT EXISTS np_upload_samples (
    hash TEXT NOT NULL REFERENCES np_uploads (hash),
    step INTEGER NOT NULL,
    arc TEXT NOT NULL,
    sample INTEGER NOT NULL,
    PRIMARY KEY (hash, step),
    UNIQUE (arc, sample)
);
"""


class SQLiteConnection(Nesting):
    """A SQLite connection that runs the service's SQL (``%s`` placeholders, as psycopg).

    ``transaction()`` is a write transaction (``BEGIN IMMEDIATE``, after the process's writer
    lock); nested uses join it. ``snapshot()`` is a read transaction: one consistent view,
    no lock (WAL). Errors become one line naming the file (:func:`~nonprehensile.motion.
    store._explain`).
    """

    def __init__(self, path: str, writer: threading.Lock, timeout: float) -> None:
        self.path = path
        self._writer = writer
        self._depth = 0
        try:
            self.raw = sqlite3.connect(path, timeout=timeout, isolation_level=None,
                                       check_same_thread=False)
            self.raw.execute("PRAGMA journal_mode=WAL")
            self.raw.execute("PRAGMA synchronous=NORMAL")
            self.raw.execute("PRAGMA foreign_keys=ON")
        except sqlite3.Error as exc:
            raise StoreFileError(
                f"{path}: cannot open as the service's database ({exc}); give a SQLite file "
                "written by `nonprehensile serve`, or a new file name in a writable folder"
            ) from None

    def execute(self, sql: str, args: Any = ()) -> sqlite3.Cursor:
        try:
            return self.raw.execute(sql.replace("%s", "?"), tuple(args))
        except sqlite3.Error as exc:
            raise _explain(self.path, exc) from None

    def executemany(self, sql: str, rows: list[tuple[Any, ...]]) -> None:
        try:
            self.raw.executemany(sql.replace("%s", "?"), rows)
        except sqlite3.Error as exc:
            raise _explain(self.path, exc) from None

    @property
    def in_transaction(self) -> bool:
        return self.raw.in_transaction

    def close(self) -> None:
        self.raw.close()

    def _end(self, ok: bool) -> None:
        _end_transaction(self.raw, self.path, ok)

    @contextlib.contextmanager
    def transaction(self) -> Iterator[None]:
        """Commit everything inside together (nested uses join); one writer at a time."""
        if self._depth:
            with self._joined():
                yield
            return
        with self._writer:
            self.execute("BEGIN IMMEDIATE")
            self._depth = 1
            try:
                yield
            except BaseException:
                self._depth = 0
                self._end(ok=False)
                raise
            self._depth = 0
            self._end(ok=True)

    @contextlib.contextmanager
    def snapshot(self) -> Iterator[None]:
        """Read one consistent state (a WAL read transaction: writers go on meanwhile)."""
        self.execute("BEGIN DEFERRED")
        try:
            yield
        finally:
            self._end(ok=True)


class SQLitePool:
    """Connections to the service's SQLite file, one per thread at a time (like psycopg's
    ``ConnectionPool``); the tables are created on first use.

    Parameters
    ----------
    path : str or Path
        The database file (created if absent).
    timeout : float
        Seconds another process's write lock is waited for before giving up.
    """

    def __init__(self, path: str | Path, *, timeout: float = 30.0) -> None:
        self.path = str(path)
        check_path(self.path, "store")
        if Path(self.path).is_dir():
            raise InputError(f"{self.path}: is a folder; give the service database's file name")
        self._timeout = float(timeout)
        self._writer = threading.Lock()
        self._free: list[SQLiteConnection] = []
        self._guard = threading.Lock()
        try:
            with self.connection() as conn:
                _schema(conn)
        except BaseException:
            self.close()  # a refused file (a `cluster` store, not a database) keeps no handle
            raise

    @contextlib.contextmanager
    def connection(self) -> Iterator[SQLiteConnection]:
        with self._guard:
            conn = self._free.pop() if self._free else None
        if conn is None:
            conn = SQLiteConnection(self.path, self._writer, self._timeout)
        try:
            yield conn
        finally:
            if conn.in_transaction:  # an interrupted block: never hand out an open one
                conn._end(ok=False)
            with self._guard:
                self._free.append(conn)

    def cut(self) -> None:
        """Nothing to cut when the server stops: SQLite's work never waits on a server, and a
        write waits at most ``timeout`` for another process's lock."""

    def abort(self) -> None:
        """As :meth:`cut`: nothing to cut."""

    def close(self) -> None:
        with self._guard:
            for conn in self._free:
                conn.close()
            self._free.clear()


def _schema(conn: SQLiteConnection) -> None:
    """Create the tables on first use; refuse a `cluster` store file and newer layouts."""
    names = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    if "samples" in names and "np_samples" not in names:
        raise InputError(
            f"{conn.path}: is a `nonprehensile cluster` store, not a service database; give "
            "`serve --store` a new file (or the service's own)"
        )
    with conn.transaction():
        for stmt in _DDL.split(";"):
            if stmt.strip():
                conn.execute(stmt)
        for table, version in (("np_schema", SCHEMA_VERSION),
                               ("np_service_schema", SERVICE_SCHEMA_VERSION)):
            row = conn.execute(f"SELECT max(version) FROM {table}").fetchone()
            have = None if row is None else row[0]
            if have is None:
                conn.execute(f"INSERT INTO {table} (version) VALUES (%s)", (version,))
            elif have > version:
                raise InputError(
                    f"{conn.path}: the database's {table} layout is of version {have}; this "
                    f"version reads {version}: upgrade nonprehensile"
                )


class SQLiteArcStore(TableStore):
    """One named store (an arc's samples, keys, cluster ids and model) in the service's
    SQLite file, on a pooled connection: its transactions join the connection's."""

    schema_version = SCHEMA_VERSION

    def __init__(self, conn: SQLiteConnection, name: str) -> None:
        self.name = check_store_name(name)
        self.url = conn.path
        self._conn = conn
        self._d = None
        self._check_ids()

    @contextlib.contextmanager
    def transaction(self) -> Iterator[None]:
        with self._conn.transaction():
            yield

    def _insert(self, rows: list[tuple[Any, ...]]) -> None:
        self._conn.executemany("INSERT INTO np_samples (store, id, key, label, micro, vector) "
                               "VALUES (%s, %s, %s, %s, %s, %s)", rows)

    def _rekey(self, start: int, keys: list[int], labels: list[int],
               micro: list[int] | None) -> None:
        ids = range(start, start + len(keys))
        if micro is None:
            self._conn.executemany(
                "UPDATE np_samples SET key = %s, label = %s WHERE store = %s AND id = %s",
                [(k, c, self.name, i) for k, c, i in zip(keys, labels, ids, strict=True)])
        else:
            self._conn.executemany(
                "UPDATE np_samples SET key = %s, label = %s, micro = %s "
                "WHERE store = %s AND id = %s",
                [(k, c, u, self.name, i)
                 for k, c, u, i in zip(keys, labels, micro, ids, strict=True)])

