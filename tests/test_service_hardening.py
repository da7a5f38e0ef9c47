"""Issue 25's service failures, one regression test each: bad uploads that got a 500 (huge
integers, deep nesting, name clashes, unreadable zip members, YAML types JSON has not), an
archive bomb loaded whole before its file count was checked, a chunked body over the limit
answered 400, a reply naming the server's temporary folder, archive keys dropped silently,
and a withdrawn take that never came back when uploaded again."""

from __future__ import annotations

import gzip
import io
import json
import re
import struct
import tarfile
import tempfile
import tracemalloc
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

pytest.importorskip("fastapi", reason="the service extra (FastAPI) is not installed")
pytest.importorskip("psycopg", reason="the pg extra (psycopg) is not installed")

from fastapi.testclient import TestClient

import nonprehensile
from nonprehensile.cli import main
from nonprehensile.demonstrations.dataset import dataset_path
from nonprehensile.errors import InputError
from nonprehensile.service import ServiceConfig, create_app, create_token, load_template, make_pool
from nonprehensile.service.ingest import MAX_ARCHIVE_FILES, Registry, extract_archive

CUBE = dataset_path("cube")
ANN = json.loads((CUBE / "annotations.json").read_text())
TOP = {k: v for k, v in ANN.items() if k != "demonstrations"}
MAX_BYTES = 4_000_000
#: What a reply must never show: where the server keeps its files.
SERVER_PATHS = (tempfile.gettempdir() + "/", str(Path(nonprehensile.__file__).parent),
                str(CUBE))


@pytest.fixture(scope="module")
def template() -> Any:
    return load_template("cube")


def _client(store: str, template: Any) -> Iterator[dict[str, Any]]:
    pool = make_pool(store, max_size=4)
    with pool.connection() as conn:
        tokens = {m: create_token(conn, m) for m in ("ana", "ben")}
    registry = Registry(pool, template, init_size=4, checkpoint=3)
    app = create_app(pool, template, ServiceConfig("test", max_bytes=MAX_BYTES),
                     registry=registry, background=False)
    # a 500 must come back as a response here, as a client sees it, not as the exception
    with TestClient(app, raise_server_exceptions=False) as client:
        yield {"client": client, "pool": pool,
               "auth": {m: {"Authorization": f"Bearer {t}"} for m, t in tokens.items()}}
    pool.close()


@pytest.fixture
def svc(tmp_path: Path, template: Any) -> Iterator[dict[str, Any]]:
    yield from _client(str(tmp_path / "service.db"), template)


def _entry(skill: str = "push-roll", mentor: str = "ana", k: int = 0) -> dict[str, Any]:
    return [d for d in ANN["demonstrations"] if d["skill"] == skill and d["mentor"] == mentor][k]


def _post_take(c: TestClient, auth: dict[str, str], entry: dict[str, Any],
               annotation: str | None = None) -> Any:
    ann = annotation if annotation is not None else json.dumps(
        {k: v for k, v in entry.items() if k not in ("file", "mentor")})
    return c.post("/demonstrations",
                  files={"file": (entry["file"], (CUBE / entry["file"]).read_bytes(),
                                  "application/octet-stream")},
                  data={"annotation": ann}, headers=auth)


def _refused(r: Any, *statuses: int) -> str:
    """The one-line detail of a 4xx reply (and no server path anywhere in it)."""
    assert r.status_code in statuses, (r.status_code, r.text[:300])
    detail = r.json()["detail"]
    assert isinstance(detail, str) and detail and "\n" not in detail
    for p in SERVER_PATHS:
        assert p not in r.text, (p, r.text[:300])
    return detail


def _dataset_files(mentor: str = "ben", n: int = 2, prefix: str = "takes/",
                   **top: Any) -> dict[str, bytes]:
    demos = [d for d in ANN["demonstrations"] if d["mentor"] == mentor][:n]
    files = {f"{prefix}{d['file']}": (CUBE / d["file"]).read_bytes() for d in demos}
    files[f"{prefix}skills.json"] = (CUBE / ANN["skills"]).read_bytes()
    files[f"{prefix}annotations.json"] = json.dumps(
        {**TOP, **top, "demonstrations": demos}).encode()
    return files


def _zip(files: dict[str, bytes], method: int = zipfile.ZIP_STORED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name, data in files.items():
            zf.writestr(name, data)
    return buf.getvalue()


def _post_archive(c: TestClient, auth: dict[str, str], data: bytes, name: str = "a.zip") -> Any:
    return c.post("/datasets", files={"archive": (name, data, "application/octet-stream")},
                  headers=auth)


def _patch_member(data: bytes, name: str, *, flags: int | None = None,
                  method: int | None = None, payload: Any = None) -> bytes:
    """``data`` (a zip) with the local and central headers of member ``name`` changed."""
    b = bytearray(data)
    zf = zipfile.ZipFile(io.BytesIO(data))
    info = zf.getinfo(name)
    local = info.header_offset
    assert b[local:local + 4] == b"PK\x03\x04"
    central = b.find(b"PK\x01\x02")
    while central >= 0:
        n = struct.unpack_from("<H", b, central + 28)[0]
        if bytes(b[central + 46 : central + 46 + n]) == name.encode():
            break
        central = b.find(b"PK\x01\x02", central + 4)
    assert central >= 0
    if flags is not None:
        struct.pack_into("<H", b, local + 6, flags)
        struct.pack_into("<H", b, central + 8, flags)
    if method is not None:
        struct.pack_into("<H", b, local + 8, method)
        struct.pack_into("<H", b, central + 10, method)
    if payload is not None:
        n, m = struct.unpack_from("<HH", b, local + 26)
        start = local + 30 + n + m
        payload(b, start, info.compress_size)
    return bytes(b)


# ------------------------------------------------------------------------ annotation JSON
@pytest.mark.parametrize("depth", [970, 985, 990, 5000])
def test_deeply_nested_annotation_is_a_400(svc: dict[str, Any], depth: int) -> None:
    """985 levels got a 500 (a RecursionError in json.dumps); 970 a 422, 990 a 400."""
    e = _entry()
    ann = {k: v for k, v in e.items() if k not in ("file", "mentor")}
    text = json.dumps(ann)[:-1] + ', "x": ' + "[" * depth + "]" * depth + "}"
    detail = _refused(_post_take(svc["client"], svc["auth"]["ana"], e, text), 400)
    assert "nested more than 64 levels" in detail


def test_huge_integers_in_an_annotation_are_refused(svc: dict[str, Any]) -> None:
    """A 5,000-digit integer (ValueError in json.loads) and a theta of 10**400
    (OverflowError in State.from_dict) both got a 500."""
    c, auth, e = svc["client"], svc["auth"]["ana"], _entry()
    ann = json.dumps({k: v for k, v in e.items() if k not in ("file", "mentor")})
    detail = _refused(_post_take(c, auth, e, ann.replace('"theta": 0.0', '"theta": ' + "9" * 5000,
                                                         1)), 400)
    assert "digits" in detail
    detail = _refused(_post_take(c, auth, e, ann.replace('"theta": 0.0', '"theta": 1' + "0" * 400,
                                                         1)), 400, 422)
    assert "theta" in detail or "too large" in detail
    assert c.get("/clusters").json()["arcs"] == []


def test_state_from_dict_refuses_a_theta_beyond_floats() -> None:
    from nonprehensile.states import State

    with pytest.raises(InputError, match="theta"):
        State.from_dict({"face": "a", "theta": 10**400})


@pytest.mark.parametrize("theta", ["1e300", "-1e7", "1000000.0"])
def test_a_theta_past_a_million_degrees_in_an_annotation_is_a_422(svc: dict[str, Any],
                                                                 theta: str) -> None:
    """1e300 degrees, reduced modulo 360, was read as a:0: the upload was stored (201) as a
    demonstration from a:0 (and 1e6 as a:280); the CLI has refused them since 75f3b14."""
    c, auth, e = svc["client"], svc["auth"]["ana"], _entry()
    ann = json.dumps({k: v for k, v in e.items() if k not in ("file", "mentor")})
    assert '"theta": 0.0' in ann
    detail = _refused(_post_take(c, auth, e, ann.replace('"theta": 0.0', '"theta": ' + theta,
                                                         1)), 422)
    assert "theta" in detail and "360" in detail
    assert c.get("/clusters").json()["arcs"] == []
    from nonprehensile.states import State

    with pytest.raises(InputError, match="within one turn"):
        State.from_dict({"face": "a", "theta": float(theta)})
    assert State.from_dict({"face": "a", "theta": -450}) == State("a", 270)


# ------------------------------------------------------------------------ archive members
def test_a_name_that_is_a_file_and_a_folder_is_a_400(svc: dict[str, Any]) -> None:
    files = _dataset_files()
    files["takes/a"] = b"x"
    files["takes/a/b"] = b"y"
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], _zip(files)), 400)
    assert "'takes/a'" in detail and "folder" in detail


def test_a_300_character_folder_name_is_a_400(svc: dict[str, Any]) -> None:
    files = _dataset_files()
    files["takes/" + "f" * 300 + "/x.txt"] = b"x"
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], _zip(files)), 400)
    assert "characters" in detail


def test_duplicate_member_names_are_a_400(svc: dict[str, Any]) -> None:
    files = _dataset_files()
    data = _zip(files)
    buf = io.BytesIO(data)
    with zipfile.ZipFile(buf, "a") as zf, pytest.warns(UserWarning):
        zf.writestr("takes/annotations.json", b"{}")
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], buf.getvalue()), 400)
    assert "twice" in detail


def test_encrypted_member_is_a_400(svc: dict[str, Any]) -> None:
    data = _patch_member(_zip(_dataset_files()), "takes/skills.json", flags=0x1)
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], data), 400)
    assert "encrypted" in detail and "takes/skills.json" in detail


def test_unsupported_compression_method_is_a_400(svc: dict[str, Any]) -> None:
    data = _patch_member(_zip(_dataset_files()), "takes/skills.json", method=99)
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], data), 400)
    assert "compression method 99" in detail


@pytest.mark.parametrize("method", [zipfile.ZIP_DEFLATED, zipfile.ZIP_LZMA, zipfile.ZIP_BZIP2])
def test_corrupt_compressed_member_is_a_400(svc: dict[str, Any], method: int) -> None:
    def damage(b: bytearray, start: int, size: int) -> None:
        # deflate: block type 3 (reserved); LZMA: past its 9-byte properties; bzip2: the magic
        skip = 9 if method == zipfile.ZIP_LZMA else 0
        b[start + skip : start + skip + 16] = b"\xff" * 16

    data = _patch_member(_zip(_dataset_files(), method), "takes/skills.json", payload=damage)
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], data), 400)
    assert "takes/skills.json" in detail and "cannot be read" in detail


def test_a_truncated_tar_gz_is_a_400(svc: dict[str, Any]) -> None:
    data = _targz(_dataset_files())
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], data[: len(data) // 2],
                                    "a.tar.gz"), 400)
    assert "archive" in detail


def _targz(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        for name, data in files.items():
            ti = tarfile.TarInfo(name)
            ti.size = len(data)
            tf.addfile(ti, io.BytesIO(data))
    return buf.getvalue()


@pytest.mark.parametrize("kind", ["tar.gz", "zip"])
def test_archive_of_many_empty_members_is_refused_before_they_are_loaded(kind: str,
                                                                         tmp_path: Path) -> None:
    """A tar.gz of 5,000,000 empty headers drove the server to 2 GB: every member was loaded
    before the count was checked. 200,000 here: refused after the first 5,001, in a few MB."""
    n = 200_000
    data = gzip.compress(_empty_tar(n), compresslevel=1) if kind == "tar.gz" else _empty_zip(n)
    tracemalloc.start()
    try:
        with pytest.raises(InputError) as err:
            extract_archive(data, tmp_path, 10**9)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert getattr(err.value, "status", None) == 413
    assert f"more than {MAX_ARCHIVE_FILES}" in str(err.value)
    assert peak < 30 * 2**20, f"{peak / 2**20:.0f} MB to refuse it"
    assert not any(tmp_path.iterdir())  # nothing was unpacked (and no time spent on it)


def _empty_tar(n: int) -> bytes:
    """A tar of ``n`` empty files e0000000, e0000001, ... (headers made as arrays: tarfile
    takes seconds)."""
    import numpy as np

    blocks = np.frombuffer(tarfile.TarInfo("e0000000").tobuf(), np.uint8)
    blocks = np.tile(blocks, (n, 1))
    digits = np.arange(n)[:, None] // 10 ** np.arange(6, -1, -1) % 10
    blocks[:, 1:8] = ord("0") + digits
    blocks[:, 148:156] = ord(" ")
    chksum = blocks.sum(axis=1, dtype=np.int64)
    octal = chksum[:, None] // 8 ** np.arange(5, -1, -1) % 8
    blocks[:, 148:154] = ord("0") + octal
    blocks[:, 154] = 0
    return blocks.tobytes() + b"\0" * 1024


def _empty_zip(n: int) -> bytes:
    """A zip of ``n`` empty stored members (written directly: zipfile takes seconds)."""
    local, central = [], []
    offset = 0
    for i in range(n):
        name = b"e%07d" % i
        local.append(struct.pack("<4s5H3L2H", b"PK\x03\x04", 20, 0, 0, 0, 0, 0, 0, 0,
                                 len(name), 0) + name)
        central.append(struct.pack("<4s6H3L5H2L", b"PK\x01\x02", 20, 20, 0, 0, 0, 0, 0, 0,
                                   0, len(name), 0, 0, 0, 0, 0, offset) + name)
        offset += 30 + len(name)
    cd = b"".join(central)
    # the end record claims one entry: only a walk of the directory tells how many there are
    end = struct.pack("<4s4H2LH", b"PK\x05\x06", 0, 0, 1, 1, len(cd), offset, 0)
    return b"".join(local) + cd + end


# ------------------------------------------------------------------------ annotation YAML
@pytest.mark.parametrize("value", ["2019-12-31", "!!binary aGVsbG8=", "!!set {a, b}"])
def test_yaml_values_json_has_not_are_a_422(svc: dict[str, Any], value: str) -> None:
    import yaml

    files = _dataset_files()
    doc = json.loads(files.pop("takes/annotations.json"))
    text = yaml.safe_dump(doc, sort_keys=False) + f"recorded: {value}\n"
    files["takes/annotations.yaml"] = text.encode()
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], _zip(files)), 422)
    assert "recorded" in detail or "JSON" in detail


# ------------------------------------------------------------------------ the body limit
def test_chunked_body_over_the_limit_is_a_413(svc: dict[str, Any]) -> None:
    e = _entry()
    boundary = "bnd0123456789"
    head = (f'--{boundary}\r\nContent-Disposition: form-data; name="annotation"\r\n\r\n{{}}\r\n'
            f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="{e["file"]}"'
            "\r\nContent-Type: application/octet-stream\r\n\r\n").encode()

    def body() -> Iterator[bytes]:  # no Content-Length: sent chunked
        yield head
        for _ in range(MAX_BYTES // 65536 + 2):
            yield b"\0" * 65536
        yield f"\r\n--{boundary}--\r\n".encode()

    r = svc["client"].post("/demonstrations", content=body(), headers={
        **svc["auth"]["ana"], "Content-Type": f"multipart/form-data; boundary={boundary}"})
    assert "content-length" not in {k.lower() for k in r.request.headers}
    detail = _refused(r, 413)
    assert str(MAX_BYTES) in detail


# ------------------------------------------------------------------------ server paths
def test_no_reply_names_a_server_path(svc: dict[str, Any]) -> None:
    """A malformed annotations file in an archive got a 422 naming the server's temporary
    folder."""
    c, auth = svc["client"], svc["auth"]["ben"]
    files = _dataset_files()
    files["takes/annotations.json"] = b'{"format": '
    _refused(_post_archive(c, auth, _zip(files)), 422)
    files["takes/annotations.json"] = b'{"skills": "skills.json", "demonstrations": [{}]}'
    _refused(_post_archive(c, auth, _zip(files)), 422)
    _refused(_post_take(c, svc["auth"]["ana"], {**_entry(), "file": _entry()["file"]},
                        '{"skill": "nope"}'), 422)
    r = c.post("/demonstrations", files={"file": ("t.c3d", b"C3D garbage" * 50, "x/y")},
               data={"annotation": json.dumps({"skill": "push-roll"})},
               headers=svc["auth"]["ana"])
    _refused(r, 422)


# ------------------------------------------------------------------------ archive keys
def test_unknown_archive_keys_are_refused_like_dataset_show(svc: dict[str, Any],
                                                            tmp_path: Path) -> None:
    files = _dataset_files(zz_note="hello")
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], _zip(files)), 422)
    # the line `dataset show` prints for the same folder
    for name, data in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(data)
    cli = CliRunner().invoke(main, ["dataset", "show", str(tmp_path / "takes")])
    assert cli.exit_code == 2
    line = re.search(r"unknown key\(s\) \['zz_note'\]; the annotations have \[[^\]]*\]",
                     " ".join(cli.output.split()))
    assert line is not None, cli.output
    assert line.group(0) in detail
    # a known setting unlike the service's is refused, not dropped: the takes would be read
    # in other units than the mentor's
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"],
                                    _zip(_dataset_files(units="cm"))), 422)
    assert "'units'" in detail
    assert svc["client"].get("/clusters").json()["arcs"] == []
    # the service's own settings written out in full are fine
    r = _post_archive(svc["client"], svc["auth"]["ben"],
                      _zip(_dataset_files(tolerance_mm=10.0, object_markers={})))
    assert r.status_code == 201, r.text


# ------------------------------------------------------------------------ withdrawn takes
@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_a_withdrawn_take_uploaded_again_is_stored_again(backend: str, tmp_path: Path,
                                                         template: Any,
                                                         request: pytest.FixtureRequest) -> None:
    store = (request.getfixturevalue("pg_url") if backend == "postgresql"
             else str(tmp_path / "service.db"))
    for s in _client(store, template):
        c, auth = s["client"], s["auth"]
        e = _entry("roll-arc", "ana")
        first = _post_take(c, auth["ana"], e)
        assert first.status_code == 201, first.text
        up = first.json()["upload"]
        assert c.delete(f"/uploads/{up}", headers=auth["ana"]).json()["withdrawn"]
        assert c.get("/mentors/ana").json()["uploads"] == 0
        again = _post_take(c, auth["ana"], e)
        assert again.status_code == 201, again.text
        doc = again.json()
        assert doc["upload"] == up and not doc["withdrawn"] and not doc["duplicate"]
        assert doc["reinstated"]
        assert not c.get(f"/uploads/{up}").json()["withdrawn"]
        stats = c.get("/mentors/ana").json()
        assert stats["uploads"] == 1 and stats["withdrawn"] == 0
        assert stats["segments"] == len(first.json()["segments"])
        assert sum(a["samples"] for a in c.get("/clusters").json()["arcs"]) == stats["segments"]
        # and once more: now a plain duplicate
        third = _post_take(c, auth["ana"], e)
        assert third.status_code == 200 and third.json()["duplicate"]


# ------------------------------------------------------------------------ one take, one upload
def _theta(entry: dict[str, Any], theta: Any, *, final: bool = False) -> str:
    ann = {k: v for k, v in entry.items() if k not in ("file", "mentor")}
    key = "final" if final else "initial"
    ann[key] = {**ann[key], "theta": theta}
    return json.dumps(ann)


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_the_same_take_with_theta_written_otherwise_is_one_upload(
        backend: str, tmp_path: Path, template: Any, request: pytest.FixtureRequest) -> None:
    """A state's theta is an angle: 0, 360, -0.0, 0.0 and 720 are one state (``State``
    normalises them), so the same take annotated with any of them is one upload; a state
    left out is the skill's, the same again."""
    store = (request.getfixturevalue("pg_url") if backend == "postgresql"
             else str(tmp_path / "service.db"))
    for s in _client(store, template):
        c, auth = s["client"], s["auth"]
        e = _entry("push-roll", "ana")
        assert e["initial"]["theta"] == 0.0 and e["final"]["theta"] == 0.0
        first = _post_take(c, auth["ana"], e, _theta(e, 0))
        assert first.status_code == 201, first.text
        up = first.json()["upload"]
        bare = {k: v for k, v in e.items() if k not in ("file", "mentor", "initial")}
        for ann in (_theta(e, 360), "-0.0".join(_theta(e, 12345).split("12345")),
                    _theta(e, 0.0), _theta(e, 720, final=True), _theta(e, -360.0),
                    json.dumps(bare)):
            r = _post_take(c, auth["ana"], e, ann)
            assert r.status_code == 200, (ann, r.text)
            assert r.json()["duplicate"] and r.json()["upload"] == up
        # another state is another upload (refused here: not the skill's)
        assert _post_take(c, auth["ana"], e, _theta(e, 90)).status_code == 422
        assert c.get("/mentors/ana").json()["uploads"] == 1
        assert sum(a["samples"] for a in c.get("/clusters").json()["arcs"]) == len(
            first.json()["segments"])
        # an archive holding the take twice (two files), as 0 and as 360, holds it twice
        twice = [{**e, "file": "a.c3d"}, {**e, "file": "b.c3d",
                                          "initial": {"face": "a", "theta": 360}}]
        files = {f"t/{n}": (CUBE / e["file"]).read_bytes() for n in ("a.c3d", "b.c3d")}
        files |= {"t/skills.json": (CUBE / ANN["skills"]).read_bytes(),
                 "t/annotations.json": json.dumps({**TOP, "demonstrations": twice}).encode()}
        assert "the same demonstration twice" in _refused(
            _post_archive(c, auth["ana"], _zip(files)), 422)


def test_uploads_stored_under_their_annotations_text_are_found(tmp_path: Path,
                                                               template: Any) -> None:
    """Versions before canonical annotations stored an upload under the hash of its
    annotation's text: the same text sent again is a duplicate of that upload (its stored
    hash is neither rewritten nor stored twice)."""
    from nonprehensile.service.ingest import UploadKey, content_hash, single_upload

    for s in _client(str(tmp_path / "service.db"), template):
        c, auth = s["client"], s["auth"]
        e = _entry("roll-pull", "ana")
        text = _theta(e, 360)
        data = (CUBE / e["file"]).read_bytes()
        old = content_hash("ana", json.loads(text), data)
        registry = c.app.state.registry
        with single_upload(template, "ana", e["file"], data, json.loads(text)) as (ds, keys):
            assert keys[0].given == old and keys[0].digest != old
            # as the previous version registered it: under the text's hash
            registry.register("ana", ds, [UploadKey(old, old)], "recording")
        r = _post_take(c, auth["ana"], e, text)
        assert r.status_code == 200 and r.json()["duplicate"] and r.json()["upload"] == old
        # an annotation already canonical (the bundled ones) hashes as it always did
        plain = {k: v for k, v in e.items() if k not in ("file", "mentor")}
        with single_upload(template, "ana", e["file"], data, plain) as (ds, keys):
            assert keys[0].digest == keys[0].given == content_hash("ana", plain, data)
        assert c.get("/mentors/ana").json()["uploads"] == 1


@pytest.mark.parametrize("mode", ["w:gz", "w:bz2", "w:xz", "w"])
def test_tar_archives_of_a_folder_are_read(svc: dict[str, Any], tmp_path: Path,
                                           mode: str) -> None:
    """The streaming reader takes what `tar -czf a.tgz -C folder .` makes (a `./` member)."""
    folder = tmp_path / "takes"
    for name, data in _dataset_files(n=1, prefix="").items():
        folder.mkdir(exist_ok=True)
        (folder / name).write_bytes(data)
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode=mode) as tf:
        tf.add(folder, arcname=".")
    r = _post_archive(svc["client"], svc["auth"]["ben"], buf.getvalue(), "a.tar")
    assert r.status_code == 201, r.text
    assert r.json()["stored"] == 1


def test_an_annotated_file_name_too_long_for_the_file_system(svc: dict[str, Any],
                                                             tmp_path: Path) -> None:
    """Found by the HTTP fuzz: a 'file' of 2,000 characters made the check's look for a
    rosbag2 folder raise ENAMETOOLONG (a 500; `dataset show` exit 1)."""
    files = _dataset_files(n=1)
    doc = json.loads(files["takes/annotations.json"])
    doc["demonstrations"][0]["file"] = "t" * 2000 + ".c3d"
    files["takes/annotations.json"] = json.dumps(doc).encode()
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], _zip(files)), 422)
    assert "cannot look for the trajectory file" in detail
    for name, data in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(data)
    cli = CliRunner().invoke(main, ["dataset", "show", str(tmp_path / "takes")])
    assert cli.exit_code == 2 and "cannot look for the trajectory file" in cli.output


def test_a_full_disk_while_checking_an_upload_is_one_line(svc: dict[str, Any],
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The server's own file-system errors: 507 for a full disk, never a 500."""
    import errno

    def full(self: Path, data: bytes) -> int:
        raise OSError(errno.ENOSPC, "No space left on device", str(self))

    monkeypatch.setattr(Path, "write_bytes", full)
    detail = _refused(_post_take(svc["client"], svc["auth"]["ana"], _entry()), 507)
    assert "disk is full" in detail
    real_open = Path.open

    def full_open(self: Path, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        if mode.startswith(("w", "x")):
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return real_open(self, mode, *args, **kwargs)

    monkeypatch.setattr(Path, "open", full_open)
    detail = _refused(_post_archive(svc["client"], svc["auth"]["ben"], _zip(_dataset_files())),
                      507)
    assert "disk is full" in detail


def test_a_marker_label_that_is_not_utf8_is_a_4xx_not_a_500(svc: dict[str, Any]) -> None:
    """A C3D whose marker label holds a byte that is not UTF-8 (read as a lone surrogate):
    the refusal quoting it could not be encoded as JSON, and the reply was a 500."""
    c, auth = svc["client"], svc["auth"]["ana"]
    entry = _entry()
    data = (CUBE / entry["file"]).read_bytes()
    at = data.index(b"index_knuckle")
    bad = data[:at] + b"\x9b" + data[at + 1:]
    ann = json.dumps({k: v for k, v in entry.items() if k not in ("file", "mentor")})
    r = c.post("/demonstrations",
               files={"file": (entry["file"], bad, "application/octet-stream")},
               data={"annotation": ann}, headers=auth)
    detail = _refused(r, 400, 422)
    assert "index_knuckle" in detail and "\\udc9bndex_knuckle" in detail, detail
