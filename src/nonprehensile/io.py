"""Reading and writing the spec's files: object models and state lists (JSON or YAML).

Every reading error names the file and the culprit (key, face, line) and is an
:class:`~nonprehensile.errors.InputError`, so the command line exits with code 2.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from nonprehensile.bounds import (
    MAX_DOCUMENT_BYTES,
    MAX_DOCUMENT_DEPTH,
    check_document,
    check_file_size,
    check_path,
    key_list,
)
from nonprehensile.errors import InputError, ModelError, SkillError, StateError
from nonprehensile.geometry.polyhedron import DEFAULT_RTOL, Polyhedron
from nonprehensile.geometry.units import check_units
from nonprehensile.skills.skill import Skill, skill_from_dict, skill_to_dict
from nonprehensile.states import DEFAULT_ANGLE_TOL, State, check_states

__all__ = [
    "BUNDLED_MODELS",
    "load_document",
    "load_model",
    "model_from_dict",
    "model_json",
    "model_to_dict",
    "parse_document",
    "read_model",
    "read_skills",
    "read_state_set",
    "read_states",
    "save_document",
    "skills_to_dict",
    "write_model",
]

#: Object models shipped inside the package, by name.
BUNDLED_MODELS = ("cube",)

_MODEL_KEYS = {"name", "vertices", "faces", "center_of_mass", "virtual_faces", "units", "rtol"}


def load_document(path: str | Path) -> Any:
    """Parse a JSON or YAML file (by suffix; ``.yaml``/``.yml`` are YAML, others JSON).

    The file is bounded before it is parsed (size, :data:`~nonprehensile.bounds.MAX_DOCUMENT_BYTES`)
    and the document after (nesting depth and size once YAML aliases are expanded), so that
    no later step recurses or loops without bound.

    Raises
    ------
    InputError
        Missing file, a file too large, a syntax error (one line, with its line and column),
        or nesting too deep.
    """
    path = check_path(path)
    try:
        check_file_size(path, MAX_DOCUMENT_BYTES, "JSON/YAML document")
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, expected a JSON/YAML file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read it: {exc}") from None
    return parse_document(text, str(path), yaml=path.suffix.lower() in (".yaml", ".yml"))


def parse_document(text: str, source: str, *, yaml: bool = False) -> Any:
    """Parse JSON (or YAML) text from ``source`` (a file name, or what the text is, as "the
    annotation" of an upload), bounded as :func:`load_document` bounds a file.

    Raises
    ------
    InputError
        A syntax error (one line, with its line and column), an integer of more than 4300
        digits, nesting deeper than :data:`~nonprehensile.bounds.MAX_DOCUMENT_DEPTH`, too
        many values, or a value JSON has not (a YAML date, binary or set); the message
        starts with ``source``.
    """
    kind = "YAML" if yaml else "JSON"
    yaml_errors: tuple[type[Exception], ...] = ()
    if yaml:
        import yaml as pyyaml  # only for YAML files: PyYAML's import is 10-15 ms of every command

        yaml_errors = (pyyaml.YAMLError,)
    try:
        data = pyyaml.safe_load(text) if yaml else json.loads(text)
    except yaml_errors as exc:
        raise InputError(f"{source}: malformed YAML{_yaml_error(exc)}") from None
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{source}: malformed JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except RecursionError:
        # the parsers recurse once per level: thousands of levels overflow the stack
        raise InputError(
            f"{source}: lists and mappings nested more than {MAX_DOCUMENT_DEPTH} levels deep; "
            "the spec's files nest a few levels"
        ) from None
    except (ValueError, OverflowError) as exc:
        if "digits" in str(exc):  # Python's bound on int() of a long digit string
            raise InputError(
                f"{source}: malformed {kind}: an integer of more than 4300 digits; no value of "
                "these files is that large"
            ) from None
        # YAML: a date like 2019-13-45
        raise InputError(f"{source}: malformed {kind}: {exc}") from None
    return check_document(data, source)


def _yaml_error(exc: Exception) -> str:
    """A YAML error on one line: where, and what (PyYAML's own text spans several lines)."""
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    parts = [getattr(exc, "context", None), getattr(exc, "problem", None)]
    what = "; ".join(str(p) for p in parts if p) or str(exc).splitlines()[0]
    return f"{where}: {what}"


def save_document(data: Any, path: str | Path) -> None:
    """Write ``data`` as JSON, or YAML when the suffix is ``.yaml``/``.yml``.

    The file is written to a temporary name and renamed, so a crash never leaves half a file.

    Raises
    ------
    InputError
        The file cannot be written (a full disk, a read-only folder); the message names it.
    """
    path = check_path(path)
    if path.suffix.lower() in (".yaml", ".yml"):
        import yaml

        text = yaml.safe_dump(data, sort_keys=False)
    else:
        text = json.dumps(data, indent=2) + "\n"
    write_text_file(path, text)


def write_text_file(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through a temporary name and a rename.

    A crash never leaves half a file, and a failure names the file: a full disk fails in
    ``write``, whose error carries no file name of its own.

    Raises
    ------
    InputError
        The file cannot be written (a full disk, a read-only folder); the message names it.
    """
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
    except OSError as exc:
        raise InputError(f"{path}: cannot write it: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
    return path


def model_from_dict(
    data: Any, *, source: str | None = None, rtol: float | None = None
) -> Polyhedron:
    """Build a model from the spec's dictionary form.

    Parameters
    ----------
    data : dict
        ``{"name", "vertices", "faces", ["center_of_mass"], ["virtual_faces"], ["units"],
        ["rtol"]}``.
    source : str, optional
        Where it came from, for error messages.
    rtol : float, optional
        Length tolerance relative to the diameter. Default: the model's own ``rtol`` (the
        tolerance it was built at, which a model made from a mesh stores), else
        :data:`DEFAULT_RTOL`.

    Raises
    ------
    ModelError
        Missing or unknown keys, wrong types, or an invalid polyhedron (naming the face).
    """
    if not isinstance(data, Mapping):
        raise ModelError(
            f"an object model must be a JSON/YAML object with keys 'vertices' and 'faces', "
            f"got {type(data).__name__}",
            source=source,
        )
    missing = [k for k in ("vertices", "faces") if k not in data]
    if missing:
        raise ModelError(f"missing key(s) {missing}", source=source)
    unknown = key_list(set(data) - _MODEL_KEYS)
    if unknown:
        raise ModelError(
            f"unknown key(s) {unknown}; an object model has {sorted(_MODEL_KEYS)}",
            source=source,
        )
    faces = data["faces"]
    if not isinstance(faces, Mapping):
        raise ModelError(
            "'faces' must map face IDs to vertex loops, e.g. {\"a\": [0, 1, 2, 3]}",
            source=source,
        )
    virtual = data.get("virtual_faces", [])
    if not isinstance(virtual, list) or not all(isinstance(f, str) for f in virtual):
        raise ModelError("'virtual_faces' must be a list of face IDs", source=source)
    units = data.get("units", "m")
    try:
        check_units(units, what="'units'")
    except ModelError as exc:
        raise ModelError(str(exc), source=source) from None
    if rtol is None:
        rtol = data.get("rtol", DEFAULT_RTOL)
        if isinstance(rtol, bool) or not isinstance(rtol, (int, float)):
            raise ModelError(
                f"'rtol' must be a positive number (the model's length tolerance relative to "
                f"its diameter), got {rtol!r}",
                source=source,
            )
    try:
        return Polyhedron(
            data["vertices"],
            {str(k): v for k, v in faces.items()},
            name=str(data.get("name", Path(source).stem if source else "object")),
            center_of_mass=data.get("center_of_mass"),
            virtual_faces=frozenset(virtual),
            units=units,
            rtol=rtol,
        )
    except ModelError as exc:
        if source is None or exc.source is not None:
            raise
        raise ModelError(str(exc), source=source) from None


def model_to_dict(poly: Polyhedron) -> dict[str, Any]:
    """The spec's dictionary form of a model (centre of mass always written)."""
    out = _model_header(poly)
    out["vertices"] = np.asarray(poly.vertices, dtype=float).tolist()
    out["faces"] = {f: list(loop) for f, loop in poly.faces.items()}
    return out


def _model_header(poly: Polyhedron) -> dict[str, Any]:
    """:func:`model_to_dict` with ``vertices`` and ``faces`` left as placeholders (None),
    in the document's order."""
    out: dict[str, Any] = {
        "name": poly.name,
        "vertices": None,
        "faces": None,
        "center_of_mass": [float(c) for c in poly.com],
        "units": poly.units,
    }
    if poly.rtol != DEFAULT_RTOL:
        out["rtol"] = poly.rtol  # the tolerance the model is valid at travels with it
    if poly.virtual_faces:
        out["virtual_faces"] = sorted(poly.virtual_faces)
    return out


def read_model(path: str | Path, *, rtol: float | None = None) -> Polyhedron:
    """Read an object model file (JSON or YAML), at its own tolerance unless ``rtol``."""
    return model_from_dict(load_document(path), source=str(path), rtol=rtol)


def load_model(spec: str | Path, *, rtol: float | None = None) -> Polyhedron:
    """A model from a file path, or a bundled model by name (``"cube"``) when no such file.

    Raises
    ------
    InputError
        Neither a file nor a bundled model.
    """
    path = Path(spec)
    if path.exists():
        return read_model(path, rtol=rtol)
    if str(spec) in BUNDLED_MODELS:
        ref = resources.files("nonprehensile").joinpath("data", f"{spec}.json")
        with resources.as_file(ref) as p:
            return read_model(p, rtol=rtol)
    raise InputError(
        f"{spec}: no such model file (bundled models: {', '.join(BUNDLED_MODELS)})"
    )


def write_model(poly: Polyhedron, path: str | Path) -> None:
    """Write a model file (JSON, or YAML by suffix)."""
    path = check_path(path)
    if path.suffix.lower() in (".yaml", ".yml"):
        save_document(model_to_dict(poly), path)
    else:
        write_text_file(path, model_json(poly))


def model_json(poly: Polyhedron) -> str:
    """The model file's JSON text (:func:`model_to_dict`), one vertex and one face a line.

    Written row by row: ``json.dumps(..., indent=2)`` runs its pure-Python encoder over every
    number (a line each), which for a million-face model takes half a minute and a GB.
    """
    doc = _model_header(poly)
    items = []
    for key, value in doc.items():
        if key == "vertices":
            rows = ",\n".join(f"    [{x!r}, {y!r}, {z!r}]"
                               for x, y, z in np.asarray(poly.vertices, dtype=float).tolist())
            items.append(f'  "vertices": [\n{rows}\n  ]')
        elif key == "faces":
            rows = ",\n".join(f"    {json.dumps(f)}: [{', '.join(map(str, loop))}]"
                               for f, loop in poly.faces.items())
            items.append(f'  "faces": {{\n{rows}\n  }}')
        else:
            items.append(f"  {json.dumps(key)}: {json.dumps(value)}")
    return "{\n" + ",\n".join(items) + "\n}\n"


def read_states(path: str | Path) -> list[State]:
    """Read a state list file: a JSON/YAML list of ``{"face": ..., "theta": ...}``, or a
    document whose ``states`` key holds one (what ``nonprehensile states --json`` prints;
    other keys of its entries, such as ``class``, are ignored).

    Raises
    ------
    StateError
        Not a list, or an entry that is not a state (naming its position).
    """
    data = load_document(path)
    if isinstance(data, dict) and isinstance(data.get("states"), list):
        data = data["states"]
    if not isinstance(data, list):
        raise StateError(f'{path}: expected a list of {{"face": ..., "theta": ...}} (or the '
                         f'document `nonprehensile states --json` writes, with its "states" '
                         f"list), got {type(data).__name__}")
    out = []
    for i, item in enumerate(data):
        try:
            out.append(State.from_dict(item))
        except StateError as exc:
            raise StateError(f"{path}: entry {i}: {exc}") from None
    return out


def read_state_set(
    poly: Polyhedron, path: str | Path, *, angle_tol: float = DEFAULT_ANGLE_TOL
) -> list[State]:
    """Read a state list file (:func:`read_states`) and check it against the object.

    Parameters
    ----------
    poly : Polyhedron
        The object the states are of.
    path : str or Path
        The file.
    angle_tol : float
        Degrees within which two states of a face are the same (listed twice).

    Returns
    -------
    list of State
        The states, checked (:func:`~nonprehensile.states.check_states`).

    Raises
    ------
    StateError
        Naming the file: not a list, empty, an entry that is not a state, a face the object
        lacks or cannot rest on, a state listed twice.
    """
    states = read_states(path)
    if not states:
        raise StateError(f'{path}: the state list is empty; list at least one {{"face": ..., '
                         f'"theta": ...}} (or use --step)')
    try:
        return check_states(poly, states, angle_tol=angle_tol)
    except StateError as exc:
        raise StateError(f"{path}: {exc}") from None


def read_skills(
    path: str | Path,
    *,
    rtol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> tuple[Polyhedron, list[Skill]]:
    """Read a skills file (docs/files.md) and its object model.

    ``object`` is a path relative to the skills file, a bundled model name, or the model
    inline. Every skill is validated against the model.

    Raises
    ------
    SkillError
        Naming the file, the skill and the culprit.
    """
    path = Path(path)
    data = load_document(path)
    if not isinstance(data, Mapping) or "object" not in data or "skills" not in data:
        raise SkillError(f'{path}: a skills file is {{"object": ..., "skills": [...]}}')
    obj = data["object"]
    if isinstance(obj, Mapping):
        poly = model_from_dict(obj, source=f"{path} (inline object)", rtol=rtol)
    elif isinstance(obj, str):
        target = path.parent / obj
        try:
            poly = load_model(target if target.exists() or obj not in BUNDLED_MODELS else obj,
                              rtol=rtol)
        except InputError as exc:
            raise SkillError(f"{path}: its object: {exc}") from None
    else:
        raise SkillError(f"{path}: 'object' must be a model file path or an inline model")
    raw = data["skills"]
    if not isinstance(raw, list) or not raw:
        raise SkillError(f"{path}: 'skills' must be a non-empty list")
    skills: list[Skill] = []
    for item in raw:
        try:
            skill = skill_from_dict(item, poly, angle_tol=angle_tol)
        except InputError as exc:
            raise SkillError(f"{path}: {exc}") from None
        if any(s.name == skill.name for s in skills):
            raise SkillError(f"{path}: two skills are named {skill.name!r}; names must differ")
        skills.append(skill)
    return poly, skills


def skills_to_dict(poly: Polyhedron, skills: list[Skill]) -> dict[str, Any]:
    """A skills file's content with the model inline."""
    return {"object": model_to_dict(poly), "skills": [skill_to_dict(s) for s in skills]}
