"""``setupcam user add NAME --role operator|admin``, ``setupcam user passwd NAME`` and
``setupcam apikey create --scope mes|admin``."""

from __future__ import annotations

import argparse
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("user", help="manage operator and admin accounts")
    us = p.add_subparsers(dest="user_command", metavar="ACTION")
    add = us.add_parser("add", help="add a user; prints a random password once unless --password is given")
    add.add_argument("name")
    add.add_argument("--role", required=True, choices=["operator", "admin"])
    add.add_argument("--password", help="set this password instead of a random one (at least 8 characters)")
    add.set_defaults(func=run_user_add)
    pw = us.add_parser("passwd", help="give a user a new password (a forgotten one, the first admin's); "
                                      "prints a random one once unless --password is given; signs the user out")
    pw.add_argument("name")
    pw.add_argument("--password", help="set this password instead of a random one (at least 8 characters)")
    pw.set_defaults(func=run_user_passwd)

    k = sub.add_parser("apikey", help="manage API keys for scripts and the MES")
    ks = k.add_subparsers(dest="apikey_command", metavar="ACTION")
    create = ks.add_parser("create", help="create a key; the secret is printed once")
    create.add_argument("--scope", required=True, choices=["mes", "admin"])
    create.add_argument("--name", default="", help="what the key is for (e.g. the MES host)")
    create.set_defaults(func=run_apikey_create)


def _session():
    from app.config import Settings
    from app.store.db import make_engine, migrate, session_scope

    settings = Settings()
    engine = make_engine(settings.database_url)
    migrate(engine)
    return session_scope(engine)


def run_user_add(args: argparse.Namespace) -> int:
    from app.services.access import create_user
    from app.services.errors import ServiceError

    try:
        with _session() as session:
            user, password = create_user(session, args.name, args.role, args.password)
    except ServiceError as exc:
        print(f"setupcam user add: {exc.detail}", file=sys.stderr)
        return 2
    print(f"user {user.name} ({user.role}) created")
    if not args.password:
        print(f"password (shown once): {password}")
    return 0


def run_user_passwd(args: argparse.Namespace) -> int:
    from app.services.access import set_password
    from app.services.errors import ServiceError

    try:
        with _session() as session:
            user, password = set_password(session, args.name, args.password)
    except ServiceError as exc:
        print(f"setupcam user passwd: {exc.detail}", file=sys.stderr)
        return 2
    print(f"password of {user.name} ({user.role}) changed; their open sessions are signed out")
    if not args.password:
        print(f"new password (shown once): {password}")
    return 0


def run_apikey_create(args: argparse.Namespace) -> int:
    from app.services.access import create_api_key

    with _session() as session:
        row, secret = create_api_key(session, args.name or args.scope, args.scope)
    print(f"API key {row.id} ({row.scope}) created; use it as 'Authorization: Bearer <key>'")
    print(f"key (shown once): {secret}")
    return 0
