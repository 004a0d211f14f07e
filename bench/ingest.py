"""Raw broker rate against fleetbus's end-to-end ingest, measured in one run on one broker.

    .venv/bin/python -m bench.ingest [--events 20000] [--runs 3] [--size 512]

Scenarios, each in a fresh virtual host, repeated ``--runs`` times (medians reported):
  raw publish    pika, persistent messages of ``--size`` bytes, pipelined confirms, into a quorum
                 queue declared like fleetbus's ingest queue
  raw consume    aio-pika, manual ack per message, prefetch 512, from that queue
  ingest         a robot publishes status events of about ``--size`` bytes (pipelined confirms)
                 while `fleetbus worker --no-recorder` runs as a process of its own; timed from
                 the first publish until the store holds them all
  drain          the same events already queued, then the worker starts; timed until stored
                 (the worker's share alone: compare with raw consume)

After each, the worker is stopped and the check is that the store holds every event once and
the ingest queue is empty (all acked) with nothing dead-lettered.
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from bench.processes import worker_process
from bench.raw import declare_queue, ingest_queue_arguments, raw_consume, raw_publish
from bench.results import medians, save, spread
from broker.accounts import fresh_vhost
from broker.dead_letter_queue import peek_dead_letters
from broker.endpoint import BrokerEndpoint, resolve_broker
from broker.management import ManagementAPI
from fleetbus.config import load_settings
from schemas.envelope import build_event, encode_event
from schemas.routing import INGEST_QUEUE, EventType
from tests.support import Bus, fresh_bus, wait_for

BENCH_VHOST = "fleetbus-bench"
ROBOT = "bench-ingest"
SIZE = 512
console = Console()


def status_body(waypoint: str = "wp-") -> dict[str, Any]:
    """Telemetry as a robot sends it (doubles at full precision); ``waypoint`` pads it."""
    orientation = {"x": 0.0, "y": 0.0, "z": 0.38268343236508984, "w": 0.9238795325112867}
    return {
        "battery_percent": 81.23456789012345,
        "pose": {"x": 12.345678901234567, "y": -3.4567890123456789, "orientation": orientation},
        "current_waypoint": waypoint,
        "processing_rate_hz": 9.876543210987654,
    }


def event_size(body: dict[str, Any] | None = None) -> int:
    """Bytes of one benchmark event on the wire (sequence number 10,000)."""
    return len(encode_event(build_event(EventType.STATUS, ROBOT, 10_000, body or status_body())))


def status_items(count: int, size: int = SIZE) -> list[tuple[EventType, dict[str, Any]]]:
    """``count`` status events of ``size`` bytes on the wire (give or take the digits of their numbers);
    the waypoint pads them, up to its 128 characters."""
    pad = size - event_size()
    if pad < 0:
        raise ValueError(f"a status event is at least {event_size()} bytes")
    return [(EventType.STATUS, status_body("wp-" + "x" * pad))] * count


def stored_and_acked(bus: Bus, count: int) -> None:
    """After the worker stopped: each event stored once, none left in the queue, none dead-lettered."""
    stored = bus.count(EventType.STATUS.value)
    waiting = bus.ready_messages(INGEST_QUEUE)
    dead = len(peek_dead_letters(bus.admin_url))
    if (stored, waiting, dead) != (count, 0, 0):
        raise RuntimeError(f"{count} published: {stored} stored, {waiting} left in the queue, {dead} dead")


def ingest_rate(bus: Bus, count: int, size: int = SIZE, queued_first: bool = False) -> float:
    """Events a second stored by `fleetbus worker --no-recorder` (a process of its own).

    Timed from a robot's first publish until the store holds all ``count``; with ``queued_first``
    the events wait in the queue first and the rate is the worker's, from the moment it consumes
    (the events stored before that moment are left out, so its start-up does not count).
    """
    robot = bus.robot(bus.add(ROBOT))
    items = status_items(count, size)

    def publish() -> None:
        for start in range(0, count, 5000):
            robot.publish_many(items[start : start + 5000])

    if queued_first:
        publish()
    with worker_process(bus, "--no-recorder"):
        started, before = time.perf_counter(), 0
        if queued_first:
            before = bus.count(EventType.STATUS.value)
        else:
            publish()
        wait_for(lambda: bus.count(EventType.STATUS.value) >= count, 600, f"{count} events stored", 0.02)
        elapsed = time.perf_counter() - started
    stored_and_acked(bus, count)
    return (count - before) / elapsed


def raw_rates(admin_url: str, count: int, size: int = SIZE) -> dict[str, float]:
    """Raw publish and consume of ``count`` messages of ``size`` bytes, in a queue like the ingest's."""
    declare_queue(admin_url, ingest_queue_arguments())
    return {
        "raw_publish": raw_publish(admin_url, count, size),
        "raw_consume": asyncio.run(raw_consume(admin_url, count)),
    }


def one_run(endpoint: BrokerEndpoint, api: ManagementAPI, count: int, size: int) -> dict[str, float]:
    result = raw_rates(fresh_vhost(api, endpoint.amqp_url, BENCH_VHOST), count, size)
    api.delete_vhost(BENCH_VHOST)
    for scenario in ("ingest", "drain"):
        with tempfile.TemporaryDirectory() as tmp, fresh_bus(endpoint, api, Path(tmp), "bench") as bus:
            result[scenario] = ingest_rate(bus, count, size, queued_first=scenario == "drain")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--events", type=int, default=20000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--size", type=int, default=SIZE)
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
            runs.append(one_run(endpoint, api, args.events, args.size))
            progress.advance(task)
    middle = medians(runs)
    size = event_size(status_items(1, args.size)[0][1])
    table = Table(title=f"msg/s, median of {args.runs} runs of {args.events} messages of {size} bytes")
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
