"""``setupcam serve``: run the service (migrations and example library at start)."""

from __future__ import annotations

import argparse
import os
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help="run the web service")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default 8000)")
    p.add_argument("--data-dir", help="data folder (overrides SETUPCAM_DATA_DIR)")
    p.add_argument("--viser-port", type=int, help="port of the 3D viewer (overrides SETUPCAM_VISER_PORT)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from app.config import Settings
    from app.logging_setup import configure_logging
    from app.main import create_app
    from app.store.files import FileStoreError

    if args.data_dir:
        os.environ["SETUPCAM_DATA_DIR"] = args.data_dir
    if args.viser_port:
        os.environ["SETUPCAM_VISER_PORT"] = str(args.viser_port)
    settings = Settings()
    configure_logging(settings.log_json)
    try:
        app = create_app(settings)
    except FileStoreError as exc:  # an unknown bucket or refused key: the sentence, not a traceback
        print(f"setupcam serve: file store: {exc}", file=sys.stderr)
        return 1
    why = database_unreachable(app.state.engine)
    if why:  # a sentence, not a traceback from deep inside the start-up
        print(f"setupcam serve: {why}", file=sys.stderr)
        return 1
    uvicorn.run(app, host=args.host, port=args.port, log_config=None, access_log=False)
    return 0


def database_unreachable(engine) -> str | None:
    """None when the database answers, else one sentence: where, and what it said."""
    from sqlalchemy import text

    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
        return None
    except Exception as exc:  # noqa: BLE001 - any refusal becomes the sentence
        where = engine.url.render_as_string(hide_password=True)
        said = str(getattr(exc, "orig", None) or exc).strip().splitlines()[0][:300]
        return f"cannot reach the database at {where}: {said} (check DATABASE_URL and that the server is running)"
