"""The fuzz campaign of issue 13: generated and mutated inputs through the command line.

Every input family a user can hand the tool is covered: object models, skills files, state
lists and state strings, dataset folders (annotations), C3D files, Motive CSV files, meshes,
numeric options (every numeric option of every command, found by walking the command
tree: issue 25), the API's constructors, sample arrays (.npy/.npz) and store files. Inputs
come from seeds (the repository's bundled data and the real files in ``../shared/realdata``)
mutated by bit flips, truncations, deletions, insertions and token replacements, and from
generators of hostile values (huge, tiny, NaN, negative zero, deep nesting, NUL, lone
surrogates).

Each case runs the command line in-process (click's ``CliRunner``); every ``--subprocess-every``
th case also runs as a real process under ``RLIMIT_AS`` = 2 GiB and a 60 s timeout. A case
fails when it ends in a traceback, an exit code other than 0 and 2, a run over 60 s, memory
over 2 GiB, exit 0 on an input known to be invalid, or a success that writes a file the next
command rejects.

    python tests/fuzz_harness.py --budget 10000 --jobs 2     # make fuzz
    python tests/fuzz_harness.py --family c3d --case 17      # replay one case

The case numbered ``i`` of a family is generated from ``(seed, family, i)`` alone, so a
failure is replayed by its family and number.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
# <repo>/../shared/realdata (GUIDE.md); NONPREHENSILE_SHARED points elsewhere (a worktree)
REALDATA = Path(os.environ.get("NONPREHENSILE_SHARED") or ROOT.parent / "shared") / "realdata"
PACKAGE_DATA = ROOT / "src" / "nonprehensile" / "data"

#: A run longer than this is a failure (seconds).
TIME_LIMIT = 60
#: Address space allowed to a subprocess run (bytes).
MEMORY_LIMIT = 2 * 2**30

#: Values a hostile user types where a number goes.
HOSTILE_NUMBERS = [
    "0", "-0", "-1", "1e-320", "5e-324", "1e308", "-1e308", "1e309", "inf", "-inf", "nan",
    "NaN", "4294967296", "18446744073709551616", "-5", "1e9", "0.0036", "1e-9", "3.5", "", " ",
    "abc", "1,5", "0x10", "9" * 400, "1e", "--", "2**64",
]
#: Strings a hostile user types where a name goes.
HOSTILE_STRINGS = [
    "", " ", "a\x00b", "a\ud800b", "\u202e", "../../etc/passwd", "x" * 5000, "a:b:c", "a:",
    ":5", "a:nan", "a:1e308", "a:-0", "😀:0", "a:1e-320", "null", "{}", "[]", "CON", ".",
]
#: Values put into JSON/YAML documents in place of a number or a string.
HOSTILE_TOKENS = [
    "1e308", "-1e308", "NaN", "Infinity", "-Infinity", "-0", "5e-324", "18446744073709551616",
    "9" * 5000, '""', "null", "[]", "{}", "true", '"\\u0000"', '"\\ud800"', "[" * 3000,
    '{"1": 2, "b": 3}', "0.0036", "-5", "1e-320",
]


@dataclass
class Case:
    """One input: the command line, the files it needs, and what must happen."""

    family: str
    index: int
    argv: list[str]
    #: "invalid": must exit 2; "any": 0 or 2; then: if exit 0, run this command too (must exit 0)
    expect: str = "any"
    then: list[str] | None = None
    files: dict[str, bytes] = field(default_factory=dict)
    dirs: dict[str, Path] = field(default_factory=dict)
    note: str = ""
    #: if exit 0, the JSON output must equal this (less "store"): a damaged copy of a store
    #: either fails or reads as the original, never as something else
    same_as: dict[str, Any] | None = None


@dataclass
class Outcome:
    case: Case
    exit_code: int | None
    seconds: float
    failure: str | None
    detail: str = ""


# ------------------------------------------------------------------------------ mutations
def mutate_bytes(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """A damaged copy of ``data``: one of bit flips, truncation, deletion, insertion, a
    duplicated or zeroed range, or an extreme 16/32-bit value written somewhere."""
    b = bytearray(data)
    n = max(1, len(b))
    # damage concentrates in headers, where lengths and offsets live
    def pos() -> int:
        return rng.randrange(min(n, 4096)) if rng.random() < 0.6 else rng.randrange(n)

    op = rng.choice(["flip", "flip", "flip2", "truncate", "delete", "insert", "duplicate",
                     "zero", "extreme"])
    if not b:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64))), "random"
    if op in ("flip", "flip2"):
        for _ in range(1 if op == "flip" else rng.randint(2, 8)):
            i = pos()
            b[i] ^= 1 << rng.randrange(8)
    elif op == "truncate":
        del b[rng.randrange(n):]
    elif op == "delete":
        i = pos()
        del b[i : i + rng.choice([1, 2, 4, 23, 100, 512])]
    elif op == "insert":
        i = pos()
        b[i:i] = bytes(rng.randrange(256) for _ in range(rng.choice([1, 4, 23, 100])))
    elif op == "duplicate":
        i = pos()
        b[i:i] = b[i : i + rng.choice([8, 64, 512])]
    elif op == "zero":
        i = pos()
        k = rng.choice([4, 16, 64, 512])
        b[i : i + k] = bytes(len(b[i : i + k]))
    else:
        i = pos()
        v = rng.choice([b"\xff\xff", b"\x00\x80", b"\xff\xff\xff\x7f", b"\x00\x00\x80\xff",
                        b"\x00\x00\xc0\x7f", b"\x01\x00"])
        b[i : i + len(v)] = v
    return bytes(b), op


def mutate_text(text: str, rng: random.Random) -> tuple[str, str]:
    """A damaged copy of a JSON/YAML/CSV text: a token replaced by a hostile one, a line
    dropped or doubled, deep nesting, or a byte-level mutation."""
    import re

    op = rng.choice(["number", "number", "string", "line", "nest", "bytes", "key"])
    if op == "number":
        spans = [m.span() for m in re.finditer(r"-?\d+(\.\d+)?([eE][-+]?\d+)?", text)]
        if spans:
            a, b = rng.choice(spans)
            return text[:a] + rng.choice(HOSTILE_TOKENS) + text[b:], op
    if op == "string":
        spans = [m.span() for m in re.finditer(r'"[^"\n]*"', text)]
        if spans:
            a, b = rng.choice(spans)
            return text[:a] + rng.choice(HOSTILE_TOKENS) + text[b:], op
    if op == "key":
        i = text.find("{")
        if i >= 0:
            return text[: i + 1] + rng.choice(['"zz": 1, ', '"1": [], ', '"": 0, ']) \
                + text[i + 1 :], op
    if op == "line":
        lines = text.splitlines(keepends=True)
        if lines:
            i = rng.randrange(len(lines))
            if rng.random() < 0.5:
                del lines[i]
            else:
                lines.insert(i, lines[i])
            return "".join(lines), op
    if op == "nest":
        depth = rng.choice([70, 1200, 20000])
        i = rng.randrange(len(text) + 1)
        return text[:i] + "[" * depth + "]" * depth + text[i:], op
    data, how = mutate_bytes(text.encode("utf-8", "surrogateescape"), rng)
    return data.decode("utf-8", "surrogateescape"), how


# --------------------------------------------------------------------------------- corpus
class Corpus:
    """Seed files and folders, made once per process in a temporary folder."""

    def __init__(self, root: Path) -> None:
        from click.testing import CliRunner

        from nonprehensile.cli import main

        self.root = root
        self.model = (PACKAGE_DATA / "cube.json").read_text()
        self.skills = (PACKAGE_DATA / "cube_skills.json").read_text()
        self.datasets: dict[str, Path] = {}
        for fmt in ("c3d", "csv"):
            out = root / f"seed_{fmt}"
            r = CliRunner().invoke(main, ["dataset", "synth", str(out), "--n-per-skill", "1",
                                          "--format", fmt, "--json"])
            assert r.exit_code == 0, r.output
            self.datasets[fmt] = out
        self.c3d = sorted(self.datasets["c3d"].glob("*.c3d"))
        self.csv = sorted(self.datasets["csv"].glob("*.csv"))
        self.real_c3d = sorted(REALDATA.glob("c3d/*.c3d")) if REALDATA.is_dir() else []
        self.real_csv = sorted(REALDATA.glob("motive/*.csv")) if REALDATA.is_dir() else []
        meshes = sorted(REALDATA.glob("meshes/*")) if REALDATA.is_dir() else []
        self.meshes = [m for m in meshes if m.is_file() and m.stat().st_size < 100_000
                       and m.suffix.lower() in (".stl", ".obj", ".ply", ".off", ".glb")]
        self.meshes += sorted((ROOT / "tests" / "data").glob("*.stl"))
        self.meshes += sorted((ROOT / "tests" / "data").glob("*.obj"))
        import numpy as np

        rng = np.random.default_rng(0)
        x = rng.normal(size=(60, 8))
        np.save(root / "x.npy", x)
        np.savez(root / "xy.npz", X=x, y=np.array(["a", "b"] * 30))
        self.arrays = [root / "x.npy", root / "xy.npz"]
        self.store = root / "seed.db"
        r = CliRunner().invoke(main, ["cluster", "fit", str(self.store), "--arrays",
                                      str(root / "x.npy"), "--n-clusters", "3", "--json"])
        assert r.exit_code == 0, r.output
        r = CliRunner().invoke(main, ["cluster", "show", str(self.store), "--json"])
        assert r.exit_code == 0, r.output
        self.store_show = json.loads(r.output)
        self.store_show.pop("store")


# --------------------------------------------------------------------------------- families
def _fam_model(c: Corpus, rng: random.Random, i: int) -> Case:
    text, how = mutate_text(c.model, rng)
    suffix = rng.choice([".json", ".json", ".yaml"])
    cmd = rng.choice([["object", "show", "{f}"], ["states", "{f}", "--step", "90"],
                      ["object", "show", "{f}", "--json"]])
    return Case("model", i, cmd, files={f"m{suffix}": text.encode("utf-8", "surrogateescape")},
                note=how)


def _fam_skills(c: Corpus, rng: random.Random, i: int) -> Case:
    text, how = mutate_text(c.skills, rng)
    cmd = rng.choice([["skills", "show", "{f}"], ["infer", "{f}", "--step", "90"],
                      ["plan", "{f}", "--from", "a:0", "--to", "f:0", "--step", "90"]])
    return Case("skills", i, cmd, files={"s.json": text.encode("utf-8", "surrogateescape")},
                note=how)


def _fam_states(c: Corpus, rng: random.Random, i: int) -> Case:
    if rng.random() < 0.5:
        doc = [{"face": rng.choice(["a", "b", "zz", 1, None, ""]),
                "theta": rng.choice([0, 90, -0.0, 1e308, "x", None, 5e-324, 2**70])}
               for _ in range(rng.randrange(0, 5))]
        text, how = json.dumps(doc), "generated"
        if rng.random() < 0.5:
            text, how = mutate_text(text, rng)
        return Case("states", i, ["states", "cube", "--states", "{f}"],
                    files={"st.json": text.encode("utf-8", "surrogateescape")}, note=how)
    start = rng.choice([*HOSTILE_STRINGS, "a:0", "b:90", "a:360", "f:-90", "a:1e308"])
    return Case("states", i, ["plan", str(PACKAGE_DATA / "cube_skills.json"), "--from", start,
                              "--to", "f:0", "--step", "90"], note=f"--from {start!r}")


def _one_demo(c: Corpus, fmt: str, victim: Path) -> dict[str, bytes]:
    """A dataset folder of the one demonstration recorded in ``victim`` (its files)."""
    seed_dir = c.datasets[fmt]
    ann = json.loads((seed_dir / "annotations.json").read_text())
    ann["demonstrations"] = [d for d in ann["demonstrations"] if d["file"] == victim.name]
    # the skills file keeps the demonstrated skill only: reading it is most of a load's time
    skills = json.loads((seed_dir / "skills.json").read_text())
    used = {d["skill"] for d in ann["demonstrations"]}
    skills["skills"] = [s for s in skills["skills"] if s["name"] in used]
    return {"d/annotations.json": json.dumps(ann).encode(),
            "d/skills.json": json.dumps(skills).encode()}


def _dataset_case(c: Corpus, rng: random.Random, i: int, family: str, fmt: str,
                  real: list[Path]) -> Case:
    files = c.c3d if fmt == "c3d" else c.csv
    victim = rng.choice(files)
    source = victim
    if real and rng.random() < 0.3:
        source = rng.choice(real)  # a real file from another vendor, damaged, in its place
    data, how = mutate_bytes(source.read_bytes(), rng)
    if rng.random() < 0.1:
        data, how = source.read_bytes(), "unchanged real file"
    return Case(family, i, ["dataset", "show", "{d}", *rng.choice([[], ["--json"]])],
                files={**_one_demo(c, fmt, victim), f"d/{victim.name}": data},
                note=f"{source.name}: {how}")


def _fam_c3d(c: Corpus, rng: random.Random, i: int) -> Case:
    return _dataset_case(c, rng, i, "c3d", "c3d", c.real_c3d)


def _fam_csv(c: Corpus, rng: random.Random, i: int) -> Case:
    return _dataset_case(c, rng, i, "csv", "csv", c.real_csv)


def _fam_dataset(c: Corpus, rng: random.Random, i: int) -> Case:
    fmt = rng.choice(["c3d", "csv"])
    files = c.c3d if fmt == "c3d" else c.csv
    picked = rng.sample(files, 2)
    base = _one_demo(c, fmt, picked[0])
    ann = json.loads(base["d/annotations.json"])
    other = _one_demo(c, fmt, picked[1])
    ann["demonstrations"] += json.loads(other["d/annotations.json"])["demonstrations"]
    skills = json.loads(base["d/skills.json"])
    skills["skills"] += json.loads(other["d/skills.json"])["skills"]
    base["d/skills.json"] = json.dumps(skills).encode()
    mutated, how = mutate_text(json.dumps(ann, indent=1), rng)
    cmd = rng.choice([["dataset", "show", "{d}"], ["dataset", "show", "{d}", "--arcs"],
                      ["cluster", "fit", "{tmp}/s.db", "--dataset", "{d}"]])
    return Case("dataset", i, cmd,
                files={**base, "d/annotations.json": mutated.encode("utf-8", "surrogateescape"),
                       **{f"d/{p.name}": p.read_bytes() for p in picked}},
                note=how)


def _fam_mesh(c: Corpus, rng: random.Random, i: int) -> Case:
    if not c.meshes:
        return _fam_model(c, rng, i)
    source = rng.choice(c.meshes)
    data, how = mutate_bytes(source.read_bytes(), rng)
    name = "mesh" + source.suffix.lower()
    return Case("mesh", i, ["object", "from-mesh", "{tmp}/" + name, "-o", "{tmp}/out.json",
                            "--allow-open"],
                then=["object", "show", "{tmp}/out.json"], files={name: data},
                note=f"{source.name}: {how}")


def _fam_numbers(c: Corpus, rng: random.Random, i: int) -> Case:
    v = rng.choice(HOSTILE_NUMBERS)
    skills = str(PACKAGE_DATA / "cube_skills.json")
    cmd = rng.choice([
        ["dataset", "synth", "{tmp}/syn", "--n-per-skill", "1", "--format", "csv",
         rng.choice(["--seed", "--n-per-skill", "--mentors", "--rate", "--scale", "--noise",
                     "--dropouts", "--gap-limit"]), v],
        ["object", "show", "cube", "--rtol", v],
        ["states", "cube", "--step", v],
        ["states", "cube", "--step", "90", rng.choice(["--rtol", "--atol", "--angle-tol"]), v],
        ["infer", skills, "--step", "90", rng.choice(["--rtol", "--atol", "--angle-tol"]), v],
        ["plan", skills, "--from", "a:0", "--to", "f:0", "--step", "90", "--at", v, "0"],
        ["plan", skills, "--from", "a:0", "--to", "f:0", "--step", "90", "--cost",
         f"push-roll={v}"],
        ["cluster", "fit", "{tmp}/s.db", "--arrays", str(c.arrays[0]),
         rng.choice(["--n-clusters", "--init-size", "--seed"]), v],
    ])
    return Case("numbers", i, cmd, note=v)


_OPTIONS: list[tuple[list[str], str, list[Any]]] = []


def numeric_options() -> list[tuple[list[str], str, list[Any]]]:
    """Every numeric option of every command: (command path, option, its Range per value),
    from the command tree itself, so that an option added tomorrow is fuzzed too."""
    if not _OPTIONS:
        import click

        from nonprehensile.cli import main
        from nonprehensile.cli.options import Number

        def walk(cmd: click.Command, path: list[str]) -> None:
            for p in cmd.params:
                types = list(p.type.types) if isinstance(p.type, click.Tuple) else [p.type]
                if isinstance(p, click.Option) and any(isinstance(t, Number) for t in types):
                    _OPTIONS.append((path, p.opts[0], [getattr(t, "range", None)
                                                        for t in types]))
            if isinstance(cmd, click.Group):
                ctx = click.Context(cmd)
                for name in cmd.list_commands(ctx):
                    sub = cmd.get_command(ctx, name)
                    if sub is not None:
                        walk(sub, [*path, name])

        walk(main, [])
    return _OPTIONS


def _option_templates(c: Corpus) -> dict[str, list[str]]:
    """Complete command lines of the cheap commands (a valid value then runs them whole);
    other commands get only values their option refuses, checked at parsing."""
    skills = str(PACKAGE_DATA / "cube_skills.json")
    out = {
        "states": ["states", "cube", "--step", "90"],
        "object show": ["object", "show", "cube"],
        "infer": ["infer", skills, "--step", "90"],
        "plan": ["plan", skills, "--from", "a:0", "--to", "f:0", "--step", "90"],
        "skills show": ["skills", "show", skills],
        "cluster fit": ["cluster", "fit", "{tmp}/s.db", "--arrays", str(c.arrays[0])],
        "dataset synth": ["dataset", "synth", "{tmp}/syn", "--n-per-skill", "1", "--format",
                          "csv"],
    }
    if c.meshes:
        out["object from-mesh"] = ["object", "from-mesh", str(c.meshes[0]), "-o",
                                   "{tmp}/o.json"]
    return out


def _fam_options(c: Corpus, rng: random.Random, i: int) -> Case:
    """Any numeric option of any command, given a hostile value or one at its limits: a
    value its range refuses must exit 2 at parsing, on one line naming the option."""
    path, opt, ranges = rng.choice(numeric_options())
    template = _option_templates(c).get(" ".join(path))
    values = []
    invalid = False
    for r in ranges:
        pool = list(HOSTILE_NUMBERS)
        if r is not None:
            for edge in (r.low, r.high):
                if math.isfinite(edge):
                    step = 1 if r.integer else max(abs(edge) * 1e-9, 1e-300)
                    pool += [repr(int(edge) if r.integer else edge),
                             repr((int(edge) if r.integer else edge) + step),
                             repr((int(edge) if r.integer else edge) - step)]
        v = rng.choice(pool)
        if template is None and r is not None:
            # a command that would run for long (physics, a server): refused values only
            for _ in range(20):
                if r.problem(v)[1] is not None:
                    break
                v = rng.choice(pool)
        values.append(v)
        invalid = invalid or (r is not None and r.problem(v)[1] is not None)
    argv = [*(template or path), opt, *values]
    if template is None and not invalid:
        argv = [*path, opt, *values, "--definitely-not-an-option"]  # parse, never run
    return Case("options", i, argv, expect="invalid" if invalid else "any",
                note=f"{' '.join(path)} {opt} {' '.join(values)}")


def _fam_api(c: Corpus, rng: random.Random, i: int) -> Case:
    """The API's constructors with hostile numbers: each must raise the project's errors."""
    return Case("api", i, ["__api__", rng.choice(_API), rng.choice(API_VALUES)], note="api")


#: Values passed to the constructors by the API family (evaluated: ``float('nan')``).
API_VALUES = ["0", "-0.0", "-1", "1e-320", "5e-324", "1e-301", "1e-9", "1e308", "float('inf')",
              "float('nan')", "4294967296", "2**70", "True", "None", "3.5", "'1'", "[]", "1",
              "1e-13", "-float('inf')", "10**400"]


def _scaled(points: Any, v: Any) -> Any:
    """``points * v`` where ``v`` is a real number (else ``v`` itself, as the user gave it)."""
    import numbers

    import numpy as np

    if isinstance(v, numbers.Real) and not isinstance(v, bool) and abs(v) < 1e300:
        with np.errstate(all="ignore"):
            return np.asarray(points) * float(v)
    return v


def _api_calls() -> dict[str, Callable[[Any], object]]:
    import numpy as np

    import nonprehensile as nph

    cube = nph.cube()
    pts = np.random.default_rng(0).normal(size=(40, 3))
    return {
        "cube": lambda v: nph.cube(v),
        "box": lambda v: nph.box(1, 1, v),
        "box3": lambda v: nph.box(v, v, v),
        "prism_n": lambda v: nph.prism(v),
        "prism_r": lambda v: nph.prism(5, v),
        "prism_h": lambda v: nph.prism(5, 1, v),
        "tetrahedron": lambda v: nph.tetrahedron(v),
        "octahedron": lambda v: nph.octahedron(v),
        "hull_scale": lambda v: nph.convex_hull(_scaled(pts, v)),
        "hull_rtol": lambda v: nph.convex_hull(cube.vertices, rtol=v),
        "hull_angle": lambda v: nph.convex_hull(cube.vertices, angle=v),
        "hull_faces": lambda v: nph.convex_hull(cube.vertices, max_faces=v),
        "model_scale": lambda v: nph.Polyhedron(_scaled(cube.vertices, v), dict(cube.faces)),
        "model_rtol": lambda v: nph.Polyhedron(cube.vertices, dict(cube.faces), rtol=v),
        "state": lambda v: nph.State("a", v),
        "step": lambda v: nph.states_by_step(cube, v),
        "margin": lambda v: nph.stable_faces(cube, v),
        "rotate": lambda v: nph.rotate(cube, nph.State("a", 0), v),
        "classes": lambda v: nph.equivalence_classes(cube, nph.states_by_step(cube, 90),
                                                     angle_tol=v),
    }


_API = ["cube", "box", "box3", "prism_n", "prism_r", "prism_h", "tetrahedron", "octahedron",
        "hull_scale", "hull_rtol", "hull_angle", "hull_faces", "model_scale", "model_rtol",
        "state", "step", "margin", "rotate", "classes"]


def run_api_case(case: Case) -> Outcome:
    """One constructor call: it returns, or raises a NonprehensileError; anything else (or
    a run over the time limit) fails."""
    from nonprehensile.errors import NonprehensileError

    _, key, text = case.argv
    value = eval(text)  # the harness's own literals
    case.note = f"{key}({text})"
    t0 = time.perf_counter()
    failure = None
    try:
        with _alarm(TIME_LIMIT):
            _api_calls()[key](value)
    except NonprehensileError:
        pass
    except _Timeout:
        failure = f"ran over {TIME_LIMIT} s"
    except Exception as exc:  # another library's error is what this family looks for
        failure = f"traceback: {type(exc).__name__}: {str(exc)[:200]}"
    return Outcome(case, 0 if failure is None else 1, time.perf_counter() - t0, failure)


def _fam_arrays(c: Corpus, rng: random.Random, i: int) -> Case:
    source = rng.choice(c.arrays)
    data, how = mutate_bytes(source.read_bytes(), rng)
    name = "a" + source.suffix
    cmd = rng.choice([["cluster", "fit", "{tmp}/s.db", "--arrays", "{tmp}/" + name],
                      ["cluster", "add", "{tmp}/seed.db", "--arrays", "{tmp}/" + name]])
    return Case("arrays", i, cmd, files={name: data, "seed.db": c.store.read_bytes()},
                note=f"{source.name}: {how}")


def _fam_store(c: Corpus, rng: random.Random, i: int) -> Case:
    data, how = mutate_bytes(c.store.read_bytes(), rng)
    if rng.random() < 0.6:
        return Case("store", i, ["cluster", "show", "{tmp}/st.db", "--json"],
                    files={"st.db": data}, note=how, same_as=c.store_show)
    return Case("store", i, ["cluster", "add", "{tmp}/st.db", "--arrays", str(c.arrays[0]),
                             "--json"], files={"st.db": data}, note=how)


def _fam_names(c: Corpus, rng: random.Random, i: int) -> Case:
    name = rng.choice(HOSTILE_STRINGS)
    cmd = rng.choice([["object", "show", name], ["object", "from-mesh", name, "-o", "{tmp}/x.json"],
                      ["dataset", "show", name], ["cluster", "show", name],
                      ["skills", "show", name], ["object", "show", "cube", "--rtol", name]])
    return Case("names", i, cmd, note=repr(name))


FAMILIES: dict[str, tuple[Callable[[Corpus, random.Random, int], Case], float]] = {
    # family: (generator, share of the budget)
    "model": (_fam_model, 0.14),
    "skills": (_fam_skills, 0.12),
    "states": (_fam_states, 0.08),
    "dataset": (_fam_dataset, 0.10),
    "c3d": (_fam_c3d, 0.13),
    "csv": (_fam_csv, 0.11),
    "mesh": (_fam_mesh, 0.08),
    "numbers": (_fam_numbers, 0.08),
    "arrays": (_fam_arrays, 0.06),
    "store": (_fam_store, 0.06),
    "names": (_fam_names, 0.04),
    "options": (_fam_options, 0.08),
    "api": (_fam_api, 0.03),
}


def make_case(corpus: Corpus, family: str, index: int, seed: int) -> Case:
    rng = random.Random(f"{seed}/{family}/{index}")
    return FAMILIES[family][0](corpus, rng, index)


# ---------------------------------------------------------------------------------- running
class _Timeout(BaseException):
    """Raised by the alarm: not an Exception, so the code under test cannot swallow it."""


@contextlib.contextmanager
def _alarm(seconds: int) -> Iterator[None]:
    def handler(signum: int, frame: object) -> None:
        raise _Timeout

    old = signal.signal(signal.SIGALRM, handler)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _materialise(case: Case, work: Path) -> list[str]:
    for name, src in case.dirs.items():
        shutil.copytree(src, work / name)
    for rel, data in case.files.items():
        p = work / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    first = next(iter(case.files), None)
    subs = {"{tmp}": str(work), "{f}": str(work / first) if first else "",
            "{d}": str(work / "d")}
    for name in case.dirs:
        subs["{" + name + "}"] = str(work / name)

    def sub(a: str) -> str:
        for k, v in subs.items():
            a = a.replace(k, v)
        return a

    case.argv = [sub(a) for a in case.argv]
    if case.then:
        case.then = [sub(a) for a in case.then]
    return case.argv


def _judge(case: Case, code: int | None, output: str, exc: BaseException | None,
           seconds: float) -> str | None:
    if isinstance(exc, _Timeout) or seconds > TIME_LIMIT:
        return f"ran over {TIME_LIMIT} s"
    if isinstance(exc, MemoryError):
        return "memory: MemoryError"
    if exc is not None and not isinstance(exc, SystemExit):
        return f"traceback: {type(exc).__name__}: {str(exc)[:200]}"
    if "Traceback (most recent call last)" in output:
        return "traceback in output"
    if code not in (0, 2):
        return f"exit code {code}"
    if code == 0 and case.expect == "invalid":
        return "exit 0 on invalid input"
    if code == 2 and "error" not in output.lower():
        return "exit 2 without an error line"
    if code == 0 and case.same_as is not None:
        try:
            doc = json.loads(output[output.index("{"):])
        except ValueError:
            return "exit 0 without its JSON document"
        doc.pop("store", None)
        if doc != case.same_as:
            return "silent corruption: a damaged store read as different data"
    return None


def run_in_process(case: Case, work: Path) -> Outcome:
    from click.testing import CliRunner

    from nonprehensile.cli import main

    argv = _materialise(case, work)
    t0 = time.perf_counter()
    exc: BaseException | None = None
    code: int | None = None
    output = ""
    try:
        with _alarm(TIME_LIMIT):
            r = CliRunner().invoke(main, argv, catch_exceptions=True)
        code, output, exc = r.exit_code, r.output, r.exception
        if exc is not None and not isinstance(exc, SystemExit):
            output += "".join(traceback.format_exception(exc)[-3:])
        if code == 0 and case.then:
            with _alarm(TIME_LIMIT):
                r2 = CliRunner().invoke(main, case.then, catch_exceptions=True)
            if r2.exit_code != 0:
                seconds = time.perf_counter() - t0
                return Outcome(case, code, seconds,
                               "a success wrote a file the next command rejects",
                               r2.output[-400:])
    except _Timeout as e:
        exc = e
    seconds = time.perf_counter() - t0
    return Outcome(case, code, seconds, _judge(case, code, output, exc, seconds), output[-600:])


def _limits() -> None:  # pragma: no cover - runs in the child before exec
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def _os_arg(arg: str) -> bytes:
    """An argument as the bytes a shell would pass: a lone surrogate, which no OS argument can
    hold as text, becomes the invalid UTF-8 bytes that stand for it (the child decodes them
    back to surrogate escapes, as Python does for any undecodable argument)."""
    try:
        return os.fsencode(arg)
    except UnicodeEncodeError:
        return arg.encode("utf-8", "surrogatepass")


def run_subprocess(case: Case, work: Path) -> Outcome:
    argv = _materialise(case, work)
    t0 = time.perf_counter()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    try:
        r = subprocess.run([sys.executable, "-m", "nonprehensile.cli", *map(_os_arg, argv)],
                           capture_output=True, timeout=TIME_LIMIT, preexec_fn=_limits, env=env)
    except subprocess.TimeoutExpired:
        return Outcome(case, None, time.perf_counter() - t0, f"ran over {TIME_LIMIT} s")
    seconds = time.perf_counter() - t0
    output = (r.stdout + r.stderr).decode("utf-8", "replace")
    code = r.returncode
    failure = _judge(case, code, output, None, seconds)
    if code < 0:
        failure = f"killed by signal {-code}"
    elif "MemoryError" in output:
        failure = "memory over 2 GiB"
    return Outcome(case, code, seconds, failure, output[-600:])


@dataclass
class Report:
    counts: Counter[str] = field(default_factory=Counter)
    subprocess_counts: Counter[str] = field(default_factory=Counter)
    exits: Counter[str] = field(default_factory=Counter)
    failures: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0

    def add(self, o: Outcome, sub: bool) -> None:
        self.counts[o.case.family] += 1
        if sub:
            self.subprocess_counts[o.case.family] += 1
        self.exits[f"{o.case.family}:{o.exit_code}"] += 1
        if o.failure:
            self.failures.append({"family": o.case.family, "case": o.case.index,
                                  "subprocess": sub, "failure": o.failure,
                                  "argv": o.case.argv, "note": o.case.note,
                                  "seconds": round(o.seconds, 2), "output": o.detail})

    def to_dict(self) -> dict[str, Any]:
        return {"inputs": sum(self.counts.values()), "failures": len(self.failures),
                "by_family": dict(sorted(self.counts.items())),
                "subprocess_by_family": dict(sorted(self.subprocess_counts.items())),
                "exit_codes": dict(sorted(self.exits.items())),
                "seconds": round(self.seconds, 1), "failure_list": self.failures}


def plan_cases(budget: int, families: list[str] | None = None) -> list[tuple[str, int]]:
    """``budget`` (family, index) pairs, shared by the families' weights, interleaved."""
    names = families or list(FAMILIES)
    weights = {n: FAMILIES[n][1] for n in names}
    total = sum(weights.values())
    per = {n: max(1, round(budget * w / total)) for n, w in weights.items()}
    cases = [(n, i) for n in names for i in range(per[n])]
    random.Random(0).shuffle(cases)
    return cases


def run_campaign(cases: list[tuple[str, int]], *, seed: int = 13, subprocess_every: int = 0,
                 progress: Callable[[int, int, Report], None] | None = None) -> Report:
    """Run ``cases`` in this process (and every ``subprocess_every``-th also as a subprocess)."""
    report = Report()
    t0 = time.perf_counter()
    cwd = Path.cwd()
    with tempfile.TemporaryDirectory(prefix="np-fuzz-") as tmp:
        base = Path(tmp)
        os.chdir(base)  # a relative name a case writes lands here, never in the repository
        corpus = Corpus(base / "corpus")
        for k, (family, index) in enumerate(cases):
            work = base / f"case{k}"
            work.mkdir()
            case = make_case(corpus, family, index, seed)
            try:
                if case.argv[:1] == ["__api__"]:
                    report.add(run_api_case(case), False)
                else:
                    report.add(run_in_process(case, work), False)
                if subprocess_every and k % subprocess_every == 0 and case.family != "api":
                    shutil.rmtree(work)
                    work.mkdir()
                    report.add(run_subprocess(make_case(corpus, family, index, seed), work),
                               True)
            finally:
                shutil.rmtree(work, ignore_errors=True)
            if progress is not None:
                progress(k + 1, len(cases), report)
        os.chdir(cwd)
    report.seconds = time.perf_counter() - t0
    return report


def _child(args: argparse.Namespace, part: int, out: Path) -> None:
    cases = plan_cases(args.budget, args.family and [args.family])[part :: args.jobs]
    last = [time.perf_counter()]

    seen = [0]

    def progress(done: int, total: int, report: Report) -> None:
        for f in report.failures[seen[0]:]:
            print(f"[part {part}] FAIL {f['family']} #{f['case']}: {f['failure']} "
                  f"({f['note']!r})", file=sys.stderr, flush=True)
        seen[0] = len(report.failures)
        if time.perf_counter() - last[0] > 30 or done == total:
            last[0] = time.perf_counter()
            print(f"[part {part}] {done}/{total} inputs, {len(report.failures)} failures",
                  file=sys.stderr, flush=True)

    report = run_campaign(cases, seed=args.seed, subprocess_every=args.subprocess_every,
                          progress=progress)
    out.write_text(json.dumps(report.to_dict(), indent=1))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--budget", type=int, default=10_000, help="number of generated inputs")
    p.add_argument("--jobs", type=int, default=2, help="parallel processes")
    p.add_argument("--seed", type=int, default=13)
    p.add_argument("--subprocess-every", type=int, default=100,
                   help="also run every N-th input as a subprocess (0: never)")
    p.add_argument("--family", choices=sorted(FAMILIES), default=None)
    p.add_argument("--case", type=int, default=None, help="replay one case of --family")
    p.add_argument("--report", type=Path, default=ROOT / "fuzz-report.json")
    p.add_argument("--http-budget", type=int, default=0,
                   help="also this many HTTP requests to the service over SQLite and "
                        "PostgreSQL, alongside (tests/fuzz_http.py; 0: none)")
    p.add_argument("--http-kills", type=int, default=6,
                   help="SIGKILLs of the server mid-upload per store (HTTP family)")
    p.add_argument("--part", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--part-out", type=Path, default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.part is not None:
        _child(args, args.part, args.part_out)
        return 0
    if args.case is not None:
        if not args.family:
            p.error("--case needs --family")
        report = run_campaign([(args.family, args.case)], seed=args.seed, subprocess_every=1)
        print(json.dumps(report.to_dict(), indent=1))
        return 1 if report.failures else 0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="np-fuzz-parts-") as tmp:
        procs = []
        for part in range(args.jobs):
            out = Path(tmp) / f"part{part}.json"
            cmd = [sys.executable, __file__, "--part", str(part), "--part-out", str(out),
                   "--budget", str(args.budget), "--jobs", str(args.jobs), "--seed",
                   str(args.seed), "--subprocess-every", str(args.subprocess_every)]
            if args.family:
                cmd += ["--family", args.family]
            procs.append((subprocess.Popen(cmd), out))
        http = None
        if args.http_budget and not args.family:
            # the service's family runs beside the command line's (its own module and
            # report: tests/fuzz_http.py)
            http_out = Path(tmp) / "http.json"
            http = (subprocess.Popen([sys.executable, str(ROOT / "tests" / "fuzz_http.py"),
                                      "--budget", str(args.http_budget), "--seed",
                                      str(args.seed), "--kills", str(args.http_kills),
                                      "--report", str(http_out)]), http_out)
        merged = Report()
        for proc, out in procs:
            proc.wait()
            if proc.returncode != 0 or not out.exists():
                merged.failures.append({"failure": f"fuzz worker exited {proc.returncode}"})
                continue
            part = json.loads(out.read_text())
            merged.counts.update(part["by_family"])
            merged.subprocess_counts.update(part["subprocess_by_family"])
            merged.exits.update(part["exit_codes"])
            merged.failures.extend(part["failure_list"])
        http_doc = None
        if http is not None:
            http[0].wait()
            if not http[1].exists():
                merged.failures.append({"failure": f"HTTP fuzz exited {http[0].returncode}"})
            else:
                http_doc = json.loads(http[1].read_text())
                for store, r in http_doc["stores"].items():
                    merged.counts[f"http:{store}"] += r["requests"]
                    merged.exits.update({f"http:{store}:{k}": v
                                         for k, v in r["statuses"].items()})
                    merged.failures.extend(r["failure_list"])
    merged.seconds = time.perf_counter() - t0
    doc = merged.to_dict()
    doc["budget"], doc["jobs"], doc["seed"] = args.budget, args.jobs, args.seed
    if http_doc is not None:
        doc["http"] = {k: v for k, v in http_doc.items() if k != "stores"}
        doc["http"]["stores"] = {k: {kk: vv for kk, vv in v.items() if kk != "failure_list"}
                                 for k, v in http_doc["stores"].items()}
    args.report.write_text(json.dumps(doc, indent=1))
    print(f"fuzz: {doc['inputs']} inputs ({sum(merged.subprocess_counts.values())} also as "
          f"subprocesses) in {doc['seconds']:.0f} s on {args.jobs} processes: "
          f"{doc['failures']} failures; report {args.report}")
    for fam in sorted(merged.counts):
        print(f"  {fam:8} {merged.counts[fam]:6d}")
    if http_doc is not None:
        h = http_doc
        print(f"  HTTP: {h['requests']} requests over {', '.join(h['stores']) or 'no store'}; "
              f"{h['kills']} SIGKILLs of the server mid-upload, {h['lost']} acknowledged "
              f"uploads lost; server peak "
              f"{max((r['server_peak_mb'] for r in h['stores'].values()), default=0):.0f} MB")
        for store, why in h["skipped"].items():
            print(f"  HTTP on {store} skipped: {why}")
    for f in merged.failures[:20]:
        print(f"  FAIL {f.get('family')} #{f.get('case')}: {f.get('failure')} "
              f"({f.get('note', '')!r})")
    return 1 if merged.failures else 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "tests"))
    raise SystemExit(main())
