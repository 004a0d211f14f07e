"""Which RabbitMQ fleetbus talks to, decided in one place.

In order:

1. ``FLEETBUS_AMQP_URL`` (``settings.amqp_url``) when an AMQP login with it works;
2. else, when a Docker engine answers, the ``rabbitmq`` service of ``compose.yaml``
   (``docker compose up -d rabbitmq``; administrator ``fleetbus-admin`` with the password in
   ``FLEETBUS_BROKER_PASSWORD``, generated and kept in the data folder when unset);
3. else the private node of :mod:`broker.local_node` under ``settings.broker_dir``.
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

from broker.local_node import (
    ADMIN_USER,
    RABBITMQ_SERVER,
    SETUP_HINT,
    LocalNode,
    LocalNodeError,
    amqp_login,
    management_answers,
    write_private_file,
)
from fleetbus.config import Settings

PROJECT_ROOT = Path(__file__).resolve().parent.parent
COMPOSE_FILE = PROJECT_ROOT / "compose.yaml"
COMPOSE_SERVICE = "rabbitmq"
DOCKER_AMQP_PORT = 5672
DOCKER_MANAGEMENT_PORT = 15672
PASSWORD_VARIABLE = "FLEETBUS_BROKER_PASSWORD"
PROBE_TIMEOUT = 4.0

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


def external_endpoint(settings: Settings) -> BrokerEndpoint | None:
    """The broker of ``FLEETBUS_AMQP_URL`` when it accepts the login, None when nothing answers.

    A broker that answers but refuses the credentials is an error, not a reason to fall back.
    """
    if not settings.amqp_url:
        return None
    login = amqp_login(settings.amqp_url, timeout=PROBE_TIMEOUT)
    if login is False:
        raise BrokerUnavailable("the broker of FLEETBUS_AMQP_URL refused its credentials")
    if login is None:
        log.info("FLEETBUS_AMQP_URL does not answer; looking for another broker")
        return None
    management_url = settings.management_url or derive_management_url(settings.amqp_url)
    return BrokerEndpoint(settings.amqp_url, management_url, "external")


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
    password = os.environ.get(PASSWORD_VARIABLE)
    if password:
        return password
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
            f"no broker: FLEETBUS_AMQP_URL is unset or does not answer, no Docker engine answers, "
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
    """The broker to use (see the module docstring); with ``start=False`` nothing is started and
    a broker that does not run is an error."""
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
