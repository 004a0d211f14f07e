"""Raw broker rate against fleetbus's end-to-end ingest, measured in one run on one broker.

    .venv/bin/python -m bench.ingest [--events 20000] [--runs 3]

Scenarios, each in a fresh virtual host, repeated ``--runs`` times (medians reported):
  raw publish    pika, persistent messages as large as the events below, pipelined confirms,
                 into a quorum queue declared like fleetbus's ingest queue
  raw consume    aio-pika, manual ack per message, prefetch 512, from that queue
  ingest         a robot publishes status events (pipelined confirms) while the worker runs;
                 timed from the first publish until the store holds them all
  drain          the same events already queued, then the worker starts; timed until stored
                 (the worker's share alone: compare with raw consume)
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import aio_pika
import pika
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from bench.results import medians, save, spread
from broker.accounts import Role, fresh_vhost, provision_account
from broker.endpoint import BrokerEndpoint, resolve_broker
from broker.management import ManagementAPI
from broker.topology import QueueSpec, Topology, core_topology, declare_with_url
from fleetbus.config import Settings, load_settings
from publishers.client import RobotClient
from publishers.confirms import Outgoing, PipelinedConfirms
from schemas.envelope import build_event, encode_event
from schemas.routing import INGEST_QUEUE, EventType
from workers.store import open_store
from workers.thread import WorkerThread

BENCH_VHOST = "fleetbus-bench"
RAW_QUEUE = "bench.raw"
console = Console()


def event_size() -> int:
    """Bytes of one benchmark event on the wire; the raw scenarios send bodies of this size."""
    event_type, body = status_items(1)[0]
    return len(encode_event(build_event(event_type, "bench-ingest", 0, body)))


def raw_publish(url: str, count: int, size: int, queue: str = RAW_QUEUE) -> float:
    connection = pika.BlockingConnection(pika.URLParameters(url))
    confirms = PipelinedConfirms(connection, connection.channel(), timeout=60)
    properties = pika.BasicProperties(delivery_mode=2)
    body = b"x" * size
    started = time.perf_counter()
    for start in range(0, count, 1000):
        confirms.publish([Outgoing("", queue, body, properties) for _ in range(min(1000, count - start))], 60)
    elapsed = time.perf_counter() - started
    connection.close()
    return count / elapsed


async def raw_consume(url: str, count: int, queue_name: str = RAW_QUEUE) -> float:
    connection = await aio_pika.connect(url)
    async with connection:
        channel = await connection.channel()
        await channel.set_qos(prefetch_count=512)
        queue = await channel.get_queue(queue_name, ensure=False)
        done = asyncio.Event()
        seen = 0

        async def on_message(message: aio_pika.abc.AbstractIncomingMessage) -> None:
            nonlocal seen
            await message.ack()
            seen += 1
            if seen == count:
                done.set()

        started = time.perf_counter()
        await queue.consume(on_message)
        await asyncio.wait_for(done.wait(), 600)
        return count / (time.perf_counter() - started)


def stored_count(settings: Settings) -> int:
    async def go() -> int:
        async with open_store(settings) as store:
            return await store.count_events(EventType.STATUS.value)

    return asyncio.run(go())


def wait_stored(settings: Settings, count: int, timeout: float = 600) -> None:
    deadline = time.monotonic() + timeout
    while stored_count(settings) < count:
        if time.monotonic() > deadline:
            raise TimeoutError(f"only {stored_count(settings)} of {count} stored")
        time.sleep(0.05)


def status_items(count: int) -> list[tuple[EventType, dict[str, Any]]]:
    body = {
        "battery_percent": 80.0,
        "pose": {"x": 1.0, "y": 2.0},
        "current_waypoint": "wp-" + "x" * 120,
        "processing_rate_hz": 10.0,
    }
    return [(EventType.STATUS, body)] * count


def one_run(endpoint: BrokerEndpoint, api: ManagementAPI, count: int) -> dict[str, float]:
    admin_url = fresh_vhost(api, endpoint.amqp_url, BENCH_VHOST)
    ingest_args = next(q.arguments for q in core_topology().queues if q.name == INGEST_QUEUE)
    asyncio.run(declare_with_url(admin_url, [Topology(queues=(QueueSpec(RAW_QUEUE, ingest_args),))]))
    result = {
        "raw_publish": raw_publish(admin_url, count, event_size()),
        "raw_consume": asyncio.run(raw_consume(admin_url, count)),
    }
    ep = replace(endpoint, amqp_url=admin_url)
    for scenario in ("ingest", "drain"):
        with tempfile.TemporaryDirectory() as tmp:
            settings = replace(load_settings(), data_dir=Path(tmp), amqp_url=admin_url, mongodb_url=None)
            account = asyncio.run(
                provision_account(admin_url, api, f"bench-{scenario}", Role.ROBOT, rotate=True)
            )
            robot = RobotClient(account.amqp_url, state_dir=settings.robots_dir)
            robot.connect()
            items = status_items(count)
            if scenario == "drain":
                for start in range(0, count, 5000):
                    robot.publish_many(items[start : start + 5000])
                started = time.perf_counter()
                with WorkerThread(settings, ep):
                    wait_stored(settings, count)
            else:
                with WorkerThread(settings, ep):
                    started = time.perf_counter()
                    for start in range(0, count, 5000):
                        robot.publish_many(items[start : start + 5000])
                    wait_stored(settings, count)
            result[scenario] = count / (time.perf_counter() - started)
            robot.close()
    api.delete_vhost(BENCH_VHOST)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--events", type=int, default=20000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    endpoint = resolve_broker(load_settings(), start=True)
    runs: list[dict[str, float]] = []
    with (
        ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api,
        Progress(console=console) as progress,
    ):
        task = progress.add_task(f"{args.runs} runs of {args.events} events", total=args.runs)
        for _ in range(args.runs):
            runs.append(one_run(endpoint, api, args.events))
            progress.advance(task)
    middle = medians(runs)
    table = Table(
        title=f"msg/s, median of {args.runs} runs of {args.events} messages of {event_size()} bytes"
    )
    table.add_column("scenario")
    table.add_column("median msg/s", justify="right")
    table.add_column("spread", justify="right")
    table.add_column("vs raw consume", justify="right")
    for key, median in middle.items():
        table.add_row(key, f"{median:,.0f}", spread(runs, key), f"{median / middle['raw_consume']:.2f}")
    console.print(table)
    path = save(args.out, "ingest", {"events": args.events, "runs": runs, "medians": middle})
    console.print(f"wrote {path}")


if __name__ == "__main__":
    main()
