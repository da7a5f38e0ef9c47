"""The service's own tables: mentors' tokens, uploads and their samples, on PostgreSQL (a
``postgresql://`` URL) or in one SQLite file (a path; :mod:`nonprehensile.service.sqlite`).

The service talks to either through a pool (:func:`make_pool`) of connections that run the
same SQL (psycopg's ``%s`` placeholders); :func:`arc_store` opens an arc's store on a pooled
connection and :func:`snapshot` a consistent read of it.

Tokens are stored as SHA-256 hashes: a token is 32 random bytes (``secrets.token_urlsafe``),
far beyond guessing, so a slow password hash adds nothing; the database never holds one a
thief could replay. Uploads are keyed by the SHA-256 of their content (the recording's bytes
and its annotation), which makes them idempotent: the same upload twice stores one copy and
answers the same reply.
"""

from __future__ import annotations

import contextlib
import hashlib
import secrets
from collections.abc import Iterator
from contextlib import AbstractContextManager
from typing import Any, Protocol

from psycopg_pool import ConnectionPool, PoolTimeout

from nonprehensile.errors import InputError, StoreError
from nonprehensile.motion.pgstore import PostgresStore, connect, ensure_schema
from nonprehensile.motion.stores import display_name, is_postgres_url
from nonprehensile.motion.tablestore import TableStore
from nonprehensile.service.sqlite import SQLiteArcStore, SQLiteConnection, SQLitePool

__all__ = ["SERVICE_SCHEMA_VERSION", "Pool", "arc_store", "create_token", "hash_token",
           "list_tokens", "make_pool", "mentor_of", "service_schema", "snapshot"]


class Pool(Protocol):
    """What the service needs of a pool: a connection for a block, and closing."""

    def connection(self) -> AbstractContextManager[Any]: ...

    def close(self) -> None: ...

#: Version of the service tables' layout.
SERVICE_SCHEMA_VERSION = 1
_DDL_LOCK = 0x6E707376  # "npsv"

_DDL = (
    """CREATE TABLE IF NOT EXISTS np_service_schema (version integer NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS np_tokens (
        token_hash text PRIMARY KEY,
        mentor text NOT NULL,
        created timestamptz NOT NULL DEFAULT now(),
        revoked boolean NOT NULL DEFAULT false
    )""",
    "CREATE INDEX IF NOT EXISTS np_tokens_mentor ON np_tokens (mentor)",
    """CREATE TABLE IF NOT EXISTS np_uploads (
        hash text PRIMARY KEY,
        mentor text NOT NULL,
        file text NOT NULL,
        skill text NOT NULL,
        kind text NOT NULL,
        created timestamptz NOT NULL DEFAULT now(),
        withdrawn boolean NOT NULL DEFAULT false,
        reply jsonb NOT NULL
    )""",
    "CREATE INDEX IF NOT EXISTS np_uploads_mentor ON np_uploads (mentor)",
    """CREATE TABLE IF NOT EXISTS np_upload_samples (
        hash text NOT NULL REFERENCES np_uploads (hash),
        step integer NOT NULL,
        arc text NOT NULL,
        sample bigint NOT NULL,
        PRIMARY KEY (hash, step),
        UNIQUE (arc, sample)
    )""",
)


def hash_token(token: str) -> str:
    """SHA-256 of a token, hex."""
    return hashlib.sha256(token.encode()).hexdigest()


def make_pool(url: str, *, max_size: int = 8, timeout: float = 30.0) -> Pool:
    """A pool on the service's database, tables created: a psycopg pool of autocommit
    connections for a ``postgresql://`` URL, a :class:`SQLitePool` for a file path."""
    if not is_postgres_url(url):
        return SQLitePool(url, timeout=timeout)
    # one plain connection first: an unreachable server is one clear error at once, not a
    # pool retrying in the background until its timeout
    connect(url, timeout=timeout).close()
    pool = ConnectionPool(url, min_size=1, max_size=max_size, timeout=timeout,
                          kwargs={"autocommit": True}, open=False)
    try:
        pool.open(wait=True, timeout=timeout)
    except PoolTimeout as exc:
        pool.close()
        raise StoreError(f"{display_name(url)}: cannot connect to PostgreSQL ({exc}); check "
                         "that the server runs and the URL") from None
    with pool.connection() as conn:
        ensure_schema(conn)
        service_schema(conn)
    return pool


def arc_store(conn: Any, arc: str) -> TableStore:
    """An arc's store on a pooled connection (its transactions join the connection's)."""
    if isinstance(conn, SQLiteConnection):
        return SQLiteArcStore(conn, arc)
    return PostgresStore(conn, arc)


@contextlib.contextmanager
def snapshot(conn: Any) -> Iterator[None]:
    """A read of one consistent state, taking no lock (PostgreSQL: REPEATABLE READ; SQLite:
    a WAL read transaction)."""
    if isinstance(conn, SQLiteConnection):
        with conn.snapshot():
            yield
        return
    with conn.transaction():
        conn.execute("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ")
        yield


def service_schema(conn: Any) -> None:
    """Create the service's tables on first use; refuse a newer layout."""
    with conn.transaction():
        conn.execute("SELECT pg_advisory_xact_lock(%s)", (_DDL_LOCK,))
        for stmt in _DDL:
            conn.execute(stmt)
        row = conn.execute("SELECT max(version) FROM np_service_schema").fetchone()
        version = None if row is None else row[0]
        if version is None:
            conn.execute("INSERT INTO np_service_schema (version) VALUES (%s)",
                         (SERVICE_SCHEMA_VERSION,))
        elif version > SERVICE_SCHEMA_VERSION:
            raise InputError(f"the database's service tables are of version {version}; this "
                             f"version reads {SERVICE_SCHEMA_VERSION}: upgrade nonprehensile")


def _check_mentor(mentor: str) -> str:
    name = mentor.strip() if isinstance(mentor, str) else ""
    if not name or len(name) > 100 or any(ord(c) < 32 for c in name):
        raise InputError(f"a mentor's name must be 1 to 100 printable characters, got "
                         f"{mentor!r}")
    return name


def create_token(conn: Any, mentor: str) -> str:
    """A new bearer token for ``mentor`` (shown once; only its hash is stored)."""
    name = _check_mentor(mentor)
    token = "np_" + secrets.token_urlsafe(32)
    conn.execute("INSERT INTO np_tokens (token_hash, mentor) VALUES (%s, %s)",
                 (hash_token(token), name))
    return token


def revoke_tokens(conn: Any, mentor: str) -> int:
    """Revoke every token of ``mentor``; returns how many."""
    cur = conn.execute("UPDATE np_tokens SET revoked = true WHERE mentor = %s AND NOT revoked",
                       (_check_mentor(mentor),))
    return int(cur.rowcount)


def list_tokens(conn: Any) -> list[dict[str, Any]]:
    """Mentors with their number of live tokens (never the tokens)."""
    rows = conn.execute(
        "SELECT mentor, count(*) FILTER (WHERE NOT revoked), min(created) FROM np_tokens "
        "GROUP BY mentor ORDER BY mentor"
    ).fetchall()
    # PostgreSQL gives a datetime, SQLite the ISO text it stored
    return [{"mentor": m, "tokens": int(n), "since": t if isinstance(t, str) else t.isoformat()}
            for m, n, t in rows]


def mentor_of(conn: Any, token: str) -> str | None:
    """The mentor a live token belongs to, or None."""
    row = conn.execute("SELECT mentor FROM np_tokens WHERE token_hash = %s AND NOT revoked",
                       (hash_token(token),)).fetchone()
    return None if row is None else str(row[0])
