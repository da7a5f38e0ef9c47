"""Dataset archives (zip; tar, plain or gzip, bzip2, xz) unpacked member by member, bounded
as they stream.

Nothing of an archive is loaded whole before it is counted. A zip's central directory is
walked entry by entry, and refused past ``max_files``, before :mod:`zipfile` reads it
(zipfile makes an object of every entry of the whole directory: 64 MiB of directory is about
a million entries and gigabytes). A tar is read as a stream, one header at a time, through a
reader that counts the bytes it decompresses (a tar.gz of millions of empty headers is
refused after ``max_files`` of them, and a gzip bomb hidden in one header, as a GNU long name
or a PAX record, after ``max_bytes``).

Each member's name is checked before anything of it is written: relative, without ``..``,
``\\``, NUL or control characters, valid UTF-8, at most :data:`MAX_NAME_PART` characters a
folder or file name and :data:`MAX_NAME_DEPTH` levels, never both a file and a folder (``a``
and ``a/b``), never twice. Links, devices, encrypted zip members and compression methods
other than stored, deflate, bzip2 and LZMA are refused; sizes are summed as members come
(at most ``max_bytes`` unpacked). Every error of decompression or of the file system is one
line: a :class:`~nonprehensile.service.errors.Rejected` with its HTTP status (400 a damaged or
refused archive, 413 one too large, 507 a full disk on the server).

The standard library reads the formats (zipfile, tarfile, gzip, bz2, lzma); only the walk of
the zip directory is written here, because zipfile has no way to stop its own early.
"""

from __future__ import annotations

import bz2
import errno
import gzip
import io
import lzma
import stat
import struct
import tarfile
import zipfile
import zlib
from pathlib import Path, PurePosixPath
from typing import IO, Any, BinaryIO, Protocol

from nonprehensile.service.errors import Rejected, disk_error, one_line

__all__ = ["MAX_ARCHIVE_FILES", "MAX_NAME_DEPTH", "MAX_NAME_PART", "unpack_archive"]

#: Most members (files and folders) in an uploaded archive.
MAX_ARCHIVE_FILES = 5000
#: Longest folder or file name in an archive, characters (file systems take 255 bytes).
MAX_NAME_PART = 200
#: Deepest folder nesting in an archive.
MAX_NAME_DEPTH = 32
#: Bytes of tar headers (and PAX records, GNU long names) allowed per member, beyond the
#: members' data, when the decompressed stream is counted.
TAR_HEADER_ALLOWANCE = 4096
_ZIP_METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate",
                zipfile.ZIP_BZIP2: "bzip2", zipfile.ZIP_LZMA: "LZMA"}
_CHUNK = 1 << 16
# what a damaged archive or member raises in the standard library's readers
_READ_ERRORS = (tarfile.TarError, zipfile.BadZipFile, EOFError, zlib.error, lzma.LZMAError,
                ValueError, RuntimeError, NotImplementedError, struct.error, OverflowError)

_EOCD = struct.Struct("<4s4H2LH")  # end of central directory
_ZIP64_LOCATOR = struct.Struct("<4sLQL")
_ZIP64_EOCD = struct.Struct("<4sQ2H2L4Q")
_CENTRAL = struct.Struct("<4s6H3L5H2L")  # one central directory entry, before its name


def unpack_archive(source: bytes | BinaryIO, dest: Path, *, max_bytes: int,
                   max_files: int = MAX_ARCHIVE_FILES) -> None:
    """Unpack a zip or tar archive (``source``: its bytes, or a seekable binary file) into
    the folder ``dest``, checking every member as it comes (see the module notes).

    Raises
    ------
    Rejected
        One line naming the member at fault; ``status`` 400 (damaged or refused), 413 (too
        many members or too many bytes) or 507 (the server's disk is full).
    """
    f: BinaryIO = io.BytesIO(source) if isinstance(source, bytes | bytearray) else source
    plan = _Plan(dest, max_bytes, max_files)
    try:
        f.seek(0)
        if zipfile.is_zipfile(f):
            _unpack_zip(f, plan)
        else:
            _unpack_tar(f, plan)
    except Rejected:
        raise
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise disk_error(exc, "the archive") from None
        where = f" (member {plan.current!r})" if plan.current else ""
        raise Rejected(f"the archive cannot be unpacked{where}: {one_line(exc)}",
                       status=400) from None
    except _READ_ERRORS as exc:
        where = f"archive member {plan.current!r} cannot be read" if plan.current \
            else "the archive cannot be read"
        raise Rejected(f"{where} ({one_line(exc)})", status=400) from None


class _Plan:
    """The members seen so far: names, kinds, count and bytes, checked as each comes."""

    def __init__(self, dest: Path, max_bytes: int, max_files: int) -> None:
        self.dest = dest
        self.max_bytes = max_bytes
        self.max_files = max_files
        self.files: set[str] = set()
        self.dirs: set[str] = set()
        self.count = 0
        self.declared = 0
        self.written = 0
        self.current = ""

    def too_many(self, n: int | None = None) -> Rejected:
        """The refusal of an archive of ``n`` members (None: more than can be had)."""
        has = f"{n} members, more than {self.max_files}" if n else \
            f"more than {self.max_files} members"
        return Rejected(f"the archive has {has}; a dataset archive holds its annotations, "
                        "skills file and recordings", status=413)

    def too_big(self) -> Rejected:
        return Rejected(f"the archive unpacks to more than {self.max_bytes} bytes", status=413)

    def add(self, raw: str, *, is_dir: bool, size: int) -> PurePosixPath | None:
        """Check member ``raw`` (its name in the archive) and count it; its relative path
        (None: the archive's top folder itself, ``./``)."""
        self.count += 1
        if self.count > self.max_files:
            raise self.too_many()
        self.current = raw[:300]
        path = _member_path(raw)
        if path is None:
            if not is_dir:
                raise Rejected(f"archive member {raw!r} has no name", status=400)
            return None
        name = path.as_posix()
        for i in range(1, len(path.parts)):
            folder = PurePosixPath(*path.parts[:i]).as_posix()
            if folder in self.files:
                raise _clash(folder)
            self.dirs.add(folder)
        if is_dir:
            if name in self.files:
                raise _clash(name)
            self.dirs.add(name)
            return path
        if name in self.dirs:
            raise _clash(name)
        if name in self.files:
            raise Rejected(f"archive member {name!r} is in the archive twice; which one is "
                           "meant? Make the archive again", status=400)
        self.files.add(name)
        self.declared += max(0, size)
        if self.declared > self.max_bytes:
            raise self.too_big()
        return path

    def write(self, path: PurePosixPath, src: IO[bytes], size: int) -> None:
        """Copy at most ``size`` bytes of ``src`` to the member's file."""
        target = self.dest.joinpath(*path.parts)
        target.parent.mkdir(parents=True, exist_ok=True)
        left = size
        with target.open("xb") as out:
            while left > 0:
                try:
                    chunk = src.read(min(_CHUNK, left))
                except Rejected:
                    raise
                except (*_READ_ERRORS, OSError) as exc:  # bz2 says OSError of bad data
                    raise Rejected(f"archive member {path.as_posix()!r} cannot be read "
                                   f"({one_line(exc)})", status=400) from None
                if not chunk:
                    raise Rejected(f"archive member {path.as_posix()!r} is cut short",
                                   status=400)
                left -= len(chunk)
                self.written += len(chunk)
                if self.written > self.max_bytes:
                    raise self.too_big()
                out.write(chunk)

    def folder(self, path: PurePosixPath) -> None:
        self.dest.joinpath(*path.parts).mkdir(parents=True, exist_ok=True)


def _clash(name: str) -> Rejected:
    return Rejected(f"archive member {name!r} is both a file and a folder of the archive; "
                    "rename one of them", status=400)


def _member_path(raw: str) -> PurePosixPath | None:
    """A member's name as a relative path, or an error saying what is wrong with it."""
    shown = repr(raw[:80] + ("..." if len(raw) > 80 else ""))
    bad = next((c for c in raw if ord(c) < 32 or ord(c) == 127), None)
    if bad is not None:
        raise Rejected(f"archive member {shown}: its name holds the control character "
                       f"{bad!r}", status=400)
    try:
        raw.encode("utf-8")
    except UnicodeEncodeError:
        raise Rejected(f"archive member {shown}: its name is not valid UTF-8; name files "
                       "in UTF-8", status=400) from None
    if "\\" in raw:
        raise Rejected(f"archive member {shown}: '\\' in its name; archives separate folders "
                       "with '/' (make it with zip or tar, not by hand)", status=400)
    p = PurePosixPath(raw)
    if p.is_absolute() or ".." in p.parts:
        raise Rejected(f"archive member {shown} lies outside the archive's folder", status=400)
    if not p.parts:
        return None
    if len(p.parts) > MAX_NAME_DEPTH:
        raise Rejected(f"archive member {shown}: folders nested {len(p.parts)} deep, more than "
                       f"{MAX_NAME_DEPTH}", status=400)
    for part in p.parts:
        if len(part) > MAX_NAME_PART or len(part.encode("utf-8")) > 255:
            raise Rejected(f"archive member {shown}: the name {part[:40] + '...'!r} has "
                           f"{len(part)} characters, more than {MAX_NAME_PART}", status=400)
    return p


# ---------------------------------------------------------------------------------- zip
def _unpack_zip(f: BinaryIO, plan: _Plan) -> None:
    _count_zip_entries(f, plan.max_files, plan)
    f.seek(0)
    with zipfile.ZipFile(f) as zf:
        infos = zf.infolist()
        if len(infos) > plan.max_files:  # (the walk above counted the same directory)
            raise plan.too_many(len(infos))
        checked: list[tuple[zipfile.ZipInfo, PurePosixPath | None]] = []
        for info in infos:  # every name, kind and size before anything is written
            mode = info.external_attr >> 16
            if mode and stat.S_IFMT(mode) not in (0, stat.S_IFREG, stat.S_IFDIR):
                raise Rejected(f"archive member {info.filename!r} is a link or a device; a "
                               "dataset archive holds plain files", status=400)
            path = plan.add(info.filename, is_dir=info.is_dir(), size=info.file_size)
            if not info.is_dir():
                if info.flag_bits & 0x1:
                    raise Rejected(f"archive member {info.filename!r} is encrypted; upload "
                                   "the archive without a password", status=400)
                if info.compress_type not in _ZIP_METHODS:
                    raise Rejected(
                        f"archive member {info.filename!r} uses compression method "
                        f"{info.compress_type}, which the service does not read; use "
                        f"{', '.join(sorted(_ZIP_METHODS.values()))}", status=400)
            checked.append((info, path))
        for info, path in checked:
            plan.current = info.filename
            if path is None:
                continue
            if info.is_dir():
                plan.folder(path)
                continue
            with zf.open(info) as src:
                plan.write(path, src, info.file_size)
                if src.read(1):  # zipfile stops at the declared size; checked all the same
                    raise Rejected(f"archive member {info.filename!r} holds more than its "
                                   "declared size", status=400)
        plan.current = ""


def _count_zip_entries(f: BinaryIO, limit: int, plan: _Plan) -> None:
    """Walk the central directory as zipfile will (found the same way), entry by entry, and
    refuse it past ``limit`` entries; reads at most ``limit + 1`` entries' headers."""
    f.seek(0, io.SEEK_END)
    size = f.tell()
    tail_len = min(size, _EOCD.size + 0xFFFF + _ZIP64_LOCATOR.size)
    f.seek(size - tail_len)
    tail = f.read(tail_len)
    # zipfile: first an end record without a comment, then the last one in the last 64 kB
    at = len(tail) - _EOCD.size
    if not (at >= 0 and tail[at : at + 4] == b"PK\x05\x06" and tail[-2:] == b"\0\0"):
        at = tail.rfind(b"PK\x05\x06")
    if at < 0 or at + _EOCD.size > len(tail):
        raise zipfile.BadZipFile("no end of central directory record")
    _, _, _, _, n_total, cd_size, cd_offset, _ = _EOCD.unpack_from(tail, at)
    eocd_pos = size - tail_len + at
    extra = 0
    loc = at - _ZIP64_LOCATOR.size
    if loc >= 0 and tail[loc : loc + 4] == b"PK\x06\x07":
        # zip64: the counts and offsets are in the record before the locator
        rec = eocd_pos - _ZIP64_LOCATOR.size - _ZIP64_EOCD.size
        if rec < 0:
            raise zipfile.BadZipFile("a zip64 locator without its record")
        f.seek(rec)
        data = f.read(_ZIP64_EOCD.size)
        if len(data) < _ZIP64_EOCD.size or data[:4] != b"PK\x06\x06":
            raise zipfile.BadZipFile("a damaged zip64 end of central directory record")
        fields = _ZIP64_EOCD.unpack(data)
        n_total, cd_size, cd_offset = fields[7], fields[8], fields[9]
        extra = _ZIP64_LOCATOR.size + _ZIP64_EOCD.size
    if n_total > limit:  # (0xFFFF in a zip without zip64 records: at least that many)
        raise plan.too_many(None if n_total == 0xFFFF else n_total)
    start = eocd_pos - extra - cd_size
    if start < 0 or cd_offset > start:
        raise zipfile.BadZipFile("the central directory lies outside the file")
    f.seek(start)
    seen = count = 0
    while seen < cd_size:
        head = f.read(_CENTRAL.size)
        if len(head) < _CENTRAL.size or head[:4] != b"PK\x01\x02":
            raise zipfile.BadZipFile("a damaged central directory entry")
        fields = _CENTRAL.unpack(head)
        skip = fields[10] + fields[11] + fields[12]  # name, extra field, comment
        count += 1
        if count > limit:
            raise plan.too_many()
        f.seek(skip, io.SEEK_CUR)
        seen += _CENTRAL.size + skip


# ---------------------------------------------------------------------------------- tar
class _Readable(Protocol):
    def read(self, n: int = -1, /) -> bytes: ...


class _Counted(io.RawIOBase):
    """A stream's bytes, at most ``limit`` of them (past it: a 413)."""

    def __init__(self, raw: _Readable, limit: int, plan: _Plan) -> None:
        self.raw = raw
        self.limit = limit
        self.plan = plan
        self.total = 0

    def readable(self) -> bool:
        return True

    def read(self, n: int = -1) -> bytes:
        if n is None or n < 0 or self.total + n > self.limit + _CHUNK:
            n = max(0, self.limit + _CHUNK - self.total)
        data = self.raw.read(n)
        self.total += len(data)
        if self.total > self.limit:
            raise self.plan.too_big()
        return data

    def readinto(self, b: Any) -> int:
        data = self.read(len(b))
        b[: len(data)] = data
        return len(data)


def _decompressed(f: BinaryIO) -> _Readable:
    f.seek(0)
    magic = f.read(6)
    f.seek(0)
    if magic[:2] == b"\x1f\x8b":
        return gzip.GzipFile(fileobj=f, mode="rb")
    if magic[:3] == b"BZh":
        return bz2.BZ2File(f)
    if magic == b"\xfd7zXZ\x00":
        return lzma.LZMAFile(f)
    return f


def _unpack_tar(f: BinaryIO, plan: _Plan) -> None:
    # twice through the stream: first every header (names, kinds, count, sizes; the data
    # skipped over as it decompresses), then, all of them good, the files written; a bomb
    # is refused without a file made
    _walk_tar(f, plan, write=False)
    _walk_tar(f, _Plan(plan.dest, plan.max_bytes, plan.max_files), write=True)


def _walk_tar(f: BinaryIO, plan: _Plan, *, write: bool) -> None:
    limit = plan.max_bytes + TAR_HEADER_ALLOWANCE * (plan.max_files + 2)
    stream = _Counted(_decompressed(f), limit, plan)
    try:
        tf = tarfile.open(fileobj=stream, mode="r|")  # noqa: SIM115 - closed below
    except tarfile.ReadError as exc:
        raise Rejected(f"the upload is neither a zip nor a tar archive ({one_line(exc)})",
                       status=400) from None
    with tf:
        for ti in tf:  # one header at a time; the data of each member read before the next
            if not (ti.isfile() or ti.isdir()):
                raise Rejected(f"archive member {ti.name[:300]!r} is a link or a device; a "
                               "dataset archive holds plain files", status=400)
            path = plan.add(ti.name, is_dir=ti.isdir(), size=ti.size)
            if path is None or not write:
                continue
            if ti.isdir():
                plan.folder(path)
                continue
            src = tf.extractfile(ti)
            if src is None:  # pragma: no cover - a regular file always has its data
                raise Rejected(f"archive member {ti.name!r} has no data", status=400)
            plan.write(path, src, ti.size)
        plan.current = ""
