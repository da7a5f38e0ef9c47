"""The demonstration service: tokens, uploads validated as `dataset show` validates,
idempotency, mentors' data, size limit, background recalibration, listings, a schema fuzz, and
real uvicorns on 127.0.0.1 and on localhost (each of its addresses)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import socket
import subprocess
import sys
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

pytest.importorskip("fastapi", reason="the service extra (FastAPI) is not installed")
pytest.importorskip("psycopg", reason="the pg extra (psycopg) is not installed")

from fastapi.testclient import TestClient

from nonprehensile.cli import main
from nonprehensile.demonstrations.dataset import dataset_path
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.pgstore import PostgresStore
from nonprehensile.service import (
    ServiceConfig,
    create_app,
    create_token,
    load_template,
    make_pool,
)
from nonprehensile.service.ingest import CHECKPOINT_N, Registry
from serving import free_port, serve, wait_up

CUBE = dataset_path("cube")
ANN = json.loads((CUBE / "annotations.json").read_text())
MAX_BYTES = 1_000_000
#: Samples an arc gathers before its first clustering (small: uploads cost time).
INIT = 4


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread() -> Iterator[None]:
    # a loaded 2-core machine runs an SVD 10x slower with several BLAS threads than with one
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        yield


def entries(skill: str, mentor: str, n: int) -> list[dict[str, Any]]:
    return [d for d in ANN["demonstrations"]
            if d["skill"] == skill and d["mentor"] == mentor][:n]


def form(entry: dict[str, Any], *, annotation: dict[str, Any] | None = None
         ) -> dict[str, Any]:
    ann = annotation if annotation is not None else {
        k: v for k, v in entry.items() if k not in ("file", "mentor")}
    return {"files": {"file": (entry["file"], (CUBE / entry["file"]).read_bytes(),
                               "application/octet-stream")},
            "data": {"annotation": json.dumps(ann)}}


@pytest.fixture(scope="module")
def template() -> Any:
    return load_template("cube")


@pytest.fixture
def service(pg_url: str, template: Any) -> Iterator[dict[str, Any]]:
    pool = make_pool(pg_url, max_size=6)
    with pool.connection() as conn:
        tokens = {m: create_token(conn, m) for m in ("ana", "ben")}
    registry = Registry(pool, template, init_size=INIT, checkpoint=3)
    app = create_app(pool, template, ServiceConfig("test", max_bytes=MAX_BYTES),
                     registry=registry, background=False)
    with TestClient(app) as client:
        yield {"client": client, "tokens": tokens, "registry": registry, "pool": pool,
               "auth": {m: {"Authorization": f"Bearer {t}"} for m, t in tokens.items()}}
    pool.close()


def test_health_and_openapi(service: dict[str, Any]) -> None:
    c = service["client"]
    assert c.get("/health").json()["status"] == "ok"
    paths = c.get("/openapi.json").json()["paths"]
    assert {"/health", "/demonstrations", "/datasets", "/clusters", "/mentors",
            "/uploads/{digest}", "/recalibrate"} <= set(paths)


def test_every_post_needs_a_token(service: dict[str, Any]) -> None:
    c = service["client"]
    e = entries("push-roll", "ana", 1)[0]
    r = c.post("/demonstrations", **form(e))
    assert r.status_code == 401 and "token" in r.json()["detail"]
    r = c.post("/demonstrations", **form(e), headers={"Authorization": "Bearer np_wrong"})
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
    assert c.post("/recalibrate").status_code == 401
    assert c.delete("/uploads/abc").status_code == 401


def test_uploads_register_to_clusters_idempotently(service: dict[str, Any]) -> None:
    c, auth = service["client"], service["auth"]
    replies = []
    for e in entries("push-roll", "ana", 3) + entries("push-roll", "ben", 3):
        mentor = e["mentor"]
        r = c.post("/demonstrations", **form(e), headers=auth[mentor])
        assert r.status_code == 201, r.text
        replies.append(r.json())
    last = replies[-1]
    # push-roll has 4 motions: 4 segments, each on its arc, clustered once INIT are there
    assert [s["step"] for s in last["segments"]] == [0, 1, 2, 3]
    assert all(s["arc"].startswith("rolling-g0-") for s in last["segments"])
    assert all(isinstance(s["cluster"], int) for s in last["segments"])
    assert replies[0]["segments"][0]["cluster"] is None  # before the first clustering
    # ... and the reply says why, and when the clusters will be named (issue 24)
    first = replies[0]["segments"][0]
    assert first["pending"].startswith("not clustered yet: arc ")
    assert "holds 1 sample(s)" in first["pending"] and "GET /clusters" in first["pending"]
    assert "pending" not in last["segments"][0]
    # the same upload again: one copy, the same reply
    e = entries("push-roll", "ben", 3)[-1]
    again = c.post("/demonstrations", **form(e), headers=auth["ben"])
    assert again.status_code == 200 and again.json()["duplicate"]
    assert again.json()["upload"] == last["upload"]
    arcs = c.get("/clusters").json()["arcs"]
    assert len(arcs) == 4 and all(a["samples"] == 6 and a["pending"] == 0 for a in arcs)
    # a restarted server (no model in memory) rebuilds each arc's model from its checkpoint
    # and the samples stored after it, checking that they get the keys they have
    arc = last["segments"][0]["arc"]
    with service["pool"].connection() as conn:
        store = PostgresStore(conn, arc)
        assert int(store.get_meta(CHECKPOINT_N) or b"0") < store.n_samples
        before = store.keys()
    service["registry"]._cache.clear()
    e = entries("push-roll", "ana", 4)[-1]
    r = c.post("/demonstrations", **form(e), headers=auth["ana"])
    assert r.status_code == 201, r.text
    with service["pool"].connection() as conn:
        assert PostgresStore(conn, arc).keys()[:6] == before
    got = c.get(f"/uploads/{replies[0]['upload']}").json()
    assert got["mentor"] == "ana" and all(s["cluster"] is not None for s in got["segments"])
    stats = {m["mentor"]: m for m in c.get("/mentors").json()["mentors"]}
    assert stats["ana"]["uploads"] == 4 and stats["ben"]["segments"] == 12
    assert c.get("/mentors/ana").json()["skills"] == {"push-roll": 4}
    assert c.get("/mentors/nobody").status_code == 404


def test_bad_uploads_get_the_clis_reasons(service: dict[str, Any], tmp_path: Path) -> None:
    c, auth = service["client"], service["auth"]
    e = entries("twist", "ana", 1)[0]
    bad = {k: v for k, v in e.items() if k not in ("file", "mentor")}
    bad["events"] = list(reversed(bad["events"]))
    r = c.post("/demonstrations", **form(e, annotation=bad), headers=auth["ana"])
    assert r.status_code == 422
    problems = r.json()["problems"]
    # the CLI's lines for the same demonstration in a dataset folder
    folder = tmp_path / "ds"
    folder.mkdir()
    (folder / e["file"]).write_bytes((CUBE / e["file"]).read_bytes())
    top = {k: v for k, v in ANN.items() if k != "demonstrations"}
    top["skills"] = str(CUBE / ANN["skills"])
    (folder / "annotations.json").write_text(json.dumps(
        {**top, "demonstrations": [{**bad, "file": e["file"], "mentor": "ana"}]}))
    cli = CliRunner().invoke(main, ["dataset", "show", str(folder)])
    assert cli.exit_code == 2
    for line in problems:
        assert f"  - {line}" in cli.output.replace("\n    ", " ") or line in cli.output
    # garbage recording, unknown suffix, not JSON, another mentor's name, missing field
    r = c.post("/demonstrations", files={"file": ("t.c3d", b"garbage", "x/y")},
               data={"annotation": json.dumps(bad)}, headers=auth["ana"])
    assert r.status_code == 422 and r.json()["problems"][0].startswith("t.c3d (demonstration 0)")
    r = c.post("/demonstrations", files={"file": ("t.txt", b"x", "x/y")},
               data={"annotation": "{}"}, headers=auth["ana"])
    assert r.status_code == 400 and "unknown trajectory format" in r.json()["detail"]
    r = c.post("/demonstrations", **{**form(e), "data": {"annotation": "{nope"}},
               headers=auth["ana"])
    assert r.status_code == 400 and "malformed JSON" in r.json()["detail"]
    r = c.post("/demonstrations", **form(e, annotation={**bad, "mentor": "ben"}),
               headers=auth["ana"])
    assert r.status_code == 403
    r = c.post("/demonstrations", data={"annotation": "{}"}, headers=auth["ana"])
    assert r.status_code == 400 and "file" in r.json()["detail"]
    # oversized body: refused before it is read
    r = c.post("/demonstrations", files={"file": ("big.c3d", b"\0" * (MAX_BYTES + 1), "x/y")},
               data={"annotation": "{}"}, headers=auth["ana"])
    assert r.status_code == 413
    assert c.get("/clusters").json()["arcs"] == []


def test_mentors_cannot_touch_each_others_data(service: dict[str, Any]) -> None:
    c, auth = service["client"], service["auth"]
    e = entries("roll-arc", "ana", 1)[0]
    up = c.post("/demonstrations", **form(e), headers=auth["ana"]).json()["upload"]
    r = c.delete(f"/uploads/{up}", headers=auth["ben"])
    assert r.status_code == 403 and "'ana'" in r.json()["detail"]
    assert not c.get(f"/uploads/{up}").json()["withdrawn"]
    r = c.delete(f"/uploads/{up}", headers=auth["ana"])
    assert r.status_code == 200 and r.json()["withdrawn"]
    assert c.get("/mentors/ana").json()["withdrawn"] == 1
    assert c.delete("/uploads/nope", headers=auth["ana"]).status_code == 404


def _zip(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in files.items():
            zf.writestr(name, data)
    return buf.getvalue()


def test_dataset_archives(service: dict[str, Any]) -> None:
    c, auth = service["client"], service["auth"]
    demos = entries("tumble-lift", "ben", 3)
    skills = (CUBE / ANN["skills"]).read_bytes()
    top = {k: v for k, v in ANN.items() if k != "demonstrations"}
    files = {f"takes/{d['file']}": (CUBE / d["file"]).read_bytes() for d in demos}
    files["takes/skills.json"] = skills
    files["takes/annotations.json"] = json.dumps({**top, "demonstrations": demos}).encode()
    archive = _zip(files)
    r = c.post("/datasets", files={"archive": ("t.zip", archive, "application/zip")},
               headers=auth["ben"])
    assert r.status_code == 201, r.text
    assert r.json()["stored"] == 3 and len(r.json()["uploads"]) == 3
    r = c.post("/datasets", files={"archive": ("t.zip", archive, "application/zip")},
               headers=auth["ben"])
    assert r.status_code == 200 and r.json()["duplicates"] == 3
    r = c.post("/datasets", files={"archive": ("t.zip", archive, "application/zip")},
               headers=auth["ana"])
    assert r.status_code == 403 and "'ben'" in r.json()["detail"]
    evil = _zip({"../escape.txt": b"x", "annotations.json": b"{}"})
    r = c.post("/datasets", files={"archive": ("e.zip", evil, "application/zip")},
               headers=auth["ben"])
    assert r.status_code == 400 and "outside" in r.json()["detail"]
    r = c.post("/datasets", files={"archive": ("e.zip", b"not an archive", "x/y")},
               headers=auth["ben"])
    assert r.status_code == 400


def test_background_recalibration_never_blocks_uploads(
    service: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    c, auth, reg = service["client"], service["auth"], service["registry"]
    first = entries("twist", "ana", 4) + entries("twist", "ben", 4)
    for e in first:
        assert c.post("/demonstrations", **form(e), headers=auth[e["mentor"]]).status_code == 201
    due = reg.arcs_due()
    assert due and all(a.startswith("rotating-") for a in due)
    arc = due[0]
    # uploads made while the recalibration computes: they must not wait for it (a lock held
    # here would make them time out), and they end up registered to the new model
    late = entries("twist", "chen", 2)
    real = HilbertClusterer.recalibrate
    with service["pool"].connection() as conn:
        chen = create_token(conn, "chen")
    auth["chen"] = {"Authorization": f"Bearer {chen}"}

    def during(self: HilbertClusterer) -> HilbertClusterer:
        t0 = time.perf_counter()
        for e in late:
            r = c.post("/demonstrations", **form(e), headers=auth["chen"])
            assert r.status_code == 201, r.text
        assert time.perf_counter() - t0 < 20
        return real(self)

    monkeypatch.setattr(HilbertClusterer, "recalibrate", during)
    res = reg.recalibrate(arc)
    monkeypatch.setattr(HilbertClusterer, "recalibrate", real)
    assert res["recalibrated"] and res["during"] == 2 and res["samples"] == 10
    listing = {a["arc"]: a for a in c.get("/clusters").json()["arcs"]}
    assert listing[arc]["recalibrated_at"] == 10 and listing[arc]["pending"] == 0
    assert sum(cl["size"] for cl in listing[arc]["clusters"]) == 10
    assert c.post("/recalibrate", headers=auth["ana"]).status_code == 202


def test_schema_fuzz_never_500(service: dict[str, Any]) -> None:
    schemathesis = pytest.importorskip("schemathesis")
    from hypothesis import HealthCheck, settings

    app = service["client"].app
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    token = service["tokens"]["ana"]
    failures = []
    for op in schema.get_all_operations():
        operation = op.ok()

        @settings(max_examples=8, deadline=None, database=None,
                  suppress_health_check=list(HealthCheck))
        def check(case: Any) -> None:
            headers = {"Authorization": f"Bearer {token}"}
            response = case.call(headers=headers)
            if response.status_code >= 500:
                failures.append((case.method, case.path, response.status_code,
                                 response.text[:200]))

        from hypothesis import given

        given(operation.as_strategy())(check)()
    assert not failures, failures


@pytest.mark.parametrize("backend", ["postgresql", "sqlite"])
def test_real_uvicorn_on_loopback(backend: str, request: pytest.FixtureRequest,
                                  tmp_path: Path) -> None:
    """A real server on each store: tokens by the CLI, concurrent uploads (the same one
    twice at once among them), kill -9, restart: every upload answered 2xx is stored once."""
    import httpx

    store = (request.getfixturevalue("pg_url") if backend == "postgresql"
             else str(tmp_path / "service.db"))
    runner = CliRunner()
    r = runner.invoke(main, ["serve", "token", "create", "dana", "--store", store, "--json"])
    assert r.exit_code == 0, r.output
    token = json.loads(r.stdout)["token"]
    r = runner.invoke(main, ["serve", "token", "list", "--store", store, "--json"])
    assert json.loads(r.stdout)["mentors"] == [
        {"mentor": "dana", "tokens": 1, "since": json.loads(r.stdout)["mentors"][0]["since"]}]
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    auth = {"Authorization": f"Bearer {token}"}
    takes = entries("roll-pull", "chen", 2)
    jobs = [takes[0], takes[1], takes[1]]  # takes[1] twice, at the same time

    def send(e: dict[str, Any]) -> httpx.Response:
        ann = {k: v for k, v in e.items() if k not in ("file", "mentor")}
        return httpx.post(f"{url}/demonstrations", files=form(e)["files"],
                          data={"annotation": json.dumps(ann)}, headers=auth, timeout=60)

    proc = serve(store, port)
    try:
        wait_up(url, proc)
        e = takes[0]
        ann = {k: v for k, v in e.items() if k not in ("file", "mentor")}
        r = httpx.post(f"{url}/demonstrations", files=form(e)["files"],
                       data={"annotation": json.dumps({**ann, "mentor": "chen"})},
                       headers=auth, timeout=60)
        assert r.status_code == 403  # the entry is chen's, the token dana's
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(3) as ex:
            replies = list(ex.map(send, jobs))
        assert sorted(r.status_code for r in replies) == [200, 201, 201], [
            r.text for r in replies]
        assert replies[0].json()["mentor"] == "dana" and len(replies[0].json()["segments"]) >= 2
        proc.kill()  # SIGKILL: no shutdown of any kind
        proc.wait()
        proc = serve(store, port)
        wait_up(url, proc)
        again = [send(e) for e in takes]
        assert all(r.status_code == 200 and r.json()["duplicate"] for r in again), [
            (r.status_code, r.text[:300]) for r in again]
        assert {r.json()["upload"] for r in again} == {r.json()["upload"] for r in replies}
        stats = httpx.get(f"{url}/mentors/dana", timeout=30).json()
        assert stats["uploads"] == 2
        assert stats["segments"] == sum(len(r.json()["segments"]) for r in again)
        # Ctrl-C, the documented stop: exit 0, no click "Aborted!" (the command's own
        # listening socket once let uvicorn's re-raised interrupt reach click: exit 1)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
        assert "Aborted" not in (proc.stderr.read().decode() if proc.stderr else "")
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_same_results_from_sqlite_and_postgresql(pg_url: str, tmp_path: Path,
                                                 template: Any) -> None:
    """The same uploads to a service on each store: the same replies, clusters, statistics,
    before and after a background recalibration."""

    def run(store: str) -> list[Any]:
        pool = make_pool(store, max_size=4)
        with pool.connection() as conn:
            tokens = {m: create_token(conn, m) for m in ("ana", "ben")}
        registry = Registry(pool, template, init_size=INIT, checkpoint=3)
        app = create_app(pool, template, ServiceConfig("test"), registry=registry,
                         background=False)
        docs: list[Any] = []
        with TestClient(app) as c:
            for e in entries("twist", "ana", 4) + entries("twist", "ben", 4):
                r = c.post("/demonstrations", **form(e),
                           headers={"Authorization": f"Bearer {tokens[e['mentor']]}"})
                assert r.status_code == 201, r.text
                docs.append(r.json())
            docs.append(c.get("/clusters").json())
            assert registry.arcs_due()
            docs.extend(registry.recalibrate(arc) for arc in registry.arcs_due())
            docs.append(c.get("/clusters").json())
            docs.append(c.get("/mentors").json())
            docs.extend(c.get(f"/uploads/{d['upload']}").json() for d in docs[:8])
        pool.close()
        return docs

    sqlite = run(str(tmp_path / "service.db"))
    assert run(pg_url) == sqlite
    assert any(a["clusters"] for a in sqlite[8]["arcs"])  # clustered, not all pending


def test_serve_refuses_what_it_cannot_serve(tmp_path: Path) -> None:
    runner = CliRunner()
    # a `cluster` store file is not the service's database
    arrays = tmp_path / "x.npy"
    import numpy as np

    np.save(arrays, np.random.default_rng(0).normal(size=(30, 4)))
    r = runner.invoke(main, ["cluster", "fit", str(tmp_path / "c.db"), "--arrays", str(arrays),
                             "--n-clusters", "2"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(main, ["serve", "--store", str(tmp_path / "c.db"), "--port", "0"])
    assert r.exit_code == 2 and "`nonprehensile cluster` store" in r.output
    # and the other way: `cluster` leaves the service's database as it was
    svc = tmp_path / "svc.db"
    r = runner.invoke(main, ["serve", "token", "create", "alice", "--store", str(svc)])
    assert r.exit_code == 0, r.output
    import sqlite3

    def tables() -> set[str]:
        with contextlib.closing(sqlite3.connect(svc)) as db:
            return {t for (t,) in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}

    before = tables()
    for cmd in (["cluster", "fit", str(svc), "--arrays", str(arrays), "--n-clusters", "2"],
                ["cluster", "show", str(svc)]):
        r = runner.invoke(main, cmd)
        assert r.exit_code == 2 and "`nonprehensile serve` database" in r.output, r.output
    assert tables() == before and "samples" not in before
    (tmp_path / "notes.txt").write_text("not a database, not at all " * 100)
    r = runner.invoke(main, ["serve", "token", "list", "--store", str(tmp_path / "notes.txt")])
    assert r.exit_code == 2 and "notes.txt" in r.output and "Traceback" not in r.output
    r = runner.invoke(main, ["serve"])
    assert r.exit_code == 2 and "--store" in r.output
    r = runner.invoke(main, ["serve", "token", "create", " ", "--store",
                             "postgresql://nobody@/nodb?host=/nonexistent-dir"])
    assert r.exit_code == 1 and "cannot connect" in r.output and "Traceback" not in r.output


def test_serve_on_a_taken_port_or_unknown_host_is_bad_input(tmp_path: Path) -> None:
    """An address in use (or not this machine's) is exit 2, one line naming --host/--port,
    and the store is not created; it was uvicorn's own "ERROR: [Errno 98] ..." and exit 3."""
    store = tmp_path / "svc.db"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = CliRunner().invoke(main, ["serve", "--store", str(store), "--host", "127.0.0.1",
                                      "--port", str(port)])
    assert r.exit_code == 2, r.output
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and "--port" in line and str(port) in line, r.stderr
    assert not store.exists()
    r = CliRunner().invoke(main, ["serve", "--store", str(store), "--host", "999.1.1.1",
                                  "--port", "0"])
    assert r.exit_code == 2 and "--host" in r.stderr and "999.1.1.1" in r.stderr, r.output
    assert len(r.stderr.strip().splitlines()) == 1 and not store.exists()


#: ``python -c`` for a server on a machine whose ``localhost`` is ``::1`` first, then
#: ``127.0.0.1`` (the hosts file of many Linux distributions, and macOS): ``localhost``
#: resolves so, everything else as the system resolves it.
_IPV6_FIRST = """
import socket, sys
real = socket.getaddrinfo
def getaddrinfo(host, *args, **kwargs):
    if host == "localhost":
        return real("::1", *args, **kwargs) + real("127.0.0.1", *args, **kwargs)
    return real(host, *args, **kwargs)
socket.getaddrinfo = getaddrinfo
from nonprehensile.cli import main
sys.exit(main())
"""


def _ipv6_loopback() -> bool:
    """Whether this machine can listen on ``::1``."""
    try:
        with socket.socket(socket.AF_INET6) as s:
            s.bind(("::1", 0))
    except OSError:
        return False
    return True


@pytest.mark.parametrize("address", ["127.0.0.1", "::1"])
def test_serve_on_localhost_listens_on_each_of_its_addresses(address: str,
                                                             tmp_path: Path) -> None:
    """``--host localhost`` where localhost is ``::1`` first: http://127.0.0.1:PORT/ and
    http://localhost:PORT/ answer (only ``::1`` was bound: refused), and so does
    http://[::1]:PORT/ where this machine has IPv6; Ctrl-C stops it with exit 0."""
    import re
    import threading

    import httpx

    if address == "::1" and not _ipv6_loopback():
        pytest.skip("this machine cannot listen on ::1 (no IPv6 loopback): the IPv6 half of "
                    "localhost is not checked here; the 127.0.0.1 case still is")
    proc = subprocess.Popen(
        [sys.executable, "-c", _IPV6_FIRST, "serve", "--store", str(tmp_path / "svc.db"),
         "--host", "localhost", "--port", "0", "--recalibrate-every", "0"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})
    said: list[str] = []
    assert proc.stderr is not None
    reader = threading.Thread(target=lambda: said.extend(proc.stderr or ()), daemon=True)
    reader.start()
    try:
        port = None
        for _ in range(600):  # --port 0: the port it chose is on its "serving" line
            found = re.search(r"http://localhost:(\d+)", "".join(said))
            if found or proc.poll() is not None:
                port = found and int(found.group(1))
                break
            time.sleep(0.05)
        assert port, "the server did not say where it serves: " + "".join(said)[:500]
        host = f"[{address}]" if ":" in address else address
        urls = [f"http://{host}:{port}/health"]
        if address == "127.0.0.1":
            urls.append(f"http://localhost:{port}/health")
        for url in urls:
            for _ in range(100):  # listening since before the line; the app may start late
                try:
                    r = httpx.get(url, timeout=2)
                    break
                except httpx.ConnectError:
                    if proc.poll() is not None:
                        break
                    time.sleep(0.1)
            else:
                pytest.fail(f"{url}: refused")
            assert proc.poll() is None, "".join(said)[:500]
            assert r.status_code == 200, (url, r.text[:200])
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        reader.join(timeout=5)


def test_listening_on_several_addresses(monkeypatch: pytest.MonkeyPatch,
                                        tmp_path: Path) -> None:
    """The sockets behind --host: an address this machine does not have is left out when
    another is bound (localhost's ::1 on a machine without IPv6); a port taken on any of
    them is exit 2, one line, every socket closed, no store made."""
    from nonprehensile.cli import serve

    # 192.0.2.1 (TEST-NET-1, RFC 5737) is nobody's address: EADDRNOTAVAIL, as ::1 without IPv6
    socks = serve._bind_all([(socket.AF_INET, ("192.0.2.1", 0)),
                             (socket.AF_INET, ("127.0.0.1", 0))])
    try:
        assert [s.getsockname()[0] for s in socks] == ["127.0.0.1"]
    finally:
        for s in socks:
            s.close()
    with pytest.raises(OSError):
        serve._bind_all([(socket.AF_INET, ("192.0.2.1", 0))])

    real = socket.getaddrinfo
    # localhost as two addresses of which the second is taken (another program's server)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        try:
            with socket.socket() as probe:
                probe.bind(("127.0.0.2", 0))
        except OSError:
            pytest.skip("no 127.0.0.2 on this machine (Linux answers on all of 127/8): the "
                        "port taken on a second address is not checked; the rest was")

        def two(host: str, *args: Any, **kwargs: Any) -> Any:
            if host == "localhost":
                return real("127.0.0.2", *args, **kwargs) + real("127.0.0.1", *args, **kwargs)
            return real(host, *args, **kwargs)

        def no_store(*args: Any, **kwargs: Any) -> Any:  # past the sockets: fail, not serve
            raise AssertionError("it listened although the port is taken on 127.0.0.1")

        monkeypatch.setattr(socket, "getaddrinfo", two)
        monkeypatch.setattr("nonprehensile.service.make_pool", no_store)
        store = tmp_path / "svc.db"
        r = CliRunner().invoke(main, ["serve", "--store", str(store), "--host", "localhost",
                                      "--port", str(port)])
        monkeypatch.undo()
        assert r.exit_code == 2, r.output
        assert len(r.stderr.strip().splitlines()) == 1 and str(port) in r.stderr
        assert not store.exists()
        # the socket bound on 127.0.0.2 before the failure was closed: the port is free there
        with socket.socket() as again:
            again.bind(("127.0.0.2", port))


def test_serve_writes_an_ipv6_address_as_a_url_does(monkeypatch: pytest.MonkeyPatch,
                                                    tmp_path: Path) -> None:
    """The "serving" line's URL, the one a user copies: ``http://[::1]:PORT``, not
    ``http://::1:PORT`` (which no client reads)."""
    import re

    import uvicorn

    if not _ipv6_loopback():
        pytest.skip("this machine cannot listen on ::1 (no IPv6 loopback)")

    def interrupted(self: Any, sockets: Any = None) -> None:  # Ctrl-C at once
        raise KeyboardInterrupt

    monkeypatch.setattr(uvicorn.Server, "run", interrupted)
    r = CliRunner().invoke(main, ["serve", "--store", str(tmp_path / "svc.db"), "--host",
                                  "::1", "--port", "0", "--recalibrate-every", "0"])
    assert r.exit_code == 0, r.output
    assert re.search(r"http://\[::1\]:\d+ ", r.stderr), r.stderr
