"""Log in: a password for a token that expires, and the caller's broker credentials."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.security import OAuth2PasswordRequestForm

from fleetbus.api import audit
from fleetbus.api.accounts import WrongCredentials
from fleetbus.api.auth import ServiceDep
from fleetbus.api.errors import Forbidden
from fleetbus.api.login_limits import TooManyFailures
from fleetbus.api.models import BrokerOut, TokenOut, UserOut

router = APIRouter(prefix="/auth", tags=["auth"])


@router.post("/token", response_model=TokenOut)
async def login(
    request: Request, form: Annotated[OAuth2PasswordRequestForm, Depends()], svc: ServiceDep
) -> TokenOut:
    """Log in with user name and password (an OAuth2 password form). The token expires; the reply
    also hands over the user's broker account, whose password the service generated. Too many
    failed logins to an account from one address, or from one address to any, get 429 with
    Retry-After until the oldest of them is old enough."""
    address = audit.client_address(request)
    try:
        svc.login_limits.check(form.username, address)
    except TooManyFailures as error:
        audit.refused(request, 429, form.username, error.detail)
        raise HTTPException(
            429, detail=error.detail, headers={"Retry-After": str(error.retry_after)}
        ) from None
    try:
        login = await svc.accounts.login(form.username, form.password)
    except WrongCredentials as error:
        svc.login_limits.failed(form.username, address)
        audit.refused(request, 401, form.username, str(error))
        raise HTTPException(401, detail=str(error), headers={"WWW-Authenticate": "Bearer"}) from None
    except Forbidden as error:
        audit.refused(request, 403, form.username, error.detail)
        raise HTTPException(403, detail=error.detail) from None
    svc.login_limits.succeeded(form.username, address)
    return TokenOut(
        access_token=login.token.value,
        expires_at=login.token.expires_at,
        user=UserOut.of(login.user),
        broker=BrokerOut.of(login.broker),
    )
