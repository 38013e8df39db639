"""The FastAPI application factory. ``create_app(settings)`` has no global state, so two services
with different settings run side by side (and tests start as many as they like)."""

from __future__ import annotations

import logging
import sys
import threading
from contextlib import asynccontextmanager

from fastapi import Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from sqlalchemy.exc import DataError
from starlette.exceptions import HTTPException as StarletteHTTPException

import app as app_pkg
from app.api.deps import path_ids_in_range
from app.api.headers import SecurityHeaders
from app.api.limits import RequestGuard, route_table
from app.api.problems import problem
from app.api.routes import (audit, auth, cameras, health, jobs, machines, models, pages, planning, rotary, setups,
                            sheet, viewer)
from app.api.routes import docs as api_docs
from app.config import Settings, get_settings
from app.services.access import dummy_hash, ensure_first_admin
from app.services.errors import ServiceError
from app.services.events import EventBus
from app.services.export import ExportWatch, reconcile_open_exports
from app.services.job_kinds import KINDS
from app.services.jobs import JobContext
from app.services.queues import make_queue
from app.services.setups import enqueue_orphaned_setups
from app.services.sheet import SheetMonitors
from app.services.throttle import LoginThrottle
from app.store.db import make_engine, migrate, protect_data, session_scope
from app.store.files import open_file_store
from app.viewer.service import start_viewer, stop_viewer

log = logging.getLogger("setupcam")

API_PREFIX = "/api/v1"


def operation_id(route: APIRoute) -> str:
    """Stable OpenAPI operation ids (``models-create_model``): the MES generates clients from them."""
    return f"{route.tags[0]}-{route.name}" if route.tags else route.name


def startup(app: FastAPI) -> None:
    """Migrate the database, then load the example library (idempotent)."""
    settings: Settings = app.state.settings
    migrate(app.state.engine)
    protect_data(settings.data_dir, settings.database_url, settings.files_dir)
    dummy_hash()  # made once now, so that the first unknown name costs no more than a wrong password
    with session_scope(app.state.engine) as session:
        password = ensure_first_admin(session)
    if password:
        # Printed once, never stored in clear: the first admin signs in with it and makes accounts.
        print(f"setupcam: first start - user 'admin' created with password: {password}", file=sys.stderr, flush=True)
    if settings.load_example_library:
        from app.services.library import load_example_library

        with session_scope(app.state.engine) as session:
            load_example_library(session, app.state.files, settings.models_library_dir)
    app.state.events = EventBus(settings.webhooks, settings.mqtt_url, settings.mqtt_topic_prefix)
    ctx = JobContext(app.state.engine, app.state.files, settings, app.state.events)
    # the queue: Procrastinate on PostgreSQL, the job table polled on SQLite; jobs run here unless
    # SETUPCAM_EMBEDDED_WORKER=false (then `setupcam worker` processes run them). Jobs a dead process
    # left running are queued again by the workers' stalled-job recovery (heartbeats).
    app.state.jobs = make_queue(ctx, KINDS, run_jobs=settings.embedded_worker, concurrency=settings.workers)
    with session_scope(app.state.engine) as session:
        orphans = enqueue_orphaned_setups(session, settings)
    for job_id in orphans:
        app.state.jobs.push(job_id)
    # exports a previous run left pending / writing / unknown are settled by reading the controllers back
    threading.Thread(target=reconcile_open_exports, args=(ctx,), name="export-reconcile", daemon=True).start()
    app.state.export_watch = ExportWatch(ctx, settings.export_watch_s).start()
    # sheet monitors live as long as the service: those a previous run left running carry on
    app.state.sheet_monitors = SheetMonitors(app.state.engine, app.state.files, app.state.events, sheet.decision_url)
    app.state.sheet_monitors.resume()


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        startup(app)
        start_viewer(app)
        log.info("setupcam ready", extra={"database": app.state.engine.dialect.name,
                                          "data_dir": str(settings.data_dir),
                                          "file_store": app.state.files.describe()})
        yield
        stop_viewer(app)
        app.state.sheet_monitors.shutdown()  # their state stays 'running' in the database: the next start resumes them
        app.state.export_watch.stop()
        app.state.jobs.shutdown()
        app.state.events.close()
        app.state.engine.dispose()

    app = FastAPI(
        title="setupcam",
        version=app_pkg.__version__,
        description="Camera-based workpiece setup for CNC machine tools. Lengths in mm, angles in degrees; "
                    "poses are 4x4 matrices `T_a_b` (pose of frame b in frame a).",
        generate_unique_id_function=operation_id,
        lifespan=lifespan,
        docs_url=None, redoc_url=None,  # served by routes/docs.py from packaged assets, not a CDN
    )
    app.state.settings = settings
    app.state.engine = make_engine(settings.database_url)
    app.state.files = open_file_store(settings)
    app.state.login_throttle = LoginThrottle(free=settings.login_free_failures)

    @app.exception_handler(ServiceError)
    async def _service_error(_request: Request, exc: ServiceError) -> JSONResponse:
        return JSONResponse(status_code=exc.status_code, content=problem(exc.status_code, exc.detail, exc.code))

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(_request: Request, exc: StarletteHTTPException) -> JSONResponse:
        # FastAPI's own answer without the code: unknown paths, wrong methods, sign-in and role refusals
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        return JSONResponse(status_code=exc.status_code, headers=getattr(exc, "headers", None),
                            content=problem(exc.status_code, detail, getattr(exc, "code", None)))

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
        # One readable sentence first, the full list after it for machines.
        errors = exc.errors()
        first = errors[0] if errors else {}
        where = ".".join(str(p) for p in first.get("loc", ()) if p != "body")
        msg = str(first.get("msg", "invalid request")).removeprefix("Value error, ")
        return JSONResponse(status_code=422, content={"detail": f"{where}: {msg}" if where else msg,
                                                      "code": "invalid_parameter", "errors": jsonable_errors(errors)})

    @app.exception_handler(OverflowError)
    async def _overflow(_request: Request, _exc: OverflowError) -> JSONResponse:
        # SQLite cannot bind an integer past 2^63: whatever it was looked up by does not exist
        return JSONResponse(status_code=404, content=problem(404, "not found: a number in the request is out of "
                                                                  "range for an id", "id_out_of_range"))

    @app.exception_handler(DataError)
    async def _data_error(_request: Request, exc: DataError) -> JSONResponse:
        # PostgreSQL refused a value (22003: integer out of range; 22001: text too long): the request's fault
        code = getattr(getattr(exc, "orig", None), "sqlstate", "") or ""
        if code == "22003":
            return JSONResponse(status_code=404, content=problem(404, "not found: a number in the request is out "
                                                                      "of range for an id", "id_out_of_range"))
        return JSONResponse(status_code=422, content=problem(422, f"a value does not fit the database ({code}): "
                                                                  f"{str(getattr(exc, 'orig', exc)).splitlines()[0]}",
                                                             "value_does_not_fit"))

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error", extra={"path": request.url.path})
        return JSONResponse(status_code=500, content=problem(500, "internal error; it has been logged"))

    install_error_schema(app)

    api_routers = (health.router, auth.router, models.router, cameras.router, machines.router, setups.router,
                   audit.router, planning.router, rotary.router, sheet.router, jobs.router)
    for router in api_routers:
        app.include_router(router, prefix=API_PREFIX, dependencies=[Depends(path_ids_in_range)])
    # auth, origin and size are checked before any body is read
    app.add_middleware(RequestGuard, fastapi_app=app, routes=route_table(api_routers, API_PREFIX))
    app.add_middleware(SecurityHeaders)  # outermost: every answer carries them, refusals included
    app.include_router(api_docs.router)  # /docs, /redoc without internet
    app.include_router(pages.router)  # operator pages, /static
    app.include_router(viewer.router)  # /viewer/<kind>/<id>/: the 3D view's one door
    return app


PROBLEM_SCHEMA = {
    "title": "Problem", "type": "object", "required": ["detail", "code"],
    "properties": {
        "detail": {"type": "string", "description": "Why, in one sentence (the first problem for a 422)"},
        "code": {"type": "string", "description": "The reason as a machine-readable code (snake_case): "
                                                  "clients choose their advice by it, not by the sentence"},
        "errors": {"type": "array", "items": {"$ref": "#/components/schemas/ValidationError"},
                   "description": "422 from request validation: every problem, for machines"},
    },
}


def install_error_schema(app: FastAPI) -> None:
    """The OpenAPI says what errors really look like: ``{"detail": "<sentence>", "errors": [...]}``
    (FastAPI's default says ``detail`` is an array); every declared 4xx/5xx answer gets that schema."""
    generate = app.openapi

    def openapi() -> dict:
        if app.openapi_schema is None:
            schema = generate()
            schemas = schema.setdefault("components", {}).setdefault("schemas", {})
            schemas["HTTPValidationError"] = PROBLEM_SCHEMA
            ref = {"$ref": "#/components/schemas/HTTPValidationError"}
            for item in schema.get("paths", {}).values():
                for op in item.values():
                    for code, resp in op.get("responses", {}).items():
                        if code[0] in "45" and "content" not in resp:
                            resp["content"] = {"application/json": {"schema": ref}}
        return app.openapi_schema

    app.openapi = openapi


def jsonable_errors(errors: list) -> list:
    out = []
    for e in errors:
        e = dict(e)
        e.pop("ctx", None)
        e.pop("input", None)
        e.pop("url", None)
        out.append(e)
    return out
