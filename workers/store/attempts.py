"""How often the worker began to handle a redelivered message: a delivery limit for a classic queue.

A quorum queue counts deliveries itself (``x-delivery-limit``); a classic queue only flags a
redelivery, so the worker keeps the count (:mod:`fleetbus.workers.attempts`). Keys are the worker's own
(publisher and message id); a count is forgotten once its message was handled.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from datetime import datetime

from fleetbus.workers.store.port import INTEGER, TEXT, TIME, Database, In, Schema


class AttemptLog(abc.ABC):
    @abc.abstractmethod
    async def count_attempt(self, key: str, at: datetime) -> int:
        """Count one more attempt at ``key``, durably; return the attempts counted so far (1 first)."""

    @abc.abstractmethod
    async def forget_attempts(self, keys: Sequence[str]) -> None:
        """Drop the counts of ``keys`` (their messages were handled); unknown keys are ignored."""


ATTEMPTS = Schema("delivery_attempts", {"key": TEXT, "attempts": INTEGER, "last_at": TIME}, key=("key",))


class Attempts(AttemptLog):
    def __init__(self, database: Database) -> None:
        self._attempts = database.collection(ATTEMPTS)

    async def count_attempt(self, key: str, at: datetime) -> int:
        return await self._attempts.increment(
            {"key": key, "attempts": 1, "last_at": at}, "attempts", overwrite=["last_at"]
        )

    async def forget_attempts(self, keys: Sequence[str]) -> None:
        if keys:
            await self._attempts.delete({"key": In(keys)})
