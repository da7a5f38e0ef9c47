"""The service's stores know their arcs: a store served with the skills file reordered is
refused (its arcs' names would stand for other arcs and file segments into another skill's
arc), and stores written before arcs were recorded are checked and adopted."""

from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("fastapi", reason="the service extra (FastAPI) is not installed")
pytest.importorskip("psycopg", reason="the pg extra (psycopg) is not installed")

import httpx
from fastapi.testclient import TestClient

from nonprehensile.cli import main
from nonprehensile.demonstrations.dataset import dataset_path
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.service import ServiceConfig, create_app, create_token, load_template, make_pool
from nonprehensile.service.errors import ArcMismatch
from nonprehensile.service.ingest import (
    ARC_IDENTITY,
    CHECKPOINT_N,
    CLUSTER_MAP,
    STATE,
    Registry,
    single_upload,
)

CUBE = dataset_path("cube")
ANN = json.loads((CUBE / "annotations.json").read_text())
SKILLS = json.loads((CUBE / ANN["skills"]).read_text())


def _dataset(root: Path, order: list[str]) -> Path:
    """A dataset folder of the cube's settings with its skills in ``order`` (no takes)."""
    root.mkdir()
    by_name = {s["name"]: s for s in SKILLS["skills"]}
    (root / "skills.json").write_text(json.dumps(
        {**SKILLS, "skills": [by_name[n] for n in order]}))
    top = {k: v for k, v in ANN.items() if k != "demonstrations"}
    (root / "annotations.json").write_text(json.dumps(
        {**top, "skills": "skills.json", "demonstrations": []}))
    return root


ORIGINAL = [s["name"] for s in SKILLS["skills"]]
#: roll-arc first: the rolling graph's nodes are numbered from its events, so the store
#: names of push-roll's arcs now stand for roll-arc's and roll-pull's (and back)
REORDERED = ["roll-arc", *[n for n in ORIGINAL if n != "roll-arc"]]


def _take(skill: str, k: int = 0, mentor: str | None = "ana"
          ) -> tuple[dict[str, Any], bytes]:
    """Take ``k`` of ``skill`` by ``mentor`` (None: anyone's)."""
    e = [d for d in ANN["demonstrations"]
         if d["skill"] == skill and mentor in (None, d["mentor"])][k]
    return ({k2: v for k2, v in e.items() if k2 not in ("file", "mentor")} | {"file": e["file"]},
            (CUBE / e["file"]).read_bytes())


def _upload(client: TestClient, token: str, skill: str, k: int = 0,
            mentor: str | None = "ana") -> Any:
    entry, data = _take(skill, k, mentor)
    ann = {key: v for key, v in entry.items() if key != "file"}
    return client.post("/demonstrations", files={"file": (entry["file"], data, "x/y")},
                       data={"annotation": json.dumps(ann)},
                       headers={"Authorization": f"Bearer {token}"})


def _register(registry: Registry, skill: str, k: int = 0) -> list[dict[str, Any]]:
    """Register a take straight to ``registry`` (no application, hence no startup check)."""
    entry, data = _take(skill, k)
    ann = {key: v for key, v in entry.items() if key != "file"}
    with single_upload(registry.template, "ana", entry["file"], data, ann) as (ds, hashes):
        return registry.register("ana", ds, hashes, "recording")


def _contents(store: str) -> list[Any]:
    """Everything the database holds of the service (vectors by digest)."""
    pool = make_pool(store, max_size=1)
    try:
        with pool.connection() as conn:
            samples = [(s, int(i), int(k), int(lab), int(m), hashlib.sha256(bytes(v)).hexdigest())
                       for s, i, k, lab, m, v in conn.execute(
                           "SELECT store, id, key, label, micro, vector FROM np_samples "
                           "ORDER BY store, id").fetchall()]
            meta = [(s, n, bytes(v)) for s, n, v in conn.execute(
                "SELECT store, name, value FROM np_meta ORDER BY store, name").fetchall()]
            ups = [tuple(r) for r in conn.execute(
                "SELECT hash, step, arc, sample FROM np_upload_samples ORDER BY 1, 2")]
    finally:
        pool.close()
    return [samples, meta, ups]


def _both_orders(store: str, tmp_path: Path) -> tuple[Path, Path, Any, Any, Any, str]:
    """The original and the reordered skills files' datasets and templates, a pool on
    ``store`` and a mentor's token."""
    a = _dataset(tmp_path / "a", ORIGINAL)
    b = _dataset(tmp_path / "b", REORDERED)
    pool = make_pool(store, max_size=2)
    with pool.connection() as conn:
        token = create_token(conn, "ana")
    return a, b, load_template(a), load_template(b), pool, token


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    if request.param == "postgresql":
        return str(request.getfixturevalue("pg_url"))
    return str(tmp_path / "service.db")


def test_a_reordered_skills_file_is_refused_and_the_store_left_as_it_was(
        store: str, tmp_path: Path) -> None:
    _, b, ta, tb, pool, token = _both_orders(store, tmp_path)
    with TestClient(create_app(pool, ta, ServiceConfig("t"), background=False,
                               registry=Registry(pool, ta, init_size=4))) as c:
        first = _upload(c, token, "push-roll")
        assert first.status_code == 201, first.text
    # push-roll's first arc as the store recorded it
    arc = first.json()["segments"][0]["arc"]
    with pool.connection() as conn:
        rows = conn.execute("SELECT value FROM np_meta WHERE store = %s AND name = %s",
                            (arc, ARC_IDENTITY)).fetchall()
    assert [bytes(v).decode() for (v,) in rows] == [ta.identities[arc]]
    assert "push-roll motion 0" in ta.identities[arc] and "(G,a) ->" in ta.identities[arc]
    before = _contents(store)

    # the same store with the skills reordered: `serve` refuses, one line, exit 2
    r = CliRunner().invoke(main, ["serve", "--store", store, "--dataset", str(b),
                                  "--port", "0"])
    assert r.exit_code == 2, r.output
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and "Traceback" not in r.output, r.output
    assert f"'{arc}'" in line and ta.identities[arc] in line and tb.identities[arc] in line
    assert "the skills file it was written with" in line and "new database" in line
    # ... so does the application (whoever builds one), and nothing was written
    with pytest.raises(ArcMismatch, match=arc):
        create_app(pool, tb, ServiceConfig("t"), background=False)
    # an upload through a registry that skipped the check: 409, nothing stored
    with pytest.raises(ArcMismatch) as exc:
        _register(Registry(pool, tb, init_size=4), "roll-arc")
    assert exc.value.status == 409
    assert _contents(store) == before

    # the original order: served, and the next take lands on push-roll's arcs again
    with TestClient(create_app(pool, ta, ServiceConfig("t"), background=False,
                               registry=Registry(pool, ta, init_size=4))) as c:
        second = _upload(c, token, "push-roll", 1)
        assert second.status_code == 201, second.text
        assert [s["arc"] for s in second.json()["segments"]] == [
            s["arc"] for s in first.json()["segments"]]
    pool.close()


def test_stores_written_before_arcs_were_recorded(store: str, tmp_path: Path) -> None:
    """The migration: a store with samples and no recorded arc is checked against its
    uploads' skills and motions; the skills file that files them there adopts it (recording
    the arcs), another is refused as above."""
    a, _, ta, tb, pool, token = _both_orders(store, tmp_path)
    with TestClient(create_app(pool, ta, ServiceConfig("t"), background=False,
                               registry=Registry(pool, ta, init_size=4))) as c:
        arcs = [s["arc"] for s in _upload(c, token, "push-roll").json()["segments"]]
    with pool.connection() as conn:  # as the previous version left it: no arc recorded
        conn.execute("DELETE FROM np_meta WHERE name = %s", (ARC_IDENTITY,))
    before = _contents(store)
    with pytest.raises(ArcMismatch) as exc:
        Registry(pool, tb).check_arcs()
    assert "written before stores recorded their arcs" in str(exc.value)
    assert "push-roll motion" in str(exc.value)
    # a registry that skipped the check does not add to an unrecorded store either
    with pytest.raises(ArcMismatch, match="restart `nonprehensile serve`"):
        _register(Registry(pool, ta, init_size=4), "push-roll", 1)
    assert _contents(store) == before
    pool.close()

    if store.startswith("postgresql"):
        pool = make_pool(store, max_size=2)
        assert Registry(pool, ta).check_arcs() == (sorted(arcs), [])
        assert Registry(pool, ta).check_arcs() == ([], [])  # recorded: nothing left to adopt
        pool.close()
        return
    # the real server says so on stderr, in one line, and serves
    proc = subprocess.Popen(
        [sys.executable, "-m", "nonprehensile.cli", "serve", "--store", store, "--dataset",
         str(a), "--port", "0", "--recalibrate-every", "0"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    try:
        assert proc.stderr is not None
        note = proc.stderr.readline()
        assert note.startswith(f"recorded the arc of {len(arcs)} arc store(s) written before"
                               ), note
        serving = proc.stderr.readline()
        url = re.search(r"http://127\.0\.0\.1:\d+", serving)
        assert url, serving
        for _ in range(300):  # up (Ctrl-C before uvicorn runs is not its graceful stop)
            try:
                if httpx.get(f"{url[0]}/health", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.1)
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    samples, meta, ups = _contents(store)
    assert samples == before[0] and ups == before[2]
    assert {(s, bytes(v).decode()) for s, n, v in meta if n == ARC_IDENTITY} == {
        (arc, ta.identities[arc]) for arc in arcs}


# ------------------------------------------------------------------------ cluster now
def _truth(pool: Any, arc: str) -> tuple[np.ndarray, np.ndarray]:
    """The arc's model's own clusters of its samples, as `cluster show` reports a model's
    (``labels_``: the model loaded from its checkpoint, the samples after it registered
    again), and the ids the samples got when registered."""
    from nonprehensile.motion.store import MemoryStore
    from nonprehensile.service.db import arc_store

    with pool.connection() as conn:
        store = arc_store(conn, arc)
        x, keys = store.vectors(0, store.n_samples), store.keys()
        labels, micro = store.labels(), store.micro_ids()
        state = store.get_meta(STATE)
        n_seen = int(store.get_meta(CHECKPOINT_N) or b"0")
    mem = MemoryStore()
    mem.add(x[:n_seen], keys[:n_seen], labels[:n_seen], micro=micro[:n_seen])
    c = HilbertClusterer.load_state(state, mem)
    c.partial_fit(x[n_seen:])
    assert mem.keys() == keys and np.array_equal(mem.micro_ids(), micro)
    return c.labels_, labels


def _listing_is_the_models(c: TestClient, pool: Any, ups: list[dict[str, Any]]) -> int:
    """GET /clusters, /uploads and /mentors against the models' clusters; how many samples
    are in another cluster now than the one they were registered to."""
    moved = 0
    listing = {a["arc"]: a for a in c.get("/clusters").json()["arcs"]}
    truth = {}
    for arc, doc in listing.items():
        now, registered = _truth(pool, arc)
        truth[arc] = now
        moved += int(np.sum(now != registered))
        sizes = {int(k): int(n) for k, n in zip(*np.unique(now, return_counts=True),
                                                 strict=True)}
        assert {cl["id"]: cl["size"] for cl in doc["clusters"]} == sizes, arc
        assert doc["pending"] == 0 and doc["samples"] == len(now)
    per_mentor: dict[tuple[str, str, int], int] = {}
    for up in ups:
        got = c.get(f"/uploads/{up['upload']}").json()
        for seg in got["segments"]:
            assert seg["cluster"] == int(truth[seg["arc"]][seg["sample"]]), seg
            key = (got["mentor"], seg["arc"], seg["cluster"])
            per_mentor[key] = per_mentor.get(key, 0) + 1
    stats = {(m["mentor"], cl["arc"], cl["cluster"]): cl["segments"]
             for m in c.get("/mentors").json()["mentors"] for cl in m["clusters"]}
    assert stats == per_mentor
    return moved


def test_cluster_now_is_the_models_cluster_after_a_recalibration(store: str) -> None:
    """``GET /clusters``, ``/uploads/{hash}`` and ``/mentors`` name each segment's cluster in
    its arc's model now, not the micro-cluster's id at its registration, after a background
    recalibration, more uploads, a restart, and for an arc written before the service kept
    its cluster map."""
    template = load_template("cube")
    pool = make_pool(store, max_size=3)
    with pool.connection() as conn:
        tokens = {m: create_token(conn, m) for m in {d["mentor"] for d in ANN["demonstrations"]}}
    reg = Registry(pool, template, init_size=4, checkpoint=3)
    ups = []
    with TestClient(create_app(pool, template, ServiceConfig("t"), registry=reg,
                               background=False)) as c:
        takes = [d for d in ANN["demonstrations"] if d["skill"] == "twist"]
        for i, e in enumerate(takes[:8]):
            r = _upload(c, tokens[e["mentor"]], "twist", i, mentor=None)
            assert r.status_code == 201, r.text
            ups.append(r.json())
        due = reg.arcs_due()
        assert due
        for arc in due:
            assert reg.recalibrate(arc)["recalibrated"]
        for i, e in enumerate(takes[8:10], 8):  # registered to the recalibrated models
            r = _upload(c, tokens[e["mentor"]], "twist", i, mentor=None)
            assert r.status_code == 201, r.text
            ups.append(r.json())
        moved = _listing_is_the_models(c, pool, ups)
    # not a vacuous check: the recalibration moved samples out of their registered ids
    assert moved > 0
    # a restarted server reads the maps the uploads stored
    with TestClient(create_app(pool, template, ServiceConfig("t"), background=False,
                               registry=Registry(pool, template, init_size=4))) as c:
        assert _listing_is_the_models(c, pool, ups) == moved
    # arcs last written by a version that kept no map: their models are rebuilt
    with pool.connection() as conn:
        conn.execute("DELETE FROM np_meta WHERE name = %s", (CLUSTER_MAP,))
    with TestClient(create_app(pool, template, ServiceConfig("t"), background=False,
                               registry=Registry(pool, template, init_size=4))) as c:
        assert _listing_is_the_models(c, pool, ups) == moved
    pool.close()


def _serve_once(monkeypatch: pytest.MonkeyPatch, store: str, dataset: Path) -> Any:
    """`serve` on ``store`` with ``dataset``'s skills, interrupted as soon as it would serve."""
    import uvicorn

    def interrupted(self: Any, sockets: Any = None) -> None:  # Ctrl-C at once
        raise KeyboardInterrupt

    monkeypatch.setattr(uvicorn.Server, "run", interrupted)
    return CliRunner().invoke(main, ["serve", "--store", store, "--dataset", str(dataset),
                                     "--port", "0", "--recalibrate-every", "0"])


def test_serve_checks_the_arcs_once(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """`serve` checks the arcs, and the application built on its registry does not again."""
    calls = []
    check = Registry.check_arcs

    def counted(self: Registry) -> Any:
        calls.append(1)
        return check(self)

    monkeypatch.setattr(Registry, "check_arcs", counted)
    r = _serve_once(monkeypatch, str(tmp_path / "svc.db"), _dataset(tmp_path / "a", ORIGINAL))
    assert r.exit_code == 0, r.output
    assert len(calls) == 1


def test_a_skill_left_out_or_added_on_an_arc_is_served_when_its_segments_still_match(
        store: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Only the skills' motions on an arc changed (roll-pull left out: it shares all its arcs
    with roll-arc): `serve` checks the arc's segments against the skills file, rewrites the
    arc's record and says so; nothing else changes. A segment of the skill left out is
    refused, and so is a reordered skills file (other events under the same names)."""
    ta = load_template(_dataset(tmp_path / "a", ORIGINAL))
    c = _dataset(tmp_path / "c", [n for n in ORIGINAL if n != "roll-pull"])
    tc = load_template(c)
    pool = make_pool(store, max_size=2)
    with pool.connection() as conn:
        token = create_token(conn, "ana")
    with TestClient(create_app(pool, ta, ServiceConfig("t"), background=False,
                               registry=Registry(pool, ta, init_size=4))) as client:
        shared = [s["arc"] for s in _upload(client, token, "roll-arc").json()["segments"]]
        assert _upload(client, token, "push-roll").status_code == 201
    assert all(ta.identities[a] != tc.identities[a] and ta.edges[a] == tc.edges[a]
               for a in shared)
    before = _contents(store)
    # an upload (no start checked the store): refused, nothing stored
    with pytest.raises(ArcMismatch, match="restart `nonprehensile serve` with this skills"):
        _register(Registry(pool, tc, init_size=4), "roll-arc", 1)
    assert _contents(store) == before

    r = _serve_once(monkeypatch, store, c)
    assert r.exit_code == 0, r.output
    assert r.stderr.splitlines()[0] == (
        f"rewrote the recorded arc of {len(shared)} arc store(s) whose skills' motions changed "
        f"in the skills file (their segments checked against it): {', '.join(sorted(shared))}")
    samples, meta, ups = _contents(store)
    assert samples == before[0] and ups == before[2]
    assert [m for m in meta if m[1] != ARC_IDENTITY] == [m for m in before[1]
                                                          if m[1] != ARC_IDENTITY]
    assert {(s, v.decode()) for s, n, v in meta if n == ARC_IDENTITY} == {
        (a, tc.identities[a]) for a in {*shared, *(s for s, n, _ in before[1]
                                                    if n == ARC_IDENTITY)}}
    # reordered: still refused
    r = _serve_once(monkeypatch, store, _dataset(tmp_path / "b", REORDERED))
    assert r.exit_code == 2 and "the skills file it was written with" in r.stderr, r.output
    # roll-pull added back: served again (the arcs' segments are roll-arc's)
    r = _serve_once(monkeypatch, store, tmp_path / "a")
    assert r.exit_code == 0 and "rewrote the recorded arc of 4" in r.stderr, r.output
    with TestClient(create_app(pool, ta, ServiceConfig("t"), background=False,
                               registry=Registry(pool, ta, init_size=4))) as client:
        assert _upload(client, token, "roll-pull").status_code == 201
    # ... and now the arcs hold roll-pull's segments: left out again, refused
    r = _serve_once(monkeypatch, store, c)
    assert r.exit_code == 2, r.output
    assert "roll-pull motion 0 (a motion not in this skills file)" in r.stderr
    pool.close()


def test_a_skill_left_out_that_renumbers_the_arcs_is_refused(store: str,
                                                              tmp_path: Path) -> None:
    """push-roll left out (the only skill on its arcs) renumbers the rolling graph: roll-arc's
    stores are no longer named by the skills file, and its new uploads went to new stores,
    the arc's samples split between two models; now refused, nothing written."""
    ta = load_template(_dataset(tmp_path / "a", ORIGINAL))
    td = load_template(_dataset(tmp_path / "d", [n for n in ORIGINAL if n != "push-roll"]))
    pool = make_pool(store, max_size=2)
    Registry(pool, ta, init_size=4).check_arcs()
    arcs = [s["arc"] for s in _register(Registry(pool, ta, init_size=4),
                                        "roll-arc")[0]["segments"]]
    moved = {a for (skill, _), a in td.motion_arcs.items() if skill == "roll-arc"}
    assert moved.isdisjoint(arcs)  # the renumbering this test is about
    before = _contents(store)
    with pytest.raises(ArcMismatch, match=r"the store's arc 'rolling-g\d-n\d+-n\d+' holds "
                       r"rolling: .* which the skills file skills\.json names"):
        Registry(pool, td, init_size=4).check_arcs()
    assert _contents(store) == before
    assert Registry(pool, ta, init_size=4).check_arcs() == ([], [])
    pool.close()


def test_a_start_waits_for_an_upload_in_flight_before_reading_its_arcs_segments(
        pg_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Server A (the whole skills file) registers a roll-pull take; server B starts with
    roll-pull left out while A holds the arc's lock. B read the arcs' segments without the
    locks (PostgreSQL: A's not yet committed), passed, and rewrote their record over A's
    roll-pull segments; now it waits for A and refuses."""
    import threading

    ta = load_template(_dataset(tmp_path / "a", ORIGINAL))
    tc = load_template(_dataset(tmp_path / "c", [n for n in ORIGINAL if n != "roll-pull"]))
    pool = make_pool(pg_url, max_size=4)
    ra = Registry(pool, ta, init_size=4)
    ra.check_arcs()
    _register(ra, "roll-arc")  # the shared arcs record their identity (ta's)
    inside, go = threading.Event(), threading.Event()
    real = Registry._check_arc

    def paused(self: Registry, st: Any) -> bool:
        out = real(self, st)
        if threading.current_thread().name == "A":
            inside.set()
            go.wait(10)
        return out

    monkeypatch.setattr(Registry, "_check_arc", paused)
    done: list[Any] = []
    a = threading.Thread(target=lambda: done.append(_register(ra, "roll-pull")), name="A")
    a.start()
    assert inside.wait(10)
    threading.Timer(0.5, go.set).start()
    try:
        with pytest.raises(ArcMismatch, match="roll-pull motion 0"):
            Registry(pool, tc, init_size=4).check_arcs()
    finally:
        go.set()
        a.join(10)
    assert done and done[0][0]["segments"]  # A's take stored, under A's record
    pool.close()


def test_an_archive_with_an_arc_refused_stores_nothing(store: str, tmp_path: Path) -> None:
    """An archive whose later demonstration's arc is refused (a registry that skipped the
    start's check, serving a store of another skills file) is refused before its first
    demonstration is registered: 409, nothing stored (it stored the ones before)."""
    import io
    import zipfile

    from nonprehensile.service.ingest import archive_upload

    ta = load_template(_dataset(tmp_path / "a", ORIGINAL))
    tb = load_template(_dataset(tmp_path / "b", REORDERED))
    pool = make_pool(store, max_size=2)
    _register(Registry(pool, ta, init_size=4), "push-roll")
    before = _contents(store)
    # twist (arcs of its own, new stores) first, then roll-arc (push-roll's stores under tb)
    takes = [_take("twist"), _take("roll-arc")]
    top = {k: v for k, v in ANN.items() if k != "demonstrations"}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("annotations.json", json.dumps(
            {**top, "demonstrations": [{**e, "mentor": "ana"} for e, _ in takes]}))
        for e, data in takes:
            z.writestr(e["file"], data)
    buf.seek(0)
    with archive_upload(tb, "ana", buf, 10**8) as (ds, hashes), \
            pytest.raises(ArcMismatch) as exc:
        Registry(pool, tb, init_size=4).register("ana", ds, hashes, "archive")
    assert exc.value.status == 409
    assert _contents(store) == before
    pool.close()


def test_a_rebuilt_model_is_checked_against_the_stored_micro_cluster_ids(store: str) -> None:
    """Rebuilding an arc's model (its checkpoint, the samples after it registered again)
    checks their micro-cluster ids too, which the listings map through: a store whose ids
    differ is an error naming the arc, not listings from another model."""
    from nonprehensile.errors import NonprehensileError

    template = load_template("cube")
    pool = make_pool(store, max_size=2)
    reg = Registry(pool, template, init_size=4)
    for k in range(6):
        _register(reg, "twist", k)
    arc = "rotating-g2-n0-n1"
    with pool.connection() as conn:
        n_seen = int(bytes(conn.execute(
            "SELECT value FROM np_meta WHERE store = %s AND name = %s",
            (arc, CHECKPOINT_N)).fetchone()[0]))
        last = conn.execute("SELECT max(id) FROM np_samples WHERE store = %s",
                            (arc,)).fetchone()[0]
        assert last >= n_seen  # a sample after the checkpoint, registered again to rebuild
        # another micro-cluster of the model (the listings would count it there, silently)
        conn.execute("UPDATE np_samples SET micro = CASE WHEN micro = 0 THEN 1 ELSE 0 END "
                     "WHERE store = %s AND id = %s",
                     (arc, last))
        conn.execute("DELETE FROM np_meta WHERE name = %s", (CLUSTER_MAP,))
    with pytest.raises(NonprehensileError, match=f"arc {arc}: .* micro-cluster ids"):
        Registry(pool, template, init_size=4).clusters()
    pool.close()
