"""``nonprehensile object``: object models (``states`` is in :mod:`nonprehensile.cli.states`).

Registered in :data:`nonprehensile.cli.COMMANDS`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
from rich.table import Table

from nonprehensile.cli import HelpGroup
from nonprehensile.cli.common import emit_json, err, fmt_num, handle_errors, out
from nonprehensile.cli.options import (
    RTOL,
    count,
    json_option,
    load_cli_model,
    number,
    rtol_option,
)
from nonprehensile.errors import InputError
from nonprehensile.geometry.build import MESH_RTOL, from_mesh
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.geometry.symmetry import rotation_group
from nonprehensile.io import write_model
from nonprehensile.states import stable_faces

__all__ = ["STREAM_ROWS", "adjacency_table", "object_group", "object_summary"]

#: Tables longer than this are streamed as plain text rather than drawn as a rich Table.
STREAM_ROWS = 500


@click.group("object", cls=HelpGroup)
def object_group() -> None:
    """Object models: show one, or make one from a mesh."""


def object_summary(poly: Polyhedron) -> dict[str, Any]:
    """The spec's ``object show --json`` document."""
    faces = {}
    stable = set(stable_faces(poly))
    for f, loop in poly.faces.items():
        faces[f] = {
            "loop": list(loop),
            "delta": list(poly.delta[f]),
            "normal": [round(float(c), 12) + 0.0 for c in poly.normals[f]],
            "stable": f in stable,
            "virtual": f in poly.virtual_faces,
        }
    return {
        "name": poly.name,
        "units": poly.units,
        "n_vertices": len(poly.vertices),
        "center_of_mass": [float(c) for c in poly.com],
        "hull_volume": poly.volume,
        "faces": faces,
        "adjacency": poly.adjacency,
        "symmetry_order": len(rotation_group(poly)),
    }


#: Models with more faces are shown as plain lines, their adjacency row by row.
MATRIX_FACES = 40


def adjacency_table(poly: Polyhedron) -> Table:
    """The adjacency matrix of edge numbers as the paper prints it (Fig. 3(b))."""
    labels, a = poly.adjacency_matrix()
    t = Table(title="Adjacency matrix A (A\\[row]\\[col] = edge number on the row face)")
    t.add_column("A", style="bold")
    for f in labels:
        t.add_column(f, justify="center")
    for i, f in enumerate(labels):
        t.add_row(f, *[str(k) if k else "-" for k in a[i]])
    return t


@object_group.command("show")
@click.argument("model")
@rtol_option
@json_option
@handle_errors
def object_show(model: str, rtol: float | None, as_json: bool) -> None:
    """Show MODEL (a model file, or a bundled name such as `cube`): faces, A, Delta."""
    poly = load_cli_model(model, rtol)
    summary = object_summary(poly)
    if as_json:
        emit_json(summary)
        return
    out.print(
        f"[bold]{poly.name}[/]: {len(poly.faces)} faces, {len(poly.vertices)} vertices, "
        f"hull volume {fmt_num(poly.volume)} {poly.units}^3, centre of mass "
        f"({', '.join(fmt_num(c) for c in poly.com)}), rotation symmetry order "
        f"{summary['symmetry_order']}"
    )
    rows = [
        (
            f + (" (virtual)" if info["virtual"] else ""),
            " ".join(map(str, info["loop"])),
            ", ".join(fmt_num(d) for d in info["delta"]),
            "(" + ", ".join(fmt_num(c) for c in info["normal"]) + ")",
            "yes" if info["stable"] else "no",
        )
        for f, info in summary["faces"].items()
    ]
    if len(rows) > MATRIX_FACES:
        # a big model (a scan, a faceted ball): plain lines, and A row by row (its edges,
        # not an F x F matrix that no terminal shows and that takes minutes to lay out)
        out.print("faces: face | loop (clockwise from outside) | Delta (deg) | outward normal "
                  "| stable", markup=False, highlight=False)
        out.print("\n".join(" | ".join(r) for r in rows), markup=False, highlight=False)
        out.print("adjacency A, row by row (neighbour=edge number on the row face):",
                  markup=False, highlight=False)
        out.print("\n".join(f"{f}: " + " ".join(f"{g}={k}" for g, k in row.items())
                            for f, row in poly.adjacency.items()), markup=False,
                  highlight=False)
        return
    faces = Table(title="Faces")
    for col in ("face", "loop (clockwise from outside)", "Delta (deg)", "outward normal",
                "stable"):
        faces.add_column(col)
    for r in rows:
        faces.add_row(*r)
    out.print(faces)
    out.print(adjacency_table(poly))


def _face_list(ctx: click.Context, param: click.Parameter, value: str | None
               ) -> list[str] | None:
    """``a,b,c`` as a list of face IDs (checked against the model later)."""
    if value is None:
        return None
    faces = [f.strip() for f in value.split(",") if f.strip()]
    if not faces:
        raise click.BadParameter("give face IDs separated by commas, e.g. --faces a,b,c")
    return faces


@object_group.command("figure")
@click.argument("model")
@click.option("-o", "--output", default=None, type=click.Path(dir_okay=False),
              help="Image file to write (PNG, SVG or PDF, by suffix): two opposite labeled "
              "views, A and Delta.")
@click.option("--html", "html_out", default=None, type=click.Path(dir_okay=False),
              help="Also (or instead) write a rotatable 3-D view: one self-contained HTML file "
              "(plotly.js embedded, opens offline) with every face labeled; needs the view3d "
              "extra.")
@click.option("--faces", default=None, callback=_face_list, metavar="A,B,...",
              help="Label only these faces (IDs separated by commas): on a large model, whose "
              "figure otherwise has no labels, the faces you want to find.")
@rtol_option
@handle_errors
def object_figure_cmd(model: str, output: str | None, html_out: str | None,
                      faces: list[str] | None, rtol: float | None) -> None:
    """Draw MODEL labeled like the paper's Fig. 3: faces, edge numbers, A and Delta.

    Give -o for a picture, --html for a rotatable 3-D view, or both.
    """
    if output is None and html_out is None:
        raise InputError("nothing to write: give -o FILE (PNG, SVG or PDF) and/or --html FILE")
    poly = load_cli_model(model, rtol)
    if html_out is not None:
        from nonprehensile.viz.view3d import object_view, write_html

        if not html_out.lower().endswith((".html", ".htm")):
            raise InputError(f"--html {html_out}: the 3-D view is an HTML file; name it .html")
        write_html(object_view(poly, faces=faces), html_out)
        err.print(f"wrote {html_out}")
    if output is not None:
        from nonprehensile.viz import object_figure, save_figure
        from nonprehensile.viz.labeled_object import DETAIL_LIMIT

        save_figure(object_figure(poly, faces=faces), output, dpi=100)
        err.print(f"wrote {output}")
        if faces is None and len(poly.faces) > DETAIL_LIMIT:
            err.print(f"note: {poly.name} has {len(poly.faces)} faces, more than the picture "
                      f"labels ({DETAIL_LIMIT}): label some with --faces a,b,..., or see every "
                      "face labeled in a rotatable view with --html FILE", markup=False,
                      highlight=False)


#: Neighbouring facets merged within this angle: a right angle would merge across edges.
_MERGE_ANGLE = number(0.0, 90.0, high_open=True, unit="degrees")


@object_group.command("from-mesh")
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Model file to write (.json, or .yaml/.yml).")
@click.option("--name", default=None, help="Object name (default: the mesh file's stem).")
@click.option("--rtol", type=RTOL, default=MESH_RTOL, show_default=True,
              help="Tolerance, relative to the object's size, for merging nearly coplanar "
              "facets; raise it to facet a curved object more coarsely. The model stores it.")
@click.option("--merge-angle", type=_MERGE_ANGLE, default=0.0, show_default=True,
              help="Also merge neighbouring facets whose normals differ by at most this many "
              "degrees.")
@click.option("--max-faces", type=count(4, 10**7), default=None,
              help="Facet a curved object (a ball, a can) into at most this many faces.")
@click.option("--strict", is_flag=True,
              help="Refuse an open, non-manifold or multi-piece mesh instead of using the "
              "convex hull of its points.")
@click.option("--allow-open", is_flag=True, hidden=True,
              help="Accepted for compatibility: open meshes are used unless --strict.")
@click.option("--units", default="m", show_default=True,
              help="Length units of the mesh: m, dm, cm, mm, um, in or ft (the model stores "
                   "them; physics converts with them).")
@json_option
@handle_errors
def object_from_mesh(
    mesh: str, output: str, name: str | None, rtol: float, merge_angle: float,
    max_faces: int | None, strict: bool, allow_open: bool, units: str, as_json: bool,
) -> None:
    """Make an object model from MESH (STL, OBJ, PLY, OFF, GLB, ...): its convex hull."""
    notes: list[str] = []
    poly = from_mesh(mesh, name=name, rtol=rtol, angle=merge_angle, max_faces=max_faces,
                     strict=strict, units=units, notes=notes)
    if units == "m" and poly.diameter > 2.0:
        # STL carries no units and CAD exports are usually millimetres: a hand-held object
        # read as metres is metres across, so say what was assumed and how to change it
        notes.append(f"the mesh was read in metres (--units m) and is {poly.diameter:.4g} m "
                     "across; if the file is in millimetres, pass --units mm")
    for note in notes:
        err.print(f"note: {note}", markup=False, highlight=False)
    write_model(poly, output)
    if as_json:
        emit_json({"output": str(Path(output)), **object_summary(poly)})
        return
    # names in model order; a scanned part can have a thousand virtual faces: name a few
    virtual = [f for f in poly.faces if f in poly.virtual_faces]
    shown = ", ".join(virtual[:12]) + (f", ... ({len(virtual) - 12} more)"
                                       if len(virtual) > 12 else "")
    out.print(
        f"wrote {output}: {poly.name}, {len(poly.faces)} faces "
        f"({len(virtual)} virtual{': ' + shown if virtual else ''}), "
        f"{len(poly.vertices)} vertices, {poly.diameter:.4g} {poly.units} across"
    )
