"""The dashboard's reads of the sites' sums and the ledger's gaps, as the logs behind them grow.

    .venv/bin/python -m bench.dashboard_reads [--forwards 20000,200000] [--numberings 5000,50000]

Every refresh of the console's dashboard (at most twice a second while one is open) reads each
site's sums of what it forwarded and every robot's open gaps. For each size, a fresh SQLite store
gets that many forwards from one site (one in fifty late) and that many numberings of a
thousand robots' client runs (one in a hundred with a gap), through the store's own calls; then
``summaries()`` and ``gaps()`` are each timed seven times. It prints the medians and extremes in
milliseconds: flat if the reads do not grow with the logs.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import time
from collections.abc import Awaitable, Callable
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from fleetbus.workers.store.ledger import RobotEpoch
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.sites import Forward
from fleetbus.workers.store.sqlite import sqlite_repositories

T0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
RUNS = 7
BATCH = 2000


async def timed(read: Callable[[], Awaitable[Any]]) -> str:
    times = []
    for _ in range(RUNS):
        started = time.perf_counter()
        await read()
        times.append(1000 * (time.perf_counter() - started))
    return f"{statistics.median(times):.2f} ms (min {min(times):.2f}, max {max(times):.2f})"


async def fill(store: Repositories, forwards: int, numberings: int) -> None:
    await store.sites.set_robots("base1", ["r0"])
    for start in range(0, forwards, BATCH):
        await store.sites.record_forwards(
            [
                Forward("r0", "e1", seq, "base1", "status", T0 + timedelta(seconds=seq), T0, seq % 50 == 0)
                for seq in range(start, min(start + BATCH, forwards))
            ]
        )
    for start in range(0, numberings, 1000):
        seen = {
            RobotEpoch(f"r{i % 1000}", f"e{i}"): [0, 2] if i % 100 == 0 else [0, 1]
            for i in range(start, min(start + 1000, numberings))
        }
        await store.events.observe_sequences(seen, T0)


async def measure(forwards: int, numberings: int) -> None:
    with tempfile.TemporaryDirectory() as folder:
        async with sqlite_repositories(Path(folder) / "store.sqlite3") as store:
            await fill(store, forwards, numberings)
            print(f"{forwards:,} forwards: the sites' sums {await timed(store.sites.summaries)}")
            print(f"{numberings:,} numberings: the gaps {await timed(store.events.gaps)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--forwards", default="20000,200000")
    parser.add_argument("--numberings", default="5000,50000")
    args = parser.parse_args()
    sizes = zip(
        (int(n) for n in args.forwards.split(",")), (int(n) for n in args.numberings.split(",")), strict=True
    )
    for forwards, numberings in sizes:
        asyncio.run(measure(forwards, numberings))


if __name__ == "__main__":
    main()
