"""The worker's background pruning: the event log, the hazard registry's cleared hazards, central's
log of what sites forwarded, the duplicates register, the beacon discards, map versions and staged
map chunks, and the acknowledged alerts whose condition ended, each held to its bound
(:mod:`fleetbus.bounds`).

A round runs every ``FLEETBUS_PRUNE_EVERY_S`` seconds, in one worker at a time (a lease in the
store), as a task beside the consumers. It deletes in small batches, each its own short write,
with a pause between them: the ingest's batches interleave with it and wait for at most one
batch, never for a round. What a round removed is added to the bound counts (``fleetbus
stats``) and logged.

The event log keeps the event of every hazard not yet cleared, whatever its age. The sequence
ledger needs no event: it keeps each robot's high-water mark and open gaps itself, and a gap
closes on the numbers that arrive, not on its neighbours; a numbering not observed within its
bound is forgotten whole.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from datetime import datetime, timedelta, timezone

from fleetbus.bounds import Bounds
from fleetbus.broker.retry import pause
from fleetbus.limits import Retention, policy_for
from fleetbus.schemas.routing import EventType
from fleetbus.workers.store.alerts import AlertStore
from fleetbus.workers.store.base import StoreError
from fleetbus.workers.store.housekeeping import Housekeeping
from fleetbus.workers.store.leases import LeaseStore
from fleetbus.workers.store.maps import MapStore, versions_to_prune

log = logging.getLogger("fleetbus.pruning")

LEASE = "pruner"
#: Records deleted per write, and the pause after each, during which ingest takes the store.
BATCH = 500
PAUSE_S = 0.02
#: A version a robot began to fetch this recently is still referenced: it is not pruned.
MAP_FETCH_GRACE = timedelta(minutes=10)
#: Maps whose staged chunks expire per write.
STAGED_MAPS_PER_BATCH = 20

Counts = dict[tuple[str, str], int]
Prune = Callable[[datetime | None, int | None, int], Awaitable[int]]
"""A store's ``prune_*``: (before, keep, limit) -> how many went."""


class Pruner:
    def __init__(
        self,
        housekeeping: Housekeeping,
        leases: LeaseStore,
        maps: MapStore,
        alerts: AlertStore,
        bounds: Bounds,
        holder: str,
        *,
        not_a_site: Callable[[], bool] = lambda: False,
        batch: int = BATCH,
        pause_s: float = PAUSE_S,
    ) -> None:
        self._housekeeping = housekeeping
        self._leases = leases
        self._maps = maps
        self._alerts = alerts
        self._bounds = bounds
        self._holder = holder
        self._not_a_site = not_a_site
        """Whether this store is known not to be a site's (its broker has no hazard uplink): its
        hazards' states go to no central, so a cleared one never waits to be sent."""
        self._batch = batch
        self._pause_s = pause_s
        self._stop = asyncio.Event()
        self._task: asyncio.Task[None] | None = None

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="fleetbus-pruning")

    async def stop(self) -> None:
        """End the round in hand after its current batch, and give the lease up for another worker."""
        self._stop.set()
        if self._task is not None:
            await asyncio.gather(self._task, return_exceptions=True)
        with contextlib.suppress(StoreError):
            await self._leases.release_lease(LEASE, self._holder)

    async def _run(self) -> None:
        every = self._bounds.prune_every_s
        while not self._stop.is_set():
            now = datetime.now(timezone.utc)
            try:
                if await self._leases.acquire_lease(
                    LEASE, self._holder, now + timedelta(seconds=3 * every), now
                ):
                    await self.prune(now)
            except StoreError as error:  # the store is away: the next round tries again
                log.warning("pruning skipped: %s", error)
            except Exception:  # a bug in one round must not end the worker's other tasks
                log.exception("pruning round failed")
            await pause(every, self._stop)

    async def prune(self, now: datetime | None = None) -> Counts:
        """One round; what it removed, by bound and subject (also added to the store's counts, even
        when the round ends half way: what went is counted)."""
        now = now or datetime.now(timezone.utc)
        housekeeping, bounds = self._housekeeping, self._bounds
        counts: Counts = {}
        try:
            for event_type in EventType:
                policy = policy_for(bounds.events, event_type.value)
                if policy is not None:
                    counts[("events", event_type.value)] = await self._apply(
                        policy, now, lambda *a, t=event_type.value: housekeeping.prune_events(t, *a)
                    )
            counts[("hazards", "cleared")] = await self._apply(
                bounds.cleared_hazards,
                now,
                lambda *a: housekeeping.prune_cleared_hazards(*a, unsent_too=self._not_a_site()),
            )
            logs: list[tuple[tuple[str, str], Retention, Prune]] = [
                (("ledger", "numberings"), bounds.numberings, housekeeping.prune_numberings),
                (("workers", "gone"), bounds.gone_workers, housekeeping.prune_gone_workers),
                (("rejections", "dead letters"), bounds.rejections, housekeeping.prune_rejections),
                (("forwards", "sites"), bounds.forwards, housekeeping.prune_forwards),
                (("duplicates", "seen"), bounds.duplicates, housekeeping.prune_duplicates),
                (("discards", "beacon"), bounds.discards, housekeeping.prune_discards),
            ]
            for key, policy, prune in logs:
                counts[key] = await self._apply(policy, now, prune)
            counts.update(await self._prune_maps(now))
            counts[("map-staging", "chunks")] = await self._expire_staged_chunks(now)
            counts[("alerts", "acknowledged")] = await self._apply(
                Retention(max_age=bounds.acknowledged_alerts),
                now,
                lambda before, _keep, limit: self._alerts.prune_alerts(before or now, limit),
            )
        finally:
            counts = {key: count for key, count in counts.items() if count}
            if counts:
                await housekeeping.count_bounded(counts, now)
                log.info(
                    "pruned %s",
                    ", ".join(f"{n} {bound} ({subject})" for (bound, subject), n in sorted(counts.items())),
                )
        return counts

    async def _apply(self, policy: Retention, now: datetime, prune: Prune) -> int:
        if policy.max_age is None and policy.max_records is None:
            return 0
        before = now - policy.max_age if policy.max_age is not None else None
        deleted = 0
        while True:
            count = await prune(before, policy.max_records, self._batch)
            deleted += count
            if count < self._batch or self._stop.is_set():
                return deleted
            await asyncio.sleep(self._pause_s)

    async def _prune_maps(self, now: datetime) -> Counts:
        versions = await self._maps.map_versions()
        robots = {version.version: version.robot_id for version in versions}
        reads = await self._maps.map_reads()
        counts: Counts = {}
        for number in versions_to_prune(versions, reads, self._bounds.map_versions, now - MAP_FETCH_GRACE):
            # one version per write: an image may be large
            if await self._maps.delete_map_versions([number]):
                key = ("map-versions", robots[number])
                counts[key] = counts.get(key, 0) + 1
            await asyncio.sleep(self._pause_s)
        return counts

    async def _expire_staged_chunks(self, now: datetime) -> int:
        before = now - self._bounds.map_staging_ttl
        chunks = 0
        while expired := await self._maps.expire_staged_chunks(before, STAGED_MAPS_PER_BATCH):
            for map_id, count in sorted(expired.items()):
                log.warning(
                    "map %s: %d staged chunks expired, no map event named them within %s",
                    map_id,
                    count,
                    self._bounds.map_staging_ttl,
                )
            chunks += sum(expired.values())
            if len(expired) < STAGED_MAPS_PER_BATCH:
                break
            await asyncio.sleep(self._pause_s)
        return chunks
