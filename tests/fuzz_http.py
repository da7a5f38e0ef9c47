"""The HTTP family of the fuzz campaign (issue 25): ``nonprehensile serve`` on 127.0.0.1, over
a SQLite file and over PostgreSQL.

Each store gets its own real server (a subprocess, as a user runs it) and the same sequence of
generated requests: takes with mutated annotations (the hostile tokens of
``fuzz_harness.mutate_text``: 5000-digit integers, 1e308, NaN, deep nesting, NUL and surrogate
escapes, other mentors) and mutated or foreign recordings (the real C3D and Motive files of
``../shared/realdata``); dataset archives (zip, tar, tar.gz/bz2/xz) damaged byte-wise, with
hostile member names (``..``, absolute, ``\\``, 300 characters, ``a`` and ``a/b``, twice, NUL),
links, encrypted members, unknown compression methods, mutated JSON or YAML annotations (dates,
``!!binary``, ``!!set``), unknown keys and settings unlike the service's; bad tokens (none,
malformed, unknown, revoked, revoked while the body streams); bodies over the limit (by
Content-Length and chunked), malformed multipart bodies, uploads cut off mid-body; listings,
withdrawals (one's own and another's) and re-uploads; concurrent identical uploads; and
SIGKILLs of the server while uploads are in flight, each followed by a restart and retries.

A request **fails** on: a 5xx; no answer within 60 s; a 4xx whose ``detail`` is not one line;
a reply naming a folder of the server; a traceback in the server's log; the server dying
without being killed, or its peak memory over 2 GiB; a status other than the one required (401
for a bad token, 403 for another mentor's data, 413 over the limit, 2xx for a valid take, 4xx
for an input known to be invalid); **a wrong success**: a 2xx for a take or archive that
``check_dataset`` (what ``dataset show`` runs), on the same folder, rejects. At the end, every
upload acknowledged with a 2xx (through every kill) must be stored, whole (all its segments,
its reply), withdrawn exactly when it was last withdrawn; no sample belongs to no upload.

    python tests/fuzz_http.py --budget 3200          # both stores, half the requests each
    python tests/fuzz_http.py --store sqlite --budget 200 --kills 2

The case numbered ``i`` is generated from ``(seed, i)`` alone; the server's state depends on
the cases before it, so a failure is replayed by running the campaign up to it.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import random
import re
import signal
import socket
import struct
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
import warnings
import zipfile
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from fuzz_harness import HOSTILE_STRINGS, REALDATA, mutate_bytes, mutate_text  # noqa: E402

#: A request answered later than this is a failure (seconds).
TIME_LIMIT = 60.0
#: Peak resident memory allowed to the server (bytes).
MEMORY_LIMIT = 2 * 2**30
#: The server's ``--max-bytes``: the cube's takes are 40-100 kB, archives of a few a MB.
MAX_BYTES = 2 * 2**20
MENTORS = ("ana", "ben", "chen", "dana")
#: SIGKILLs of the server per store (spread over its requests).
DEFAULT_KILLS = 6


# ------------------------------------------------------------------------------ the server
class Server:
    """``nonprehensile serve`` on a free port of 127.0.0.1, its log in a file."""

    def __init__(self, store: str, work: Path) -> None:
        self.store = store
        self.work = work
        self.proc: subprocess.Popen[bytes] | None = None
        self.log = work / "server.log"
        self.log_seen = 0
        self.peak_mb = 0.0
        self.starts = 0
        self.port = 0

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> None:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = int(s.getsockname()[1])
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
        with self.log.open("ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "nonprehensile.cli", "serve", "--store", self.store,
                 "--host", "127.0.0.1", "--port", str(self.port), "--max-bytes",
                 str(MAX_BYTES), "--recalibrate-every", "3", "--workers", "4"],
                stdout=log, stderr=log, env=env, start_new_session=True)
        self.starts += 1
        import httpx

        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 120:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the server exited {self.proc.returncode} at start: "
                                   + self.log.read_text(errors="replace")[-500:])
            with contextlib.suppress(httpx.TransportError):
                if httpx.get(f"{self.url}/health", timeout=5).status_code == 200:
                    return
            time.sleep(0.1)
        raise RuntimeError("the server did not come up in 120 s")

    def kill(self) -> None:
        """SIGKILL: no shutdown of any kind (its C3D worker, in its process group, too)."""
        assert self.proc is not None
        self.sample_memory()
        self.proc.kill()
        self.proc.wait()
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)

    def stop(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        self.sample_memory()
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def sample_memory(self) -> float:
        if self.alive():
            assert self.proc is not None
            with contextlib.suppress(OSError):
                for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
                    if line.startswith("VmHWM:"):
                        self.peak_mb = max(self.peak_mb, int(line.split()[1]) / 1024)
        return self.peak_mb

    def new_log(self) -> str:
        """What the server logged since the last call."""
        with self.log.open("rb") as f:
            f.seek(self.log_seen)
            data = f.read()
        self.log_seen += len(data)
        return data.decode("utf-8", "replace")


# ------------------------------------------------------------------------------ the data
@dataclass
class Take:
    file: str
    data: bytes
    entry: dict[str, Any]  # the annotation entry, without file and mentor


class Data:
    """The bundled cube dataset's takes and the service's settings (the oracle's too)."""

    def __init__(self) -> None:
        from nonprehensile.demonstrations.dataset import dataset_path
        from nonprehensile.service import load_template

        cube = dataset_path("cube")
        ann = json.loads((cube / "annotations.json").read_text())
        self.top = {k: v for k, v in ann.items() if k != "demonstrations"}
        self.skills = (cube / ann["skills"]).read_bytes()
        self.takes = [Take(d["file"], (cube / d["file"]).read_bytes(),
                           {k: v for k, v in d.items() if k not in ("file", "mentor")})
                      for d in ann["demonstrations"]]
        self.template = load_template("cube")
        real = REALDATA if REALDATA.is_dir() else None
        self.real = ([p for p in sorted(real.glob("c3d/*.c3d")) if p.stat().st_size < 1 << 20]
                     + sorted(real.glob("motive/*.csv")) if real else [])

    def check(self, folder: Path) -> bool:
        """The oracle: would ``dataset show`` accept this folder?"""
        from nonprehensile.demonstrations.dataset import check_dataset

        try:
            ds, _ = check_dataset(folder, known_skills=self.template.known)
        except Exception:
            return False
        return ds is not None


def multipart(fields: list[tuple[str, str | None, bytes]]) -> tuple[str, bytes]:
    """A multipart/form-data body: (content type, bytes)."""
    boundary = f"np{random.getrandbits(64):016x}"
    out = io.BytesIO()
    for name, filename, data in fields:
        out.write(f"--{boundary}\r\n".encode())
        disp = f'form-data; name="{name}"'
        if filename is not None:
            disp += f'; filename="{filename}"'
        out.write(f"Content-Disposition: {disp}\r\n".encode("utf-8", "surrogatepass"))
        if filename is not None:
            out.write(b"Content-Type: application/octet-stream\r\n")
        out.write(b"\r\n" + data + b"\r\n")
    out.write(f"--{boundary}--\r\n".encode())
    return f"multipart/form-data; boundary={boundary}", out.getvalue()


def raw_request(port: int, head: bytes, parts: list[bytes], *, pause: float = 0.0,
                between: Callable[[], None] | None = None, close_early: bool = False,
                timeout: float = TIME_LIMIT) -> tuple[int | None, bytes]:
    """Send a request by hand (head, then the body in ``parts``); its status and reply
    (None: the connection closed before one, as ``close_early`` wants)."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(head)
        for i, p in enumerate(parts):
            if i and pause:
                time.sleep(pause)
            if i and between is not None and i == len(parts) // 2:
                between()
            try:
                s.sendall(p)
            except OSError:  # the server answered (413) and closed: read what it said
                break
        if close_early:
            s.shutdown(socket.SHUT_RDWR)
            return None, b""
        chunks = []
        with contextlib.suppress(OSError):
            while True:
                c = s.recv(65536)
                if not c:
                    break
                chunks.append(c)
                if b"\r\n\r\n" in b"".join(chunks) and _complete(b"".join(chunks)):
                    break
    reply = b"".join(chunks)
    m = re.match(rb"HTTP/1\.[01] (\d{3})", reply)
    return (int(m.group(1)) if m else None), reply


def _complete(reply: bytes) -> bool:
    head, _, body = reply.partition(b"\r\n\r\n")
    m = re.search(rb"(?i)content-length: *(\d+)", head)
    return m is not None and len(body) >= int(m.group(1))


# ------------------------------------------------------------------------------ archives
def _zip_bytes(files: list[tuple[str, bytes]], method: int = zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name, data in files:
            # names zip cannot hold (writestr("") is an IndexError)
            with contextlib.suppress(ValueError, UnicodeError, IndexError):
                zf.writestr(name, data)
    return buf.getvalue()


def _member_names(data: bytes) -> list[str]:
    """The member names an archive really holds (as the standard library reads them)."""
    try:
        if zipfile.is_zipfile(io.BytesIO(data)):
            return zipfile.ZipFile(io.BytesIO(data)).namelist()
        with tarfile.open(fileobj=io.BytesIO(data)) as tf:
            return tf.getnames()
    except Exception:
        return []


def _tar_bytes(files: list[tuple[str, bytes]], mode: str,
               links: list[tuple[str, str]] | None = None, pax: bool = False) -> bytes:
    """A tar (``pax``: its first member carrying a PAX record of 25 times the server's
    limit, which a reader holds whole in memory)."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode=mode, format=tarfile.PAX_FORMAT) as tf:  # type: ignore[call-overload]
        for k, (name, data) in enumerate(files):
            ti = tarfile.TarInfo(name)
            ti.size = len(data)
            if pax and k == 0:
                ti.pax_headers = {"comment": "x" * (25 * MAX_BYTES)}
            with contextlib.suppress(ValueError, UnicodeError):  # names tar cannot hold
                tf.addfile(ti, io.BytesIO(data))
        for name, target in links or []:
            ti = tarfile.TarInfo(name)
            ti.type = tarfile.SYMTYPE
            ti.linkname = target
            tf.addfile(ti)
    return buf.getvalue()


def _zip_patch(data: bytes, *, flags: int | None = None, method: int | None = None) -> bytes:
    """Set the flags or method of every member of a zip (local and central headers)."""
    b = bytearray(data)
    for sig, off in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        i = b.find(sig)
        while i >= 0:
            if flags is not None:
                struct.pack_into("<H", b, i + off, flags)
            if method is not None:
                struct.pack_into("<H", b, i + off + 2, method)
            i = b.find(sig, i + 4)
    return bytes(b)


HOSTILE_MEMBERS = ["../escape.txt", "/etc/passwd", "takes/../../x", "a\\b.txt", "x" * 300,
                   "d/" + "f" * 256 + "/x", "n\x00ul.txt", "/".join(["d"] * 40) + "/x",
                   "ctl\x07.txt", "", "./../x"]


# ------------------------------------------------------------------------------ the campaign
@dataclass
class Result:
    kind: str
    status: int | None
    failure: str | None = None
    note: str = ""
    seconds: float = 0.0


@dataclass
class StoreRun:
    """One store's campaign: its server, tokens, what was acknowledged."""

    name: str
    store: str
    server: Server
    data: Data
    tokens: dict[str, str]
    work: Path
    rng_seed: int
    acked: dict[str, dict[str, Any]] = field(default_factory=dict)
    requests: int = 0
    kinds: Counter[str] = field(default_factory=Counter)
    kind_seconds: Counter[str] = field(default_factory=Counter)
    statuses: Counter[str] = field(default_factory=Counter)
    failures: list[dict[str, Any]] = field(default_factory=list)
    kills: int = 0
    kill_acked: int = 0
    disagreements: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    #: one client for the run: a client per request costs more than most requests
    http: Any = None

    def __post_init__(self) -> None:
        import httpx

        self.http = httpx.Client(timeout=TIME_LIMIT,
                                 limits=httpx.Limits(max_connections=16))

    # -------------------------------------------------------------- judging one reply
    def judge(self, kind: str, r: Any, *, want: set[int] | None = None,
              note: str = "", seconds: float = 0.0) -> int | None:
        """Count and judge one reply (an ``httpx.Response``, or a status, or None)."""
        status = r if isinstance(r, int) or r is None else r.status_code
        with self.lock:
            self.requests += 1
            self.kinds[kind] += 1
            self.statuses[f"{kind}:{status}"] += 1
        failure = None
        if status is None:
            failure = "no answer"
        elif status >= 500:
            failure = f"server error {status}"
        elif seconds > TIME_LIMIT:
            failure = f"answered after {seconds:.0f} s"
        elif want is not None and status not in want:
            failure = f"status {status}, expected {sorted(want)}"
        if failure is None and not isinstance(r, int) and r is not None and status >= 400:
            try:
                detail = r.json().get("detail")
            except ValueError:
                detail = None
            if not isinstance(detail, str) or not detail or "\n" in detail:
                failure = f"a {status} without one line of detail"
            elif _server_path(r.text, self):
                failure = "the reply names a folder of the server"
        if failure is None and not isinstance(r, int) and r is not None and status < 400 \
                and _server_path(r.text, self):
            failure = "the reply names a folder of the server"
        if failure:
            self.fail(kind, failure, note, r)
        return status

    def fail(self, kind: str, failure: str, note: str = "", r: Any = None) -> None:
        text = "" if r is None or isinstance(r, int) else r.text[:300]
        with self.lock:
            self.failures.append({"family": f"http:{self.name}", "kind": kind,
                                  "failure": failure, "note": note[:300], "reply": text,
                                  "request": self.requests})

    def count(self, kind: str) -> None:
        """Count a request that has no reply to judge (cut off by the client or a kill)."""
        with self.lock:
            self.requests += 1
            self.kinds[kind] += 1

    def check_log(self) -> None:
        log = self.server.new_log()
        if "Traceback" in log:
            self.fail("log", "a traceback in the server's log",
                      log[log.index("Traceback"):][:600])

    def ack(self, reply: dict[str, Any]) -> None:
        with self.lock:
            self.acked[reply["upload"]] = {"segments": len(reply["segments"]),
                                           "withdrawn": bool(reply.get("withdrawn")),
                                           "mentor": reply["mentor"]}

    def auth(self, mentor: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.tokens[mentor]}"}


def _server_path(text: str, run: StoreRun) -> bool:
    return (tempfile.gettempdir() + "/np-" in text or str(run.work) in text
            or str(ROOT / "src") in text)


def _post(run: StoreRun, path: str, **kw: Any) -> tuple[Any, float]:
    import httpx

    t0 = time.perf_counter()
    try:
        r = run.http.post(run.server.url + path, timeout=TIME_LIMIT, **kw)
    except httpx.TimeoutException:
        return None, time.perf_counter() - t0
    except httpx.TransportError as exc:
        return f"transport error: {exc}", time.perf_counter() - t0
    return r, time.perf_counter() - t0


def _take_folder(run: StoreRun, folder: Path, mentor: str, name: str, data: bytes,
                 entry: Any) -> Path:
    """The folder the service checks for a single upload, built by the harness."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_bytes(data)
    doc = {**run.data.template.top,
           "demonstrations": [{**entry, "file": name, "mentor": mentor}]}
    (folder / "annotations.json").write_text(json.dumps(doc))
    return folder


def case_take(run: StoreRun, rng: random.Random, i: int, variant: str) -> None:
    take = rng.choice(run.data.takes)
    mentor = rng.choice(MENTORS)
    data, name, note = take.data, take.file, variant
    entry: Any = dict(take.entry)
    text = json.dumps(entry)
    want: set[int] | None = None
    if variant == "annotation":
        text, how = mutate_text(json.dumps(entry, indent=rng.choice([None, 1])), rng)
        note = f"annotation {how}"
        if rng.random() < 0.15:
            entry = {**take.entry, "mentor": rng.choice([m for m in MENTORS if m != mentor])}
            text, want, note = json.dumps(entry), {403}, "another mentor's name"
    elif variant == "recording":
        if run.data.real and rng.random() < 0.3:
            src = rng.choice(run.data.real)
            data, name = src.read_bytes(), "real" + src.suffix.lower()
            note = f"real file {src.name}"
            if rng.random() < 0.5:
                data, how = mutate_bytes(data, rng)
                note += f" {how}"
        else:
            data, how = mutate_bytes(take.data, rng)
            note = f"recording {how}"
    elif variant == "valid":
        want = {200, 201}
    elif variant == "name":
        name = rng.choice([*HOSTILE_STRINGS, "t.C3D", "t.txt", ".c3d", "a/b/../t.c3d",
                           "t" * 250 + ".c3d", "t\u202e.c3d"])
        note = f"file name {name[:40]!r}"
    try:
        payload = text.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:
        payload = text.encode("utf-8", "surrogatepass")
    ctype, body = multipart([("annotation", None, payload), ("file", name, data)])
    r, sec = _post(run, "/demonstrations", content=body,
                   headers={**run.auth(mentor), "Content-Type": ctype})
    if isinstance(r, str):
        run.judge(variant, None, note=f"{note}: {r}", seconds=sec)
        return
    status = run.judge(variant, r, want=want, note=note, seconds=sec)
    if status in (200, 201):
        reply = r.json()
        run.ack(reply)
        if variant != "valid":
            # a wrong success? the harness's own check of the same folder must accept it
            try:
                parsed = json.loads(text)
            except ValueError:
                run.fail(variant, "a success for an annotation that is not JSON", note, r)
                return
            with tempfile.TemporaryDirectory(dir=run.work) as tmp:
                ok = isinstance(parsed, dict) and run.data.check(
                    _take_folder(run, Path(tmp), mentor, Path(name).name, data, parsed))
            if not ok:
                run.fail(variant, "wrong success: dataset show rejects what was stored", note,
                         r)
    elif status == 422 and variant != "name":
        with tempfile.TemporaryDirectory(dir=run.work) as tmp:
            try:
                parsed = json.loads(text)
            except ValueError:
                parsed = None
            if isinstance(parsed, dict) and run.data.check(
                    _take_folder(run, Path(tmp), mentor, Path(name).name, data, parsed)):
                run.disagreements += 1  # segmentation refused what the check accepts


def _archive_files(run: StoreRun, rng: random.Random, mentor: str) -> tuple[
        list[tuple[str, bytes]], dict[str, Any]]:
    takes = rng.sample(run.data.takes, rng.choice([1, 1, 2]))
    prefix = rng.choice(["takes/", "", "./", "my dataset/"])
    demos = [{**t.entry, "file": t.file, "mentor": mentor} for t in takes]
    doc = {**run.data.top, "demonstrations": demos}
    files = [(prefix + t.file, t.data) for t in takes]
    files.append((prefix + "skills.json", run.data.skills))
    return files, {"doc": doc, "prefix": prefix}


def case_archive(run: StoreRun, rng: random.Random, i: int) -> None:
    mentor = rng.choice(MENTORS)
    files, meta = _archive_files(run, rng, mentor)
    doc, prefix = meta["doc"], meta["prefix"]
    fmt = rng.choice(["zip", "zip", "tar", "tar:gz", "tar:gz", "tar:bz2", "tar:xz"])
    how = rng.choice(["none", "bytes", "bytes", "annotations", "annotations", "yaml", "member",
                      "clash", "twice", "link", "encrypted", "method", "key", "setting",
                      "mentor", "truncate", "bomb"])
    want: set[int] | None = None
    ann_name, ann = prefix + "annotations.json", json.dumps(doc, indent=1)
    links: list[tuple[str, str]] = []
    hostile = ""
    note = f"{fmt} {how}"
    if how == "none":
        want = {200, 201}
    elif how == "annotations":
        ann, m = mutate_text(ann, rng)
        note += f" {m}"
    elif how == "yaml":
        import yaml

        ann_name = prefix + "annotations.yaml"
        ann = yaml.safe_dump(doc, sort_keys=False)
        extra = rng.choice(["", "recorded: 2019-12-31\n", "blob: !!binary aGVsbG8=\n",
                            "tags: !!set {a, b}\n", "when: 2001-12-14t21:59:43.10-05:00\n"])
        ann += extra
        if extra:
            want = {422}
        else:
            ann, m = mutate_text(ann, rng) if rng.random() < 0.5 else (ann, "unchanged")
            note += f" {m}"
    elif how == "member":
        hostile = rng.choice(HOSTILE_MEMBERS)
        files.append((hostile, b"x"))
        note += f" {hostile[:40]!r}"
    elif how == "clash":
        files += [(prefix + "a", b"x"), (prefix + "a/b", b"y")]
        want = {400}
    elif how == "twice":
        files.append(files[0])
        want = {400}
    elif how == "link":
        if fmt.startswith("tar"):
            links.append((prefix + "ln", rng.choice(["/etc/passwd", "../x", "skills.json"])))
            want = {400}
    elif how == "key":
        doc = {**doc, rng.choice(["zz", "note", "1", "Skills"]): rng.choice([1, "x", [], {}])}
        ann, want = json.dumps(doc), {422}
    elif how == "setting":
        key, value = rng.choice([("scale", 0.5), ("units", "cm"), ("gap_limit", 0),
                                 ("fingers", {"R1": "thumb_tip"}), ("markers", []),
                                 ("tolerance_mm", 1e308), ("axes", "y-up")])
        doc = {**doc, key: value}
        ann, want = json.dumps(doc), {422}
    elif how == "bomb":
        bomb = rng.choice(["many", "big", "pax"] if fmt.startswith("tar") else ["many", "big"])
        note += f" {bomb}"
        if bomb == "many":  # more members than an archive may have
            files += [(f"{prefix}e/{k}", b"") for k in range(5001)]
        elif bomb == "big":  # one member unpacking to 3 times the limit (compresses to kB)
            files.append((prefix + "zeros.bin", bytes(3 * MAX_BYTES)))
            fmt = "tar:gz" if fmt == "tar" else fmt
        want = {413}
    elif how == "mentor":
        other = rng.choice([m for m in MENTORS if m != mentor])
        doc = {**doc, "demonstrations": [{**d, "mentor": other} for d in doc["demonstrations"]]}
        ann, want = json.dumps(doc), {403}
    files.append((ann_name, ann.encode("utf-8", "surrogateescape")))
    rng.shuffle(files)
    if fmt == "zip":
        data = _zip_bytes(files, rng.choice([zipfile.ZIP_DEFLATED, zipfile.ZIP_STORED,
                                             zipfile.ZIP_LZMA, zipfile.ZIP_BZIP2]))
        if how == "encrypted":
            data, want = _zip_patch(data, flags=0x1), {400}
        elif how == "method":
            data, want = _zip_patch(data, method=rng.choice([1, 6, 9, 97, 98, 99])), {400}
    else:
        mode = "w" if fmt == "tar" else "w:" + fmt.split(":")[1]
        pax = how == "bomb" and "pax" in note
        data = _tar_bytes(files, "w:gz" if pax else mode, links, pax=pax)
    if how == "member" and hostile and hostile in _member_names(data):
        want = {400}  # (zip cuts a name at a NUL; tar cannot hold some: then any answer)
    if how == "bytes":
        data, m = mutate_bytes(data, rng)
        note += f" {m}"
    elif how == "truncate":
        data = data[: rng.randrange(len(data))]
    r, sec = _post(run, "/datasets", files={"archive": ("a." + fmt.replace(":", "."), data)},
                   headers=run.auth(mentor))
    if isinstance(r, str):
        run.judge("archive", None, note=f"{note}: {r}", seconds=sec)
        return
    status = run.judge("archive", r, want=want, note=note, seconds=sec)
    if status in (200, 201):
        for reply in r.json()["uploads"]:
            run.ack(reply)
        if how != "none" and not _archive_oracle(run, data, mentor):
            run.fail("archive", "wrong success: dataset show rejects the archive's folder",
                     note, r)


def _archive_oracle(run: StoreRun, data: bytes, mentor: str) -> bool:
    """Unpacked by the standard library, with the service's settings: does the check accept
    the folder, and is every demonstration the mentor's?"""
    from nonprehensile.demonstrations.dataset import _TOP_KEYS, ANNOTATION_FILES
    from nonprehensile.io import load_document

    with tempfile.TemporaryDirectory(dir=run.work) as tmp:
        dest = Path(tmp)
        try:
            if zipfile.is_zipfile(io.BytesIO(data)):
                zipfile.ZipFile(io.BytesIO(data)).extractall(dest)
            else:
                with tarfile.open(fileobj=io.BytesIO(data)) as tf:
                    tf.extractall(dest, filter="data")
        except Exception:
            return False
        roots = [dest, *sorted(p for p in dest.iterdir() if p.is_dir())]
        root = next((c for c in roots for n in ANNOTATION_FILES if (c / n).is_file()), None)
        if root is None:
            return False
        ann = next(root / n for n in ANNOTATION_FILES if (root / n).is_file())
        try:
            doc = load_document(ann)
        except Exception:
            return False
        if not isinstance(doc, dict) or not isinstance(doc.get("demonstrations"), list):
            return False
        if any(isinstance(d, dict) and d.get("mentor") != mentor for d in doc["demonstrations"]):
            return False
        from nonprehensile.service.ingest import _SETTING_DEFAULTS

        top = run.data.template.top
        for k, v in doc.items():
            if k in _TOP_KEYS and k not in ("demonstrations", "skills") \
                    and v != top.get(k, _SETTING_DEFAULTS.get(k)):
                return False
        ann.unlink()
        unknown = {str(k): v for k, v in doc.items() if k not in _TOP_KEYS}
        (root / "annotations.json").write_text(json.dumps(
            {**top, **unknown, "demonstrations": doc["demonstrations"]}))
        return run.data.check(root)


BAD_TOKENS = ["", "Bearer", "Bearer np_", "Bearer np_" + "A" * 43, "bearer {tok}",
              "Basic YWxhZGRpbjpvcGVuc2VzYW1l", "Bearer {tok}x", "Bearer x" + "y" * 10000,
              "Bearer {tok} {tok}", "Token {tok}", "Bearer np_ x", "Bearer np_' OR '1'='1",
              "Bearer %00", "{tok}"]


def case_token(run: StoreRun, rng: random.Random, i: int) -> None:
    take = rng.choice(run.data.takes)
    mentor = rng.choice(MENTORS)
    bad = rng.choice([*BAD_TOKENS, "revoked", "missing"])
    headers: dict[str, str] = {}
    if bad == "revoked":
        headers = {"Authorization": f"Bearer {_revoked_token(run, f'rev{i}')}"}
    elif bad != "missing":
        headers = {"Authorization": bad.replace("{tok}", run.tokens[mentor])}
    target = rng.choice(["demonstrations", "datasets", "delete", "recalibrate"])
    import httpx

    t0 = time.perf_counter()
    try:
        if target == "demonstrations":
            r = run.http.post(run.server.url + "/demonstrations", headers=headers,
                           files={"file": (take.file, take.data)},
                           data={"annotation": json.dumps(take.entry)}, timeout=TIME_LIMIT)
        elif target == "datasets":
            files, meta = _archive_files(run, rng, mentor)
            files.append((meta["prefix"] + "annotations.json", json.dumps(meta["doc"]).encode()))
            r = run.http.post(run.server.url + "/datasets", headers=headers,
                           files={"archive": ("a.zip", _zip_bytes(files))}, timeout=TIME_LIMIT)
        elif target == "delete":
            digest = rng.choice(sorted(run.acked) or ["0" * 64])
            r = run.http.delete(run.server.url + f"/uploads/{digest}", headers=headers,
                             timeout=TIME_LIMIT)
        else:
            r = run.http.post(run.server.url + "/recalibrate", headers=headers, timeout=TIME_LIMIT)
    except httpx.TransportError as exc:
        run.judge("token", None, note=f"{bad[:30]!r} {target}: {exc}")
        return
    run.judge("token", r, want={401}, note=f"{bad[:30]!r} on {target}",
              seconds=time.perf_counter() - t0)


def _new_token(run: StoreRun, mentor: str) -> str:
    """A fresh token for ``mentor``, written to the store through a pool of its own."""
    from nonprehensile.service.db import create_token, make_pool

    pool = make_pool(run.store, max_size=1)
    try:
        with pool.connection() as conn:
            return create_token(conn, mentor)
    finally:
        pool.close()


def _revoked_token(run: StoreRun, mentor: str) -> str:
    from nonprehensile.service.db import create_token, make_pool, revoke_tokens

    pool = make_pool(run.store, max_size=1)
    try:
        with pool.connection() as conn:
            token = create_token(conn, mentor)
            revoke_tokens(conn, mentor)
    finally:
        pool.close()
    return token


def case_revoked_mid_upload(run: StoreRun, rng: random.Random, i: int) -> None:
    """A token revoked while its upload's body streams: 401 (the body is read first)."""
    from nonprehensile.service.db import make_pool, revoke_tokens

    mentor = f"mid{i}"
    token = _new_token(run, mentor)
    take = rng.choice(run.data.takes)
    ctype, body = multipart([("annotation", None, json.dumps(take.entry).encode()),
                             ("file", take.file, take.data)])
    head = (f"POST /demonstrations HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer "
            f"{token}\r\nContent-Type: {ctype}\r\nContent-Length: {len(body)}\r\n"
            "Connection: close\r\n\r\n").encode()
    parts = [body[k : k + 8192] for k in range(0, len(body), 8192)]

    def revoke() -> None:
        p = make_pool(run.store, max_size=1)
        try:
            with p.connection() as conn:
                revoke_tokens(conn, mentor)
        finally:
            p.close()

    t0 = time.perf_counter()
    try:
        status, _ = raw_request(run.server.port, head, parts, pause=0.01, between=revoke)
    except OSError as exc:
        run.judge("revoked-mid-upload", None, note=str(exc))
        return
    run.judge("revoked-mid-upload", status, want={401}, note="token revoked mid-body",
              seconds=time.perf_counter() - t0)


def case_body(run: StoreRun, rng: random.Random, i: int) -> None:
    import httpx

    take = rng.choice(run.data.takes)
    mentor = rng.choice(MENTORS)
    auth = run.auth(mentor)
    kind = rng.choice(["length", "chunked", "no-boundary", "garbage", "json", "empty",
                       "missing-file", "missing-annotation", "missing-archive", "lying-length"])
    url = run.server.url
    t0 = time.perf_counter()
    note = kind
    try:
        if kind == "length":
            ctype, body = multipart([("annotation", None, b"{}"),
                                     ("file", "big.c3d", b"\0" * (MAX_BYTES + 1))])
            r: Any = run.http.post(url + "/demonstrations", content=body,
                                headers={**auth, "Content-Type": ctype}, timeout=TIME_LIMIT)
            want: set[int] | None = {413}
        elif kind == "chunked":
            ctype, body = multipart([("annotation", None, b"{}"),
                                     ("file", "big.c3d", b"\0" * (MAX_BYTES + 1))])

            def gen() -> Iterator[bytes]:
                for k in range(0, len(body), 65536):
                    yield body[k : k + 65536]

            path = rng.choice(["/demonstrations", "/datasets"])
            r = run.http.post(url + path, content=gen(), headers={**auth, "Content-Type": ctype},
                           timeout=TIME_LIMIT)
            want = {413}
        elif kind == "no-boundary":
            r = run.http.post(url + "/demonstrations", content=b"xx",
                           headers={**auth, "Content-Type": "multipart/form-data"},
                           timeout=TIME_LIMIT)
            want = {400}
        elif kind == "garbage":
            data, _ = mutate_bytes(multipart([("annotation", None, json.dumps(
                take.entry).encode()), ("file", take.file, take.data)])[1], rng)
            r = run.http.post(url + "/demonstrations", content=data, headers={
                **auth, "Content-Type": "multipart/form-data; boundary=np0"}, timeout=TIME_LIMIT)
            want = {400}
        elif kind == "json":
            r = run.http.post(url + rng.choice(["/demonstrations", "/datasets"]),
                           json=take.entry, headers=auth, timeout=TIME_LIMIT)
            want = {400}
        elif kind == "empty":
            r = run.http.post(url + "/demonstrations", headers=auth, timeout=TIME_LIMIT)
            want = {400}
        elif kind == "missing-file":
            r = run.http.post(url + "/demonstrations", data={"annotation": "{}"}, headers=auth,
                           timeout=TIME_LIMIT)
            want = {400}
        elif kind == "missing-annotation":
            r = run.http.post(url + "/demonstrations", files={"file": (take.file, take.data)},
                           headers=auth, timeout=TIME_LIMIT)
            want = {400}
        elif kind == "missing-archive":
            r = run.http.post(url + "/datasets", data={"x": "y"}, headers=auth, timeout=TIME_LIMIT)
            want = {400}
        else:  # a Content-Length larger than the body, then the connection closed
            ctype, body = multipart([("annotation", None, json.dumps(take.entry).encode()),
                                     ("file", take.file, take.data)])
            head = (f"POST /demonstrations HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: "
                    f"Bearer {run.tokens[mentor]}\r\nContent-Type: {ctype}\r\nContent-Length: "
                    f"{len(body) + 1000}\r\n\r\n").encode()
            raw_request(run.server.port, head, [body], close_early=True)
            r = run.http.get(url + "/health", timeout=TIME_LIMIT)
            want, note = {200}, "lying Content-Length, closed; then /health"
    except httpx.TimeoutException:
        run.judge("body", None, note=f"{note}: no answer in {TIME_LIMIT} s",
                  seconds=time.perf_counter() - t0)
        return
    except (httpx.TransportError, OSError) as exc:
        run.judge("body", None, note=f"{note}: {exc}")
        return
    run.judge("body", r, want=want, note=note, seconds=time.perf_counter() - t0)


def case_cut(run: StoreRun, rng: random.Random, i: int) -> None:
    """An upload cut off mid-body (the client killed): nothing stored; the server goes on."""
    import httpx

    take = rng.choice(run.data.takes)
    mentor = rng.choice(MENTORS)
    ctype, body = multipart([("annotation", None, json.dumps(take.entry).encode()),
                             ("file", take.file, take.data)])
    head = (f"POST /demonstrations HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer "
            f"{run.tokens[mentor]}\r\nContent-Type: {ctype}\r\nContent-Length: {len(body)}"
            "\r\n\r\n").encode()
    cut = rng.randrange(len(body))
    with contextlib.suppress(OSError):
        raw_request(run.server.port, head, [body[:cut]], close_early=True)
    run.count("cut")  # the cut request itself: no reply to judge
    t0 = time.perf_counter()
    try:
        r = run.http.get(run.server.url + "/health", timeout=TIME_LIMIT)
    except httpx.TransportError as exc:
        run.judge("cut", None, note=f"/health after a cut upload: {exc}")
        return
    run.judge("cut", r, want={200}, note="/health after a cut upload",
              seconds=time.perf_counter() - t0)


def case_read(run: StoreRun, rng: random.Random, i: int) -> None:
    import httpx

    url = run.server.url
    digest = rng.choice(sorted(run.acked)) if run.acked and rng.random() < 0.7 else \
        rng.choice(["0" * 64, "x", "%2e%2e", "a" * 5000, "..", "null"])
    kind = rng.choice(["upload", "clusters", "mentors", "mentor", "health", "openapi",
                       "unknown-path", "put", "delete-other", "delete-unknown"])
    t0 = time.perf_counter()
    want: set[int] | None = None
    try:
        if kind == "upload":
            r = run.http.get(f"{url}/uploads/{digest}", timeout=TIME_LIMIT)
            want = {200} if digest in run.acked else {404}
        elif kind == "clusters":
            r, want = run.http.get(f"{url}/clusters", timeout=TIME_LIMIT), {200}
        elif kind == "mentors":
            r, want = run.http.get(f"{url}/mentors", timeout=TIME_LIMIT), {200}
        elif kind == "mentor":
            from urllib.parse import quote

            name = rng.choice([*MENTORS, *HOSTILE_STRINGS, "zz"])
            r = run.http.get(f"{url}/mentors/{quote(name.encode('utf-8', 'surrogatepass'))}",
                          timeout=TIME_LIMIT)
        elif kind == "health":
            r, want = run.http.get(f"{url}/health", timeout=TIME_LIMIT), {200}
        elif kind == "openapi":
            r, want = run.http.get(f"{url}/openapi.json", timeout=TIME_LIMIT), {200}
        elif kind == "unknown-path":
            r, want = run.http.get(f"{url}/{rng.choice(['x', 'admin', '../etc', 'uploads'])}",
                                timeout=TIME_LIMIT), {404, 405}
        elif kind == "put":
            r, want = run.http.put(f"{url}/demonstrations", timeout=TIME_LIMIT), {405}
        elif kind == "delete-other":
            if digest not in run.acked:
                r, want = run.http.delete(f"{url}/uploads/{digest}", headers=run.auth("ana"),
                                       timeout=TIME_LIMIT), {404}
            else:
                owner = run.acked[digest]["mentor"]
                other = next((m for m in MENTORS if m != owner), "ana")
                r, want = run.http.delete(f"{url}/uploads/{digest}", headers=run.auth(other),
                                       timeout=TIME_LIMIT), {403}
        else:
            r, want = run.http.delete(f"{url}/uploads/{'f' * 64}", headers=run.auth("ana"),
                                   timeout=TIME_LIMIT), {404}
    except httpx.TransportError as exc:
        run.judge("read", None, note=f"{kind}: {exc}")
        return
    status = run.judge("read", r, want=want, note=kind, seconds=time.perf_counter() - t0)
    if kind == "upload" and status == 200:
        doc = r.json()
        known = run.acked[digest]
        if len(doc["segments"]) != known["segments"] or doc["withdrawn"] != known["withdrawn"]:
            run.fail("read", "an upload reads back other than it was acknowledged",
                     f"{digest}: {known}", r)


def case_withdraw(run: StoreRun, rng: random.Random, i: int) -> None:
    """Withdraw one's own upload, then upload it again: stored again (reinstated)."""
    import httpx

    take = rng.choice(run.data.takes)
    mentor = rng.choice(MENTORS)
    url = run.server.url
    try:
        r = run.http.post(f"{url}/demonstrations", files={"file": (take.file, take.data)},
                       data={"annotation": json.dumps(take.entry)}, headers=run.auth(mentor),
                       timeout=TIME_LIMIT)
        if run.judge("withdraw", r, want={200, 201}, note="upload") not in (200, 201):
            return
        run.ack(r.json())
        digest = r.json()["upload"]
        r = run.http.delete(f"{url}/uploads/{digest}", headers=run.auth(mentor), timeout=TIME_LIMIT)
        if run.judge("withdraw", r, want={200}, note="withdraw") != 200:
            return
        run.acked[digest]["withdrawn"] = True
        if rng.random() < 0.6:
            r = run.http.post(f"{url}/demonstrations", files={"file": (take.file, take.data)},
                           data={"annotation": json.dumps(take.entry)},
                           headers=run.auth(mentor), timeout=TIME_LIMIT)
            if run.judge("withdraw", r, want={201}, note="upload again") == 201:
                if not r.json().get("reinstated"):
                    run.fail("withdraw", "a withdrawn take uploaded again is not reinstated",
                             digest, r)
                run.ack(r.json())
    except httpx.TransportError as exc:
        run.judge("withdraw", None, note=str(exc))


def case_concurrent(run: StoreRun, rng: random.Random, i: int) -> None:
    """The same new take four times at once (and a fifth other): one stored, one 201."""
    import httpx

    mentor = f"con{i}"
    run.tokens[mentor] = _new_token(run, mentor)
    take, other = rng.sample(run.data.takes, 2)
    jobs = [take] * 4 + [other]

    def send(t: Take) -> Any:
        try:
            return run.http.post(f"{run.server.url}/demonstrations",
                              files={"file": (t.file, t.data)},
                              data={"annotation": json.dumps(t.entry)},
                              headers=run.auth(mentor), timeout=TIME_LIMIT)
        except httpx.TransportError as exc:
            return f"{exc}"

    with ThreadPoolExecutor(5) as ex:
        replies = list(ex.map(send, jobs))
    same: list[int] = []
    for r, t in zip(replies, jobs, strict=True):  # each reply beside the job it answers
        if isinstance(r, str):
            run.judge("concurrent", None, note=r)
            continue
        status = run.judge("concurrent", r, want={200, 201}, note="same take x4")
        if r.status_code in (200, 201):
            run.ack(r.json())
        if t is take and status is not None:
            same.append(status)
    problem = identical_uploads_problem(same, asked=4)
    if problem:
        run.fail("concurrent", problem)


def identical_uploads_problem(statuses: list[int], asked: int) -> str | None:
    """What is wrong with the answered statuses of ``asked`` identical uploads sent at once
    (None if nothing): exactly one is stored (201) and the others find it (200). An upload
    whose reply was lost (a transport error, judged on its own) may be the one stored, so
    with fewer answers than uploads at most one 201 is required."""
    got = sorted(statuses)
    if len(got) == asked:
        ok = got == [200] * (asked - 1) + [201]
    else:
        ok = set(got) <= {200, 201} and got.count(201) <= 1
    if ok:
        return None
    return (f"{asked} identical uploads at once answered {got}"
            + ("" if len(got) == asked else f" ({asked - len(got)} without a reply)")
            + f", expected one 201 and {asked - 1} 200")


def kill_round(run: StoreRun, rng: random.Random, k: int) -> None:
    """Uploads in flight on 4 threads; SIGKILL while at least one is; restart; retry."""
    import httpx

    mentor = f"kill{k}"
    run.tokens[mentor] = _new_token(run, mentor)
    queue = list(run.data.takes)
    rng.shuffle(queue)
    in_flight = [0]
    flight_lock = threading.Lock()
    dead = threading.Event()
    cut: list[Take] = []
    answered = [0]

    def uploader(mine: list[Take]) -> None:
        for t in mine:
            if dead.is_set():
                return
            with flight_lock:
                in_flight[0] += 1
            try:
                r = run.http.post(f"{run.server.url}/demonstrations",
                               files={"file": (t.file, t.data)},
                               data={"annotation": json.dumps(t.entry)},
                               headers=run.auth(mentor), timeout=TIME_LIMIT)
            except httpx.TransportError:
                cut.append(t)  # cut by the kill: not acknowledged, sent again after
                run.count("kill")
                return
            finally:
                with flight_lock:
                    in_flight[0] -= 1
            if run.judge("kill", r, want={200, 201}, note=f"round {k}") in (200, 201):
                run.ack(r.json())
                with run.lock:
                    run.kill_acked += 1
                answered[0] += 1

    threads = [threading.Thread(target=uploader, args=(queue[j::4],)) for j in range(4)]
    for t in threads:
        t.start()
    delay = rng.uniform(0.3, 2.0)
    t0 = time.perf_counter()
    busy = False
    while time.perf_counter() - t0 < TIME_LIMIT and any(t.is_alive() for t in threads):
        with flight_lock:
            busy = in_flight[0] > 0
        if busy and time.perf_counter() - t0 >= delay:
            break
        time.sleep(0.005)
    if not busy:
        run.fail("kill", "no upload in flight to kill the server in the middle of")
    run.server.kill()
    dead.set()
    run.kills += 1
    for t in threads:
        t.join()
    run.check_log()
    run.server.start()
    # the retries: each stored once (a 200 when it had committed before the kill)
    for t in cut:
        try:
            r = run.http.post(f"{run.server.url}/demonstrations", files={"file": (t.file, t.data)},
                           data={"annotation": json.dumps(t.entry)}, headers=run.auth(mentor),
                           timeout=TIME_LIMIT)
        except httpx.TransportError as exc:
            run.judge("kill", None, note=f"retry after restart: {exc}")
            continue
        if run.judge("kill", r, want={200, 201}, note=f"retry, round {k}") in (200, 201):
            run.ack(r.json())


def final_check(run: StoreRun) -> dict[str, Any]:
    """Every acknowledged upload stored whole, as last left; no sample of no upload."""
    import httpx

    lost = []
    for digest, known in sorted(run.acked.items()):
        try:
            r = run.http.get(f"{run.server.url}/uploads/{digest}", timeout=TIME_LIMIT)
        except httpx.TransportError as exc:
            lost.append(f"{digest}: {exc}")
            continue
        if r.status_code != 200:
            lost.append(f"{digest}: {r.status_code}")
            continue
        doc = r.json()
        if len(doc["segments"]) != known["segments"] or doc["withdrawn"] != known["withdrawn"]:
            lost.append(f"{digest}: {len(doc['segments'])} segments, withdrawn "
                        f"{doc['withdrawn']}; acknowledged {known}")
    run.server.stop()
    from nonprehensile.service.db import make_pool

    pool = make_pool(run.store, max_size=1)
    try:
        with pool.connection() as conn:
            orphans = conn.execute(
                "SELECT count(*) FROM np_samples s WHERE NOT EXISTS (SELECT 1 FROM "
                "np_upload_samples u WHERE u.arc = s.store AND u.sample = s.id)").fetchone()[0]
            empty = conn.execute(
                "SELECT count(*) FROM np_uploads p WHERE NOT EXISTS (SELECT 1 FROM "
                "np_upload_samples u WHERE u.hash = p.hash)").fetchone()[0]
            no_reply = sum(1 for (reply,) in conn.execute("SELECT reply FROM np_uploads")
                           .fetchall() if not (json.loads(reply) if isinstance(reply, str)
                                              else reply))
            stored = conn.execute("SELECT count(*) FROM np_uploads").fetchone()[0]
    finally:
        pool.close()
    for what, n in (("samples of no upload", orphans), ("uploads without segments", empty),
                    ("uploads without their reply", no_reply)):
        if n:
            run.fail("final", f"{n} {what}")
    for line in lost[:20]:
        run.fail("final", "an acknowledged upload is lost or changed", line)
    return {"acknowledged": len(run.acked), "lost": len(lost), "stored": int(stored),
            "orphan_samples": int(orphans), "uploads_without_segments": int(empty)}


def _take_kind(variant: str) -> Callable[[StoreRun, random.Random, int], None]:
    def case(run: StoreRun, rng: random.Random, i: int) -> None:
        case_take(run, rng, i, variant)

    case.__name__ = f"case_{variant}"
    return case


KINDS: list[tuple[Callable[[StoreRun, random.Random, int], None], float]] = [
    (_take_kind("annotation"), 0.22),
    (_take_kind("recording"), 0.12),
    (_take_kind("valid"), 0.08),
    (_take_kind("name"), 0.04),
    (case_archive, 0.20),
    (case_token, 0.11),
    (case_body, 0.07),
    (case_read, 0.09),
    (case_cut, 0.03),
    (case_withdraw, 0.02),
    (case_concurrent, 0.015),
    (case_revoked_mid_upload, 0.005),
]


KIND_NAMES = {f: f.__name__.removeprefix("case_") for f, _ in KINDS}


def run_store(name: str, store: str, data: Data, work: Path, budget: int, seed: int,
              kills: int, progress: Callable[[str], None],
              only: int | None = None) -> dict[str, Any]:
    from nonprehensile.service.db import create_token, make_pool

    pool = make_pool(store, max_size=1)
    try:
        with pool.connection() as conn:
            tokens = {m: create_token(conn, m) for m in MENTORS}
    finally:
        pool.close()
    server = Server(store, work)
    run = StoreRun(name, store, server, data, tokens, work, seed)
    server.start()
    t0 = time.perf_counter()
    kill_at = [budget * (k + 1) // (kills + 1) for k in range(kills)]
    weights = [w for _, w in KINDS]
    i = 0
    last = time.perf_counter()
    if only is not None:  # replay one case on a fresh server (its state may differ)
        i, budget, kill_at = only, 1, []
    while run.requests < budget:
        rng = random.Random(f"{seed}/http/{i}")
        if kill_at and run.requests >= kill_at[0]:
            kill_at.pop(0)
            kill_round(run, rng, run.kills)
        else:
            fn = rng.choices([f for f, _ in KINDS], weights)[0]
            name_of = KIND_NAMES[fn]
            c0 = time.perf_counter()
            try:
                fn(run, rng, i)
            except Exception as exc:  # a bug of this harness: reported, the run goes on
                import traceback

                run.fail("harness", f"the harness failed: {type(exc).__name__}: {exc}",
                         "".join(traceback.format_exception(exc)[-3:]))
            run.kind_seconds[name_of] += time.perf_counter() - c0
        i += 1
        if not server.alive():
            run.fail("server", "the server died", server.new_log()[-600:])
            server.start()
        if i % 10 == 0:
            if server.sample_memory() * 2**20 > MEMORY_LIMIT:
                run.fail("server", f"peak memory {server.peak_mb:.0f} MB")
            run.check_log()
        if time.perf_counter() - last > 30:
            last = time.perf_counter()
            progress(f"[http {name}] {run.requests}/{budget} requests, {run.kills} kills, "
                     f"{len(run.failures)} failures")
    run.check_log()
    if only is not None:
        progress(server.log.read_text(errors="replace")[-4000:])
    final = final_check(run)
    run.check_log()
    progress(f"[http {name}] {run.requests} requests, {run.kills} kills, "
             f"{len(run.failures)} failures, {time.perf_counter() - t0:.0f} s")
    return {"requests": run.requests, "kinds": dict(sorted(run.kinds.items())),
            "statuses": dict(sorted(run.statuses.items())), "kills": run.kills,
            "acknowledged_in_kill_rounds": run.kill_acked, "server_starts": server.starts,
            "server_peak_mb": round(server.peak_mb, 1), **final,
            "check_accepts_but_segmentation_refuses": run.disagreements,
            "seconds": round(time.perf_counter() - t0, 1),
            "seconds_by_case_kind": {k: round(v, 1) for k, v in
                                     sorted(run.kind_seconds.items())},
            "failure_list": run.failures}


@contextlib.contextmanager
def postgres() -> Iterator[str]:
    """A fresh database on ``NONPREHENSILE_TEST_PG``'s server or on one started here with
    ``.ci/start-postgres`` (stopped after); raises RuntimeError saying why when none can be
    had."""
    from pgserver import fresh_database, server

    gen = server()
    url = next(gen)
    try:
        if url is None or url.startswith("skip:"):
            raise RuntimeError((url or "no PostgreSQL server").removeprefix("skip: "))
        db = fresh_database(url)
        try:
            yield next(db)
        finally:
            db.close()
    finally:
        gen.close()


def run(budget: int, seed: int, kills: int, stores: list[str],
        progress: Callable[[str], None] = print, only: int | None = None) -> dict[str, Any]:
    """The HTTP family over ``stores`` ("sqlite", "postgresql"), ``budget`` requests in all."""
    data = Data()
    out: dict[str, Any] = {"budget": budget, "seed": seed, "stores": {}, "skipped": {}}
    per = max(1, budget // len(stores))
    def one(name: str, work: Path) -> None:
        if name == "sqlite":
            out["stores"][name] = run_store(name, str(work / "service.db"), data, work, per,
                                            seed, kills, progress, only)
            return
        try:
            with postgres() as url:
                out["stores"][name] = run_store(name, url, data, work, per, seed, kills,
                                                progress, only)
        except RuntimeError as exc:
            if name in out["stores"]:
                raise
            out["skipped"][name] = f"no PostgreSQL server: {exc}"
            progress(f"[http {name}] skipped: no PostgreSQL server: {exc}")

    # the stores side by side: the harness mostly waits for its servers
    with tempfile.TemporaryDirectory(prefix="np-fuzz-http-") as tmp, \
            ThreadPoolExecutor(len(stores)) as ex:
        futures = []
        for name in stores:
            work = Path(tmp) / name
            work.mkdir()
            futures.append(ex.submit(one, name, work))
        for f in futures:
            f.result()
    runs = out["stores"].values()
    out["requests"] = sum(r["requests"] for r in runs)
    out["kills"] = sum(r["kills"] for r in runs)
    out["lost"] = sum(r["lost"] for r in runs)
    out["failures"] = sum(len(r["failure_list"]) for r in runs)
    return out


def main(argv: list[str] | None = None) -> int:
    warnings.simplefilter("ignore")  # zipfile's "Duplicate name" of the archives made so
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--budget", type=int, default=3200, help="HTTP requests over all stores")
    p.add_argument("--seed", type=int, default=13)
    p.add_argument("--kills", type=int, default=DEFAULT_KILLS, help="SIGKILLs per store")
    p.add_argument("--store", choices=["sqlite", "postgresql", "both"], default="both")
    p.add_argument("--report", type=Path, default=None)
    p.add_argument("--case", type=int, default=None,
                   help="replay case N alone, on a fresh server (the server's log is printed)")
    args = p.parse_args(argv)
    stores = ["sqlite", "postgresql"] if args.store == "both" else [args.store]

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    doc = run(args.budget, args.seed, args.kills, stores, progress, args.case)
    if args.report:
        args.report.write_text(json.dumps(doc, indent=1))
    else:
        print(json.dumps({k: v for k, v in doc.items() if k != "stores"}, indent=1))
        for name, r in doc["stores"].items():
            print(name, json.dumps({k: v for k, v in r.items() if k != "failure_list"}))
            for f in r["failure_list"][:20]:
                print("  FAIL", f)
    return 1 if doc["failures"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
