"""nonprehensile: learn nonprehensile manipulation of polyhedral objects from demonstration.

The package reads like the paper's list of models (Integrated Object, Skill, and Motion Models
for Nonprehensile Manipulation):

* :mod:`nonprehensile.geometry`: the object model (Section III) and its symmetry;
* :mod:`nonprehensile.states`: states ``{F_b, theta}`` and their poses (Section II);
* :mod:`nonprehensile.maneuvers`: exact rolling, rotating and tumbling (Section II);
* :mod:`nonprehensile.transitions`: the state-transition graph (Fig. 7);
* :mod:`nonprehensile.io`: the spec's model and state files.

Plotting (:mod:`nonprehensile.viz`) and the command line (:mod:`nonprehensile.cli`) sit at
the edges and are not imported here.
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
from nonprehensile.io import load_model, read_model, read_states, write_model
from nonprehensile.maneuvers import Maneuver, classify, roll, rotate, tumble
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
    "GeometryError",
    "InputError",
    "Maneuver",
    "ManeuverError",
    "MeshError",
    "ModelError",
    "NonprehensileError",
    "Polyhedron",
    "State",
    "StateError",
    "Symmetry",
    "Transition",
    "TransitionGraph",
    "__version__",
    "box",
    "classify",
    "convex_hull",
    "cube",
    "equivalence_classes",
    "equivalent",
    "from_mesh",
    "is_stable",
    "load_model",
    "octahedron",
    "prism",
    "read_model",
    "read_states",
    "roll",
    "rotate",
    "rotation_group",
    "stable_faces",
    "state_of_pose",
    "state_pose",
    "states_by_step",
    "tetrahedron",
    "tumble",
    "write_model",
]
