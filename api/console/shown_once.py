"""Broker credentials shown once: the one way the console hands a broker password to a browser,
for an administrator's reset of anyone's (the Accounts page) and for a user's own (the dashboard:
shown on request, or new).

The password goes from the POST that asked for it to the page that shows it (a GET, so that a
reload asks for nothing again) in a cookie sealed with the service's key, readable only by that
page, for two minutes; the page deletes it as it shows it, and answers ``Cache-Control: no-store``.
The request is refused before anything changes when its connection may not carry a password
(:func:`fleetbus.api.transport.broker_password_refusal`: plain HTTP from another machine).
"""

from __future__ import annotations

import json
from dataclasses import asdict

from fastapi import Request
from fastapi.responses import RedirectResponse, Response

from fleetbus.api import audit
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import BrokerCredentials
from fleetbus.api.transport import broker_password_refusal

SHOWN_ONCE_COOKIE = "fleetbus_shown_once"
SHOWN_ONCE_S = 120
NO_STORE = {"Cache-Control": "no-store"}


def refusal(request: Request, svc: Service, who: str) -> str | None:
    """Why this request may not be handed a broker password (audited); None when it may."""
    if why := broker_password_refusal(request, svc.settings):
        audit.refused(request, 403, who, why)
    return why


def hand_over(
    request: Request, svc: Service, credentials: BrokerCredentials, shown_at: str, query: str = ""
) -> Response:
    """Send the browser to ``shown_at`` (with ``query``), which alone can read ``credentials``, once."""
    location = f"{shown_at}?{query}" if query else shown_at
    response = RedirectResponse(location, status_code=303, headers=NO_STORE)
    response.set_cookie(
        SHOWN_ONCE_COOKIE,
        svc.secrets.box.seal(json.dumps(asdict(credentials))),
        max_age=SHOWN_ONCE_S,
        path=shown_at,
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",  # as the session's cookie
    )
    return response


def take(request: Request, svc: Service, name: str) -> BrokerCredentials | None:
    """The credentials of ``name`` handed over to this page, if they are still there (not too
    old, sealed by this service); :func:`forget` them in the answer."""
    sealed = request.cookies.get(SHOWN_ONCE_COOKIE)
    if not sealed:
        return None
    try:
        credentials = BrokerCredentials(**json.loads(svc.secrets.box.open(sealed, max_age_s=SHOWN_ONCE_S)))
    except (ValueError, TypeError):  # too old, or not sealed by this service
        return None
    return credentials if credentials.username == name else None


def forget(response: Response, shown_at: str) -> Response:
    """The answer that showed them: the browser drops them, and no cache keeps the page."""
    response.delete_cookie(SHOWN_ONCE_COOKIE, path=shown_at)
    response.headers.update(NO_STORE)
    return response
