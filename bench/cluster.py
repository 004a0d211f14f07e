"""The ingest on a three-node cluster against one node, and how soon the cluster serves again after
the express lane's leader is killed; both brokers started by the bench, measured in one run.

    .venv/bin/python -m bench.cluster [--events 20000] [--robots 4] [--shards 2] [--workers 1] [--kills 5]

In a temporary folder the bench starts one private node and a private three-node cluster
(:mod:`fleetbus_dev.cluster`, 512 MiB each), then on each:

  raw consume   pika, one BlockingConnection, manual acks, prefetch 256, from a quorum queue
                declared like an ingest shard, filled first with --events messages of an event's size
  drain         --robots robots queue --events status events; --workers ``fleetbus worker``
                processes then store them (bench.scaling's drain: from the moment each worker holds
                its share until 85 % are stored); every event checked stored once, in order

Both drains are given as ratios to the cluster's raw consume (and to their own broker's). Then, on
the cluster, --kills times: a worker process runs and a robot is connected; the node leading the
express lane's queue is killed with SIGKILL; the robot publishes a hazard at once: seconds until
it is confirmed (publishing resumes) and until the store holds it (the worker consumes again);
the node is started again before the next kill. Medians are printed and written to
``bench/results/cluster-<time>.json``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

from rich.console import Console

from bench.ingest import event_size
from bench.raw import raw_publish
from bench.results import save
from bench.scaling import Options, drain
from fleetbus.broker.accounts import Role, fresh_vhost, provision_account
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.topology import INGEST_QUEUE_ARGUMENTS, QueueSpec, Topology, declare_with_url
from fleetbus.broker.urls import without_password
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import EXPRESS_QUEUE
from fleetbus.settings import Settings, load_settings
from fleetbus.workers.setup import set_up_service
from fleetbus.workers.store import run_with_repositories
from fleetbus.workers.store.base import EventQuery
from fleetbus_dev.cluster import LocalCluster
from fleetbus_dev.local_node import LocalNode

RAW_QUEUE = "bench.cluster.raw"
KILL_VHOST = "fleetbus-bench-cluster"
PREFETCH = 256

console = Console()


def pika_consume(url: str, count: int) -> float:
    """Consume ``count`` messages from the raw queue with pika, acking each; messages a second."""
    connection = blocking_connection(url)
    try:
        channel = connection.channel()
        channel.basic_qos(prefetch_count=PREFETCH)
        started = time.perf_counter()
        seen = 0
        for method, _, _ in channel.consume(RAW_QUEUE, inactivity_timeout=60):
            if method is None:
                raise TimeoutError(f"the raw queue ran dry after {seen} of {count} messages")
            channel.basic_ack(method.delivery_tag)
            seen += 1
            if seen == count:
                break
        rate = count / (time.perf_counter() - started)
        channel.cancel()
        return rate
    finally:
        if connection.is_open:
            connection.close()


def raw_consume_rate(endpoint: BrokerEndpoint, api: ManagementAPI, events: int) -> float:
    admin_url = fresh_vhost(api, endpoint.amqp_url, "fleetbus-bench-raw")
    try:
        queue = QueueSpec(RAW_QUEUE, dict(INGEST_QUEUE_ARGUMENTS))
        asyncio.run(declare_with_url(admin_url, [Topology(queues=(queue,))]))
        raw_publish(admin_url, events, event_size(), RAW_QUEUE)
        return pika_consume(admin_url, events)
    finally:
        api.delete_vhost("fleetbus-bench-raw")


@contextmanager
def brokers(folder: Path) -> Iterator[tuple[BrokerEndpoint, BrokerEndpoint, LocalCluster]]:
    """One private node and a three-node cluster, both in ``folder``; stopped at the end."""
    node, cluster = LocalNode(folder / "single" / "broker"), LocalCluster(folder / "cluster")
    try:
        info = node.up()
        status = cluster.up(timeout=300)
        assert info.amqp_url and info.management_url and status.amqp_url and status.management_url
        yield (
            BrokerEndpoint(info.amqp_url, info.management_url, "private"),
            BrokerEndpoint(status.amqp_url, status.management_url, "private"),
            cluster,
        )
    finally:
        node.kill()
        node.down()
        for index in range(cluster.size):
            cluster.kill(index)
        cluster.down()


def leader_of(cluster: LocalCluster, vhost: str) -> int:
    names = [node.node_name for node in cluster.nodes]
    for index, node in enumerate(cluster.nodes):
        if node.pid() is None:
            continue
        url = cluster.management_url(index)
        assert url is not None
        with ManagementAPI.from_urls(url, cluster.amqp_url() or "") as api:
            return names.index(api.get_queue(vhost, EXPRESS_QUEUE)["leader"])
    raise RuntimeError("no node of the cluster runs")


def stored(settings: Settings, robot: str, seq: int) -> bool:
    records = run_with_repositories(
        settings, lambda store: store.events.find_events(EventQuery(robot_id=robot))
    )
    return any(record.seq == seq for record in records)


def kill_resumes(endpoint: BrokerEndpoint, cluster: LocalCluster, kills: int, folder: Path) -> dict[str, Any]:
    """``kills`` times: kill the express leader, time a robot's hazard confirmed and stored."""
    from tests.factories import hazard

    confirmed: list[float] = []
    consumed: list[float] = []
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        admin_url = fresh_vhost(api, endpoint.amqp_url, KILL_VHOST)
    settings = load_settings().updated(
        data_dir=folder / "kills", amqp_url=admin_url, management_url=endpoint.management_url, cluster=True
    )
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        account = asyncio.run(
            provision_account(admin_url, api, "bench-robot1", Role.ROBOT, rotate=True, cluster=True)
        )
    service = asyncio.run(set_up_service(settings, replace(endpoint, amqp_url=admin_url)))
    env = {
        **{key: value for key, value in os.environ.items() if not key.startswith("FLEETBUS_")},
        "FLEETBUS_SERVICE_URL": without_password(service.service_url),
        "FLEETBUS_DATA_DIR": str(settings.data_dir),
        "FLEETBUS_CLUSTER": "true",
    }
    log = open(settings.data_dir / "worker.log", "ab")
    worker = subprocess.Popen(
        [sys.executable, "-m", "fleetbus", "worker", "--no-recorder"],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        with RobotClient(account.amqp_url, state_dir=settings.robots_dir) as robot:
            event = robot.publish("hazard", hazard(0))
            _wait(lambda: stored(settings, robot.robot_id, event.seq), 120, "the first hazard stored")
            for n in range(kills):
                leader = leader_of(cluster, KILL_VHOST)
                killed_at = time.monotonic()
                cluster.kill(leader)
                event = robot.publish("hazard", hazard(n + 1), wait=False)
                if not robot.flush(timeout=120):
                    raise RuntimeError(f"a hazard was not confirmed 120 s after the kill: {robot.last_error}")
                confirmed.append(time.monotonic() - killed_at)
                _wait(
                    lambda event=event: stored(settings, robot.robot_id, event.seq), 120, "the hazard stored"
                )
                consumed.append(time.monotonic() - killed_at)
                console.print(
                    f"kill {n + 1}: confirmed after {confirmed[-1]:.1f} s, stored after {consumed[-1]:.1f} s"
                )
                cluster.start_node(leader)
                cluster.wait_members(time.monotonic() + 180)
    finally:
        worker.terminate()
        worker.wait(60)
    return {
        "kill_confirmed_s": confirmed,
        "kill_stored_s": consumed,
        "kill_confirmed_median_s": statistics.median(confirmed),
        "kill_stored_median_s": statistics.median(consumed),
    }


def _wait(condition: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"no {what} within {timeout:.0f} s")
        time.sleep(0.05)


def run(events: int, robots: int, shards: int, workers: int, kills: int) -> dict[str, Any]:
    result: dict[str, Any] = {"events": events, "robots": robots, "shards": shards, "workers": workers}
    with tempfile.TemporaryDirectory() as tmp, brokers(Path(tmp)) as (single, clustered, cluster):
        for name, endpoint, on_cluster in (("single", single, False), ("cluster", clustered, True)):
            options = Options(events, robots, shards, (workers,), None, on_cluster)
            with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
                console.print(f"{name}: raw pika consume")
                result[f"{name}_raw_consume"] = raw_consume_rate(endpoint, api, events)
                console.print(f"{name}: raw pika consume {result[f'{name}_raw_consume']:,.0f} msg/s")
                console.print(f"{name}: drain with {workers} worker(s)")
                result[f"{name}_drain"] = drain(endpoint, api, options, workers)[f"drain_{workers}w"]
                console.print(f"{name}: drain {result[f'{name}_drain']:,.0f} msg/s")
        result.update(kill_resumes(clustered, cluster, kills, Path(tmp)))
    raw = result["cluster_raw_consume"]
    result["cluster_drain_vs_cluster_raw"] = result["cluster_drain"] / raw
    result["single_drain_vs_cluster_raw"] = result["single_drain"] / raw
    result["single_drain_vs_single_raw"] = result["single_drain"] / result["single_raw_consume"]
    result["cluster_vs_single_drain"] = result["cluster_drain"] / result["single_drain"]
    result["load_average"] = os.getloadavg()[1]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--events", type=int, default=20_000)
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--shards", type=int, default=2)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--kills", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    result = run(args.events, args.robots, args.shards, args.workers, args.kills)
    for key, value in result.items():
        if isinstance(value, float):
            console.print(f"{key:<32} {value:,.2f}")
    console.print(f"wrote {save(args.out, 'cluster', result)}")


if __name__ == "__main__":
    main()
