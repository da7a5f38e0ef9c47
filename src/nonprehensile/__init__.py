"""nonprehensile: learn nonprehensile manipulation of polyhedral objects from demonstration.

The package reads like the paper's list of models (Integrated Object, Skill, and Motion Models
for Nonprehensile Manipulation):

* :mod:`nonprehensile.geometry`: the object model (Section III) and its symmetry;
* :mod:`nonprehensile.states`: states ``{F_b, theta}`` and their poses (Section II);
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
"""

from nonprehensile.errors import (
    GeometryError,
    InputError,
    ManeuverError,
    MeshError,
    ModelError,
    NonprehensileError,
    StateError,
)
from nonprehensile.geometry import (
    Polyhedron,
    Symmetry,
    box,
    convex_hull,
    cube,
    equivalence_classes,
    equivalent,
    from_mesh,
    octahedron,
    prism,
    rotation_group,
    tetrahedron,
)
from nonprehensile.inference import Expansion, cross_check, expand
from nonprehensile.io import load_model, read_model, read_skills, read_states, write_model
from nonprehensile.maneuvers import Maneuver, classify, roll, rotate, tumble
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
    "is_stable",
    "load_model",
    "octahedron",
    "parse_event",
    "plan",
    "prism",
    "read_model",
    "read_skills",
    "read_states",
    "roll",
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
