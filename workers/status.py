"""A worker's status in the store every few seconds: its counters, and what it waits for.

Transient failures are retried where they happen (:mod:`fleetbus.broker.retry`, a log line each); this
makes them visible where an operator looks, ``fleetbus stats``, beside the counts of what was
stored, dead-lettered and failed on. A status that stops changing says the worker, or its way to
the store, is gone.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from datetime import datetime, timezone

from fleetbus.broker.retry import pause
from fleetbus.workers.ingest import IngestStats
from fleetbus.workers.store.base import StoreUnavailable
from fleetbus.workers.store.statuses import StatusBoard, WorkerStatus

log = logging.getLogger("fleetbus.worker")

STATUS_INTERVAL_S = 5.0
COUNTERS = ("stored", "duplicates", "rejected", "internal_errors", "notified", "store_retries")


def status_of(name: str, stats: IngestStats, extra: dict[str, int]) -> WorkerStatus:
    counters = {counter: getattr(stats, counter) for counter in COUNTERS}
    counters.update({f"rejected.{reason}": count for reason, count in stats.by_reason.items()})
    counters.update(extra)
    return WorkerStatus(
        name, datetime.now(timezone.utc), counters, stats.waiting_for, stats.waiting_since, stats.last_error
    )


async def report_status(
    board: StatusBoard,
    name: str,
    stats: IngestStats,
    stop: asyncio.Event,
    extra: Callable[[], dict[str, int]] = dict,
    interval: float = STATUS_INTERVAL_S,
) -> None:
    """Write the status every ``interval`` seconds until ``stop``, and once more then."""
    while True:
        try:
            await board.put_status(status_of(name, stats, extra()))
        except StoreUnavailable as error:  # the retries say so where they happen
            log.debug("status not written: %s", error)
        except Exception:  # a status that stops changing says the worker is gone: never stop
            log.exception("status not written; trying again in %.0f s", interval)
        if stop.is_set():
            return
        await pause(interval, stop)
