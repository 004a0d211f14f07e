"""My account (every user who may log in to the console): name and role, change the password, the
user's own login sessions (when begun, last seen, from where), each of which it may end, and its
broker login: the URL, the password shown once on request (:mod:`..shown_once`), a new password
(the accounts service's reset, as an administrator's on the Accounts page).

The rules are the services' (``svc.accounts``, ``svc.sessions``), as ``/users/me`` and
``/users/me/sessions`` use them: a password change ends the user's other sessions; ending the
session this page was opened with is a logout.
"""

from __future__ import annotations

from typing import Annotated
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, Form, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from fleetbus.api.auth import ServiceDep
from fleetbus.api.console import shown_once
from fleetbus.api.console.my_work import broker_login
from fleetbus.api.console.session import Allowed, end_session
from fleetbus.api.console.sitemap import ACCOUNT
from fleetbus.api.console.templating import render
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import ServiceRefusal

router = APIRouter()
Owner = Annotated[User, Depends(Allowed.page(ACCOUNT))]
NOTICES = {
    "password": "Your password is changed; your other sessions have ended.",
    "ended": "That session has ended: its browser or token is refused from now on.",
}


async def _page(
    request: Request,
    user: User,
    svc: Service,
    status_code: int = 200,
    problem: str | None = None,
    notice: str | None = None,
) -> Response:
    return render(
        request,
        "account/page.html",
        user,
        ACCOUNT,
        status_code=status_code,
        sessions=await svc.sessions.of(user.name),
        current=request.state.session.id,
        most=svc.sessions.per_user,
        broker=broker_login(svc, user),
        problem=problem,
        notice=notice,
    )


@router.get("/console/account", response_class=HTMLResponse)
async def account(request: Request, user: Owner, svc: ServiceDep, done: str | None = None) -> Response:
    return await _page(request, user, svc, notice=NOTICES.get(done or ""))


def _done(done: str) -> RedirectResponse:
    return RedirectResponse(f"/console/account?{urlencode({'done': done})}", status_code=303)


@router.post("/console/account/password", response_class=HTMLResponse)
async def change_password(
    request: Request,
    user: Owner,
    svc: ServiceDep,
    current_password: Annotated[str, Form()] = "",
    new_password: Annotated[str, Form()] = "",
) -> Response:
    try:
        await svc.accounts.change_own_password(
            user, current_password, new_password, keep=request.state.session.id
        )
    except ServiceRefusal as refusal:
        return await _page(request, user, svc, refusal.status, problem=refusal.detail)
    return _done("password")


@router.post("/console/account/sessions/{session_id}/end", response_class=HTMLResponse)
async def end_one(request: Request, session_id: str, user: Owner, svc: ServiceDep) -> Response:
    if session_id == request.state.session.id:  # this browser's own: a logout
        response = RedirectResponse("/console/login", status_code=303)
        await end_session(request, svc, response)
        return response
    if not await svc.sessions.end(user.name, session_id):
        problem = "you have no such session (it may have ended already)"
        return await _page(request, user, svc, 404, problem=problem)
    return _done("ended")


SHOWN_AT = "/console/account/broker-password"


def _not_handed(request: Request, user: User, problem: str, status_code: int) -> Response:
    response = render(
        request, "account/broker_password.html", user, ACCOUNT, status_code=status_code, problem=problem
    )
    return shown_once.forget(response, SHOWN_AT)


@router.post("/console/account/broker-password/show", response_class=HTMLResponse)
async def show_broker_password(request: Request, user: Owner, svc: ServiceDep) -> Response:
    """The user's broker password as it is, on the page that shows it once."""
    if refusal := shown_once.refusal(request, svc, user.name):
        return _not_handed(request, user, refusal, 403)
    try:
        credentials = svc.accounts.broker_credentials(user)
    except ServiceRefusal as refusal:
        return _not_handed(request, user, refusal.detail, refusal.status)
    return shown_once.hand_over(request, svc, credentials, SHOWN_AT)


@router.post("/console/account/broker-password/new", response_class=HTMLResponse)
async def new_broker_password(request: Request, user: Owner, svc: ServiceDep) -> Response:
    """A new broker password for the user (the old one stops logging in), shown once."""
    if refusal := shown_once.refusal(request, svc, user.name):  # before the password changes
        return _not_handed(request, user, refusal, 403)
    try:
        credentials = await svc.accounts.reset_broker_password(user.name, user.name)
    except ServiceRefusal as refusal:
        return _not_handed(request, user, refusal.detail, refusal.status)
    return shown_once.hand_over(request, svc, credentials, SHOWN_AT, "new=1")


@router.get(SHOWN_AT, response_class=HTMLResponse)
async def broker_password(request: Request, user: Owner, svc: ServiceDep, new: bool = False) -> Response:
    """The password handed over, once: a reload finds the cookie gone."""
    credentials = shown_once.take(request, svc, user.name)
    response = render(
        request, "account/broker_password.html", user, ACCOUNT, credentials=credentials, new=new
    )
    return shown_once.forget(response, SHOWN_AT)
