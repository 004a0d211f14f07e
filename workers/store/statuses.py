"""Each worker's last word on how it fares: its counters, and what it is waiting for if anything.

A worker writes its status every few seconds (:mod:`fleetbus.workers.status`); ``fleetbus stats`` shows
them. A status that stopped changing says the worker, or its way to the store, is gone.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from datetime import datetime

from fleetbus.workers.store.port import JSON, TEXT, TIME, Database, Schema


@dataclass(frozen=True)
class WorkerStatus:
    name: str
    updated_at: datetime
    counters: dict[str, int] = field(default_factory=dict)
    waiting_for: str | None = None
    """What the worker is retrying now (a transient failure), or None."""
    waiting_since: datetime | None = None
    last_error: str | None = None
    """The transient error of the latest retry, while it waits."""


class StatusBoard(abc.ABC):
    @abc.abstractmethod
    async def put_status(self, status: WorkerStatus) -> None:
        """Keep ``status`` as its worker's latest (replacing the one before)."""

    @abc.abstractmethod
    async def statuses(self) -> list[WorkerStatus]:
        """Every worker's latest status, by name."""


STATUSES = Schema(
    "worker_status",
    {
        "name": TEXT,
        "updated_at": TIME,
        "counters": JSON,
        "waiting_for": TEXT.maybe,
        "waiting_since": TIME.maybe,
        "last_error": TEXT.maybe,
    },
    key=("name",),
)


class Statuses(StatusBoard):
    def __init__(self, database: Database) -> None:
        self._statuses = database.collection(STATUSES)

    async def put_status(self, status: WorkerStatus) -> None:
        await self._statuses.put(status.__dict__)

    async def statuses(self) -> list[WorkerStatus]:
        return [WorkerStatus(**doc) for doc in await self._statuses.find(order=["name"])]
