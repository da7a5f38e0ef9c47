"""A sweep's provenance names the git commit it was computed at; without git, outside a
checkout, or when git hangs, it says "unknown (why)" at once and never fails the job."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import time
from pathlib import Path

import pytest

from nonprehensile.sim.report_runs import _commit

GIT = shutil.which("git")
needs_git = pytest.mark.skipif(GIT is None, reason="git is not installed here")


def _fake_git(folder: Path, body: str) -> None:
    """A program named git on a PATH of its own."""
    folder.mkdir()
    exe = folder / "git"
    exe.write_text(f"#!/bin/sh\n{body}\n")
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)


def _git(cwd: Path, *args: str) -> str:
    env = {k: v for k, v in os.environ.items() if not k.startswith("GIT_")}
    return subprocess.run([str(GIT), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                          cwd=cwd, check=True, capture_output=True, text=True,
                          env=env).stdout.strip()


def test_without_git_the_commit_is_unknown(monkeypatch: pytest.MonkeyPatch,
                                          tmp_path: Path) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))  # a PATH with no git on it
    assert _commit() == "unknown (no 'git' program on PATH)"


def test_a_git_that_hangs_or_fails_is_unknown_at_once(monkeypatch: pytest.MonkeyPatch,
                                                      tmp_path: Path) -> None:
    # a child of git holding its pipes (a hook, an fsmonitor) must not hang the read either
    _fake_git(tmp_path / "hang", "sleep 60 &\nsleep 60")
    monkeypatch.setenv("PATH", f"{tmp_path / 'hang'}{os.pathsep}{os.environ['PATH']}")
    t0 = time.monotonic()
    assert _commit(timeout=0.5) == "unknown (git did not answer in 0.5 s)"
    assert time.monotonic() - t0 < 10  # the 60 s git was killed, not waited for
    _fake_git(tmp_path / "fail", "echo 'fatal: broken' >&2; exit 128")
    monkeypatch.setenv("PATH", f"{tmp_path / 'fail'}{os.pathsep}{os.environ['PATH']}")
    assert _commit().startswith("unknown (")
    _fake_git(tmp_path / "junk", "echo 'not a hash'")  # answers, but not with a commit
    monkeypatch.setenv("PATH", f"{tmp_path / 'junk'}{os.pathsep}{os.environ['PATH']}")
    assert _commit() == "unknown (git could not read this checkout's commit)"


@needs_git
def test_outside_a_checkout_or_untracked_the_commit_is_unknown(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    pkg = tmp_path / "site-packages" / "nonprehensile"
    (pkg / "sim").mkdir(parents=True)
    (pkg / "sim" / "report_runs.py").write_text("# a copy\n")
    # (were the temporary folder inside some repository, that one would not track this
    # file either: the answer is the same)
    outside = _commit(root=pkg)
    assert outside == "unknown (not a git checkout of nonprehensile's source)"
    # a repository around an installed copy that it does not track (a venv in a checkout)
    _git(tmp_path, "init", "-q")
    (tmp_path / "README").write_text("x\n")
    _git(tmp_path, "add", "README")
    _git(tmp_path, "commit", "-q", "-m", "x")
    assert _commit(root=pkg) == outside
    # a GIT_DIR in the caller's environment (a hook's) does not redirect it
    monkeypatch.setenv("GIT_DIR", str(tmp_path / ".git"))
    assert _commit(root=pkg) == outside


@needs_git
def test_in_a_checkout_the_commit_is_gits_head_and_dirty_when_changed(
        tmp_path: Path) -> None:
    pkg = tmp_path / "src" / "nonprehensile"
    (pkg / "sim").mkdir(parents=True)
    (pkg / "sim" / "report_runs.py").write_text("# the executor\n")
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "commit", "-q", "-m", "x")
    head = _git(tmp_path, "rev-parse", "HEAD")
    assert _commit(root=pkg) == head
    (pkg / "sim" / "report_runs.py").write_text("# changed\n")
    assert _commit(root=pkg) == head + "+dirty"
