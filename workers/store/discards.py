"""Messages the broker discarded from the beacon exchange, kept so that they can be counted.

A beacon message without the headers ``type: beacon`` and ``codename`` never reaches a
listener: the beacon exchange's alternate exchange routes it to a queue the workers drain into
this log. A message seen twice (same exchange and message id, after a redelivery) counts once.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any


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
