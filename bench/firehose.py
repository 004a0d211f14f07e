"""What recording costs the broker: RabbitMQ's firehose against one more bound queue.

    .venv/bin/python -m bench.firehose [--messages 20000] [--runs 3]

Each run, in a fresh virtual host, publishes persistent messages of 480 bytes (pika, pipelined
confirms) to a topic exchange bound to a durable queue, then consumes them (pika, manual ack,
prefetch 512), in three set-ups:

  baseline     the exchange feeds one queue
  bound copy   the exchange also feeds a second durable queue, as fleetbus.recorder is fed
  firehose     tracing on for the vhost, a queue bound to amq.rabbitmq.trace with ``#`` (every
               publish and every delivery is copied there), as a firehose recorder would read it

It prints the publish and consume rates (median and spread), each set-up's rate against the
baseline, and, when the broker is the private node, the broker's CPU time per 1,000 messages
(publish and consume together): the cost the rates hide when the client is the bottleneck.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import pika
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from bench.proc import cpu_seconds
from bench.results import medians, save, spread
from fleetbus.broker.accounts import fresh_vhost
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.publishers.confirms import Outgoing, PipelinedConfirms
from fleetbus.publishers.tls import blocking_connection
from fleetbus.settings import load_settings
from fleetbus_dev.fallback import resolve_broker
from fleetbus_dev.local_node import LocalNode

VHOST = "fleetbus-bench-firehose"
EXCHANGE, QUEUE, COPY, TRACE = "bench.events", "bench.main", "bench.copy", "bench.trace"
SIZE = 480
SETUPS = ("baseline", "bound copy", "firehose")
console = Console()


def prepare(channel: pika.adapters.blocking_connection.BlockingChannel, setup: str) -> None:
    channel.exchange_declare(EXCHANGE, "topic", durable=True)
    channel.queue_declare(QUEUE, durable=True)
    channel.queue_bind(QUEUE, EXCHANGE, "#")
    if setup == "bound copy":
        channel.queue_declare(COPY, durable=True)
        channel.queue_bind(COPY, EXCHANGE, "#")
    if setup == "firehose":
        channel.queue_declare(TRACE, durable=True)
        channel.queue_bind(TRACE, "amq.rabbitmq.trace", "#")


def publish(connection: pika.BlockingConnection, count: int) -> float:
    confirms = PipelinedConfirms(connection, connection.channel(), timeout=120)
    properties = pika.BasicProperties(delivery_mode=2, content_type="application/json")
    body = b"x" * SIZE
    started = time.perf_counter()
    for start in range(0, count, 1000):
        batch = [
            Outgoing(EXCHANGE, "robot.status", body, properties) for _ in range(min(1000, count - start))
        ]
        confirms.publish(batch, 120)
    return count / (time.perf_counter() - started)


def consume(connection: pika.BlockingConnection, count: int) -> float:
    channel = connection.channel()
    channel.basic_qos(prefetch_count=512)
    seen = 0
    started = time.perf_counter()
    for method, _properties, _body in channel.consume(QUEUE, inactivity_timeout=30):
        if method is None:
            raise TimeoutError(f"only {seen} of {count} consumed")
        seen += 1
        if seen % 256 == 0 or seen == count:
            channel.basic_ack(method.delivery_tag, multiple=True)
        if seen == count:
            break
    elapsed = time.perf_counter() - started
    channel.cancel()
    return count / elapsed


def settled_count(channel: pika.adapters.blocking_connection.BlockingChannel, queue: str) -> int:
    """The queue's message count once it stops changing for half a second (at most 10 s)."""
    last, deadline = -1, time.monotonic() + 10
    while time.monotonic() < deadline:
        count = channel.queue_declare(queue, passive=True).method.message_count
        if count == last:
            return count
        last = count
        time.sleep(0.5)
    return last


def one_run(
    endpoint: BrokerEndpoint, api: ManagementAPI, setup: str, count: int, broker_pid: int | None
) -> dict[str, float]:
    url = fresh_vhost(api, endpoint.amqp_url, VHOST)
    api.set_tracing(VHOST, setup == "firehose")
    connection = blocking_connection(url)
    try:
        prepare(connection.channel(), setup)
        cpu = cpu_seconds(broker_pid) if broker_pid else 0.0
        result = {"publish": publish(connection, count), "consume": consume(connection, count)}
        if broker_pid:
            result["broker CPU s per 1000"] = (cpu_seconds(broker_pid) - cpu) * 1000 / count
        if setup == "firehose":  # a copy of each publish and of each delivery, routed a moment later
            result["trace copies"] = settled_count(connection.channel(), TRACE)
        return result
    finally:
        connection.close()
        api.set_tracing(VHOST, False)
        api.delete_vhost(VHOST)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--messages", type=int, default=20000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    endpoint = resolve_broker(load_settings(), start=True)
    runs: dict[str, list[dict[str, float]]] = {setup: [] for setup in SETUPS}
    broker_pid = LocalNode(load_settings().broker_dir).pid() if endpoint.kind == "private" else None
    with (
        ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api,
        Progress(console=console, transient=True) as progress,
    ):
        task = progress.add_task("runs", total=args.runs * len(SETUPS))
        for _ in range(args.runs):  # set-ups interleaved, so a slow spell of the machine hits them alike
            for setup in SETUPS:
                runs[setup].append(one_run(endpoint, api, setup, args.messages, broker_pid))
                progress.advance(task)
    table = Table(title=f"{args.messages} persistent messages of {SIZE} bytes, {args.runs} runs: msg/s")
    columns = ["set-up", "publish", "spread", "vs baseline", "consume", "spread", "vs baseline"]
    if broker_pid:
        columns.append("broker CPU s / 1000 msg")
    for column in columns:
        table.add_column(column, justify="left" if column == "set-up" else "right")
    middle = {setup: medians(found) for setup, found in runs.items()}
    for setup, found in runs.items():
        cells = [setup]
        for key in ("publish", "consume"):
            cells += [
                f"{middle[setup][key]:,.0f}",
                spread(found, key),
                f"{middle[setup][key] / middle['baseline'][key]:.2f}",
            ]
        if broker_pid:
            cells.append(f"{middle[setup]['broker CPU s per 1000']:.3f}")
        table.add_row(*cells)
    console.print(table)
    copies = [run["trace copies"] for run in runs["firehose"]]
    console.print(f"firehose: {statistics.median(copies):,.0f} trace messages for {args.messages} published")
    path = save(
        args.out, "firehose", {"messages": args.messages, "size": SIZE, "runs": runs, "medians": middle}
    )
    console.print(f"wrote {path}")


if __name__ == "__main__":
    main()
