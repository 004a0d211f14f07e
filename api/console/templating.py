"""Rendering the console's pages and fragments (Jinja2, autoescaped: what a robot or user sent
shows as text, never as markup)."""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from fastapi import Request
from fastapi.responses import HTMLResponse
from fastapi.templating import Jinja2Templates

from fleetbus.api.console.session import CSRF_FIELD, CSRF_HEADER, csrf_token, keep_csrf_cookie
from fleetbus.api.console.sitemap import Page, pages_for
from fleetbus.api.services.accounts import User

templates = Jinja2Templates(directory=Path(__file__).parent / "templates")


def _when(moment: datetime | None) -> str:
    """A time as operators read it: UTC, to the second."""
    if moment is None:
        return ""
    if moment.tzinfo is not timezone.utc:
        moment = moment.astimezone(timezone.utc)
    return moment.isoformat(" ", "seconds")[:19]  # half strftime's time: a live page formats thousands


def _ago(moment: datetime | None) -> str:
    if moment is None:
        return "never"
    seconds = max(0, int((datetime.now(timezone.utc) - moment).total_seconds()))
    if seconds < 120:
        return f"{seconds} s ago"
    if seconds < 7200:
        return f"{seconds // 60} min ago"
    return f"{seconds // 3600} h ago"


templates.env.filters["when"] = _when
templates.env.filters["ago"] = _ago


def render(
    request: Request,
    template: str,
    user: User | None,
    page: Page | None = None,
    status_code: int = 200,
    headers: Mapping[str, str] | None = None,
    **context: Any,
) -> HTMLResponse:
    """A whole page: the layout with the navigation ``user`` may use, and the CSRF value its forms carry."""
    response = templates.TemplateResponse(
        request,
        template,
        {
            "user": user,
            "page": page,
            "nav": pages_for(user.role) if user else [],
            "csrf": csrf_token(request),
            "csrf_field": CSRF_FIELD,
            "csrf_header": CSRF_HEADER,
            **context,
        },
        status_code=status_code,
        headers=headers,
    )
    keep_csrf_cookie(request, response)
    return response


def fragment(template: str, **context: Any) -> str:
    """A piece of a page (for the live stream or an htmx answer), as HTML."""
    return templates.env.get_template(template).render(**context)
