"""Named dependencies so route signatures read like sentences."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Request
from sqlmodel import Session

from app.config import Settings
from app.store.files import FileStore


def get_session(request: Request) -> Iterator[Session]:
    with Session(request.app.state.engine, expire_on_commit=False) as session:
        try:
            yield session
            session.commit()
        except Exception:
            session.rollback()
            raise


def get_files(request: Request) -> FileStore:
    return request.app.state.files


def get_app_settings(request: Request) -> Settings:
    return request.app.state.settings


# scope="function": commit before the response leaves, so the next request sees the change.
SessionDep = Annotated[Session, Depends(get_session, scope="function")]
FilesDep = Annotated[FileStore, Depends(get_files)]
SettingsDep = Annotated[Settings, Depends(get_app_settings)]


# --------------------------------------------------------------------------------------- access
from app.api.problems import Refused  # noqa: E402
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer  # noqa: E402

from app.services.access import Principal, resolve_token  # noqa: E402

SESSION_COOKIE = "setupcam_session"
_bearer = HTTPBearer(auto_error=False, description="An API key (sck_...) or a session token (scs_...)")

# What a route needs from its caller (found by app/api/limits.py from the route's dependencies, so that a
# caller without it is refused before the body is read).
GUARD_ANY, GUARD_PERSON, GUARD_ADMIN = "any", "person", "admin"


def token_of(headers, cookies) -> tuple[str | None, bool]:
    """(token, from_cookie): the bearer value, else the session cookie."""
    auth = headers.get("authorization", "")
    if auth[:7].lower() == "bearer " and auth[7:].strip():
        return auth[7:].strip(), False
    token = cookies.get(SESSION_COOKIE)
    return (token or None), bool(token)


def refusal(principal: Principal | None, had_token: bool, guard: str) -> tuple[int, str, str] | None:
    """(status, reason, reason code) when the caller may not use a route guarded by ``guard``; None
    when it may."""
    if principal is None:
        if not had_token:
            return 401, "sign in (POST /api/v1/auth/login) or send 'Authorization: Bearer <API key>'", "sign_in_required"
        return 401, "the key or session is unknown, revoked or expired; sign in again", "session_expired"
    if guard == GUARD_ADMIN and not principal.is_admin:
        return 403, (f"{principal.label()} may not change the library, cameras, machines or accounts; "
                     "an admin must do this"), "admin_required"
    if guard == GUARD_PERSON and not principal.is_person:
        return 403, (f"{principal.label()} may create setups and read results, but confirming, "
                     "adjusting and exporting need a signed-in operator"), "operator_required"
    return None


def _refuse(principal: Principal | None, had_token: bool, guard: str, request: Request | None = None) -> None:
    why = refusal(principal, had_token, guard)
    if why is None:
        return
    if why[0] == 403 and request is not None:  # role refusals are audited (reads included)
        from app.services.audit import audit_refusal

        audit_refusal(request.app.state.engine, principal.label(), f"{request.method} {request.url.path}",
                      request.client.host if request.client else "unknown", why[1])
    raise Refused(why[0], why[1], why[2], headers={"WWW-Authenticate": "Bearer"} if why[0] == 401 else None)


def get_principal(request: Request, session: SessionDep,
                  creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> Principal:
    token = creds.credentials if creds else request.cookies.get(SESSION_COOKIE)
    principal = resolve_token(session, token) if token else None
    _refuse(principal, bool(token), GUARD_ANY)
    return principal


def require_admin(request: Request, principal: Annotated[Principal, Depends(get_principal)]) -> Principal:
    _refuse(principal, True, GUARD_ADMIN, request)
    return principal


def require_person(request: Request, principal: Annotated[Principal, Depends(get_principal)]) -> Principal:
    """Adjust, confirm and export need a signed-in operator or admin, never an API key."""
    _refuse(principal, True, GUARD_PERSON, request)
    return principal


CurrentPrincipal = Annotated[Principal, Depends(get_principal)]
AdminPrincipal = Annotated[Principal, Depends(require_admin)]
OperatorPrincipal = Annotated[Principal, Depends(require_person)]


# --------------------------------------------------------------------------------------- ids
MAX_ID = 2**31 - 1  # ids are 32-bit integers in every database we run on


def path_ids_in_range(request: Request) -> None:
    """An id in the path beyond what a row can have (``/setups/99999999999``) is simply not found (404),
    before any database sees it (SQLite overflows past 2^63, PostgreSQL's integer past 2^31)."""
    from app.services.errors import NotFound

    for name, value in request.path_params.items():
        if not name.endswith("_id"):
            continue
        try:
            number = int(value)
        except (TypeError, ValueError):
            continue  # not a number: the route's own validation answers 422
        if not 0 < number <= MAX_ID:
            raise NotFound(f"{name.removesuffix('_id').replace('_', ' ')} {value} not found")
