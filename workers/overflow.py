"""Count what full queues dropped: drain ``fleetbus.overflow.dropped`` into the store's bound counts.

A bound queue (an inbox, the dead letters, the recorder's backlog: :mod:`fleetbus.broker.policies`)
dead-letters its oldest message when it is full. The broker says which queue dropped it and why
in the message's ``x-death`` header, newest death first; this consumer adds each batch to the
counts under ``overflow`` and ``<queue> <reason>`` (``warden1.inbox maxlen``), logs it, and acks
the batch only once the counts are durable.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import Counter
from collections.abc import Iterable
from datetime import datetime, timezone
from typing import Any

from aio_pika.abc import AbstractChannel, AbstractQueue

from fleetbus.broker.retry import Stopped, async_retrying, pause, run_retrying
from fleetbus.workers.batches import BatchInbox
from fleetbus.workers.queue_consumer import AGAIN_AFTER_S
from fleetbus.workers.store.base import StoreUnavailable
from fleetbus.workers.store.housekeeping import BoundCount, Housekeeping

log = logging.getLogger("fleetbus.overflow")
BOUND = "overflow"
UNREADABLE = "unreadable"


def dropped_from_queue(counts: Iterable[BoundCount], queue: str) -> int:
    """How many messages the full ``queue`` dropped, as the workers counted them."""
    subject = f"{queue} maxlen"
    return sum(c.count for c in counts if c.bound == BOUND and c.subject == subject)


def _text(value: Any) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else str(value)


def dropped_from(headers: dict[str, Any] | None) -> str:
    """``<queue> <reason>`` of the message's latest death (the broker puts it first); ``unreadable``
    for an ``x-death`` that is not a list of tables (not the broker's: anyone who may publish to
    the queue can send one)."""
    deaths = (headers or {}).get("x-death") or []
    if not deaths:
        return "unknown"
    latest = deaths[0] if isinstance(deaths, list) else None
    if not isinstance(latest, dict):
        return UNREADABLE
    return f"{_text(latest.get('queue', '?'))} {_text(latest.get('reason', '?'))}"


class OverflowCounter:
    def __init__(self, channel: AbstractChannel, queue: AbstractQueue, store: Housekeeping) -> None:
        self._channel = channel
        self._queue = queue
        self._store = store
        self._inbox = BatchInbox(batch_size=256, linger=0.05)
        self._stopping = asyncio.Event()
        self._tag: str | None = None
        self._task: asyncio.Task[None] | None = None
        self.counted = 0

    async def start(self) -> None:
        self._tag = await self._queue.consume(self._inbox.put)
        self._task = asyncio.create_task(self._run(), name="fleetbus-overflow")
        self._task.add_done_callback(_ended)

    async def stop(self) -> None:
        if self._tag is not None and not self._channel.is_closed:
            with contextlib.suppress(Exception):
                await self._queue.cancel(self._tag)
        self._stopping.set()
        if self._task is not None:
            await asyncio.gather(self._task, return_exceptions=True)  # its error: logged by _ended

    async def _run(self) -> None:
        while not self._stopping.is_set():
            batch = await self._inbox.next_batch(self._stopping)
            if not batch:
                continue
            retrying = async_retrying(
                "the store (overflow counts)", on=StoreUnavailable, stop=self._stopping, logger=log
            )
            try:
                counts = Counter(dropped_from(message.headers) for message in batch)
                added = {(BOUND, subject): n for subject, n in counts.items()}
                await run_retrying(
                    retrying,
                    lambda added=added: self._store.count_bounded(added, datetime.now(timezone.utc)),
                )
                await batch[-1].ack(multiple=True)
            except Stopped:
                return  # unacked: the broker gives them to the next worker
            except Exception:  # never stop counting: these are counted when they come again
                log.exception("counting %d dropped messages failed; they are counted again later", len(batch))
                with contextlib.suppress(Exception):  # a closed channel gives them back itself
                    await batch[-1].nack(multiple=True, requeue=True)
                await pause(AGAIN_AFTER_S, self._stopping)
                continue
            self.counted += len(batch)
            for subject, n in sorted(counts.items()):
                log.warning("a full queue dropped its %d oldest: %s", n, subject)


def _ended(task: asyncio.Task[None]) -> None:
    """Said at once: its consumer stays on the queue, the messages it holds unacked, nothing counted."""
    if not task.cancelled() and (error := task.exception()) is not None:
        log.error("counting dropped messages stopped: %r", error, exc_info=error)
