"""The service's refusals (a 4xx with one line each) and what a reply may show of the server.

A refusal names the culprit as the mentor knows it (``takes/t01.c3d``, ``annotations.json``),
never where the server keeps it: the lines of the dataset checks and of the readers name the
files they read by path, and the service reads an upload in a temporary folder of its own,
beside the skills file of its dataset. :func:`public_text` takes those folders out.
"""

from __future__ import annotations

import errno
import re
import tempfile
from collections.abc import Iterable
from pathlib import Path

import nonprehensile
from nonprehensile.errors import InputError, StoreError

__all__ = ["TEMP_PREFIX", "ArcMismatch", "Forbidden", "Rejected", "Unavailable", "disk_error",
           "one_line", "public_text"]

#: Prefix of the service's temporary folders (an upload is checked in one).
TEMP_PREFIX = "np-svc-"


class Rejected(InputError):
    """An upload that fails validation: HTTP 422 (or ``status``) with every problem, one line
    each."""

    def __init__(self, message: str, problems: list[str] | None = None, status: int = 422):
        super().__init__(message)
        self.problems = problems or [message]
        self.status = status


class Forbidden(InputError):
    """A mentor acting on another mentor's data: HTTP 403."""


class ArcMismatch(Rejected):
    """An arc's store holds another arc than the service's skills file gives its name (the
    skills were reordered or edited since it was written): ``serve`` refuses to start (exit
    2), and an upload that would add to it is refused with HTTP 409; nothing is written."""

    def __init__(self, message: str) -> None:
        super().__init__(message, status=409)


class Unavailable(StoreError):
    """The service's database cannot serve a request now (it is down, it dropped the
    connection, every connection is busy, or the server is stopping): HTTP 503 with one line
    and ``Retry-After``.

    The message is the client's, and names nothing of the server; ``reason`` (the driver's
    own words: a socket's path, a host) is for the server's log only.
    """

    def __init__(self, message: str, reason: str = "") -> None:
        super().__init__(message)
        self.reason = reason or message


def disk_error(exc: OSError, what: str) -> Rejected:
    """A file-system error of the server while it handles an upload: 507 for a full disk
    (the server's state, not the upload's fault), else 400 naming ``what`` it wrote."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return Rejected("the server's disk is full: the upload could not be checked; try "
                        "again later (nothing was stored)", status=507)
    return Rejected(f"{what} cannot be written on the server ({exc.strerror or one_line(exc)})",
                    status=400)


def one_line(exc: BaseException | str) -> str:
    """An exception's message (or a text) on one line (a library's own may span several)."""
    text = " ".join(str(exc).split())
    if isinstance(exc, str):
        return text
    return text or type(exc).__name__


def _temp_roots() -> list[str]:
    roots = {tempfile.gettempdir()}
    roots.add(str(Path(tempfile.gettempdir()).resolve()))
    return sorted(roots, key=len, reverse=True)


def public_text(text: str, hidden: Iterable[str | Path] = ()) -> str:
    """``text`` without the server's folders: the service's temporary folders (a name inside
    one keeps its part below it, ``takes/t01.c3d``), the package's folder and ``hidden``
    (the dataset the service runs on)."""
    for root in _temp_roots():
        # np-svc-<random>/ and everything the random part is made of
        text = re.sub(re.escape(root.rstrip("/")) + "/" + re.escape(TEMP_PREFIX)
                      + r"[A-Za-z0-9_]+(?:/|\b)", "", text)
    folders = {str(Path(nonprehensile.__file__).parent)}
    for h in hidden:
        folders.add(str(h))
        folders.add(str(Path(h).resolve()))
    for folder in sorted(folders, key=len, reverse=True):
        text = text.replace(folder.rstrip("/") + "/", "").replace(folder, ".")
    # a lone surrogate quoted from the input (a C3D label's byte that is not UTF-8, read with
    # ``surrogateescape``) cannot be encoded as JSON: the reply was a 500; written as its
    # escape (``\udc9b``) the detail still names it
    return text.encode("utf-8", "backslashreplace").decode("utf-8")
