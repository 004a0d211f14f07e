"""A delivery limit for a classic queue, kept by the worker: a poison message cannot stop a lane.

A quorum queue counts its deliveries and dead-letters a message redelivered too often
(``x-delivery-limit``); the express queue is classic (a hazard reaches the worker sooner), and a
classic queue only flags a redelivery. So the worker counts, in the store, each time it begins to
handle a redelivered message; once a message has been begun ``limit`` times (each time the worker
died on it, or its connection did), it is dead-lettered with the reason ``delivery-limit``
instead of being handled again.

A message that was never redelivered costs nothing here, so the count is off a hazard's usual way.
Redelivered messages are handled one at a time (:class:`~workers.ingest.IngestConsumer` does it),
so only the message being handled counts up, not the ones that merely came back with it.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timezone

from aio_pika.abc import AbstractIncomingMessage

from fleetbus.broker.dead_letter_queue import dead_letter_key
from fleetbus.workers.store.attempts import AttemptLog
from fleetbus.workers.validation import Rejected, RejectReason


def attempt_key(message: AbstractIncomingMessage) -> str:
    """The same for every delivery of one message: a digest of its broker-validated publisher,
    route, message id and body. Not the delivery tag (new at each delivery), so a message sent
    without a message id is counted too; not the message id alone, which a client may repeat."""
    return dead_letter_key(
        message.user_id, message.exchange or "", message.routing_key or "", message.message_id, message.body
    )


class AttemptLimit:
    def __init__(self, log: AttemptLog, limit: int) -> None:
        self._log = log
        self.limit = limit

    async def admit(self, message: AbstractIncomingMessage) -> Rejected | None:
        """None to handle ``message`` now; why not, once it was begun ``limit`` times already."""
        if not message.redelivered:
            return None
        # the first delivery is not counted (nothing flags it): at the n-th redelivery the count is n,
        # the times it was begun before
        begun = await self._log.count_attempt(attempt_key(message), datetime.now(timezone.utc))
        if begun <= self.limit:
            return None
        return Rejected(
            RejectReason.DELIVERY_LIMIT,
            f"the worker began to handle message {message.message_id} {begun} times and never finished "
            f"(the limit is {self.limit}): it is set aside so that the queue can go on",
        )

    async def handled(self, messages: Sequence[AbstractIncomingMessage]) -> None:
        """Forget the counts of redelivered ``messages`` that were handled (or set aside)."""
        await self._log.forget_attempts([attempt_key(m) for m in messages if m.redelivered])
