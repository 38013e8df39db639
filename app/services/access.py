"""Who may do what: users (operator, admin) with sessions, API keys (mes, admin) for scripts and the MES.

Secrets are never stored: passwords as scrypt hashes, API keys and session tokens as sha256. A key or
a password is shown once, when it is made.

What each principal may do (checked in app/api/deps.py):

| action                                   | operator | admin | key mes | key admin |
| ---------------------------------------- | :------: | :---: | :-----: | :-------: |
| read library, cameras, machines, setups  |    x     |   x   |    x    |     x     |
| create setups (upload / grab)            |    x     |   x   |    x    |     x     |
| adjust, refine, confirm, export          |    x     |   x   |         |           |
| change library, cameras, machines, users |          |   x   |         |     x     |
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import secrets
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from functools import lru_cache

from sqlmodel import Session, col, select

from app.services.errors import Conflict, Invalid, NotFound
from app.store.db import session_scope
from app.store.models import ApiKey, LoginSession, User, utcnow

log = logging.getLogger(__name__)

ROLES = ("operator", "admin")
SCOPES = ("mes", "admin")
SESSION_HOURS = 12
_SCRYPT = {"n": 2**14, "r": 8, "p": 1}


@dataclass(frozen=True)
class Principal:
    """The caller: a signed-in user or an API key."""

    name: str
    kind: str      # "user" | "apikey"
    role: str      # operator | admin (users) ; mes | admin (keys)

    @property
    def is_admin(self) -> bool:
        return self.role == "admin"

    @property
    def is_person(self) -> bool:
        return self.kind == "user"

    def label(self) -> str:
        return f"{self.name} ({self.role}{' key' if self.kind == 'apikey' else ''})"


def hash_password(password: str) -> str:
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, dklen=32, **_SCRYPT)
    return f"scrypt${salt.hex()}${digest.hex()}"


def verify_password(password: str, stored: str) -> bool:
    try:
        _, salt_hex, digest_hex = stored.split("$")
    except ValueError:
        return False
    digest = hashlib.scrypt(password.encode(), salt=bytes.fromhex(salt_hex), dklen=32, **_SCRYPT)
    return hmac.compare_digest(digest.hex(), digest_hex)


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def create_user(session: Session, name: str, role: str, password: str | None = None) -> tuple[User, str]:
    """Make a user; returns (user, password). Without a password a random one is made (shown once)."""
    name = (name or "").strip()
    if not name:
        raise Invalid("user name must not be empty")
    if role not in ROLES:
        raise Invalid(f"unknown role {role!r}; use operator or admin")
    if session.exec(select(User).where(User.name == name)).first():
        raise Conflict(f"user {name!r} exists already")
    password = password or secrets.token_urlsafe(12)
    if len(password) < 8:
        raise Invalid("password must have at least 8 characters")
    user = User(name=name, role=role, password_hash=hash_password(password))
    session.add(user)
    session.flush()
    return user, password


def create_api_key(session: Session, name: str, scope: str) -> tuple[ApiKey, str]:
    """Make an API key; returns (row, secret). Only the secret's sha256 is kept."""
    if scope not in SCOPES:
        raise Invalid(f"unknown scope {scope!r}; use mes or admin")
    secret = "sck_" + secrets.token_urlsafe(32)
    row = ApiKey(name=(name or scope)[:100], prefix=secret[:12], key_hash=_sha(secret), scope=scope)
    session.add(row)
    session.flush()
    return row, secret


def revoke_api_key(session: Session, key_id: int) -> None:
    row = session.get(ApiKey, key_id)
    if row is None:
        raise NotFound(f"API key {key_id} not found")
    row.revoked_at = utcnow()
    session.add(row)


@lru_cache(maxsize=1)
def dummy_hash() -> str:
    """A hash no password matches: an unknown name costs the same scrypt work as a wrong password."""
    return hash_password(secrets.token_urlsafe(24))


def login(session: Session, name: str, password: str) -> tuple[User, str, datetime] | None:
    """Check a password; on success make a session token (returned once) valid for SESSION_HOURS.
    Unknown, disabled and wrong all take the same time and answer the same None (no enumeration)."""
    user = session.exec(select(User).where(User.name == name, col(User.disabled_at).is_(None))).first()
    ok = verify_password(password, user.password_hash if user is not None else dummy_hash())
    if user is None or not ok:
        return None
    token = "scs_" + secrets.token_urlsafe(32)
    expires = datetime.now(timezone.utc) + timedelta(hours=SESSION_HOURS)
    session.add(LoginSession(token_hash=_sha(token), user_id=user.id, expires_at=expires))
    session.flush()
    return user, token, expires


def logout(session: Session, token: str) -> None:
    row = session.exec(select(LoginSession).where(LoginSession.token_hash == _sha(token))).first()
    if row is not None:
        session.delete(row)


def resolve_token(session: Session, token: str) -> Principal | None:
    """A bearer value or cookie: an API key (sck_...) or a session token (scs_...)."""
    if token.startswith("sck_"):
        key = session.exec(select(ApiKey).where(ApiKey.key_hash == _sha(token), col(ApiKey.revoked_at).is_(None))).first()
        return Principal(key.name, "apikey", key.scope) if key else None
    if token.startswith("scs_"):
        row = session.exec(select(LoginSession).where(LoginSession.token_hash == _sha(token))).first()
        if row is None:
            return None
        expires = row.expires_at if row.expires_at.tzinfo else row.expires_at.replace(tzinfo=timezone.utc)
        if expires < datetime.now(timezone.utc):
            return None
        user = session.get(User, row.user_id)
        if user is None or user.disabled_at is not None:
            return None
        return Principal(user.name, "user", user.role)
    return None


def principal_of_token(engine, token: str | None) -> Principal | None:
    """:func:`resolve_token` in a transaction of its own (for callers without a request's session: the
    viewer's websocket relay); None without a token."""
    if not token:
        return None
    with session_scope(engine) as session:
        return resolve_token(session, token)


def ensure_first_admin(session: Session) -> str | None:
    """On a fresh install make user 'admin' with a random password and return it (printed once)."""
    if session.exec(select(User)).first() is not None:
        return None
    _, password = create_user(session, "admin", "admin")
    return password


# ------------------------------------------------------------------------ account management (CLI, admin)
def find_user(session: Session, name: str) -> User:
    user = session.exec(select(User).where(User.name == name)).first()
    if user is None:
        raise NotFound(f"no user {name!r}")
    return user


def list_users(session: Session) -> list[User]:
    return list(session.exec(select(User).order_by(User.id)).all())


def end_sessions(session: Session, user_id: int) -> int:
    """Sign a user out everywhere; returns how many sessions ended."""
    rows = session.exec(select(LoginSession).where(LoginSession.user_id == user_id)).all()
    for row in rows:
        session.delete(row)
    return len(rows)


def _disable(session: Session, user: User) -> User:
    """The user can no longer sign in; open sessions end now. The row stays (audit trail names it)."""
    if user.disabled_at is None:
        user.disabled_at = utcnow()
        session.add(user)
    end_sessions(session, user.id)
    session.flush()
    return user


def disable_user(session: Session, name: str) -> User:
    """Disable a user by name (the CLI, run by whoever runs the service: no self or last-admin guard,
    ``setupcam user passwd`` and the database stay with them)."""
    return _disable(session, find_user(session, name))


def set_password(session: Session, name: str, password: str | None = None) -> tuple[User, str]:
    """A new password (random when None; shown once); open sessions end."""
    user = find_user(session, name)
    password = password or secrets.token_urlsafe(12)
    if len(password) < 8:
        raise Invalid("password must have at least 8 characters")
    user.password_hash = hash_password(password)
    session.add(user)
    end_sessions(session, user.id)
    session.flush()
    return user, password


def get_user(session: Session, user_id: int) -> User:
    user = session.get(User, user_id)
    if user is None:
        raise NotFound(f"user {user_id} not found")
    return user


def set_user_disabled(session: Session, user_id: int, disabled: bool, by: str) -> User:
    """Disable (sign out, refuse sign-in) or enable a user. Nobody disables themselves or the last admin."""
    user = get_user(session, user_id)
    if disabled and user.disabled_at is None:
        if user.name == by:
            raise Conflict("you cannot disable your own account; ask another admin")
        if user.role == "admin" and not session.exec(select(User).where(
                User.role == "admin", User.id != user.id, col(User.disabled_at).is_(None))).first():
            raise Conflict(f"{user.name} is the last active admin; make another admin first")
        return _disable(session, user)
    if not disabled:
        user.disabled_at = None
        session.add(user)
        session.flush()
    return user


def list_api_keys(session: Session) -> list[ApiKey]:
    return list(session.exec(select(ApiKey).order_by(ApiKey.id)).all())
