"""Leases on every adapter: one holder at a time, renewals, expiry, a dead holder replaced."""

from __future__ import annotations

import asyncio
from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.leases import Lease
from fleetbus.workers.store.repositories import Repositories
from tests.store.second import second_connection

T0 = datetime(2026, 11, 24, 8, 0, 0, tzinfo=timezone.utc)
TTL = timedelta(seconds=5)


async def test_a_free_lease_is_taken_and_renewed_by_its_holder_only(store: Repositories) -> None:
    assert await store.leases.acquire_lease("shard:0", "w1", T0 + TTL, T0)
    assert not await store.leases.acquire_lease("shard:0", "w2", T0 + TTL, T0 + timedelta(seconds=1))
    assert await store.leases.acquire_lease("shard:0", "w1", T0 + 2 * TTL, T0 + timedelta(seconds=1)), (
        "a renewal"
    )
    assert await store.leases.leases("shard:") == [Lease("shard:0", "w1", T0 + 2 * TTL)]


async def test_an_expired_lease_goes_to_the_next_asker(store: Repositories) -> None:
    await store.leases.acquire_lease("shard:0", "w1", T0 + TTL, T0)
    assert not await store.leases.acquire_lease(
        "shard:0", "w2", T0 + 2 * TTL, T0 + TTL - timedelta(microseconds=1)
    )
    assert await store.leases.acquire_lease("shard:0", "w2", T0 + 2 * TTL, T0 + TTL)
    assert not await store.leases.acquire_lease("shard:0", "w1", T0 + 2 * TTL, T0 + TTL), "its holder lost it"
    [lease] = await store.leases.leases("shard:0")
    assert lease.holder == "w2" and lease.live(T0 + TTL) and not lease.live(T0 + 2 * TTL)


async def test_a_holder_known_dead_is_replaced_at_once(store: Repositories) -> None:
    await store.leases.acquire_lease("shard:1", "host:100:a", T0 + TTL, T0)
    assert not await store.leases.acquire_lease("shard:1", "host:200:b", T0 + TTL, T0, replacing="host:300:c")
    assert await store.leases.acquire_lease("shard:1", "host:200:b", T0 + TTL, T0, replacing="host:100:a")
    assert [lease.holder for lease in await store.leases.leases("shard:")] == ["host:200:b"]


async def test_only_the_holder_releases(store: Repositories) -> None:
    await store.leases.acquire_lease("shard:0", "w1", T0 + TTL, T0)
    await store.leases.release_lease("shard:0", "w2")
    assert [lease.holder for lease in await store.leases.leases("shard:")] == ["w1"]
    await store.leases.release_lease("shard:0", "w1")
    assert await store.leases.leases("shard:") == []
    assert await store.leases.acquire_lease("shard:0", "w2", T0 + TTL, T0), "free again"


async def test_leases_are_listed_by_prefix_in_name_order(store: Repositories) -> None:
    for name in ("worker:b", "shard:1", "worker:a", "shard:0"):
        await store.leases.acquire_lease(name, name.split(":")[1], T0 + TTL, T0)
    assert [lease.name for lease in await store.leases.leases("worker:")] == ["worker:a", "worker:b"]
    assert [lease.name for lease in await store.leases.leases()] == [
        "shard:0",
        "shard:1",
        "worker:a",
        "worker:b",
    ]


async def test_of_many_workers_asking_at_once_exactly_one_holds_the_lease(store: Repositories) -> None:
    others = [second_connection(store) for _ in range(3)]
    for other in others:
        await other.open()
    try:
        askers = [store, *others]
        won = await asyncio.gather(
            *(asker.leases.acquire_lease("shard:2", f"w{n}", T0 + TTL, T0) for n, asker in enumerate(askers))
        )
        [winner] = [n for n, ok in enumerate(won) if ok]
        assert [lease.holder for lease in await store.leases.leases("shard:2")] == [f"w{winner}"]
    finally:
        for other in others:
            await other.close()
