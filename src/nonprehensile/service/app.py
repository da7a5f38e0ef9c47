"""The HTTP service: FastAPI application over a :class:`~nonprehensile.service.ingest.Registry`
(on PostgreSQL or one SQLite file).

Every POST and DELETE needs a mentor's bearer token (``Authorization: Bearer np_...``, made by
``nonprehensile serve token create MENTOR``); GETs are open. Errors answer
``{"detail": "<one line>", "problems": [...]}`` with a 4xx status: 400 malformed request,
401 no or unknown token, 403 another mentor's data, 404 unknown upload, 413 body too large,
422 a demonstration that ``dataset show`` would reject (the same lines), 409 an upload to an
arc whose store holds another arc (a store written under another skills file). A database
that does not answer (down, restarted, a connection lost, every connection busy) answers 503
with one line and ``Retry-After``, never a wait: see :class:`~nonprehensile.service.db.
PostgresPool`.
"""


import json
import logging
import threading
from collections.abc import Awaitable, Callable, MutableMapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from fastapi import Depends, FastAPI, File, Form, Header, Request, UploadFile
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

import nonprehensile
from nonprehensile.errors import InputError, NonprehensileError
from nonprehensile.io import parse_document
from nonprehensile.service.db import Pool, mentor_of, snapshot
from nonprehensile.service.errors import Forbidden, Rejected, Unavailable, one_line, public_text
from nonprehensile.service.ingest import (
    Registry,
    Template,
    archive_upload,
    registration_error,
    single_upload,
)

__all__ = ["DEFAULT_MAX_BYTES", "ServiceConfig", "create_app"]

log = logging.getLogger("nonprehensile.service")

#: Largest request body accepted, bytes (a C3D take is ~100 kB; a dataset archive some MB).
DEFAULT_MAX_BYTES = 64 * 1024 * 1024

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


@dataclass(frozen=True)
class ServiceConfig:
    """How the service runs.

    Attributes
    ----------
    store : str
        The database: a PostgreSQL URL (shown without its password) or a SQLite file.
    max_bytes : int
        Largest request body.
    recalibrate_every : float
        Seconds between checks for arcs due a background recalibration (0: never by itself;
        ``POST /recalibrate`` still runs one).
    shutdown_timeout : float
        Seconds the application's shutdown waits for a background recalibration to end
        (``serve`` waits as long for the requests in flight).
    """

    store: str
    max_bytes: int = DEFAULT_MAX_BYTES
    recalibrate_every: float = 5.0
    shutdown_timeout: float = 5.0


class BodyLimit:
    """ASGI middleware: refuses a body over ``max_bytes`` with 413, by its Content-Length or
    while it streams (a chunked upload has none), before the endpoint reads it whole."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        length = headers.get(b"content-length")
        if length is not None:
            try:
                too_big = int(length) > self.max_bytes
            except ValueError:
                too_big = False
            if too_big:
                await self._refuse(send)
                return
        seen = 0
        refused = False
        started = False

        async def limited() -> Message:
            nonlocal seen, refused
            msg = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > self.max_bytes:
                    refused = True
                    raise _TooLarge
            return msg

        async def guarded_send(msg: Message) -> None:
            nonlocal started
            if refused:
                # the application answered the body it could not read with its own error
                # (FastAPI: 400 "error parsing the body"): the answer is ours, a 413
                if msg["type"] == "http.response.start" and not started:
                    started = True
                    await self._refuse(send)
                return
            if msg["type"] == "http.response.start":
                started = True
            await send(msg)

        try:
            await self.app(scope, limited, guarded_send)
        except Exception:
            if not refused:
                raise
            if not started:
                await self._refuse(send)

    async def _refuse(self, send: Send) -> None:
        body = json.dumps({"detail": f"the request body is larger than {self.max_bytes} bytes",
                           "problems": []}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})


class _TooLarge(Exception):
    pass


def _error(status: int, detail: str, problems: list[str] | None = None,
           hidden: tuple[Path, ...] = ()) -> JSONResponse:
    """The one reply of every refusal: one line, and nothing of the server's folders."""
    return JSONResponse({"detail": public_text(one_line(detail), hidden),
                         "problems": [public_text(one_line(p), hidden) for p in problems or []]},
                        status_code=status)


class Recalibrator:
    """The background recalibration thread: checks for due arcs every ``every`` seconds, and
    on request. Uploads never wait for it (see :meth:`Registry.recalibrate`)."""

    def __init__(self, registry: Registry, every: float) -> None:
        self.registry = registry
        self.every = every
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.runs: list[dict[str, Any]] = []
        self.last_error: str | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="recalibrate", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 30.0) -> None:
        """Stop the thread, waiting up to ``timeout`` s for a recalibration under way (one
        blocked on the database is left: the thread is a daemon, and the connection it waits
        on is cut when the server stops; its transaction rolls back)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout)

    def request(self) -> None:
        self._wake.set()

    def run_once(self, force: bool = False) -> list[dict[str, Any]]:
        done = []
        arcs = self.registry.arcs_due()
        if force:
            arcs = sorted({a["arc"] for a in self.registry.clusters()})
        for arc in arcs:
            done.append(self.registry.recalibrate(arc))
        self.runs.extend(done)
        del self.runs[:-100]
        return done

    def _loop(self) -> None:
        while not self._stop.is_set():
            forced = self._wake.wait(self.every if self.every > 0 else None)
            self._wake.clear()
            if self._stop.is_set():
                return
            try:
                self.run_once(force=forced)
            except Unavailable as exc:
                # the database is down: one line each time, not a traceback every few seconds
                self.last_error = f"{type(exc).__name__}: {exc}"
                log.warning("background recalibration: %s (%s)", exc, exc.reason)
            except Exception as exc:  # a failed recalibration must not kill the thread
                self.last_error = f"{type(exc).__name__}: {exc}"
                log.exception("background recalibration failed")


def create_app(pool: Pool, template: Template, config: ServiceConfig, *,
               registry: Registry | None = None, background: bool = True) -> FastAPI:
    """The FastAPI application (``background=False``: no recalibration thread, for tests).

    Raises
    ------
    ArcMismatch
        If an arc's store holds another arc than the skills file gives its name
        (:meth:`Registry.check_arcs`, unless ``registry`` passed it already, as ``serve``'s
        does): the service never starts on it.
    """
    reg = registry or Registry(pool, template)
    # before anything is served: a store written under another skills file is refused here,
    # not found out by filing segments into another skill's arc (once: `serve` checked already)
    if not reg.arcs_checked:
        reg.check_arcs()
    recal = Recalibrator(reg, config.recalibrate_every)

    from contextlib import asynccontextmanager

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> Any:
        if background:
            recal.start()
        yield
        recal.stop(timeout=config.shutdown_timeout)

    app = FastAPI(
        title="nonprehensile demonstration service",
        version=nonprehensile.__version__ if hasattr(nonprehensile, "__version__") else "0",
        description="Mentors upload demonstrations; each is validated as `nonprehensile "
                    "dataset show` validates, segmented at its contact events and registered "
                    "to the clusters of its skill-graph arcs.",
        lifespan=lifespan,
    )
    app.state.registry = reg
    app.state.recalibrator = recal
    # the service's dataset (its skills file's folder): no reply shows where it is
    hidden = (Path(str(template.top.get("skills", "."))).parent,)

    @app.exception_handler(Rejected)
    async def _rejected(request: Request, exc: Rejected) -> JSONResponse:
        return _error(exc.status, str(exc), exc.problems, hidden)

    @app.exception_handler(Forbidden)
    async def _forbidden(request: Request, exc: Forbidden) -> JSONResponse:
        return _error(403, str(exc), hidden=hidden)

    @app.exception_handler(InputError)
    async def _input(request: Request, exc: InputError) -> JSONResponse:
        return _error(422, str(exc), hidden=hidden)

    @app.exception_handler(Unavailable)
    async def _unavailable(request: Request, exc: Unavailable) -> JSONResponse:
        # the client's line names nothing of the server; the driver's words go to the log
        log.warning("%s %s: 503: %s", request.method, request.url.path, one_line(exc.reason))
        resp = _error(503, str(exc), hidden=hidden)
        resp.headers["Retry-After"] = "5"
        return resp

    @app.exception_handler(NonprehensileError)
    async def _other(request: Request, exc: NonprehensileError) -> JSONResponse:
        return _error(503, str(exc), hidden=hidden)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        lines = []
        for e in exc.errors():
            where = ".".join(str(p) for p in e.get("loc", ()))
            lines.append(f"{where}: {e.get('msg', 'invalid')}")
        return _error(400, "; ".join(lines) or "malformed request", lines)

    def mentor(authorization: Annotated[str | None, Header()] = None) -> str:
        if not authorization or not authorization.startswith("Bearer "):
            raise _Unauthorized("a mentor's token is needed: send 'Authorization: Bearer "
                                "<token>' (create one with `nonprehensile serve token create`)")
        with pool.connection() as conn:
            who = mentor_of(conn, authorization.removeprefix("Bearer ").strip())
        if who is None:
            raise _Unauthorized("unknown or revoked token")
        return who

    @app.exception_handler(_Unauthorized)
    async def _unauth(request: Request, exc: _Unauthorized) -> JSONResponse:
        resp = _error(401, str(exc))
        resp.headers["WWW-Authenticate"] = "Bearer"
        return resp

    Mentor = Annotated[str, Depends(mentor)]

    store_kind = _public_store(config.store)

    @app.get("/health", operation_id="health")
    def health() -> dict[str, Any]:
        """Liveness, whether the database answers, and its kind (never where it is)."""
        with pool.connection() as conn:
            conn.execute("SELECT 1")
        return {"status": "ok", "store": store_kind,
                "recalibration_error": None if recal.last_error is None
                else public_text(recal.last_error, hidden)}

    @app.post("/demonstrations", status_code=201, operation_id="uploadDemonstration",
              responses=_upload_links("#/upload"))
    def upload_demonstration(
        who: Mentor,
        file: Annotated[UploadFile, File(description="The recording: C3D or Motive CSV.")],
        annotation: Annotated[str, Form(description="Its annotation entry, JSON: skill, "
                                                    "initial, final, events.")],
    ) -> JSONResponse:
        """Upload one recording with its annotation entry; the reply names its clusters."""
        try:
            # the CLI's bounded reader: integers, nesting, size, text
            entry = parse_document(annotation, "the annotation")
        except InputError as exc:
            raise Rejected(str(exc), status=400) from None
        data = file.file.read()
        with single_upload(template, who, file.filename, data, entry) as (ds, hashes):
            try:
                replies = reg.register(who, ds, hashes, "recording")
            except NonprehensileError as exc:
                raise registration_error(exc) from None
        return JSONResponse(replies[0], status_code=200 if replies[0]["duplicate"] else 201)

    @app.post("/datasets", status_code=201, operation_id="uploadDataset",
              responses=_upload_links("#/uploads/0/upload"))
    def upload_dataset(
        who: Mentor,
        archive: Annotated[UploadFile, File(description="A dataset folder as a zip or tar "
                                                        "archive.")],
    ) -> JSONResponse:
        """Upload a dataset folder (zip or tar); every demonstration must be the mentor's."""
        # read from the spooled file member by member, never whole (ingest/archive.py)
        with archive_upload(template, who, archive.file, config.max_bytes) as (ds, hashes):
            try:
                replies = reg.register(who, ds, hashes, "archive")
            except NonprehensileError as exc:
                raise registration_error(exc) from None
        new = sum(not r["duplicate"] for r in replies)
        return JSONResponse({"uploads": replies, "stored": new,
                             "duplicates": len(replies) - new},
                            status_code=201 if new else 200)

    @app.get("/uploads/{digest}", operation_id="getUpload")
    def get_upload(digest: str) -> dict[str, Any]:
        """One upload: mentor, file, skill, and each segment's arc, sample and cluster."""
        with pool.connection() as conn, snapshot(conn):  # samples and clusters of one state
            return reg.upload(conn, digest)

    @app.delete("/uploads/{digest}", operation_id="withdrawUpload",
                responses={200: {"description": "The upload, withdrawn.", "links": {
                    "GetUpload": {"operationId": "getUpload",
                                  "parameters": {"digest": "$response.body#/upload"}}}}})
    def withdraw_upload(who: Mentor, digest: str) -> dict[str, Any]:
        """Withdraw one of the mentor's own uploads (another's: 403)."""
        return reg.withdraw(who, digest)

    @app.get("/clusters", operation_id="listClusters")
    def clusters() -> dict[str, Any]:
        """Every arc: its clusters and their sizes, samples pending a first clustering."""
        return {"arcs": reg.clusters()}

    @app.get("/mentors", operation_id="listMentors")
    def mentors() -> dict[str, Any]:
        """Per-mentor statistics: uploads, segments, skills and clusters."""
        return {"mentors": reg.mentor_stats()}

    @app.get("/mentors/{name}", operation_id="getMentor")
    def mentor_stats(name: str) -> dict[str, Any]:
        """One mentor's statistics."""
        docs = reg.mentor_stats(name)
        if not docs:
            raise Rejected(f"no uploads by mentor {name!r}", status=404)
        return docs[0]

    @app.post("/recalibrate", status_code=202, operation_id="recalibrate")
    def recalibrate(who: Mentor) -> dict[str, Any]:
        """Ask for a recalibration of every arc, in the background (uploads go on)."""
        recal.request()
        return {"scheduled": True, "recent": recal.runs[-10:]}

    app.add_middleware(BodyLimit, max_bytes=config.max_bytes)
    return app


def _upload_links(pointer: str) -> dict[int | str, dict[str, Any]]:
    """OpenAPI links from an upload's reply (``pointer``: where its hash is) to reading,
    withdrawing and the mentor's statistics (clients and stateful testers follow them)."""
    digest = {"digest": f"$response.body{pointer}"}
    links = {"GetUpload": {"operationId": "getUpload", "parameters": digest},
             "WithdrawUpload": {"operationId": "withdrawUpload", "parameters": digest},
             "GetMentor": {"operationId": "getMentor", "parameters": {
                 "name": f"$response.body{pointer.rsplit('/', 1)[0]}/mentor"}}}
    return {201: {"description": "Stored.", "links": links},
            200: {"description": "Stored before (`duplicate`).", "links": links}}


def _public_store(store: str) -> str:
    """The store as a reply may show it: its kind and database or file name, not its host,
    folder or user (``postgresql:nonprehensile``, ``sqlite:demos.db``)."""
    from urllib.parse import urlsplit

    from nonprehensile.motion.stores import is_postgres_url

    if is_postgres_url(store):
        return f"postgresql:{urlsplit(store).path.lstrip('/') or 'postgres'}"
    return f"sqlite:{Path(store).name}"


class _Unauthorized(NonprehensileError):
    pass
