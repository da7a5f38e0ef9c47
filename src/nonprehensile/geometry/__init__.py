"""The object model (paper Section III): polyhedra, their builders and their symmetry."""

from nonprehensile.geometry.build import (
    box,
    convex_hull,
    cube,
    face_name,
    from_mesh,
    octahedron,
    prism,
    tetrahedron,
)
from nonprehensile.geometry.polyhedron import DEFAULT_RTOL, Polyhedron, check_polyhedron, wrap_index
from nonprehensile.geometry.symmetry import Symmetry, rotation_group

__all__ = [
    "DEFAULT_RTOL",
    "Polyhedron",
    "Symmetry",
    "box",
    "check_polyhedron",
    "convex_hull",
    "cube",
    "face_name",
    "from_mesh",
    "octahedron",
    "prism",
    "rotation_group",
    "tetrahedron",
    "wrap_index",
]
