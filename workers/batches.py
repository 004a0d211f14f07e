"""Gather delivered messages into batches: what has arrived, up to a size.

A consumer callback puts messages in; the consuming loop takes a batch at a time and writes it
in one transaction. With no ``linger`` a batch is whatever waits when the loop asks: one message
when traffic is light (no added latency), hundreds under load (they pile up while the previous
batch is being written). A ``linger`` waits that long for more, trading latency for fewer writes.
"""

from __future__ import annotations

import asyncio
from typing import Generic, TypeVar

#: A delivered message: aio-pika's, or the recorder's (:mod:`fleetbus.workers.recorder.source`).
M = TypeVar("M")


class BatchInbox(Generic[M]):
    def __init__(self, batch_size: int = 256, linger: float = 0.0) -> None:
        self._queue: asyncio.Queue[M] = asyncio.Queue()
        self._batch_size = batch_size
        self._linger = linger

    async def put(self, message: M) -> None:
        """The consumer callback (aio-pika wants a coroutine function)."""
        self._queue.put_nowait(message)

    def put_nowait(self, message: M) -> None:
        """The consumer callback of a callback client (pika)."""
        self._queue.put_nowait(message)

    def empty(self) -> bool:
        return self._queue.empty()

    async def next_batch(self, stopping: asyncio.Event, idle: float | None = None) -> list[M]:
        """The next batch; empty when ``stopping`` is set or ``idle`` seconds pass with nothing."""
        batch: list[M] = []
        get = asyncio.ensure_future(self._queue.get())
        stop = asyncio.ensure_future(stopping.wait())
        try:
            done, _ = await asyncio.wait({get, stop}, timeout=idle, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stop.cancel()
        if get not in done and get.cancel():
            return batch  # the message it would have taken stays in the queue
        batch.append(get.result())
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self._linger
        while len(batch) < self._batch_size:
            try:
                batch.append(self._queue.get_nowait())
            except asyncio.QueueEmpty:
                remaining = deadline - loop.time()
                if remaining <= 0:
                    break
                try:
                    batch.append(await asyncio.wait_for(self._queue.get(), remaining))
                except asyncio.TimeoutError:
                    break
        return batch
