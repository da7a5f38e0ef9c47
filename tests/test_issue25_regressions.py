"""Regression tests of issue 25, command line and library side: each failure by name.

The options' side (NaN, infinities, signs, ranges of every numeric option) is
``tests/test_cli_options.py``; here are the constructors and readers that raised another
library's error (scipy's, a ZeroDivisionError, a traceback), and the big valid inputs'
algorithms checked against independent truth (their speed is a benchmark:
``benchmarks/bench_big_inputs.py``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import nonprehensile as nph
from conftest import occupies_same_space
from nonprehensile.cli import main
from nonprehensile.demonstrations.annotate import DetectionParams
from nonprehensile.equivalence import apply_to_state, equivalence_classes
from nonprehensile.errors import DemonstrationError, MeshError, ModelError, NonprehensileError
from nonprehensile.geometry.symmetry import _every_flag, _group_elements, _GroupSearch


def _one_line(r: object, *words: str) -> None:
    assert r.exit_code == 2, r.output  # type: ignore[attr-defined]
    err = r.stderr.strip()  # type: ignore[attr-defined]
    assert len(err.splitlines()) == 1 and err.startswith("error:"), err
    for w in words:
        assert w in err, (w, err)


# ------------------------------------------------------------------- constructors and readers
def test_a_thin_box_names_the_tolerance() -> None:
    """``nph.box(1, 1, 1e-9)`` raised scipy's ``ValueError: No points given``."""
    with pytest.raises(ModelError, match=r"box height 1e-09 .*tolerance.*smaller rtol"):
        nph.box(1, 1, 1e-9)
    thin = nph.box(1, 1, 1e-9, rtol=1e-12)  # at a finer tolerance it is a box
    assert len(thin.faces) == 6 and thin.volume == pytest.approx(1e-9)


@pytest.mark.parametrize("scale", [1e-301, 1e-200, 1e-13])
def test_points_too_small_are_refused(scale: float, tmp_path: Path) -> None:
    """Coordinates near 1e-301 gave a ZeroDivisionError (the hull, a model file, a mesh)."""
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3)) * scale
    with pytest.raises(MeshError, match="smallest object size"):
        nph.convex_hull(pts)
    with pytest.raises(ModelError, match="smallest object size"):
        nph.Polyhedron(nph.cube().vertices * scale, dict(nph.cube().faces))
    with pytest.raises(ModelError, match="cube size"):
        nph.cube(scale)
    stl = tmp_path / "tiny.stl"
    tri = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    v = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * scale).tolist()
    stl.write_text("solid t\n" + "".join(
        "facet normal 0 0 0\nouter loop\n" + "".join(
            f"vertex {v[i][0]!r} {v[i][1]!r} {v[i][2]!r}\n" for i in t) + "endloop\nendfacet\n"
        for t in tri) + "endsolid t\n")
    pytest.importorskip("trimesh", reason="reading meshes needs the mesh extra")
    r = CliRunner().invoke(main, ["object", "from-mesh", str(stl), "-o", str(tmp_path / "m.json")])
    _one_line(r, "tiny.stl", "smallest object size")


def test_small_meshes_keep_their_shape(tmp_path: Path) -> None:
    """A mesh a few micrometres across: trimesh welds vertices closer than 1e-8, so it is
    cleaned at a larger scale (a power of two, undone after)."""
    pytest.importorskip("trimesh", reason="reading meshes needs the mesh extra")
    c = nph.prism(8, 2e-6, 3e-6)
    stl = tmp_path / "small.stl"
    lines = ["solid t"]
    for loop in c.faces.values():
        for k in range(1, len(loop) - 1):
            lines += ["facet normal 0 0 0", "outer loop"]
            lines += [f"vertex {x!r} {y!r} {z!r}" for x, y, z in
                      c.vertices[[loop[0], loop[k + 1], loop[k]]].tolist()]
            lines += ["endloop", "endfacet"]
    stl.write_text("\n".join([*lines, "endsolid t"]) + "\n")
    m = nph.from_mesh(stl)
    assert len(m.faces) == 10 and m.volume == pytest.approx(c.volume, rel=1e-9)


@pytest.mark.parametrize(("build", "word"), [
    (lambda: nph.prism(float("nan")), "prism sides"),
    (lambda: nph.prism(1e308), "prism sides"),  # numpy's "Maximum allowed size exceeded"
    (lambda: nph.prism(3.5), "prism sides"),
    (lambda: nph.prism(None), "prism sides"),  # type: ignore[arg-type]
    (lambda: nph.tetrahedron(1e-320), "tetrahedron edge"),  # ZeroDivisionError
    (lambda: nph.tetrahedron(-1), "tetrahedron edge"),  # a valid model, mirrored
    (lambda: nph.octahedron(None), "octahedron edge"),  # type: ignore[arg-type]
    (lambda: nph.cube(None), "cube size"),  # type: ignore[arg-type]
    (lambda: nph.convex_hull(nph.cube().vertices, rtol=1e308), "rtol"),  # OverflowError
    (lambda: nph.convex_hull(nph.cube().vertices, rtol=4294967296), "rtol"),  # scipy's
    (lambda: nph.convex_hull(nph.cube().vertices, rtol=5e-324), "rtol"),  # ZeroDivisionError
    (lambda: nph.convex_hull(nph.cube().vertices, max_faces=math.inf), "max_faces"),
    (lambda: nph.convex_hull(nph.cube().vertices, max_faces=math.nan), "max_faces"),
    (lambda: nph.states_by_step(nph.cube(), None), "angle step"),  # type: ignore[arg-type]
    (lambda: nph.is_stable(nph.cube(), "a", None), "margin"),  # type: ignore[arg-type]
    (lambda: nph.rotate(nph.cube(), nph.State("a", 0), None), "angle"),  # type: ignore[arg-type]
    (lambda: nph.state_of_pose(nph.cube(), np.eye(3), None), "tolerance"),  # type: ignore[arg-type]
    (lambda: DetectionParams(min_duration=1e308), "min_duration"),  # OverflowError later
    (lambda: equivalence_classes(nph.cube(), [], angle_tol=math.nan), "angle_tol"),
])
def test_constructors_raise_the_projects_errors(build: object, word: str) -> None:
    with pytest.raises(NonprehensileError, match=word):
        build()  # type: ignore[operator]


def test_detection_thresholds_are_the_projects_errors() -> None:
    with pytest.raises(DemonstrationError, match="state_tol"):
        DetectionParams(state_tol=1e9)
    # 0 degrees matches no measured pose: refused, as ``annotate --state-tol 0`` is
    with pytest.raises(DemonstrationError, match=r"state_tol: expected .*above 0"):
        DetectionParams(state_tol=0.0)
    assert DetectionParams(state_tol=1e-3).state_tol == 1e-3


def test_a_big_prism_keeps_its_faces() -> None:
    """``prism(9000)`` had 5,654 faces: its hull merged sides the tolerance tells apart; a
    100,000-gon, whose corners are straight within the tolerance, came out with 6,590."""
    assert len(nph.prism(9000).faces) == 9002
    with pytest.raises(ModelError, match="use at most 9395 sides"):
        nph.prism(100_000)


def test_npy_header_of_negative_shape(tmp_path: Path) -> None:
    """A ``.npy`` header of shape (-1, 12) gave a traceback (a read of -96 bytes)."""
    path = tmp_path / "neg.npy"
    with path.open("wb") as fh:
        np.lib.format.write_array_header_1_0(
            fh, {"descr": "<f8", "fortran_order": False, "shape": (-1, 12)})
    r = CliRunner().invoke(main, ["cluster", "fit", str(tmp_path / "s.db"), "--arrays",
                                  str(path)])
    _one_line(r, "neg.npy", "(-1, 12)")


# ------------------------------------------------------------------- big valid inputs
@pytest.mark.parametrize("n", [7, 12, 60])
def test_group_by_generators_is_every_flag(n: int) -> None:
    """The symmetry group found from generators and closed under products equals the one
    found by trying every flag (the definition), on prisms and a perturbed cube."""
    rng = np.random.default_rng(n)
    c = nph.cube()
    noisy = nph.Polyhedron(c.vertices + rng.normal(scale=1e-9, size=c.vertices.shape),
                           dict(c.faces), rtol=1e-6)
    for poly in (nph.prism(n), noisy, nph.octahedron()):
        atol = poly.atol
        fast = _group_elements(poly, atol)
        search = _GroupSearch(poly, atol)
        f0 = poly.face_ids[0]
        src = np.column_stack([poly.edge_direction(f0, 1),
                               np.cross(poly.normals[f0], poly.edge_direction(f0, 1)),
                               poly.normals[f0]])
        i0, _ = poly.edge_vertices(f0, 1)
        slow = _every_flag(poly, search, src, i0, fast[0])
        assert [e.vmap.tolist() for e in fast] == [e.vmap.tolist() for e in slow]
        assert [e.shift.tolist() for e in fast] == [e.shift.tolist() for e in slow]
    assert len(_group_elements(nph.prism(n), nph.prism(n).atol)) == 2 * n


@pytest.mark.parametrize(("n", "step"), [(12, 10.0), (40, 9.0), (9, 20.0)])
def test_classes_of_a_prism_against_geometry(n: int, step: float) -> None:
    """Equivalence classes through face-orbit stabilisers, against the definition (the
    object occupies the same space: its vertices, posed, coincide as point sets)."""
    p = nph.prism(n)
    states = nph.states_by_step(p, step)
    classes = equivalence_classes(p, states)
    rng = np.random.default_rng(n)
    by_class: dict[int, list[int]] = {}
    for i, c in enumerate(classes):
        by_class.setdefault(c, []).append(i)
    pairs = [tuple(rng.choice(m, 2)) for m in by_class.values() if len(m) > 1][:40]
    pairs += [tuple(rng.integers(0, len(states), 2)) for _ in range(200)]
    for i, j in pairs:
        same = occupies_same_space(p, states[i], states[j])
        assert same == (classes[i] == classes[j]), (states[i], states[j])
    # and against the group acting on every state
    group = nph.rotation_group(p)
    for i in rng.integers(0, len(states), 20).tolist():
        for g in group[:: max(1, len(group) // 8)]:
            t = apply_to_state(p, g, states[i])
            hit = [k for k, s in enumerate(states) if s.isclose(t)]
            assert all(classes[k] == classes[i] for k in hit)


def test_a_hull_of_too_many_triangles_is_refused_with_the_way_out(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``from-mesh`` of a 1.3-million-triangle sphere ran past 60 s and 2.9 GB: a hull of
    more than ``MAX_HULL_TRIANGLES`` is refused right after Qhull, saying how to simplify
    the mesh (the bound is lowered here so that a small sphere shows it)."""
    from nonprehensile.geometry import build

    monkeypatch.setattr(build, "MAX_HULL_TRIANGLES", 50)
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 3))
    pts /= np.linalg.norm(pts, axis=1)[:, None]
    with pytest.raises(MeshError, match=r"has 396 triangles, more than the 50 .*simplify"):
        nph.convex_hull(pts)
