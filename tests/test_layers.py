"""The package's arrows point inward: no module of the core imports one above it.

The core is layered like the paper's list of models: the object model knows nothing of states,
states nothing of maneuvers, the motion model nothing of the object or the planner, and so on
up to the planner and the controller. The edges (files and figures, storage, simulation, the
service, the command line, the main job) import the core, never the other way round; ruff's
banned-import rule keeps third-party edge libraries out of the core, this test keeps the
package's own modules in order. Every import counts, at module level or inside a function,
``TYPE_CHECKING`` blocks included: a lazy import is still an arrow.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "nonprehensile"

#: Rank of each part of the core. A module may import its own part (a top-level module or a
#: subpackage) and parts of lower rank only. Parts of equal rank know nothing of each other.
CORE_RANKS: dict[str, int] = {
    "errors": 0,         # the one exception family
    "checks": 1, "bounds": 1,  # validators and size limits
    "geometry": 2,       # the object model (paper III)
    "motion": 2,         # trajectories, the Hilbert index, clustering (paper VI): no object
    "states": 3,         # states {F_b, theta} and their poses (paper II)
    "equivalence": 4,    # the symmetry group acting on states (paper V)
    "maneuvers": 4,      # exact rolling, rotating, tumbling (paper II)
    "transitions": 5,    # the state-transition graph
    "skills": 6,         # contact events and skills (paper IV)
    "inference": 7,      # undemonstrated transitions (paper V)
    "io": 7,             # model and skills files
    "demonstrations": 8,  # recordings and datasets
    "success_rates": 8,  # measured success rates of transitions (physics' verdict as data)
    "planning": 9,       # plans (paper VII)
    "step_paths": 10,    # a plan step's reference finger paths as a controller tracks them
    "observation": 10,   # what a controller observes (sensor model, contacts from geometry)
    "control": 11,       # the controller's decisions while a plan executes
    "finger_budget": 11,  # the skills and plans a number of fingertips allows
    "transit": 11,       # collision-free, bounded fingertip motions between steps
    "references": 11,    # the edge joining motion clusters, demonstrations and the planner
}

#: The edges: they may import anything of the core; the core imports none of them.
EDGES = {"__init__", "__main__", "cli", "viz", "pipeline", "sim", "service", "export",
         "naming"}


def _part(module: str) -> str:
    """``nonprehensile.motion.store`` -> ``motion``; ``nonprehensile`` -> ``__init__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _module_name(path: Path, package: Path) -> str:
    rel = path.relative_to(package.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__" and len(parts) > 1:
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import of a ``nonprehensile`` module in the file."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "nonprehensile":
                # ``from nonprehensile import motion``: the names are modules or top-level API
                found += [(node.lineno, f"nonprehensile.{a.name}") for a in node.names]
            elif node.module.startswith("nonprehensile."):
                found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names
                      if a.name.startswith("nonprehensile.")]
    return found


def arrows_pointing_up(package: Path = PACKAGE) -> list[str]:
    """Every import of the core that points at a part of higher or equal rank, or an edge."""
    bad = []
    for path in sorted(package.rglob("*.py")):
        name = _module_name(path, package)
        part = _part(name)
        if part in EDGES:
            continue
        if part not in CORE_RANKS:
            bad.append(f"{name}: a new part of the core; give it a rank in CORE_RANKS "
                       f"(tests/test_layers.py) or put it under an edge ({sorted(EDGES)})")
            continue
        for line, target in _imports(path):
            tpart = _part(target)
            if tpart == part:
                continue
            where = f"{path.relative_to(package.parent)}:{line}"
            if tpart in EDGES:
                bad.append(f"{where}: {name} imports the edge {target}")
            elif tpart in CORE_RANKS and CORE_RANKS[tpart] >= CORE_RANKS[part]:
                bad.append(f"{where}: {name} (rank {CORE_RANKS[part]}) imports {target} "
                           f"(rank {CORE_RANKS[tpart]}): the arrow points up")
    return bad


def test_no_arrow_points_up() -> None:
    bad = arrows_pointing_up()
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize(("module", "line"), [
    ("geometry/extra.py", "from nonprehensile.states import State\n"),
    ("motion/extra.py", "def f():\n    from nonprehensile.planning import plan\n"),
    ("states.py", "import nonprehensile.cli.common\n"),
    ("maneuvers.py", "from nonprehensile.equivalence import equivalent\n"),
    ("geometry/extra.py", "from nonprehensile import states\n"),
])
def test_the_check_fails_on_an_arrow_pointing_up(tmp_path: Path, module: str,
                                                  line: str) -> None:
    # a copy of the package with one arrow turned the wrong way (or a part with no rank)
    root = tmp_path / "nonprehensile"
    for path in PACKAGE.rglob("*.py"):
        dst = root / path.relative_to(PACKAGE)
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_text(path.read_text(encoding="utf-8"), encoding="utf-8")
    target = root / module
    target.write_text((target.read_text(encoding="utf-8") if target.exists() else "") + line,
                      encoding="utf-8")
    assert arrows_pointing_up() == []
    assert arrows_pointing_up(root)
