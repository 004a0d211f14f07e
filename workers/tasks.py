"""Waiting for a task asked to stop: what it ended with is logged, not raised, so that the rest of
the worker still stops (and not thrown away either, which would hide a failed hand-over)."""

from __future__ import annotations

import asyncio
import logging

log = logging.getLogger("fleetbus.worker")


async def stopped(task: asyncio.Future[None], what: str) -> None:
    """Wait for ``task``, asked to stop; log the error it ended with, ``what`` naming it."""
    [outcome] = await asyncio.gather(task, return_exceptions=True)
    if isinstance(outcome, BaseException) and not isinstance(outcome, asyncio.CancelledError):
        log.error("%s ended with an error: %r", what, outcome, exc_info=outcome)
