"""Logging in, the one way: the limits on failed logins, the password check and the refusals log.
The HTTP API's ``POST /auth/token`` and the console's login form both go through :func:`log_in`."""

from __future__ import annotations

from collections.abc import Callable

from fastapi import HTTPException, Request

from fleetbus.api import audit
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import Login, User, WrongCredentials
from fleetbus.api.services.errors import Forbidden
from fleetbus.api.services.login_limits import TooManyFailures
from fleetbus.api.services.sessions import AGENT_MOST, Origin


async def log_in(
    request: Request, svc: Service, name: str, password: str, admit: Callable[[User], None] | None = None
) -> Login:
    """The login, or an :class:`HTTPException` saying why not: 429 with Retry-After when too many
    logins failed (answered before the password is checked), 401 for a wrong name or password,
    403 for an inactive account or one ``admit`` refuses (no session begun)."""
    address = audit.client_address(request)
    try:
        attempt = await svc.login_limits.begin(name, address)
    except TooManyFailures as error:
        audit.refused(request, 429, name, error.detail)
        raise HTTPException(
            429, detail=error.detail, headers={"Retry-After": str(error.retry_after)}
        ) from None
    async with attempt:
        try:
            login = await svc.accounts.login(name, password, origin_of(request), admit)
        except WrongCredentials as error:
            svc.login_limits.failed(name, address)
            audit.refused(request, 401, name, str(error))
            raise HTTPException(401, detail=str(error), headers={"WWW-Authenticate": "Bearer"}) from None
        except Forbidden as error:
            audit.refused(request, 403, name, error.detail)
            raise HTTPException(403, detail=error.detail) from None
        svc.login_limits.succeeded(name, address)
        return login


def origin_of(request: Request) -> Origin:
    """Where a login comes from: the client's address and its user agent (shortened)."""
    agent = request.headers.get("user-agent")
    address = audit.client_address(request) if request.client else None
    return Origin(address, agent[:AGENT_MOST] if agent else None)
