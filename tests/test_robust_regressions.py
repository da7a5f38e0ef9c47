"""Regression tests of issue 13: each failure the fuzz and fault campaign found, by name.

Bad input must end in one clear line and exit 2 (never a traceback, a hang or an unbounded
allocation), and stored data must never be lost or silently corrupted.
"""

from __future__ import annotations

import json
import os
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result

from nonprehensile.cli import main
from nonprehensile.errors import InputError
from nonprehensile.io import load_document
from nonprehensile.motion.store import SQLiteStore, StoreFileError


def run(*args: object) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_clear_error(r: Result, *words: str) -> None:
    """Exit 2, no traceback, one line of error naming ``words``."""
    assert r.exit_code == 2, (r.exit_code, r.output, r.exception)
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    text = r.output.strip()
    assert "Traceback" not in text
    last = text.splitlines()[-1]
    for w in words:
        assert w in text, (w, text)
    assert last.startswith(("error:", "Error:")), text


# ----------------------------------------------------------------------- JSON / YAML files
@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_document_nested_thousands_deep(tmp_path: Path, suffix: str) -> None:
    p = tmp_path / f"deep{suffix}"
    p.write_text("[" * 5000 + "]" * 5000)
    assert_clear_error(run("object", "show", p), "nested more than")
    # below the parser's recursion limit but far deeper than the spec's files
    p.write_text("[" * 500 + "]" * 500)
    assert_clear_error(run("object", "show", p), "nested more than")


def test_yaml_aliases_that_expand_or_loop(tmp_path: Path) -> None:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    for i in range(1, 9):
        refs = ", ".join([f"*a{i - 1}"] * 10)
        lines.append(f"a{i}: &a{i} [{refs}]")
    p = tmp_path / "laughs.yaml"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="expands to more than"):
        load_document(p)
    q = tmp_path / "loop.yaml"
    q.write_text("&a [*a]\n")
    with pytest.raises(InputError, match="contains itself"):
        load_document(q)


def test_yaml_error_is_one_line(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("a: [1, 2\nb: 3\n")
    r = run("object", "show", p)
    assert_clear_error(r, "line 2, column 2")
    assert len(r.output.strip().splitlines()) == 1


def test_unknown_keys_of_different_types(tmp_path: Path) -> None:
    model = tmp_path / "m.yaml"
    model.write_text("vertices: []\nfaces: {}\n1: 2\nb: 3\n")
    assert_clear_error(run("object", "show", model), "unknown key(s) ['1', 'b']")
    skills = tmp_path / "s.yaml"
    skills.write_text("object: cube\nskills:\n- name: x\n  1: 2\n  b: 3\n")
    assert_clear_error(run("skills", "show", skills), "unknown key(s)")
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "annotations.yaml").write_text(
        "skills: s.json\n1: 2\nzz: 3\ndemonstrations:\n- {file: a.csv, 2: 1, q: 2}\n")
    r = run("dataset", "show", ds)
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert "unknown key(s) ['1', 'zz']" in r.output


@pytest.mark.parametrize("name", ["a\x00b.json", "a\ud800b.json"])
def test_nul_and_lone_surrogate_in_file_names(tmp_path: Path, name: str) -> None:
    assert_clear_error(run("object", "show", name), "argument 3", "NUL")
    assert_clear_error(run("object", "from-mesh", "x.stl", "-o", name), "the value of -o")
    with pytest.raises(InputError, match="file name"):
        load_document(name)


# ------------------------------------------------------------------------ dataset synth
@pytest.mark.parametrize(("option", "value"), [
    ("--mentors", "4294967296"),
    ("--n-per-skill", "4294967296"),
    ("--rate", "1e9"),
    ("--rate", "nan"),
    ("--seed", "-5"),
    ("--gap-limit", str(2**64)),
    ("--noise", "inf"),
    ("--scale", "1e300"),
])
def test_synth_options_are_bounded_before_work(tmp_path: Path, option: str, value: str) -> None:
    r = run("dataset", "synth", tmp_path / "out", option, value)
    assert_clear_error(r, option)
    assert not (tmp_path / "out").exists()


def test_synth_total_work_is_bounded(tmp_path: Path) -> None:
    r = run("dataset", "synth", tmp_path / "out", "--n-per-skill", "1000", "--rate", "2000")
    assert_clear_error(r, "demonstrations x rate")


def test_synth_noise_minus_zero(tmp_path: Path) -> None:
    r = run("dataset", "synth", tmp_path / "out", "--noise", "-0", "--n-per-skill", "1",
            "--format", "csv")
    assert r.exit_code == 0, r.output
    assert run("dataset", "show", tmp_path / "out").exit_code == 0


def test_synth_refuses_to_overwrite_a_dataset(tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert run("dataset", "synth", out, "--n-per-skill", "1", "--format", "csv").exit_code == 0
    ann = out / "annotations.json"
    ann.write_text(ann.read_text().replace('"mentor": "ana"', '"mentor": "edited"'))
    before = ann.read_text()
    r = run("dataset", "synth", out, "--n-per-skill", "1", "--format", "csv")
    assert_clear_error(r, "already holds a dataset", "--force")
    assert ann.read_text() == before
    r = run("dataset", "synth", out, "--n-per-skill", "1", "--format", "csv", "--force")
    assert r.exit_code == 0 and ann.read_text() != before


# -------------------------------------------------------------------------- .npy inputs
def _huge_header_npy(path: Path) -> None:
    hdr = "{'descr': '<f8', 'fortran_order': False, 'shape': (100000000, 100000), }"
    hdr = hdr + " " * (118 - len(hdr)) + "\n"
    path.write_bytes(b"\x93NUMPY\x01\x00" + len(hdr).to_bytes(2, "little") + hdr.encode()
                     + b"\0" * 64)


def test_bad_npy_inputs_to_cluster(tmp_path: Path) -> None:
    store = tmp_path / "s.db"
    cases: dict[str, str] = {}
    np.save(tmp_path / "zero_d.npy", np.array(3.0))
    cases["zero_d.npy"] = "2-D array"
    np.save(tmp_path / "object.npy", np.array([[1, "a"]], dtype=object), allow_pickle=True)
    cases["object.npy"] = "object"
    (tmp_path / "empty.npy").write_bytes(b"")
    cases["empty.npy"] = "not a numpy"
    np.save(tmp_path / "ok.npy", np.random.default_rng(0).random((20, 4)))
    ok = (tmp_path / "ok.npy").read_bytes()
    (tmp_path / "truncated.npy").write_bytes(ok[:-8])
    cases["truncated.npy"] = "truncated"
    (tmp_path / "header_cut.npy").write_bytes(ok[:60])
    cases["header_cut.npy"] = "header"
    _huge_header_npy(tmp_path / "huge.npy")
    cases["huge.npy"] = "more than the"
    np.savez(tmp_path / "z.npz", X=np.random.default_rng(0).random((20, 4)))
    z = (tmp_path / "z.npz").read_bytes()
    (tmp_path / "crc.npz").write_bytes(z[:200] + bytes([z[200] ^ 1]) + z[201:])
    cases["crc.npz"] = "damaged"
    (tmp_path / "cut.npz").write_bytes(z[:-30])
    cases["cut.npz"] = "damaged"
    np.save(tmp_path / "one_d.npy", np.zeros(5))
    cases["one_d.npy"] = "2-D array"
    for name, words in cases.items():
        r = run("cluster", "fit", store, "--arrays", tmp_path / name)
        assert_clear_error(r, name, words)
    assert not store.exists()


# ------------------------------------------------------------------------- SQLite store
def _fitted_store(tmp_path: Path, n: int = 40) -> Path:
    x = np.random.default_rng(1).normal(size=(n, 6))
    x[7] = 12345.678  # a recognisable vector, to find its bytes in the file
    np.save(tmp_path / "x.npy", x)
    store = tmp_path / "s.db"
    r = run("cluster", "fit", store, "--arrays", tmp_path / "x.npy", "--n-clusters", "2")
    assert r.exit_code == 0, r.output
    return store


def test_store_checksum_reports_zeroed_vector(tmp_path: Path) -> None:
    store = _fitted_store(tmp_path)
    data = bytearray(store.read_bytes())
    needle = np.full(6, 12345.678).tobytes()
    at = data.find(needle)
    assert at > 0
    data[at : at + len(needle)] = bytes(len(needle))  # zeroed: the page stays well formed
    store.write_bytes(bytes(data))
    with SQLiteStore(store) as db:
        assert db.integrity() == "ok"  # SQLite cannot see it ...
        with pytest.raises(StoreFileError, match=r"sample 7: .*checksum"):
            db.verify()
        with pytest.raises(StoreFileError, match=r"sample 7: .*checksum"):
            db.vectors(0, 40)  # every read of it, not only verify()


def test_store_short_vector_blob(tmp_path: Path) -> None:
    store = _fitted_store(tmp_path)
    db = sqlite3.connect(store)
    db.execute("UPDATE samples SET vector = x'0102' WHERE id = 5")
    db.commit()
    db.close()
    with SQLiteStore(store) as db, pytest.raises(StoreFileError, match=r"sample 4: .*bytes"):
        db.vectors(0, 40)


def test_store_corrupted_page(tmp_path: Path) -> None:
    store = _fitted_store(tmp_path, n=400)
    data = bytearray(store.read_bytes())
    page = 4096
    assert len(data) > 4 * page
    data[2 * page + 8 : 2 * page + 400] = b"\xa5" * 392
    store.write_bytes(bytes(data))
    for cmd in ("show", "add"):
        args = ["cluster", cmd, store] + (["--arrays", tmp_path / "x.npy"] if cmd == "add"
                                          else [])
        assert_clear_error(run(*args), "s.db", "damaged")


def test_store_not_a_database(tmp_path: Path) -> None:
    store = tmp_path / "s.db"
    store.write_bytes(b"not sqlite at all" * 100)
    assert_clear_error(run("cluster", "show", store), "s.db")


def test_cluster_show_takes_no_write_lock(tmp_path: Path) -> None:
    store = _fitted_store(tmp_path)
    holder = sqlite3.connect(store, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")  # another process is registering
    try:
        r = run("cluster", "show", store, "--json")
        assert r.exit_code == 0, r.output
        assert json.loads(r.output)["n_samples"] == 40
    finally:
        holder.execute("ROLLBACK")
        holder.close()


def test_readonly_store_reads_and_refuses_writes(tmp_path: Path) -> None:
    store = _fitted_store(tmp_path)
    with SQLiteStore(store, readonly=True) as db:
        assert db.n_samples == 40
        with pytest.raises(StoreFileError, match="read-only"):
            db.put_meta("x", b"1")
    with pytest.raises(InputError, match="no such store"):
        SQLiteStore(tmp_path / "absent.db", readonly=True)


# ------------------------------------------------------------------------------- C3D files
SEED_C3D = Path(__file__).parent / "data" / "seed.c3d"  # a copy, so the offsets below hold


def _mutant(tmp_path: Path, name: str) -> Path:
    """The two damaged files of issue 13, made from the seed: two flipped bits that make ezc3d
    crash (SIGSEGV), and bytes deleted / bits flipped that make it loop."""
    b = bytearray(SEED_C3D.read_bytes())
    if name == "segfault_flip":
        b[1033] ^= 1 << 7
        b[2808] ^= 1 << 1
    elif name == "segfault_delete":
        del b[1063 : 1063 + 23]
    elif name == "hang_flip":
        b[977] ^= 1 << 5
        b[767] ^= 1 << 6
    p = tmp_path / f"{name}.c3d"
    p.write_bytes(bytes(b))
    return p


def _raw_ezc3d(path: Path, timeout: float) -> int | str:
    """What ezc3d alone does with ``path``, in a throwaway process: exit code or 'hang'."""
    import subprocess
    import sys

    try:
        r = subprocess.run([sys.executable, "-c", "import ezc3d, sys; ezc3d.c3d(sys.argv[1])",
                            str(path)], capture_output=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "hang"
    return r.returncode


@pytest.mark.parametrize("name", ["segfault_flip", "segfault_delete"])
def test_c3d_that_crashes_ezc3d_cannot_take_the_caller_down(tmp_path: Path, name: str) -> None:
    from nonprehensile.demonstrations.c3d_safe import C3DWorker
    from nonprehensile.demonstrations.formats import read_c3d
    from nonprehensile.errors import DemonstrationError

    path = _mutant(tmp_path, name)
    assert _raw_ezc3d(path, 30) == -11  # the library alone dies of SIGSEGV
    # the isolated worker alone (no structural check first) reports the crash and recovers
    worker = C3DWorker()
    try:
        with pytest.raises(DemonstrationError, match=r"crashed on this file \(signal SIGSEGV"):
            worker.parse(path)
        assert worker.parse(SEED_C3D)["data"]["points"].shape[1] == 4
    finally:
        worker.close()
    with pytest.raises(DemonstrationError, match=name):
        read_c3d(path)


def test_c3d_that_hangs_ezc3d_is_stopped(tmp_path: Path) -> None:
    from nonprehensile.demonstrations.c3d_safe import C3DWorker, check_c3d_structure
    from nonprehensile.errors import DemonstrationError

    path = _mutant(tmp_path, "hang_flip")
    assert _raw_ezc3d(path, 5) == "hang"
    worker = C3DWorker(timeout=1.0)
    try:
        with pytest.raises(DemonstrationError, match="did not finish"):
            worker.parse(path)
        assert worker.parse(SEED_C3D)["data"]["points"].shape[1] == 4
    finally:
        worker.close()
    # the structural check rejects it before ezc3d sees it
    with pytest.raises(DemonstrationError, match="outside the parameter section"):
        check_c3d_structure(path)


def test_damaged_c3d_in_a_dataset_is_one_problem(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    assert run("dataset", "synth", out, "--n-per-skill", "1").exit_code == 0
    victim = sorted(out.glob("*.c3d"))[0]
    b = bytearray(victim.read_bytes())
    del b[1063 : 1063 + 23]
    victim.write_bytes(bytes(b))
    r = run("dataset", "show", out)
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert victim.name in r.output and "C3D" in r.output


def test_huge_coordinate_in_csv_is_refused_at_read(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    assert run("dataset", "synth", out, "--n-per-skill", "1", "--format", "csv").exit_code == 0
    victim = sorted(out.glob("*.csv"))[0]
    lines = victim.read_text().splitlines()
    cells = lines[10].split(",")
    cells[4] = "1e308"
    lines[10] = ",".join(cells)
    victim.write_text("\n".join(lines) + "\n")
    r = run("dataset", "show", out)
    assert r.exit_code == 2 and "beyond" in r.output
    r = run("cluster", "fit", tmp_path / "s.db", "--dataset", out)
    assert r.exit_code == 2 and "beyond" in r.output and "Traceback" not in r.output


# <repo>/../shared/realdata (GUIDE.md); NONPREHENSILE_SHARED points elsewhere (a worktree)
REAL_C3D = Path(os.environ.get("NONPREHENSILE_SHARED")
                or Path(__file__).resolve().parents[1].parent / "shared") / "realdata" / "c3d"


@pytest.mark.skipif(not REAL_C3D.is_dir(), reason="../shared/realdata is not beside the repo")
def test_real_c3d_two_flipped_bits_and_23_bytes_deleted(tmp_path: Path) -> None:
    """Issue 13's two files, from real recordings: two flipped bits of an Optotrak file make
    ezc3d segfault; 23 bytes deleted from a force-plate file make it loop."""
    from nonprehensile.demonstrations.formats import read_c3d
    from nonprehensile.errors import DemonstrationError

    b = bytearray((REAL_C3D / "Optotrak.c3d").read_bytes())
    b[550] ^= 1 << 7
    b[317] ^= 1 << 1
    flipped = tmp_path / "optotrak_flipped.c3d"
    flipped.write_bytes(bytes(b))
    b = bytearray((REAL_C3D / "FP_Type3.c3d").read_bytes())
    del b[855 : 855 + 23]
    cut = tmp_path / "fp_type3_cut.c3d"
    cut.write_bytes(bytes(b))
    assert _raw_ezc3d(flipped, 30) == -11
    assert _raw_ezc3d(cut, 3) == "hang"
    for path in (flipped, cut):
        with pytest.raises(DemonstrationError, match=path.name):
            read_c3d(path)
    # and the reader still works after them
    assert read_c3d(REAL_C3D / "Vicon.c3d").n_frames > 0


# ----------------------------------------------------------- found by `make fuzz` (07:40)
def _npy_with_header(path: Path, header: str) -> None:
    body = header.ljust(118) + "\n"
    path.write_bytes(b"\x93NUMPY\x01\x00" + len(body).to_bytes(2, "little") + body.encode()
                     + bytes(8 * 80))


def test_npy_header_numpy_cannot_tokenize(tmp_path: Path) -> None:
    # numpy parses the header dict with tokenize: an unclosed bracket raised TokenError
    bad = tmp_path / "unclosed.npy"
    _npy_with_header(bad, "{'descr': '<f8', 'fortran_order': False, 'shape': (20, 4")
    r = run("cluster", "fit", tmp_path / "s.db", "--arrays", bad)
    assert_clear_error(r, "unclosed.npy", "header")


def test_nul_in_an_annotated_file_name(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    assert run("dataset", "synth", out, "--n-per-skill", "1").exit_code == 0
    ann = out / "annotations.json"
    doc = json.loads(ann.read_text())
    doc["demonstrations"][0]["file"] = "a\x00b.c3d"
    ann.write_text(json.dumps(doc))
    r = run("dataset", "show", out)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "NUL" in r.output


def test_full_disk_writing_the_report_names_the_file(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    # a full disk fails in write(), whose OSError names no file: the report's writer names it
    from nonprehensile.viz.report import write_report

    def full(self: Path, *args: object, **kwargs: object) -> int:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "write_text", full)
    with pytest.raises(InputError, match=r"index\.html: cannot write it: No space left"):
        write_report(tmp_path, "t", "i", [])
    assert not list(tmp_path.iterdir())  # no half-written file left behind


@pytest.mark.skipif(not REAL_C3D.is_dir(), reason="../shared/realdata is not beside the repo")
def test_c3d_worker_answers_with_the_point_group_only() -> None:
    """Vendors' files carry many parameter groups (analog, force plates, subjects...); the
    worker sends back the one the reader uses (issue 16), and the reader's result is what
    ezc3d's full object gives."""
    import ezc3d

    from nonprehensile.demonstrations.c3d_safe import parse_c3d
    from nonprehensile.demonstrations.formats import read_c3d

    for name in ("Vicon.c3d", "FP_Type1.c3d", "Qualisys.c3d"):
        full = ezc3d.c3d(str(REAL_C3D / name))
        assert len(full["parameters"]) > 2
        doc = parse_c3d(REAL_C3D / name)
        assert set(doc["parameters"]) == {"POINT"}
        for key in ("RATE", "UNITS", "LABELS"):
            assert list(doc["parameters"]["POINT"][key]["value"]) == list(
                full["parameters"]["POINT"][key]["value"])
        traj = read_c3d(REAL_C3D / name)
        assert traj.n_frames == full["data"]["points"].shape[2]


@pytest.mark.skipif(not REAL_C3D.is_dir(), reason="../shared/realdata is not beside the repo")
def test_a_c3d_file_cut_inside_a_frame_is_refused_and_overstated_counts_are_not(
        tmp_path: Path) -> None:
    """A copy of a Vicon take cut at 30,000 bytes read as a 4-frame recording, silently (ezc3d
    reads the frames there are). A file that ends inside a frame was cut; the Optotrak sample,
    whose header counts 1149 frames but which holds 29 whole ones, still reads."""
    from nonprehensile.demonstrations.formats import read_c3d
    from nonprehensile.errors import DemonstrationError

    data = (REAL_C3D / "Vicon.c3d").read_bytes()
    for n in (30000, len(data) // 2, len(data) - 1000):
        cut = tmp_path / f"vicon_{n}.c3d"
        cut.write_bytes(data[:n])
        with pytest.raises(DemonstrationError, match=r"cut short: the header and POINT:FRAMES "
                                                     r"count 580 frames") as info:
            read_c3d(cut)
        assert str(info.value).startswith(str(cut)) and "\n" not in str(info.value)
    assert read_c3d(REAL_C3D / "Optotrak.c3d").n_frames == 29
    for name in ("Vicon.c3d", "BTS.c3d", "Qualisys.c3d", "FP_Type1.c3d", "read_NOTworking2.c3d"):
        assert read_c3d(REAL_C3D / name).n_frames > 0


def test_a_written_c3d_file_cut_short_is_refused(tmp_path: Path) -> None:
    """The same without the real files: a take the project wrote, cut inside a frame."""
    pytest.importorskip("ezc3d")
    from nonprehensile.demonstrations.formats import read_c3d, write_c3d
    from nonprehensile.demonstrations.record import MarkerTrajectory
    from nonprehensile.errors import DemonstrationError

    pos = np.random.default_rng(0).normal(size=(300, 4, 3)) * 100
    path = tmp_path / "take.c3d"
    write_c3d(MarkerTrajectory.from_arrays(pos, ["a", "b", "c", "d"], 120.0, "mm"), path)
    assert read_c3d(path).n_frames == 300
    data = path.read_bytes()
    (tmp_path / "cut.c3d").write_bytes(data[: len(data) // 2 + 7])
    with pytest.raises(DemonstrationError, match="cut short"):
        read_c3d(tmp_path / "cut.c3d")
