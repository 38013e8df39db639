"""The FastAPI application factory. ``create_app(settings)`` has no global state, so two services
with different settings run side by side (and tests start as many as they like)."""

from __future__ import annotations

import logging
import sys
from contextlib import asynccontextmanager

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute

import app as app_pkg
from app.api.routes import audit, auth, cameras, health, machines, models, pages, planning, rotary, setups, sheet
from app.config import Settings, get_settings
from app.services.access import ensure_first_admin
from app.services.errors import ServiceError
from app.services.events import EventBus
from app.services.jobs import JobContext, JobRunner
from app.services.setups import run_setup_job, unfinished_setup_ids
from app.store.db import make_engine, migrate, session_scope
from app.store.files import FileStore
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
    app.state.jobs = JobRunner(JobContext(app.state.engine, app.state.files, settings, app.state.events),
                               settings.workers)
    with session_scope(app.state.engine) as session:
        for setup_id in unfinished_setup_ids(session):
            app.state.jobs.submit(run_setup_job, setup_id)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        startup(app)
        start_viewer(app)
        log.info("setupcam ready", extra={"database": app.state.engine.dialect.name,
                                          "data_dir": str(settings.data_dir)})
        yield
        stop_viewer(app)
        monitors = getattr(app.state, "sheet_monitors", None)
        if monitors is not None:
            monitors.shutdown()
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
    )
    app.state.settings = settings
    app.state.engine = make_engine(settings.database_url)
    app.state.files = FileStore(settings.files_dir)

    @app.exception_handler(ServiceError)
    async def _service_error(_request: Request, exc: ServiceError) -> JSONResponse:
        body = {"detail": exc.detail} if exc.code is None else {"detail": exc.detail, "code": exc.code}
        return JSONResponse(status_code=exc.status_code, content=body)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
        # One readable sentence first, the full list after it for machines.
        errors = exc.errors()
        first = errors[0] if errors else {}
        where = ".".join(str(p) for p in first.get("loc", ()) if p != "body")
        msg = str(first.get("msg", "invalid request")).removeprefix("Value error, ")
        return JSONResponse(status_code=422, content={"detail": f"{where}: {msg}" if where else msg,
                                                      "code": "invalid_parameter", "errors": jsonable_errors(errors)})

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error", extra={"path": request.url.path})
        return JSONResponse(status_code=500, content={"detail": "internal error; it has been logged"})

    for router in (health.router, auth.router, models.router, cameras.router, machines.router, setups.router,
                   audit.router, planning.router, rotary.router, sheet.router):
        app.include_router(router, prefix=API_PREFIX)
    app.include_router(pages.router)  # operator pages, /static, /viewer relay
    return app


def jsonable_errors(errors: list) -> list:
    out = []
    for e in errors:
        e = dict(e)
        e.pop("ctx", None)
        e.pop("input", None)
        e.pop("url", None)
        out.append(e)
    return out
