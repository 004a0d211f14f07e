"""Leases: a name held by one holder until a time, taken over only once it has expired.

Worker processes share the ingest shards through leases in the store they all use: ``shard:<n>``
says which worker consumes a shard, ``worker:<id>`` that a worker is alive. A holder renews its lease by
acquiring it again before it expires; a holder that died stops renewing, and its lease is free
once its time has passed. Every acquisition is one atomic conditional write, so of two workers
asking at once exactly one gets a free lease.

Times come from the callers' clocks: the workers sharing a store should run NTP (or chrony).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from datetime import datetime

from fleetbus.workers.store.port import TEXT, TIME, Database, In, Range, Schema


@dataclass(frozen=True)
class Lease:
    name: str
    holder: str
    expires_at: datetime

    def live(self, now: datetime) -> bool:
        return self.expires_at > now


class LeaseStore(abc.ABC):
    @abc.abstractmethod
    async def acquire_lease(
        self, name: str, holder: str, until: datetime, now: datetime, replacing: str | None = None
    ) -> bool:
        """Hold ``name`` until ``until``: when it is free, expired at ``now``, already ``holder``'s
        (a renewal), or held by ``replacing`` (a holder known to be dead). False: someone else holds it."""

    @abc.abstractmethod
    async def release_lease(self, name: str, holder: str) -> None:
        """Give ``name`` up; nothing happens unless ``holder`` holds it."""

    @abc.abstractmethod
    async def leases(self, prefix: str = "") -> list[Lease]:
        """Every lease whose name starts with ``prefix`` (expired ones too), by name."""


LEASES = Schema("leases", {"name": TEXT, "holder": TEXT, "expires_at": TIME}, key=("name",))


class Leases(LeaseStore):
    """An acquisition is one conditional insert-or-overwrite (:meth:`Collection.put`) per way a
    lease may be taken: of two workers asking at once, the database lets one win."""

    def __init__(self, database: Database) -> None:
        self._leases = database.collection(LEASES)

    async def acquire_lease(
        self, name: str, holder: str, until: datetime, now: datetime, replacing: str | None = None
    ) -> bool:
        lease = {"name": name, "holder": holder, "expires_at": until}
        holders = [holder] if replacing is None else [holder, replacing]
        return await self._leases.put(lease, where={"holder": In(holders)}) or await self._leases.put(
            lease, where={"expires_at": Range(le=now)}
        )

    async def release_lease(self, name: str, holder: str) -> None:
        await self._leases.delete({"name": name, "holder": holder})

    async def leases(self, prefix: str = "") -> list[Lease]:
        found = await self._leases.find(order=["name"])
        return [Lease(**doc) for doc in found if doc["name"].startswith(prefix)]
