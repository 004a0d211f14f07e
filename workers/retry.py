"""Run a store operation until the store answers, backing off, unless the consumer is stopping."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from typing import TypeVar

from workers.backoff import Backoff
from workers.store.base import StoreUnavailable

T = TypeVar("T")


class Stopping(Exception):
    """The consumer is stopping while the store is down: leave the batch unacked."""


async def until_available(
    operation: Callable[[], Awaitable[T]],
    stopping: asyncio.Event,
    log: logging.Logger,
    on_retry: Callable[[], None] = lambda: None,
) -> T:
    backoff = Backoff()
    while True:
        try:
            return await operation()
        except StoreUnavailable as error:
            if stopping.is_set():
                raise Stopping from error
            on_retry()
            delay = backoff.next_delay()
            log.warning("store unavailable (%s); retry %d in %.1f s", error, backoff.attempts, delay)
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(stopping.wait(), delay)
