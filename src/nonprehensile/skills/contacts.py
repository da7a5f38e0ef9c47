"""Contact elements, contact pairs and contact events (paper Section IV).

A contact pair ``(X, Y)`` says that elements ``X`` and ``Y`` touch; a contact event is the
logical AND of its pairs, e.g. the paper's ``(R_1, c) ∧ (R_2, d)``. An element is

* the ground ``G`` (:class:`Ground`),
* a finger ``R1``, ``R2``, ... (:class:`Finger`),
* a face of the object, written by its ID (:class:`Face`),
* the edge shared by faces ``f`` and ``g``, written ``E(f,g)`` (:class:`Edge`),
* the vertex shared by faces ``f, g, h, ...``, written ``V(f,g,h,...)`` (:class:`Vertex`).

Written forms (docs/files.md, "Skills file")
----------------------------------------------------------------
* A pair is ``(X,Y)``, e.g. ``(R1,f)``, ``(G,E(a,d))``, ``(R2,V(a,b,c))``; spaces around the
  punctuation are allowed. An event is a list of such strings (the skills file) or one string
  joining pairs with ``∧``, ``^``, ``&`` or ``AND`` (any case): the paper's notation.
* Printing is canonical, so equal values print the same: faces inside ``E(...)`` and
  ``V(...)`` are sorted; a pair puts the ground first, then fingers, then the object element
  (``(G,a)``, ``(R1,f)``, ``(G,R1)``); an event lists the pairs that involve fingers first (by
  finger number), then the others. ``parse(format(x)) == x`` for every value, and text that is
  already canonical, such as every event of the spec's example, is printed back unchanged.

Face IDs and reserved names
---------------------------
A face ID is any non-empty text without whitespace, commas or parentheses (``a``, ``top``,
``aa``, ``face-1``). In *element position* ``G`` always means the ground and ``R<k>`` (``R``
followed by digits) always means finger ``k``: the simplest sound rule, as no quoting is
needed and no text means two things. So a face literally named ``G`` or ``R1`` cannot be a
contact element on its own (:class:`Face` refuses it, with a message saying to rename the face
in the object model); inside ``E(...)`` and ``V(...)`` only faces can appear, so there such a
face is fine. ``E`` and ``V`` are ordinary face IDs unless followed by ``(``. Matching is
case-sensitive: ``g`` and ``r1`` are ordinary faces.

Which pairs are legal
---------------------
A pair joins two different elements, and at least one side must be the ground or a finger:
the object touches the ground (``(G,a)``) or a finger (``(R1,f)``), or a finger touches the
ground (``(G,R1)``, e.g. a finger sliding under the object). Two elements of the same rigid
object (``(a,E(a,b))``) do not make a contact, nor do two fingers (``(R1,R2)``) in the skill
model, nor an element with itself; these are refused when the pair is made.

Faces, edges and vertices are checked against an object by :func:`check_element` and
:func:`check_event`. A vertex may be named by any three or more of the faces that meet there
(on an octahedron four faces meet at each vertex, and ``V(a,b,c)`` of three of them names it);
:func:`normalize_element` rewrites it with all of them.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from numbers import Integral
from typing import Literal, TypeAlias, overload

from nonprehensile.errors import ContactError
from nonprehensile.geometry.polyhedron import Polyhedron

__all__ = [
    "AND_OPERATORS",
    "ContactEvent",
    "ContactPair",
    "Edge",
    "Element",
    "Face",
    "Finger",
    "Ground",
    "ObjectElement",
    "Vertex",
    "check_element",
    "check_event",
    "check_pair",
    "element_vertices",
    "faces_of",
    "format_element",
    "format_event",
    "format_pair",
    "map_element",
    "map_event",
    "map_pair",
    "normalize_element",
    "normalize_event",
    "parse_element",
    "parse_event",
    "parse_pair",
]

#: Words accepted between the pairs of an event written on one line (``AND`` in any case).
AND_OPERATORS = ("∧", "^", "&", "AND")

#: What the paper's notation prints between pairs.
_PAPER_AND = " ∧ "

# A face ID: the tokenizer and the Face/Edge/Vertex constructors share this pattern, so every
# ID a value accepts is one the parser reads back as a single token.
_NAME = r"[^\s,()]+"
_NAME_RE = re.compile(_NAME)
_FINGER_RE = re.compile(r"R(\d+)")
_TOKEN_RE = re.compile(rf"\s*(?:(?P<punct>[(),])|(?P<name>{_NAME}))")

_PAIR_HINT = "write a contact pair as (X,Y), e.g. (R1,f) or (G,E(a,d))"
_ELEMENT_HINT = (
    "an element is G (the ground), R1, R2, ... (fingers), a face ID, E(f,g) (an edge) or "
    "V(f,g,h,...) (a vertex)"
)
_AND_HINT = "join the pairs of an event with ∧, ^, & or AND"


def _check_face_id(face: object, where: str = "") -> str:
    prefix = f"{where}: " if where else ""
    if not isinstance(face, str):
        raise ContactError(f"{prefix}a face ID must be a string, got {face!r}")
    if not _NAME_RE.fullmatch(face):
        raise ContactError(
            f"{prefix}face ID {face!r} cannot be written in a contact: face IDs must be "
            "non-empty and contain no whitespace, commas or parentheses; rename the face in "
            "the object model"
        )
    return face


def _face_set(faces: object, kind: str, letter: str) -> frozenset[str]:
    if isinstance(faces, str) or not isinstance(faces, Iterable):
        raise ContactError(
            f"{kind} must be given the set of faces that meet there, e.g. "
            f"{letter}(a,b{',c' if letter == 'V' else ''}); got {faces!r}"
        )
    items = list(faces)
    for f in items:
        _check_face_id(f, f"{letter}({','.join(map(str, items))})")
    return frozenset(items)


# ---------------------------------------------------------------------------- elements
@dataclass(frozen=True)
class Ground:
    """The ground surface the object rests on, written ``G``."""

    def __str__(self) -> str:
        return "G"

    def __repr__(self) -> str:
        return "Ground()"


@dataclass(frozen=True)
class Finger:
    """Finger ``R_k`` of the hand, written ``R1``, ``R2``, ...

    Parameters
    ----------
    index : int
        The finger number ``k >= 1``.
    """

    index: int

    def __post_init__(self) -> None:
        k = self.index
        if isinstance(k, bool) or not isinstance(k, Integral) or int(k) < 1:
            raise ContactError(f"a finger number must be an integer >= 1 (R1, R2, ...), got {k!r}")
        object.__setattr__(self, "index", int(k))

    def __str__(self) -> str:
        return f"R{self.index}"


@dataclass(frozen=True)
class Face:
    """A face of the object, written by its ID.

    Parameters
    ----------
    id : str
        The face ID: non-empty, no whitespace, commas or parentheses, and neither ``G`` nor
        ``R<k>``, which in element position mean the ground and a finger.
    """

    id: str

    def __post_init__(self) -> None:
        _check_face_id(self.id)
        if self.id == "G" or _FINGER_RE.fullmatch(self.id):
            meaning = "the ground" if self.id == "G" else "a finger"
            raise ContactError(
                f"face {self.id!r} cannot be a contact element on its own: {self.id} means "
                f"{meaning} there (G is the ground, R1, R2, ... are fingers); rename the face "
                "in the object model (inside E(...) and V(...) it may keep its name)"
            )

    def __str__(self) -> str:
        return self.id


@dataclass(frozen=True)
class Edge:
    """The edge shared by two faces, written ``E(f,g)`` (the paper's ``E_{f,g}``).

    Parameters
    ----------
    faces : frozenset of str
        Exactly two distinct face IDs; any iterable is accepted and stored as a frozenset.
    """

    faces: frozenset[str]

    def __post_init__(self) -> None:
        faces = _face_set(self.faces, "an edge", "E")
        if len(faces) != 2:
            shown = ",".join(sorted(faces))
            hint = f"; for the vertex of those faces write V({shown})" if len(faces) > 2 else ""
            raise ContactError(
                f"E({shown}): an edge is named by exactly 2 distinct faces, got {len(faces)}{hint}"
            )
        object.__setattr__(self, "faces", faces)

    @classmethod
    def of(cls, *faces: str) -> Edge:
        """``Edge.of("a", "d")`` is ``E(a,d)``."""
        return cls(frozenset(faces))

    def __str__(self) -> str:
        return f"E({','.join(sorted(self.faces))})"

    def __repr__(self) -> str:
        return f"Edge.of({', '.join(map(repr, sorted(self.faces)))})"


@dataclass(frozen=True)
class Vertex:
    """The vertex shared by three or more faces, written ``V(f,g,h,...)``.

    Parameters
    ----------
    faces : frozenset of str
        At least three distinct face IDs that meet at the vertex (not necessarily all of
        them); any iterable is accepted and stored as a frozenset.
    """

    faces: frozenset[str]

    def __post_init__(self) -> None:
        faces = _face_set(self.faces, "a vertex", "V")
        if len(faces) < 3:
            shown = ",".join(sorted(faces))
            hint = f"; for the edge of those faces write E({shown})" if len(faces) == 2 else ""
            raise ContactError(
                f"V({shown}): a vertex is named by at least 3 distinct faces, got "
                f"{len(faces)}{hint}"
            )
        object.__setattr__(self, "faces", faces)

    @classmethod
    def of(cls, *faces: str) -> Vertex:
        """``Vertex.of("a", "b", "f")`` is ``V(a,b,f)``."""
        return cls(frozenset(faces))

    def __str__(self) -> str:
        return f"V({','.join(sorted(self.faces))})"

    def __repr__(self) -> str:
        return f"Vertex.of({', '.join(map(repr, sorted(self.faces)))})"


#: An element of the object: a face, an edge or a vertex.
ObjectElement: TypeAlias = Face | Edge | Vertex
#: Any contact element.
Element: TypeAlias = Ground | Finger | Face | Edge | Vertex

_ELEMENT_TYPES = (Ground, Finger, Face, Edge, Vertex)
_OBJECT_TYPES = (Face, Edge, Vertex)


_Key: TypeAlias = tuple[int, int, tuple[str, ...]]


def _element_key(el: Element) -> _Key:
    """Canonical order: ground, fingers by number, then faces, edges, vertices by faces."""
    if isinstance(el, Ground):
        return (0, 0, ())
    if isinstance(el, Finger):
        return (1, el.index, ())
    if isinstance(el, Face):
        return (2, 0, (el.id,))
    return (2, 1 if isinstance(el, Edge) else 2, tuple(sorted(el.faces)))


def format_element(el: Element) -> str:
    """The written form of an element: ``G``, ``R1``, ``a``, ``E(a,d)``, ``V(a,b,f)``."""
    return str(el)


# ---------------------------------------------------------------------------- pairs, events
@dataclass(frozen=True)
class ContactPair:
    """Two elements in touch, ``(X, Y)``; unordered, so ``(G, a) == (a, G)``.

    Parameters
    ----------
    x, y : Element
        The two elements, in any order; they are stored in canonical order (ground, fingers,
        then the object element), so ``x`` is what :func:`format_pair` prints first.

    Raises
    ------
    ContactError
        If an element is not an :data:`Element`, both are the same, both are fingers, or both
        are on the object (see the module's "Which pairs are legal").
    """

    x: Element
    y: Element

    def __post_init__(self) -> None:
        for el in (self.x, self.y):
            if not isinstance(el, _ELEMENT_TYPES):
                raise ContactError(
                    f"a contact pair joins two contact elements; got {el!r}. {_ELEMENT_HINT}"
                )
        x, y = sorted((self.x, self.y), key=_element_key)
        shown = f"({x},{y})"
        if x == y:
            raise ContactError(
                f"{shown}: an element cannot be in contact with itself; {_PAIR_HINT}"
            )
        if isinstance(x, Finger) and isinstance(y, Finger):
            raise ContactError(
                f"{shown}: two fingers touching each other is not a contact of the skill "
                "model; a pair joins the object to the ground or to a finger, or a finger "
                "to the ground, e.g. (R1,f), (G,a), (G,R1)"
            )
        if isinstance(x, _OBJECT_TYPES):
            raise ContactError(
                f"{shown}: both elements are on the object, which cannot touch itself; one "
                "side of a pair must be the ground G or a finger R1, R2, ..."
            )
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)

    @property
    def elements(self) -> tuple[Element, Element]:
        """``(x, y)`` in canonical order."""
        return (self.x, self.y)

    def __str__(self) -> str:
        return f"({self.x},{self.y})"


def format_pair(pair: ContactPair) -> str:
    """The written form ``(X,Y)`` of a pair, in canonical order."""
    return str(pair)


def _pair_key(pair: ContactPair) -> tuple[int, int, _Key, _Key]:
    # pairs with a finger first, by finger number: the spec's example lists (R1,f) before (G,a)
    fingers = [el.index for el in pair.elements if isinstance(el, Finger)]
    group = (0, min(fingers)) if fingers else (1, 0)
    return (*group, _element_key(pair.x), _element_key(pair.y))


@dataclass(frozen=True)
class ContactEvent:
    """A contact event: the logical AND of its contact pairs.

    Parameters
    ----------
    id : str
        The event's ID in its skill (may be empty for an unnamed event).
    pairs : frozenset of ContactPair
        At least one pair; any iterable of pairs is accepted and stored as a frozenset.
    """

    id: str
    pairs: frozenset[ContactPair]

    def __post_init__(self) -> None:
        if not isinstance(self.id, str):
            raise ContactError(f"an event's id must be a string, got {self.id!r}")
        if isinstance(self.pairs, str) or not isinstance(self.pairs, Iterable):
            raise ContactError(
                f"event {self.id!r}: pairs must be a set of ContactPair, got {self.pairs!r}"
            )
        pairs = frozenset(self.pairs)
        for p in pairs:
            if not isinstance(p, ContactPair):
                raise ContactError(
                    f"event {self.id!r}: expected contact pairs, got {p!r}; {_PAIR_HINT}"
                )
        if not pairs:
            raise ContactError(
                f"event {self.id!r} has no contact pair; an event is the AND of at least one "
                "pair, e.g. (G,a)"
            )
        object.__setattr__(self, "pairs", pairs)

    @property
    def ordered_pairs(self) -> tuple[ContactPair, ...]:
        """The pairs in canonical order: those with fingers first (by finger), then the rest."""
        return tuple(sorted(self.pairs, key=_pair_key))

    def __str__(self) -> str:
        return _PAPER_AND.join(map(str, self.ordered_pairs))

    def __repr__(self) -> str:
        inner = ", ".join(repr(str(p)) for p in self.ordered_pairs)
        return f"ContactEvent(id={self.id!r}, pairs=[{inner}])"


@overload
def format_event(event: ContactEvent, notation: Literal["ascii"] = ...) -> list[str]: ...
@overload
def format_event(event: ContactEvent, notation: Literal["paper"]) -> str: ...
@overload
def format_event(event: ContactEvent, notation: str) -> list[str] | str: ...


def format_event(event: ContactEvent, notation: str = "ascii") -> list[str] | str:
    """Write an event in the skills file's form or the paper's.

    Parameters
    ----------
    event : ContactEvent
    notation : {"ascii", "paper"}
        ``"ascii"``: the skills file's list of pairs, e.g. ``["(R1,f)", "(G,a)"]``;
        ``"paper"``: one string, e.g. ``"(R1,f) ∧ (G,a)"``.

    Returns
    -------
    list of str or str
        The pairs in canonical order (:attr:`ContactEvent.ordered_pairs`).

    Raises
    ------
    ContactError
        If ``notation`` is neither.
    """
    if notation == "ascii":
        return [str(p) for p in event.ordered_pairs]
    if notation == "paper":
        return str(event)
    raise ContactError(f"notation must be 'ascii' or 'paper', got {notation!r}")


# ---------------------------------------------------------------------------- parsing
@dataclass(frozen=True)
class _Token:
    kind: Literal["punct", "name"]
    text: str
    col: int  # 1-based column in the source text, for messages


class _Parser:
    """Recursive descent over the tiny grammar below (a regular expression cannot check the
    nesting of ``E(...)`` inside a pair, and no parser library is a dependency)::

        event   := pair (AND pair)*
        pair    := "(" element "," element ")"
        element := ("E" | "V") "(" name ("," name)* ")" | name
    """

    def __init__(self, text: str, what: str) -> None:
        self.text = text
        self.what = what
        self.tokens = self._tokenize(text)
        self.pos = 0

    def _tokenize(self, text: str) -> list[_Token]:
        tokens: list[_Token] = []
        i = 0
        # the token pattern matches at every position (a name is any run of characters other
        # than whitespace and punctuation), except at trailing whitespace
        while (m := _TOKEN_RE.match(text, i)) is not None:
            kind: Literal["punct", "name"] = "punct" if m.group("punct") else "name"
            tokens.append(_Token(kind, m.group(kind), m.start(kind) + 1))
            i = m.end()
        return tokens

    # ------------------------------------------------------------ errors
    def fail(self, expected: str, hint: str, tok: _Token | None = None) -> ContactError:
        tok = tok if tok is not None else self.peek()
        got = f"{tok.text!r} at column {tok.col}" if tok else "the end of the text"
        return ContactError(
            f"cannot read {self.what} {self.text!r}: expected {expected}, got {got}; {hint}"
        )

    def wrap(self, err: ContactError, start: _Token) -> ContactError:
        return ContactError(f"cannot read {self.what} {self.text!r} (at column {start.col}): {err}")

    # ------------------------------------------------------------ cursor
    def peek(self) -> _Token | None:
        return self.tokens[self.pos] if self.pos < len(self.tokens) else None

    def at_end(self) -> bool:
        return self.pos >= len(self.tokens)

    def take(self) -> _Token:
        tok = self.tokens[self.pos]
        self.pos += 1
        return tok

    def expect_punct(self, char: str, expected: str, hint: str) -> _Token:
        tok = self.peek()
        if tok is None or tok.kind != "punct" or tok.text != char:
            raise self.fail(expected, hint)
        return self.take()

    def expect_name(self, expected: str, hint: str) -> _Token:
        tok = self.peek()
        if tok is None or tok.kind != "name":
            raise self.fail(expected, hint)
        return self.take()

    # ------------------------------------------------------------ grammar
    def element(self) -> Element:
        tok = self.expect_name("a contact element", _ELEMENT_HINT)
        nxt = self.peek()
        if tok.text in ("E", "V") and nxt is not None and nxt.text == "(":
            self.take()
            names = [self.expect_name("a face ID", _ELEMENT_HINT).text]
            while (nxt := self.peek()) is not None and nxt.text == ",":
                self.take()
                names.append(self.expect_name("a face ID", _ELEMENT_HINT).text)
            self.expect_punct(")", f"',' or ')' in {tok.text}(...)", _ELEMENT_HINT)
            try:
                return Edge(frozenset(names)) if tok.text == "E" else Vertex(frozenset(names))
            except ContactError as err:
                raise self.wrap(err, tok) from None
        if tok.text == "G":
            return Ground()
        if (m := _FINGER_RE.fullmatch(tok.text)) is not None:
            digits = m.group(1)
            if digits.startswith("0") or len(digits) > 6:
                raise self.fail(
                    "a finger R1, R2, ... (numbered from 1, no leading zeros)",
                    "fingers are numbered from 1 (at most 6 digits), e.g. R1",
                    tok,
                )
            return Finger(int(digits))
        return Face(tok.text)

    def pair(self) -> ContactPair:
        start = self.expect_punct("(", "'(' opening a contact pair", _PAIR_HINT)
        x = self.element()
        self.expect_punct(",", "',' between the two elements of the pair", _PAIR_HINT)
        y = self.element()
        self.expect_punct(")", "')' closing the pair", _PAIR_HINT)
        try:
            return ContactPair(x, y)
        except ContactError as err:
            raise self.wrap(err, start) from None

    def conjunction(self) -> list[tuple[ContactPair, _Token]]:
        out = []
        while True:
            start = self.peek()
            pair = self.pair()
            assert start is not None  # pair() has consumed it
            out.append((pair, start))
            if self.at_end():
                return out
            tok = self.peek()
            if tok is None or tok.kind != "name" or not _is_and(tok.text):
                raise self.fail("an AND operator (∧, ^, & or AND) or the end", _AND_HINT)
            self.take()

    def finish(self, hint: str) -> None:
        if not self.at_end():
            raise self.fail("the end of the text", hint)


def _is_and(text: str) -> bool:
    return text in AND_OPERATORS or text.upper() == "AND"


def _require_str(text: object, what: str, example: str) -> str:
    if not isinstance(text, str):
        raise ContactError(f"{what} must be a string such as {example!r}, got {text!r}")
    return text


def parse_element(text: str) -> Element:
    """Read one element: ``G``, ``R1``, ``a``, ``E(a,d)``, ``V(a,b,f)``.

    Raises
    ------
    ContactError
        Quoting the text and pointing at the column of the problem.
    """
    p = _Parser(_require_str(text, "a contact element", "E(a,d)"), "contact element")
    el = p.element()
    p.finish(_ELEMENT_HINT)
    return el


def parse_pair(text: str) -> ContactPair:
    """Read one pair ``(X,Y)``, e.g. ``(R1,f)``, ``(G,E(a,d))``, ``(R2,V(a,b,c))``.

    Raises
    ------
    ContactError
        Quoting the text and pointing at the column of the problem.
    """
    p = _Parser(_require_str(text, "a contact pair", "(R1,f)"), "contact pair")
    pair = p.pair()
    p.finish(f"one pair per string; to AND several pairs use an event; {_PAIR_HINT}")
    return pair


def parse_event(contacts: str | Sequence[str], event_id: str = "") -> ContactEvent:
    """Read an event from the skills file's list of pairs or from the paper's notation.

    Parameters
    ----------
    contacts : str or sequence of str
        A list of pairs, one per string (``["(R1,f)", "(G,a)"]``), or one string of pairs
        joined by ``∧``, ``^``, ``&`` or ``AND`` (``"(R1,c) ∧ (R2,d)"``).
    event_id : str
        The event's ID.

    Returns
    -------
    ContactEvent

    Raises
    ------
    ContactError
        If a pair cannot be read (quoting it and pointing at the column), the event has no
        pair, or a pair is written twice.
    """
    where = f"event {event_id!r}" if event_id else "event"
    found: list[tuple[ContactPair, str]] = []
    if isinstance(contacts, str):
        p = _Parser(contacts, f"{where} contacts")
        if p.at_end():
            raise ContactError(
                f"{where}: no contact pair in {contacts!r}; an event is the AND of at least "
                "one pair, e.g. (R1,c) ∧ (R2,d)"
            )
        found = [(pair, f"column {tok.col}") for pair, tok in p.conjunction()]
    elif isinstance(contacts, Sequence):
        for i, item in enumerate(contacts):
            s = _require_str(item, f"{where}: contacts[{i}]", "(R1,f)")
            try:
                found.append((parse_pair(s), f"contacts[{i}]"))
            except ContactError as err:
                raise ContactError(f"{where}: contacts[{i}]: {err}") from None
    else:
        raise ContactError(
            f"{where}: contacts must be a list of pairs like ['(R1,f)', '(G,a)'] or a string "
            f"like '(R1,f) ∧ (G,a)', got {contacts!r}"
        )
    source = f" {contacts!r}" if isinstance(contacts, str) else ""
    seen: dict[ContactPair, str] = {}
    for pair, at in found:
        if pair in seen:
            raise ContactError(
                f"{where}{source}: pair {pair} is written twice ({seen[pair]} and {at}); remove one"
            )
        seen[pair] = at
    return ContactEvent(event_id, frozenset(seen))


# ---------------------------------------------------------------------------- validation
def _vertex_element(poly: Polyhedron, i: int) -> Vertex:
    return Vertex(poly.vertex_faces[i])


def _check_faces_known(el: Element, faces: Iterable[str], poly: Polyhedron) -> None:
    for f in sorted(faces):
        if f not in poly.faces:
            raise ContactError(
                f"element {el} names face {f!r}, which the object {poly.name!r} does not "
                f"have; its faces are {', '.join(poly.faces)}"
            )


def element_vertices(el: ObjectElement, poly: Polyhedron) -> tuple[int, ...]:
    """The object's vertices that make up an element, checking it against the object.

    Parameters
    ----------
    el : Face, Edge or Vertex
    poly : Polyhedron

    Returns
    -------
    tuple of int
        Indices into ``poly.vertices``: a face's loop, an edge's two ends (as run by one of its
        faces), or the one vertex.

    Raises
    ------
    ContactError
        If the element is the ground or a finger, names a face the object lacks, is an edge of
        two faces that share no edge, or a vertex of faces that share no vertex; the message
        names the element and lists the valid choices.
    """
    if not isinstance(el, _OBJECT_TYPES):
        raise ContactError(
            f"element {el} is not part of the object; expected a face, E(f,g) or V(f,g,h)"
        )
    if isinstance(el, Face):
        _check_faces_known(el, (el.id,), poly)
        return poly.loop(el.id)
    _check_faces_known(el, el.faces, poly)
    if isinstance(el, Edge):
        if el.faces in poly.edges:
            return poly.edges[el.faces]
        f, g = sorted(el.faces)
        choices = sorted({str(Edge(k)) for k in poly.edges if f in k or g in k})
        meet = poly.shared_vertices(el.faces)
        also = f" (they meet only at vertex {_vertex_element(poly, meet[0])})" if meet else ""
        raise ContactError(
            f"element {el}: faces {f!r} and {g!r} of {poly.name!r} share no edge{also}; the "
            f"edges of those faces are {', '.join(choices)}"
        )
    shared = poly.shared_vertices(el.faces)
    if len(shared) == 1:
        return (shared[0],)
    if not shared:
        # the closest choices: the vertices that have the most of the named faces
        overlap = [len(el.faces & fs) for fs in poly.vertex_faces]
        best = max(overlap)
        choices = sorted(str(_vertex_element(poly, i)) for i, n in enumerate(overlap) if n == best)
        raise ContactError(
            f"element {el}: faces {', '.join(sorted(el.faces))} of {poly.name!r} share no "
            f"vertex; the vertices with most of them are {', '.join(choices)}"
        )
    # Two faces of a convex polyhedron meet in one edge, one vertex or not at all, so three
    # or more faces share at most one vertex of a valid model; kept so that a model breaking
    # that rule is reported rather than silently resolved to one of its vertices.
    choices = sorted(str(_vertex_element(poly, i)) for i in shared)
    raise ContactError(
        f"element {el} is ambiguous on {poly.name!r}: those faces share {len(shared)} "
        f"vertices, {', '.join(choices)}; name one of them with all its faces"
    )


def check_element(el: Element, poly: Polyhedron) -> None:
    """Check that the object has an element; the ground and fingers always pass.

    Raises
    ------
    ContactError
        As :func:`element_vertices`.
    """
    if isinstance(el, (Ground, Finger)):
        return
    element_vertices(el, poly)


def check_pair(pair: ContactPair, poly: Polyhedron) -> None:
    """Check both elements of a pair against the object.

    Raises
    ------
    ContactError
        Naming the pair and the element at fault.
    """
    for el in pair.elements:
        try:
            check_element(el, poly)
        except ContactError as err:
            raise ContactError(f"pair {pair}: {err}") from None


def check_event(event: ContactEvent, poly: Polyhedron) -> None:
    """Check every pair of an event against the object.

    Raises
    ------
    ContactError
        Naming the event, the pair and the element at fault, with the valid choices.
    """
    for pair in event.ordered_pairs:
        try:
            check_pair(pair, poly)
        except ContactError as err:
            name = f"event {event.id!r}" if event.id else f"event {event}"
            raise ContactError(f"{name}: {err}") from None


@overload
def normalize_element(el: ObjectElement, poly: Polyhedron) -> ObjectElement: ...
@overload
def normalize_element(el: Element, poly: Polyhedron) -> Element: ...


def normalize_element(el: Element, poly: Polyhedron) -> Element:
    """The element written with all its faces: a vertex named by some of the faces that meet
    there (``V(a,b,c)`` on an octahedron) becomes ``V`` of all of them; others are unchanged.

    Raises
    ------
    ContactError
        As :func:`check_element`.
    """
    check_element(el, poly)
    if isinstance(el, Vertex):
        return _vertex_element(poly, element_vertices(el, poly)[0])
    return el


def normalize_event(event: ContactEvent, poly: Polyhedron) -> ContactEvent:
    """The event with every element normalised (:func:`normalize_element`).

    Raises
    ------
    ContactError
        As :func:`check_event`.
    """
    check_event(event, poly)
    return ContactEvent(
        event.id,
        frozenset(
            ContactPair(normalize_element(p.x, poly), normalize_element(p.y, poly))
            for p in event.pairs
        ),
    )


# ---------------------------------------------------------------------------- mapping
def faces_of(item: ContactEvent | ContactPair | Element) -> frozenset[str]:
    """Every face named by an event, a pair or an element, including inside ``E(...)`` and
    ``V(...)``; the ground and fingers name none."""
    if isinstance(item, ContactEvent):
        return frozenset[str]().union(*(faces_of(p) for p in item.pairs))
    if isinstance(item, ContactPair):
        return faces_of(item.x) | faces_of(item.y)
    if isinstance(item, Face):
        return frozenset((item.id,))
    if isinstance(item, (Edge, Vertex)):
        return item.faces
    return frozenset()


def _images(faces: Iterable[str], face_map: Mapping[str, str], where: str) -> dict[str, str]:
    """The images of ``faces``, checking that the map covers them and keeps them apart (a
    map joining two faces would merge an edge's faces or two pairs of an event)."""
    out: dict[str, str] = {}
    by_image: dict[str, str] = {}
    for f in sorted(faces):
        if f not in face_map:
            raise ContactError(
                f"{where}: the face map has no image for face {f!r}; it maps "
                f"{', '.join(sorted(map(str, face_map))) or 'no face'}"
            )
        g = face_map[f]
        if g in by_image:
            raise ContactError(
                f"{where}: the face map sends both {by_image[g]!r} and {f!r} to {g!r}; a map "
                "between equivalent states is one-to-one"
            )
        by_image[g] = f
        out[f] = g
    return out


def _map_element(el: Element, images: Mapping[str, str]) -> Element:
    if isinstance(el, Face):
        return Face(images[el.id])
    if isinstance(el, Edge):
        return Edge(frozenset(images[f] for f in el.faces))
    if isinstance(el, Vertex):
        return Vertex(frozenset(images[f] for f in el.faces))
    return el


def _map_pair(pair: ContactPair, images: Mapping[str, str]) -> ContactPair:
    return ContactPair(_map_element(pair.x, images), _map_element(pair.y, images))


def map_element(el: Element, face_map: Mapping[str, str]) -> Element:
    """Rename the faces of an element (the paper's Section V: the equivalent element).

    Parameters
    ----------
    el : Element
        The ground and fingers are returned unchanged.
    face_map : mapping of str to str
        Face ``f`` becomes ``face_map[f]``; it must cover every face of ``el`` and send them
        to distinct faces.

    Raises
    ------
    ContactError
        If the map misses a face of the element or joins two of them.
    """
    return _map_element(el, _images(faces_of(el), face_map, f"element {el}"))


def map_pair(pair: ContactPair, face_map: Mapping[str, str]) -> ContactPair:
    """Rename the faces of both elements of a pair (see :func:`map_element`)."""
    return _map_pair(pair, _images(faces_of(pair), face_map, f"pair {pair}"))


def map_event(event: ContactEvent, face_map: Mapping[str, str]) -> ContactEvent:
    """Rename the faces of every pair of an event, keeping its ID (see :func:`map_element`).

    Raises
    ------
    ContactError
        If the map misses a face the event names or sends two of them to the same face.
    """
    images = _images(faces_of(event), face_map, f"event {event.id!r} ({event})")
    return ContactEvent(event.id, frozenset(_map_pair(p, images) for p in event.pairs))
