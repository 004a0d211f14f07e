"""Dead-letter a rejected message: record why in the store, then let the broker move it.

``basic.nack`` without requeue makes the broker move the message to its queue's dead-letter
exchange (``fleetbus.dlx``) in one step: it is in the dead-letter queue or still in its own
queue, never both, whenever the worker dies. The reason cannot travel in that move, so it is
recorded first, idempotently, under the key :mod:`fleetbus.broker.dead_letter_queue` finds it by
(docs/decisions/0002-dead-letters.md).
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Protocol, TypeVar

from fleetbus.broker.dead_letter_queue import dead_letter_key
from fleetbus.workers.store.rejections import Rejection

MAX_DETAIL = 4000


class Delivered(Protocol):
    """What settling a delivered message reads of it: aio-pika's messages have it, and so do the
    recorder's (:mod:`fleetbus.workers.recorder.source`, pika)."""

    @property
    def user_id(self) -> str | None: ...
    @property
    def exchange(self) -> str: ...
    @property
    def routing_key(self) -> str | None: ...
    @property
    def message_id(self) -> str | None: ...
    @property
    def body(self) -> bytes: ...
    @property
    def processed(self) -> bool: ...

    async def nack(self, requeue: bool = True) -> None: ...


D = TypeVar("D", bound=Delivered)


def rejection_of(message: Delivered, reason: str, detail: str) -> Rejection:
    key = dead_letter_key(
        message.user_id, message.exchange or "", message.routing_key or "", message.message_id, message.body
    )
    return Rejection(key, reason, detail[:MAX_DETAIL], datetime.now(timezone.utc))


async def move_to_dead_letters(message: Delivered) -> None:
    """The broker moves it to the queue's dead-letter exchange (its reason already recorded)."""
    await message.nack(requeue=False)


def last_unsettled(batch: list[D]) -> D | None:
    """The last message of the batch not dead-lettered: acking (or nacking) it with ``multiple``
    settles every earlier one still open; a dead-lettered one is settled already."""
    return next((message for message in reversed(batch) if not message.processed), None)
