"""How the worker processes share the ingest shards: leases in the store they all use.

Every second each worker renews its presence (``worker:<id>``) and the shards it consumes
(``shard:<n>``), and counts the live workers. Its share is the number of shards divided by
that count (the first workers by id take one more when it does not divide). A worker holding
more than its share gives the extra shards back: it stops consuming them, finishes and acks what
it received, and only then releases their leases; a worker holding fewer takes free ones. So a
new worker gets its share within two heartbeats, and a stopped one's shards move at once.

A worker that dies (SIGKILL, a lost machine) cannot give anything back: its leases expire after
:data:`LEASE_SECONDS`, and the others take its shards (at once when it ran on the same host).
The broker has given the messages it had not acked back to the queue, in their order, so
nothing is lost; what it had stored but not acked comes again and is recognised as a duplicate.

The leases only divide the work. Correctness does not depend on them: every shard queue has a
single active consumer, so even two workers that both believe they hold a shard (one paused past
its lease) never consume it at once; the second waits until the first lets go.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from datetime import datetime, timedelta, timezone
from typing import Protocol

from fleetbus.workers.identity import known_dead, new_holder, retire
from fleetbus.workers.store.base import StoreUnavailable
from fleetbus.workers.store.leases import Lease, LeaseStore

log = logging.getLogger("fleetbus.shards")

HEARTBEAT_SECONDS = 1.0
LEASE_SECONDS = 5.0
WORKER_PREFIX = "worker:"
SHARD_PREFIX = "shard:"


def shard_lease(shard: int) -> str:
    return f"{SHARD_PREFIX}{shard}"


def share(shards: int, workers: list[str], me: str) -> int:
    """How many shards ``me`` should consume among ``workers`` (sorted, ``me`` included)."""
    base, extra = divmod(shards, len(workers))
    return base + (1 if workers.index(me) < extra else 0)


class RunningShard(Protocol):
    """A shard being consumed."""

    @property
    def done(self) -> asyncio.Future[None]:
        """Completes when consuming ended by itself (the error, if any, is its exception)."""
        ...

    async def stop(self) -> None:
        """Stop taking messages, finish and ack the ones received, let the queue go; log what
        consuming ended with (the pool reports only a shard that ends by itself first)."""
        ...


StartShard = Callable[[int], Awaitable[RunningShard]]


class ShardPool:
    def __init__(
        self,
        store: LeaseStore,
        shards: int,
        start_shard: StartShard,
        *,
        heartbeat: float = HEARTBEAT_SECONDS,
        lease: float = LEASE_SECONDS,
    ) -> None:
        self._store = store
        self.shards = shards
        self._start_shard = start_shard
        self._heartbeat = heartbeat
        self._lease = timedelta(seconds=lease)
        self.holder = new_holder()
        self.held: dict[int, RunningShard] = {}
        self._failed: asyncio.Future[BaseException | None] = asyncio.get_running_loop().create_future()
        self._beating: asyncio.Task[None] | None = None

    async def start(self) -> None:
        """Take this worker's share of the free shards now, then keep the share every heartbeat."""
        await self.tick()
        self._beating = asyncio.create_task(self._beat(), name="fleetbus-shard-heartbeat")

    async def wait_failed(self) -> BaseException | None:
        """Returns when a shard's consumer ended by itself (what it raised), which stops the worker."""
        return await asyncio.shield(self._failed)

    async def stop(self) -> None:
        """Stop every shard (their batches finished and acked), then give the leases back."""
        if self._beating is not None:
            self._beating.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._beating
        for shard in sorted(self.held):
            await self._let_go(shard, release=True)
        with contextlib.suppress(StoreUnavailable):
            await self._store.release_lease(WORKER_PREFIX + self.holder, self.holder)
        retire(self.holder)

    async def _beat(self) -> None:
        while True:
            await asyncio.sleep(self._heartbeat)
            try:
                await self.tick()
            except StoreUnavailable as error:
                # keep consuming what is held: the single active consumer still guards each shard
                log.warning("shard leases not renewed: %s", error)
            except Exception:  # a broker error starting a shard, say: the next beat tries again
                log.exception("sharing the shards failed this time")

    async def tick(self) -> None:
        now = datetime.now(timezone.utc)
        until = now + self._lease
        await self._store.acquire_lease(WORKER_PREFIX + self.holder, self.holder, until, now)
        leases = await self._store.leases()
        workers = sorted(
            {self.holder}
            | {
                lease.holder
                for lease in leases
                if lease.name.startswith(WORKER_PREFIX) and lease.live(now) and not known_dead(lease.holder)
            }
        )
        for shard in sorted(self.held):
            if not await self._store.acquire_lease(shard_lease(shard), self.holder, until, now):
                log.warning("shard %d was taken over while this worker held it; letting it go", shard)
                await self._let_go(shard, release=False)
        wanted = share(self.shards, workers, self.holder)
        for shard in sorted(self.held, reverse=True)[: max(0, len(self.held) - wanted)]:
            log.info("giving shard %d back: %d workers share %d shards", shard, len(workers), self.shards)
            await self._let_go(shard, release=True)
        owners = {lease.name: lease for lease in leases if lease.name.startswith(SHARD_PREFIX)}
        for shard in range(self.shards):
            if len(self.held) >= wanted:
                break
            if shard not in self.held:
                await self._try_take(shard, owners.get(shard_lease(shard)), until, now)

    async def _try_take(self, shard: int, lease: Lease | None, until: datetime, now: datetime) -> None:
        replacing = None
        if lease is not None and lease.holder != self.holder and lease.live(now):
            if not known_dead(lease.holder):
                return
            replacing = lease.holder
        if not await self._store.acquire_lease(shard_lease(shard), self.holder, until, now, replacing):
            return
        if replacing:
            log.info("taking shard %d over from %s, which is no longer running", shard, replacing)
        try:
            running = await self._start_shard(shard)
        except BaseException:
            with contextlib.suppress(StoreUnavailable):
                await self._store.release_lease(shard_lease(shard), self.holder)
            raise
        self.held[shard] = running
        running.done.add_done_callback(lambda done, shard=shard: self._ended(shard, done))

    def _ended(self, shard: int, done: asyncio.Future[None]) -> None:
        error = done.exception() if not done.cancelled() else None
        if self.held.get(shard) is None or self._failed.done():
            return  # stopped on purpose, or the worker stops: the shard's stop logs its error
        log.error("consuming shard %d ended by itself: %r", shard, error)
        self._failed.set_result(error)

    async def _let_go(self, shard: int, *, release: bool) -> None:
        running = self.held.pop(shard)
        await running.stop()
        if release:
            with contextlib.suppress(StoreUnavailable):
                await self._store.release_lease(shard_lease(shard), self.holder)
