"""The service's own tables: mentors' tokens, uploads and their samples, on PostgreSQL (a
``postgresql://`` URL) or in one SQLite file (a path; :mod:`nonprehensile.service.sqlite`).

The service talks to either through a pool (:func:`make_pool`) of connections that run the
same SQL (psycopg's ``%s`` placeholders); :func:`arc_store` opens an arc's store on a pooled
connection and :func:`snapshot` a consistent read of it.

On PostgreSQL the pool (:class:`PostgresPool`) turns a database outage into
:class:`~nonprehensile.service.errors.Unavailable` (a 503 with one line) instead of a wait: a
connection lost in a request fails it at once, and a request that waits for a connection asks
the server itself after ``probe_after`` seconds, failing at once when it does not answer
(psycopg's pool would wait its whole timeout, reconnecting), and serving the request on a
connection of its own when it answers while the pool reconnects. :meth:`PostgresPool.cut` cuts
the connections still in use when the server stops (a request blocked on a database that
never answers would otherwise hold the process).

Tokens are stored as SHA-256 hashes: a token is 32 random bytes (``secrets.token_urlsafe``),
far beyond guessing, so a slow password hash adds nothing; the database never holds one a
thief could replay. Uploads are keyed by the SHA-256 of their content (the recording's bytes
and its annotation), which makes them idempotent: the same upload twice stores one copy and
answers the same reply.
"""

from __future__ import annotations

import collections
import contextlib
import hashlib
import logging
import os
import secrets
import socket
import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import AbstractContextManager
from types import MappingProxyType
from typing import Any, Literal, Protocol

import psycopg
from psycopg.conninfo import conninfo_to_dict, make_conninfo
from psycopg_pool import ConnectionPool, PoolClosed, PoolTimeout

from nonprehensile.errors import InputError, LockTimeout, StoreError
from nonprehensile.motion.pgstore import PostgresStore, connect, ensure_schema
from nonprehensile.motion.stores import display_name, is_postgres_url
from nonprehensile.motion.tablestore import TableStore
from nonprehensile.service.errors import Unavailable, one_line
from nonprehensile.service.sqlite import SQLiteArcStore, SQLiteConnection, SQLitePool

__all__ = ["CONNECTION_SETTINGS", "SERVICE_SCHEMA_VERSION", "Pool", "PostgresPool",
           "arc_store", "create_token", "hash_token", "list_tokens", "make_pool", "mentor_of",
           "service_schema", "snapshot"]

log = logging.getLogger("nonprehensile.service")


class Pool(Protocol):
    """What the service needs of a pool: a connection for a block, closing, and cutting the
    connections in use when the server stops."""

    def connection(self) -> AbstractContextManager[Any]: ...

    def close(self) -> None: ...

    def cut(self) -> None: ...

    def abort(self) -> None: ...


#: libpq settings of the service's PostgreSQL connections (a URL's own setting of one wins):
#: a connection attempt gives up after 5 s; on TCP, a server that vanished without a reset (a
#: crashed host, a cut network) is found out by keepalives within about 10 + 3 x 5 s while a
#: reply is awaited, and data it does not acknowledge fails the connection after 30 s. A
#: unix socket needs none of them (its server's end closes with its process); libpq ignores
#: them there.
CONNECTION_SETTINGS: Mapping[str, str] = MappingProxyType({
    "connect_timeout": "5", "keepalives": "1", "keepalives_idle": "10",
    "keepalives_interval": "5", "keepalives_count": "3", "tcp_user_timeout": "30000"})

#: What a client is told after a database error: an upload is stored whole or not at all,
#: and sending it again stores it once (uploads are keyed by their content).
_RETRY = "try again later (each demonstration is stored whole or not at all, and once however " \
         "often it is sent)"


class _Watch:
    """One check of a connection under :class:`_Watchdog`: its deadline, and whether the check
    ended (``done``) or overran its deadline and had its connection cut (``fired``)."""

    __slots__ = ("conn", "deadline", "done", "fired")

    def __init__(self, conn: psycopg.Connection[Any], deadline: float) -> None:
        self.conn = conn
        self.deadline = deadline
        self.done = False
        self.fired = False


class _Watchdog:
    """One daemon thread that cuts (:func:`_shut`) the connection of a check that overran its
    deadline: psycopg has no client-side timeout of a query.

    A thread per check (``threading.Timer``) cost 0.6 ms a checkout, several times the
    checkout and its query. Every check of a pool has the same timeout, so deadlines come in
    the order the checks start: a queue, not a heap. A check that ended stays queued until it
    reaches the head (dropped there unread), which bounds the queue by the checks of one
    timeout's span. Cutting and ending a check take the same lock: a check that ended is
    never cut, and one cut is known to be (``fired``), whatever its query returned.
    """

    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self._cond = threading.Condition(threading.Lock())
        self._queue: collections.deque[_Watch] = collections.deque()
        self._thread: threading.Thread | None = None

    def arm(self, conn: psycopg.Connection[Any]) -> _Watch:
        """Watch a check of ``conn`` starting now (the thread started on first use)."""
        with self._cond:
            watch = _Watch(conn, time.monotonic() + self.timeout)
            self._queue.append(watch)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="nonprehensile-db-watchdog",
                                                daemon=True)
                self._thread.start()
            elif len(self._queue) == 1:
                self._cond.notify()  # (the thread waits without a deadline on an empty queue)
        return watch

    def disarm(self, watch: _Watch) -> bool:
        """End a check; whether it overran its deadline (its connection cut)."""
        with self._cond:
            watch.done = True
            return watch.fired

    def stop(self) -> None:
        """Stop the thread (a later :meth:`arm` starts another)."""
        with self._cond:
            thread, self._thread = self._thread, None
            self._cond.notify_all()
        if thread is not None:
            thread.join(timeout=1.0)

    def _run(self) -> None:
        me = threading.current_thread()
        with self._cond:
            while self._thread is me:
                queue = self._queue
                while queue and queue[0].done:
                    queue.popleft()
                if not queue:
                    self._cond.wait()
                    continue
                left = queue[0].deadline - time.monotonic()
                if left > 0:
                    self._cond.wait(left)
                    continue
                watch = queue.popleft()
                watch.fired = watch.done = True
                # under the lock: the check's thread cannot have ended it (and given the
                # connection back, its descriptor closed and perhaps reused) meanwhile
                _shut(watch.conn)


#: What :meth:`PostgresPool._checked` found of a connection from the pool.
_Check = Literal["ok", "failed", "silent"]


class PostgresPool:
    """The service's connections to PostgreSQL: psycopg's pool, whose failures are
    :class:`~nonprehensile.service.errors.Unavailable` (HTTP 503, one line), never a long wait
    on a database that is down.

    Parameters
    ----------
    pool : ConnectionPool
        psycopg's pool, open, of autocommit connections made with ``settings``.
    url : str
        Its database (asked directly by the probe).
    settings : Mapping[str, str]
        The libpq settings of the pool's connections (the probe's too).
    timeout : float
        Seconds a request waits for a free connection while the database answers (every
        connection busy), before a 503.
    probe_after : float
        Seconds of waiting for a connection after which the database is asked directly
        (one connection attempt, shared by the requests waiting): one that does not answer
        ends every wait at once with a 503, where psycopg's pool would wait ``timeout``
        reconnecting. One that answers while fewer than the pool's ``max_size`` connections
        are in use serves the request on a connection of its own (closed after it): the pool
        is then between the attempts of its reconnection back-off, which after a long outage
        are up to a minute apart.
    check_timeout : float
        Seconds the check of a connection taken from the pool (an empty query) may take
        before the connection is cut and the request answered a 503: a server that stopped
        answering (frozen, its disk hung), where the query would wait for ever.
    """

    def __init__(self, pool: ConnectionPool[Any], url: str, settings: Mapping[str, str], *,
                 timeout: float = 30.0, probe_after: float = 1.0,
                 check_timeout: float = 5.0) -> None:
        self._pool = pool
        self._url = url
        # the probe asks only whether the server answers: 2 s (libpq's least) for a new
        # connection, whatever the pool's connections wait, so that a thread blocked in it
        # notices a stop soon; a request's own connection (the pool reconnecting) is made
        # the same way, the pool's settings otherwise
        self._probe_conninfo = make_conninfo(url, **{**settings, "connect_timeout": "2"})
        self.timeout = float(timeout)
        self.probe_after = float(probe_after)
        self.check_timeout = float(check_timeout)
        self._watchdog = _Watchdog(self.check_timeout)
        self._guard = threading.Lock()
        # connections given to requests (pooled or their own), and own ones being made: what
        # cut() cuts, and the count that keeps own connections within the pool's max_size
        self._in_use: set[psycopg.Connection[Any]] = set()
        self._dialing = 0
        self._probe_lock = threading.Lock()
        self._probed: tuple[float, str | None] = (-float("inf"), None)
        # set once, by cut() (a plain flag: read by the waiting threads between their waits)
        self._stopping = False

    def _down(self, reason: str) -> Unavailable:
        return Unavailable("the service's database is unavailable (it does not answer or "
                           f"dropped the connection): {_RETRY}", reason)

    def _probe(self) -> str | None:
        """Why the database does not answer a new connection, or None when it does (one
        attempt at a time; a result less than ``probe_after`` / 2 old is reused)."""
        with self._probe_lock:
            when, why = self._probed
            if time.monotonic() - when < self.probe_after / 2:
                return why
            try:
                psycopg.connect(self._probe_conninfo, autocommit=True).close()
                why = None
            except psycopg.Error as exc:
                why = one_line(exc)
            self._probed = (time.monotonic(), why)
            return why

    def _getconn(self) -> tuple[psycopg.Connection[Any], bool]:
        """A checked connection for a request, and whether it is the pool's (else the
        request's own, made while the pool reconnects)."""
        deadline = time.monotonic() + self.timeout
        try:
            while True:
                # every pass: a pass can take a check's timeout or a probe's 2 s
                if self._stopping:
                    raise PoolClosed("cut")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise PoolTimeout("deadline")
                try:
                    conn: psycopg.Connection[Any] = self._pool.getconn(
                        timeout=max(0.01, min(self.probe_after, left)))
                except PoolTimeout:
                    pass
                else:
                    state = self._checked(conn)
                    if state == "ok":
                        return conn, True
                    if state == "silent":
                        # a server that does not answer the check does not answer the next
                        # idle connection's either: each would hold the request a timeout
                        raise self._down(f"{display_name(self._url)}: no answer to a "
                                         f"connection's check within {self.check_timeout:g} s")
                    continue  # one the database dropped while it was idle: the next one
                why = self._probe()
                if why is not None:
                    raise self._down(f"{display_name(self._url)}: {why}") from None
                own = self._own_connection()
                if own is not None:
                    return own, False
        except PoolTimeout:
            raise Unavailable(f"no database connection came free within {self.timeout:g} s "
                              f"(the service is overloaded): {_RETRY}") from None
        except PoolClosed:
            raise Unavailable(f"the service is stopping: {_RETRY}") from None

    def _own_connection(self) -> psycopg.Connection[Any] | None:
        """A connection of the request's own when the database answers but the pool gave
        none while fewer than its ``max_size`` connections are in use (its reconnection
        waiting out a back-off); None when that many are (an overload: wait for one).

        psycopg's pool retries a failed connection after 1, 2, 4 ... s: after an outage of
        a minute or more its next attempt can come a minute after the database is back.
        """
        with self._guard:
            if len(self._in_use) + self._dialing >= self._pool.max_size:
                return None
            self._dialing += 1
        conn: psycopg.Connection[Any] | None = None
        try:
            conn = psycopg.connect(self._probe_conninfo, autocommit=True)
        except psycopg.Error as exc:
            raise self._down(f"{display_name(self._url)}: {one_line(exc)}") from None
        finally:
            with self._guard:
                self._dialing -= 1
                stopping = self._stopping
                if conn is not None and not stopping:
                    self._in_use.add(conn)
        if stopping:
            conn.close()
            raise PoolClosed("cut")
        log.info("the database answers but its pool gave no connection within %g s "
                 "(reconnecting): a request served on a connection of its own", self.probe_after)
        return conn

    def _checked(self, conn: psycopg.Connection[Any]) -> _Check:
        """Whether a connection from the pool still works (an empty query: ``"ok"``), counted
        as in use from here on; one that does not is given back (the pool drops it): it
        failed (``"failed"``), or the server did not answer it within ``check_timeout``
        (``"silent"``: cut).

        After the database restarted, the pool's idle connections are dead: each would fail
        its next request with a 503. psycopg's pool can check them itself (``check=``), but
        inside ``getconn``, where :meth:`cut` cannot reach one blocked on a database that
        does not answer.
        """
        with self._guard:
            self._in_use.add(conn)
        watch = self._watchdog.arm(conn)
        try:
            try:
                conn.execute("")
            finally:
                overran = self._watchdog.disarm(watch)
        except BaseException as exc:
            self._give_back(conn, close=overran)
            if overran:
                return "silent"
            if isinstance(exc, psycopg.Error):
                return "failed"
            raise
        if overran:
            # cut just as its answer came: the socket is shut down, the connection dead
            self._give_back(conn, close=True)
            return "silent"
        return "ok"

    def _give_back(self, conn: psycopg.Connection[Any], *, close: bool = False) -> None:
        with self._guard:
            self._in_use.discard(conn)
        if close:
            # (a shut socket the connection has not read yet: the pool would keep it)
            conn.close()
        self._pool.putconn(conn)

    @contextlib.contextmanager
    def connection(self) -> Iterator[psycopg.Connection[Any]]:
        """A connection for a block (its transaction ended as psycopg's pool ends it).

        Raises
        ------
        Unavailable
            No connection (the database does not answer, every connection stayed busy for
            ``timeout``, or the pool is closed), or the connection failed in the block (a
            lock waited for too long among them).
        """
        conn, pooled = self._getconn()
        try:
            # a pooled connection commits or rolls back and stays open; a request's own
            # closes
            with conn:
                yield conn
        except Exception as exc:
            # a lost connection (the server killed, restarted, cut off) or an operational
            # failure of a live one (shutting down, out of disk, a lock waited for too
            # long); the store's own wrapping (StoreError) of one is recognised by the
            # connection it left broken, or, for its write lock, by its kind
            if conn.broken:
                raise self._down(one_line(exc)) from None
            if isinstance(exc, psycopg.OperationalError):
                raise Unavailable(f"the service's database could not serve the request now "
                                  f"({type(exc).__name__}): {_RETRY}", one_line(exc)) from None
            if isinstance(exc, LockTimeout):
                # the store's line is advice to a command line's user ("raise timeout")
                raise Unavailable("the service's database could not serve the request now "
                                  f"(LockNotAvailable: another upload holds an arc's write "
                                  f"lock): {_RETRY}", one_line(exc)) from None
            raise
        finally:
            if pooled:
                self._give_back(conn)
            else:
                with self._guard:
                    self._in_use.discard(conn)
                conn.close()

    def close(self) -> None:
        """Close the pool (waiting requests fail; connections in use close when returned)."""
        self._pool.close(timeout=5.0)
        self._watchdog.stop()

    def cut(self) -> None:
        """Cut every connection in use, and refuse new ones: each request still blocked on
        the database (one that never answers) fails at once with a 503, its transaction
        rolled back by the server; one waiting for a connection fails within
        ``probe_after`` s. Returns at once (sockets shut down, not closed: :func:`_shut`).
        """
        self._stopping = True
        with self._guard:
            # under the lock: a request gives its connection back (and the pool may close
            # it, its descriptor then reused by another socket) only after taking it
            for conn in self._in_use:
                _shut(conn)
            n = len(self._in_use)
        if n:
            log.warning("stopping: cut %d database connection(s) still in use", n)

    def abort(self) -> None:
        """:meth:`cut`, then close the pool (its threads, daemons, given half a second each:
        one stuck in a connection attempt to a server that does not answer is left)."""
        self.cut()
        self._pool.close(timeout=0.5)
        self._watchdog.stop()

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


def _shut(conn: psycopg.Connection[Any]) -> None:
    """Shut a connection's socket down (both ways), from any thread: the thread reading it
    sees the end of the stream (libpq: "server closed the connection"), the server rolls its
    transaction back. Shut down, not closed: the descriptor stays the connection's until its
    thread gives it back, which closing it under that thread would not give."""
    try:
        fd = os.dup(conn.fileno())
    except (OSError, psycopg.Error):
        return  # closed meanwhile: nothing to cut
    with socket.socket(fileno=fd) as sock, contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)


def make_pool(url: str, *, max_size: int = 8, timeout: float = 30.0,
              probe_after: float = 1.0,
              settings: Mapping[str, str] = CONNECTION_SETTINGS) -> Pool:
    """A pool on the service's database, tables created.

    Parameters
    ----------
    url : str
        A ``postgresql://`` URL (a :class:`PostgresPool` of autocommit connections) or a
        SQLite file path (a :class:`SQLitePool`).
    max_size : int
        Most PostgreSQL connections at once.
    timeout : float
        Seconds a connection is waited for (SQLite: another process's write lock).
    probe_after : float
        PostgreSQL: seconds of waiting for a connection after which the database is asked
        whether it answers (see :class:`PostgresPool`).
    settings : Mapping[str, str]
        PostgreSQL: libpq settings of every connection (:data:`CONNECTION_SETTINGS`); the
        URL's own setting of one wins.
    """
    if not is_postgres_url(url):
        return SQLitePool(url, timeout=timeout)
    # one plain connection first: an unreachable server is one clear error at once, not a
    # pool retrying in the background until its timeout
    connect(url, timeout=timeout).close()
    given = conninfo_to_dict(url)
    params = {k: v for k, v in settings.items() if k not in given}
    pool = ConnectionPool(url, min_size=1, max_size=max_size, timeout=timeout,
                          kwargs={"autocommit": True, **params}, open=False)
    try:
        pool.open(wait=True, timeout=timeout)
    except PoolTimeout as exc:
        pool.close()
        raise StoreError(f"{display_name(url)}: cannot connect to PostgreSQL ({exc}); check "
                         "that the server runs and the URL") from None
    with pool.connection() as conn:
        ensure_schema(conn)
        service_schema(conn)
    return PostgresPool(pool, url, params, timeout=timeout, probe_after=probe_after)


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
