"""Rebuild the bundled cube demonstrations (``src/nonprehensile/data/cube_demos``).

Run from the repository root: ``.venv/bin/python docs/make_cube_demos.py OUT_DIR`` (about a
minute or two). Skills whose takes succeed in physics are recorded from the MuJoCo simulation
(``nonprehensile.sim.record``: the fingers push the simulated object, events and times come
from physics); the two tumbling skills, which physics refutes as written (the pinch on two
adjacent faces slides the cube off its pivot vertex; at most 2 takes in 12 keep every
contact), are the kinematic generator's (``demonstrations.synth``, same seed as before), and
are marked so in ``docs/physics.md``. The object markers are left out to keep the folder
about 4 MB (``nonprehensile simulate record`` writes them).
"""

from __future__ import annotations

import sys
from dataclasses import replace

from nonprehensile.demonstrations.dataset import DEFAULT_MARKERS, save_dataset
from nonprehensile.demonstrations.synth import DEFAULT_SEED, _bundled_skills, synthesize_dataset
from nonprehensile.sim.record import record_dataset

PHYSICS = ("push-roll", "roll-arc", "roll-pull", "twist")


def main(out_dir: str) -> None:
    skills = _bundled_skills()
    recorded, stats = record_dataset(skills, seed=DEFAULT_SEED, only=PHYSICS,
                                     with_object_markers=False, max_attempts=100)
    kinematic = synthesize_dataset(seed=DEFAULT_SEED, skills_file=skills)
    by_skill = {s.name: [d for d in recorded.demonstrations if d.skill.name == s.name]
                or [d for d in kinematic.demonstrations if d.skill.name == s.name]
                for s in recorded.skills}
    demos = tuple(d for s in recorded.skills for d in by_skill[s.name])
    save_dataset(replace(recorded, demonstrations=demos, object_markers={}), out_dir,
                 markers=DEFAULT_MARKERS)
    for name, st in stats.items():
        print(f"{name}: kept {st['kept']} of {st['tried']} physics takes")


if __name__ == "__main__":
    main(sys.argv[1])
