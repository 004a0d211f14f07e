"""Each worker's last word on how it fares: its counters, and what it is waiting for if anything.

A worker writes its status every few seconds (:mod:`fleetbus.workers.status`); ``fleetbus stats`` shows
them. A status that stopped changing says the worker, or its way to the store, is gone.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from datetime import datetime


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
