"""The refusals log: every 401, 403 and 429 the service answers, and every broker password withheld,
and why, on ``fleetbus.api.services.security``."""

from __future__ import annotations

import logging

from fastapi import Request

log = logging.getLogger("fleetbus.api.security")


def client_address(request: Request) -> str:
    """The caller's address (uvicorn takes it from X-Forwarded-For only behind a trusted proxy)."""
    return request.client.host if request.client else "?"


def where(request: Request) -> str:
    return f"{request.method} {request.url.path} from {client_address(request)}"


def refused(request: Request, status: int, who: str, why: str) -> None:
    log.warning("refused %d: %s as %s: %s", status, where(request), who, why)


def withheld(request: Request, who: str, why: str) -> None:
    """A broker password not handed out over this connection (the rest of the answer was given)."""
    log.warning("withheld the broker password: %s as %s: %s", where(request), who, why)
