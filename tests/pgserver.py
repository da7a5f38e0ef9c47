"""A PostgreSQL server for the tests: the one `.ci/run` started (``NONPREHENSILE_TEST_PG``), or
one started here with `.ci/start-postgres` in a temporary folder, or none (tests skip, saying
why)."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

REPO = Path(__file__).resolve().parents[1]
ENV = "NONPREHENSILE_TEST_PG"


def with_database(url: str, dbname: str) -> str:
    """The same server URL naming another database."""
    parts = urlsplit(url)
    return urlunsplit(parts._replace(path=f"/{dbname}"))


def server() -> Iterator[str | None]:
    """Yield a server URL (or a reason to skip, prefixed by 'skip:'), stopping what we start."""
    url = os.environ.get(ENV)
    if url:
        yield url
        return
    try:
        import psycopg  # noqa: F401
    except ImportError:
        yield "skip: psycopg is not installed (pip install 'nonprehensile[pg]')"
        return
    script = REPO / ".ci" / "start-postgres"
    tmp = tempfile.mkdtemp(prefix="np-pg-")
    try:
        proc = subprocess.run([str(script), tmp], capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as exc:
        yield f"skip: no PostgreSQL server: {script} failed ({exc}) and {ENV} is not set"
        return
    if proc.returncode != 0:
        shutil.rmtree(tmp, ignore_errors=True)
        yield (f"skip: no PostgreSQL server: {script} failed ({proc.stderr.strip()}) and {ENV} "
               "is not set")
        return
    try:
        yield proc.stdout.strip().splitlines()[-1]
    finally:
        subprocess.run([str(REPO / ".ci" / "stop-postgres"), tmp], capture_output=True,
                       timeout=120, check=False)
        shutil.rmtree(tmp, ignore_errors=True)


def fresh_database(url: str) -> Iterator[str]:
    """A new empty database on the server, dropped afterwards."""
    import psycopg

    name = f"t_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute(f"CREATE DATABASE {name}")
    try:
        yield with_database(url, name)
    finally:
        with psycopg.connect(url, autocommit=True) as conn:
            conn.execute(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)")
