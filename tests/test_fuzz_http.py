"""The HTTP family of the fuzz campaign with a small budget (``make test``): a real server on
127.0.0.1 over a SQLite file, mutated uploads, bad tokens, cut bodies, and one SIGKILL
mid-upload; ``make fuzz`` runs 3,200 requests over SQLite and PostgreSQL with 12 kills
(tests/fuzz_http.py, docs/robustness.md)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("fastapi", reason="the service extra (FastAPI) is not installed")
pytest.importorskip("httpx", reason="httpx (a dev dependency) is not installed")

sys.path.insert(0, str(Path(__file__).parent))
import fuzz_http


def test_http_family_small_budget() -> None:
    doc = fuzz_http.run(60, seed=5, kills=1, stores=["sqlite"], progress=lambda _: None)
    run = doc["stores"]["sqlite"]
    assert run["failure_list"] == []
    assert doc["requests"] >= 60 and doc["kills"] == 1 and doc["lost"] == 0
    assert run["acknowledged"] >= 5 and run["orphan_samples"] == 0
    # the campaign reached the refusals it is there for
    statuses = {k.split(":")[1] for k in run["statuses"]}
    assert {"201", "400", "401"} <= statuses, run["statuses"]


def test_identical_uploads_judged_on_their_own_replies() -> None:
    """case_concurrent pairs each reply with its job before skipping lost replies: a lost
    reply neither shifts the fifth (other) take's status into the four identical ones nor
    is taken for a wrong answer."""
    check = fuzz_http.identical_uploads_problem
    assert check([200, 201, 200, 200], asked=4) is None
    assert check([201, 201, 200, 200], asked=4) is not None  # stored twice
    assert check([200, 200, 200, 200], asked=4) is not None  # never stored
    # one reply lost: the lost one may be the 201
    assert check([200, 200, 200], asked=4) is None
    assert check([200, 201, 200], asked=4) is None
    assert check([201, 201, 200], asked=4) is not None
    assert check([200, 409, 200], asked=4) is not None
