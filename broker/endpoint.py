"""Which RabbitMQ fleetbus talks to, decided in one place.

A broker that is configured is the only one used: ``FLEETBUS_AMQP_URL`` (``settings.amqp_url``),
or for the worker and the recorder ``FLEETBUS_SERVICE_URL``. When it does not answer, the command
waits with backoff for ``FLEETBUS_BROKER_WAIT_S`` and then fails; it never starts or picks
another broker, which would split the fleet between two (robots on one, workers on the other).

Only when nothing is configured does fleetbus look, in order, for

1. the ``rabbitmq`` service of ``compose.yaml``, when a Docker engine answers
   (``docker compose up -d rabbitmq``; administrator ``fleetbus-admin`` with the password in
   ``FLEETBUS_BROKER_PASSWORD``, generated and kept in the data folder when unset);
2. else the private node of :mod:`broker.local_node` under ``settings.broker_dir``.
"""

from __future__ import annotations

import logging
import os
import secrets
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal
from urllib.parse import quote, unquote, urlsplit

from broker.accounts import SERVICE_USER, kept_password, url_for
from broker.local_node import (
    ADMIN_USER,
    RABBITMQ_SERVER,
    SETUP_HINT,
    LocalNode,
    LocalNodeError,
    NoAnswer,
    amqp_login,
    check_amqp_login,
    management_answers,
    write_private_file,
)
from broker.retry import Backoff, GaveUp, retrying
from broker.urls import mask_password
from fleetbus.settings import Settings

PROJECT_ROOT = Path(__file__).resolve().parent.parent
COMPOSE_FILE = PROJECT_ROOT / "compose.yaml"
COMPOSE_SERVICE = "rabbitmq"
DOCKER_AMQP_PORT = 5672
DOCKER_MANAGEMENT_PORT = 15672
PASSWORD_VARIABLE = "FLEETBUS_BROKER_PASSWORD"
PROBE_TIMEOUT = 4.0
#: Waiting for a configured broker: first retry after half a second, then at most every 5 s.
BROKER_BACKOFF = Backoff(initial=0.5, maximum=5.0, jitter=0.5)

log = logging.getLogger("fleetbus.broker")

Kind = Literal["external", "docker", "private"]


class BrokerUnavailable(RuntimeError):
    """No broker could be found or started; the message says what to do."""


@dataclass(frozen=True)
class BrokerEndpoint:
    amqp_url: str
    """Administrator's AMQP URL (credentials included)."""
    management_url: str
    """Base URL of the management HTTP API (same credentials as ``amqp_url``)."""
    kind: Kind


def derive_management_url(amqp_url: str) -> str:
    """``http://<host>:15672/`` for ``amqp://…@<host>…`` (``https://<host>:15671/`` for amqps)."""
    parts = urlsplit(amqp_url)
    host = parts.hostname or "localhost"
    if ":" in host:
        host = f"[{host}]"
    if parts.scheme == "amqps":
        return f"https://{host}:15671/"
    return f"http://{host}:{DOCKER_MANAGEMENT_PORT}/"


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
    return BrokerEndpoint(settings.amqp_url, management_url, "external")


def service_account_url(settings: Settings, account: str = SERVICE_USER, start: bool = True) -> str:
    """The URL a service process (the worker as ``fleetbus``, the recorder as ``fleetbus-recorder``)
    logs in with, once that login works. It logs in as no other account.

    The broker is ``FLEETBUS_SERVICE_URL``'s, else ``FLEETBUS_AMQP_URL``'s, else the one the
    fallback chain finds (or starts, with ``start``). The password is ``FLEETBUS_SERVICE_URL``'s
    for ``fleetbus`` when it has one, else the one ``fleetbus setup`` kept in the data folder.
    """
    base = settings.service_url or settings.amqp_url
    if base is None:
        base = resolve_broker(settings, start=start).amqp_url
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


# --------------------------------------------------------------------------- Docker


def docker_engine_answers(timeout: float = 5.0) -> bool:
    """Whether ``docker info`` exits 0 within ``timeout`` seconds (a client alone is not enough)."""
    if shutil.which("docker") is None:
        return False
    try:
        result = subprocess.run(
            ["docker", "info"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            timeout=timeout,
        )
    except (OSError, subprocess.TimeoutExpired):
        return False
    return result.returncode == 0


def docker_password(settings: Settings) -> str:
    """``FLEETBUS_BROKER_PASSWORD``, else one generated once and kept in the data folder."""
    if settings.broker_password:
        return settings.broker_password.get_secret_value()
    path = settings.broker_dir / "docker-password"
    if path.exists():
        return path.read_text().strip()
    password = secrets.token_urlsafe(24)
    settings.broker_dir.mkdir(parents=True, exist_ok=True)
    write_private_file(path, password + "\n")
    return password


def docker_endpoint(settings: Settings) -> BrokerEndpoint:
    password = docker_password(settings)
    return BrokerEndpoint(
        f"amqp://{ADMIN_USER}:{quote(password, safe='')}@127.0.0.1:{DOCKER_AMQP_PORT}/",
        f"http://127.0.0.1:{DOCKER_MANAGEMENT_PORT}/",
        "docker",
    )


def endpoint_ready(endpoint: BrokerEndpoint, timeout: float = PROBE_TIMEOUT) -> bool:
    """AMQP login and ``GET /api/overview`` both work with the endpoint's credentials."""
    if not amqp_login(endpoint.amqp_url, timeout=timeout):
        return False
    return management_answers(endpoint.management_url, *_credentials(endpoint.amqp_url), timeout=timeout)


def compose_up(settings: Settings, timeout: float = 180.0) -> BrokerEndpoint:
    """``docker compose up -d rabbitmq`` from the project root, then wait until it answers."""
    endpoint = docker_endpoint(settings)
    if endpoint_ready(endpoint):
        return endpoint
    if not COMPOSE_FILE.exists():
        raise BrokerUnavailable(f"a Docker engine answers but {COMPOSE_FILE} is missing")
    env = dict(os.environ)
    env[PASSWORD_VARIABLE] = docker_password(settings)
    log.info("starting RabbitMQ with docker compose (%s)", COMPOSE_FILE)
    try:
        result = subprocess.run(
            ["docker", "compose", "-f", str(COMPOSE_FILE), "up", "-d", COMPOSE_SERVICE],
            cwd=PROJECT_ROOT,
            env=env,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired as error:
        raise BrokerUnavailable(
            f"`docker compose up -d {COMPOSE_SERVICE}` took over {timeout:.0f} s"
        ) from error
    if result.returncode != 0:
        raise BrokerUnavailable(
            f"`docker compose up -d {COMPOSE_SERVICE}` failed ({result.returncode}): "
            f"{(result.stderr or result.stdout).strip()[-2000:]}"
        )
    deadline = time.monotonic() + timeout
    while not endpoint_ready(endpoint):
        if time.monotonic() >= deadline:
            raise BrokerUnavailable(
                f"the {COMPOSE_SERVICE} container did not accept {ADMIN_USER}'s login in {timeout:.0f} s "
                f"(see `docker compose logs {COMPOSE_SERVICE}`; a data volume made with another "
                f"{PASSWORD_VARIABLE} keeps the old password)"
            )
        time.sleep(0.5)
    return endpoint


# --------------------------------------------------------------------------- private node


def private_endpoint(settings: Settings, start: bool = True) -> BrokerEndpoint:
    if not RABBITMQ_SERVER.exists():
        raise BrokerUnavailable(
            f"no broker: FLEETBUS_AMQP_URL is unset, no Docker engine answers, "
            f"and RabbitMQ is not installed ({RABBITMQ_SERVER} is missing): {SETUP_HINT}"
        )
    node = LocalNode(settings.broker_dir)
    if start:
        info = node.up()
    else:
        info = node.status()
        if not info.running or not node.ready():
            raise BrokerUnavailable("the private RabbitMQ node is not running: run `fleetbus broker up`")
    assert info.amqp_url is not None and info.management_url is not None
    return BrokerEndpoint(info.amqp_url, info.management_url, "private")


def resolve_broker(settings: Settings, start: bool = True) -> BrokerEndpoint:
    """The broker to use, as administrator (see the module docstring); with ``start=False``
    nothing is started and a broker that does not run is an error."""
    endpoint = external_endpoint(settings)
    if endpoint is not None:
        return endpoint
    if docker_engine_answers():
        if start:
            return compose_up(settings)
        endpoint = docker_endpoint(settings)
        if endpoint_ready(endpoint):
            return endpoint
        raise BrokerUnavailable(f"the {COMPOSE_SERVICE} container does not answer: run `fleetbus broker up`")
    try:
        return private_endpoint(settings, start=start)
    except LocalNodeError as error:
        raise BrokerUnavailable(str(error)) from error
