"""Which RabbitMQ fleetbus talks to, decided in one place.

A broker that is configured is the only one used: ``FLEETBUS_AMQP_URL`` (``settings.amqp_url``),
or for the worker and the recorder ``FLEETBUS_SERVICE_URL``. When it does not answer, the command
waits with backoff for ``FLEETBUS_BROKER_WAIT_S`` and then fails; it never starts or picks
another broker, which would split the fleet between two (robots on one, workers on the other).

Only when nothing is configured does the command line look for one (Docker's, else a private
node): that is development tooling, :mod:`fleetbus_dev.fallback`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal
from urllib.parse import unquote, urlsplit

from fleetbus.broker.accounts import SERVICE_USER, kept_password, url_for
from fleetbus.broker.probe import NoAnswer, NotVerified, amqp_login, check_amqp_login, management_answers
from fleetbus.broker.retry import Backoff, GaveUp, retrying
from fleetbus.broker.urls import mask_password
from fleetbus.publishers.addresses import join_addresses, split_addresses
from fleetbus.publishers.errors import BrokerUnavailable
from fleetbus.settings import Settings

MANAGEMENT_PORT = 15672
PROBE_TIMEOUT = 4.0
#: Waiting for a configured broker: first retry after half a second, then at most every 5 s.
BROKER_BACKOFF = Backoff(initial=0.5, maximum=5.0, jitter=0.5)

log = logging.getLogger("fleetbus.broker")

Kind = Literal["external", "docker", "private"]


@dataclass(frozen=True)
class BrokerEndpoint:
    amqp_url: str
    """Administrator's AMQP URL (credentials included)."""
    management_url: str
    """Base URL of the management HTTP API (same credentials as ``amqp_url``)."""
    kind: Kind
    public_url: str | None = None
    """The broker as robots and users reach it, without credentials (``FLEETBUS_PUBLIC_AMQP_URL``,
    or the private node's AMQPS listener); None: ``amqp_url``'s broker."""


def derive_management_url(amqp_url: str) -> str:
    """``http://<host>:15672/`` for ``amqp://…@<host>…`` (``https://<host>:15671/`` for amqps);
    a cluster's URL: every node's, in the same order (the management client fails over alike)."""

    def one(single: str) -> str:
        parts = urlsplit(single)
        host = parts.hostname or "localhost"
        if ":" in host:
            host = f"[{host}]"
        if parts.scheme == "amqps":
            return f"https://{host}:15671/"
        return f"http://{host}:{MANAGEMENT_PORT}/"

    return join_addresses(list(dict.fromkeys(one(single) for single in split_addresses(amqp_url))))


def _credentials(amqp_url: str) -> tuple[str, str]:
    parts = urlsplit(amqp_url)
    return unquote(parts.username or ""), unquote(parts.password or "")


def wait_for_login(url: str, what: str, wait_s: float, refused_hint: str = "") -> None:
    """Return once an AMQP login at ``url`` works. Nothing answering is retried with backoff for
    ``wait_s`` seconds, each retry logged with the URL (password masked); then, or at once when
    the broker refuses the credentials, :class:`BrokerUnavailable` says so."""
    shown = f"{what} ({mask_password(url)})"
    deadline = time.monotonic() + wait_s

    def login() -> bool:
        timeout = min(PROBE_TIMEOUT, max(0.5, deadline - time.monotonic()))
        return check_amqp_login(url, timeout=timeout)

    try:
        accepted = retrying(shown, on=NoAnswer, deadline=wait_s, backoff=BROKER_BACKOFF, logger=log)(login)
    except NotVerified as error:
        raise BrokerUnavailable(
            f"{shown} cannot be trusted: {error}. Check the URL's cacertfile (the CA that signed the "
            "broker's certificate) and that its host is a name in that certificate "
            "(`fleetbus certs show`); verify=verify_none turns the check off"
        ) from None
    except GaveUp as error:
        raise BrokerUnavailable(
            f"{shown} did not answer in {error.waited:.0f} s ({error.error}). A configured broker is "
            f"never replaced by another one: check that it runs and can be reached, or wait longer "
            f"with FLEETBUS_BROKER_WAIT_S (now {wait_s:g})"
        ) from None
    if not accepted:
        raise BrokerUnavailable(f"{shown} refused its credentials{refused_hint}")


def configured_broker(settings: Settings) -> str | None:
    """The setting that names the broker (``FLEETBUS_AMQP_URL`` ...), None when nothing does."""
    for name, value in (
        ("FLEETBUS_AMQP_URL", settings.amqp_url),
        ("FLEETBUS_SERVICE_URL", settings.service_url),
        ("FLEETBUS_MANAGEMENT_URL", settings.management_url),
    ):
        if value:
            return name
    return None


def external_endpoint(settings: Settings) -> BrokerEndpoint | None:
    """The configured broker, once its administrator's login works; None when none is configured.

    A configured broker that does not answer within ``FLEETBUS_BROKER_WAIT_S``, or refuses the
    credentials, is an error: never a reason to use another broker.
    """
    configured = configured_broker(settings)
    if configured is None:
        return None
    if not settings.amqp_url:
        raise BrokerUnavailable(
            f"{configured} is set but FLEETBUS_AMQP_URL is not: this command needs the broker's "
            "administrator URL in FLEETBUS_AMQP_URL (another broker is not looked for when one is configured)"
        )
    wait_for_login(settings.amqp_url, "the broker of FLEETBUS_AMQP_URL", settings.broker_wait_s)
    management_url = settings.management_url or derive_management_url(settings.amqp_url)
    return BrokerEndpoint(settings.amqp_url, management_url, "external", settings.public_amqp_url)


def service_account_url(
    settings: Settings, account: str = SERVICE_USER, unconfigured: Callable[[], str] | None = None
) -> str:
    """The URL a service process (the worker as ``fleetbus``, the recorder as ``fleetbus-recorder``)
    logs in with, once that login works. It logs in as no other account.

    The broker is ``FLEETBUS_SERVICE_URL``'s, else ``FLEETBUS_AMQP_URL``'s, else the AMQP URL
    ``unconfigured()`` gives (the command line's fallback chain; without it, an error). The
    password is ``FLEETBUS_SERVICE_URL``'s for ``fleetbus`` when it has one, else the one
    ``fleetbus setup`` kept in the data folder.
    """
    base = settings.service_url or settings.amqp_url
    if base is None:
        if unconfigured is None:
            raise BrokerUnavailable("no broker configured: set FLEETBUS_SERVICE_URL or FLEETBUS_AMQP_URL")
        base = unconfigured()
    given = urlsplit(settings.service_url).password if settings.service_url else None
    password = (
        unquote(given) if given and account == SERVICE_USER else kept_password(settings.accounts_dir, account)
    )
    if password is None:
        raise BrokerUnavailable(
            f"no password for the {account} account: run `fleetbus setup` with the administrator's "
            f"credentials once (it keeps it in {settings.accounts_dir}), or put it in FLEETBUS_SERVICE_URL"
        )
    url = url_for(base, account, password)
    wait_for_login(
        url,
        f"the broker as {account}",
        settings.broker_wait_s,
        refused_hint=": run `fleetbus setup` with the administrator's credentials (it makes the account)",
    )
    return url


def endpoint_ready(endpoint: BrokerEndpoint, timeout: float = PROBE_TIMEOUT) -> bool:
    """AMQP login and ``GET /api/overview`` both work with the endpoint's credentials."""
    if not amqp_login(endpoint.amqp_url, timeout=timeout):
        return False
    return management_answers(endpoint.management_url, *_credentials(endpoint.amqp_url), timeout=timeout)
