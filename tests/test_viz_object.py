"""Tests of the labeled-object figure (paper Fig. 3): labels, their places, tables, PNG."""

from __future__ import annotations

import builtins
import io
import itertools
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NamedTuple

import matplotlib.image
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.table import Table
from matplotlib.transforms import Bbox
from mpl_toolkits.mplot3d import proj3d
from mpl_toolkits.mplot3d.art3d import Line3D, Poly3DCollection, Text3D
from mpl_toolkits.mplot3d.axes3d import Axes3D

from nonprehensile.errors import InputError, ModelError
from nonprehensile.geometry import Polyhedron, convex_hull, cube, prism, tetrahedron
from nonprehensile.viz import (
    default_view,
    object_figure,
    plot_adjacency,
    plot_delta,
    plot_object,
    view_direction,
)


class Drawn(NamedTuple):
    poly: Polyhedron
    fig: Figure
    png: bytes


OBJECTS: dict[str, Callable[[], Polyhedron]] = {
    "cube": cube,
    "tetrahedron": tetrahedron,
    "hexagonal prism": lambda: prism(6),
}


@pytest.fixture(scope="module", params=list(OBJECTS))
def drawn(request: pytest.FixtureRequest) -> Drawn:
    """Each object with its figure, saved once as PNG with Agg (text extents need a renderer)."""
    poly = OBJECTS[request.param]()
    fig = object_figure(poly)
    FigureCanvasAgg(fig)
    # saving draws the figure: the PNG is kept for the PNG test, the layout for the others
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return Drawn(poly, fig, buf.getvalue())


def views(fig: Figure) -> list[Axes3D]:
    return [ax for ax in fig.axes if isinstance(ax, Axes3D)]


def labels(ax: Axes) -> dict[str, Text3D]:
    """Face and edge labels of one 3-D view, by gid."""
    return {
        t.get_gid(): t
        for t in ax.texts
        if isinstance(t, Text3D) and str(t.get_gid()).startswith(("face:", "edge:"))
    }


def screen(ax: Axes3D, points: np.ndarray) -> np.ndarray:
    """2-D coordinates (x right, y up) of 3-D points under the axes' own projection."""
    xs, ys, _ = proj3d.proj_transform(points[:, 0], points[:, 1], points[:, 2], ax.get_proj())
    return np.column_stack([xs, ys])


def drawn_extent(ax: Axes3D, t: Text3D, renderer: object) -> Bbox:
    """Pixel box of a 3-D text where it is drawn (at its projected position)."""
    pos = t.get_position_3d()
    t.set_position(tuple(screen(ax, np.array([pos], dtype=float))[0]))
    try:
        box: Bbox = t.get_window_extent(renderer)
        return box
    finally:
        t.set_position_3d(pos)


def shoelace(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def table_text(table: Table) -> dict[tuple[int, int], str]:
    return {rc: cell.get_text().get_text() for rc, cell in table.get_celld().items()}


# ---------------------------------------------------------------- labels: present, once each
def test_every_face_id_and_edge_number_is_written_once(drawn: Drawn) -> None:
    poly, fig = drawn.poly, drawn.fig
    panels = views(fig)
    assert len(panels) == 2
    found: dict[str, list[str]] = {}
    for ax in panels:
        for gid, t in labels(ax).items():
            found.setdefault(gid, []).append(t.get_text())
    expected = {f"face:{f}": f for f in poly.faces}
    expected |= {
        f"edge:{f}:{k}": str(k) for f in poly.faces for k in range(1, len(poly.faces[f]) + 1)
    }
    assert set(found) == set(expected)
    for gid, texts in found.items():
        assert texts == [expected[gid]], gid  # once, with the right text
    # every edge of the solid shows two numbers: E = (sum of face sizes) / 2
    n_edge_labels = sum(1 for g in found if g.startswith("edge:"))
    n_edges = len({frozenset(p) for p in _undirected_edges(poly)})
    assert n_edge_labels == 2 * n_edges


def _undirected_edges(poly: Polyhedron) -> Iterator[tuple[int, int]]:
    for loop in poly.faces.values():
        yield from itertools.pairwise((*loop, loop[0]))


def test_each_face_is_labeled_in_the_view_it_faces(drawn: Drawn) -> None:
    # Truth from matplotlib's own projection: a face facing the viewer, listed clockwise from
    # outside (the spec), is drawn clockwise on screen: negative shoelace area.
    poly, fig = drawn.poly, drawn.fig
    for ax in views(fig):
        faces = [g.split(":", 1)[1] for g in labels(ax) if g.startswith("face:")]
        assert faces
        for f in faces:
            assert shoelace(screen(ax, poly.vertices[list(poly.faces[f])])) < 0, f


def test_no_label_overlaps_another_or_the_centre_of_mass(
    drawn: Drawn,
) -> None:
    poly, fig = drawn.poly, drawn.fig
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    for ax in views(fig):
        boxes = {g: drawn_extent(ax, t, renderer) for g, t in labels(ax).items()}
        for (g1, b1), (g2, b2) in itertools.combinations(boxes.items(), 2):
            assert not b1.overlaps(b2), f"{g1} overlaps {g2} in {poly.name}"
        com_xy = ax.transData.transform(screen(ax, poly.com[None, :]))[0]
        marker_radius_px = 5 * fig.dpi / 72  # markersize 10 pt is a diameter
        for g, b in boxes.items():
            nearest = np.clip(com_xy, [b.x0, b.y0], [b.x1, b.y1])
            assert np.linalg.norm(com_xy - nearest) > marker_radius_px, g


def test_edge_numbers_sit_inside_their_face_next_to_their_edge(
    drawn: Drawn,
) -> None:
    poly, fig = drawn.poly, drawn.fig
    for ax in views(fig):
        for gid, t in labels(ax).items():
            if not gid.startswith("edge:"):
                continue
            _, f, k = gid.split(":")
            p = np.array(t.get_position_3d(), dtype=float)
            loop = poly.vertices[list(poly.faces[f])]
            # in the face's plane
            n = np.cross(loop[1] - loop[0], loop[2] - loop[0])
            assert abs((p - loop[0]) @ n) / np.linalg.norm(n) < 1e-9
            # strictly inside: on the centroid's side of every edge line
            centre = loop.mean(axis=0)
            segs = list(itertools.pairwise(np.vstack([loop, loop[:1]])))
            for a, b in segs:
                side = np.cross(b - a, p - a) @ n
                assert side * (np.cross(b - a, centre - a) @ n) > 0
            # nearest to segment k: loop vertex k to loop vertex k+1 (the spec's numbering)
            dist = [_segment_distance(p, a, b) for a, b in segs]
            assert int(np.argmin(dist)) + 1 == int(k)


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    t = float(np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0))
    return float(np.linalg.norm(p - (a + t * (b - a))))


def test_cube_edge_numbers_face_the_paper_neighbours() -> None:
    # Hand-worked truth, paper Section III: A(b,a) = 2 (edge 2 of b borders a) and
    # A(a,b) = 3. On a cube every dihedral angle is 90 degrees, so the face across the edge a
    # number sits by is the face whose plane is nearest to the number.
    poly = cube()
    fig = object_figure(poly)
    planes = {
        "a": (2, 0.0), "c": (2, 1.0), "e": (0, 0.0), "b": (0, 1.0), "f": (1, 0.0), "d": (1, 1.0)
    }
    across: dict[tuple[str, int], str] = {}
    for ax in views(fig):
        for gid, t in labels(ax).items():
            if gid.startswith("edge:"):
                _, f, k = gid.split(":")
                p = np.array(t.get_position_3d(), dtype=float)
                dist = {g: abs(p[axis] - c) for g, (axis, c) in planes.items() if g != f}
                across[(f, int(k))] = min(dist, key=lambda g: dist[g])
    assert across[("b", 2)] == "a"
    assert across[("a", 3)] == "b"
    assert across == {(f, k): g for f, row in poly.adjacency.items() for g, k in row.items()}


# ---------------------------------------------------------------- the rest of the drawing
def test_virtual_faces_are_hatched_and_dashed_and_the_com_is_marked() -> None:
    c = cube()
    poly = Polyhedron(c.vertices, c.faces, name="half-virtual", virtual_faces=frozenset({"c", "a"}))
    fig = object_figure(poly)
    styles: dict[str, list[tuple[str | None, bool]]] = {}
    for ax in views(fig):
        for coll in ax.collections:
            if isinstance(coll, Poly3DCollection) and str(coll.get_gid()).startswith("facet:"):
                f = str(coll.get_gid()).split(":", 1)[1]
                dashed = coll.get_linestyle()[0][1] is not None
                fill = coll.get_facecolor()
                filled = len(fill) > 0 and fill[0][3] > 0  # hidden faces: no fill at all
                if filled:
                    styles.setdefault(f, []).append((coll.get_hatch(), dashed))
        com = [ln for ln in ax.lines if ln.get_gid() == "com"]
        assert com and all(isinstance(ln, Line3D) for ln in com)
        for ln in com:
            assert np.allclose(np.ravel(ln.get_data_3d()), [0.5, 0.5, 0.5])
    # each face is filled in exactly one of the two views
    assert {f: len(s) for f, s in styles.items()} == dict.fromkeys(poly.faces, 1)
    for f, [(hatch, dashed)] in styles.items():
        virtual = f in {"a", "c"}
        assert bool(hatch) == virtual and dashed == virtual, f
    assert "virtual faces: a, c" in fig.get_suptitle()


def test_adjacency_table_cells_equal_the_model() -> None:
    for make in OBJECTS.values():
        poly = make()
        ax = plot_adjacency(poly)
        cells = table_text(ax.tables[0])
        ids = list(poly.faces)
        for j, g in enumerate(ids):
            assert cells[(0, j)] == g
        for i, f in enumerate(ids):
            assert cells[(i + 1, -1)] == f
            for j, g in enumerate(ids):
                want = str(poly.adjacency[f][g]) if g in poly.adjacency[f] else "-"
                assert cells[(i + 1, j)] == want
        assert len(cells) == len(ids) * (len(ids) + 2)
    # the paper's two values, read off the cube's table
    cells = table_text(plot_adjacency(cube()).tables[0])
    assert cells[(2, 0)] == "2"  # A(b, a)
    assert cells[(1, 1)] == "3"  # A(a, b)
    assert cells[(1, 0)] == "-" and cells[(1, 2)] == "-"  # diagonal; a and c are opposite


def test_delta_table_lists_each_face_shape() -> None:
    # Hand-worked: a square turns 90 degrees per edge, a regular triangle 120 (exterior
    # angle), a regular hexagon 60; every face of these solids can be rested on.
    cases = {
        "cube": {"[0, 90, 180, 270]"},
        "tetrahedron": {"[0, 120, 240]"},
        "hexagonal prism": {"[0, 90, 180, 270]", "[0, 60, 120, 180, 240, 300]"},
    }
    for name, make in OBJECTS.items():
        poly = make()
        cells = table_text(plot_delta(poly).tables[0])
        rows = [[cells[(i + 1, j)] for j in (-1, 0, 1, 2)] for i in range(len(poly.faces))]
        assert [r[0] for r in rows] == list(poly.faces)
        assert {r[1] for r in rows} == cases[name]
        assert all(r[2] == str(len(r[1].split(","))) for r in rows)
        assert all(r[3] == "yes" for r in rows)


def test_unstable_and_virtual_faces_are_marked_in_the_delta_table() -> None:
    # Hand-worked: a prism on the obtuse triangle (0,0), (10,0), (1,1) of the xz plane. Its
    # centroid (11/3, 1/3) projects onto the line of the short side (0,0)-(1,1) at (2,2),
    # beyond the side's end: the prism cannot rest on that side's face. It rests on the
    # long bottom face (the centroid projects to x = 11/3, inside [0, 10]).
    tri = [(0.0, 0.0), (10.0, 0.0), (1.0, 1.0)]
    poly = convex_hull([(x, y, z) for x, z in tri for y in (0.0, 1.0)])
    cells = table_text(plot_delta(poly).tables[0])
    stable = {cells[(i + 1, -1)]: cells[(i + 1, 2)] for i in range(len(poly.faces))}
    by_normal = {tuple(np.round(n, 6)): f for f, n in poly.normals.items()}
    short_side = by_normal[tuple(np.round([-1 / np.sqrt(2), 0.0, 1 / np.sqrt(2)], 6))]
    bottom = by_normal[(0.0, 0.0, -1.0)]
    assert stable[short_side] == "no"
    assert stable[bottom] == "yes"
    c = cube()
    marked = Polyhedron(c.vertices, c.faces, virtual_faces=frozenset({"b"}))
    cells = table_text(plot_delta(marked).tables[0])
    assert {cells[(i + 1, -1)]: cells[(i + 1, 2)] for i in range(6)} == {
        "a": "yes", "b": "yes (virtual)", "c": "yes", "d": "yes", "e": "yes", "f": "yes"
    }


def test_figure_saves_to_a_non_blank_png(
    drawn: Drawn, tmp_path: Path
) -> None:
    poly, fig, data = drawn
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    img = matplotlib.image.imread(io.BytesIO(data))
    height, width = fig.get_figheight() * fig.dpi, fig.get_figwidth() * fig.dpi
    assert img.shape[:2] == (round(height), round(width))
    ink = np.mean(img[..., :3] < 0.9)  # share of pixels that are not (near) white
    assert 0.05 < ink < 0.9
    # and to a file, as users do
    path = tmp_path / "figure.png"
    small = Figure()
    plot_adjacency(poly, small.add_subplot())
    small.savefig(path, dpi=30)
    assert path.stat().st_size > 1000


def test_plot_object_alone_makes_its_own_figure_and_vertex_labels() -> None:
    poly = cube()
    ax = plot_object(poly, view=(30, -60), show_vertices=True)
    assert isinstance(ax, Axes3D) and isinstance(ax.figure, Figure)
    assert (ax.elev, ax.azim) == (30, -60)
    texts = {t.get_gid(): t.get_text() for t in ax.texts}
    # from (30, -60) the viewer sees +x (b), -y (f) and +z (c): hand-worked
    assert {g for g in texts if g.startswith("face:")} == {"face:b", "face:c", "face:f"}
    # the vertices of b, c and f: every vertex but (0, 1, 0), index 3
    assert {g for g in texts if g.startswith("vertex:")} == {
        f"vertex:{i}" for i in range(8) if i != 3
    }
    every = plot_object(poly, view=(30, -60), labeled_faces=list(poly.faces), legend=False)
    assert sum(str(t.get_gid()).startswith("face:") for t in every.texts) == 6
    assert every.get_legend() is None


# ---------------------------------------------------------------- default view
@pytest.mark.parametrize("name", list(OBJECTS))
def test_default_view_sees_no_face_edge_on(name: str) -> None:
    poly = OBJECTS[name]()
    elev, azim = default_view(poly)
    assert 0 <= elev < 90 and elev % 5 == 0 and azim % 5 == 0
    v = np.array(
        [np.cos(np.radians(elev)) * np.cos(np.radians(azim)),
         np.cos(np.radians(elev)) * np.sin(np.radians(azim)),
         np.sin(np.radians(elev))]
    )
    assert np.allclose(view_direction((elev, azim)), v)
    # the best any view achieves is 1/sqrt(3) for the cube and the tetrahedron; the default
    # must stay well clear of edge-on (0)
    assert min(abs(n @ v) for n in poly.normals.values()) > 0.3


# ---------------------------------------------------------------- property: random hulls
@settings(max_examples=6, deadline=None)
@given(
    st.lists(
        st.tuples(*[st.integers(-20, 20)] * 3), min_size=5, max_size=10, unique=True
    ).filter(lambda pts: np.linalg.matrix_rank(np.array(pts[1:]) - pts[0]) == 3)
)
def test_any_hull_gets_every_label_once_on_a_face_it_faces(
    pts: list[tuple[int, int, int]],
) -> None:
    poly = convex_hull(np.array(pts, dtype=float))
    fig = object_figure(poly)
    seen: list[str] = []
    for ax in views(fig):
        for gid in labels(ax):
            seen.append(gid)
            f = gid.split(":")[1]
            # drawn clockwise on screen means facing the viewer (or edge-on, area ~ 0)
            area = shoelace(screen(ax, poly.vertices[list(poly.faces[f])]))
            assert area < 1e-12
    want = [f"face:{f}" for f in poly.faces]
    want += [f"edge:{f}:{k}" for f in poly.faces for k in range(1, len(poly.faces[f]) + 1)]
    assert sorted(seen) == sorted(want)


# ---------------------------------------------------------------- errors
def test_bad_input_raises_input_errors_that_say_what_to_do() -> None:
    poly = cube()
    with pytest.raises(InputError, match="Polyhedron"):
        plot_object("cube")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="3-D axes"):
        plot_object(poly, Figure().add_subplot())
    with pytest.raises(InputError, match="two angles"):
        plot_object(poly, view=(30,))  # type: ignore[arg-type]
    with pytest.raises(InputError, match="finite"):
        object_figure(poly, view=(float("nan"), 0.0))
    with pytest.raises(InputError, match="label_offset"):
        plot_object(poly, label_offset=1.5)
    with pytest.raises(ModelError, match="'zz'"):
        plot_object(poly, labeled_faces=["a", "zz"])
    with pytest.raises(InputError, match="Polyhedron"):
        plot_adjacency(None)  # type: ignore[arg-type]


def test_missing_matplotlib_names_the_viz_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    real_import = builtins.__import__

    def no_matplotlib(name: str, *args: object, **kwargs: object) -> object:
        if name.split(".")[0] in {"matplotlib", "mpl_toolkits"}:
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    for call in (
        lambda: object_figure(cube()),
        lambda: plot_object(cube()),
        lambda: plot_adjacency(cube()),
        lambda: plot_delta(cube()),
    ):
        with pytest.raises(InputError, match=r"nonprehensile\[viz\]"):
            call()
