"""The broker to use when none is configured: Docker's, else the private node.

Only when nothing names a broker (``FLEETBUS_AMQP_URL``, ``FLEETBUS_SERVICE_URL``,
``FLEETBUS_MANAGEMENT_URL``) does fleetbus look, in order, for

1. the ``rabbitmq`` service of ``compose.yaml``, when a Docker engine answers
   (``docker compose up -d rabbitmq``; administrator ``fleetbus-admin`` with the password in
   ``FLEETBUS_BROKER_PASSWORD``, generated and kept in the data folder when unset);
2. else the private node of :mod:`fleetbus_dev.local_node` under ``settings.broker_dir``.

A configured broker is the only one used (:func:`fleetbus.broker.endpoint.external_endpoint`).
"""

from __future__ import annotations

import logging
import os
import secrets
import shutil
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path
from urllib.parse import quote

from fleetbus.broker.certificates import TlsFiles
from fleetbus.broker.endpoint import (
    MANAGEMENT_PORT,
    BrokerEndpoint,
    BrokerUnavailable,
    endpoint_ready,
    external_endpoint,
)
from fleetbus.broker.probe import write_private_file
from fleetbus.settings import Settings
from fleetbus_dev.cluster import ClusterInfo, LocalCluster
from fleetbus_dev.local_node import ADMIN_USER, LocalNode, LocalNodeError, NodeInfo
from fleetbus_dev.rabbitmq import InstallationError

PROJECT_ROOT = Path(__file__).resolve().parents[2]
COMPOSE_FILE = PROJECT_ROOT / "compose.yaml"
COMPOSE_SERVICE = "rabbitmq"
DOCKER_AMQP_PORT = 5672
PASSWORD_VARIABLE = "FLEETBUS_BROKER_PASSWORD"

log = logging.getLogger("fleetbus.broker")


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
        f"http://127.0.0.1:{MANAGEMENT_PORT}/",
        "docker",
        settings.public_amqp_url,
    )


def compose_up(settings: Settings, timeout: float = 600.0) -> BrokerEndpoint:
    """``docker compose up -d rabbitmq`` from the project root, then wait until it answers. Compose
    runs the one-shot ``certs`` service first (the broker's TLS certificate), which builds the
    fleetbus image the first time: minutes, hence the long ``timeout``."""
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


def local_node(settings: Settings) -> LocalNode:
    """The private node of ``settings``' data folder, serving ``FLEETBUS_TLS_*``'s certificates."""
    return LocalNode(settings.broker_dir, TlsFiles.for_settings(settings), settings.broker_tls_only)


def node_endpoint(settings: Settings, info: NodeInfo) -> BrokerEndpoint:
    """The private node as administrator; robots are handed its AMQPS listener."""
    assert info.amqp_url is not None and info.management_url is not None
    return BrokerEndpoint(
        info.amqp_url, info.management_url, "private", settings.public_amqp_url or info.public_url
    )


def local_cluster(settings: Settings, size: int = 3) -> LocalCluster:
    """The private cluster of ``settings``' data folder (``fleetbus broker up --nodes N``)."""
    return LocalCluster(settings.data_dir / "cluster", size, TlsFiles.for_settings(settings))


def cluster_endpoint(info: ClusterInfo) -> BrokerEndpoint:
    """The private cluster as administrator, its URL listing every node; robots are handed it too
    (with their own login): a URL with several AMQPS addresses is not made for them."""
    assert info.amqp_url is not None and info.management_url is not None
    return BrokerEndpoint(info.amqp_url, info.management_url, "private", None)


def private_endpoint(settings: Settings, start: bool = True) -> BrokerEndpoint:
    cluster = local_cluster(settings)
    if cluster.exists() and cluster.status().running:  # `fleetbus broker up --nodes N` started it
        return cluster_endpoint(cluster.up() if start else cluster.status())
    node = local_node(settings)
    try:
        node.installation().require()
    except InstallationError as error:
        raise BrokerUnavailable(
            f"no broker: FLEETBUS_AMQP_URL is unset, no Docker engine answers, and {error}"
        ) from None
    if start:
        info = node.up()
    else:
        info = node.status()
        if not info.running or not node.ready():
            raise BrokerUnavailable("the private RabbitMQ node is not running: run `fleetbus broker up`")
    return node_endpoint(settings, info)


def resolve_broker(settings: Settings, start: bool = True) -> BrokerEndpoint:
    """The broker to use, as administrator (see the module docstring); with ``start=False``
    nothing is started and a broker that does not run is an error."""
    endpoint = external_endpoint(settings)
    return endpoint if endpoint is not None else unconfigured_broker(settings, start)


def unconfigured_broker(settings: Settings, start: bool = True) -> BrokerEndpoint:
    """Docker's broker when a Docker engine answers, else the private node (or cluster)."""
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


class PrivateBroker:
    """The command line's broker when none is configured (:mod:`fleetbus.cli.local_broker`)."""

    def resolve(self, settings: Settings, start: bool) -> BrokerEndpoint:
        return unconfigured_broker(settings, start)

    def public_url(self, settings: Settings) -> str | None:
        return local_node(settings).public_url()

    def enable_plugins(self, settings: Settings, plugins: Sequence[str]) -> None:
        local_node(settings).rabbitmq_plugins("enable", "--online", *plugins)


#: The ``fleetbus.local_broker`` entry point of ``dev/pyproject.toml``.
LOCAL_BROKER = PrivateBroker()
