"""Inferring undemonstrated transitions and adapted skills (paper Section V).

A demonstrated skill takes the object from ``{F_i, theta_i}`` to ``{F_f, theta_f}``. Applied to
a geometrically equivalent initial state ``{F̄_i, θ̄_i}`` (the object occupies the same space,
only its labels differ), the same finger motions give an equivalent final state, and every face
named in the skill maps to its equivalent face.

Two methods:

``exact`` (default)
    Through the object's proper rotation symmetry group ``G``. For each ``g`` in ``G``, the
    state ``g . {F_i, theta_i}`` is equivalent to the demonstration; if it is in the state set,
    the transition is inferred with final state ``g . {F_f, theta_f}`` and face map ``g``. It
    finds all and only the truly equivalent states, maps faces, edges and vertices, and takes
    length and angle tolerances for measured models.

``paper``
    The paper's method, faithfully: the shortest chain of adjacent faces from ``F_i`` to each
    face of interest, edge-index arithmetic along it with modular indices, and the paper's
    final-orientation formula ``θ̄_f = Δ_{F̄_f}[A(F_f, F_N*) - A(F̄_f, F̄_N*) + 1] + θ_f``.
    Two known limits (see :func:`cross_check` and ``docs/inference.md``): the formula reads
    ``Δ`` of ``F̄_f`` where the edge-index shift refers to ``F_f``, which matters when a
    face's edge angles are not all equal; and nothing tells a rectangle from a square, so on a
    1 x 1 x 2 box it accepts initial states that are not equivalent.
"""

from __future__ import annotations

import gc
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Literal

import networkx as nx

from nonprehensile.checks import check_tolerance
from nonprehensile.equivalence import apply_to_state
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron, wrap_index
from nonprehensile.geometry.symmetry import rotation_group
from nonprehensile.skills.skill import Skill, events_to_dicts
from nonprehensile.states import DEFAULT_ANGLE_TOL, State, StateIndex, angles_close
from nonprehensile.transitions import Transition, TransitionGraph

__all__ = [
    "METHODS",
    "Disagreement",
    "Expansion",
    "InferredTransition",
    "Method",
    "cross_check",
    "expand",
    "infer",
    "infer_exact",
    "infer_paper",
    "paper_chains",
    "paper_face_map",
]

Method = Literal["exact", "paper"]
METHODS: tuple[Method, ...] = ("exact", "paper")


@dataclass(frozen=True)
class InferredTransition:
    """A transition obtained by applying a skill to an equivalent initial state.

    Attributes
    ----------
    skill : Skill
        The adapted skill: initial and final states and events with mapped faces (Fig. 8).
    source : Skill
        The demonstrated skill it comes from (or its reverse, for an invertible skill).
    mapping : mapping of str to str
        Every face the source skill names, to its equivalent face here.
    demonstrated : bool
        True for the demonstration itself (identity mapping, same initial state).
    """

    skill: Skill
    source: Skill
    mapping: Mapping[str, str]
    demonstrated: bool

    @property
    def start(self) -> State:
        """Initial state."""
        return self.skill.initial

    @property
    def end(self) -> State:
        """Final state (exact, even outside the state set)."""
        return self.skill.final

    def to_dict(self) -> dict[str, Any]:
        """The spec's JSON form (``nonprehensile infer --json``)."""
        return {
            "from": self.start.to_dict(),
            "to": self.end.to_dict(),
            "skill": self.skill.name,
            "maneuver": self.skill.maneuver,
            "demonstrated": self.demonstrated,
            "mapping": dict(sorted(self.mapping.items())),
            "events": events_to_dicts(self.skill.events),
        }

    def transition(self) -> Transition:
        """The arc of the state-transition graph, with mapping and events as its info."""
        d = self.to_dict()
        return Transition(
            self.start, self.end, self.skill.name, self.skill.maneuver, self.demonstrated,
            {"mapping": d["mapping"], "events": d["events"]},
        )


def _with_reverses(skills: Iterable[Skill]) -> list[Skill]:
    out = []
    for s in skills:
        out.append(s)
        if s.invertible:
            out.append(s.reversed())
    return out


def _is_demo(skill: Skill, start: State, identity: bool, angle_tol: float) -> bool:
    return identity and not skill.name.endswith(":reverse") and start.isclose(
        skill.initial, angle_tol
    )


def infer_exact(
    poly: Polyhedron,
    skill: Skill,
    states: Sequence[State],
    *,
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
    index: StateIndex | None = None,
) -> list[InferredTransition]:
    """Every transition of ``skill`` from an equivalent initial state in ``states`` (exact).

    Parameters
    ----------
    poly : Polyhedron
    skill : Skill
        The demonstrated skill.
    states : sequence of State
        The state set (candidate initial states).
    atol : float, optional
        Length tolerance of the symmetry group (default the model's).
    angle_tol : float
        Angle tolerance in degrees for matching states.
    index : StateIndex, optional
        A prebuilt index of ``states`` (saves rebuilding it for many skills).

    Returns
    -------
    list of InferredTransition
        In the order of ``states``.
    """
    index = index or StateIndex(states)
    faces = skill.faces()
    found: dict[int, InferredTransition] = {}
    for n, g in enumerate(rotation_group(poly, atol)):
        start = apply_to_state(poly, g, skill.initial)
        for i in index.find_all(start, angle_tol):
            if i in found:
                continue
            mapping = {f: g.face_map[f] for f in faces}
            adapted = skill.mapped(g.face_map, states[i], apply_to_state(poly, g, skill.final))
            found[i] = InferredTransition(
                adapted, skill, mapping, _is_demo(skill, states[i], n == 0, angle_tol)
            )
    return [found[i] for i in sorted(found)]


@lru_cache(maxsize=64)
def _face_graph(poly: Polyhedron) -> nx.Graph:
    g = nx.Graph()
    for f, row in poly.adjacency.items():
        for h in row:
            g.add_edge(f, h)
    return g


def _row_lookup(poly: Polyhedron, face: str, index: int) -> str | None:
    """The column of ``face``'s row of ``A`` holding ``index`` (the paper's "search")."""
    for h, k in poly.adjacency[face].items():
        if k == index:
            return h
    return None


def paper_face_map(
    poly: Polyhedron,
    demo_initial: State,
    new_initial: State,
    faces: Iterable[str],
    *,
    angle_tol: float = DEFAULT_ANGLE_TOL,
    chains: Mapping[str, Sequence[str]] | None = None,
) -> tuple[dict[str, str], dict[str, int]] | None:
    """The paper's Section V steps 1 to 3: equivalent faces through chains of adjacent faces.

    Parameters
    ----------
    poly : Polyhedron
    demo_initial : State
        ``{F_i, theta_i}`` of the demonstration.
    new_initial : State
        ``{F̄_i, θ̄_i}``.
    faces : iterable of str
        Faces of interest ``F_x``.
    angle_tol : float
        Tolerance for finding ``δ_k = θ̄_i - θ_i`` in ``Δ_{F_i}``.
    chains : mapping of str to sequence of str, optional
        The step-1 chains from ``F_i`` to each face of interest (:func:`paper_chains`); they
        depend only on the demonstration, so a caller trying many candidates passes them once.

    Returns
    -------
    (mapping, shift) or None
        ``mapping[F_x] = F̄_x``; ``shift[F_x]`` is the edge-index difference between ``F_x``
        and ``F̄_x`` (``A(F_x, F_N*) - A(F̄_x, F̄_N*)``, or ``k - 1`` for ``F_i``), so edge
        ``m`` of ``F_x`` is edge ``m - shift`` of ``F̄_x``. None when a step finds nothing:
        ``δ`` is not in ``Δ_{F_i}``, or an index is not in a row of ``A``.
    """
    f_i, fb_i = demo_initial.face, new_initial.face
    n = poly.n_edges(f_i)
    if poly.n_edges(fb_i) != n:
        return None
    delta = (new_initial.theta - demo_initial.theta) % 360.0
    # step 2: search δ_k in Δ_{F_i}
    k = next(
        (j for j, d in enumerate(poly.delta[f_i], start=1) if angles_close(d, delta, angle_tol)),
        None,
    )
    if k is None:
        return None
    faces = list(faces)
    if chains is None:
        chains = paper_chains(poly, f_i, faces)
    mapping = {f_i: fb_i}
    shift = {f_i: k - 1}
    for x in faces:
        if x in mapping:
            continue
        prev, prev_bar, s = f_i, fb_i, k - 1
        for nxt in chains[x][1:]:
            idx_bar = wrap_index(poly.adjacency[prev][nxt] - s, poly.n_edges(prev_bar))
            nxt_bar = _row_lookup(poly, prev_bar, idx_bar)
            if nxt_bar is None:
                return None
            # step 3: the index difference carried to the next face of the chain
            s = poly.adjacency[nxt][prev] - poly.adjacency[nxt_bar][prev_bar]
            prev, prev_bar = nxt, nxt_bar
        mapping[x] = prev_bar
        shift[x] = s
    return mapping, shift


def paper_chains(poly: Polyhedron, start: str, faces: Iterable[str]) -> dict[str, list[str]]:
    """Step 1: the shortest chain of adjacent faces (an unweighted Dijkstra, i.e. BFS) from
    ``start`` to each of ``faces``."""
    graph = _face_graph(poly)
    return {x: nx.shortest_path(graph, start, x) for x in faces}


def infer_paper(
    poly: Polyhedron,
    skill: Skill,
    states: Sequence[State],
    *,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[InferredTransition]:
    """Every transition of ``skill`` that the paper's method infers over ``states``.

    Each state of the set is a candidate ``{F̄_i, θ̄_i}``; it is accepted when the method's
    steps succeed for every face the skill names. The final orientation follows the paper's
    formula ``θ̄_f = Δ_{F̄_f}[A(F_f, F_N*) - A(F̄_f, F̄_N*) + 1] + θ_f``. The chains of step 1
    are found once per skill, and only the faces the skill names are mapped, so the work per
    candidate does not grow with the number of faces.
    """
    faces = sorted(skill.faces())
    chains = paper_chains(poly, skill.initial.face, faces)
    n_i = poly.n_edges(skill.initial.face)
    out = []
    for s in states:
        if poly.n_edges(s.face) != n_i:
            continue
        got = paper_face_map(poly, skill.initial, s, faces, angle_tol=angle_tol, chains=chains)
        if got is None:
            continue
        mapping, shift = got
        f_f = skill.final.face
        fb_f = mapping[f_f]
        theta_f = poly.delta[fb_f][wrap_index(shift[f_f] + 1, poly.n_edges(fb_f)) - 1]
        final = State(fb_f, theta_f + skill.final.theta)
        adapted = skill.mapped(mapping, s, final)
        demo = _is_demo(skill, s, all(mapping[f] == f for f in faces), angle_tol)
        out.append(InferredTransition(adapted, skill, mapping, demo))
    return out


def infer(
    poly: Polyhedron,
    skill: Skill,
    states: Sequence[State],
    *,
    method: Method = "exact",
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
    index: StateIndex | None = None,
) -> list[InferredTransition]:
    """Transitions of one skill over a state set, by ``method`` (``"exact"`` or ``"paper"``).

    ``index`` is a prebuilt :class:`StateIndex` of ``states`` (the exact method uses it).
    """
    angle_tol = check_tolerance(angle_tol, "angle_tol", allow_zero=True)
    if method == "exact":
        return infer_exact(poly, skill, states, atol=atol, angle_tol=angle_tol, index=index)
    if method == "paper":
        return infer_paper(poly, skill, states, angle_tol=angle_tol)
    raise InputError(f"inference method must be one of {list(METHODS)}, got {method!r}")


@dataclass
class Expansion:
    """The expanded state-transition graph and the adapted skill of every arc.

    Attributes
    ----------
    graph : TransitionGraph
        States of the set (and final states reached outside it) and every transition.
    transitions : list of InferredTransition
        In order: skill by skill, then by initial state.
    method : str
        The inference method used.
    state_set : tuple of State
        The state set it was expanded over (empty when not given: an expansion made by
        hand).
    angle_tol : float
        The angle tolerance it was expanded with, degrees: a re-plan over it matches states
        as the expansion did.
    """

    graph: TransitionGraph
    transitions: list[InferredTransition]
    method: Method
    state_set: tuple[State, ...] = ()
    angle_tol: float = DEFAULT_ANGLE_TOL
    _by_arc: dict[tuple[State, State, str], InferredTransition] = field(
        default_factory=dict, repr=False
    )

    def __post_init__(self) -> None:
        self._by_arc = {(t.start, t.end, t.skill.name): t for t in self.transitions}

    def adapted(self, start: State, end: State, skill: str) -> InferredTransition:
        """The inferred transition behind an arc of the graph."""
        return self._by_arc[(start, end, skill)]

    def to_dict(self, object_name: str) -> dict[str, Any]:
        """The spec's ``nonprehensile infer --json`` document."""
        return {
            "object": object_name,
            "method": self.method,
            "states": [s.to_dict() for s in self.graph.states],
            "transitions": [t.to_dict() for t in self.transitions],
        }


@contextmanager
def _collector_paused() -> Iterator[None]:
    """Pause CPython's cyclic garbage collector while a large expansion is built.

    An expansion allocates millions of small container objects (states, face maps, adapted
    events, arcs) that all stay alive. Every few thousand allocations the generational
    collector walks the survivors again, so without the pause building it is super-linear in
    the state set (at 10,000 faces the collector took 37 % of the paper's method and 37 % of
    the exact one). Nothing built here needs collecting: the objects form no cycles that
    become garbage while the expansion is built. The collector is resumed (if it was running)
    when the block ends, even on an error.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def expand(
    poly: Polyhedron,
    skills: Sequence[Skill],
    states: Sequence[State],
    *,
    method: Method = "exact",
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> Expansion:
    """Expand demonstrated skills over a state set (paper Fig. 7).

    Invertible skills also give their reverse transitions (events run backwards).

    Parameters
    ----------
    poly : Polyhedron
    skills : sequence of Skill
        The demonstrated skills.
    states : sequence of State
        The state set.
    method : {"exact", "paper"}
    atol, angle_tol : float
        Tolerances (see :func:`infer_exact`).

    Returns
    -------
    Expansion
    """
    with _collector_paused():
        graph = TransitionGraph(states)
        found: list[InferredTransition] = []
        index = StateIndex(states)
        for skill in _with_reverses(skills):
            found.extend(infer(poly, skill, states, method=method, atol=atol,
                               angle_tol=angle_tol, index=index))
        for t in found:
            graph.add(t.transition())
        return Expansion(graph, found, method, tuple(states), angle_tol)


@dataclass(frozen=True)
class Disagreement:
    """Where the paper's method and the exact one differ for a skill and an initial state.

    Attributes
    ----------
    skill : str
    start : State
    kind : {"only_exact", "only_paper", "final", "mapping"}
        Inferred by one method only, or by both with different final states or face maps.
    exact, paper : str
        What each method gave (empty when it gave nothing).
    """

    skill: str
    start: State
    kind: str
    exact: str
    paper: str

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"skill": self.skill, "from": self.start.to_dict(), "kind": self.kind,
                "exact": self.exact, "paper": self.paper}


def cross_check(
    poly: Polyhedron,
    skills: Sequence[Skill],
    states: Sequence[State],
    *,
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[Disagreement]:
    """Report every (skill, initial state) where the paper's method and the exact one differ."""
    out = []
    for skill in _with_reverses(skills):
        ex = {t.start: t for t in infer_exact(poly, skill, states, atol=atol,
                                               angle_tol=angle_tol)}
        pa = {t.start: t for t in infer_paper(poly, skill, states, angle_tol=angle_tol)}
        for s in [s for s in states if s in ex or s in pa]:
            e, p = ex.get(s), pa.get(s)
            if e is None or p is None:
                kind = "only_paper" if e is None else "only_exact"
                out.append(Disagreement(skill.name, s, kind, str(e.end) if e else "",
                                        str(p.end) if p else ""))
            elif not e.end.isclose(p.end, angle_tol):
                out.append(Disagreement(skill.name, s, "final", str(e.end), str(p.end)))
            elif dict(e.mapping) != dict(p.mapping):
                out.append(Disagreement(skill.name, s, "mapping", _fmt_map(e.mapping),
                                        _fmt_map(p.mapping)))
    return out


def _fmt_map(m: Mapping[str, str]) -> str:
    return ", ".join(f"{k}->{v}" for k, v in sorted(m.items()))
