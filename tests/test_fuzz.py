"""The fuzz suite with a small budget (``make test``); ``make fuzz`` runs >= 10,000 inputs.

Hypothesis properties over the library's entries (documents, models, state strings, numeric
options, stores), and a short run of the mutation campaign of ``tests/fuzz_harness.py``
through the command line (in-process, and a few cases as subprocesses under the memory and
time limits). See docs/robustness.md.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
from pathlib import Path
from typing import Any

import click
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from nonprehensile.cli.common import bounded
from nonprehensile.errors import InputError
from nonprehensile.io import load_document, model_from_dict
from nonprehensile.motion.store import SQLiteStore
from nonprehensile.skills.skill import skill_from_dict
from nonprehensile.states import State

sys.path.insert(0, str(Path(__file__).parent))
import fuzz_harness

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(
        st.text(max_size=6) | st.integers(), kids, max_size=4),
    max_leaves=30,
)


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=300), st.sampled_from([".json", ".yaml"]))
def test_any_bytes_as_a_document(tmp_path_factory: pytest.TempPathFactory, data: bytes,
                                 suffix: str) -> None:
    p = tmp_path_factory.mktemp("doc") / f"d{suffix}"
    p.write_bytes(data)
    try:
        load_document(p)
    except InputError as exc:
        assert "\n" not in str(exc)


@settings(max_examples=80, deadline=None)
@given(json_values)
def test_any_document_as_a_model(doc: Any) -> None:
    for data in (doc, {"vertices": doc, "faces": doc}, {"vertices": [[0, 0, 0]] * 4,
                                                         "faces": doc, doc.__class__.__name__:
                                                         1}):
        with contextlib.suppress(InputError):
            model_from_dict(data)


@settings(max_examples=60, deadline=None)
@given(json_values)
def test_any_document_as_a_skill(doc: Any) -> None:
    from nonprehensile.geometry import cube

    poly = cube()
    for data in (doc, {"name": "x", "initial": doc, "final": doc, "events": doc,
                       "motions": doc}):
        with contextlib.suppress(InputError):
            skill_from_dict(data, poly)


@settings(max_examples=150, deadline=None)
@given(st.text(max_size=20))
def test_any_text_as_a_state(text: str) -> None:
    try:
        s = State.parse(text)
    except InputError:
        return
    assert math.isfinite(s.theta)


@settings(max_examples=150, deadline=None)
@given(st.one_of(st.floats(), st.integers(), st.text(max_size=12)))
def test_bounded_options(value: object) -> None:
    t_int, t_float = bounded(int, 1, 1000), bounded(float, 30.0, 2000.0)
    for t in (t_int, t_float):
        try:
            v = t.convert(value, None, None)
        except click.BadParameter:
            continue
        assert t.low <= v <= t.high and math.isfinite(v)
        assert not (isinstance(v, float) and math.copysign(1.0, v) < 0 and v == 0)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(1, 6), st.lists(st.floats(-1e6, 1e6), min_size=1, max_size=40))
def test_store_round_trip_is_checksummed(tmp_path_factory: pytest.TempPathFactory, d: int,
                                         values: list[float]) -> None:
    n = max(1, len(values) // d)
    x = np.resize(np.asarray(values, dtype=np.float64), (n, d))
    path = tmp_path_factory.mktemp("store") / "s.db"
    with SQLiteStore(path) as db:
        db.add(x, list(range(n)), np.zeros(n, dtype=np.int64))
    with SQLiteStore(path, readonly=True) as db:
        np.testing.assert_array_equal(db.vectors(0, n), x)
        assert db.verify() == n


def test_mutation_campaign_small_budget() -> None:
    """About 60 mutated and generated inputs over every family, two as subprocesses."""
    cases = fuzz_harness.plan_cases(60)
    assert {f for f, _ in cases} == set(fuzz_harness.FAMILIES)
    report = fuzz_harness.run_campaign(cases, subprocess_every=30)
    doc = report.to_dict()
    assert doc["inputs"] >= 60
    assert sum(report.subprocess_counts.values()) >= 2
    assert doc["failures"] == 0, json.dumps(doc["failure_list"], indent=1)[:4000]


def test_harness_catches_a_failure(tmp_path: Path) -> None:
    """The judge is not blind: a traceback, a bad exit code and a wrong success fail."""
    case = fuzz_harness.Case("model", 0, ["object", "show"], expect="invalid")
    assert fuzz_harness._judge(case, 1, "", ValueError("x"), 0.1) is not None
    assert fuzz_harness._judge(case, 3, "", None, 0.1) == "exit code 3"
    assert fuzz_harness._judge(case, 0, "", None, 0.1) == "exit 0 on invalid input"
    assert fuzz_harness._judge(case, 2, "error: x", None, 61.0) is not None
    assert fuzz_harness._judge(case, 2, "error: bad", None, 0.1) is None
