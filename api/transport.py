"""Whether a request's connection may carry a broker password: the one rule, for the login
(``POST /auth/token``) and the console's broker password reset.

A password goes out over HTTPS, or to a client on this machine (loopback: nobody else is on the
path), or when ``FLEETBUS_API_INSECURE_HTTP`` says so. Behind a TLS-terminating proxy, uvicorn
takes the scheme from ``X-Forwarded-Proto`` when the proxy is trusted (``--forwarded-allow-ips``).
"""

from __future__ import annotations

import ipaddress

from fastapi import Request

from fleetbus.settings import Settings


def _loopback(host: str | None) -> bool:
    try:
        return host is not None and ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def broker_password_refusal(request: Request, settings: Settings) -> str | None:
    """Why this request may not be handed a broker password; None when it may."""
    if request.url.scheme == "https" or settings.api_insecure_http:
        return None
    host = request.client.host if request.client else None
    if _loopback(host):
        return None
    return (
        f"a broker password is handed out over HTTPS only, and this request came over plain HTTP from "
        f"{host or 'an unknown address'}: use the API's https:// address (`fleetbus api --tls`, or a "
        "TLS proxy in front of it), or log in from the API's own machine; FLEETBUS_API_INSECURE_HTTP=true "
        "allows it anyway (anyone on the network path then reads the password)"
    )
