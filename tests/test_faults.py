"""Fault injection (issue 13): SIGKILL during ingest, concurrent writers, a full disk and a
damaged store file. Nothing committed may be lost, and every failure is one clear line.

The full disk is a 1 MiB tmpfs mounted for the test where the machine allows it (root with
CAP_SYS_ADMIN); the same checks also run everywhere with ``RLIMIT_FSIZE`` (a file-size limit
on the process, whose writes then fail with EFBIG), which needs no privilege.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from nonprehensile.cli import main
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.store import SQLiteStore

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _cli(*args: object, env: dict[str, str] | None = None, fsize: int | None = None,
         timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """The command line as a real process (optionally under a file-size limit)."""
    def limits() -> None:
        if fsize is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of a kill
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run([sys.executable, "-m", "nonprehensile.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, preexec_fn=limits,
                          env={**os.environ, "PYTHONPATH": SRC, **(env or {})})


def _one_error_line(stderr: str, *words: str) -> None:
    lines = [ln for ln in stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert lines[0].startswith("error:"), stderr
    assert "Traceback" not in stderr
    for w in words:
        assert w in lines[0], (w, stderr)


def _snapshot(path: Path) -> tuple[int, np.ndarray, list[int]]:
    with SQLiteStore(path, readonly=True) as db:
        assert db.integrity() == "ok"
        n = db.verify()
        return n, db.vectors(0, n), db.labels().tolist()


@pytest.fixture
def fitted(tmp_path: Path) -> Path:
    rng = np.random.default_rng(3)
    np.save(tmp_path / "x.npy", rng.normal(size=(60, 8)))
    np.save(tmp_path / "more.npy", rng.normal(size=(5, 8)))
    np.save(tmp_path / "big.npy", rng.normal(size=(4000, 8)))
    store = tmp_path / "s.db"
    r = CliRunner().invoke(main, ["cluster", "fit", str(store), "--arrays",
                                  str(tmp_path / "x.npy"), "--n-clusters", "3"])
    assert r.exit_code == 0, r.output
    return store


def test_sigkill_during_ingest_loses_nothing_committed(fitted: Path) -> None:
    """Kill ``cluster add`` at several moments: the store holds exactly the committed adds
    (all or nothing per add), its samples unchanged and checksummed."""
    n0, x0, _ = _snapshot(fitted)
    big = fitted.parent / "big.npy"
    # one add left to finish says how long an add takes on this machine now; the kills
    # then fall across that span (start-up, reading, the transaction, its commit) whatever
    # the load, where fixed delays (0.3-4 s) mostly fell after the end on a quiet machine
    t0 = time.monotonic()
    whole = _cli("cluster", "add", fitted, "--arrays", big, "--json")
    took = time.monotonic() - t0
    assert whole.returncode == 0, whole.stderr
    committed = n0 + 4000
    assert _snapshot(fitted)[0] == committed
    for delay in (f * took for f in (0.15, 0.35, 0.55, 0.75, 0.95)):
        proc = subprocess.Popen(
            [sys.executable, "-m", "nonprehensile.cli", "cluster", "add", str(fitted),
             "--arrays", str(big), "--json"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            env={**os.environ, "PYTHONPATH": SRC})
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
        n, x, _ = _snapshot(fitted)
        assert n in (committed, committed + 4000), (delay, n)  # one transaction per add
        np.testing.assert_array_equal(x[:n0], x0)  # what was committed is untouched
        committed = n
    r = CliRunner().invoke(main, ["cluster", "show", str(fitted), "--json"])
    assert r.exit_code == 0 and json.loads(r.output)["n_samples"] == committed


def test_four_concurrent_writers_complete_every_add(fitted: Path) -> None:
    """4 processes x 3 adds each: every add waits its turn and completes.

    It flaked under load (an add exiting 1): ``cluster add`` read its summary after its
    commit, so another process's add landing in between made the clusterer's labels and the
    store's keys disagree (an IndexError). The summary is now read under the write lock; the
    next test forces that interleaving. A failed add prints its error here."""
    more = fitted.parent / "more.npy"
    script = (
        "import sys\nfrom click.testing import CliRunner\nfrom nonprehensile.cli import main\n"
        "for _ in range(3):\n"
        "    r = CliRunner().invoke(main, ['cluster', 'add', sys.argv[1], '--arrays', "
        "sys.argv[2], '--json'])\n"
        "    print(r.exit_code, flush=True)\n"
        "    if r.exit_code:\n"
        "        print(r.output[-1500:], repr(r.exception), file=sys.stderr, flush=True)\n"
    )
    n0, x0, _ = _snapshot(fitted)
    procs = [subprocess.Popen([sys.executable, "-c", script, str(fitted), str(more)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": SRC}) for _ in range(4)]
    codes, errors = [], []
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
        codes += out.split()
        errors.append(err)
    assert codes == ["0"] * 12, errors
    n, x, _ = _snapshot(fitted)
    assert n == n0 + 12 * 5
    np.testing.assert_array_equal(x[:n0], x0)


def test_an_add_beside_another_reports_the_store_it_wrote(
        fitted: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Another writer's add is ready to commit the moment this add has written its samples
    (what a loaded machine did to the test above): this add's summary is still of the store
    as it wrote it (it crashed, exit 1, when read after its own commit), and both adds are
    kept."""
    import nonprehensile.cli.cluster as cluster_cli

    more_x = np.load(fitted.parent / "more.npy")
    n0 = _snapshot(fitted)[0]
    done = threading.Event()

    def other_add() -> None:  # what another process's `cluster add` does, on its own thread
        with SQLiteStore(fitted) as db, db.transaction():
            c = HilbertClusterer.load_state(db.get_meta(cluster_cli.STATE), db)
            c.partial_fit(more_x)
            db.put_meta(cluster_cli.STATE, c.save_state())
        done.set()

    real = cluster_cli.summary
    other = threading.Thread(target=other_add)

    def summary_with_a_rival(*args: object) -> object:
        other.start()
        # read after the commit, the rival's add landed here; under the lock it waits
        done.wait(1.0)
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(cluster_cli, "summary", summary_with_a_rival)
    r = CliRunner().invoke(main, ["cluster", "add", str(fitted), "--arrays",
                                  str(fitted.parent / "more.npy"), "--json"])
    other.join(60)
    assert r.exit_code == 0, (r.output, r.exception)
    doc = json.loads(r.output)
    assert doc["n_samples"] == n0 + 5 == sum(c["size"] for c in doc["clusters"])
    assert len(doc["labels"]) == 5
    assert done.is_set() and _snapshot(fitted)[0] == n0 + 10


def test_a_writer_waits_longer_than_the_busy_timeout(tmp_path: Path) -> None:
    """A lock held past SQLite's busy timeout: the waiting writer retries and completes."""
    path = tmp_path / "s.db"
    SQLiteStore(path).close()
    started = threading.Event()

    def hold() -> None:  # a connection belongs to its thread
        with SQLiteStore(path) as holder, holder.transaction():
            holder.add(np.ones((1, 2)), [1], np.zeros(1, dtype=np.int64))
            started.set()
            time.sleep(1.0)  # 20 busy timeouts

    t = threading.Thread(target=hold)
    t.start()
    assert started.wait(60)
    with SQLiteStore(path, timeout=0.05) as waiter:  # lock_wait stays at its default
        waiter.add(np.ones((1, 2)), [2], np.zeros(1, dtype=np.int64))
        t.join()
        assert waiter.keys() == [1, 2]


@pytest.fixture
def small_fs(tmp_path: Path) -> Iterator[Path]:
    """A 1 MiB tmpfs, or skip where mounting is not allowed (the RLIMIT_FSIZE tests below
    cover that case)."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root; full disk covered by RLIMIT_FSIZE")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip()}); full disk covered by "
                    "RLIMIT_FSIZE")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def _fill(mnt: Path, leave: int) -> None:
    """Fill the file system but ``leave`` bytes."""
    st = os.statvfs(mnt)
    free = st.f_bavail * st.f_frsize
    if free > leave:
        (mnt / "filler").write_bytes(b"\0" * (free - leave))


def test_full_disk_tmpfs(small_fs: Path, fitted: Path) -> None:
    store = small_fs / "s.db"
    shutil.copy(fitted, store)
    n0, x0, labels0 = _snapshot(store)
    big = fitted.parent / "big.npy"
    _fill(small_fs, 16 * 1024)
    r = _cli("cluster", "add", store, "--arrays", big)
    assert r.returncode == 2, r.stderr
    _one_error_line(r.stderr, str(store), "disk is full")
    n, x, labels = _snapshot(store)
    assert n == n0 and labels == labels0
    np.testing.assert_array_equal(x, x0)
    (small_fs / "filler").unlink()
    _fill(small_fs, 4 * 1024)
    r = _cli("dataset", "synth", small_fs / "ds", "--n-per-skill", "2", "--format", "csv")
    assert r.returncode == 2, r.stderr
    _one_error_line(r.stderr, str(small_fs / "ds"))
    r = _cli("object", "from-mesh", Path(__file__).parent / "data" / "cube.stl", "-o",
             small_fs / "m" / "cube.json")
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_full_disk_file_size_limit(fitted: Path, tmp_path: Path) -> None:
    """The same with RLIMIT_FSIZE: every write beyond the limit fails (EFBIG)."""
    n0, x0, labels0 = _snapshot(fitted)
    big = fitted.parent / "big.npy"
    limit = fitted.stat().st_size + 8 * 1024
    r = _cli("cluster", "add", fitted, "--arrays", big, fsize=limit)
    assert r.returncode == 2, r.stderr
    _one_error_line(r.stderr, str(fitted))
    n, x, labels = _snapshot(fitted)
    assert n == n0 and labels == labels0
    np.testing.assert_array_equal(x, x0)
    out = tmp_path / "ds"
    r = _cli("dataset", "synth", out, "--n-per-skill", "1", "--format", "csv", fsize=4096)
    assert r.returncode == 2, r.stderr
    _one_error_line(r.stderr, str(out))
    r = _cli("object", "show", "cube", "--json")  # reading needs no space: still works
    assert r.returncode == 0


def test_damaged_store_changes_nothing(fitted: Path) -> None:
    """A failed command on a damaged store leaves the file as it was."""
    data = bytearray(fitted.read_bytes())
    data[4096 : 4096 + 8] = b"\xff" * 8  # the header of a b-tree page
    fitted.write_bytes(bytes(data))
    before = fitted.read_bytes()
    r = _cli("cluster", "add", fitted, "--arrays", fitted.parent / "more.npy")
    assert r.returncode == 2
    _one_error_line(r.stderr, str(fitted))
    assert fitted.read_bytes() == before
