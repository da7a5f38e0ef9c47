"""The service when its PostgreSQL database fails under it: a request answers a 503 with one
line at once (not a 500, not a wait of the pool's 30 s), the service serves again when the
database is back (its dead connections replaced, not failed in a request), and `serve` stops
promptly on SIGTERM even with a request blocked on a database that never answers (uvicorn's
graceful shutdown waited for it for ever: the benchmark's server had to be SIGKILLed).

The outage is of the test's own database only (the server is shared by the tests running at
once): its connections terminated and new ones refused (``ALLOW_CONNECTIONS false``), or a
table locked by the test, so that a request's query waits as on a server that does not
answer.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from typing import Any
from urllib.parse import urlsplit

import pytest

pytest.importorskip("fastapi", reason="the service extra (FastAPI) is not installed")
pytest.importorskip("psycopg", reason="the pg extra (psycopg) is not installed")

import psycopg
from fastapi.testclient import TestClient
from psycopg.conninfo import conninfo_to_dict

from nonprehensile.demonstrations.dataset import dataset_path
from nonprehensile.service import ServiceConfig, create_app, create_token, load_template, make_pool
from nonprehensile.service.ingest import Registry
from serving import free_port, serve, wait_up

CUBE = dataset_path("cube")
ANN = json.loads((CUBE / "annotations.json").read_text())


def _form(k: int) -> dict[str, Any]:
    e = [d for d in ANN["demonstrations"] if d["mentor"] == "ana"][k]
    ann = {key: v for key, v in e.items() if key not in ("file", "mentor")}
    return {"files": {"file": (e["file"], (CUBE / e["file"]).read_bytes(),
                               "application/octet-stream")},
            "data": {"annotation": json.dumps(ann)}}


def _dbname(url: str) -> str:
    return urlsplit(url).path.lstrip("/")


def _refuse(admin: str, db: str, refuse: bool) -> None:
    """Make the test's database refuse new connections and end its present ones (or accept
    them again): for the service, as the server going down (or coming back)."""
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f"ALTER DATABASE {db} ALLOW_CONNECTIONS {'false' if refuse else 'true'}")
        if refuse:
            conn.execute("SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                         "WHERE datname = %s AND pid <> pg_backend_pid()", (db,))


def _check_one_line(r: Any, pg_url: str) -> None:
    assert r.status_code == 503, r.text
    body = r.json()
    assert "\n" not in body["detail"] and "try again later" in body["detail"], body
    # the server's own words (the socket's folder, the host) stay in its log
    host = str(conninfo_to_dict(pg_url).get("host") or "localhost")
    assert "PGSQL" not in r.text and host not in r.text, body
    assert r.headers["retry-after"]


@pytest.fixture
def service(pg_url: str) -> Iterator[dict[str, Any]]:
    pool = make_pool(pg_url, max_size=4)
    with pool.connection() as conn:
        token = create_token(conn, "ana")
    registry = Registry(pool, load_template("cube"), init_size=4, checkpoint=3)
    app = create_app(pool, registry.template, ServiceConfig("test"), registry=registry,
                     background=False)
    # a 500 comes back as the response a client sees, not as the exception
    with TestClient(app, raise_server_exceptions=False) as client:
        yield {"client": client, "auth": {"Authorization": f"Bearer {token}"}}
    pool.close()


def test_a_database_outage_answers_503_at_once_and_the_service_recovers(
        service: dict[str, Any], pg_url: str, pg_server: str) -> None:
    c, auth = service["client"], service["auth"]
    assert c.post("/demonstrations", **_form(0), headers=auth).status_code == 201
    db = _dbname(pg_url)
    _refuse(pg_server, db, True)
    try:
        # the pool's connections are dead and no new one can be made: every request says so
        # in one line, the first at once (its connection fails), the next after a probe of
        # the database (not the pool's whole timeout, 30 s)
        for path in ("/demonstrations", "/health", "/demonstrations"):
            t0 = time.monotonic()
            r = (c.post(path, **_form(1), headers=auth) if path == "/demonstrations"
                 else c.get(path))
            assert time.monotonic() - t0 < 15, path  # (with the fix: about 1 s)
            _check_one_line(r, pg_url)
    finally:
        _refuse(pg_server, db, False)
    # back: the dead connections are replaced, not failed in a client's request
    deadline = time.monotonic() + 30
    while True:
        r = c.post("/demonstrations", **_form(1), headers=auth)
        if r.status_code != 503 or time.monotonic() > deadline:
            break
        time.sleep(0.5)  # (psycopg's pool reconnects after a back-off)
    assert r.status_code == 201, r.text
    with psycopg.connect(pg_url) as conn:
        n_uploads = conn.execute("SELECT count(*) FROM np_uploads").fetchone()[0]
        orphans = conn.execute(
            "SELECT count(*) FROM np_samples s LEFT JOIN np_upload_samples u "
            "ON u.arc = s.store AND u.sample = s.id WHERE u.hash IS NULL").fetchone()[0]
    assert (n_uploads, orphans) == (2, 0)


def test_serve_stops_promptly_with_a_request_blocked_on_the_database(pg_url: str) -> None:
    """SIGTERM while a request waits on the database for ever (here: a lock the test holds,
    as a server that does not answer): the request is cut after --shutdown-timeout, answers
    its 503, and `serve` exits; nothing of it is stored."""
    import httpx

    pool = make_pool(pg_url, max_size=2)
    with pool.connection() as conn:
        token = create_token(conn, "ana")
    pool.close()
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    proc = serve(pg_url, port, "--shutdown-timeout", "1")
    locker = psycopg.connect(pg_url)
    try:
        wait_up(base, proc)
        # the upload's first query (its token's mentor) waits for this lock
        locker.execute("LOCK TABLE np_tokens IN ACCESS EXCLUSIVE MODE")
        replies: list[Any] = []
        t = threading.Thread(target=lambda: replies.append(httpx.post(
            f"{base}/demonstrations", **_form(0), headers={"Authorization": f"Bearer {token}"},
            timeout=120)))
        t.start()
        with psycopg.connect(pg_url, autocommit=True) as watch:
            for _ in range(600):  # until the request's query waits for the lock
                if watch.execute("SELECT count(*) FROM pg_stat_activity WHERE datname = %s "
                                 "AND wait_event_type = 'Lock'", (_dbname(pg_url),)
                                 ).fetchone()[0]:
                    break
                time.sleep(0.05)
            else:
                pytest.fail("the upload never reached the database")
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        try:
            code = proc.wait(timeout=30)  # (with the fix: about 2 s; before it, never)
        except subprocess.TimeoutExpired:
            pytest.fail("serve did not stop within 30 s of SIGTERM with a request blocked on "
                        "the database")
        assert time.monotonic() - t0 < 30
        assert code in (0, -signal.SIGTERM), code  # (uvicorn ends by the signal it caught)
        t.join(timeout=30)
        assert replies and replies[0].status_code == 503, replies and replies[0].text
        assert "\n" not in replies[0].json()["detail"]
    finally:
        locker.rollback()
        locker.close()
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    with psycopg.connect(pg_url) as conn:
        assert conn.execute("SELECT count(*) FROM np_uploads").fetchone()[0] == 0


# ---------------------------------------------------------------- the pool's own logic
# Fakes of psycopg's pool and its connections: a connection's check waits for its server's
# answer on a socket pair, so that a server that never answers is simulated without
# stopping a PostgreSQL server (the test server is shared).

_NOWHERE = "postgresql://nobody@/nowhere?host=/nonexistent-np-socket-folder"


class _FakeConn:
    """A pooled connection whose empty query the server answers at once (``"now"``), after
    ``late`` s whatever happens to the socket (``"late"``), or never (``"never"``: the query
    waits until the socket is shut down, then fails as libpq does)."""

    def __init__(self, answer: str = "now", late: float = 0.0) -> None:
        self.answer, self.late = answer, late
        self.ours, self.server = socket.socketpair()
        self.closed = self.broken = False
        self.checks = 0

    def fileno(self) -> int:
        return self.ours.fileno()

    def execute(self, query: str) -> None:
        self.checks += 1
        if self.answer == "late":
            time.sleep(self.late)
        elif self.answer == "never":
            self.ours.recv(1)  # (b"" once the socket is shut down)
            self.broken = True
            raise psycopg.OperationalError("server closed the connection unexpectedly")

    def __enter__(self) -> _FakeConn:
        return self

    def __exit__(self, *exc: object) -> None:
        pass  # (a pooled connection stays open)

    def close(self) -> None:
        self.closed = True
        self.ours.close()
        self.server.close()


class _FakePool:
    """psycopg's pool with these idle connections; none more (a wait times out)."""

    def __init__(self, conns: list[_FakeConn], max_size: int = 4) -> None:
        self.idle = list(conns)
        self.max_size = max_size
        self.returned: list[_FakeConn] = []

    def getconn(self, timeout: float | None = None) -> _FakeConn:
        from psycopg_pool import PoolTimeout

        if self.idle:
            return self.idle.pop(0)
        time.sleep(timeout or 0.0)
        raise PoolTimeout("no connection")

    def putconn(self, conn: _FakeConn) -> None:
        self.returned.append(conn)

    def close(self, timeout: float | None = None) -> None:
        pass


def test_a_server_that_does_not_answer_a_check_fails_the_request_after_one_check() -> None:
    """A frozen server (SIGSTOP): the check of the first idle connection is cut after
    ``check_timeout`` and the request answers 503 at once (it held the request a timeout per
    idle connection: 8 idle, 40 s, past the pool's 30 s, answered "overloaded")."""
    from nonprehensile.service.db import PostgresPool
    from nonprehensile.service.errors import Unavailable

    conns = [_FakeConn("never") for _ in range(3)]
    fake = _FakePool(conns)
    pool = PostgresPool(fake, _NOWHERE, {}, timeout=5.0, probe_after=0.2,  # type: ignore[arg-type]
                        check_timeout=0.3)
    pool._probe = lambda: None  # type: ignore[method-assign]  # (as a server accepting)
    try:
        t0 = time.monotonic()
        with pytest.raises(Unavailable, match="database is unavailable"), pool.connection():
            pass
        assert time.monotonic() - t0 < 0.85  # (before: 0.3 s per idle connection, then more)
        assert [c.checks for c in conns] == [1, 0, 0]
        assert fake.returned == [conns[0]] and conns[0].closed and not pool._in_use
    finally:
        pool.close()
        for c in conns:
            c.close()


def test_a_check_cut_just_as_it_answered_is_not_used() -> None:
    """The watchdog cuts a check that overran its timeout even if the answer comes right
    then: the connection (its socket shut down) is dropped, not given to the request."""
    from nonprehensile.service.db import PostgresPool
    from nonprehensile.service.errors import Unavailable

    conn = _FakeConn("late", late=0.3)
    fake = _FakePool([conn])
    pool = PostgresPool(fake, _NOWHERE, {}, timeout=5.0, check_timeout=0.05)  # type: ignore[arg-type]
    try:
        with pytest.raises(Unavailable, match="database is unavailable"), pool.connection():
            pytest.fail("the request got a connection that was cut")
        assert conn.closed and fake.returned == [conn] and not pool._in_use
    finally:
        pool.close()
        conn.close()


def test_checks_start_no_thread_per_checkout(monkeypatch: pytest.MonkeyPatch) -> None:
    """The checks share one watchdog thread (a ``threading.Timer`` per checkout cost 0.6 ms,
    several times the checkout and its query); closing the pool stops it."""
    from nonprehensile.service.db import PostgresPool

    started: list[threading.Thread] = []
    start = threading.Thread.start

    def counted(self: threading.Thread) -> None:
        started.append(self)
        start(self)

    monkeypatch.setattr(threading.Thread, "start", counted)
    conns = [_FakeConn() for _ in range(50)]
    fake = _FakePool(conns)
    pool = PostgresPool(fake, _NOWHERE, {})  # type: ignore[arg-type]
    for _ in range(50):
        with pool.connection() as conn:
            assert conn.checks == 1
    assert len(started) == 1 and started[0].daemon and started[0].is_alive()
    assert len(fake.returned) == 50 and not any(c.closed for c in conns)
    pool.close()
    assert not started[0].is_alive()
    for c in conns:
        c.close()


def test_a_request_is_served_on_its_own_connection_while_the_pool_reconnects(
        pg_url: str) -> None:
    """The database answers but the pool gives no connection (psycopg's pool waits out its
    reconnection back-off, up to a minute apart after a long outage): after ``probe_after``
    the request is served on a connection of its own, closed after it; with the pool's
    ``max_size`` connections in use, a request waits (an overload) and says so."""
    from nonprehensile.service.db import PostgresPool
    from nonprehensile.service.errors import Unavailable

    fake = _FakePool([], max_size=1)
    pool = PostgresPool(fake, pg_url, {}, timeout=3.0, probe_after=0.1)  # type: ignore[arg-type]
    try:
        t0 = time.monotonic()
        with pool.connection() as conn:
            assert conn.execute("SELECT 1").fetchone() == (1,)
            assert conn.autocommit
            assert time.monotonic() - t0 < 1.5  # (before: 3 s, then "overloaded")
            pool.timeout = 0.5
            with pytest.raises(Unavailable, match="overloaded"), pool.connection():
                pass
        assert conn.closed and not pool._in_use and fake.returned == []
    finally:
        pool.close()


def test_an_arc_write_lock_waited_for_too_long_answers_503_to_retry(pg_url: str) -> None:
    """The arc store's write lock not taken in time: a 503 to retry (Retry-After), not the
    command line's advice ("raise timeout"), which the command line still gives."""
    from nonprehensile.errors import StoreError
    from nonprehensile.motion.pgstore import PostgresStore, _lock_id
    from nonprehensile.service.errors import Unavailable

    pool = make_pool(pg_url, max_size=2)
    with psycopg.connect(pg_url, autocommit=True) as holder:
        holder.execute("SELECT pg_advisory_lock(%s)", (_lock_id("a-b"),))
        try:
            with pytest.raises(Unavailable, match="LockNotAvailable") as err, \
                    pool.connection() as conn, PostgresStore(conn, "a-b", timeout=0.2) as store, \
                    store.transaction():
                pass
            assert "raise timeout" not in str(err.value) and "try again later" in str(err.value)
            with pytest.raises(StoreError, match="retry, or raise timeout"), \
                    PostgresStore(pg_url, "a-b", timeout=0.2) as store, store.transaction():
                pass
        finally:
            pool.close()
