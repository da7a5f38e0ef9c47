"""The state-transition graph (paper Section II, Fig. 7).

A digraph whose nodes are states and whose arcs are transitions realised by skills. Several
skills may realise the same transition, so the graph is a :class:`networkx.MultiDiGraph`
keyed by skill name. It holds state (arcs are added as demonstrations and inferences come in),
so it is a class; its nodes and arcs are values.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import networkx as nx

from nonprehensile.errors import InputError
from nonprehensile.maneuvers import MANEUVER_TYPES, ManeuverType
from nonprehensile.states import State

__all__ = ["Transition", "TransitionGraph"]


@dataclass(frozen=True)
class Transition:
    """An arc of the state-transition graph.

    Attributes
    ----------
    start, end : State
        Initial and final states.
    skill : str
        Name of the skill that realises it.
    maneuver : {"rolling", "rotating", "tumbling"}
        Maneuver type.
    demonstrated : bool
        True if shown by a mentor, False if inferred.
    info : dict
        Anything else a producer wants to keep with the arc (e.g. the face mapping of an
        inferred skill); not compared.
    """

    start: State
    end: State
    skill: str
    maneuver: ManeuverType
    demonstrated: bool = True
    info: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    def __post_init__(self) -> None:
        if self.maneuver not in MANEUVER_TYPES:
            raise InputError(
                f"transition {self.start} -> {self.end} ({self.skill}): maneuver must be one "
                f"of {list(MANEUVER_TYPES)}, got {self.maneuver!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        """The spec's JSON form of a transition (plus ``info`` entries)."""
        out: dict[str, Any] = {
            "from": self.start.to_dict(),
            "to": self.end.to_dict(),
            "skill": self.skill,
            "maneuver": self.maneuver,
            "demonstrated": self.demonstrated,
        }
        out.update(self.info)
        return out

    @classmethod
    def from_dict(cls, data: Any) -> Transition:
        """Read the form written by :meth:`to_dict`."""
        if not isinstance(data, dict):
            raise InputError(f"a transition must be a JSON object, got {data!r}")
        missing = [k for k in ("from", "to", "skill", "maneuver") if k not in data]
        if missing:
            raise InputError(f"transition {data!r} lacks keys {missing}")
        info = {
            k: v
            for k, v in data.items()
            if k not in ("from", "to", "skill", "maneuver", "demonstrated")
        }
        demonstrated = data.get("demonstrated", True)
        if not isinstance(demonstrated, bool):
            raise InputError(f"transition {data!r}: 'demonstrated' must be true or false")
        return cls(
            State.from_dict(data["from"]),
            State.from_dict(data["to"]),
            str(data["skill"]),
            data["maneuver"],
            demonstrated,
            info,
        )


class TransitionGraph:
    """A digraph of states whose arcs are :class:`Transition` objects.

    Parameters
    ----------
    states : iterable of State, optional
        Nodes to start with (a state set); states reached by transitions are added as arcs
        are.

    Attributes
    ----------
    graph : networkx.MultiDiGraph
        The underlying graph: nodes are :class:`State`, arcs are keyed by skill name and carry
        the :class:`Transition` under ``"transition"``.
    """

    def __init__(self, states: Iterable[State] = ()) -> None:
        self.graph: nx.MultiDiGraph = nx.MultiDiGraph()
        self.graph.add_nodes_from(states)  # one call: add_node per state costs 3x more

    def add_state(self, state: State) -> None:
        """Add a node (no effect if present)."""
        self.graph.add_node(state)

    def add(self, t: Transition) -> None:
        """Add an arc; a second arc with the same ends and skill replaces the first, except
        that a demonstrated arc is never replaced by an inferred one."""
        old = self.graph.get_edge_data(t.start, t.end, key=t.skill)
        if old is not None and old["transition"].demonstrated and not t.demonstrated:
            return
        self.graph.add_edge(t.start, t.end, key=t.skill, transition=t)

    @property
    def states(self) -> list[State]:
        """Nodes, in insertion order."""
        return list(self.graph.nodes)

    def transitions(self) -> Iterator[Transition]:
        """Arcs, in insertion order."""
        for _, _, data in self.graph.edges(data=True):
            yield data["transition"]

    def __len__(self) -> int:
        return int(self.graph.number_of_edges())

    def successors(self, state: State) -> list[Transition]:
        """Transitions leaving ``state``."""
        if state not in self.graph:
            return []
        return [d["transition"] for _, _, d in self.graph.out_edges(state, data=True)]

    def adjacency_view(self) -> tuple[list[State], list[list[list[str]]]]:
        """The paper's Fig. 7(b): a matrix over states whose entries list the skills.

        Returns
        -------
        states : list of State
            Row and column labels.
        cells : list of list of list of str
            ``cells[i][j]`` names the skills taking ``states[i]`` to ``states[j]`` (empty
            where there is no transition).
        """
        states = self.states
        pos = {s: i for i, s in enumerate(states)}
        cells: list[list[list[str]]] = [[[] for _ in states] for _ in states]
        for t in self.transitions():
            cells[pos[t.start]][pos[t.end]].append(t.skill)
        return states, cells

    def to_dict(self) -> dict[str, Any]:
        """JSON form ``{"states": [...], "transitions": [...]}``."""
        return {
            "states": [s.to_dict() for s in self.states],
            "transitions": [t.to_dict() for t in self.transitions()],
        }

    @classmethod
    def from_dict(cls, data: Any) -> TransitionGraph:
        """Read the form written by :meth:`to_dict`."""
        if not isinstance(data, dict) or "states" not in data or "transitions" not in data:
            raise InputError(
                'a transition graph must be {"states": [...], "transitions": [...]}'
            )
        g = cls(State.from_dict(s) for s in data["states"])
        for t in data["transitions"]:
            g.add(Transition.from_dict(t))
        return g
