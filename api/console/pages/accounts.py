"""Accounts (administrators): every user and robot with its role; create one, change its role,
disable it (the ``inactive`` role, as ``PUT /users/{name}/role`` does), give its broker account a
new password, shown once, end all its login sessions (as ``DELETE /users/{name}/sessions``).

Every rule is the accounts service's (``svc.accounts``, which ``/users`` calls too): the page passes
what the form says and shows the service's refusal as it is.

Supervisors open the page too and see the registered robots only (as ``GET /users`` shows them), with
no control: every action here is an administrator's.

The new broker password is shown once (:mod:`..shown_once`).
"""

from __future__ import annotations

from typing import Annotated
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, Form, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from fleetbus.api.auth import ServiceDep
from fleetbus.api.console import shown_once
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import ACCOUNTS, ADMINS
from fleetbus.api.console.templating import render
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import BadRequest, ServiceRefusal
from fleetbus.schemas.roles import ROLE_PURPOSE, UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.schemas.use_cases import USE_CASES

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(ACCOUNTS))]
Creator = Annotated[User, Depends(Allowed(ADMINS, "create users"))]
RoleSetter = Annotated[User, Depends(Allowed(ADMINS, "change roles or disable users"))]
Rekeyer = Annotated[User, Depends(Allowed(ADMINS, "reset broker passwords"))]
SessionEnder = Annotated[User, Depends(Allowed(ADMINS, "end users' sessions"))]
UseCaseSetter = Annotated[User, Depends(Allowed(ADMINS, "change users' use cases"))]
NOTICES = {
    "created": "User {name} created.",
    "role": "{name} has a new role.",
    "disabled": "{name} is disabled (role inactive): it can neither log in nor reach the broker.",
    "sessions": "Every session of {name} has ended: its console logins and API tokens are refused.",
    "use-cases": "{name}'s use cases are set.",
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
        users=await svc.accounts.listed(user),
        may_edit=user.role in ADMINS,
        use_cases=list(USE_CASES),
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


@router.post("/console/accounts/{name}/use-cases", response_class=HTMLResponse)
async def set_use_cases(
    request: Request,
    name: str,
    admin: UseCaseSetter,
    svc: ServiceDep,
    scope: Annotated[str, Form()] = "every",
    use_case: Annotated[list[str] | None, Form()] = None,
) -> Response:
    """``scope`` ``every``: every use case; else only those ticked (none ticked: none)."""
    allowed = None if scope == "every" else (use_case or [])
    try:
        await svc.accounts.set_use_cases(name, allowed, admin.name)
    except ServiceRefusal as refusal:
        return await _page(request, admin, svc, refusal.status, problem=refusal.detail)
    return _done("use-cases", name)


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
    if refusal := shown_once.refusal(request, svc, admin.name):  # before the password changes
        return await _page(request, admin, svc, 403, problem=refusal)
    try:
        credentials = await svc.accounts.reset_broker_password(name, admin.name)
    except ServiceRefusal as refusal:
        return await _page(request, admin, svc, refusal.status, problem=refusal.detail)
    return shown_once.hand_over(request, svc, credentials, _shown_once_path(credentials.username))


@router.get("/console/accounts/{name}/broker-password", response_class=HTMLResponse)
async def new_broker_password(request: Request, name: str, admin: Rekeyer, svc: ServiceDep) -> Response:
    """The password the reset just made, once: a reload finds the cookie gone."""
    response = render(
        request,
        "accounts/broker_password.html",
        admin,
        ACCOUNTS,
        name=name,
        credentials=shown_once.take(request, svc, name),
    )
    return shown_once.forget(response, _shown_once_path(name))
