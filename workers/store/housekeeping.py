"""What the background pruning asks of the store, and the counts of what every bound removed.

Logs are pruned by time, oldest first, in batches the caller sizes, each its own short write, so
that ingest never waits long for the store. Nothing here names an event's key: the event log is
pruned by the time the store received each event, whatever identifies it.

The counts are what an operator reads (``fleetbus stats``): per bound (``events``, ``overflow``…)
and subject (a type, a queue), how many records or messages it removed, and when it last did.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any


@dataclass(frozen=True)
class BoundCount:
    bound: str
    """What was bounded: ``events``, ``duplicates``, ``discards``, ``map-versions``,
    ``map-staging``, ``overflow``."""
    subject: str
    """Within it: the event type, the robot, the queue and why (``warden1.inbox maxlen``)."""
    count: int
    first_at: datetime
    last_at: datetime

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "first_at": self.first_at.isoformat(), "last_at": self.last_at.isoformat()}


class Housekeeping(abc.ABC):
    """Each ``prune_*`` deletes up to ``limit`` of the oldest records that are older than ``before``
    or beyond the newest ``keep`` (either may be None), and says how many it deleted: the caller
    calls again until fewer than ``limit`` go."""

    @abc.abstractmethod
    async def prune_events(self, type: str, before: datetime | None, keep: int | None, limit: int) -> int:
        """The event log's events of ``type``, by the time the store received them; never the
        event of a hazard not yet cleared."""

    @abc.abstractmethod
    async def prune_duplicates(self, before: datetime | None, keep: int | None, limit: int) -> int: ...

    @abc.abstractmethod
    async def prune_discards(self, before: datetime | None, keep: int | None, limit: int) -> int: ...

    @abc.abstractmethod
    async def count_bounded(self, counts: Mapping[tuple[str, str], int], at: datetime) -> None:
        """Add ``counts`` (by bound and subject) to the running totals, durably."""

    @abc.abstractmethod
    async def bound_counts(self) -> list[BoundCount]:
        """Every total, by bound then subject."""
