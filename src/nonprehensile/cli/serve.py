"""``nonprehensile serve``: the demonstration service, and its mentors' tokens.

Registered on the main group by :mod:`nonprehensile.cli`. ``serve --store STORE`` runs the HTTP
service (FastAPI on uvicorn) until interrupted; ``serve token create MENTOR --store STORE``
prints a new bearer token once (the database keeps only its hash). STORE is a
``postgresql://`` URL or a SQLite file path, as everywhere a store is named.
"""

from __future__ import annotations

import socket
import sys
from typing import Any

import click

from nonprehensile.cli import HelpGroup
from nonprehensile.cli.common import emit_json, err, handle_errors, out
from nonprehensile.cli.options import count, number
from nonprehensile.errors import InputError

__all__ = ["serve_group"]

#: The default upload size limit, bytes (nonprehensile.service.app.DEFAULT_MAX_BYTES).
_MAX_BYTES = 64 * 1024 * 1024


def _pool(store: str) -> Any:
    try:
        from nonprehensile.service.db import make_pool
    except ImportError:
        raise InputError("the service needs its extra: pip install 'nonprehensile[service]'"
                         ) from None
    return make_pool(store, max_size=2)


_STORE_HELP = ("The service's database: a postgresql://user@host:port/db URL, or a SQLite "
               "file path (created if absent).")
store_option = click.option("--store", required=True, metavar="STORE", help=_STORE_HELP)


@click.group("serve", cls=HelpGroup, invoke_without_command=True)
@click.option("--store", default=None, metavar="STORE", help=_STORE_HELP)
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on (127.0.0.1: this machine only).")
@click.option("--port", type=count(0, 65535), default=8000, show_default=True,
              help="TCP port to listen on.")
@click.option("--dataset", default="cube", show_default=True,
              help="Dataset folder (or bundled name) whose skills file and settings "
                   "(scale, markers, fingers, gap limit) every upload uses.")
@click.option("--max-bytes", type=count(1024, 2**31), default=_MAX_BYTES,
              show_default=True, help="Largest request body, bytes.")
@click.option("--recalibrate-every", type=number(0, 86400, unit="s"), default=5.0,
              show_default=True,
              help="Seconds between checks for arcs due a background recalibration (0: only "
                   "on POST /recalibrate).")
@click.option("--workers", type=count(1, 64), default=8, show_default=True,
              help="Database connections in the pool (PostgreSQL).")
@click.pass_context
@handle_errors
def serve_group(ctx: click.Context, store: str | None, host: str, port: int, dataset: str,
                max_bytes: int, recalibrate_every: float, workers: int) -> None:
    """Run the demonstration service: mentors upload demonstrations into a PostgreSQL
    or SQLite store.

    Without a subcommand, serves http://HOST:PORT until interrupted (OpenAPI at
    /openapi.json). STORE is a PostgreSQL URL or a SQLite file. `serve token create MENTOR
    --store STORE` makes a mentor's token."""
    if ctx.invoked_subcommand is not None:
        return
    if store is None:
        raise InputError("give --store postgresql://user@host:port/db or --store FILE.db (the "
                         "service's database)")
    try:
        import uvicorn

        from nonprehensile.service import ServiceConfig, create_app, load_template, make_pool
    except ImportError:
        raise InputError("the service needs its extra: pip install 'nonprehensile[service]'"
                         ) from None
    from nonprehensile.motion.stores import display_name

    template = load_template(dataset)
    # the listening socket first: an address in use or unknown is bad input (exit 2, one
    # line naming the option), not uvicorn's own exit 3 after the store was opened
    sock = _listen(host, port)
    pool = None
    try:
        pool = make_pool(store, max_size=workers + 2)
        config = ServiceConfig(display_name(store), max_bytes=max_bytes,
                               recalibrate_every=recalibrate_every)
        app = create_app(pool, template, config)
        port = int(sock.getsockname()[1])  # --port 0: the port the system chose
        err.print(f"serving {display_name(store)} on http://{host}:{port} (OpenAPI at "
                  f"/openapi.json, docs at /docs); Ctrl-C stops")
        server = uvicorn.Server(uvicorn.Config(
            app, host=host, port=port, log_level="warning", workers=1,
            limit_concurrency=max(16, 4 * workers), timeout_keep_alive=30))
        try:
            server.run(sockets=[sock])
        except KeyboardInterrupt:
            # Ctrl-C, the documented stop: uvicorn has shut down gracefully and re-raised
            # the interrupt (``uvicorn.run`` catches it likewise); exit 0, not click's
            # "Aborted!" and 1
            return
        if not server.started:  # (uvicorn.run's rule: a server that never started is 3)
            sys.exit(3)
    finally:
        sock.close()
        if pool is not None:
            pool.close()


def _listen(host: str, port: int) -> socket.socket:
    """A socket listening on ``host:port``, or an :class:`InputError` naming them."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM,
                                   flags=socket.AI_PASSIVE)
    except (OSError, UnicodeError) as exc:
        raise InputError(f"--host {host!r}: not an address of this machine "
                         f"({getattr(exc, 'strerror', None) or exc}); give an IP address "
                         "such as 127.0.0.1 or 0.0.0.0") from None
    family, _, _, _, address = infos[0]
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(2048)
        sock.set_inheritable(True)
    except OSError as exc:
        sock.close()
        raise InputError(f"--host {host} --port {port}: cannot listen there "
                         f"({exc.strerror or exc}); give a free --port (0: any free one) "
                         "and an address of this machine") from None
    return sock


@serve_group.group("token")
def token_group() -> None:
    """Mentors' bearer tokens: create, list, revoke."""


@token_group.command("create")
@click.argument("mentor")
@store_option
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
@handle_errors
def token_create(mentor: str, store: str, as_json: bool) -> None:
    """Create a bearer token for MENTOR and print it (only once: keep it)."""
    from nonprehensile.service.db import create_token

    pool = _pool(store)
    try:
        with pool.connection() as conn:
            token = create_token(conn, mentor)
    finally:
        pool.close()
    if as_json:
        emit_json({"mentor": mentor.strip(), "token": token})
        return
    out.print(token)
    err.print(f"token for {mentor.strip()!r}: send it as 'Authorization: Bearer <token>'; "
              "it is not shown again")


@token_group.command("list")
@store_option
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
@handle_errors
def token_list(store: str, as_json: bool) -> None:
    """List the mentors and their number of live tokens (never the tokens)."""
    from nonprehensile.service.db import list_tokens

    pool = _pool(store)
    try:
        with pool.connection() as conn:
            rows = list_tokens(conn)
    finally:
        pool.close()
    if as_json:
        emit_json({"mentors": rows})
        return
    for r in rows:
        out.print(f"{r['mentor']}: {r['tokens']} live token(s), since {r['since']}")


@token_group.command("revoke")
@click.argument("mentor")
@store_option
@handle_errors
def token_revoke(mentor: str, store: str) -> None:
    """Revoke every token of MENTOR."""
    from nonprehensile.service.db import revoke_tokens

    pool = _pool(store)
    try:
        with pool.connection() as conn:
            n = revoke_tokens(conn, mentor)
    finally:
        pool.close()
    err.print(f"revoked {n} token(s) of {mentor.strip()!r}")
