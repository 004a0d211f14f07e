"""Who is looking at the console, may they open this page, and did this form come from us.

- The session is the API's own login token in a cookie: HttpOnly (no script reads it),
  SameSite=Strict (no other site's page sends it), Secure when the console is served over HTTPS,
  expiring with the token. The token names a login session in the store, checked on every
  request (:mod:`fleetbus.api.services.sessions`): logging out ends it there, so a copy of the cookie
  opens nothing afterwards. The role is read from the store on every request, as for the API.
- CSRF: a random value in a second cookie (HttpOnly, SameSite=Strict), which every form of the
  console carries back as a hidden field and every htmx request as the ``X-CSRF-Token`` header.
  A POST whose value does not match is refused with 403 before anything runs.
"""

from __future__ import annotations

import hmac
import secrets
import time
from typing import Annotated

from fastapi import Depends, HTTPException, Request, Response

from fleetbus.api import audit
from fleetbus.api.auth import ServiceDep
from fleetbus.api.console.sitemap import Page
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.security import Token, TokenRefused
from fleetbus.schemas.roles import UserRole

SESSION_COOKIE = "fleetbus_session"
CSRF_COOKIE = "fleetbus_csrf"
CSRF_FIELD = "csrf"
CSRF_HEADER = "X-CSRF-Token"
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


class LoginRequired(Exception):
    """No valid session: the page sends the browser to the login form."""

    def __init__(self, why: str) -> None:
        super().__init__(why)
        self.why = why


class PageForbidden(Exception):
    """The user's role may not open this page or take this action (answered with 403)."""

    def __init__(self, user: User, what: str) -> None:
        super().__init__(what)
        self.user = user
        self.what = what


def _secure(request: Request) -> bool:
    return request.url.scheme == "https"


def start_session(request: Request, response: Response, token: Token) -> None:
    max_age = max(1, int(token.expires_at.timestamp() - time.time()))
    response.set_cookie(
        SESSION_COOKIE,
        token.value,
        max_age=max_age,
        httponly=True,
        samesite="strict",
        secure=_secure(request),
        path="/",
    )


async def end_session(request: Request, svc: Service, response: Response) -> None:
    """End the browser's session in the store (its cookie refused from now on) and drop the cookie."""
    token = request.cookies.get(SESSION_COOKIE)
    if token:
        await svc.sessions.end_token(token)
    response.delete_cookie(SESSION_COOKIE, path="/")


def csrf_token(request: Request) -> str:
    """This browser's CSRF value (made on its first visit; :func:`keep_csrf_cookie` stores it)."""
    token = getattr(request.state, "csrf", None)
    if token is None:
        token = request.cookies.get(CSRF_COOKIE) or secrets.token_urlsafe(32)
        request.state.csrf = token
    return token


def keep_csrf_cookie(request: Request, response: Response) -> None:
    token = csrf_token(request)
    if request.cookies.get(CSRF_COOKIE) != token:
        response.set_cookie(
            CSRF_COOKIE, token, httponly=True, samesite="strict", secure=_secure(request), path="/"
        )


async def check_csrf(request: Request) -> None:
    """Refuse a POST whose CSRF value (form field or header) does not match the browser's cookie."""
    if request.method in SAFE_METHODS:
        return
    expected = request.cookies.get(CSRF_COOKIE)
    sent = request.headers.get(CSRF_HEADER)
    if sent is None and request.headers.get("content-type", "").startswith(
        ("application/x-www-form-urlencoded", "multipart/form-data")
    ):
        sent = (await request.form()).get(CSRF_FIELD)
    if not expected or not isinstance(sent, str) or not hmac.compare_digest(expected, sent):
        audit.refused(request, 403, "(console)", "the form's CSRF token is missing or does not match")
        raise HTTPException(403, detail="the form's CSRF token is missing or does not match; reload the page")


async def console_user(request: Request, svc: ServiceDep) -> User:
    """The logged-in user, from the session cookie; :class:`LoginRequired` when there is none."""
    token = request.cookies.get(SESSION_COOKIE)
    if not token:
        raise LoginRequired("please log in")
    try:
        session, user = await svc.signed_in.check(token)
    except TokenRefused as refused:  # UserGone too: "user ... no longer exists"
        raise LoginRequired(str(refused)) from None
    request.state.user = user
    request.state.session = session
    return user


ConsoleUser = Annotated[User, Depends(console_user)]


class Allowed:
    """A dependency admitting ``roles`` to ``what`` (a page, or an action on one); 403 otherwise:

    Viewer = Annotated[User, Depends(Allowed.page(HAZARDS))]
    Requeuer = Annotated[User, Depends(Allowed({UserRole.ADMIN}, "requeue dead letters"))]
    """

    def __init__(self, roles: frozenset[UserRole] | set[UserRole], what: str) -> None:
        self.roles = frozenset(roles)
        self.what = what

    @classmethod
    def page(cls, page: Page) -> Allowed:
        return cls(page.roles, f"the {page.title.lower()} page")

    async def __call__(self, request: Request, user: ConsoleUser) -> User:
        if user.role not in self.roles:
            audit.refused(request, 403, f"{user.name} ({user.role.value})", f"console: {self.what}")
            raise PageForbidden(user, self.what)
        return user
