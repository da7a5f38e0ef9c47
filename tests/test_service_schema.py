"""Schemathesis over the service's OpenAPI schema, stateful, on SQLite and PostgreSQL: no 5xx.

Schemathesis builds a state machine from the schema's links (an upload's reply leads to
reading it, withdrawing it and its mentor's statistics; a withdrawal to reading it again) and
runs sequences of generated requests through them. Generated uploads are almost never valid,
so a sequence's upload is, at random, replaced by a real take (one of the bundled dataset's
recordings with its annotation, or an archive of one) under a real mentor's token: the links
then lead to real uploads, withdrawals and re-uploads. Every reply is checked for a 5xx (or
an exception in the application).

    python tests/test_service_schema.py --examples 300      # the measured run (both stores)

(``make test`` runs a few sequences per store.)
"""

from __future__ import annotations

import io
import json
import random
import sys
import zipfile
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("fastapi", reason="the service extra (FastAPI) is not installed")
pytest.importorskip("psycopg", reason="the pg extra (psycopg) is not installed")
pytest.importorskip("schemathesis", reason="schemathesis (a dev dependency) is not installed")

MENTORS = ("ana", "ben", "chen")


def run_stateful(store: str, examples: int, steps: int, seed: int = 0) -> dict[str, Any]:
    """Run the state machine on a service over ``store``; its statistics and 5xx list."""
    import schemathesis
    from fastapi.testclient import TestClient
    from hypothesis import HealthCheck, settings
    from hypothesis.errors import Flaky
    from schemathesis.core.transport import Response

    from nonprehensile.demonstrations.dataset import dataset_path
    from nonprehensile.service import (
        ServiceConfig,
        create_app,
        create_token,
        load_template,
        make_pool,
    )
    from nonprehensile.service.ingest import Registry

    cube = dataset_path("cube")
    ann = json.loads((cube / "annotations.json").read_text())
    top = {k: v for k, v in ann.items() if k != "demonstrations"}
    template = load_template("cube")
    pool = make_pool(store, max_size=4)
    with pool.connection() as conn:
        tokens = {m: create_token(conn, m) for m in MENTORS}
    app = create_app(pool, template, ServiceConfig("schema", max_bytes=1 << 20),
                     registry=Registry(pool, template, init_size=4, checkpoint=3),
                     background=False)
    statuses: Counter[str] = Counter()
    made = [0]
    server_errors: list[str] = []
    planted: dict[int, tuple[str, dict[str, Any]]] = {}

    with TestClient(app, raise_server_exceptions=False) as client:
        schema = schemathesis.openapi.from_asgi("/openapi.json", app)
        base = schema.as_state_machine()

        class Machine(base):  # type: ignore[misc,valid-type]
            def setup(self) -> None:
                # a new mentor per sequence: hypothesis replays sequences (to vary them),
                # and a replay must meet the same answers (not "duplicate" where the first
                # run stored), or its rules' bundles differ
                made[0] += 1
                self.mentor = f"m{seed}-{made[0]}"
                with pool.connection() as conn:
                    tokens[self.mentor] = create_token(conn, self.mentor)

            def before_call(self, case: Any) -> None:
                # decided by the generated case alone (a replay decides the same)
                rng = random.Random(repr((case.method, case.path, case.path_parameters,
                                          case.query, case.headers, case.body)))
                mentor = self.mentor
                if rng.random() < 0.8:  # a real token, else the generated header
                    case.headers = {**(case.headers or {}),
                                    "authorization": f"Bearer {tokens[mentor]}"}
                if case.method != "POST" or rng.random() < 0.4:
                    return
                demo = rng.choice(ann["demonstrations"])
                if rng.random() < 0.85:  # (else another mentor's take in an archive: 403)
                    demo = {**demo, "mentor": mentor}
                data = (cube / demo["file"]).read_bytes()
                entry = {k: v for k, v in demo.items() if k not in ("file", "mentor")}
                if case.path == "/demonstrations":
                    planted[id(case)] = ("/demonstrations", {
                        "files": {"file": (demo["file"], data)},
                        "data": {"annotation": json.dumps(entry)}})
                elif case.path == "/datasets":
                    buf = io.BytesIO()
                    with zipfile.ZipFile(buf, "w") as zf:
                        zf.writestr(f"t/{demo['file']}", data)
                        zf.writestr("t/skills.json", (cube / ann["skills"]).read_bytes())
                        zf.writestr("t/annotations.json", json.dumps(
                            {**top, "demonstrations": [demo]}))
                    planted[id(case)] = ("/datasets", {
                        "files": {"archive": ("t.zip", buf.getvalue())}})

            def call(self, case: Any, **kwargs: Any) -> Any:
                plant = planted.pop(id(case), None)
                if plant is None:
                    try:
                        return case.call(**kwargs)
                    except Exception as exc:  # the application raised: a 500 to a client
                        server_errors.append(f"{case.method} {case.path}: raised "
                                             f"{type(exc).__name__}: {exc}")
                        raise
                path, parts = plant
                r = client.post(path, headers=dict(case.headers or {}), **parts)
                return Response.from_any(r)

            def validate_response(self, response: Any, case: Any, **kwargs: Any) -> None:
                statuses[f"{case.method} {case.path} {response.status_code}"] += 1
                if response.status_code >= 500:
                    server_errors.append(f"{case.method} {case.formatted_path}: "
                                         f"{response.status_code} {response.text[:200]}")

        # the service keeps what each sequence did, so hypothesis, replaying a sequence
        # to vary it, may meet other answers (a sequence's bundles differ): it raises Flaky.
        # schemathesis's own runner then starts a new suite; so does this one, keeping
        # every reply judged so far, until ``examples`` sequences ran
        restarts = 0
        while made[0] < examples and restarts < 100:
            try:
                Machine.run(settings=settings(
                    max_examples=examples - made[0], stateful_step_count=steps, deadline=None,
                    database=None, derandomize=restarts == 0,
                    suppress_health_check=list(HealthCheck)))
                break
            except Flaky:
                restarts += 1
    pool.close()
    return {"requests": sum(statuses.values()), "sequences": made[0],
            "suites_restarted": restarts, "server_errors": server_errors,
            "statuses": dict(sorted(statuses.items()))}


def _followed(statuses: dict[str, int], prefix: str) -> int:
    return sum(n for k, n in statuses.items() if k.startswith(prefix) and k.endswith(" 200"))


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    if request.param == "postgresql":
        yield request.getfixturevalue("pg_url")
    else:
        yield str(tmp_path / "service.db")


def test_stateful_schema_run_has_no_server_error(store: str) -> None:
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        res = run_stateful(store, examples=8, steps=6)
    assert not res["server_errors"], res["server_errors"]
    # the links were followed to real uploads: read back, withdrawn
    assert _followed(res["statuses"], "GET /uploads/") >= 1, res["statuses"]
    assert _followed(res["statuses"], "DELETE /uploads/") >= 1, res["statuses"]


def main(argv: list[str]) -> int:
    import argparse
    import tempfile

    sys.path.insert(0, str(Path(__file__).parent))
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--examples", type=int, default=300, help="sequences per store")
    p.add_argument("--steps", type=int, default=8, help="requests per sequence, at most")
    args = p.parse_args(argv)
    from pgserver import fresh_database, server

    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out["sqlite"] = run_stateful(str(Path(tmp) / "s.db"), args.examples, args.steps)
    gen = server()
    url = next(gen)
    if url is None or url.startswith("skip:"):
        out["postgresql"] = f"skipped: {url}"
    else:
        db = fresh_database(url)
        out["postgresql"] = run_stateful(next(db), args.examples, args.steps)
        db.close()
    gen.close()
    for name, res in out.items():
        if isinstance(res, str):
            print(name, res)
            continue
        print(f"{name}: {res['requests']} requests in {res['sequences']} sequences "
              f"({res['suites_restarted']} suites restarted), {len(res['server_errors'])} 5xx; "
              f"uploads read back {_followed(res['statuses'], 'GET /uploads/')}, withdrawn "
              f"{_followed(res['statuses'], 'DELETE /uploads/')}")
        print("  ", json.dumps(res["statuses"]))
        for e in res["server_errors"][:10]:
            print("   5xx:", e)
    return 1 if any(not isinstance(r, str) and r["server_errors"] for r in out.values()) else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
