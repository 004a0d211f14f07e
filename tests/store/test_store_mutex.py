"""The hazard service's critical section across workers: a lease in the store, on every adapter."""

from __future__ import annotations

import asyncio
from datetime import datetime, timedelta, timezone

from tests.store.second import second_connection
from workers.identity import new_holder
from workers.mutex import StoreMutex
from workers.store.interface import Store


async def test_two_workers_never_run_the_critical_section_at_once(store: Store) -> None:
    other = second_connection(store)
    await other.open()
    try:
        mutexes = [StoreMutex(store, "hazards"), StoreMutex(other, "hazards")]
        inside: list[int] = []
        most = 0

        async def critical(mutex: StoreMutex, n: int) -> None:
            nonlocal most
            async with mutex.hold():
                inside.append(n)
                most = max(most, len(inside))
                await asyncio.sleep(0.003)
                inside.remove(n)

        await asyncio.gather(*(critical(mutexes[n % 2], n) for n in range(20)))
        assert most == 1, "one holder at a time, across connections and within one"
        assert await store.leases("lock:") == [], "every holder let go"
    finally:
        await other.close()


async def test_a_holder_that_died_on_this_host_is_replaced_at_once(store: Store) -> None:
    now = datetime.now(timezone.utc)
    dead = new_holder("lock").replace(":lock-", ":gone-")  # this process, a token no longer live
    await store.acquire_lease("lock:hazards", dead, now + timedelta(hours=1), now)

    async def enter() -> str:
        async with StoreMutex(store, "hazards").hold():
            [lease] = await store.leases("lock:")
            return lease.holder

    holder = await asyncio.wait_for(enter(), 5)
    assert holder != dead, "not an hour's wait for a holder known to be gone"
