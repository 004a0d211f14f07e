"""``fleetbus broker up | down | status``: the broker the other commands use.

``up`` reports the broker of ``FLEETBUS_AMQP_URL`` when it answers; otherwise it starts the
``rabbitmq`` service of ``compose.yaml`` (when a Docker engine answers) or the project's private
node under ``.fleetbus/broker/``. ``down`` stops the private node; ``status`` exits 1 when no
broker runs.
"""

from __future__ import annotations

import time
from typing import Annotated

import typer

from broker.endpoint import (
    BrokerEndpoint,
    BrokerUnavailable,
    compose_up,
    docker_endpoint,
    docker_engine_answers,
    endpoint_ready,
    external_endpoint,
    resolve_broker,
)
from broker.local_node import LocalNode, LocalNodeError
from fleetbus.context import console, fail, settings

app = typer.Typer(
    help="The broker: FLEETBUS_AMQP_URL, Docker, or a private RabbitMQ node.", no_args_is_help=True
)

KIND_LABEL = {
    "external": "FLEETBUS_AMQP_URL",
    "docker": "docker compose service `rabbitmq`",
    "private": "private RabbitMQ node",
}


def _show(endpoint: BrokerEndpoint, extra: dict[str, str] | None = None) -> None:
    """One ``key  value`` line each, never wrapped, so that the URLs can be copied."""
    rows = {"broker": KIND_LABEL[endpoint.kind], **(extra or {})}
    rows["AMQP URL"] = endpoint.amqp_url
    rows["management URL"] = endpoint.management_url
    for key, value in rows.items():
        console.print(f"[bold]{key:<15}[/] {value}", soft_wrap=True, highlight=False)


def _node_extra(node: LocalNode) -> dict[str, str]:
    info = node.status()
    return {"pid": str(info.pid), "node": info.node_name, "folder": str(info.base_dir)}


@app.command()
def up(
    timeout: Annotated[float, typer.Option(help="seconds to wait for the broker")] = 90.0,
) -> None:
    """Make sure a broker runs (start one if needed) and print its URLs."""
    current = settings()
    started = time.monotonic()
    try:
        endpoint = external_endpoint(current)
        if endpoint is None:
            if current.amqp_url:
                console.print("[yellow]FLEETBUS_AMQP_URL does not answer; using another broker[/]")
            if docker_engine_answers():
                with console.status("starting RabbitMQ with docker compose…"):
                    endpoint = compose_up(current)
            else:
                node = LocalNode(current.broker_dir)
                already = node.pid() is not None
                with console.status("starting the private RabbitMQ node…"):
                    info = node.up(timeout=timeout)
                assert info.amqp_url is not None and info.management_url is not None
                endpoint = BrokerEndpoint(info.amqp_url, info.management_url, "private")
                console.print(
                    "[green]already running[/]"
                    if already
                    else f"[green]started[/] in {time.monotonic() - started:.1f} s"
                )
                _show(endpoint, _node_extra(node))
                return
    except (BrokerUnavailable, LocalNodeError) as error:
        fail(str(error))
    _show(endpoint)


@app.command()
def down(
    timeout: Annotated[float, typer.Option(help="seconds to wait for the node to stop")] = 60.0,
) -> None:
    """Stop the private RabbitMQ node and its epmd (a broker fleetbus did not start is left alone)."""
    current = settings()
    node = LocalNode(current.broker_dir)
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
def status() -> None:
    """Print the broker's URLs; exit 1 when none runs."""
    current = settings()
    try:
        endpoint = resolve_broker(current, start=False)
    except (BrokerUnavailable, LocalNodeError) as error:
        console.print(f"[red]not running[/]: {error}")
        raise typer.Exit(1) from None
    extra = _node_extra(LocalNode(current.broker_dir)) if endpoint.kind == "private" else None
    console.print("[green]running[/]")
    _show(endpoint, extra)
