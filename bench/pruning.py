"""What the background pruning costs the ingest on SQLite, the store with one writer at a time.

    .venv/bin/python -m bench.pruning [--old 200000] [--seconds 20]

A store holds ``--old`` status events received 40 days ago. Two phases of ``--seconds`` each
write what a worker writes under load, through the same store calls: a hazard every 20 ms as the
express lane does (``store_batch``, urgent, one event: its latency is the figure), and 256
status events every 250 ms as a shard's batches (1,000 a second). In the second phase a pruning
round (``Pruner.prune``, the worker's own, retention 30 days) deletes the old events meanwhile.
It prints the hazard write's p50, p99 and max in each phase, and how fast the round pruned.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import tempfile
import time
from dataclasses import replace
from datetime import datetime, timedelta, timezone
from pathlib import Path

from fleetbus.bounds import bounds
from fleetbus.settings import load_settings
from fleetbus.workers.pruning import Pruner
from fleetbus.workers.store.base import EventRecord
from fleetbus.workers.store.repositories import EventLog
from fleetbus.workers.store.sqlite import sqlite_repositories
from tests.store.test_contract import record

HAZARD_EVERY_S = 0.02
BULK_EVERY_S = 0.25
BULK = 256


class Numbers:
    def __init__(self) -> None:
        self.next = 0

    def take(self, count: int) -> range:
        self.next += count
        return range(self.next - count, self.next)


def events(robot: str, seqs: range, type: str, received: datetime) -> list[EventRecord]:
    return [replace(record(robot, seq, type, received), received_at=received) for seq in seqs]


async def seed(store: EventLog, count: int) -> None:
    old = datetime.now(timezone.utc) - timedelta(days=40)
    for start in range(0, count, 5000):
        await store.write_events(events("old", range(start, min(count, start + 5000)), "status", old))


async def load(store: EventLog, seconds: float, numbers: Numbers) -> list[float]:
    """The ingest's writes for ``seconds``; each hazard write's milliseconds."""
    latencies: list[float] = []
    stop = time.monotonic() + seconds

    async def hazards() -> None:
        while time.monotonic() < stop:
            batch = events("explorer", numbers.take(1), "hazard", datetime.now(timezone.utc))
            started = time.perf_counter()
            await store.store_batch(batch, datetime.now(timezone.utc), urgent=True)
            latencies.append((time.perf_counter() - started) * 1000)
            await asyncio.sleep(HAZARD_EVERY_S)

    async def statuses() -> None:
        while time.monotonic() < stop:
            batch = events("telemetry", numbers.take(BULK), "status", datetime.now(timezone.utc))
            await store.store_batch(batch, datetime.now(timezone.utc))
            await asyncio.sleep(BULK_EVERY_S)

    await asyncio.gather(hazards(), statuses())
    return latencies


def summary(latencies: list[float]) -> dict[str, float]:
    ordered = sorted(latencies)
    return {
        "p50 ms": statistics.median(ordered),
        "p99 ms": ordered[int(0.99 * (len(ordered) - 1))],
        "max ms": ordered[-1],
        "writes": float(len(ordered)),
    }


async def measure(folder: Path, old: int, seconds: float) -> dict[str, object]:
    async with sqlite_repositories(folder / "store.sqlite3") as repositories:
        store = repositories.events
        await seed(store, old)
        numbers = Numbers()
        quiet = await load(store, seconds, numbers)
        pruner = Pruner(
            repositories.housekeeping,
            repositories.leases,
            repositories.maps,
            repositories.alerts,
            bounds(load_settings({})),
            "bench",
        )
        started = time.monotonic()
        pruning = asyncio.create_task(pruner.prune())
        ended: list[float] = []
        pruning.add_done_callback(lambda _: ended.append(time.monotonic()))
        busy = await load(store, seconds, numbers)
        pruned = await pruning
        took = ended[0] - started
        return {
            "old events": old,
            "hazard write, no pruning": summary(quiet),
            "hazard write, while pruning": summary(busy),
            "pruned": pruned.get(("events", "status"), 0),
            "pruning s": took,
            "phase s": seconds,
            "pruned per s": pruned.get(("events", "status"), 0) / took,
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", type=int, default=200_000, help="old events to prune")
    parser.add_argument("--seconds", type=float, default=20.0, help="each phase")
    options = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="fleetbus-pruning-") as folder:
        print(json.dumps(asyncio.run(measure(Path(folder), options.old, options.seconds)), indent=2))


if __name__ == "__main__":
    main()
