"""How robots would spread over ingest shards with RabbitMQ's consistent-hash exchange, measured.

    .venv/bin/python -m bench.shard_balance [--teams 500] [--shards 4] [--sizes 4 8 16]

Why fleetbus binds each robot by name to the least loaded shard instead: this routes real
messages through an ``x-consistent-hash`` exchange (plugin ``rabbitmq_consistent_hash_exchange``;
enabled here for the run when the broker is the private node) bound to --shards queues, and reads
back which queue each got:

  spread          --teams teams of N robots with random names, each robot one ``<robot>.status``
                  message hashed on its routing key: the share of teams whose robots use every
                  shard, and the largest shard's share of a team's robots (mean over the teams)
  split robots    each robot's five event types (``<robot>.hazard``, ``.localisation``, ...): the
                  share of robots whose types land in more than one shard (hashing the routing key
                  would store a map before its chunks, a hazard before the localisation gating it)

fleetbus's placement gives every team min(N, shards) shards with loads differing by at most one
(``tests/test_shards.py``), and one shard per robot for every type.
"""

from __future__ import annotations

import argparse
import statistics
import time
import uuid
from collections import Counter
from pathlib import Path
from typing import Any

import pika
import pika.exceptions
from rich.console import Console
from rich.table import Table

from bench.results import save
from fleetbus.broker.accounts import fresh_vhost
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.publishers.confirms import Outgoing, PipelinedConfirms
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import EventType
from fleetbus.settings import load_settings
from fleetbus_dev.fallback import resolve_broker
from fleetbus_dev.local_node import LocalNode

VHOST = "fleetbus-bench-balance"
EXCHANGE = "bench.hash"
PLUGIN = "rabbitmq_consistent_hash_exchange"
TYPES = [t.value for t in EventType if t is not EventType.BEACON]
console = Console()


def queue_name(shard: int) -> str:
    return f"bench.shard.{shard}"


def ensure_plugin(endpoint: BrokerEndpoint, url: str) -> None:
    """Declare the exchange; on the private node, enable the plugin first if the type is unknown."""
    for attempt in (1, 2):
        connection = blocking_connection(url)
        try:
            connection.channel().exchange_declare(EXCHANGE, "x-consistent-hash", durable=False)
            return
        except (pika.exceptions.ChannelClosedByBroker, pika.exceptions.ConnectionClosedByBroker) as error:
            if attempt == 2 or endpoint.kind != "private":
                raise SystemExit(
                    f"the broker has no consistent-hash exchange ({error}); enable {PLUGIN}"
                ) from error
        finally:
            if connection.is_open:
                connection.close()
        LocalNode(load_settings().broker_dir).rabbitmq_plugins("enable", PLUGIN)
        time.sleep(1)


def route(url: str, shards: int, keys: list[str]) -> dict[str, int]:
    """Publish one message per routing key through the exchange; the shard each reached."""
    connection = blocking_connection(url)
    try:
        channel = connection.channel()
        for shard in range(shards):
            channel.queue_declare(queue_name(shard), durable=False)
            channel.queue_bind(queue_name(shard), EXCHANGE, routing_key="1")  # weight 1 each
        confirms = PipelinedConfirms(connection, channel, timeout=60)
        for start in range(0, len(keys), 1000):
            window = [
                Outgoing(EXCHANGE, key, b"", pika.BasicProperties(message_id=key))
                for key in keys[start : start + 1000]
            ]
            confirms.publish(window, 60)
        reached: dict[str, int] = {}
        for shard in range(shards):
            while True:
                method, properties, _ = channel.basic_get(queue_name(shard), auto_ack=True)
                if method is None:
                    break
                reached[properties.message_id] = shard
            channel.queue_delete(queue_name(shard))
    finally:
        connection.close()
    return reached


def measure(url: str, teams: int, shards: int, sizes: list[int]) -> dict[str, Any]:
    names = [f"robot-{uuid.uuid4().hex[:10]}" for _ in range(teams * max(sizes))]
    split_sample = names[: min(len(names), 2000)]
    keys = [f"{name}.status" for name in names] + [f"{name}.{t}" for name in split_sample for t in TYPES]
    reached = route(url, shards, keys)
    result: dict[str, Any] = {"teams": teams, "shards": shards, "spread": {}}
    for size in sizes:
        every, largest = 0, []
        for team in range(teams):
            members = names[team * size : (team + 1) * size]
            load = Counter(reached[f"{name}.status"] for name in members)
            every += len(load) == min(size, shards)
            largest.append(max(load.values()) / size)
        result["spread"][size] = {
            "teams_using_every_shard": every / teams,
            "largest_shard_share": statistics.mean(largest),
            "fleetbus_largest_shard_share": -(-size // shards) / size,
        }
    split = sum(len({reached[f"{name}.{t}"] for t in TYPES}) > 1 for name in split_sample)
    result["robots_split_across_shards"] = split / len(split_sample)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--teams", type=int, default=500)
    parser.add_argument("--shards", type=int, default=4)
    parser.add_argument("--sizes", type=int, nargs="+", default=[4, 8, 16])
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    endpoint = resolve_broker(load_settings(), start=True)
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        url = fresh_vhost(api, endpoint.amqp_url, VHOST)
        try:
            ensure_plugin(endpoint, url)
            result = measure(url, args.teams, args.shards, args.sizes)
        finally:
            api.delete_vhost(VHOST)
    table = Table(
        title=f"{args.teams} random teams per size, {args.shards} shards, x-consistent-hash on the key"
    )
    for column in ("robots", "teams using every shard", "largest shard's share", "fleetbus: largest share"):
        table.add_column(column, justify="right")
    for size, found in result["spread"].items():
        table.add_row(
            str(size),
            f"{found['teams_using_every_shard']:.1%}",
            f"{found['largest_shard_share']:.0%}",
            f"{found['fleetbus_largest_shard_share']:.0%}",
        )
    console.print(table)
    console.print(
        f"robots whose {len(TYPES)} event types land in more than one shard: "
        f"{result['robots_split_across_shards']:.1%} (fleetbus: 0)"
    )
    console.print(f"wrote {save(args.out, 'shard-balance', result)}")


if __name__ == "__main__":
    main()
