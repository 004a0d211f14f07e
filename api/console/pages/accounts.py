"""Accounts (administrators only): every user and robot with its role; create one, change its role,
disable it (the ``inactive`` role, as ``PUT /users/{name}/role`` does), give its broker account a
new password, shown once, end all its login sessions (as ``DELETE /users/{name}/sessions``).

Every rule is the accounts service's (``svc.accounts``, which ``/users`` calls too): the page passes
what the form says and shows the service's refusal as it is.

The new broker password goes from the reset (a POST) to the page that shows it (a GET, so that
a reload cannot reset it again) in a cookie sealed with the service's key, readable only by that
page, for two minutes; the page deletes it as it shows it, and answers ``Cache-Control: no-store``.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import Annotated
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, Form, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from fleetbus.api import audit
from fleetbus.api.accounts import BrokerCredentials
from fleetbus.api.auth import ServiceDep
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import ACCOUNTS, ADMINS
from fleetbus.api.console.templating import render
from fleetbus.api.errors import BadRequest, ServiceRefusal
from fleetbus.api.service import Service
from fleetbus.api.transport import broker_password_refusal
from fleetbus.schemas.roles import ROLE_PURPOSE, UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.users import User

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(ACCOUNTS))]
Creator = Annotated[User, Depends(Allowed(ADMINS, "create users"))]
RoleSetter = Annotated[User, Depends(Allowed(ADMINS, "change roles or disable users"))]
Rekeyer = Annotated[User, Depends(Allowed(ADMINS, "reset broker passwords"))]
SessionEnder = Annotated[User, Depends(Allowed(ADMINS, "end users' sessions"))]

SHOWN_ONCE_COOKIE = "fleetbus_shown_once"
SHOWN_ONCE_S = 120
NO_STORE = {"Cache-Control": "no-store"}
NOTICES = {
    "created": "User {name} created.",
    "role": "{name} has a new role.",
    "disabled": "{name} is disabled (role inactive): it can neither log in nor reach the broker.",
    "sessions": "Every session of {name} has ended: its console logins and API tokens are refused.",
}


def _shown_once_path(name: str) -> str:
    return f"/console/accounts/{name}/broker-password"


async def _page(
    request: Request,
    user: User,
    svc: Service,
    status_code: int = 200,
    problem: str | None = None,
    notice: str | None = None,
    form: dict[str, str] | None = None,
) -> Response:
    return render(
        request,
        "accounts/page.html",
        user,
        ACCOUNTS,
        status_code=status_code,
        users=await svc.repositories.users.users(),
        roles=list(UserRole),
        purposes=ROLE_PURPOSE,
        kinds=list(RobotKind),
        problem=problem,
        notice=notice,
        form=form or {"role": UserRole.INACTIVE.value},
    )


@router.get("/console/accounts", response_class=HTMLResponse)
async def accounts(
    request: Request, user: Viewer, svc: ServiceDep, done: str | None = None, name: str | None = None
) -> Response:
    notice = NOTICES[done].format(name=name) if done in NOTICES and name else None
    return await _page(request, user, svc, notice=notice)


def _done(done: str, name: str) -> RedirectResponse:
    """Back to the list, saying what was done (a reload then repeats nothing)."""
    return RedirectResponse(f"/console/accounts?{urlencode({'done': done, 'name': name})}", status_code=303)


def _role(value: str) -> UserRole:
    try:
        return UserRole(value)
    except ValueError:
        raise BadRequest(f"no role {value!r}") from None


def _kind(value: str) -> RobotKind | None:
    try:
        return RobotKind(value) if value else None
    except ValueError:
        raise BadRequest(f"no robot kind {value!r}") from None


@router.post("/console/accounts", response_class=HTMLResponse)
async def create(
    request: Request,
    admin: Creator,
    svc: ServiceDep,
    name: Annotated[str, Form()] = "",
    role: Annotated[str, Form()] = UserRole.INACTIVE.value,
    kind: Annotated[str, Form()] = "",
    password: Annotated[str, Form()] = "",
) -> Response:
    try:
        await svc.accounts.create(name, password or None, _role(role), _kind(kind), admin.name)
    except ServiceRefusal as refusal:
        form = {"name": name, "role": role, "kind": kind}  # never the password
        return await _page(request, admin, svc, refusal.status, problem=refusal.detail, form=form)
    return _done("created", name)


async def _set_role(request: Request, admin: User, svc: Service, name: str, role: str, done: str) -> Response:
    try:
        await svc.accounts.set_role(name, _role(role), admin.name)
    except ServiceRefusal as refusal:
        return await _page(request, admin, svc, refusal.status, problem=refusal.detail)
    return _done(done, name)


@router.post("/console/accounts/{name}/role", response_class=HTMLResponse)
async def set_role(
    request: Request, name: str, admin: RoleSetter, svc: ServiceDep, role: Annotated[str, Form()]
) -> Response:
    return await _set_role(request, admin, svc, name, role, "role")


@router.post("/console/accounts/{name}/disable", response_class=HTMLResponse)
async def disable(request: Request, name: str, admin: RoleSetter, svc: ServiceDep) -> Response:
    return await _set_role(request, admin, svc, name, UserRole.INACTIVE.value, "disabled")


@router.post("/console/accounts/{name}/sessions/end", response_class=HTMLResponse)
async def end_sessions(request: Request, name: str, admin: SessionEnder, svc: ServiceDep) -> Response:
    keep = request.state.session.id if name == admin.name else None  # an admin's own stays open
    try:
        await svc.accounts.end_sessions(name, admin.name, keep=keep)
    except ServiceRefusal as refusal:
        return await _page(request, admin, svc, refusal.status, problem=refusal.detail)
    return _done("sessions", name)


@router.post("/console/accounts/{name}/broker-password", response_class=HTMLResponse)
async def reset_broker_password(request: Request, name: str, admin: Rekeyer, svc: ServiceDep) -> Response:
    if refusal := broker_password_refusal(request, svc.settings):  # before the password changes
        audit.refused(request, 403, admin.name, refusal)
        return await _page(request, admin, svc, 403, problem=refusal)
    try:
        credentials = await svc.accounts.reset_broker_password(name, admin.name)
    except ServiceRefusal as refusal:
        return await _page(request, admin, svc, refusal.status, problem=refusal.detail)
    shown_at = _shown_once_path(credentials.username)
    response = RedirectResponse(shown_at, status_code=303, headers=NO_STORE)
    response.set_cookie(
        SHOWN_ONCE_COOKIE,
        svc.secrets.box.seal(json.dumps(asdict(credentials))),
        max_age=SHOWN_ONCE_S,
        path=shown_at,
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",  # as the session's cookie
    )
    return response


def _opened(svc: Service, sealed: str | None, name: str) -> BrokerCredentials | None:
    if not sealed:
        return None
    try:
        credentials = BrokerCredentials(**json.loads(svc.secrets.box.open(sealed, max_age_s=SHOWN_ONCE_S)))
    except (ValueError, TypeError):  # too old, or not sealed by this service
        return None
    return credentials if credentials.username == name else None


@router.get("/console/accounts/{name}/broker-password", response_class=HTMLResponse)
async def new_broker_password(request: Request, name: str, admin: Viewer, svc: ServiceDep) -> Response:
    """The password the reset just made, once: a reload finds the cookie gone."""
    credentials = _opened(svc, request.cookies.get(SHOWN_ONCE_COOKIE), name)
    response = render(
        request,
        "accounts/broker_password.html",
        admin,
        ACCOUNTS,
        headers=NO_STORE,
        name=name,
        credentials=credentials,
    )
    response.delete_cookie(SHOWN_ONCE_COOKIE, path=_shown_once_path(name))
    return response
