"""``fleetbus broker up | down | status``: the broker the other commands use.

``up`` waits for the broker of ``FLEETBUS_AMQP_URL`` when it is set (and fails when it does not
answer); otherwise it starts the ``rabbitmq`` service of ``compose.yaml`` (when a Docker engine
answers) or the project's private node under ``.fleetbus/broker/``; ``up --nodes 3`` starts a
private three-node cluster under ``.fleetbus/cluster/`` instead (:mod:`fleetbus_dev.cluster`).
Then it runs ``fleetbus setup``. ``down`` stops the private node and every node of the cluster;
``status`` exits 1 when no broker runs. URLs are shown with their passwords masked unless
``--show-password`` is given.
"""

from __future__ import annotations

import time
from typing import Annotated

import typer

from fleetbus.broker.endpoint import BrokerEndpoint, BrokerUnavailable, endpoint_ready, external_endpoint
from fleetbus.cli.commands.setup import ShowPassword, set_up, show_url
from fleetbus.cli.context import console, fail, settings
from fleetbus_dev.cluster import LocalCluster
from fleetbus_dev.fallback import (
    cluster_endpoint,
    compose_up,
    docker_endpoint,
    docker_engine_answers,
    local_cluster,
    local_node,
    node_endpoint,
    resolve_broker,
)
from fleetbus_dev.local_node import LocalNode, LocalNodeError

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
    extra = {
        "pid": str(info.pid),
        "node": info.node_name,
        "folder": str(info.base_dir),
        "runs": node.installation().describe(),
    }
    if info.management_tls_url:
        extra["management TLS"] = info.management_tls_url
    extra["CA"] = str(node.tls.ca)
    return extra


def _cluster_extra(cluster: LocalCluster) -> dict[str, str]:
    info = cluster.status()
    extra = {"nodes": f"{info.running} of {cluster.size} running", "folder": str(cluster.base_dir)}
    for number, node in enumerate(info.nodes, 1):
        extra[f"node {number}"] = f"{node.node_name} pid {node.pid} AMQP port {node.ports.get('amqp')}"
    return extra


def _cluster_up(nodes: int, timeout: float, show_password: bool) -> None:
    current = settings()
    if current.amqp_url:
        fail("FLEETBUS_AMQP_URL is set: that broker is the one used, no local cluster is started")
    cluster = local_cluster(current, nodes)
    if cluster.exists() and cluster.size != nodes:
        fail(f"the cluster in {cluster.base_dir} has {cluster.size} nodes: `broker down`, delete it, then up")
    started = time.monotonic()
    try:
        with console.status(f"starting a {nodes}-node RabbitMQ cluster…"):
            info = cluster.up(timeout=timeout)
    except LocalNodeError as error:
        fail(str(error))
    console.print(f"[green]running[/] after {time.monotonic() - started:.1f} s")
    endpoint = cluster_endpoint(info)
    _show(endpoint, _cluster_extra(cluster), show_password)
    console.print(
        "every process of this deployment needs FLEETBUS_CLUSTER=true (quorum queues): export it",
        highlight=False,
    )
    set_up(endpoint, show_password, current.updated(cluster=True))


@app.command()
def up(
    timeout: Annotated[float, typer.Option(help="seconds to wait for the broker to start")] = 90.0,
    nodes: Annotated[
        int,
        typer.Option(
            min=1, help="more than 1: a private cluster of this many nodes (`broker down` stops it)"
        ),
    ] = 1,
    show_password: ShowPassword = False,
) -> None:
    """Make sure a broker runs (start one if none is configured), set up the service accounts
    (`fleetbus setup`), and print the broker's URLs."""
    if nodes > 1:
        _cluster_up(nodes, max(timeout, 180.0), show_password)
        return
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
    """Stop the private RabbitMQ node and its epmd, and every node of the private cluster (a broker
    fleetbus did not start is left alone)."""
    current = settings()
    cluster = local_cluster(current)
    if cluster.exists() and cluster.status().running:
        started = time.monotonic()
        try:
            with console.status("stopping the private RabbitMQ cluster…"):
                cluster.down(timeout=max(timeout, 90.0))
        except LocalNodeError as error:
            fail(str(error))
        console.print(
            f"[green]stopped[/] the {cluster.size} nodes of the cluster in {time.monotonic() - started:.1f} s"
        )
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
    cluster = local_cluster(current)
    if endpoint.kind == "private" and cluster.exists() and cluster.status().running:
        extra: dict[str, str] | None = _cluster_extra(cluster)
    else:
        extra = _node_extra(local_node(current)) if endpoint.kind == "private" else None
    console.print("[green]running[/]")
    _show(endpoint, extra, show_password)
    if not show_password:
        private = cluster.nodes[0] if extra is not None and "nodes" in extra else local_node(current)
        where = {
            "private": f"{private.admin_file}",
            "docker": f"FLEETBUS_BROKER_PASSWORD, else the file {current.broker_dir / 'docker-password'}",
            "external": "FLEETBUS_AMQP_URL",
        }[endpoint.kind]
        console.print(f"the administrator's password: --show-password, or {where}", highlight=False)
