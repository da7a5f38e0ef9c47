"""Open a sample store by name: a ``postgresql://`` URL means PostgreSQL, anything else a
SQLite file.

Every command that names a store (``cluster fit/add/show STORE``, ``serve --store``) goes
through :func:`open_store`, so the two backends are interchangeable and give the same results.
PostgreSQL needs the ``pg`` extra (psycopg 3), imported only when a URL is given.
"""

from __future__ import annotations

from pathlib import Path

from nonprehensile.errors import InputError
from nonprehensile.motion.store import SampleStore, SQLiteStore

__all__ = ["display_name", "is_postgres_url", "open_store", "store_exists"]


def is_postgres_url(spec: object) -> bool:
    """Whether a store name is a PostgreSQL URL (``postgresql://`` or ``postgres://``)."""
    return isinstance(spec, str) and spec.startswith(("postgresql://", "postgres://"))


def display_name(spec: str | Path) -> str:
    """The store's name for messages and documents: a URL without its password."""
    text = str(spec)
    if not is_postgres_url(text):
        return text
    head, sep, tail = text.partition("@")
    if not sep:
        return text
    scheme, _, cred = head.partition("://")
    return f"{scheme}://{cred.split(':', 1)[0]}@{tail}"


def _sqlite_path(spec: str | Path, name: str | None) -> Path:
    path = Path(spec)
    if name is None:
        return path
    # named stores beside the file: service.db -> service.arc-0-n0-n1.db
    return path.with_name(f"{path.stem}.{name}{path.suffix or '.db'}")


def open_store(spec: str | Path, *, name: str | None = None,
               timeout: float = 30.0) -> SampleStore:
    """The store named ``spec``: a PostgreSQL URL, or a SQLite file path.

    Parameters
    ----------
    spec : str or Path
        ``postgresql://user@host:port/db`` (libpq's URI form, e.g. ``?host=/socket/dir``), or
        a path (created if absent).
    name : str, optional
        Which store of a PostgreSQL database (default ``"default"``); for SQLite, a sibling
        file ``<stem>.<name><suffix>``.
    timeout : float
        Seconds to wait for the connection or another writer's lock.
    """
    if is_postgres_url(spec):
        try:
            from nonprehensile.motion.pgstore import PostgresStore
        except ImportError:
            raise InputError(
                f"{spec}: PostgreSQL stores need psycopg: pip install 'nonprehensile[pg]'"
            ) from None
        return PostgresStore(str(spec), name or "default", timeout=timeout)
    return SQLiteStore(_sqlite_path(spec, name), timeout=timeout)


def store_exists(spec: str | Path) -> bool:
    """Whether a SQLite store file exists; a URL is taken to exist (the server decides)."""
    return is_postgres_url(spec) or Path(spec).exists()
