"""The dead-letter queue as the command line, the HTTP API and the console show it: the letters,
oldest first, each with the reason the workers kept in the store (nothing is removed from the
queue), and how many older letters the full queue dropped, as the workers counted them."""

from __future__ import annotations

from fleetbus.broker.dead_letter_queue import DeadLetter, Listing, read_dead_letters
from fleetbus.schemas.routing import DEAD_LETTER_QUEUE
from fleetbus.workers.overflow import dropped_from_queue
from fleetbus.workers.store.housekeeping import Housekeeping
from fleetbus.workers.store.rejections import RejectionLog

__all__ = ["DeadLetter", "DeadLetters", "Listing"]


class DeadLetters:
    def __init__(self, rejections: RejectionLog, housekeeping: Housekeeping, admin_url: str) -> None:
        """``admin_url``: the administrator's broker, whose dead-letter queue is read."""
        self._rejections = rejections
        self._housekeeping = housekeeping
        self._admin_url = admin_url

    async def listing(self, limit: int) -> Listing:
        """Up to ``limit`` letters, oldest first, each with its kept reason, and how many the queue
        held."""
        return await read_dead_letters(self._admin_url, limit, self._rejections.rejections)

    async def dropped(self) -> int:
        """How many older letters the full queue dropped (``FLEETBUS_DEAD_LETTERS_MAX``)."""
        return dropped_from_queue(await self._housekeeping.bound_counts(), DEAD_LETTER_QUEUE)
