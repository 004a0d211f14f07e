"""Central catching up after an outage of its link to a site, against the raw shovel rate.

    .venv/bin/python -m bench.sites [--robots 100] [--seconds 600] [--hz 1] [--hazard-every 60]

Two private RabbitMQ nodes on loopback, a site and central, each a fleetbus (central's worker on
SQLite here; MongoDB in production). While the link is down the site's robots publish
``robots x seconds x hz`` status events (60,000 by default: 100 robots at 1 Hz for 10 minutes),
and each robot a hazard every ``--hazard-every`` of its events (1,000 by default); they wait in
the site's uplink, each in its class. Then, in the same run:

- **raw**: the same number of messages of the same size, shovelled from a plain queue on the site
  to a plain queue at central (no exchange, no worker): the most the link between the two nodes
  carries;
- **catch-up**: the site's uplink shovels started with central's worker running: the time until
  central's store holds every event, and whether every hazard was at central (by its
  ``received_at`` there) before the first status event queued at the site after it.

It prints both rates and their ratio (catch-up / raw), and the hazards' order. Not a test:
nothing is asserted. The backlog is loaded by an account tagged ``impersonator`` publishing in
the robots' names (one connection rather than a hundred), with send times spread over the
outage; the site's own worker is not running (it is not on the path being measured).
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from dataclasses import replace
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pika
from rich.console import Console
from rich.table import Table

from fleetbus.broker.accounts import Role, fresh_vhost, provision_account, url_for, vhost_of
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.sites import add_site_account, forward_robot, local_uri, start_site_links
from fleetbus.broker.topology import core_topology, declare_with_url
from fleetbus.broker.uplink import CLASSES, UplinkBounds
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.routing import RobotKind, event_routing_key, events_exchange
from fleetbus.settings import Settings, load_settings
from fleetbus.workers.setup import set_up_service
from fleetbus.workers.sites import assign_robots
from fleetbus.workers.store import run_with_repositories
from fleetbus.workers.store.base import EventQuery
from fleetbus_dev.local_node import LocalNode
from fleetbus_dev.worker_thread import WorkerThread

#: Bounds no backlog of the bench reaches.
BENCH_BOUNDS = UplinkBounds(
    hazards=1_000_000, events=10_000_000, telemetry=10_000_000, max_bytes=16 * 1024**3
)
STATUS = {"battery_percent": 80.0, "pose": {"x": 1.0, "y": 2.0}, "processing_rate_hz": 10.0}
HAZARD = {"pose": {"x": 3.0, "y": 4.0}, "description": "smoke", "detected_at": "2026-11-27T00:00:00+00:00"}
RAW_QUEUE = "bench.raw"


def endpoint_of(node: LocalNode) -> BrokerEndpoint:
    info = node.up()
    assert info.amqp_url and info.management_url
    return BrokerEndpoint(info.amqp_url, info.management_url, "private")


def queue_count(url: str, queue: str) -> int:
    connection = blocking_connection(url)
    try:
        return connection.channel().queue_declare(queue, passive=True).method.message_count
    finally:
        connection.close()


def wait_until(condition, what: str, timeout: float = 3600.0, interval: float = 0.2) -> float:  # type: ignore[no-untyped-def]
    """Seconds until ``condition()`` held."""
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout:
            raise TimeoutError(what)
        time.sleep(interval)
    return time.monotonic() - start


def load_backlog(
    url: str, robots: list[str], seconds: int, hz: float, hazard_every: int
) -> tuple[list[tuple[str, str, int, str]], int]:
    """Publish the outage's events in the robots' names (confirmed); each robot's every
    ``hazard_every``-th event a hazard. Returns (robot, epoch, seq, type) in the order queued, and
    the bytes of one status event."""
    epochs = {robot: new_epoch() for robot in robots}
    start = datetime.now(timezone.utc) - timedelta(seconds=seconds)
    ticks = int(seconds * hz)
    connection = blocking_connection(url)
    size = 0
    queued: list[tuple[str, str, int, str]] = []
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        for tick in range(ticks):
            sent_at = start + timedelta(seconds=tick / hz)
            for number, robot in enumerate(robots):
                hazard = hazard_every and (tick + number) % hazard_every == hazard_every - 1
                kind = "hazard" if hazard else "status"
                body_of = HAZARD if kind == "hazard" else STATUS
                event = build_event(kind, robot, epochs[robot], tick, body_of, sent_at=sent_at)
                body = encode_event(event)
                size = len(body) if kind == "status" else size
                channel.basic_publish(
                    events_exchange(robot),
                    event_routing_key(robot, kind),
                    body,
                    pika.BasicProperties(
                        user_id=robot,
                        delivery_mode=2,
                        message_id=str(event.message_id),
                        content_type="application/json",
                    ),
                )
                queued.append((robot, epochs[robot], tick, kind))
    finally:
        connection.close()
    return queued, size


def hazards_first(
    queued: list[tuple[str, str, int, str]], received: dict[tuple[str, str, int], datetime]
) -> int:
    """Hazards that reached central after the first status event queued at the site after them."""
    late = 0
    first_status_after: datetime | None = None
    # from the end: the earliest central arrival of the statuses queued after each position
    for robot, epoch, seq, kind in reversed(queued):
        at = received[(robot, epoch, seq)]
        if kind == "status":
            first_status_after = at if first_status_after is None else min(first_status_after, at)
        elif first_status_after is not None and at > first_status_after:
            late += 1
    return late


def raw_rate(
    site: BrokerEndpoint, central: BrokerEndpoint, api: ManagementAPI, count: int, size: int
) -> float:
    """Messages a second one shovel moves from a queue on the site to a queue at central."""
    for url in (site.amqp_url, central.amqp_url):
        connection = blocking_connection(url)
        connection.channel().queue_declare(RAW_QUEUE, durable=True, arguments={"x-queue-type": "classic"})
        connection.close()
    connection = blocking_connection(site.amqp_url)
    channel = connection.channel()
    channel.confirm_delivery()
    body = b"x" * size
    for _ in range(count):
        channel.basic_publish("", RAW_QUEUE, body, pika.BasicProperties(delivery_mode=2))
    connection.close()
    vhost = vhost_of(site.amqp_url)
    definition = {
        "src-protocol": "amqp091",
        "src-uri": local_uri(vhost),
        "src-queue": RAW_QUEUE,
        "src-prefetch-count": 1000,
        "dest-protocol": "amqp091",
        "dest-uri": central.amqp_url,
        "dest-queue": RAW_QUEUE,
        "ack-mode": "on-confirm",
        "reconnect-delay": 1,
    }
    api.put_shovel(vhost, "bench-raw", definition)
    took = wait_until(lambda: queue_count(central.amqp_url, RAW_QUEUE) >= count, "the raw shovel")
    api.delete_shovel(vhost, "bench-raw")
    return count / took


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--robots", type=int, default=100)
    parser.add_argument("--seconds", type=int, default=600, help="the outage's length")
    parser.add_argument("--hz", type=float, default=1.0, help="each robot's events a second")
    parser.add_argument(
        "--hazard-every", type=int, default=60, help="a hazard every N events of a robot (0: none)"
    )
    args = parser.parse_args()
    console = Console()
    with tempfile.TemporaryDirectory(prefix="fleetbus-bench-sites-") as folder:
        base = Path(folder)
        nodes = [LocalNode(base / name) for name in ("site", "central")]
        try:
            site_root, central_root = (endpoint_of(node) for node in nodes)
            with (
                ManagementAPI.from_urls(site_root.management_url, site_root.amqp_url) as site_api,
                ManagementAPI.from_urls(central_root.management_url, central_root.amqp_url) as central_api,
            ):
                site = replace(site_root, amqp_url=fresh_vhost(site_api, site_root.amqp_url, "bench"))
                central = replace(
                    central_root, amqp_url=fresh_vhost(central_api, central_root.amqp_url, "bench")
                )
                result = run(console, args, base, site, central, site_api, central_api)
        finally:
            for node in nodes:
                node.kill()
                node.down()
    table = Table(
        title=f"central catching up: {result['events']:,} events "
        f"({args.robots} robots, {args.seconds} s at {args.hz:g} Hz)"
    )
    for column in ("measure", "seconds", "events/s"):
        table.add_column(column, justify="left" if column == "measure" else "right")
    table.add_row("raw shovel, queue to queue", f"{result['raw_s']:.1f}", f"{result['raw_rate']:,.0f}")
    table.add_row(
        "uplink drained (shovel into central's ingest)",
        f"{result['drained_s']:.1f}",
        f"{result['events'] / result['drained_s']:,.0f}",
    )
    table.add_row(
        "central caught up (every event stored)",
        f"{result['caught_up_s']:.1f}",
        f"{result['catch_up_rate']:,.0f}",
    )
    console.print(table)
    console.print(
        f"catch-up rate / raw shovel rate: {result['catch_up_rate'] / result['raw_rate']:.2f} "
        f"(catch-up time / raw: {result['caught_up_s'] / result['raw_s']:.2f}); "
        f"hazards at central after a status queued after them: "
        f"{result['hazards after a later status']} of {result['hazards']}",
        highlight=False,
    )


def run(
    console: Console,
    args: argparse.Namespace,
    base: Path,
    site: BrokerEndpoint,
    central: BrokerEndpoint,
    site_api: ManagementAPI,
    central_api: ManagementAPI,
) -> dict[str, float]:
    robots = [f"robot{i:03d}" for i in range(args.robots)]
    central_settings = load_settings().updated(
        data_dir=base / "central-data",
        amqp_url=central.amqp_url,
        management_url=central.management_url,
        mongodb_url=None,
    )
    accounts = asyncio.run(set_up_service(central_settings, central))
    console.print(f"provisioning {len(robots)} robots at central and at the site ...", highlight=False)
    for robot in robots:
        asyncio.run(
            provision_account(
                central.amqp_url, central_api, robot, Role.ROBOT, RobotKind.EXPLORER, rotate=True
            )
        )
        asyncio.run(
            provision_account(site.amqp_url, site_api, robot, Role.ROBOT, RobotKind.EXPLORER, rotate=True)
        )
    run_with_repositories(central_settings, lambda repos: _register(repos, robots))
    site_account = asyncio.run(add_site_account(central.amqp_url, central_api, "bench-site", rotate=True))
    run_with_repositories(
        central_settings,
        lambda repos: assign_robots(
            repos.sites, repos.hazards, central_api, central.amqp_url, "bench-site", robots
        ),
    )
    # the loader: one connection publishing in every robot's name, as a site's shovel does
    loader_password = "bench-loader-password"
    site_api.put_user("bench-loader", loader_password, "impersonator")
    site_api.put_permissions(vhost_of(site.amqp_url), "bench-loader", "^$", ".*", "^$")
    asyncio.run(declare_with_url(site.amqp_url, [core_topology(1)]))
    # the uplink queue exists before the outage's events: declared with the links, shovels stopped at once
    asyncio.run(
        start_site_links(
            site.amqp_url,
            site_api,
            "bench-site",
            "amqp://nowhere.invalid/",
            bounds=BENCH_BOUNDS,
            rejected_max=central_settings.downlink_rejected_max,
            reconnect_delay_s=1,
        )
    )
    for robot in robots:
        forward_robot(site_api, vhost_of(site.amqp_url), robot)
    console.print("loading the outage's backlog at the site ...", highlight=False)
    queued, size = load_backlog(
        url_for(site.amqp_url, "bench-loader", loader_password),
        robots,
        args.seconds,
        args.hz,
        args.hazard_every,
    )
    count = len(queued)
    wait_until(lambda: uplink_count(site.amqp_url) >= count, "the backlog in the uplink")
    console.print(
        f"{count:,} events of {size} bytes wait in the uplink; measuring the raw shovel ...", highlight=False
    )
    raw = raw_rate(site, central, site_api, count, size)
    with WorkerThread(central_settings, accounts.service_url):
        asyncio.run(
            start_site_links(
                site.amqp_url,
                site_api,
                "bench-site",
                site_account.amqp_url,
                bounds=BENCH_BOUNDS,
                rejected_max=central_settings.downlink_rejected_max,
                reconnect_delay_s=1,
            )
        )
        drained = wait_until(lambda: uplink_count(site.amqp_url) == 0, "the uplink drained")
        caught_up = drained + wait_until(
            lambda: _stored(central_settings) >= count, "central caught up", interval=0.5
        )
    received = run_with_repositories(central_settings, _received)
    return {
        "hazards": sum(1 for *_, kind in queued if kind == "hazard"),
        "hazards after a later status": hazards_first(queued, received),
        "events": count,
        "raw_s": count / raw,
        "raw_rate": raw,
        "drained_s": drained,
        "caught_up_s": caught_up,
        "catch_up_rate": count / caught_up,
    }


async def _register(repos, robots: list[str]) -> None:  # type: ignore[no-untyped-def]
    for robot in robots:
        await repos.hazards.register_robot(robot, RobotKind.EXPLORER.value)


async def _received(repos) -> dict[tuple[str, str, int], datetime]:  # type: ignore[no-untyped-def]
    return {record.key: record.received_at for record in await repos.events.find_events(EventQuery())}


def uplink_count(url: str) -> int:
    return sum(queue_count(url, uplink.queue) for uplink in CLASSES)


def _stored(settings: Settings) -> int:
    return run_with_repositories(settings, lambda repos: repos.events.count_events())


if __name__ == "__main__":
    main()
