"""Shared fixtures and hypothesis strategies."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings, strategies as st

from nonprehensile.geometry import (
    Polyhedron,
    box,
    convex_hull,
    cube,
    octahedron,
    prism,
    tetrahedron,
)
from nonprehensile.states import State, state_pose

# ``make test`` runs the suite on two processes (pytest-xdist): its workers inherit
# COLUMNS=80 (measured), and the CLI's tests read output as a pipe gives it (the tables
# whole: ``cli.common.PIPED_WIDTH``), never squeezed to a width a terminal would set
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.pop("COLUMNS", None)

settings.register_profile("default", max_examples=40, deadline=None)
settings.load_profile("default")

DATA = Path(__file__).parent / "data"


def scalene() -> Polyhedron:
    """An irregular solid with no rotation symmetry."""
    pts = [[0, 0, 0], [2.0, 0.1, 0], [0.3, 1.7, 0.2], [0.1, 0.2, 1.3], [1.4, 1.1, 0.9],
           [1.9, 1.2, 0.1]]
    return convex_hull(np.array(pts, dtype=float), name="scalene")


SOLIDS = {
    "cube": cube,
    "box112": lambda: box(1, 1, 2),
    "tetrahedron": tetrahedron,
    "octahedron": octahedron,
    "prism3": lambda: prism(3),
    "prism6": lambda: prism(6),
    "scalene": scalene,
}

#: Orders of the proper rotation groups, from the classification of finite rotation groups.
GROUP_ORDERS = {
    "cube": 24,
    "box112": 8,
    "tetrahedron": 12,
    "octahedron": 24,
    "prism3": 6,
    "prism6": 12,
    "scalene": 1,
}


@pytest.fixture(params=sorted(SOLIDS))
def solid(request: pytest.FixtureRequest) -> tuple[str, Polyhedron]:
    return request.param, SOLIDS[request.param]()


@st.composite
def random_hulls(draw: st.DrawFn) -> Polyhedron:
    """Convex hulls of 6..16 random points (general position, almost surely)."""
    seed = draw(st.integers(0, 2**31 - 1))
    n = draw(st.integers(6, 16))
    rng = np.random.default_rng(seed)
    return convex_hull(rng.normal(size=(n, 3)), name=f"hull{seed}")


def rotation_matrix(seed: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return np.asarray(Rotation.random(random_state=seed).as_matrix())


def world_points(p: Polyhedron, s: State) -> np.ndarray:
    """Vertices of ``p`` in the world when it rests in state ``s``, shape (n_vertices, 3)."""
    rot, t = state_pose(p, s)
    return np.asarray(p.vertices @ rot.T + t)


def occupies_same_space(p: Polyhedron, a: State, b: State, atol: float = 1e-7) -> bool:
    """Independent truth of geometric equivalence: the world vertex sets coincide up to a
    horizontal translation, and so do the centres of mass."""
    ra, ta = state_pose(p, a)
    rb, tb = state_pose(p, b)
    shift = (ra @ p.com + ta) - (rb @ p.com + tb)
    if abs(shift[2]) > atol:
        return False
    wa = world_points(p, a)
    wb = world_points(p, b) + shift
    d = np.linalg.norm(wa[:, None] - wb[None], axis=-1)
    return bool(d.min(axis=1).max() <= atol and d.min(axis=0).max() <= atol)


# ------------------------------------------------------------------ the cache folder
@pytest.fixture(scope="session", autouse=True)
def _session_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Motion libraries, sweeps and robot runs the tests build go to one folder of this
    session, as on CI's fresh machine: never to the user's ``~/.cache/nonprehensile``, which
    gained a library for every test dataset's temporary path at every run, and whose kept
    sweeps and robot runs hid from local timings what a fresh machine computes."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NONPREHENSILE_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


# ------------------------------------------------------------------ PostgreSQL (tests/pgserver)
@pytest.fixture(scope="session")
def pg_server() -> Iterator[str]:
    """URL of a PostgreSQL server (see tests/pgserver.py); skips, saying why, without one."""
    from pgserver import server

    gen = server()
    url = next(gen)
    if url is None or url.startswith("skip:"):
        pytest.skip(url.removeprefix("skip: ") if url else "no PostgreSQL server")
    yield url
    gen.close()


@pytest.fixture
def pg_url(pg_server: str) -> Iterator[str]:
    """A fresh, empty database on the test server, dropped after the test."""
    from pgserver import fresh_database

    yield from fresh_database(pg_server)


# ------------------------------------------------------------------ the main job, run once
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """On two processes (``make test``: ``pytest -n 2 --dist loadgroup``) the tests that use
    the main job's session run go to one worker, so the demo runs once, not once per
    worker (its robot execution and sweep are 15 s of CPU)."""
    del config
    for item in items:
        if {"demo_run", "demo_cache"} & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.xdist_group("demo"))


@pytest.fixture(scope="session")
def demo_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo's own cache folder: its robot execution and sweep are run, not found."""
    return tmp_path_factory.mktemp("demo-cache")


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory: pytest.TempPathFactory,
             demo_cache: Path) -> tuple[Path, dict[str, object]]:
    """``nonprehensile demo --json`` once for the session (tests/test_demo.py checks it;
    tests/test_report_runs.py reuses its robot execution from ``demo_cache``)."""
    import json

    from click.testing import CliRunner

    from nonprehensile.cli import main

    pytest.importorskip("matplotlib")
    pytest.importorskip("sklearn")
    pytest.importorskip("ezc3d")
    out = tmp_path_factory.mktemp("demo") / "report"
    # a CI-sized robustness sweep (3 samples, run here: the shipped 200-sample one has its
    # own tests, tests/test_report_runs.py)
    res = CliRunner(env={"NONPREHENSILE_CACHE": str(demo_cache)}).invoke(
        main, ["demo", "--out", str(out), "--json", "--sweep-samples", "3"])
    assert res.exit_code == 0, res.stderr
    return out, json.loads(res.stdout)
