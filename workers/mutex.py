"""Mutual exclusion for work that must not run twice at once, within one worker or across several.

The hazard service registers hazards and announces the held ones in one critical section: with
several workers active, two announcing at once would send a hazard twice or out of order, and a
hazard registered between another worker's read of the held list and its announcement would be
overtaken by later ones (SQLite registers a batch's hazards as it stores the batch, outside this
section: its ids are committed in order, see ``SQLiteEventStore.store_batch``). :class:`LocalMutex`
suffices while one worker consumes the only shard;
:class:`StoreMutex` holds a lease in the store all workers share.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from datetime import datetime, timedelta, timezone
from typing import Protocol

from workers.identity import known_dead, new_holder, retire
from workers.store.leases import LeaseStore

#: A holder that died inside the critical section blocks the others this long at most.
LOCK_SECONDS = 10.0
FIRST_WAIT = 0.002
LONGEST_WAIT = 0.05


class Mutex(Protocol):
    def hold(self) -> AbstractAsyncContextManager[None]:
        """``async with mutex.hold():`` runs the block while no one else does."""
        ...


class LocalMutex:
    """Exclusion within this process only: enough when no other worker can run the same work."""

    def __init__(self) -> None:
        self._lock = asyncio.Lock()

    @asynccontextmanager
    async def hold(self) -> AsyncIterator[None]:
        async with self._lock:
            yield


class StoreMutex:
    """Exclusion across processes: a lease named ``lock:<name>`` in the shared store.

    Waiting is polling, from 2 ms up to 50 ms between attempts; the critical sections it guards
    last milliseconds. A holder that dies inside one is replaced at once when it ran on this host,
    else once its lease expires (:data:`LOCK_SECONDS`).
    """

    def __init__(self, store: LeaseStore, name: str, seconds: float = LOCK_SECONDS) -> None:
        self._store = store
        self.name = f"lock:{name}"
        self._seconds = seconds
        self._local = asyncio.Lock()  # coroutines of this process queue here, not in the store

    @asynccontextmanager
    async def hold(self) -> AsyncIterator[None]:
        async with self._local:
            holder = new_holder("lock")
            try:
                await self._acquire(holder)
                try:
                    yield
                finally:
                    await self._store.release_lease(self.name, holder)
            finally:
                retire(holder)

    async def _acquire(self, holder: str) -> None:
        wait = FIRST_WAIT
        while True:
            if await self._try(holder) or ((dead := await self._dead()) and await self._try(holder, dead)):
                return
            await asyncio.sleep(wait)
            wait = min(wait * 2, LONGEST_WAIT)

    async def _try(self, holder: str, replacing: str | None = None) -> bool:
        now = datetime.now(timezone.utc)
        until = now + timedelta(seconds=self._seconds)
        return await self._store.acquire_lease(self.name, holder, until, now, replacing=replacing)

    async def _dead(self) -> str | None:
        """The current holder, when it is known to be dead."""
        found = await self._store.leases(self.name)
        return next((x.holder for x in found if x.name == self.name and known_dead(x.holder)), None)
