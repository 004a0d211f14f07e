"""A consumer of one queue that handles each message on its own: started, then stopped (its
consumer cancelled, and ``_stopping`` set so that a handler waiting on the store gives up)."""

from __future__ import annotations

import asyncio
from abc import ABC, abstractmethod

from aio_pika.abc import AbstractChannel, AbstractIncomingMessage, AbstractQueue


class QueueConsumer(ABC):
    def __init__(self, channel: AbstractChannel, queue: AbstractQueue) -> None:
        self._channel = channel
        self._queue = queue
        self._tag: str | None = None
        self._stopping = asyncio.Event()

    async def start(self) -> None:
        self._tag = await self._queue.consume(self._on_message)

    async def stop(self) -> None:
        self._stopping.set()
        if self._tag is not None and not self._channel.is_closed:
            await self._queue.cancel(self._tag)

    @abstractmethod
    async def _on_message(self, message: AbstractIncomingMessage) -> None: ...
