"""/api/v1/auth (sign in/out), /api/v1/users and /api/v1/apikeys (admin)."""

from __future__ import annotations

import logging
from datetime import datetime

from fastapi import APIRouter, Request, Response, status
from pydantic import BaseModel, Field

from app.api.deps import SESSION_COOKIE, AdminPrincipal, CurrentPrincipal, SessionDep, SettingsDep
from app.api.problems import Refused
from app.services import access
from app.services.audit import audit

router = APIRouter(tags=["auth"])
log = logging.getLogger(__name__)


def _address(request: Request) -> str:
    return request.client.host if request.client else "unknown"


class LoginBody(BaseModel):
    name: str = Field(max_length=100, examples=["anna"])
    password: str = Field(max_length=1000)


class LoginAnswer(BaseModel):
    name: str
    role: str
    token: str = Field(description="Session token; also set as an HttpOnly cookie")
    expires_at: datetime


class Me(BaseModel):
    name: str
    kind: str
    role: str


class UserCreate(BaseModel):
    name: str = Field(min_length=1, max_length=100)
    role: str = Field(examples=["operator"])
    password: str | None = Field(default=None, description="Default: a random password, answered once")


class UserCreated(BaseModel):
    id: int
    name: str
    role: str
    initial_password: str | None = Field(default=None, description="Only when the request gave no password: "
                                                                     "the random one the service made, shown once. "
                                                                     "A given password is never sent back.")


class UserPublic(BaseModel):
    id: int
    name: str
    role: str
    disabled: bool
    created_at: datetime


class UserChange(BaseModel):
    disabled: bool = Field(description="true: signed out and refused at sign-in; false: may sign in again")


class PasswordReset(BaseModel):
    password: str | None = Field(default=None, description="Default: a random password, answered once")


class PasswordAnswer(BaseModel):
    name: str
    password: str = Field(description="Shown once")


class ApiKeyPublic(BaseModel):
    id: int
    name: str
    scope: str
    prefix: str = Field(description="The key's first characters, to recognise it; never the key")
    created_at: datetime
    revoked: bool


def _user_public(u) -> UserPublic:
    return UserPublic(id=u.id, name=u.name, role=u.role, disabled=u.disabled_at is not None, created_at=u.created_at)


class ApiKeyCreate(BaseModel):
    name: str = Field(default="", max_length=100, examples=["MES line 2"])
    scope: str = Field(examples=["mes"], description="mes: create setups, read results | admin")


class ApiKeyCreated(BaseModel):
    id: int
    name: str
    scope: str
    key: str = Field(description="Shown once; send as 'Authorization: Bearer <key>'")


@router.post("/auth/login", response_model=LoginAnswer, summary="Sign in (operator or admin)",
             responses={401: {"description": "wrong name or password (the same answer for both)"},
                        429: {"description": "too many failed sign-ins for this name or address; Retry-After"}})
def login(request: Request, session: SessionDep, settings: SettingsDep, body: LoginBody,
          response: Response) -> LoginAnswer:
    address = _address(request)
    keys = (f"user:{body.name.strip().lower()}", f"addr:{address}")
    throttle = request.app.state.login_throttle
    wait = throttle.wait_s(*keys)
    if wait > 0:
        log.warning("sign-in throttled", extra={"user": body.name[:100], "address": address, "wait_s": round(wait)})
        audit(session, body.name[:100] or "?", "auth.login_throttled", address=address, wait_s=round(wait))
        session.commit()
        raise Refused(429, f"too many failed sign-ins for this name or from this address; try again in "
                           f"{wait:.0f} s", "too_many_sign_ins", headers={"Retry-After": str(max(1, round(wait)))})
    found = access.login(session, body.name, body.password)
    if found is None:
        throttle.failed(*keys)
        log.warning("sign-in failed", extra={"user": body.name[:100], "address": address})
        audit(session, body.name[:100] or "?", "auth.login_failed", address=address)
        session.commit()  # the refusal below must not roll the audit entry back
        raise Refused(401, "wrong name or password", "wrong_password")
    throttle.succeeded(keys[0])
    user, token, expires = found
    audit(session, user.name, "auth.login", address=address)
    response.set_cookie(SESSION_COOKIE, token, httponly=True, samesite="strict", secure=settings.cookie_secure,
                        max_age=access.SESSION_HOURS * 3600)
    return LoginAnswer(name=user.name, role=user.role, token=token, expires_at=expires)


@router.post("/auth/logout", status_code=status.HTTP_204_NO_CONTENT, response_class=Response, summary="Sign out")
def logout(session: SessionDep, request: Request) -> Response:
    token = request.cookies.get(SESSION_COOKIE)
    auth = request.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        token = auth[7:]
    if token:
        access.logout(session, token)
    response = Response(status_code=status.HTTP_204_NO_CONTENT)
    response.delete_cookie(SESSION_COOKIE)
    return response


@router.get("/auth/me", response_model=Me, summary="Who am I")
def me(principal: CurrentPrincipal) -> Me:
    return Me(name=principal.name, kind=principal.kind, role=principal.role)


@router.post("/users", status_code=status.HTTP_201_CREATED, response_model=UserCreated, summary="Add a user (admin)")
def create_user(request: Request, session: SessionDep, admin: AdminPrincipal, body: UserCreate) -> UserCreated:
    user, password = access.create_user(session, body.name, body.role, body.password)
    audit(session, admin.label(), "user.create", user=user.name, role=user.role, address=_address(request))
    return UserCreated(id=user.id, name=user.name, role=user.role,
                       initial_password=None if body.password else password)


@router.get("/users", response_model=list[UserPublic], summary="List users (admin)")
def list_users(session: SessionDep, _admin: AdminPrincipal) -> list[UserPublic]:
    return [_user_public(u) for u in access.list_users(session)]


@router.patch("/users/{user_id}", response_model=UserPublic, summary="Disable or enable a user (admin)",
              responses={409: {"description": "your own account, or the last active admin"}})
def change_user(session: SessionDep, admin: AdminPrincipal, user_id: int, body: UserChange) -> UserPublic:
    return _user_public(access.set_user_disabled(session, user_id, body.disabled, by=admin.name))


@router.post("/users/{user_id}/password", response_model=PasswordAnswer,
             summary="Reset a user's password (admin); their sessions end")
def reset_password(session: SessionDep, _admin: AdminPrincipal, user_id: int, body: PasswordReset) -> PasswordAnswer:
    user, password = access.set_password(session, access.get_user(session, user_id).name, body.password)
    return PasswordAnswer(name=user.name, password=password)


@router.get("/apikeys", response_model=list[ApiKeyPublic], summary="List API keys (admin; never their secrets)")
def list_api_keys(session: SessionDep, _admin: AdminPrincipal) -> list[ApiKeyPublic]:
    return [ApiKeyPublic(id=k.id, name=k.name, scope=k.scope, prefix=k.prefix, created_at=k.created_at,
                         revoked=k.revoked_at is not None) for k in access.list_api_keys(session)]


@router.post("/apikeys", status_code=status.HTTP_201_CREATED, response_model=ApiKeyCreated,
             summary="Create an API key (admin)")
def create_api_key(request: Request, session: SessionDep, admin: AdminPrincipal, body: ApiKeyCreate) -> ApiKeyCreated:
    row, secret = access.create_api_key(session, body.name, body.scope)
    audit(session, admin.label(), "apikey.create", key_id=row.id, scope=row.scope, prefix=row.prefix,
          address=_address(request))
    return ApiKeyCreated(id=row.id, name=row.name, scope=row.scope, key=secret)


@router.delete("/apikeys/{key_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               summary="Revoke an API key (admin)")
def revoke_api_key(request: Request, session: SessionDep, admin: AdminPrincipal, key_id: int) -> Response:
    access.revoke_api_key(session, key_id)
    audit(session, admin.label(), "apikey.revoke", key_id=key_id, address=_address(request))
    return Response(status_code=status.HTTP_204_NO_CONTENT)
