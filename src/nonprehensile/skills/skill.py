"""Skills and skill graphs (paper Section IV, Fig. 5).

A skill is a chain of contact events joined by motion arcs (continuous finger motions) that
takes the object from an initial state to a final state. The skill graph of a maneuver merges
the skills that realise it: skills whose events differ branch, skills with the same events and
different finger motions are parallel arcs (the paper's skills 2 and 3 in Fig. 5).

A skill is a value; it can be executed step by step (:meth:`Skill.steps`), which is the seam a
physics simulation will use to check inferred skills.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import networkx as nx

from nonprehensile.checks import DRIFT_DEG, suggest_angle_tol
from nonprehensile.equivalence import apply_to_state
from nonprehensile.errors import ContactError, ManeuverError, SkillError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.geometry.symmetry import Symmetry, rotation_group
from nonprehensile.maneuvers import MANEUVER_TYPES, ManeuverType, classify, maneuvers_from
from nonprehensile.skills.contacts import (
    ContactEvent,
    Edge,
    Face,
    Ground,
    Vertex,
    check_event,
    faces_of,
    format_event,
    map_event,
    parse_event,
)
from nonprehensile.states import DEFAULT_ANGLE_TOL, State, angle_diff

__all__ = [
    "Motion",
    "Skill",
    "SkillStep",
    "check_skill",
    "events_to_dicts",
    "group_by_maneuver",
    "skill_from_dict",
    "skill_graph",
    "skill_to_dict",
]


@dataclass(frozen=True)
class Motion:
    """A motion arc between two consecutive contact events.

    Attributes
    ----------
    source, target : str
        IDs of the events it joins.
    label : str
        Optional name of the finger motion (e.g. ``"quarter-circle"``).
    """

    source: str
    target: str
    label: str = ""

    def to_dict(self) -> dict[str, str]:
        """The skills file's form ``{"from": ..., "to": ...}`` (plus ``label`` if any)."""
        out = {"from": self.source, "to": self.target}
        if self.label:
            out["label"] = self.label
        return out


@dataclass(frozen=True)
class SkillStep:
    """One step of a skill run in order: a motion from one contact event to the next."""

    index: int
    source: ContactEvent
    target: ContactEvent
    motion: Motion


@dataclass(frozen=True)
class Skill:
    """A demonstrated (or inferred) skill.

    Attributes
    ----------
    name : str
        The skill's name.
    initial, final : State
        The state transition it realises.
    events : tuple of ContactEvent
        The chain of contact events, in order.
    motions : tuple of Motion
        ``motions[i]`` joins ``events[i]`` to ``events[i + 1]``.
    maneuver : {"rolling", "rotating", "tumbling"}
        The maneuver type.
    invertible : bool
        Whether running the events backwards reverses the maneuver.
    """

    name: str
    initial: State
    final: State
    events: tuple[ContactEvent, ...]
    motions: tuple[Motion, ...]
    maneuver: ManeuverType
    invertible: bool = False

    def __post_init__(self) -> None:
        if not self.events:
            raise SkillError(f"skill {self.name!r} has no contact event")
        ids = [e.id for e in self.events]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise SkillError(f"skill {self.name!r}: event id(s) {dup} are used more than once")
        if len(self.motions) != len(self.events) - 1:
            raise SkillError(
                f"skill {self.name!r}: {len(self.events)} events need "
                f"{len(self.events) - 1} motions joining consecutive events, got "
                f"{len(self.motions)}"
            )
        for i, m in enumerate(self.motions):
            a, b = self.events[i].id, self.events[i + 1].id
            if (m.source, m.target) != (a, b):
                raise SkillError(
                    f"skill {self.name!r}: motion {i} goes {m.source!r} -> {m.target!r}, but "
                    f"the events chain as {a!r} -> {b!r}; motions must join consecutive "
                    "events in order"
                )
        if self.maneuver not in MANEUVER_TYPES:
            raise SkillError(
                f"skill {self.name!r}: maneuver must be one of {list(MANEUVER_TYPES)}, got "
                f"{self.maneuver!r}"
            )

    def faces(self) -> frozenset[str]:
        """Every face the skill names: bottom faces and faces inside its events."""
        out = {self.initial.face, self.final.face}
        for e in self.events:
            out |= faces_of(e)
        return frozenset(out)

    def steps(self) -> Iterator[SkillStep]:
        """The skill executed step by step: each motion with the events it joins."""
        for i, m in enumerate(self.motions):
            yield SkillStep(i, self.events[i], self.events[i + 1], m)

    def mapped(
        self, face_map: Mapping[str, str], initial: State, final: State, *, name: str | None = None
    ) -> Skill:
        """The same skill with faces renamed (an adapted skill, paper Fig. 8)."""
        return Skill(
            name or self.name,
            initial,
            final,
            tuple(map_event(e, face_map) for e in self.events),
            self.motions,
            self.maneuver,
            self.invertible,
        )

    def reversed(self) -> Skill:
        """The skill run backwards (for an invertible skill): events and motions reversed."""
        if not self.invertible:
            raise SkillError(f"skill {self.name!r} is not invertible")
        motions = tuple(Motion(m.target, m.source, m.label) for m in reversed(self.motions))
        return Skill(
            f"{self.name}:reverse",
            self.final,
            self.initial,
            tuple(reversed(self.events)),
            motions,
            self.maneuver,
            True,
        )


def _check_rest(
    skill: Skill, poly: Polyhedron, event: ContactEvent, state: State, which: str
) -> None:
    """Ground contacts of the first (last) event must touch the initial (final) bottom face."""
    bottom = state.face
    for pair in event.pairs:
        if not isinstance(pair.x, Ground):
            continue
        el = pair.y
        ok = (
            (isinstance(el, Face) and el.id == bottom)
            or (isinstance(el, Edge) and bottom in el.faces)
            or (isinstance(el, Vertex) and any(
                bottom in poly.vertex_faces[i] for i in poly.shared_vertices(el.faces)
            ))
        )
        if not ok:
            raise SkillError(
                f"skill {skill.name!r}: its {which} event {event.id!r} puts {el} on the ground, "
                f"but in the {which} state {state} the object rests on face {bottom!r}"
            )


def check_skill(
    skill: Skill, poly: Polyhedron, *, angle_tol: float = DEFAULT_ANGLE_TOL
) -> None:
    """Validate a skill against the object.

    Every element must exist; the first and last events' ground contacts must agree with the
    initial and final states; the stated maneuver type must be the one the geometry gives.

    Raises
    ------
    SkillError
        Naming the skill and the element or state at fault.
    """
    for e in skill.events:
        try:
            check_event(e, poly)
        except ContactError as exc:
            raise SkillError(f"skill {skill.name!r}: {exc}") from None
    for s, which in ((skill.initial, "initial"), (skill.final, "final")):
        if s.face not in poly.faces:
            raise SkillError(
                f"skill {skill.name!r}: the {which} state {s} names face {s.face!r}, which "
                f"{poly.name!r} does not have; its faces are {list(poly.faces)}"
            )
    _check_rest(skill, poly, skill.events[0], skill.initial, "initial")
    _check_rest(skill, poly, skill.events[-1], skill.final, "final")
    kind = _geometric_kind(skill, poly, angle_tol)
    if kind != skill.maneuver:
        raise SkillError(
            f"skill {skill.name!r} says its maneuver is {skill.maneuver}, but the geometry of "
            f"{skill.initial} -> {skill.final} makes it {kind}; "
            + _right_finals(poly, skill.initial, skill.final, skill.maneuver, angle_tol)
        )


def _right_finals(poly: Polyhedron, initial: State, final: State, kind: str | None,
                  angle_tol: float) -> str:
    """Which final states the maneuvers from ``initial`` onto ``final``'s face really reach
    (of type ``kind`` when given), for a skill whose final state is wrong; where one lies
    within :data:`DRIFT_DEG` of ``final``, the model's rounding is the likelier fault (a
    model from a mesh), and the state as the model has it, or the angle tolerance, its fix."""
    face = final.face
    opts = [o for o in maneuvers_from(poly, initial, angle_tol=angle_tol)
            if kind is None or o.maneuver.kind == kind]
    onto = [o for o in opts if o.maneuver.end.face == face]
    if onto:
        # (the exact angles: a mesh's ``b:359.999989973`` prints as ``b:0``)
        listed = ", ".join(f"{o.maneuver.end.exact()} ({o.maneuver.kind} over {o.element})"
                           for o in onto[:6])
        near = min(onto, key=lambda o: abs(angle_diff(o.maneuver.end.theta, final.theta)))
        off = abs(angle_diff(near.maneuver.end.theta, final.theta))
        if angle_tol < off < DRIFT_DEG:
            # not every command that reads a skills file takes --angle-tol (simulate
            # record, dataset show): the exact state is the fix that works with all
            return (f"{kind or 'a maneuver'} from {initial} onto face {face!r} ends in "
                    f"{listed}, {off:.2g} degrees from {final.exact()}: more than the angle "
                    f"tolerance {angle_tol:g} degrees, the model's rounding (a model from a "
                    f"mesh carries its file's): write the final state as the model has it, "
                    f"{near.maneuver.end.exact()}, or raise the tolerance where the command "
                    f"takes one "
                    f"(--angle-tol, e.g. {suggest_angle_tol(off):g})")
        return (f"{kind or 'a maneuver'} from {initial} onto face {face!r} ends in {listed}: "
                f"write that final state (`nonprehensile maneuvers MODEL --from {initial}` "
                "lists them all)")
    ends = ", ".join(sorted({str(o.maneuver.end) for o in opts})[:12])
    return (f"no {kind or 'maneuver'} from {initial} lands on face {face!r}; it reaches {ends} "
            f"(`nonprehensile maneuvers MODEL --from {initial}` lists them all)")


def _geometric_kind(skill: Skill, poly: Polyhedron, angle_tol: float) -> ManeuverType:
    try:
        return classify(poly, skill.initial, skill.final, angle_tol=angle_tol).kind
    except ManeuverError as exc:
        raise SkillError(
            f"skill {skill.name!r}: {exc}; "
            + _right_finals(poly, skill.initial, skill.final, skill.maneuver, angle_tol)
        ) from None


def skill_from_dict(
    data: Any, poly: Polyhedron, *, angle_tol: float = DEFAULT_ANGLE_TOL
) -> Skill:
    """Read one skill of the skills file (docs/files.md) and validate it.

    ``maneuver`` may be omitted (it is then read from the geometry); ``invertible`` defaults
    to false; a motion may carry a ``label``.

    Raises
    ------
    SkillError
        Naming the skill and the culprit.
    """
    if not isinstance(data, Mapping):
        raise SkillError(f"a skill must be a JSON/YAML object, got {data!r}")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise SkillError(f"a skill needs a non-empty 'name', got {data!r:.80}")
    if ":" in name:
        # NAME:reverse names the reverse of an invertible skill: a user name must not clash
        raise SkillError(f"skill {name!r}: a skill name may not contain ':'; rename it")
    known = {"name", "initial", "final", "maneuver", "invertible", "events", "motions"}
    unknown = sorted({str(k) for k in data} - known)
    if unknown:
        raise SkillError(f"skill {name!r}: unknown key(s) {unknown}; a skill has {sorted(known)}")
    missing = [k for k in ("initial", "final", "events", "motions") if k not in data]
    if missing:
        raise SkillError(f"skill {name!r}: missing key(s) {missing}")
    try:
        initial = State.from_dict(data["initial"])
        final = State.from_dict(data["final"])
    except Exception as exc:
        raise SkillError(f"skill {name!r}: {exc}") from None
    raw_events = data["events"]
    if not isinstance(raw_events, Sequence) or isinstance(raw_events, str):
        raise SkillError(f"skill {name!r}: 'events' must be a list of {{id, contacts}}")
    events = []
    for i, ev in enumerate(raw_events):
        if not isinstance(ev, Mapping) or "id" not in ev or "contacts" not in ev:
            raise SkillError(
                f'skill {name!r}: event {i} must be {{"id": ..., "contacts": [...]}}, got {ev!r}'
            )
        try:
            events.append(parse_event(ev["contacts"], str(ev["id"])))
        except ContactError as exc:
            raise SkillError(f"skill {name!r}: {exc}") from None
    raw_motions = data["motions"]
    if not isinstance(raw_motions, Sequence) or isinstance(raw_motions, str):
        raise SkillError(f"skill {name!r}: 'motions' must be a list of {{from, to}}")
    motions = []
    for i, m in enumerate(raw_motions):
        if not isinstance(m, Mapping) or "from" not in m or "to" not in m:
            raise SkillError(
                f'skill {name!r}: motion {i} must be {{"from": ..., "to": ...}}, got {m!r}'
            )
        motions.append(Motion(str(m["from"]), str(m["to"]), str(m.get("label", ""))))
    invertible = data.get("invertible", False)
    if not isinstance(invertible, bool):
        raise SkillError(f"skill {name!r}: 'invertible' must be true or false")
    maneuver = data.get("maneuver")
    if maneuver is None:
        try:
            maneuver = classify(poly, initial, final, angle_tol=angle_tol).kind
        except ManeuverError as exc:
            raise SkillError(f"skill {name!r}: {exc}; "
                             + _right_finals(poly, initial, final, None, angle_tol)
                             ) from None
    skill = Skill(name, initial, final, tuple(events), tuple(motions), maneuver, invertible)
    check_skill(skill, poly, angle_tol=angle_tol)
    return skill


def events_to_dicts(events: Sequence[ContactEvent]) -> list[dict[str, Any]]:
    """Events in the skills file's form ``{"id": ..., "contacts": ["(R1,f)", ...]}``."""
    return [{"id": e.id, "contacts": format_event(e)} for e in events]


def skill_to_dict(skill: Skill) -> dict[str, Any]:
    """The skills file's form of a skill."""
    return {
        "name": skill.name,
        "initial": skill.initial.to_dict(),
        "final": skill.final.to_dict(),
        "maneuver": skill.maneuver,
        "invertible": skill.invertible,
        "events": events_to_dicts(skill.events),
        "motions": [m.to_dict() for m in skill.motions],
    }


def _symmetry_to(
    poly: Polyhedron, skill: Skill, ref: Skill, atol: float | None, angle_tol: float
) -> Symmetry | None:
    """The symmetry taking ``skill``'s transition onto ``ref``'s, if they are one maneuver."""
    for s in rotation_group(poly, atol):
        if apply_to_state(poly, s, skill.initial).isclose(ref.initial, angle_tol):
            return s if apply_to_state(poly, s, skill.final).isclose(ref.final, angle_tol) else None
    return None


def group_by_maneuver(
    poly: Polyhedron,
    skills: Sequence[Skill],
    *,
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[list[Skill]]:
    """Group skills that realise the same maneuver (the same transition up to symmetry)."""
    groups: list[list[Skill]] = []
    for skill in skills:
        for grp in groups:
            if _symmetry_to(poly, skill, grp[0], atol, angle_tol) is not None:
                grp.append(skill)
                break
        else:
            groups.append([skill])
    return groups


def skill_graph(
    poly: Polyhedron,
    skills: Sequence[Skill],
    *,
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> nx.MultiDiGraph:
    """The skill graph of one maneuver (paper Fig. 5(b)).

    The skills are brought to the labels of the first one through the symmetry that maps their
    transition onto its transition; they must all realise the same maneuver. Nodes are contact
    events, keyed by their contact pairs, so the same contacts in two skills are one node; arcs
    are motions, keyed by skill name, so skills that share events and move differently are
    parallel arcs.

    Returns
    -------
    networkx.MultiDiGraph
        Node attributes ``event`` (the :class:`ContactEvent` as first seen) and ``ids`` (the
        event IDs that name it); arc attributes ``skill`` and ``motion``.

    Raises
    ------
    SkillError
        If the skills do not all realise the same maneuver.
    """
    if not skills:
        raise SkillError("a skill graph needs at least one skill")
    ref = skills[0]
    g = nx.MultiDiGraph(maneuver=ref.maneuver, initial=ref.initial, final=ref.final)
    for skill in skills:
        sym = _symmetry_to(poly, skill, ref, atol, angle_tol)
        if sym is None:
            raise SkillError(
                f"skill {skill.name!r} ({skill.initial} -> {skill.final}) does not realise the "
                f"same maneuver as {ref.name!r} ({ref.initial} -> {ref.final})"
            )
        events = [map_event(e, sym.face_map) for e in skill.events]
        # a node is a set of contacts and how many times the chain met it before: a rotation
        # starts and ends on (G,a), which are two events, not a loop
        keys = [(e.pairs, sum(x.pairs == e.pairs for x in events[:i]))
                for i, e in enumerate(events)]
        for key, e in zip(keys, events, strict=True):
            if key not in g:
                g.add_node(key, event=e, ids={e.id})
            else:
                g.nodes[key]["ids"].add(e.id)
        for step in skill.steps():
            g.add_edge(keys[step.index], keys[step.index + 1], key=skill.name,
                       skill=skill.name, motion=step.motion)
    return g
