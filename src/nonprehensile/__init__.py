"""nonprehensile: learn nonprehensile manipulation of polyhedral objects from demonstration.

The package reads like the paper's list of models (Integrated Object, Skill, and Motion Models
for Nonprehensile Manipulation):

* :mod:`nonprehensile.geometry`: the object model (Section III) and its symmetry;
* :mod:`nonprehensile.states`: states ``{F_b, theta}`` and their poses (Section II);
* :mod:`nonprehensile.equivalence`: geometric equivalence of states (Section V);
* :mod:`nonprehensile.maneuvers`: exact rolling, rotating and tumbling (Section II);
* :mod:`nonprehensile.transitions`: the state-transition graph (Fig. 7);
* :mod:`nonprehensile.skills`: contact events and skills (Section IV);
* :mod:`nonprehensile.inference`: undemonstrated transitions and adapted skills (Section V);
* :mod:`nonprehensile.motion`: trajectories, the Hilbert index, clustering (Section VI);
* :mod:`nonprehensile.demonstrations`: recordings and datasets;
* :mod:`nonprehensile.planning`: plans with contact events and reference motions (Section VII);
* :mod:`nonprehensile.io`: the spec's model, state and skills files.

Plotting (:mod:`nonprehensile.viz`), the main job (:mod:`nonprehensile.pipeline`) and the
command line (:mod:`nonprehensile.cli`) sit at the edges and are not imported here.

The names below are imported on first use (PEP 562), so that ``import nonprehensile`` (and
``nonprehensile --help``) costs no numpy, scipy or networkx import.
"""

import importlib
from typing import TYPE_CHECKING, Any

from nonprehensile.errors import (
    GeometryError,
    InputError,
    ManeuverError,
    MeshError,
    ModelError,
    NonprehensileError,
    StateError,
)

if TYPE_CHECKING:
    from nonprehensile.equivalence import equivalence_classes, equivalent
    from nonprehensile.geometry import (
        Polyhedron,
        Symmetry,
        box,
        convex_hull,
        cube,
        from_mesh,
        octahedron,
        prism,
        rotation_group,
        tetrahedron,
    )
    from nonprehensile.geometry.units import in_metres
    from nonprehensile.inference import Expansion, cross_check, expand
    from nonprehensile.io import load_model, read_model, read_skills, read_states, write_model
    from nonprehensile.maneuvers import (
        Maneuver,
        ManeuverOption,
        classify,
        maneuvers_from,
        roll,
        roll_directions,
        rotate,
        tumble,
    )
    from nonprehensile.planning import NoPlanError, Plan, plan
    from nonprehensile.skills import ContactEvent, ContactPair, parse_event
    from nonprehensile.skills.skill import Skill, skill_graph
    from nonprehensile.states import (
        State,
        is_stable,
        stable_faces,
        state_of_pose,
        state_pose,
        states_by_step,
    )
    from nonprehensile.transitions import Transition, TransitionGraph

__version__ = "0.1.0"

__all__ = [
    "ContactEvent",
    "ContactPair",
    "Expansion",
    "GeometryError",
    "InputError",
    "Maneuver",
    "ManeuverError",
    "ManeuverOption",
    "MeshError",
    "ModelError",
    "NoPlanError",
    "NonprehensileError",
    "Plan",
    "Polyhedron",
    "Skill",
    "State",
    "StateError",
    "Symmetry",
    "Transition",
    "TransitionGraph",
    "__version__",
    "box",
    "classify",
    "convex_hull",
    "cross_check",
    "cube",
    "equivalence_classes",
    "equivalent",
    "expand",
    "from_mesh",
    "in_metres",
    "is_stable",
    "load_model",
    "maneuvers_from",
    "octahedron",
    "parse_event",
    "plan",
    "prism",
    "read_model",
    "read_skills",
    "read_states",
    "roll",
    "roll_directions",
    "rotate",
    "rotation_group",
    "skill_graph",
    "stable_faces",
    "state_of_pose",
    "state_pose",
    "states_by_step",
    "tetrahedron",
    "tumble",
    "write_model",
]

#: Public name -> module it is imported from on first use.
_LAZY = {
    "Polyhedron": "nonprehensile.geometry",
    "Symmetry": "nonprehensile.geometry",
    "box": "nonprehensile.geometry",
    "convex_hull": "nonprehensile.geometry",
    "cube": "nonprehensile.geometry",
    "equivalence_classes": "nonprehensile.equivalence",
    "equivalent": "nonprehensile.equivalence",
    "from_mesh": "nonprehensile.geometry",
    "in_metres": "nonprehensile.geometry.units",
    "octahedron": "nonprehensile.geometry",
    "prism": "nonprehensile.geometry",
    "rotation_group": "nonprehensile.geometry",
    "tetrahedron": "nonprehensile.geometry",
    "Expansion": "nonprehensile.inference",
    "cross_check": "nonprehensile.inference",
    "expand": "nonprehensile.inference",
    "load_model": "nonprehensile.io",
    "read_model": "nonprehensile.io",
    "read_skills": "nonprehensile.io",
    "read_states": "nonprehensile.io",
    "write_model": "nonprehensile.io",
    "Maneuver": "nonprehensile.maneuvers",
    "ManeuverOption": "nonprehensile.maneuvers",
    "classify": "nonprehensile.maneuvers",
    "maneuvers_from": "nonprehensile.maneuvers",
    "roll": "nonprehensile.maneuvers",
    "roll_directions": "nonprehensile.maneuvers",
    "rotate": "nonprehensile.maneuvers",
    "tumble": "nonprehensile.maneuvers",
    "NoPlanError": "nonprehensile.planning",
    "Plan": "nonprehensile.planning",
    "plan": "nonprehensile.planning",
    "ContactEvent": "nonprehensile.skills",
    "ContactPair": "nonprehensile.skills",
    "parse_event": "nonprehensile.skills",
    "Skill": "nonprehensile.skills.skill",
    "skill_graph": "nonprehensile.skills.skill",
    "State": "nonprehensile.states",
    "is_stable": "nonprehensile.states",
    "stable_faces": "nonprehensile.states",
    "state_of_pose": "nonprehensile.states",
    "state_pose": "nonprehensile.states",
    "states_by_step": "nonprehensile.states",
    "Transition": "nonprehensile.transitions",
    "TransitionGraph": "nonprehensile.transitions",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'nonprehensile' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
