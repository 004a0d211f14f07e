"""Why each dead letter was refused: one record per rejected message, keyed by its fingerprint.

The broker moves a rejected message to the dead-letter queue itself (``basic.nack`` without
requeue), which cannot add headers; the worker records the reason here first, under the key
:func:`fleetbus.broker.dead_letter_queue.dead_letter_key` computes from the message as it arrives in the
queue. Recording is idempotent: a worker that dies before its nack records the same key again
after the redelivery, and the first record stays.
"""

from __future__ import annotations

import abc
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime

from fleetbus.workers.store.port import TEXT, TIME, Database, In, Index, Schema


@dataclass(frozen=True)
class Rejection:
    key: str
    reason: str
    detail: str
    rejected_at: datetime


class RejectionLog(abc.ABC):
    @abc.abstractmethod
    async def record_rejections(self, rejections: Sequence[Rejection]) -> None:
        """Keep each rejection, durably; a key already kept is left as it is."""

    @abc.abstractmethod
    async def rejections(self, keys: Iterable[str]) -> dict[str, Rejection]:
        """The rejections kept under ``keys`` (unknown keys left out)."""


REJECTIONS = Schema(
    "rejections",
    {"key": TEXT, "reason": TEXT, "detail": TEXT, "rejected_at": TIME},
    key=("key",),
    indexes=(Index("rejected_at"),),
)


class Rejections(RejectionLog):
    def __init__(self, database: Database) -> None:
        self._rejections = database.collection(REJECTIONS)

    async def record_rejections(self, rejections: Sequence[Rejection]) -> None:
        await self._rejections.insert([rejection.__dict__ for rejection in rejections])

    async def rejections(self, keys: Iterable[str]) -> dict[str, Rejection]:
        wanted = list(dict.fromkeys(keys))
        found = await self._rejections.find({"key": In(wanted)}) if wanted else []
        return {doc["key"]: Rejection(**doc) for doc in found}
