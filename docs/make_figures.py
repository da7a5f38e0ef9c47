"""Regenerate the figures of the docs (docs/img/*.png): ``python docs/make_figures.py``.

Needs the ``viz`` extra (matplotlib) and, for the L-shaped block read from a mesh, the
``mesh`` extra (trimesh). Every figure is a :class:`matplotlib.figure.Figure` saved with the
Agg renderer, so no display is needed. This script sits at the edge, like ``examples/``, so it
may plot (pyproject.toml exempts ``docs/`` from the core's import bans).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

import nonprehensile as nph
from nonprehensile.inference import expand, infer_exact
from nonprehensile.io import read_skills
from nonprehensile.skills.skill import group_by_maneuver, skill_graph
from nonprehensile.viz import (
    default_view,
    object_figure,
    plot_object,
    plot_skill_graph,
    state_graph_figure,
    view_direction,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

IMG = Path(__file__).resolve().parent / "img"
DPI = 100
#: The graph figures are large; a lower resolution keeps the PNGs small.
GRAPH_DPI = 80


def l_block() -> nph.Polyhedron:
    """An L-shaped block (not convex) read from a mesh file, as a user would make one.

    The L lies in the ``xz`` plane (a foot 2 long along ``x``, a leg 2 high along ``z``, both
    0.5 thick) and is 1 deep along ``y``. Its convex hull closes the notch with a slanted
    face that is not a face of the mesh: a virtual face, on which the block rests on two
    edges.
    """
    import trimesh  # the `mesh` extra; only this figure needs it

    outline = np.array([(0, 0), (2, 0), (2, 0.5), (0.5, 0.5), (0.5, 2), (0, 2)], dtype=float)
    n = len(outline)
    front = np.column_stack([outline[:, 0], np.zeros(n), outline[:, 1]])
    back = front + np.array([0.0, 1.0, 0.0])
    # the L is star-shaped from its corner (0, 0), so a fan from it triangulates each cap
    cap = [(0, i, i + 1) for i in range(1, n - 1)]
    sides = []
    for i in range(n):
        j = (i + 1) % n
        sides += [(i, j, j + n), (i, j + n, i + n)]
    triangles = cap + [(a + n, c + n, b + n) for a, b, c in cap] + sides
    mesh = trimesh.Trimesh(np.vstack([front, back]), np.array(triangles), process=True)
    mesh.fix_normals()  # outward, whatever the hand-written winding
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "l-block.stl"
        mesh.export(path)
        return nph.from_mesh(path, name="l-block")


def vertex_views(poly: nph.Polyhedron) -> Figure:
    """Two opposite views with vertex indices: the numbers the model file's loops use."""
    first = default_view(poly)
    second = (-first[0], (first[1] + 360.0) % 360.0 - 180.0)
    facing = [f for f in poly.faces if poly.normals[f] @ view_direction(first) > 0]
    fig = Figure(figsize=(10.0, 5.2), layout="constrained")
    for col, (view, faces) in enumerate(
        ((first, facing), (second, [f for f in poly.faces if f not in facing]))
    ):
        ax = fig.add_subplot(1, 2, col + 1, projection="3d")
        plot_object(
            poly, ax, view=view, labeled_faces=faces, show_vertices=True, legend=False
        )
        ax.set_title(f"faces {', '.join(faces)} (elev {view[0]:g}°, azim {view[1]:g}°)")
    fig.suptitle(f"{poly.name}: vertex indices (italic) used by the face loops")
    return fig


def skill_figure(graph: object, height: float) -> Figure:
    fig = Figure(figsize=(12.0, height), layout="constrained")
    plot_skill_graph(graph, fig.add_subplot())  # type: ignore[arg-type]
    return fig


def inference_figures() -> dict[str, Figure]:
    """The paper's Fig. 5(b), 7 and 8 on the bundled cube skills (``docs/inference.md``)."""
    cube, skills = read_skills(EXAMPLES / "cube_skills.json")
    exp = expand(cube, skills, nph.states_by_step(cube, 90))
    rolling, tumbling = group_by_maneuver(cube, skills)[:2]
    (adapted,) = infer_exact(cube, skills[0], [nph.State("a", 90)])
    return {
        "cube-state-graph.png": state_graph_figure(exp, skills=["push-roll", "twist"]),
        "cube-skill-graph-rolling.png": skill_figure(skill_graph(cube, rolling), 4.0),
        "cube-skill-graph-tumbling.png": skill_figure(skill_graph(cube, tumbling), 4.0),
        "cube-adapted-skill.png": skill_figure(skill_graph(cube, [adapted.skill]), 2.6),
    }


def dataset_figures() -> dict[str, Figure]:
    """The paper's Fig. 12(a) on the bundled demonstrations (``docs/dataset.md``)."""
    from nonprehensile.demonstrations.dataset import load_dataset
    from nonprehensile.viz.trajectories import trajectory_figure

    ds = load_dataset("cube")
    return {
        "cube-trajectories-tumbling.png": trajectory_figure(ds, ["tumble-lift", "tumble-twist"]),
        "cube-trajectories-rolling.png": trajectory_figure(ds, ["roll-arc", "roll-pull"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=IMG, help="output folder (docs/img)")
    out: Path = parser.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    cube = nph.load_model("cube")
    figures = {
        "cube-object.png": object_figure(cube),
        "cube-vertices.png": vertex_views(cube),
        "l-block-object.png": object_figure(l_block()),
        **inference_figures(),
        **dataset_figures(),
    }
    for name, fig in figures.items():
        small = any(k in name for k in ("graph", "skill", "traj"))
        fig.savefig(out / name, dpi=GRAPH_DPI if small else DPI)
        print(out / name)


if __name__ == "__main__":
    main()
