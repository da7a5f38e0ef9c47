"""The service's own tables on PostgreSQL: mentors' tokens, uploads and their samples.

Tokens are stored as SHA-256 hashes: a token is 32 random bytes (``secrets.token_urlsafe``),
far beyond guessing, so a slow password hash adds nothing; the database never holds one a
thief could replay. Uploads are keyed by the SHA-256 of their content (the recording's bytes
and its annotation), which makes them idempotent: the same upload twice stores one copy and
answers the same reply.
"""

from __future__ import annotations

import hashlib
import secrets
from typing import Any

import psycopg
from psycopg_pool import ConnectionPool, PoolTimeout

from nonprehensile.errors import InputError, StoreError
from nonprehensile.motion.pgstore import connect, ensure_schema
from nonprehensile.motion.stores import display_name, is_postgres_url

__all__ = ["SERVICE_SCHEMA_VERSION", "create_token", "hash_token", "list_tokens", "make_pool",
           "mentor_of", "service_schema"]

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


def make_pool(url: str, *, max_size: int = 8, timeout: float = 30.0) -> ConnectionPool:
    """A psycopg connection pool on ``url`` (autocommit connections), tables created."""
    if not is_postgres_url(url):
        raise InputError(
            f"{url}: the service needs a postgresql:// URL (a server database that many "
            "uploaders share); a SQLite file is the embedded store of `nonprehensile cluster`"
        )
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


def service_schema(conn: psycopg.Connection[Any]) -> None:
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


def create_token(conn: psycopg.Connection[Any], mentor: str) -> str:
    """A new bearer token for ``mentor`` (shown once; only its hash is stored)."""
    name = _check_mentor(mentor)
    token = "np_" + secrets.token_urlsafe(32)
    conn.execute("INSERT INTO np_tokens (token_hash, mentor) VALUES (%s, %s)",
                 (hash_token(token), name))
    return token


def revoke_tokens(conn: psycopg.Connection[Any], mentor: str) -> int:
    """Revoke every token of ``mentor``; returns how many."""
    cur = conn.execute("UPDATE np_tokens SET revoked = true WHERE mentor = %s AND NOT revoked",
                       (_check_mentor(mentor),))
    return cur.rowcount


def list_tokens(conn: psycopg.Connection[Any]) -> list[dict[str, Any]]:
    """Mentors with their number of live tokens (never the tokens)."""
    rows = conn.execute(
        "SELECT mentor, count(*) FILTER (WHERE NOT revoked), min(created) FROM np_tokens "
        "GROUP BY mentor ORDER BY mentor"
    ).fetchall()
    return [{"mentor": m, "tokens": int(n), "since": t.isoformat()} for m, n, t in rows]


def mentor_of(conn: psycopg.Connection[Any], token: str) -> str | None:
    """The mentor a live token belongs to, or None."""
    row = conn.execute("SELECT mentor FROM np_tokens WHERE token_hash = %s AND NOT revoked",
                       (hash_token(token),)).fetchone()
    return None if row is None else str(row[0])
