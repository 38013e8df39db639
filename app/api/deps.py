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
from fastapi import HTTPException  # noqa: E402
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer  # noqa: E402

from app.services.access import Principal, resolve_token  # noqa: E402

SESSION_COOKIE = "setupcam_session"
_bearer = HTTPBearer(auto_error=False, description="An API key (sck_...) or a session token (scs_...)")


def get_principal(request: Request, session: SessionDep,
                  creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> Principal:
    token = creds.credentials if creds else request.cookies.get(SESSION_COOKIE)
    if not token:
        raise HTTPException(401, "sign in (POST /api/v1/auth/login) or send 'Authorization: Bearer <API key>'",
                            headers={"WWW-Authenticate": "Bearer"})
    principal = resolve_token(session, token)
    if principal is None:
        raise HTTPException(401, "the key or session is unknown, revoked or expired; sign in again",
                            headers={"WWW-Authenticate": "Bearer"})
    return principal


def require_admin(principal: Annotated[Principal, Depends(get_principal)]) -> Principal:
    if not principal.is_admin:
        raise HTTPException(403, f"{principal.label()} may not change the library, cameras, machines or accounts; "
                                 "an admin must do this")
    return principal


def require_person(principal: Annotated[Principal, Depends(get_principal)]) -> Principal:
    """Adjust, confirm and export need a signed-in operator or admin, never an API key."""
    if not principal.is_person:
        raise HTTPException(403, f"{principal.label()} may create setups and read results, but confirming, "
                                 "adjusting and exporting need a signed-in operator")
    return principal


CurrentPrincipal = Annotated[Principal, Depends(get_principal)]
AdminPrincipal = Annotated[Principal, Depends(require_admin)]
OperatorPrincipal = Annotated[Principal, Depends(require_person)]
