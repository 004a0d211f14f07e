"""Raw broker rate against fleetbus's end-to-end ingest, measured in one run on one broker.

    .venv/bin/python -m bench.ingest [--events 20000] [--runs 3] [--size 512]

Scenarios, each in a fresh virtual host, repeated ``--runs`` times (medians reported):
  raw publish    pika, persistent messages of ``--size`` bytes, pipelined confirms, into a quorum
                 queue declared like fleetbus's ingest queue
  raw consume    aio-pika, manual ack per message, prefetch 512, from that queue
  ingest         a robot publishes status events of about ``--size`` bytes (pipelined confirms)
                 while `fleetbus worker --no-recorder` runs as a process of its own; timed from
                 the first publish until the store holds them all
  drain          the same events already queued, then the worker starts; timed from the first
                 event it takes to the last, by their received_at stamps (the worker's share
                 alone: compare with raw consume)

After each, the worker is stopped and the check is that the store holds every event once and
the ingest queue is empty (all acked) with nothing dead-lettered.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from pymongo import MongoClient
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from bench.processes import worker_process
from bench.raw import SIZE, raw_rates
from bench.results import medians, save, spread
from bench.scenario import Context, Figures, Skip
from fleetbus.broker.accounts import fresh_vhost
from fleetbus.broker.dead_letter_queue import peek_dead_letters
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.routing import INGEST_QUEUE, EventType
from fleetbus.settings import load_settings
from fleetbus.workers.store.base import EventQuery
from fleetbus_dev.fallback import resolve_broker
from tests.support import Bus, fresh_bus, wait_for

BENCH_VHOST = "fleetbus-bench"
ROBOT = "bench-ingest"
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


def _size(body: dict[str, Any]) -> int:
    return len(encode_event(build_event(EventType.STATUS, ROBOT, new_epoch(), 10_000, body)))


def status_items(count: int, size: int = SIZE) -> list[tuple[EventType, dict[str, Any]]]:
    """``count`` status events of ``size`` bytes on the wire (give or take the digits of their numbers);
    the waypoint pads them, up to its 128 characters."""
    pad = size - _size(status_body())
    if pad < 0:
        raise ValueError(f"a status event is at least {_size(status_body())} bytes")
    return [(EventType.STATUS, status_body("wp-" + "x" * pad))] * count


def event_size(size: int = SIZE) -> int:
    """Bytes on the wire of one event of :func:`status_items` (sequence number 10,000)."""
    return _size(status_items(1, size)[0][1])


def stored_and_acked(bus: Bus, count: int) -> None:
    """After the worker stopped: each event stored once, none left in the queue, none dead-lettered."""
    stored = bus.count(EventType.STATUS.value)
    waiting = bus.ready_messages(INGEST_QUEUE)
    letters = peek_dead_letters(bus.admin_url)
    if (stored, waiting, len(letters)) != (count, 0, 0):
        reasons = Counter(letter.reason for letter in letters)
        example = f", the first: {letters[0].detail}" if letters else ""
        raise RuntimeError(
            f"{count} published: {stored} stored, {waiting} left in the queue, "
            f"dead-lettered {dict(reasons)}{example}"
        )


def ingest_rate(bus: Bus, count: int, size: int = SIZE, queued_first: bool = False) -> float:
    """Events a second stored by `fleetbus worker --no-recorder` (a process of its own).

    Timed from a robot's first publish until the store holds all ``count``. With ``queued_first``
    the events wait in the queue first and the rate is the worker's alone: from the first event
    it took to the last, by the ``received_at`` it stamped on each (its start-up left out).
    """
    robot = bus.robot(bus.add(ROBOT))
    items = status_items(count, size)

    def publish() -> None:
        for start in range(0, count, 5000):
            robot.publish_many(items[start : start + 5000])

    if queued_first:
        publish()
    with worker_process(bus, "--no-recorder"):
        started = time.perf_counter()
        if not queued_first:
            publish()
        wait_for(lambda: bus.count(EventType.STATUS.value) >= count, 600, f"{count} events stored", 0.02)
        elapsed = time.perf_counter() - started
    stored_and_acked(bus, count)
    if queued_first:
        taken = sorted(record.received_at for record in bus.find(EventQuery(type=EventType.STATUS.value)))
        return (count - 1) / max((taken[-1] - taken[0]).total_seconds(), 1e-6)
    return count / elapsed


def one_run(endpoint: BrokerEndpoint, api: ManagementAPI, count: int, size: int) -> dict[str, float]:
    raw = raw_rates(fresh_vhost(api, endpoint.amqp_url, BENCH_VHOST), count, size)
    api.delete_vhost(BENCH_VHOST)
    result = {"raw_publish": raw["publish msg/s"], "raw_consume": raw["consume msg/s"]}
    for scenario in ("ingest", "drain"):
        with tempfile.TemporaryDirectory() as tmp, fresh_bus(endpoint, api, Path(tmp), "bench") as bus:
            result[scenario] = ingest_rate(bus, count, size, queued_first=scenario == "drain")
    return result


@contextmanager
def fresh_database(url: str) -> Iterator[str]:
    """``url`` pointing at a new database of its own, dropped afterwards."""
    name = f"bench_{uuid.uuid4().hex[:10]}"
    try:
        yield urlunsplit(urlsplit(url)._replace(path="/" + name))
    finally:
        with MongoClient(url, serverSelectionTimeoutMS=5000) as client:
            client.drop_database(name)


def figures(context: Context) -> Figures:
    """The suite's ingest on the embedded SQLite store: end to end, and the worker's drain."""
    return _figures(context, lambda: nullcontext(None))


def figures_mongodb(context: Context) -> Figures:
    """The same on the MongoDB at FLEETBUS_MONGODB_URL, each measurement in a database of its own."""
    url = os.environ.get("FLEETBUS_MONGODB_URL")
    if not url:
        raise Skip("FLEETBUS_MONGODB_URL is unset (no MongoDB server can be installed here)")
    return _figures(context, lambda: fresh_database(url))


def _figures(context: Context, database: Callable[[], AbstractContextManager[str | None]]) -> Figures:
    count = context.size(20_000, 5_000)
    result: Figures = {}
    for key, queued_first in (("end to end msg/s", False), ("drain msg/s", True)):
        context.show(f"{key.split(' msg')[0]}: {count:,} events of {SIZE} bytes")
        with database() as mongodb_url, context.bus(mongodb_url) as bus:
            result[key] = ingest_rate(bus, count, SIZE, queued_first)
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
    size = event_size(args.size)
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
