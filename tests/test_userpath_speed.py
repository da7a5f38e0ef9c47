"""What the main job's speed work (issue 16) replaced, checked against what it replaced: the
adjusted Rand index against scikit-learn's, the re-entrant one-thread block against
threadpoolctl's own report, the C3D worker's framing against damaged answers."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from nonprehensile.demonstrations.c3d_safe import _pack, _unpack
from nonprehensile.errors import DemonstrationError
from nonprehensile.motion.microcluster import one_thread
from nonprehensile.pipeline import adjusted_rand_index

labelings = st.integers(0, 40).flatmap(lambda n: st.tuples(
    st.lists(st.integers(0, 4), min_size=n, max_size=n),
    st.lists(st.sampled_from("abcde"), min_size=n, max_size=n)))


@settings(max_examples=300, deadline=None)
@given(labelings)
def test_adjusted_rand_index_is_scikit_learns(pair: tuple[list[int], list[str]]) -> None:
    metrics = pytest.importorskip("sklearn.metrics")
    a, b = pair
    assert adjusted_rand_index(a, b) == pytest.approx(metrics.adjusted_rand_score(a, b),
                                                      abs=1e-12)
    assert adjusted_rand_index(a, a) == 1.0


def test_adjusted_rand_index_refuses_different_lengths() -> None:
    with pytest.raises(ValueError, match="3 and 2"):
        adjusted_rand_index([0, 1, 1], [0, 1])


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info

    return [int(i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas"]


def test_one_thread_is_reentrant_and_restores() -> None:
    pytest.importorskip("threadpoolctl")
    before = _blas_threads()
    with one_thread():
        assert set(_blas_threads()) == {1}
        with one_thread():
            assert set(_blas_threads()) == {1}
        # closing the inner block keeps the outer one's limit
        assert set(_blas_threads()) == {1}
    assert _blas_threads() == before


def test_c3d_answer_round_trip_and_damage() -> None:
    arrays = {"a0": np.arange(12.0).reshape(3, 4), "a1": np.array(["x", "yz"]),
              "a2": np.zeros((0, 3), dtype=np.int16)}
    doc = {"header": {"points": {"__array__": "a0"}}, "n": 3}
    payload = _pack(doc, arrays)
    got_doc, got = _unpack(Path("f.c3d"), payload)
    assert got_doc == doc
    for k, v in arrays.items():
        np.testing.assert_array_equal(got[k], v)
        assert got[k].dtype == v.dtype and got[k].flags.writeable
    # cut short, one byte too many, an object dtype, a header longer than the answer
    head_len = struct.unpack("<Q", payload[:8])[0]
    bad_dtype = payload.replace(b'"<f8"', b'"|O8"', 1)
    for broken in (payload[:-1], payload + b"\0", bad_dtype,
                   struct.pack("<Q", head_len + 10**6) + payload[8:]):
        with pytest.raises(DemonstrationError, match=r"f\.c3d: the C3D reader's answer"):
            _unpack(Path("f.c3d"), broken)


def test_collector_spared_skips_the_objects_alive_and_collects_the_rest() -> None:
    """The report's block (issue 16): what is alive on entry is frozen (full collections do
    not walk it), garbage made inside is still collected, and on exit the frozen objects are
    the collector's again (a cycle that died inside is collected then); where objects were
    already frozen, the block leaves the freeze as it found it."""
    import gc
    import weakref

    from nonprehensile.viz.demo_report import collector_spared

    if gc.get_freeze_count():
        pytest.skip("this process has frozen objects already")

    class Node:
        pass

    def cycle() -> tuple[Node, weakref.ref[Node]]:
        a, b = Node(), Node()
        a.other, b.other = b, a  # type: ignore[attr-defined]
        return a, weakref.ref(a)

    old, old_ref = cycle()
    with collector_spared():
        assert gc.get_freeze_count() > 0
        del old  # a frozen cycle that dies is left alone while frozen
        gc.collect()
        assert old_ref() is not None
        new, new_ref = cycle()
        del new  # one made inside is collected as usual
        gc.collect()
        assert new_ref() is None
    assert gc.get_freeze_count() == 0
    gc.collect()
    assert old_ref() is None
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        with collector_spared():
            assert gc.get_freeze_count() == frozen
        assert gc.get_freeze_count() == frozen
    finally:
        gc.unfreeze()
