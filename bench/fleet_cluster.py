"""What each robot costs a three-node cluster: its replicated queues, exchanges, bindings and connection.

    .venv/bin/python -m bench.fleet_cluster [--steps 250,500,1000] [--connections 300]

In a temporary folder the bench starts a private three-node cluster (:mod:`fleetbus_dev.cluster`)
and a virtual host on it, then makes robots' accounts in steps, as ``fleetbus users add-many``
makes them with ``FLEETBUS_CLUSTER=true`` (each robot's inbox and commands queue a quorum queue
with a member on every node). After each step it reads every node's resident memory from /proc
and what the virtual host holds. Then it opens ``--connections`` idle AMQP connections as the robots
(aio-pika, spread over the nodes as a robot's list of addresses spreads them) and reads the memory
again. The figures, per step and per robot, go to ``bench/results/fleet-cluster-<UTC time>.json``;
the scaling guide's estimate for a larger fleet is drawn from them.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import aio_pika
from rich.console import Console

from bench.proc import rss_megabytes
from bench.report import load_average
from bench.results import save
from fleetbus.broker.accounts import fresh_vhost
from fleetbus.broker.fleet import NewRobot, provision_robots
from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.routing import RobotKind
from fleetbus_dev.cluster import LocalCluster

console = Console()
VHOST = "fleet-cluster"
SETTLE_S = 5.0  # memory read this long after a step, once the queues' members have started


def node_rss(cluster: LocalCluster) -> list[float]:
    pids = [node.pid() for node in cluster.nodes]
    return [rss_megabytes(pid) if pid else float("nan") for pid in pids]


def held(api: ManagementAPI) -> dict[str, int]:
    queues = api.list_queues(VHOST)
    return {
        "queues": len(queues),
        "quorum queues": sum(1 for q in queues if q.get("type") == "quorum"),
        "exchanges": len(api.list_exchanges(VHOST)),
        "bindings": len(api.list_bindings(VHOST)),
    }


def node_urls(cluster: LocalCluster, name: str, password: str) -> list[str]:
    """One URL per node for ``name`` (a robot's list of addresses, spread: one node each)."""
    urls = []
    for node in cluster.nodes:
        info = node.status()
        assert info.amqp_url
        base = info.amqp_url.split("@", 1)[1].split("/", 1)[0]
        urls.append(f"amqp://{name}:{password}@{base}/{VHOST}")
    return urls


async def connect_all(urls: list[str]) -> list[aio_pika.abc.AbstractConnection]:
    connections = []
    for url in urls:  # one at a time: a storm of handshakes is not what is measured
        connections.append(await aio_pika.connect(url, timeout=60))
    return connections


def run(steps: list[int], connections: int) -> dict[str, Any]:
    result: dict[str, Any] = {"command": " ".join(sys.argv), "steps": []}
    with tempfile.TemporaryDirectory() as tmp:
        cluster = LocalCluster(Path(tmp) / "cluster")
        try:
            status = cluster.up(timeout=300)
            assert status.amqp_url and status.management_url
            with ManagementAPI.from_urls(status.management_url, status.amqp_url) as api:
                admin_url = fresh_vhost(api, status.amqp_url, VHOST)
                time.sleep(SETTLE_S)
                baseline = node_rss(cluster)
                result["baseline RSS MB"] = baseline
                console.print(f"baseline: {', '.join(f'{m:.0f} MB' for m in baseline)}")
                made = 0
                accounts: list[Any] = []
                for total in steps:
                    robots = [NewRobot(f"robot{i:05d}", RobotKind.WARDEN) for i in range(made, total)]
                    started = time.monotonic()
                    accounts += asyncio.run(provision_robots(admin_url, api, robots, shards=2, cluster=True))
                    took = time.monotonic() - started
                    made = total
                    time.sleep(SETTLE_S)
                    rss = node_rss(cluster)
                    step = {
                        "robots": total,
                        "provisioning s": took,
                        "RSS MB": rss,
                        "RSS growth per robot KB (each node)": [
                            1024 * (now - before) / total for now, before in zip(rss, baseline, strict=True)
                        ],
                        **held(api),
                    }
                    result["steps"].append(step)
                    console.print(step, highlight=False)
                before = node_rss(cluster)
                urls = []
                for i, account in enumerate(accounts[:connections]):
                    password = account.amqp_url.split("@", 1)[0].rsplit(":", 1)[1]
                    urls.append(node_urls(cluster, account.name, password)[i % len(cluster.nodes)])
                opened = asyncio.run(_hold(urls, cluster))
                result["connections"] = {
                    "count": connections,
                    "RSS MB before": before,
                    "RSS MB with them": opened,
                    "per connection KB (each node)": [
                        1024 * (now - then) / (connections / len(cluster.nodes))
                        for now, then in zip(opened, before, strict=True)
                    ],
                }
                console.print(result["connections"], highlight=False)
        finally:
            for index in range(cluster.size):
                cluster.kill(index)
            cluster.down()
    result["load average"] = load_average()
    return result


async def _hold(urls: list[str], cluster: LocalCluster) -> list[float]:
    connections = await connect_all(urls)
    try:
        await asyncio.sleep(SETTLE_S)
        return node_rss(cluster)
    finally:
        for connection in connections:
            await connection.close()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", default="250,500,1000", help="robots in all after each step")
    parser.add_argument("--connections", type=int, default=300, help="idle robot connections held")
    args = parser.parse_args()
    steps = [int(n) for n in args.steps.split(",")]
    result = run(steps, min(args.connections, steps[-1]))
    path = save(Path("bench/results"), "fleet-cluster", result)
    console.print(f"wrote {path}", highlight=False)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
