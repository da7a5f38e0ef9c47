"""Skill names from motion (issue 23 item 4): ties between skills with the same events and
states (roll-arc / roll-pull, tumble-lift / tumble-twist) broken by the motion model.

The truth is the generator's: each synthetic take knows its skill. The library is the bundled
dataset (recorded from the MuJoCo simulation, another generator of takes than the synthetic
one annotated here), or the folder's own recordings that name their skill.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from nonprehensile.demonstrations.annotate import annotate_dataset
from nonprehensile.demonstrations.dataset import load_dataset, save_dataset
from nonprehensile.demonstrations.synth import synthesize_dataset
from nonprehensile.io import load_document, save_document

pytest.importorskip("sklearn", reason="the motion model's clustering needs scikit-learn")
from nonprehensile.naming import TIE_DOUBT, MotionNamer

TIED = {"roll-arc", "roll-pull", "tumble-lift", "tumble-twist"}


def _folder(root: Path, n: int, seed: int, named: int = 0) -> tuple[Path, dict[str, str]]:
    """A generated folder, object tracked, its annotations stripped to the recordings (the
    first ``named`` of each skill keep their skill); returns the truth file -> skill."""
    ds = synthesize_dataset(seed=seed, n_per_skill=n, track_object=True)
    save_dataset(ds, root, trajectory_format="c3d")
    truth = {d.file: d.skill.name for d in ds.demonstrations}
    doc = load_document(root / "annotations.json")
    seen: dict[str, int] = {}
    entries = []
    for d in doc["demonstrations"]:
        e = {"file": d["file"], "mentor": d["mentor"]}
        seen[d["skill"]] = seen.get(d["skill"], 0) + 1
        if seen[d["skill"]] <= named:
            e["skill"] = d["skill"]
        entries.append(e)
    doc["demonstrations"] = entries
    save_document(doc, root / "annotations.json")
    return root, truth


@pytest.fixture(scope="module")
def cube_namer() -> MotionNamer:
    return MotionNamer(load_dataset("cube"))


def test_the_bundled_library_names_the_tied_skills(tmp_path: Path,
                                                   cube_namer: MotionNamer) -> None:
    folder, truth = _folder(tmp_path / "ds", 2, seed=5)
    plain = annotate_dataset(folder)
    named = annotate_dataset(folder, namer=cube_namer)
    tied = [r for r in plain.recordings if truth[r.file] in TIED]
    assert tied and all(len(r.result.candidates) == 2 for r in tied)
    assert all(r.result.skill == truth[r.file] for r in named.recordings)
    for r in named.recordings:
        assert not any(TIE_DOUBT in d for d in r.result.doubts), r.result.doubts
    # the complete annotations name the skill found
    by_file = {e["file"]: e["skill"] for e in named.annotations["demonstrations"]}
    assert by_file == truth


def test_an_ambiguous_motion_keeps_the_doubt(tmp_path: Path, cube_namer: MotionNamer) -> None:
    folder, truth = _folder(tmp_path / "ds", 1, seed=6)
    cube_namer.margin, margin = 1e9, cube_namer.margin
    try:
        rep = annotate_dataset(folder, namer=cube_namer)
    finally:
        cube_namer.margin = margin
    for r in rep.recordings:
        if truth[r.file] in TIED:
            assert any(TIE_DOUBT in d for d in r.result.doubts)
            assert any("does not tell them apart either" in d for d in r.result.doubts)


def test_the_folders_own_named_recordings_name_the_rest(tmp_path: Path) -> None:
    # 3 named takes of each tied skill: 6 pieces on each shared arc, enough to cluster
    folder, truth = _folder(tmp_path / "ds", 4, seed=8, named=3)
    rep = annotate_dataset(folder, namer_from=MotionNamer)
    doc = load_document(folder / "annotations.json")
    unnamed = {e["file"] for e in doc["demonstrations"] if "skill" not in e}
    rest = [r for r in rep.recordings if r.file in unnamed]
    assert len(rest) == 6
    assert all(r.result.skill == truth[r.file] for r in rest), [
        (r.file, r.result.skill, r.result.doubts) for r in rest]


def test_cli_motions_library_missing_is_one_line_exit_2(tmp_path: Path) -> None:
    folder, _ = _folder(tmp_path / "ds", 1, seed=9)
    r = subprocess.run([sys.executable, "-m", "nonprehensile.cli", "dataset", "annotate",
                        str(folder), "-o", str(folder / "annotations.json"), "--motions",
                        str(tmp_path / "nowhere")], capture_output=True, text=True, check=False)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "nowhere" in lines[0], r.stderr
