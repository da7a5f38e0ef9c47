"""Rebuild the bundled cube demonstrations (``src/nonprehensile/data/cube_demos``).

Run from the repository root: ``.venv/bin/python docs/make_cube_demos.py OUT_DIR`` (a minute
or two). Every skill is recorded from the MuJoCo simulation (``nonprehensile.sim.record``:
the fingers push the simulated object, events and times come from physics; the tumbling
skills pinch the opposite faces ``e`` and ``b``, docs/physics.md). The object markers are left
out to keep the folder about 4 MB (``nonprehensile simulate record`` writes them).
"""

from __future__ import annotations

import sys
from dataclasses import replace

from nonprehensile.demonstrations.dataset import DEFAULT_MARKERS, save_dataset
from nonprehensile.demonstrations.synth import DEFAULT_SEED, _bundled_skills
from nonprehensile.sim.record import record_dataset


def main(out_dir: str) -> None:
    # the bundled model is the unit cube; the takes are of a 5 cm cube (scale 0.05)
    recorded, stats = record_dataset(_bundled_skills(), seed=DEFAULT_SEED, scale=0.05,
                                     with_object_markers=False, max_attempts=100)
    save_dataset(replace(recorded, object_markers={}), out_dir, markers=DEFAULT_MARKERS)
    for name, st in stats.items():
        print(f"{name}: kept {st['kept']} of {st['tried']} physics takes "
              f"({st['fragile']} fragile)")


if __name__ == "__main__":
    main(sys.argv[1])
