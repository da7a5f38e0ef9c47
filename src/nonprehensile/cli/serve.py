"""``nonprehensile serve``: the demonstration service, and its mentors' tokens.

Registered on the main group by :mod:`nonprehensile.cli`. ``serve --store STORE`` runs the HTTP
service (FastAPI on uvicorn) until interrupted; ``serve token create MENTOR --store STORE``
prints a new bearer token once (the database keeps only its hash). STORE is a
``postgresql://`` URL or a SQLite file path, as everywhere a store is named.
"""

from __future__ import annotations

import errno
import socket
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import click

from nonprehensile.cli import HelpGroup
from nonprehensile.cli.common import emit_json, err, handle_errors, out
from nonprehensile.cli.options import count, number
from nonprehensile.errors import InputError

if TYPE_CHECKING:
    from nonprehensile.service.db import Pool

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
              help="Address to listen on (127.0.0.1: this machine only); a name such as "
                   "localhost listens on each of its addresses (127.0.0.1 and ::1).")
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
@click.option("--shutdown-timeout", type=count(0, 3600), default=5, show_default=True,
              help="Seconds a stop (Ctrl-C, SIGTERM) waits for the requests in flight; then "
                   "those still waiting on the database are cut (their transactions roll "
                   "back) and the server exits.")
@click.pass_context
@handle_errors
def serve_group(ctx: click.Context, store: str | None, host: str, port: int, dataset: str,
                max_bytes: int, recalibrate_every: float, workers: int,
                shutdown_timeout: int) -> None:
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
    socks = _listen(host, port)
    pool = None
    try:
        pool = make_pool(store, max_size=workers + 2)
        config = ServiceConfig(display_name(store), max_bytes=max_bytes,
                               recalibrate_every=recalibrate_every,
                               shutdown_timeout=shutdown_timeout)
        from nonprehensile.service.ingest import Registry

        registry = Registry(pool, template)
        checked = registry.check_arcs()  # a store of another skills file: exit 2, one line
        if checked.adopted:
            err.print(f"recorded the arc of {len(checked.adopted)} arc store(s) written before "
                      "stores recorded their arcs (their segments checked against this skills "
                      "file)")
        if checked.updated:
            err.print(f"rewrote the recorded arc of {len(checked.updated)} arc store(s) whose "
                      "skills' motions changed in the skills file (their segments checked "
                      f"against it): {', '.join(checked.updated)}")
        app = create_app(pool, template, config, registry=registry)
        port = int(socks[0].getsockname()[1])  # --port 0: the port the system chose
        # an IPv6 address in brackets, as a URL writes it (http://[::1]:8000, not http://::1:8000)
        shown = f"[{host}]" if ":" in host else host
        err.print(f"serving {display_name(store)} on http://{shown}:{port} (OpenAPI at "
                  f"/openapi.json, docs at /docs); Ctrl-C stops")
        server = _server(uvicorn.Config(
            app, host=host, port=port, log_level="warning", workers=1,
            limit_concurrency=max(16, 4 * workers), timeout_keep_alive=30,
            # uvicorn's own cancel, a 500 for a request still running, only when the cut
            # did not end it
            timeout_graceful_shutdown=shutdown_timeout + 2), pool, shutdown_timeout)
        try:
            server.run(sockets=socks)
        except KeyboardInterrupt:
            # Ctrl-C, the documented stop: uvicorn has shut down gracefully and re-raised
            # the interrupt (``uvicorn.run`` catches it likewise); exit 0, not click's
            # "Aborted!" and 1
            return
        if not server.started:  # (uvicorn.run's rule: a server that never started is 3)
            sys.exit(3)
    finally:
        for sock in socks:
            sock.close()
        if pool is not None:
            pool.close()


def _server(config: Any, pool: Pool, timeout: float) -> Any:
    """uvicorn's server that cuts ``pool``'s connections still in use ``timeout`` s into its
    shutdown, and closes the pool at its end.

    uvicorn's shutdown waits for the requests in flight, then (``config``'s
    ``timeout_graceful_shutdown``, a little longer than ``timeout``) cancels them: each
    answers a 500, and one blocked in a query (on a database that never answers) runs on in
    its thread, which the process then waits for. Cut first (:meth:`PostgresPool.cut`), each
    such request answers its 503 and ends, its transaction rolled back by the server: a stop
    never waits much longer than ``timeout``.
    """
    import asyncio

    import uvicorn

    class Server(uvicorn.Server):
        async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
            cut = asyncio.get_running_loop().call_later(timeout, pool.cut)
            try:
                await super().shutdown(sockets=sockets)
            finally:
                cut.cancel()
                pool.abort()

    return Server(config)


def _listen(host: str, port: int) -> list[socket.socket]:
    """Sockets listening on every address of ``host`` at ``port``, or an
    :class:`InputError` naming them.

    A name may have several addresses: ``localhost`` is ``::1`` and ``127.0.0.1`` on many
    machines, ``::1`` first. Binding only the first would leave ``http://127.0.0.1:PORT``
    refused, so every address gets its socket, as uvicorn's own ``--host localhost`` does
    (asyncio's ``create_server``), all on one port (``--port 0``: the first one's). An
    address this machine cannot have (``::1`` without IPv6) is left out when another is
    bound; any other failure (a port in use on any of them) refuses the whole.
    """
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM,
                                   flags=socket.AI_PASSIVE)
    except (OSError, UnicodeError) as exc:
        raise InputError(f"--host {host!r}: not an address of this machine "
                         f"({getattr(exc, 'strerror', None) or exc}); give an IP address "
                         "such as 127.0.0.1 or 0.0.0.0") from None
    addresses = list(dict.fromkeys((info[0], info[4]) for info in infos))
    # --port 0 on several addresses: the port the system chose for the first may be taken on
    # another (by some other program); a few more tries find one free on all
    tries = 5 if port == 0 and len(addresses) > 1 else 1
    while True:
        tries -= 1
        try:
            return _bind_all(addresses)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE and tries > 0:
                continue
            raise InputError(f"--host {host} --port {port}: cannot listen there "
                             f"({exc.strerror or exc}); give a free --port (0: any free one) "
                             "and an address of this machine") from None


def _bind_all(addresses: Sequence[tuple[Any, Any]]) -> list[socket.socket]:
    """A listening socket on each ``(family, address)``, all on the first one's port.

    Raises
    ------
    OSError
        One could not be bound (none is left open), or none of them exists here.
    """
    several_families = len({family for family, _ in addresses}) > 1
    socks: list[socket.socket] = []
    unavailable: OSError | None = None
    for family, address in addresses:
        if socks:  # --port 0: the others on the port the system chose for the first
            address = (address[0], socks[0].getsockname()[1], *address[2:])
        try:
            sock = socket.socket(family, socket.SOCK_STREAM)
        except OSError as exc:  # no IPv6 in this kernel
            unavailable = unavailable or exc
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6 and several_families:
                # beside its IPv4 socket, the IPv6 one takes IPv6 only: a dual-stack socket
                # would claim the IPv4 port too and the second bind fail (asyncio does the
                # same); alone (--host ::) it keeps the system's default
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
            sock.listen(2048)
            sock.set_inheritable(True)
        except OSError as exc:
            sock.close()
            if exc.errno in (errno.EADDRNOTAVAIL, errno.EAFNOSUPPORT):
                unavailable = unavailable or exc  # this machine has no such address
                continue
            for s in socks:
                s.close()
            raise
        socks.append(sock)
    if not socks:
        raise unavailable or OSError("no address to listen on")
    return socks


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
