"""Reading untrusted C3D files where a crash or a hang of the C3D library cannot hurt.

ezc3d (C++) trusts a C3D file's own offsets and counts: a file with two flipped bits can crash
it (a segmentation fault ends the whole process, without a message) and one with a few bytes
deleted can send it into a loop for minutes. So a C3D file passes two guards:

1. :func:`check_c3d_structure` reads the header and walks the parameter section in Python
   (sizes, offsets, the processor type, the data section's extent against the file's size)
   and rejects, with one line naming the file and the culprit, what cannot be a C3D file.
2. :func:`parse_c3d` hands the file to ezc3d in a separate worker process, with a time limit
   and a memory limit (``RLIMIT_AS``). If ezc3d crashes, hangs or runs out of memory there,
   the worker is killed and replaced and the caller gets a :class:`DemonstrationError`.

The worker is started once per process (about 0.15 s: Python, numpy and ezc3d; this file runs
as a script there, without the package's imports) and reused for every file; it is stopped when
the process exits. Its answers come back as raw numpy arrays and JSON (never a pickle; every
length and dtype checked), in the shape ezc3d's own Python object has:
``{"header": ..., "parameters": {"POINT": {PARAM: {"value": ...}}}, "data": {"points": ...,
"meta_points": {"residuals": ...}}}``. Only the ``POINT`` group of the parameters (rate,
units, labels: what the reader uses) and no analog data are transferred: encoding every
group of a file took 0.04 s of the 0.07 s spent on the bundled cube's 180 answers (issue 16).
"""

from __future__ import annotations

import atexit
import json
import math
import os
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from nonprehensile.errors import DemonstrationError

__all__ = [
    "PARSE_MEMORY_LIMIT",
    "PARSE_TIMEOUT",
    "C3DWorker",
    "check_c3d_structure",
    "parse_c3d",
]

#: Seconds ezc3d may spend on one file (plus one per MiB of file): real files take milliseconds.
PARSE_TIMEOUT = 10.0
#: Seconds the worker may take to start (importing numpy and ezc3d on a busy machine).
START_TIMEOUT = 120.0
#: Address-space limit of the worker process, bytes.
PARSE_MEMORY_LIMIT = 2 * 2**30

_BLOCK = 512
_PROCESSORS = {84: "Intel", 85: "DEC", 86: "MIPS"}
_TYPES = {-1: 1, 1: 1, 2: 2, 4: 4}  # parameter data type -> bytes per element


def _fail(path: Path, what: str) -> DemonstrationError:
    return DemonstrationError(f"{path}: cannot read it as a C3D file: {what}")


def check_c3d_structure(path: str | Path) -> None:
    """Check a C3D file's header and parameter section, before any C3D library reads it.

    Parameters
    ----------
    path : str or Path
        The file.

    Raises
    ------
    DemonstrationError
        Naming the file and what is wrong (a byte offset, a block number, a count).
    """
    path = Path(path)
    size = path.stat().st_size
    if size < 2 * _BLOCK:
        raise _fail(path, f"{size} bytes, less than a header and a parameter block (1024)")
    with path.open("rb") as fh:
        head = fh.read(_BLOCK)
        pblock, key = head[0], head[1]
        if key != 0x50:
            raise _fail(path, f"byte 2 is {key}, a C3D header holds 80 there")
        pstart = _BLOCK * (pblock - 1)
        if pblock < 2 or pstart + _BLOCK > size:
            raise _fail(path, f"the parameter section starts at block {pblock}, outside the "
                              f"file's {size // _BLOCK} blocks")
        fh.seek(pstart)
        params = fh.read(_BLOCK)
        nblocks, proc = params[2], params[3]
        if proc not in _PROCESSORS:
            raise _fail(path, f"processor type {proc} at byte {pstart + 4}; expected 84 "
                              "(Intel), 85 (DEC) or 86 (MIPS)")
        if nblocks < 1 or pstart + _BLOCK * nblocks > size:
            raise _fail(path, f"the parameter section of {nblocks} blocks from block {pblock} "
                              f"runs past the end of the file ({size} bytes)")
        params += fh.read(_BLOCK * (nblocks - 1))
    end = ">" if proc == 86 else "<"
    point_frames = _walk_parameters(path, params, pstart, end)

    dstart = struct.unpack(end + "H", head[16:18])[0]
    if _BLOCK * (dstart - 1) > size:
        raise _fail(path, f"the data section starts at block {dstart}, past the end of the "
                          f"file ({size} bytes)")
    _check_not_cut(path, head, proc, end, size, point_frames)


def _check_not_cut(path: Path, head: bytes, proc: int, end: str, size: int,
                   point_frames: int | None) -> None:
    """Refuse a file cut short in its data: fewer whole frames than the header and
    ``POINT:FRAMES`` both count, and a piece of a frame after the last whole one.

    The counts alone are not enough: real files overstate them (the Optotrak sample of
    ezc3d's test files counts 1149 frames and holds 29) and ezc3d then reads the frames there
    are. A file that ends inside a frame, where no writer stops, was cut (a copy or a download
    that did not finish); ezc3d read it as a shorter recording, silently.
    """
    n_points, n_analog, first, last = struct.unpack(end + "HHHH", head[2:10])
    counted = last - first + 1
    if n_points == 0 or counted <= 0 or point_frames != counted:
        return  # no points, or the counts disagree: nothing certain to check against
    # the scale factor's sign says float (4-byte) or integer (2-byte) data; its sign bit
    # is in byte 3 (Intel), 1 (DEC: words swapped) or 0 (MIPS, big-endian)
    sign = head[12 + {84: 3, 85: 1, 86: 0}[proc]] & 0x80
    frame_bytes = (4 * n_points + n_analog) * (4 if sign else 2)
    data_bytes = size - _BLOCK * (struct.unpack(end + "H", head[16:18])[0] - 1)
    whole, rest = divmod(data_bytes, frame_bytes)
    if whole < counted and rest:
        raise _fail(path, f"the file is cut short: the header and POINT:FRAMES count "
                          f"{counted} frames of {frame_bytes} bytes, and its {size} bytes hold "
                          f"{whole} of them and a piece of the next; copy or export the take "
                          "again")


def _walk_parameters(path: Path, params: bytes, pstart: int, end: str) -> int | None:
    """Follow the parameter records' offsets: each must move forward inside the section and
    each parameter's data must fit its record. Returns ``POINT:FRAMES`` (a scalar integer or
    float parameter), or None."""
    pos, limit = 4, len(params)
    seen = 0
    groups: dict[int, str] = {}
    frames: list[tuple[int, float]] = []  # (group id, value) of each scalar FRAMES
    while pos + 2 <= limit:
        nchar = struct.unpack("b", params[pos : pos + 1])[0]
        gid = struct.unpack("b", params[pos + 1 : pos + 2])[0]
        if nchar == 0:
            break
        n = abs(nchar)
        at = pstart + pos
        off_at = pos + 2 + n
        if off_at + 2 > limit:
            raise _fail(path, f"the parameter record at byte {at} runs past the parameter "
                              "section")
        offset = struct.unpack(end + "H", params[off_at : off_at + 2])[0]
        nxt = off_at + offset if offset else limit
        if offset and (offset < 2 or nxt > limit):
            raise _fail(path, f"the parameter record at byte {at} points to byte "
                              f"{pstart + nxt}, outside the parameter section")
        if gid == 0:
            raise _fail(path, f"the parameter record at byte {at} has group id 0")
        body = off_at + 2
        if gid > 0:  # a parameter: type, dimensions, data, description
            if body + 2 > nxt:
                raise _fail(path, f"the parameter record at byte {at} is cut short")
            dtype = struct.unpack("b", params[body : body + 1])[0]
            ndims = params[body + 1]
            if dtype not in _TYPES or ndims > 7:
                raise _fail(path, f"the parameter record at byte {at} has data type {dtype} "
                                  f"and {ndims} dimensions (types -1, 1, 2, 4; at most 7)")
            dims = params[body + 2 : body + 2 + ndims]
            count = 1
            for d in dims:
                count *= d
            data_end = body + 2 + ndims + count * _TYPES[dtype]
            if len(dims) != ndims or data_end > nxt:
                raise _fail(path, f"the data of the parameter record at byte {at} "
                                  f"({count} values) runs past its record")
            name = params[pos + 2 : pos + 2 + n].decode("latin-1").upper()
            if name == "FRAMES" and ndims == 0 and dtype in (2, 4):
                raw = params[body + 2 : body + 2 + dtype]
                value = struct.unpack(end + ("h" if dtype == 2 else "f"), raw)[0]
                frames.append((gid, value if dtype == 4 or value >= 0 else value + 65536))
        else:
            groups[-gid] = params[pos + 2 : pos + 2 + n].decode("latin-1").upper()
        seen += 1
        if not offset:
            break
        pos = nxt
    point = [v for g, v in frames if groups.get(g) == "POINT"]
    return int(point[0]) if point and math.isfinite(point[0]) and point[0] >= 0 else None


# ---------------------------------------------------------------------------------- worker


def _encode(obj: Any, arrays: dict[str, np.ndarray[Any, Any]]) -> Any:
    """ezc3d's nested dicts as JSON, numpy arrays set aside (by name) for :func:`_pack`."""
    if isinstance(obj, dict) or hasattr(obj, "keys"):  # ezc3d's Header, Data: dict-like
        return {str(k): _encode(obj[k], arrays) for k in obj.keys()}  # noqa: SIM118
    if isinstance(obj, (list, tuple)):
        return [_encode(v, arrays) for v in obj]
    if isinstance(obj, np.ndarray):
        if obj.dtype.hasobject:
            return [_encode(v, arrays) for v in obj.tolist()]
        name = f"a{len(arrays)}"
        arrays[name] = obj
        return {"__array__": name}
    if isinstance(obj, np.generic):
        return obj.item()
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    return str(obj)


#: Kinds of array the worker may send: numbers and fixed-width text, never objects.
_KINDS = frozenset("biufcUS")


def _pack(doc: Any, arrays: dict[str, np.ndarray[Any, Any]]) -> bytes:
    """``doc`` (JSON) and the arrays it names, framed: the JSON's length (8 bytes), the JSON
    (the document and each array's dtype and shape), then the arrays' bytes in order.

    A raw framing rather than an ``.npz``: a zip archive of two dozen arrays per file cost
    more to write and to read than ezc3d takes to parse the file (issue 16).
    """
    names = list(arrays)
    head = json.dumps({"doc": doc, "arrays": [
        [n, arrays[n].dtype.str, list(arrays[n].shape)] for n in names]}).encode()
    return b"".join([struct.pack("<Q", len(head)), head,
                     *(np.ascontiguousarray(arrays[n]).tobytes() for n in names)])


def _unpack(path: Path, payload: bytes) -> tuple[Any, dict[str, np.ndarray[Any, Any]]]:
    """The inverse of :func:`_pack`, checking every length and dtype (the worker parsed an
    untrusted file: its answer is checked, never trusted)."""
    try:
        (n,) = struct.unpack("<Q", payload[:8])
        head = json.loads(payload[8:8 + n].decode())
        at = 8 + n
        arrays = {}
        for name, dt, shape in head["arrays"]:
            dtype = np.dtype(dt)
            count = math.prod(int(v) for v in shape)
            if dtype.kind not in _KINDS or min(shape, default=0) < 0 or (
                    at + count * dtype.itemsize > len(payload)):
                raise ValueError(f"array {name!r} of {dt} {shape}")
            arrays[str(name)] = np.frombuffer(payload, dtype, count, at).reshape(shape).copy()
            at += count * dtype.itemsize
        if at != len(payload):
            raise ValueError(f"{len(payload) - at} bytes left over")
        return head["doc"], arrays
    except (ValueError, TypeError, KeyError, struct.error) as exc:
        raise DemonstrationError(
            f"{path}: the C3D reader's answer is malformed ({exc}); the file is damaged"
        ) from None


def _decode(obj: Any, arrays: Any) -> Any:
    if isinstance(obj, dict):
        if set(obj) == {"__array__"}:
            return np.asarray(arrays[obj["__array__"]])
        return {k: _decode(v, arrays) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_decode(v, arrays) for v in obj]
    return obj


def _worker_main() -> None:  # pragma: no cover - runs in the worker process
    """The worker: read a JSON file name per line, answer with a framed :func:`_pack`."""
    import resource

    limit = int(os.environ.get("NONPREHENSILE_C3D_MEMORY", PARSE_MEMORY_LIMIT))
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    proto = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # whatever ezc3d prints must not mix with the answers
    import ezc3d

    proto.write(b"R")
    proto.flush()
    for line in sys.stdin.buffer:
        try:
            c3d = ezc3d.c3d(json.loads(line))
            arrays: dict[str, np.ndarray[Any, Any]] = {}
            doc = {"header": _encode(c3d["header"], arrays),
                   "parameters": _encode({k: c3d["parameters"][k]
                                          for k in c3d["parameters"].keys()  # noqa: SIM118
                                          if k == "POINT"}, arrays),
                   "data": {"points": _encode(np.asarray(c3d["data"]["points"]), arrays),
                            "meta_points": _encode(
                                {k: v for k, v in dict(c3d["data"].get("meta_points", {})
                                                       ).items() if k == "residuals"},
                                arrays)}}
            status, payload = b"K", _pack(doc, arrays)
        except MemoryError:
            status, payload = b"E", b"out of memory reading it (its counts are wrong)"
        except Exception as exc:  # ezc3d raises bare RuntimeError/IOError on corrupt files
            status, payload = b"E", str(exc).encode("utf-8", "replace")[:2000]
        proto.write(status + struct.pack("<Q", len(payload)) + payload)
        proto.flush()


class C3DWorker:
    """A worker process that parses C3D files with ezc3d, restarted after a crash or a hang.

    Parameters
    ----------
    timeout : float
        Seconds allowed per file, plus one per MiB of the file.
    memory : int
        Address-space limit of the worker, bytes.
    """

    def __init__(self, timeout: float = PARSE_TIMEOUT, memory: int = PARSE_MEMORY_LIMIT
                 ) -> None:
        self.timeout = timeout
        self.memory = memory
        self._proc: subprocess.Popen[bytes] | None = None
        self._lock = threading.Lock()
        self._pid = os.getpid()

    def _start(self) -> subprocess.Popen[bytes]:
        env = dict(os.environ, NONPREHENSILE_C3D_MEMORY=str(self.memory),
                   OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
        proc = subprocess.Popen(
            # this file run as a script, not imported as nonprehensile.demonstrations.c3d_safe:
            # the package's __init__ would import scipy and more (0.4 s a start: issue 16)
            [sys.executable, "-c", "import runpy, sys; "
             "runpy.run_path(sys.argv[1], run_name='c3d_worker')['_worker_main']()", __file__],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env,
            close_fds=True,
        )
        try:
            ready = self._read(proc, 1, time.monotonic() + START_TIMEOUT)
        except TimeoutError:
            self._kill(proc)
            raise DemonstrationError(
                f"the C3D reader did not start in {START_TIMEOUT:g} s; the machine is "
                "overloaded, retry"
            ) from None
        if ready != b"R":
            code = self._kill(proc)
            raise DemonstrationError(
                f"the C3D reader could not start (exit code {code}); is ezc3d installed? "
                "pip install 'nonprehensile[mocap]'"
            )
        return proc

    @staticmethod
    def _read(proc: subprocess.Popen[bytes], n: int, deadline: float) -> bytes:
        """Exactly ``n`` bytes from the worker, fewer at its end; TimeoutError at deadline."""
        assert proc.stdout is not None
        fd = proc.stdout.fileno()
        chunks: list[bytes] = []
        got = 0
        while got < n:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                continue
            chunk = os.read(fd, min(n - got, 1 << 20))
            if not chunk:
                break
            chunks.append(chunk)
            got += len(chunk)
        return b"".join(chunks)

    @staticmethod
    def _kill(proc: subprocess.Popen[bytes]) -> int | None:
        if proc.poll() is None:
            proc.kill()
        try:
            return proc.wait(timeout=10)
        except subprocess.TimeoutExpired:  # pragma: no cover - a process that ignores SIGKILL
            return None
        finally:
            for f in (proc.stdin, proc.stdout):
                if f is not None:
                    f.close()

    def close(self) -> None:
        """Stop the worker."""
        with self._lock:
            if self._proc is not None and os.getpid() == self._pid:
                if self._proc.stdin is not None:
                    self._proc.stdin.close()
                try:
                    self._proc.wait(timeout=2)
                except subprocess.TimeoutExpired:
                    self._kill(self._proc)
            self._proc = None

    def parse(self, path: str | Path) -> dict[str, Any]:
        """ezc3d's reading of ``path`` (see the module notes), or an error naming the file.

        Raises
        ------
        DemonstrationError
            ezc3d's own error, or the worker crashed (the signal), ran out of time or memory.
        """
        path = Path(path)
        limit = self.timeout + path.stat().st_size / 2**20
        with self._lock:
            if os.getpid() != self._pid:  # a forked child does not share its parent's worker
                self._proc, self._pid = None, os.getpid()
            if self._proc is None or self._proc.poll() is not None:
                self._proc = self._start()
            proc = self._proc
            assert proc.stdin is not None
            try:
                proc.stdin.write(json.dumps(str(path.resolve())).encode() + b"\n")
                proc.stdin.flush()
                head = self._read(proc, 9, time.monotonic() + limit)
                if len(head) == 9:
                    status, n = head[:1], struct.unpack("<Q", head[1:])[0]
                    payload = self._read(proc, n, time.monotonic() + limit)
                    if len(payload) == n:
                        return self._answer(path, status, payload)
            except TimeoutError:
                self._kill(proc)
                self._proc = None
                raise DemonstrationError(
                    f"{path}: the C3D reader did not finish in {limit:.0f} s and was stopped; "
                    "the file is damaged (its counts or offsets are wrong)"
                ) from None
            except BrokenPipeError:
                pass
            code = self._kill(proc)
            self._proc = None
        raise DemonstrationError(f"{path}: the C3D reader crashed on this file "
                                 f"({_describe_exit(code)}); the file is damaged")

    @staticmethod
    def _answer(path: Path, status: bytes, payload: bytes) -> dict[str, Any]:
        if status != b"K":
            text = payload.decode("utf-8", "replace").replace("\n", " ").strip()
            raise DemonstrationError(f"{path}: ezc3d cannot read it as a C3D file: {text}")
        doc, arrays = _unpack(path, payload)
        result: dict[str, Any] = _decode(doc, arrays)
        return result


def _describe_exit(code: int | None) -> str:
    if code is None:
        return "it did not stop"
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


_shared: C3DWorker | None = None
_shared_lock = threading.Lock()


def _worker() -> C3DWorker:
    global _shared
    with _shared_lock:
        if _shared is None:
            _shared = C3DWorker()
            atexit.register(_shared.close)
        return _shared


def parse_c3d(path: str | Path) -> dict[str, Any]:
    """Check ``path``'s structure, then parse it with ezc3d in the shared worker process.

    Returns
    -------
    dict
        ``header``, ``parameters`` and ``data`` (``points``, ``meta_points.residuals``) as
        ezc3d gives them.

    Raises
    ------
    DemonstrationError
        Naming the file: a damaged structure, ezc3d's error, or a crash or hang of the
        reader (the worker is replaced).
    """
    check_c3d_structure(path)
    return _worker().parse(path)
