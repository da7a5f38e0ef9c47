"""The demonstration service under load, on loopback, with a crash in the middle.

8 concurrent uploaders send the bundled dataset's 180 recordings (each with its mentor's
token) to ``nonprehensile serve`` on 127.0.0.1, once backed by PostgreSQL and once by a SQLite
file. After a third of them the server is killed with SIGKILL and started again; uploaders
retry what failed (an upload is idempotent). Checked afterwards, in the database: every upload
that got a 2xx is stored, each of the 180 exactly once, every stored sample belongs to exactly
one upload and every upload has all its segments (nothing half-written), and each arc's
clusterer state agrees with its samples. Reported: throughput and p50/p99 latency.

Then the registration throughput into PostgreSQL with batched inserts, through the clusterer:
flattened segments (4 800 floats each, as the cube dataset's) registered by a clusterer on a
``PostgresStore`` in batches of 500 (keying, clustering, one COPY, one transaction a batch with
the arc's generation marker, the model checkpointed every 4 096 samples, as the service
does), by 2 processes at once, one arc each (the service's arcs are independent stores of one
database): the samples of both over the wall time. Also one stream alone, the client's and
the server's CPU per sample, and the bare ``PostgresStore.add`` (COPY) for comparison.

The server comes from ``NONPREHENSILE_TEST_PG`` or is started with ``.ci/start-postgres``.
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit, urlunsplit

import numpy as np

REPO = Path(__file__).resolve().parents[1]
N_UPLOADERS = 8
KILL_AFTER = 60  # uploads answered before the server is killed
GOAL_SAMPLES_PER_S = 2000.0


_SERVER: dict[str, str] = {}


def _server() -> tuple[str, str | None]:
    """The PostgreSQL URL (``NONPREHENSILE_TEST_PG``, or one server started for the run)."""
    url = os.environ.get("NONPREHENSILE_TEST_PG")
    if url:
        return url, None
    if not _SERVER:
        tmp = tempfile.mkdtemp(prefix="np-bench-pg-")
        proc = subprocess.run([str(REPO / ".ci" / "start-postgres"), tmp], capture_output=True,
                              text=True, check=True, timeout=120)
        _SERVER.update(url=proc.stdout.strip().splitlines()[-1], tmp=tmp)
    return _SERVER["url"], None


def _stop_server() -> None:
    if _SERVER:
        subprocess.run([str(REPO / ".ci" / "stop-postgres"), _SERVER["tmp"]], check=False)
        shutil.rmtree(_SERVER["tmp"], ignore_errors=True)
        _SERVER.clear()


_DBS: list[tuple[str, str]] = []


def _fresh_db(url: str) -> str:
    """A new database on the server (dropped at the end of the run)."""
    import psycopg

    name = f"bench_{uuid.uuid4().hex[:10]}"
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute(f"CREATE DATABASE {name}")
    _DBS.append((url, name))
    return urlunsplit(urlsplit(url)._replace(path=f"/{name}"))


def _drop_dbs() -> None:
    import psycopg

    for url, name in _DBS:
        with psycopg.connect(url, autocommit=True) as conn:
            conn.execute(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)")
    _DBS.clear()


_TMP: list[str] = []
#: The `serve` processes this run started (stopped at the end, whatever happened).
_SERVES: list[subprocess.Popen[bytes]] = []


def _sqlite_file() -> str:
    """A new SQLite file for the service, in a folder removed at the end of the run."""
    _TMP.append(tempfile.mkdtemp(prefix="np-bench-sqlite-"))
    return str(Path(_TMP[-1]) / "service.db")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start(db: str, port: int) -> subprocess.Popen[bytes]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "nonprehensile.cli", "serve", "--store", db, "--host",
         "127.0.0.1", "--port", str(port), "--recalibrate-every", "2"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    _SERVES.append(proc)
    return proc


def _stop_serves() -> None:
    """Stop every `serve` this run started that is still running (a load test that failed
    half-way left its server running past the benchmark)."""
    for proc in _SERVES:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)


def _wait_up(base: str, timeout: float = 120.0) -> None:
    import httpx

    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        try:
            if httpx.get(f"{base}/health", timeout=2).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    raise RuntimeError("the server did not come up")


def load_test(kind: str = "postgresql") -> dict[str, Any]:
    """The load test on a fresh PostgreSQL database (``kind="postgresql"``) or SQLite file."""
    import httpx

    from nonprehensile.demonstrations.dataset import dataset_path
    from nonprehensile.service.db import create_token, make_pool

    db = _fresh_db(_server()[0]) if kind == "postgresql" else _sqlite_file()
    pool = make_pool(db, max_size=2)
    with pool.connection() as conn:
        tokens = {m: create_token(conn, m) for m in ("ana", "ben", "chen")}
    pool.close()
    cube = dataset_path("cube")
    ann = json.loads((cube / "annotations.json").read_text())["demonstrations"]
    jobs: queue.Queue[dict[str, Any]] = queue.Queue()
    for e in ann:
        jobs.put(e)
    port = _port()
    base = f"http://127.0.0.1:{port}"
    server = {"proc": _start(db, port)}
    _wait_up(base)
    lat: list[float] = []
    ok: dict[str, str] = {}  # file -> upload hash, from 2xx replies
    duplicates = 0
    retries = 0
    answered = 0
    lock = threading.Lock()
    killed = threading.Event()

    def uploader() -> None:
        nonlocal duplicates, retries, answered
        with httpx.Client(timeout=120) as client:
            while True:
                try:
                    e = jobs.get_nowait()
                except queue.Empty:
                    return
                ann_entry = {k: v for k, v in e.items() if k not in ("file", "mentor")}
                body = (cube / e["file"]).read_bytes()
                for _attempt in range(200):  # bounded: a server down for good ends the run
                    t0 = time.perf_counter()
                    try:
                        r = client.post(f"{base}/demonstrations",
                                        files={"file": (e["file"], body)},
                                        data={"annotation": json.dumps(ann_entry)},
                                        headers={"Authorization": f"Bearer {tokens[e['mentor']]}"})
                    except httpx.TransportError:
                        with lock:
                            retries += 1
                        time.sleep(0.2)
                        continue
                    dt = time.perf_counter() - t0
                    if r.status_code >= 500:
                        with lock:
                            retries += 1
                        time.sleep(0.2)
                        continue
                    if r.status_code not in (200, 201):
                        raise RuntimeError(f"{e['file']}: {r.status_code} {r.text[:200]}")
                    with lock:
                        lat.append(dt)
                        answered += 1
                        ok[e["file"]] = r.json()["upload"]
                        duplicates += bool(r.json()["duplicate"])
                    break
                else:
                    raise RuntimeError(f"{e['file']}: no answer after 200 attempts")

    def killer() -> None:
        while answered < KILL_AFTER:
            time.sleep(0.01)
        server["proc"].send_signal(signal.SIGKILL)
        server["proc"].wait()
        killed.set()
        server["proc"] = _start(db, port)

    t0 = time.perf_counter()
    threads = [threading.Thread(target=uploader) for _ in range(N_UPLOADERS)]
    kt = threading.Thread(target=killer)
    kt.start()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    kt.join()
    wall = time.perf_counter() - t0
    # what the database holds (the same SQL on both)
    from nonprehensile.service.db import arc_store
    from nonprehensile.service.ingest import CHECKPOINT_N, STATE, _replayed

    pool = make_pool(db, max_size=2)
    with pool.connection() as conn:
        stored = {h for (h,) in conn.execute("SELECT hash FROM np_uploads").fetchall()}
        n_uploads = len(stored)
        orphans = conn.execute(
            "SELECT count(*) FROM np_samples s LEFT JOIN np_upload_samples u "
            "ON u.arc = s.store AND u.sample = s.id WHERE u.hash IS NULL").fetchone()[0]
        per_upload = conn.execute(
            "SELECT p.skill, count(u.step) FROM np_uploads p LEFT JOIN np_upload_samples u "
            "ON u.hash = p.hash GROUP BY p.hash, p.skill").fetchall()
        empty_reply = conn.execute(
            "SELECT count(*) FROM np_uploads WHERE reply = %s", ("{}",)).fetchone()[0]
        n_samples = conn.execute("SELECT count(*) FROM np_samples").fetchone()[0]
        arcs = [r[0] for r in conn.execute("SELECT DISTINCT store FROM np_samples")]
        states_ok = 0
        for arc in arcs:
            # the checkpointed model, with the samples after it registered again, gives the
            # stored keys, ids and micro-cluster ids exactly (_replayed raises otherwise)
            st = arc_store(conn, arc)
            n_seen = int((st.get_meta(CHECKPOINT_N) or b"0").decode())
            _replayed(arc, st.get_meta(STATE) or b"", n_seen, st.vectors(0, st.n_samples),
                      st.keys(), st.labels(), st.micro_ids())
            states_ok += 1
    pool.close()
    steps = {}
    for skill, n in per_upload:
        steps.setdefault(skill, set()).add(n)
    server["proc"].send_signal(signal.SIGINT)
    try:
        server["proc"].wait(timeout=30)
    except subprocess.TimeoutExpired:
        server["proc"].kill()
    lat_ms = np.array(lat) * 1000
    return {
        "store": kind, "uploads": len(ann), "answered_2xx": len(ok), "stored": n_uploads,
        "all_2xx_stored": set(ok.values()) <= stored, "duplicates_answered": duplicates,
        "retries": retries, "killed": killed.is_set(), "orphan_samples": int(orphans),
        "uploads_without_reply": int(empty_reply), "segments_per_skill": {
            k: sorted(v) for k, v in steps.items()}, "samples": int(n_samples),
        "arc_states_consistent": f"{states_ok}/{len(arcs)}",
        "wall_s": round(wall, 2), "uploads_per_s": round(len(ann) / wall, 2),
        "segments_per_s": round(n_samples / wall, 1),
        "p50_ms": round(float(np.percentile(lat_ms, 50)), 1),
        "p99_ms": round(float(np.percentile(lat_ms, 99)), 1),
    }


#: Samples each registration stream sends (the first INIT_N make its first clustering, not
#: timed), features per sample (a flattened segment of the bundled cube dataset: 400 points of
#: 4 markers), samples per batch (one COPY and one transaction each).
REG_N, REG_D, REG_BATCH, REG_INIT = 10_000, 4800, 500, 1000
#: The service checkpoints an arc's model every this many samples (as ingest.CHECKPOINT).
REG_CHECKPOINT = 4096


def _stream(seed: int) -> np.ndarray:
    """One arc's synthetic stream: 6 Gaussian clusters in REG_D features."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(scale=3.0, size=(6, REG_D))
    return centres[rng.integers(0, 6, REG_N)] + rng.normal(size=(REG_N, REG_D))


def _register_stream(args: tuple[str, str, int, Any]) -> dict[str, float]:
    """Register one arc's stream through a clusterer on a PostgresStore, batch by batch as
    the service does: each batch keyed, clustered and COPYed in one transaction with the
    arc's generation marker, the model checkpointed every REG_CHECKPOINT samples. Runs in a
    worker process; the timed part starts when every worker is ready (``barrier``)."""
    db, arc, seed, barrier = args
    from threadpoolctl import threadpool_limits

    from nonprehensile.motion.clustering import HilbertClusterer
    from nonprehensile.motion.pgstore import PostgresStore

    x = _stream(seed)
    with PostgresStore(db, arc) as st, threadpool_limits(1):
        c = HilbertClusterer(6, init_size=REG_INIT, growth=1e12, drift_fraction=1e12,
                             store=st, random_state=0)
        c.partial_fit(x[:REG_INIT])  # the first batch: a clustering, not timed
        st.put_meta("hilbert_clusterer", c.save_state())
        last = REG_INIT
        # the first through the barrier reads the server's CPU when all start and end
        first = barrier is None or barrier.wait() == 0
        server0 = _server_cpu(db) if first else None
        t0, c0 = time.perf_counter(), time.process_time()
        for s in range(REG_INIT, REG_N, REG_BATCH):
            with st.transaction():
                c.partial_fit(x[s : s + REG_BATCH])
                st.put_meta("generation", str(c.n_samples_seen_).encode())
                if c.n_samples_seen_ - last >= REG_CHECKPOINT:
                    st.put_meta("hilbert_clusterer", c.save_state())
                    last = c.n_samples_seen_
        t1, cpu = time.perf_counter(), time.process_time() - c0
        if barrier is not None:
            barrier.wait()
        server1 = _server_cpu(db) if first else None
        server = None if server0 is None or server1 is None else server1 - server0
        return {"t0": t0, "t1": t1, "cpu": cpu, "server_cpu": server,
                "n": REG_N - REG_INIT, "stored": st.n_samples}


def _proc_cpu(pid: int, children: bool) -> float:
    """CPU seconds (user + system) of a process, with its exited children's if asked."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = fields[11:15] if children else fields[11:13]
    return sum(int(t) for t in ticks) / os.sysconf("SC_CLK_TCK")


def _server_cpu(db: str) -> float | None:
    """CPU seconds so far of the PostgreSQL server behind ``db``: its postmaster with its
    exited children (closed connections' backends) and its live children. None when the
    server is not on this machine (no /proc entry for it)."""
    import psycopg

    with psycopg.connect(db, autocommit=True) as conn:
        backend = conn.execute("SELECT pg_backend_pid()").fetchone()[0]
        try:
            stat = Path(f"/proc/{backend}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            return None
    master = int(stat[1])  # the backend's parent
    total = _proc_cpu(master, children=True)
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == backend:
            continue
        try:
            stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            if int(stat[1]) == master:
                total += _proc_cpu(int(pid), children=False)
        except OSError:
            continue
    return total


def insert_throughput(workers: int = 2) -> dict[str, Any]:
    """Registration into PostgreSQL with batched inserts, through the clusterer.

    ``workers`` processes (one an arc, as the service's arcs are independent stores of one
    database) register REG_N - REG_INIT samples each; the figure is the samples of all of them
    over the wall time from the first start to the last commit. Also reported: one stream
    alone, and the bare COPY of the same batches (the store's inserts without the clusterer).
    """
    from multiprocessing import get_context

    from nonprehensile.motion.pgstore import PostgresStore

    pg, _ = _server()
    db = _fresh_db(pg)
    out: dict[str, Any] = {"features": REG_D, "batch": REG_BATCH,
                           "samples_per_stream": REG_N - REG_INIT, "workers": workers}
    x = _stream(0)
    with PostgresStore(db, "bare") as st:
        t0 = time.perf_counter()
        for s in range(0, REG_N, REG_BATCH):
            st.add(x[s : s + REG_BATCH], [0] * REG_BATCH, np.zeros(REG_BATCH, dtype=np.int64))
        out["copy_only_samples_per_s"] = round(REG_N / (time.perf_counter() - t0))
    del x
    one = _register_stream((db, "single", 1, None))
    out["one_stream_samples_per_s"] = round(one["n"] / (one["t1"] - one["t0"]))
    out["one_stream_client_cpu_ms_per_sample"] = round(1000 * one["cpu"] / one["n"], 3)
    if one["server_cpu"] is not None:
        out["one_stream_server_cpu_ms_per_sample"] = round(1000 * one["server_cpu"] / one["n"],
                                                           3)
    ctx = get_context("spawn")
    with ctx.Manager() as mgr:
        barrier = mgr.Barrier(workers)
        with ctx.Pool(workers) as pool:
            res = pool.map(_register_stream,
                           [(db, f"arc{i}", 10 + i, barrier) for i in range(workers)])
    wall = max(r["t1"] for r in res) - min(r["t0"] for r in res)
    n = sum(r["n"] for r in res)
    out["all_stored"] = all(r["stored"] == REG_N for r in res)
    out["registered_samples_per_s"] = round(n / wall)
    out["registered_wall_s"] = round(wall, 2)
    out["client_cpu_ms_per_sample"] = round(1000 * sum(r["cpu"] for r in res) / n, 3)
    server = [r["server_cpu"] for r in res if r["server_cpu"] is not None]
    out["server_cpu_ms_per_sample"] = round(1000 * server[0] / n, 3) if server else None
    out["load_average"] = [round(a, 2) for a in os.getloadavg()]
    out["goal"] = GOAL_SAMPLES_PER_S
    out["met"] = out["registered_samples_per_s"] >= GOAL_SAMPLES_PER_S
    return out


def same_results() -> dict[str, Any]:
    """The bundled dataset's 180 recordings uploaded in order to a service on PostgreSQL and
    to one on a SQLite file, then every due arc recalibrated: the same documents from both."""
    from fastapi.testclient import TestClient

    from nonprehensile.demonstrations.dataset import dataset_path
    from nonprehensile.service import ServiceConfig, create_app, load_template
    from nonprehensile.service.db import create_token, make_pool
    from nonprehensile.service.ingest import Registry

    cube = dataset_path("cube")
    ann = json.loads((cube / "annotations.json").read_text())["demonstrations"]
    template = load_template("cube")
    docs: dict[str, list[Any]] = {}
    for kind in ("postgresql", "sqlite"):
        db = _fresh_db(_server()[0]) if kind == "postgresql" else _sqlite_file()
        pool = make_pool(db, max_size=4)
        with pool.connection() as conn:
            tokens = {m: create_token(conn, m) for m in sorted({e["mentor"] for e in ann})}
        registry = Registry(pool, template)
        app = create_app(pool, template, ServiceConfig(kind), registry=registry,
                         background=False)
        out: list[Any] = []
        with TestClient(app) as client:
            for e in ann:
                entry = {k: v for k, v in e.items() if k not in ("file", "mentor")}
                r = client.post("/demonstrations",
                                files={"file": (e["file"], (cube / e["file"]).read_bytes())},
                                data={"annotation": json.dumps(entry)},
                                headers={"Authorization": f"Bearer {tokens[e['mentor']]}"})
                if r.status_code != 201:
                    raise RuntimeError(f"{kind}: {e['file']}: {r.status_code} {r.text[:200]}")
                out.append(r.json())
            out.extend(registry.recalibrate(arc) for arc in registry.arcs_due())
            out.append(client.get("/clusters").json())
            out.append(client.get("/mentors").json())
            out.extend(client.get(f"/uploads/{d['upload']}").json() for d in out[:len(ann)])
        pool.close()
        docs[kind] = out
    arcs = docs["sqlite"][-len(ann) - 2]["arcs"]
    return {"uploads": len(ann), "arcs": len(arcs),
            "clusters": sum(len(a["clusters"]) for a in arcs),
            "recalibrations": sum(1 for d in docs["sqlite"] if d.get("recalibrated")),
            "identical": docs["postgresql"] == docs["sqlite"]}


def fuzz(examples: int = 60) -> dict[str, Any]:
    """Schemathesis over the OpenAPI schema, every operation, with a mentor's token: no 5xx."""
    import schemathesis
    from fastapi.testclient import TestClient
    from hypothesis import HealthCheck, given, settings

    from nonprehensile.service import ServiceConfig, create_app, load_template
    from nonprehensile.service.db import create_token, make_pool

    pg, _ = _server()
    db = _fresh_db(pg)
    pool = make_pool(db, max_size=4)
    with pool.connection() as conn:
        token = create_token(conn, "fuzzer")
    app = create_app(pool, load_template("cube"), ServiceConfig("bench", max_bytes=1 << 20),
                     background=False)
    cases = 0
    errors: list[tuple[str, str, int]] = []
    statuses: dict[int, int] = {}
    with TestClient(app):
        schema = schemathesis.openapi.from_asgi("/openapi.json", app)
        for op in schema.get_all_operations():
            operation = op.ok()

            @settings(max_examples=examples, deadline=None, database=None,
                      suppress_health_check=list(HealthCheck))
            def check(case: Any) -> None:
                nonlocal cases
                for headers in ({"Authorization": f"Bearer {token}"}, {}):
                    r = case.call(headers=headers)
                    cases += 1
                    statuses[r.status_code] = statuses.get(r.status_code, 0) + 1
                    if r.status_code >= 500:
                        errors.append((case.method, case.path, r.status_code))

            given(operation.as_strategy())(check)()
        # malformed recordings: a real take with bytes flipped, cut short, or doubled
        from nonprehensile.demonstrations.dataset import dataset_path

        cube = dataset_path("cube")
        entry = json.loads((cube / "annotations.json").read_text())["demonstrations"][0]
        ann = json.dumps({k: v for k, v in entry.items() if k not in ("file", "mentor")})
        good = (cube / entry["file"]).read_bytes()
        rng = np.random.default_rng(0)
        client = TestClient(app)
        for i in range(examples):
            data = bytearray(good)
            if i % 3 == 0:
                pos = rng.integers(0, len(data), size=8)
                for p in pos:
                    data[p] = int(rng.integers(0, 256))
            elif i % 3 == 1:
                data = data[: int(rng.integers(0, len(data)))]
            else:
                data = data + data[: int(rng.integers(1, 4096))]
            r = client.post("/demonstrations", files={"file": (f"m{i}.c3d", bytes(data))},
                            data={"annotation": ann},
                            headers={"Authorization": f"Bearer {token}"})
            cases += 1
            statuses[r.status_code] = statuses.get(r.status_code, 0) + 1
            if r.status_code >= 500:
                errors.append(("POST", f"/demonstrations (mutated take {i})", r.status_code))
    pool.close()
    return {"requests": cases, "server_errors": len(errors), "first_errors": errors[:5],
            "statuses": dict(sorted(statuses.items()))}


def main() -> None:
    try:
        _main()
    finally:
        _stop_serves()
        _drop_dbs()
        _stop_server()
        for tmp in _TMP:
            shutil.rmtree(tmp, ignore_errors=True)


def _main() -> None:
    fz = fuzz()
    print("   schemathesis over /openapi.json (with and without a token):")
    for k, v in fz.items():
        print(f"     {k}: {v}")
    loads = {}
    for kind in ("postgresql", "sqlite"):
        res = loads[kind] = load_test(kind)
        print(f"   load test on {kind} (8 uploaders, 180 recordings, SIGKILL after "
              f"{KILL_AFTER} answers, restart):")
        for k, v in res.items():
            print(f"     {k}: {v}")
    same = same_results()
    print("   the same uploads, in order, to a service on each store:")
    for k, v in same.items():
        print(f"     {k}: {v}")
    ins = insert_throughput()
    print("   registration into PostgreSQL through the clusterer, batched:")
    for k, v in ins.items():
        print(f"     {k}: {v}")
    print("   bars (issue 12):")
    print(f"     no 5xx in the fuzz: {fz['server_errors'] == 0} ({fz['requests']} requests)")
    for kind, res in loads.items():
        whole = (res["answered_2xx"] == res["stored"] == res["uploads"] and res["all_2xx_stored"]
                 and res["orphan_samples"] == 0 and res["uploads_without_reply"] == 0)
        print(f"     load test + kill -9 on {kind}: {res['stored']}/{res['uploads']} stored, "
              f"nothing lost, twice or half-written: {whole}; {res['uploads_per_s']} uploads/s, "
              f"p50 {res['p50_ms']} ms, p99 {res['p99_ms']} ms")
    print(f"     same results from SQLite and PostgreSQL: {same['identical']}")
    print(f"     registration through the clusterer into PostgreSQL: "
          f"{ins['registered_samples_per_s']} samples/s ({ins['workers']} arcs at once; one "
          f"stream alone {ins['one_stream_samples_per_s']}), goal >= {GOAL_SAMPLES_PER_S:.0f}: "
          f"{'met' if ins['met'] else 'MISSED'} (load average {ins['load_average']})")


if __name__ == "__main__":
    main()
