"""Accounts and API keys from the command line (on the service's machine, with its environment):

    setupcam user add NAME --role operator|admin [--password P]
    setupcam user list | setupcam user disable NAME | setupcam user passwd NAME [--password P]
    setupcam key create --scope mes|admin [--name N] | setupcam key list | setupcam key revoke ID
    (``setupcam apikey create`` is the older spelling of ``key create``)

Every change is written to the audit log with the actor ``cli:<login name>``.
"""

from __future__ import annotations

import argparse
import getpass
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("user", help="manage operator and admin accounts")
    us = p.add_subparsers(dest="user_command", metavar="ACTION")
    add = us.add_parser("add", help="add a user; prints a random password once unless --password is given")
    add.add_argument("name")
    add.add_argument("--role", required=True, choices=["operator", "admin"])
    add.add_argument("--password", help="set this password instead of a random one (at least 8 characters)")
    add.set_defaults(func=run_user_add)
    us.add_parser("list", help="list accounts (name, role, enabled)").set_defaults(func=run_user_list)
    dis = us.add_parser("disable", help="stop a user signing in; their open sessions end now")
    dis.add_argument("name")
    dis.set_defaults(func=run_user_disable)
    pw = us.add_parser("passwd", help="set a new password (random, printed once, unless --password); "
                                      "open sessions end")
    pw.add_argument("name")
    pw.add_argument("--password", help="the new password (at least 8 characters)")
    pw.set_defaults(func=run_user_passwd)

    for command in ("key", "apikey"):
        k = sub.add_parser(command, help="manage API keys for scripts and the MES" if command == "key"
                           else "older name of 'key'")
        ks = k.add_subparsers(dest="key_command", metavar="ACTION")
        create = ks.add_parser("create", help="create a key; the secret is printed once")
        create.add_argument("--scope", required=True, choices=["mes", "admin"])
        create.add_argument("--name", default="", help="what the key is for (e.g. the MES host)")
        create.set_defaults(func=run_apikey_create)
        ks.add_parser("list", help="list keys (id, prefix, scope, revoked)").set_defaults(func=run_key_list)
        rev = ks.add_parser("revoke", help="revoke a key by its id (see 'list')")
        rev.add_argument("id", type=int)
        rev.set_defaults(func=run_key_revoke)


def _actor() -> str:
    try:
        return f"cli:{getpass.getuser()}"
    except Exception:  # noqa: BLE001 - no login name (container): still audited
        return "cli"


def _session():
    from app.cli.serve import database_unreachable
    from app.config import Settings
    from app.store.db import make_engine, migrate, session_scope

    settings = Settings()
    engine = make_engine(settings.database_url)
    why = database_unreachable(engine)
    if why:
        raise SystemExit(f"setupcam: {why}")
    migrate(engine)
    return session_scope(engine)


def _change(command: str, change) -> int:
    """Run ``change(session) -> exit code`` in one transaction; a refusal is one line on stderr (exit 2)."""
    from app.services.errors import ServiceError

    try:
        with _session() as session:
            return change(session)
    except ServiceError as exc:
        print(f"setupcam {command}: {exc.detail}", file=sys.stderr)
        return 2


def _audit(session, action: str, **detail) -> None:
    from app.services.audit import audit

    audit(session, _actor(), action, **detail)


def run_user_add(args: argparse.Namespace) -> int:
    from app.services.access import create_user

    def change(session) -> int:
        user, password = create_user(session, args.name, args.role, args.password)
        _audit(session, "user.create", user=user.name, role=user.role)
        print(f"user {user.name} ({user.role}) created")
        if not args.password:
            print(f"password (shown once): {password}")
        return 0

    return _change("user add", change)


def run_user_list(_args: argparse.Namespace) -> int:
    from app.services.access import list_users

    def show(session) -> int:
        print(f"{'id':>4}  {'name':<24} {'role':<9} state")
        for u in list_users(session):
            state = f"disabled {u.disabled_at:%Y-%m-%d %H:%M}" if u.disabled_at else "enabled"
            print(f"{u.id:>4}  {u.name:<24} {u.role:<9} {state}")
        return 0

    return _change("user list", show)


def run_user_disable(args: argparse.Namespace) -> int:
    from app.services.access import disable_user

    def change(session) -> int:
        user = disable_user(session, args.name)
        _audit(session, "user.disable", user=user.name)
        print(f"user {user.name} disabled; open sessions ended")
        return 0

    return _change("user disable", change)


def run_user_passwd(args: argparse.Namespace) -> int:
    from app.services.access import set_password

    def change(session) -> int:
        user, password = set_password(session, args.name, args.password)
        _audit(session, "user.passwd", user=user.name)
        print(f"password of {user.name} changed; open sessions ended")
        if not args.password:
            print(f"new password (shown once): {password}")
        return 0

    return _change("user passwd", change)


def run_apikey_create(args: argparse.Namespace) -> int:
    from app.services.access import create_api_key

    def change(session) -> int:
        row, secret = create_api_key(session, args.name or args.scope, args.scope)
        _audit(session, "apikey.create", key_id=row.id, scope=row.scope, prefix=row.prefix)
        print(f"API key {row.id} ({row.scope}) created; use it as 'Authorization: Bearer <key>'")
        print(f"key (shown once): {secret}")
        return 0

    return _change("key create", change)


def run_key_list(_args: argparse.Namespace) -> int:
    from app.services.access import list_api_keys

    def show(session) -> int:
        print(f"{'id':>4}  {'prefix':<14} {'scope':<6} {'name':<30} state")
        for k in list_api_keys(session):
            state = f"revoked {k.revoked_at:%Y-%m-%d %H:%M}" if k.revoked_at else "active"
            print(f"{k.id:>4}  {k.prefix:<14} {k.scope:<6} {k.name[:30]:<30} {state}")
        return 0

    return _change("key list", show)


def run_key_revoke(args: argparse.Namespace) -> int:
    from app.services.access import revoke_api_key

    def change(session) -> int:
        revoke_api_key(session, args.id)
        _audit(session, "apikey.revoke", key_id=args.id)
        print(f"API key {args.id} revoked")
        return 0

    return _change("key revoke", change)
