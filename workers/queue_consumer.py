"""A consumer of one queue that handles each message on its own: started, then stopped (its
consumer cancelled, and ``_stopping`` set so that a handler waiting on the store gives up).

A handler's own refusals and retries are its business; what escapes it (a bug, a store error
that is not transient) is logged, counted in ``failed``, and the message given back to the queue
after a pause, to be tried again: never left unacked, which would hold a prefetch slot until the
channel closed, and after a prefetch's worth of them stop the consumer without a word."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from abc import ABC, abstractmethod

from aio_pika.abc import AbstractChannel, AbstractIncomingMessage, AbstractQueue

from fleetbus.broker.retry import pause

log = logging.getLogger("fleetbus.worker")

#: The pause before a message whose handling failed is given back to the queue.
AGAIN_AFTER_S = 1.0


class QueueConsumer(ABC):
    def __init__(self, channel: AbstractChannel, queue: AbstractQueue) -> None:
        self._channel = channel
        self._queue = queue
        self._tag: str | None = None
        self._stopping = asyncio.Event()
        self.failed = 0
        """Messages whose handling failed unexpectedly, each given back to the queue."""

    async def start(self) -> None:
        self._tag = await self._queue.consume(self._handle)

    async def stop(self) -> None:
        self._stopping.set()
        if self._tag is not None and not self._channel.is_closed:
            await self._queue.cancel(self._tag)

    async def _handle(self, message: AbstractIncomingMessage) -> None:
        try:
            await self._on_message(message)
        except Exception:
            self.failed += 1
            log.exception(
                "%s failed on message %s from %s; it goes back to %s and is tried again",
                type(self).__name__,
                message.message_id,
                message.user_id,
                self._queue.name,
            )
            await pause(AGAIN_AFTER_S, self._stopping)
            with contextlib.suppress(Exception):  # a closed channel gives it back itself
                await message.nack(requeue=True)

    @abstractmethod
    async def _on_message(self, message: AbstractIncomingMessage) -> None: ...
