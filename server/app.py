"""The FastAPI application factory (OpenAPI page at /docs)."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import OperationalError
from sqlalchemy.exc import TimeoutError as SQLAlchemyTimeoutError

from models.batch import BatchError
from server.auth import FailedAuthGuard, RateLimiter
from server.db import make_engine, make_sessionmaker, migrate
from server.formats import PayloadTooLarge
from server.redact import install as install_log_redaction
from server.ingest import EngineHost, IngestConflict, StorageBusy, is_contention
from server.openapi import install as install_openapi
from server.openapi import operation_id
from server.settings import Settings
from server.upload import Uploader

__all__ = ["create_app", "BodyLimit", "AccessLog", "configure_logging"]

_log = logging.getLogger("pednav.server")
_access = logging.getLogger("pednav.access")


def configure_logging(level: str) -> None:
    """Send the ``pednav`` loggers (``pednav.access``: one JSON line per request) to stderr at ``level``."""
    import sys

    lg = logging.getLogger("pednav")
    lg.setLevel(level.upper())
    if not any(getattr(h, "_pednav", False) for h in lg.handlers):
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        h._pednav = True  # type: ignore[attr-defined]
        lg.addHandler(h)
        lg.propagate = False


class AccessLog:
    """Pure ASGI middleware: one structured line (JSON) per request on the ``pednav.access`` logger at INFO:
    method, path, status, duration [ms], response bytes, client. The query string is left out (the Sensor Logger
    push carries its token there); uvicorn's own access log is off for the same reason (``pednav serve``)."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or not _access.isEnabledFor(logging.INFO):
            await self.app(scope, receive, send)
            return
        import json
        import time

        t0 = time.perf_counter()
        state = {"status": 500, "bytes": 0}

        async def sent(msg: Any) -> None:
            if msg["type"] == "http.response.start":
                state["status"] = msg["status"]
            elif msg["type"] == "http.response.body":
                state["bytes"] += len(msg.get("body", b""))
            await send(msg)

        try:
            await self.app(scope, receive, sent)
        finally:
            client = scope.get("client")
            _access.info(json.dumps({
                "method": scope.get("method"), "path": scope.get("path"), "status": state["status"],
                "ms": round((time.perf_counter() - t0) * 1000, 2), "bytes": state["bytes"],
                "client": f"{client[0]}:{client[1]}" if client else None}, separators=(",", ":")))


class BodyLimit:
    """Pure ASGI middleware: 413 for a body above ``max_bytes``, refused before it is read when its
    ``Content-Length`` says so, else (a streamed, chunked body) as soon as the bytes read exceed the limit.

    Only the batch upload counted streamed bodies before, so a chunked body of any size reached every other
    route that reads one (Sensor Logger pushes, profiles) and was parsed and stored whole.
    """

    def __init__(self, app: Any, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for k, v in scope["headers"]:
            if k == b"content-length" and v.isdigit() and int(v) > self.max_bytes:
                resp = JSONResponse(status_code=413, content={
                    "detail": f"body of {int(v)} bytes exceeds the limit of {self.max_bytes} bytes"})
                await resp(scope, receive, send)
                return
        size = 0

        async def counted() -> Any:
            nonlocal size
            msg = await receive()
            if msg["type"] == "http.request":
                size += len(msg.get("body", b""))
                if size > self.max_bytes:
                    # an HTTPException passes FastAPI's body parsing untouched and is answered by its handler
                    raise HTTPException(413, f"body exceeds the limit of {self.max_bytes} bytes")
            return msg

        await self.app(scope, counted, send)


def create_app(settings: Settings | None = None, engine_cls: Any | None = None) -> FastAPI:
    """Build the app: database engine, migrations (when enabled), routers under ``/v1``.

    Parameters
    ----------
    settings : Settings, optional
        Defaults to ``Settings()`` (``PEDNAV_*`` environment variables).
    engine_cls : type, optional
        Navigation engine class (default :class:`energy.engine.Engine`); lets an operator run a newer engine.
    """
    from server.routers import auth, batches, devices, profiles, sensorlogger, sessions, timelines, trajectories, users

    settings = settings or Settings()
    install_log_redaction()  # the access log writes URLs: the Sensor Logger push carries its token in one

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        app.state.host.start()  # the engines warm up now, not under the first upload
        import asyncio

        closer = asyncio.create_task(_close_idle_loop(app)) if settings.sensorlogger_idle_close_s > 0 else None
        yield
        if closer is not None:
            closer.cancel()
        # stop the engine helper processes with the server (they are spawned again if the app is reused)
        if app.state.host.pool is not None:
            app.state.host.pool.shutdown()
        if app.state.uploader is not None:
            app.state.uploader.close()

    app = FastAPI(
        lifespan=lifespan,
        title="pednav",
        version="1",
        description="Energy-aware pedestrian navigation service: sessions, sensor batches, calibration profiles, trajectories.",
        generate_unique_id_function=operation_id,
    )
    db_engine = make_engine(settings)
    if settings.migrate_on_startup:
        migrate(db_engine)
    app.state.settings = settings
    app.state.db_engine = db_engine
    app.state.sessionmaker = make_sessionmaker(db_engine)
    app.state.limiter = RateLimiter(settings.rate_limit_per_s, settings.rate_limit_burst)
    app.state.auth_guard = FailedAuthGuard(settings.auth_failures_per_s, settings.auth_failures_burst)
    # batch uploads run on a small dedicated pool: few threads contend less for the GIL than anyio's 40
    app.state.ingest_pool = ThreadPoolExecutor(max_workers=settings.ingest_threads, thread_name_prefix="ingest")
    app.state.host = EngineHost(settings.engine_cache_size, engine_cls, serialize_writes=db_engine.dialect.name == "sqlite",
                                engine_processes=settings.engine_processes, channels=settings.ingest_threads,
                                warm=settings.engine_warmup, state_every=settings.state_every)
    # batch uploads on driver connections (SQLite: group commit; PostgreSQL: one statement), see server.upload
    sqlite = db_engine.dialect.name == "sqlite"
    app.state.uploader = Uploader(db_engine, app.state.host, app.state.limiter) if (
        sqlite or settings.pg_one_statement_writes) else None

    app.add_middleware(batches.UploadFastPath, fastapi_app=app)  # inside BodyLimit (declared sizes first)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    origins = settings.cors_origin_list()
    if origins:  # off by default: the viewer at /app is served by this app (same origin)
        from fastapi.middleware.cors import CORSMiddleware

        app.add_middleware(CORSMiddleware, allow_origins=origins, allow_methods=["*"],
                           allow_headers=["Authorization", "Content-Type"], expose_headers=["Retry-After"],
                           allow_credentials=False, max_age=600)
    if settings.log_requests:
        app.add_middleware(AccessLog)

    @app.exception_handler(BatchError)
    async def _batch_error(_request: Request, exc: BatchError) -> JSONResponse:
        return JSONResponse(status_code=422, content={"detail": f"{exc.field}: {exc.problem}", "field": exc.field, "problem": exc.problem})

    @app.exception_handler(PayloadTooLarge)
    async def _too_large(_request: Request, exc: PayloadTooLarge) -> JSONResponse:
        return JSONResponse(status_code=413, content={"detail": str(exc)})

    @app.exception_handler(IngestConflict)
    async def _conflict(_request: Request, exc: IngestConflict) -> JSONResponse:
        return JSONResponse(status_code=409, content={"detail": exc.message, "expected_seq": exc.expected_seq})

    @app.exception_handler(StorageBusy)
    async def _busy(_request: Request, exc: StorageBusy) -> JSONResponse:
        # nothing was stored: a refusal the client retries (the SDK does, waiting Retry-After), not a 500
        cause: BaseException = exc
        while cause.__cause__ is not None:  # the database's own error
            cause = cause.__cause__
        _log.warning("503: %s (last error: %s: %s)", exc.message, type(cause).__name__, cause)
        return JSONResponse(status_code=503, content={"detail": exc.message},
                            headers={"Retry-After": str(exc.retry_after_s)})

    @app.exception_handler(OperationalError)
    async def _operational(request: Request, exc: OperationalError) -> JSONResponse:
        # a route's write refused only because other writers held the database (SQLite busy past its timeout,
        # PostgreSQL lock/statement timeout, deadlock, serialization failure): its transaction is rolled back,
        # nothing stored, so a retryable 503 as StorageBusy, never a 500; any other database error stays a 500
        if not is_contention(exc):
            raise exc
        return await _busy(request, StorageBusy("database busy: nothing of this request was stored; send it again"))

    @app.exception_handler(SQLAlchemyTimeoutError)
    async def _pool_timeout(request: Request, exc: SQLAlchemyTimeoutError) -> JSONResponse:
        # every pooled connection stayed in use for pool_timeout: nothing was done for this request
        return await _busy(request, StorageBusy("database connections all busy: nothing of this request was "
                                                "stored; send it again"))

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errs = exc.errors()
        fields, problems = [], []
        for e in errs:
            loc = tuple(e.get("loc", ()))
            problem = str(e.get("msg"))
            if e.get("type") == "json_invalid":  # loc ("body", <char>): the field was the character offset "1"
                loc = ("body",)
                problem = f"not valid JSON: {(e.get('ctx') or {}).get('error', problem)} (char {e['loc'][-1]})"
            field = ".".join(str(p) for p in loc if p != "body") or "body"  # the body as a whole: not ""
            ctype = request.headers.get("content-type", "")
            if field == "body" and loc == ("body",) and "json" not in ctype:
                problem += f"; send JSON with Content-Type: application/json (got {ctype or 'none'!r})"
            fields.append(field)
            problems.append(problem)
        msg = "; ".join(f"{f}: {p}" for f, p in zip(fields, problems))
        return JSONResponse(status_code=422, content={"detail": msg, "field": fields[0] if fields else None, "errors": [
            {"field": f, "problem": p} for f, p in zip(fields, problems)]})

    for r in (auth, users, devices, sessions, batches, profiles, trajectories, timelines, sensorlogger):
        app.include_router(r.router, prefix="/v1")

    _mount_viewer(app, settings)

    @app.get("/healthz", tags=["meta"])
    def healthz() -> Any:
        """Readiness: 200 once the engines can take an upload within the normal latency; 503 with ``Retry-After``
        while they are still being compiled (first start after an install) or loaded."""
        if app.state.host.ready():
            return {"status": "ok", "ready": True}
        return JSONResponse(status_code=503, headers={"Retry-After": "2"}, content={
            "status": "starting", "ready": False, "detail": "the navigation engines are being compiled or loaded"})

    install_openapi(app)
    return app


def _mount_viewer(app: FastAPI, settings: Settings) -> None:
    """The web viewer at ``/app/`` (plain HTML/JS/CSS from ``server/static``, Leaflet vendored; no build step)."""
    from pathlib import Path
    from urllib.parse import urlsplit

    from fastapi.responses import FileResponse, RedirectResponse
    from fastapi.staticfiles import StaticFiles

    static = Path(__file__).resolve().parent / "static"
    tiles = urlsplit(settings.map_tile_url)
    tile_origin = f" {tiles.scheme}://{tiles.netloc}" if tiles.scheme in ("http", "https") else ""
    csp = ("default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
           f"img-src 'self' data:{tile_origin}; connect-src 'self'; frame-ancestors 'none'")
    app.mount("/app/static", StaticFiles(directory=static), name="viewer-static")

    @app.get("/app", include_in_schema=False)
    def viewer_redirect() -> RedirectResponse:
        return RedirectResponse("/app/")

    @app.get("/app/", include_in_schema=False)
    def viewer() -> FileResponse:
        return FileResponse(static / "index.html", headers={"Content-Security-Policy": csp, "Cache-Control": "no-cache"})

    @app.get("/app/config.json", include_in_schema=False)
    def viewer_config() -> dict[str, str]:
        return {"tile_url": settings.map_tile_url, "tile_attribution": settings.map_tile_attribution}


async def _close_idle_loop(app: FastAPI) -> None:
    """Close idle Sensor Logger sessions every quarter of the idle time (at most every 30 s), in a worker thread."""
    import asyncio

    from starlette.concurrency import run_in_threadpool

    from server.routers.sensorlogger import close_idle_sessions

    s = app.state.settings
    period = min(max(s.sensorlogger_idle_close_s / 4, 1.0), 30.0)
    while True:
        await asyncio.sleep(period)
        try:
            closed = await run_in_threadpool(close_idle_sessions, app.state.sessionmaker, app.state.host, s)
            if closed:
                _log.info("closed idle Sensor Logger sessions %s", closed)
        except Exception:  # noqa: BLE001 - a failed round is logged; the next one tries again
            _log.exception("closing idle Sensor Logger sessions failed")


def app_from_env() -> FastAPI:
    """Factory for ``uvicorn --factory server.app:app_from_env`` (settings from ``PEDNAV_*``).

    The objects alive after start-up (modules, the app, the ORM) are moved out of the garbage collector's
    reach: a full collection over them took about 100 ms with the GIL held, a stall of every request."""
    import gc
    import os

    if os.environ.get("PEDNAV_LOG_LEVEL"):  # set by `pednav serve --log-level` for every worker
        configure_logging(os.environ["PEDNAV_LOG_LEVEL"])
    app = create_app(Settings())
    gc.collect()
    gc.freeze()
    return app
