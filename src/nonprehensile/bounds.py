"""Bounds on what the library accepts from outside, checked before any work starts.

Every file and every number that comes from a user passes one of these checks at the entry
that reads it, so that a hostile or damaged input ends in one clear
:class:`~nonprehensile.errors.InputError` (exit 2 on the command line) and never in a
traceback, a hang or an unbounded allocation. The limits are far above what real data needs
(docs/robustness.md lists them with their reasons).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from nonprehensile.errors import InputError

__all__ = [
    "MAX_COORDINATE",
    "MAX_DOCUMENT_BYTES",
    "MAX_DOCUMENT_DEPTH",
    "MAX_DOCUMENT_NODES",
    "check_document",
    "check_file_size",
    "check_path",
    "key_list",
]

#: Largest JSON/YAML file read, bytes: a model, skills or annotations file of a few thousand
#: demonstrations is a few MiB.
MAX_DOCUMENT_BYTES = 64 * 2**20
#: Deepest nesting of lists and mappings in a JSON/YAML document: the spec's files nest at
#: most 6 levels; the parsers and ``repr`` recurse, so thousands of levels would overflow.
MAX_DOCUMENT_DEPTH = 64
#: Most values in a parsed document, counting every use of a YAML alias: aliases can make a
#: small file expand to billions of values (the "billion laughs").
MAX_DOCUMENT_NODES = 10_000_000
#: Largest coordinate magnitude accepted in a recording or a model (in its own units): a
#: capture volume is metres, so this is far off any real value, and products of two such
#: numbers (distances, covariances) stay far from float overflow.
MAX_COORDINATE = 1e9


def check_path(path: str | os.PathLike[str], what: str = "file name") -> Path:
    """``path`` as a :class:`Path`, or an error when the operating system cannot take it.

    A NUL character or a lone surrogate (a string that is not valid Unicode) cannot be a file
    name: the system calls would fail with an unrelated ``ValueError``.

    Raises
    ------
    InputError
        Naming the character and where it is.
    """
    text = os.fspath(path)
    if not isinstance(text, str):
        raise InputError(f"{what}: expected a text file name, got {type(text).__name__}")
    if "\x00" in text:
        raise InputError(f"{what} {text!r}: a file name cannot hold a NUL character")
    try:
        os.fsencode(text)
    except UnicodeEncodeError as exc:
        raise InputError(
            f"{what} {text!r}: character {exc.start + 1} is not valid in a file name "
            "(a lone surrogate); give a valid name"
        ) from None
    return Path(text)


def check_file_size(path: Path, limit: int, kind: str) -> int:
    """The size of ``path`` in bytes, or an error when it is above ``limit``."""
    size = path.stat().st_size
    if size > limit:
        raise InputError(
            f"{path}: {size} bytes is more than the {limit} bytes a {kind} may have; is it the "
            "right file?"
        )
    return size


def check_document(data: Any, source: str) -> Any:
    """``data`` (a parsed JSON/YAML document) if its nesting and size are within bounds.

    Iterative, and each shared node (a YAML alias) is sized once, so the check costs the
    number of distinct nodes whatever the document expands to.

    Raises
    ------
    InputError
        Nesting deeper than :data:`MAX_DOCUMENT_DEPTH`, more than
        :data:`MAX_DOCUMENT_NODES` values once aliases are expanded, an integer beyond
        floats, or a value JSON has not (a YAML date, binary or set).
    """
    sizes: dict[int, int] = {}
    open_: set[int] = set()  # nodes whose children are being walked (a cycle returns to one)
    # post-order walk: (node, depth, children done?)
    stack: list[tuple[Any, int, bool]] = [(data, 1, False)]
    while stack:
        node, depth, done = stack.pop()
        if isinstance(node, str):
            _check_text(node, source)
            continue
        if not isinstance(node, (list, tuple, Mapping)):
            _check_scalar(node, source)
            continue
        if not done and id(node) in sizes:
            continue
        if not done and id(node) in open_:
            raise InputError(
                f"{source}: the document contains itself (a YAML alias inside its own anchor); "
                "write it out plainly"
            )
        children = list(node.keys()) + list(node.values()) if isinstance(node, Mapping) \
            else list(node)
        if done:
            total = 1 + sum(sizes.get(id(c), 1) for c in children)
            if total > MAX_DOCUMENT_NODES:
                raise InputError(
                    f"{source}: the document expands to more than {MAX_DOCUMENT_NODES} values "
                    "(YAML aliases used many times over?); write it out plainly"
                )
            sizes[id(node)] = total
            open_.discard(id(node))
            continue
        if depth > MAX_DOCUMENT_DEPTH:
            raise InputError(
                f"{source}: lists and mappings nested more than {MAX_DOCUMENT_DEPTH} levels "
                "deep; the spec's files nest a few levels"
            )
        open_.add(id(node))
        stack.append((node, depth, True))
        stack.extend((c, depth + 1, False) for c in children)
    return data


def _check_scalar(value: Any, source: str) -> None:
    """A value of a document must be one JSON has (YAML also makes dates, bytes and sets,
    which no file of the spec holds and no JSON writer takes), and an integer must fit a
    float: every number of these files is used as one."""
    if value is None or isinstance(value, (bool, float)):
        return
    if isinstance(value, int):
        try:
            float(value)
        except OverflowError:
            digits = len(str(abs(value)))  # at most 4300 digits: the parsers' own bound
            raise InputError(
                f"{source}: the integer {str(value)[:12]}... ({digits} digits) is too large for "
                "any value of these files (numbers end at 1.8e308)"
            ) from None
        return
    kind = {"date": "a date", "datetime": "a date and time", "bytes": "binary data (!!binary)",
            "set": "a set (!!set)"}.get(type(value).__name__, f"a {type(value).__name__}")
    raise InputError(
        f"{source}: {kind} {str(value)[:40]!r} is not a JSON value; write it as a quoted string "
        "(or a list), as the spec's files are JSON or the same in YAML"
    )


def _check_text(text: str, source: str) -> None:
    """A string of a document must be valid Unicode: JSON's ``"\\ud800"`` escape makes a lone
    surrogate, which no file, terminal or other program can take."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise InputError(
            f"{source}: the text {text[:40]!r} holds a lone surrogate (character "
            f"{exc.start + 1}), which is not valid Unicode; fix the escape"
        ) from None


def key_list(keys: Iterable[Any]) -> list[str]:
    """Keys of a user's mapping as sorted strings, for messages (YAML keys may be of any
    type, which ``sorted`` alone cannot order)."""
    return sorted({str(k) for k in keys})


def finite_in(value: float, low: float, high: float) -> bool:
    """Whether ``value`` is a finite number in ``low..high``."""
    return math.isfinite(value) and low <= value <= high
