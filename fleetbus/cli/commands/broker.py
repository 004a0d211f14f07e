"""``fleetbus broker up | down | status``: the broker the other commands use.

``up`` waits for the broker of ``FLEETBUS_AMQP_URL`` when it is set (and fails when it does not
answer); otherwise it starts the ``rabbitmq`` service of ``compose.yaml`` (when a Docker engine
answers) or the project's private node under ``.fleetbus/broker/``. Then it runs ``fleetbus
setup``. ``down`` stops the private node; ``status`` exits 1 when no broker runs. URLs are shown
with their passwords masked unless ``--show-password`` is given.
"""

from __future__ import annotations

import time
from typing import Annotated

import typer

from fleetbus.broker.endpoint import BrokerEndpoint, BrokerUnavailable, endpoint_ready, external_endpoint
from fleetbus.cli.commands.setup import ShowPassword, set_up, show_url
from fleetbus.cli.context import console, fail, settings
from fleetbus.dev.fallback import (
    compose_up,
    docker_endpoint,
    docker_engine_answers,
    local_node,
    node_endpoint,
    resolve_broker,
)
from fleetbus.dev.local_node import LocalNode, LocalNodeError

app = typer.Typer(
    help="The broker: FLEETBUS_AMQP_URL, Docker, or a private RabbitMQ node.", no_args_is_help=True
)

KIND_LABEL = {
    "external": "FLEETBUS_AMQP_URL",
    "docker": "docker compose service `rabbitmq`",
    "private": "private RabbitMQ node",
}


def _show(endpoint: BrokerEndpoint, extra: dict[str, str] | None = None, show_password: bool = False) -> None:
    """One ``key  value`` line each, never wrapped, so that the URLs can be copied."""
    rows = {"broker": KIND_LABEL[endpoint.kind], **(extra or {})}
    rows["AMQP URL"] = show_url(endpoint.amqp_url, show_password)
    rows["management URL"] = endpoint.management_url
    if endpoint.public_url:
        rows["robots' URL"] = endpoint.public_url
    for key, value in rows.items():
        console.print(f"[bold]{key:<15}[/] {value}", soft_wrap=True, highlight=False)


def _node_extra(node: LocalNode) -> dict[str, str]:
    info = node.status()
    extra = {"pid": str(info.pid), "node": info.node_name, "folder": str(info.base_dir)}
    if info.management_tls_url:
        extra["management TLS"] = info.management_tls_url
    extra["CA"] = str(node.tls.ca)
    return extra


@app.command()
def up(
    timeout: Annotated[float, typer.Option(help="seconds to wait for the broker to start")] = 90.0,
    show_password: ShowPassword = False,
) -> None:
    """Make sure a broker runs (start one if none is configured), set up the service accounts
    (`fleetbus setup`), and print the broker's URLs."""
    current = settings()
    started = time.monotonic()
    extra: dict[str, str] | None = None
    try:
        endpoint = external_endpoint(current)  # configured: waited for, never replaced
        if endpoint is None and docker_engine_answers():
            with console.status("starting RabbitMQ with docker compose…"):
                endpoint = compose_up(current)
        elif endpoint is None:
            node = local_node(current)
            already = node.pid() is not None
            with console.status("starting the private RabbitMQ node…"):
                info = node.up(timeout=timeout)
            endpoint = node_endpoint(current, info)
            console.print(
                "[green]already running[/]"
                if already
                else f"[green]started[/] in {time.monotonic() - started:.1f} s"
            )
            extra = _node_extra(node)
    except (BrokerUnavailable, LocalNodeError) as error:
        fail(str(error))
    _show(endpoint, extra, show_password)
    set_up(endpoint, show_password)


@app.command()
def down(
    timeout: Annotated[float, typer.Option(help="seconds to wait for the node to stop")] = 60.0,
) -> None:
    """Stop the private RabbitMQ node and its epmd (a broker fleetbus did not start is left alone)."""
    current = settings()
    node = local_node(current)
    if node.pid() is None and not node.epmd_pids():
        console.print("the private RabbitMQ node is not running")
    else:
        started = time.monotonic()
        try:
            with console.status("stopping the private RabbitMQ node…"):
                node.down(timeout=timeout)
        except LocalNodeError as error:
            fail(str(error))
        console.print(f"[green]stopped[/] the private RabbitMQ node in {time.monotonic() - started:.1f} s")
    if current.amqp_url:
        console.print("FLEETBUS_AMQP_URL is set: that broker is not managed here")
    elif docker_engine_answers() and endpoint_ready(docker_endpoint(current)):
        console.print(
            "the docker compose service `rabbitmq` still runs: stop it with `docker compose stop rabbitmq`"
        )


@app.command()
def status(show_password: ShowPassword = False) -> None:
    """Print the broker's URLs (the password masked); exit 1 when none runs."""
    current = settings()
    try:
        endpoint = resolve_broker(current, start=False)
    except (BrokerUnavailable, LocalNodeError) as error:
        console.print(f"[red]not running[/]: {error}", highlight=False)
        raise typer.Exit(1) from None
    extra = _node_extra(local_node(current)) if endpoint.kind == "private" else None
    console.print("[green]running[/]")
    _show(endpoint, extra, show_password)
    if not show_password:
        where = {
            "private": f"{local_node(current).admin_file}",
            "docker": f"FLEETBUS_BROKER_PASSWORD, else the file {current.broker_dir / 'docker-password'}",
            "external": "FLEETBUS_AMQP_URL",
        }[endpoint.kind]
        console.print(f"the administrator's password: --show-password, or {where}", highlight=False)
