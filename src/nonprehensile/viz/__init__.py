"""Figures (the edge of the package): matplotlib is imported only inside the functions.

Install the ``viz`` extra (``pip install 'nonprehensile[viz]'``) to use them.
"""

from nonprehensile.viz._figures import save_figure
from nonprehensile.viz.graphs import (
    plot_skill_graph,
    plot_state_graph,
    plot_transition_matrix,
    skill_graphs_figure,
    state_graph_figure,
)
from nonprehensile.viz.labeled_object import (
    default_view,
    object_figure,
    plot_adjacency,
    plot_delta,
    plot_object,
    view_direction,
)

__all__ = [
    "default_view",
    "object_figure",
    "plot_adjacency",
    "plot_delta",
    "plot_object",
    "plot_skill_graph",
    "plot_state_graph",
    "plot_transition_matrix",
    "save_figure",
    "skill_graphs_figure",
    "state_graph_figure",
    "view_direction",
]
