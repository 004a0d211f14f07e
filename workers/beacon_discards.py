"""Count what the beacon exchange discarded: drain the discard queue into the store's discard log.

The broker does the filtering (a robot's ``<robot>.beacon`` headers exchange passes only messages
with ``type: beacon`` and a ``codename``; its alternate exchange takes the rest). This consumer
only says why each one was discarded, logs it and records it, then acks; a message is acked
only after its record is durable, and a redelivered one counts once (its message id).
"""

from __future__ import annotations

import logging
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Any

from fleetbus.broker.retry import GaveUp, Stopped, async_retrying, run_retrying
from fleetbus.schemas.routing import BEACON_CODENAME_HEADER, BEACON_TYPE, BEACON_TYPE_HEADER
from fleetbus.workers.queue_consumer import QueueConsumer
from fleetbus.workers.store.base import StoreUnavailable
from fleetbus.workers.store.discards import Discard, DiscardLog

if TYPE_CHECKING:  # the recorder reads discard_reason without aio-pika (its memory)
    from aio_pika.abc import AbstractChannel, AbstractIncomingMessage, AbstractQueue

log = logging.getLogger("fleetbus.beacons")

#: How long one discard waits for the store before it goes back to the queue.
STORE_DEADLINE_S = 5.0


def discard_reason(headers: dict[str, Any]) -> str:
    problems = []
    kind = headers.get(BEACON_TYPE_HEADER)
    if kind is None:
        problems.append(f"no {BEACON_TYPE_HEADER!r} header")
    elif kind != BEACON_TYPE:
        problems.append(f"header {BEACON_TYPE_HEADER!r} is {kind!r}, not {BEACON_TYPE!r}")
    if BEACON_CODENAME_HEADER not in headers:
        problems.append(f"no {BEACON_CODENAME_HEADER!r} header")
    return "; ".join(problems) or "no header problem found (bound only after it was published?)"


def to_discard(message: AbstractIncomingMessage, at: datetime) -> Discard:
    headers = {
        str(k): v.decode(errors="replace") if isinstance(v, bytes) else str(v)
        for k, v in (message.headers or {}).items()
    }
    return Discard(
        exchange=message.exchange or "",
        routing_key=message.routing_key or "",
        user_id=message.user_id,
        message_id=message.message_id,
        reason=discard_reason(dict(message.headers or {})),
        received_at=at,
        headers=headers,
    )


class DiscardCounter(QueueConsumer):
    def __init__(self, channel: AbstractChannel, queue: AbstractQueue, store: DiscardLog) -> None:
        super().__init__(channel, queue)
        self._store = store
        self.counted = 0

    async def _on_message(self, message: AbstractIncomingMessage) -> None:
        discard = to_discard(message, datetime.now(timezone.utc))
        retrying = async_retrying(
            "the store (a beacon discard)",
            on=StoreUnavailable,
            deadline=STORE_DEADLINE_S,
            stop=self._stopping,
            logger=log,
        )
        try:
            self.counted += await run_retrying(retrying, lambda: self._store.record_discards([discard]))
        except (GaveUp, Stopped) as error:
            # handed back to the queue: counted once the store answers (its message id)
            log.warning("%s; the discard will be redelivered", error)
            await message.nack(requeue=True)
            return
        log.warning(
            "discarded a beacon message on %s from %s: %s",
            discard.exchange,
            discard.user_id or "(no user_id)",
            discard.reason,
        )
        await message.ack()
