"""Helpers of the tests that run ``nonprehensile serve`` as a process of its own."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

import pytest


def free_port() -> int:
    """A port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve(store: str, port: int, *options: str) -> subprocess.Popen[bytes]:
    """``serve --store STORE`` on 127.0.0.1:PORT, no background recalibration, plus
    ``options``; its stderr kept for a failure's message."""
    return subprocess.Popen(
        [sys.executable, "-m", "nonprehensile.cli", "serve", "--store", store, "--host",
         "127.0.0.1", "--port", str(port), "--recalibrate-every", "0", *options],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})


def wait_up(url: str, proc: subprocess.Popen[bytes]) -> None:
    """Wait until ``proc`` answers ``GET /health`` at ``url`` (30 s at most)."""
    import httpx

    for _ in range(300):
        if proc.poll() is not None:  # ours exited (its port taken?): say so, with its words
            pytest.fail("the server exited: " + (proc.stderr.read().decode()[:500]
                                                 if proc.stderr else ""))
        try:
            if httpx.get(f"{url}/health", timeout=1).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.1)  # (a refused connection and a non-200 reply wait alike)
    pytest.fail("the server did not come up: " + (proc.stderr.read().decode()[:500]
                                                  if proc.stderr else ""))
