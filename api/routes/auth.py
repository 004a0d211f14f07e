"""Log in: a password for a token that expires, and the caller's broker credentials; log out:
revoke a token (RFC 7009), which ends its session on the server."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Form, Request, Response
from fastapi.security import OAuth2PasswordRequestForm

from fleetbus.api import audit
from fleetbus.api.auth import ServiceDep
from fleetbus.api.login import log_in
from fleetbus.api.models import BrokerOut, TokenOut, UserOut
from fleetbus.api.openapi import refusals
from fleetbus.api.transport import broker_password_refusal

router = APIRouter(prefix="/auth", tags=["auth"])


@router.post("/token", response_model=TokenOut, responses=refusals(401, 403, 429))
async def login(
    request: Request, form: Annotated[OAuth2PasswordRequestForm, Depends()], svc: ServiceDep
) -> TokenOut:
    """Log in with user name and password (an OAuth2 password form). The token expires; the reply
    also hands over the user's broker account, whose password the service generated, but only over
    HTTPS or to a client on the API's own machine (else ``broker`` is null and ``broker_withheld``
    says why; FLEETBUS_API_INSECURE_HTTP overrides). Too many
    failed logins to an account from one address, or from one address to any, get 429 with
    Retry-After until the oldest of them is old enough."""
    login = await log_in(request, svc, form.username, form.password)
    withheld = broker_password_refusal(request, svc.settings)
    if withheld:
        audit.withheld(request, form.username, withheld)
    return TokenOut(
        access_token=login.token.value,
        expires_at=login.token.expires_at,
        user=UserOut.of(login.user),
        broker=None if withheld else BrokerOut.of(login.broker),
        broker_withheld=withheld,
    )


@router.post("/revoke", status_code=200, response_class=Response, responses={200: {"description": "Done"}})
async def revoke_token(
    token: Annotated[str, Form(description="the token to revoke")], svc: ServiceDep
) -> Response:
    """Log out (OAuth 2.0 token revocation, RFC 7009): end the session of the token sent in the form,
    on the server, so that it is refused from now on wherever it is held. Answered 200 with no body
    whether or not the token was valid (an expired, foreign or revoked one ends nothing)."""
    await svc.sessions.end_token(token)
    return Response(status_code=200)
