"""The console's routes: login and logout, the pages (one module each under :mod:`.pages`), the
static files, and how a missing session or a forbidden page is answered."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated
from urllib.parse import quote

from fastapi import APIRouter, Depends, FastAPI, Form, HTTPException, Request
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles

from fleetbus.api.auth import ServiceDep
from fleetbus.api.console.headers import ConsoleHeaders
from fleetbus.api.console.pages import router as page_routers
from fleetbus.api.console.pages.alerts import banner_fragments
from fleetbus.api.console.session import (
    LoginRequired,
    PageForbidden,
    check_csrf,
    console_user,
    end_session,
    start_session,
)
from fleetbus.api.console.sitemap import home_for
from fleetbus.api.console.templating import render
from fleetbus.api.login import log_in
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import Forbidden
from fleetbus.schemas.roles import UserRole

STATIC = Path(__file__).parent / "static"
#: The console's icon: linked from every page, and at the address browsers ask for without a link.
ICON = STATIC / "favicon.svg"
router = APIRouter(dependencies=[Depends(check_csrf)], include_in_schema=False)


def _safe_next(target: str | None) -> str | None:
    """Only a path of the console itself (never another site) to go back to after logging in."""
    if target and target.startswith("/console/") and not target.startswith("//"):
        return target
    return None


@router.get("/")
async def root() -> RedirectResponse:
    return RedirectResponse("/console/", status_code=303)


@router.get("/favicon.ico")
async def favicon() -> FileResponse:
    return FileResponse(ICON, media_type="image/svg+xml")


@router.get("/console/login", response_class=HTMLResponse)
async def login_form(request: Request, next: str | None = None) -> Response:
    return render(request, "login.html", None, next=_safe_next(next), problem=None)


def _has_pages(user: User) -> None:
    """A console login is for a user with pages: refused before a session begins (a robot's API
    sessions are kept to a number, and a session begun here would end its oldest)."""
    if home_for(user.role) is None or user.role is UserRole.ROBOT:
        raise Forbidden(f"role {user.role.value} has no page in the console")


@router.post("/console/login", response_class=HTMLResponse)
async def login(
    request: Request,
    svc: ServiceDep,
    username: Annotated[str, Form()],
    password: Annotated[str, Form()],
    next: Annotated[str | None, Form()] = None,
) -> Response:
    try:
        done = await log_in(request, svc, username, password, admit=_has_pages)
    except HTTPException as refused:
        return render(
            request,
            "login.html",
            None,
            status_code=refused.status_code,
            next=_safe_next(next),
            problem=refused.detail,
            headers=refused.headers,
        )
    home = home_for(done.user.role)
    assert home is not None  # admitted by _has_pages
    response = RedirectResponse(_safe_next(next) or home.path, status_code=303)
    start_session(request, response, done.token)
    return response


@router.post("/console/logout")
async def logout(request: Request, svc: ServiceDep) -> RedirectResponse:
    response = RedirectResponse("/console/login", status_code=303)
    await end_session(request, svc, response)
    return response


def install_console(app: FastAPI) -> None:
    """Serve the console from ``app``: its routes, its files, its headers and its refusals."""
    app.add_middleware(ConsoleHeaders)
    app.state.on_every_live_page = banner_fragments
    app.mount("/static/console", StaticFiles(directory=STATIC), name="console-static")
    app.include_router(router)
    app.include_router(page_routers, dependencies=[Depends(check_csrf)], include_in_schema=False)

    @app.exception_handler(LoginRequired)
    async def login_required(request: Request, error: LoginRequired) -> Response:
        target = f"/console/login?next={quote(request.url.path)}"
        if request.headers.get("hx-request"):
            return Response(status_code=401, headers={"HX-Redirect": target})
        if request.headers.get("accept", "").startswith("text/event-stream"):
            return Response(error.why, status_code=401)
        return RedirectResponse(target, status_code=303)

    @app.exception_handler(PageForbidden)
    async def forbidden(request: Request, error: PageForbidden) -> Response:
        return render(request, "forbidden.html", error.user, status_code=403, what=error.what)


__all__ = ["console_user", "install_console"]
