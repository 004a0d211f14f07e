"""Messages the broker discarded from the beacon exchange, kept so that they can be counted.

A beacon message without the headers ``type: beacon`` and ``codename`` never reaches a
listener: the beacon exchange's alternate exchange routes it to a queue the workers drain into
this log. A message seen twice (same exchange and message id, after a redelivery) counts once.
"""

from __future__ import annotations

import abc
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from fleetbus.workers.store.port import JSON, SERIAL, TEXT, TIME, Database, Doc, Index, Schema


@dataclass(frozen=True)
class Discard:
    exchange: str
    """Where it was published: ``<robot>.beacon`` names the publisher."""
    routing_key: str
    user_id: str | None
    message_id: str | None
    reason: str
    received_at: datetime
    headers: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "received_at": self.received_at.isoformat()}


@dataclass(frozen=True)
class DiscardCount:
    exchange: str
    count: int
    last_at: datetime
    last_reason: str

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "last_at": self.last_at.isoformat()}


class DiscardLog(abc.ABC):
    @abc.abstractmethod
    async def record_discards(self, discards: Sequence[Discard]) -> int:
        """Record a batch durably, skipping an (exchange, message id) seen before; return how many are new."""

    @abc.abstractmethod
    async def discard_counts(self) -> list[DiscardCount]:
        """Per publishing exchange: how many, and the latest one's time and reason; by exchange."""

    @abc.abstractmethod
    async def recent_discards(self, limit: int = 20) -> list[Discard]:
        """The latest discards, newest first."""


DISCARDS = Schema(
    "beacon_discards",
    {
        "once": TEXT,
        "exchange": TEXT,
        "routing_key": TEXT,
        "user_id": TEXT.maybe,
        "message_id": TEXT.maybe,
        "reason": TEXT,
        "received_at": TIME,
        "headers": JSON,
    },
    serial=True,
    indexes=(Index("once", unique=True), Index("exchange", SERIAL), Index("received_at")),
)
"""In the order recorded (``serial``); ``once`` is what makes a discard seen twice one: its
exchange and message id (a discard without a message id is always new)."""


def _discard(doc: Doc) -> Discard:
    return Discard(
        doc["exchange"],
        doc["routing_key"],
        doc["user_id"],
        doc["message_id"],
        doc["reason"],
        doc["received_at"],
        doc["headers"],
    )


class Discards(DiscardLog):
    def __init__(self, database: Database) -> None:
        self._discards = database.collection(DISCARDS)

    async def record_discards(self, discards: Sequence[Discard]) -> int:
        docs = [
            {
                **discard.__dict__,
                "once": f"{discard.exchange}|{discard.message_id}"
                if discard.message_id
                else uuid.uuid4().hex,
            }
            for discard in discards
        ]
        return sum(await self._discards.insert(docs))

    async def discard_counts(self) -> list[DiscardCount]:
        groups = await self._discards.group("exchange", highest=[SERIAL])
        latest = await self._discards.get_many([(group.highest[SERIAL],) for group in groups.values()])
        return sorted(
            (
                DiscardCount(exchange, group.count, last["received_at"], last["reason"])
                for (exchange, group), last in zip(groups.items(), latest, strict=True)
                if last is not None  # pruned in between
            ),
            key=lambda count: count.exchange,
        )

    async def recent_discards(self, limit: int = 20) -> list[Discard]:
        return [_discard(doc) for doc in await self._discards.find(order=["-" + SERIAL], limit=limit)]
