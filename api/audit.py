"""The refusals log: every 401 and 403 the service answers, and why, on ``fleetbus.api.security``."""

from __future__ import annotations

import logging

from fastapi import Request

log = logging.getLogger("fleetbus.api.security")


def where(request: Request) -> str:
    client = request.client.host if request.client else "?"
    return f"{request.method} {request.url.path} from {client}"


def refused(request: Request, status: int, who: str, why: str) -> None:
    log.warning("refused %d: %s as %s: %s", status, where(request), who, why)
