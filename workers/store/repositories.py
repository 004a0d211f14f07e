"""The store's repositories, one per concern, and the composition root that builds them.

A consumer receives the repositories it uses and nothing else, the way a nameko service gets one
dependency provider per need: the ingest consumer the event log, the rejections and the attempt
counts; the hazard service the hazards and team; the API's accounts the users, the team and the
channels; the pruner the housekeeping, the leases and the maps... (the decision record
``docs/decisions/0003-store-repositories.md`` lists them all).

Every repository of one :class:`Repositories` lives in the same database (one SQLite file, or
one MongoDB database), so that a batch can be stamped with its missions and written with the
sequence ledger in one transaction where the backend has them. :func:`open_repositories` is the
one place that picks the backend (MongoDB when ``mongodb_url`` is set, else SQLite).
"""

from __future__ import annotations

import abc
import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING, TypeVar

from fleetbus.settings import Settings
from fleetbus.workers.store.attempts import AttemptLog
from fleetbus.workers.store.base import EventRecord, EventStore
from fleetbus.workers.store.beacons import BeaconRegistry
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.discards import DiscardLog
from fleetbus.workers.store.hazards import CoordinationStore
from fleetbus.workers.store.housekeeping import Housekeeping
from fleetbus.workers.store.leases import LeaseStore
from fleetbus.workers.store.ledger import SequenceLedger
from fleetbus.workers.store.maps import MapStore
from fleetbus.workers.store.missions import MissionStore
from fleetbus.workers.store.rejections import RejectionLog
from fleetbus.workers.store.statuses import StatusBoard
from fleetbus.workers.store.users import UserStore

if TYPE_CHECKING:
    from fleetbus.workers.store.interface import Store, StoredBatch

T = TypeVar("T")


class EventLog(EventStore, SequenceLedger):
    """The event log and its sequence ledger: the system of record for validated events (the
    recorder's recording is the record of the bus's traffic; see the decision record)."""

    @abc.abstractmethod
    async def store_batch(
        self, records: Sequence[EventRecord], at: datetime, *, urgent: bool = False
    ) -> StoredBatch:
        """A worker's batch, stamped with its missions, written and seen by the ledger
        (:meth:`fleetbus.workers.store.interface.Store.store_batch`)."""


@dataclass(frozen=True)
class Repositories:
    """The repositories of one database; open and close them together (``async with``)."""

    name: str
    """The backend: ``sqlite`` or ``mongodb``."""
    events: EventLog
    hazards: CoordinationStore
    """Hazards and the team (robots, their kind, localisation and service)."""
    beacons: BeaconRegistry
    maps: MapStore
    missions: MissionStore
    channels: ChannelStore
    """Who is mounted on and checked in to which mission."""
    users: UserStore
    discards: DiscardLog
    rejections: RejectionLog
    attempts: AttemptLog
    leases: LeaseStore
    statuses: StatusBoard
    housekeeping: Housekeeping
    _database: Store

    @classmethod
    def of(cls, database: Store) -> Repositories:
        """Each repository as the backend implements it over ``database``."""
        return cls(
            name=database.name,
            events=database,
            hazards=database,
            beacons=database,
            maps=database,
            missions=database,
            channels=database,
            users=database,
            discards=database,
            rejections=database,
            attempts=database,
            leases=database,
            statuses=database,
            housekeeping=database,
            _database=database,
        )

    async def open(self) -> None:
        """Connect and create the tables or indexes; idempotent."""
        await self._database.open()

    async def close(self) -> None:
        await self._database.close()

    async def __aenter__(self) -> Repositories:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()


def repositories_for(settings: Settings) -> Repositories:
    """The repositories the settings select (MongoDB when ``mongodb_url`` is set), not yet opened."""
    if settings.mongodb_url:
        from fleetbus.workers.store.mongo import MongoEventStore

        return Repositories.of(MongoEventStore(settings.mongodb_url))
    from fleetbus.workers.store.sqlite import SQLiteEventStore

    return Repositories.of(SQLiteEventStore(settings.sqlite_path))


@asynccontextmanager
async def open_repositories(settings: Settings) -> AsyncIterator[Repositories]:
    """The settings' repositories, open for the block."""
    async with repositories_for(settings) as repositories:
        yield repositories


def run_with_repositories(settings: Settings, operation: Callable[[Repositories], Awaitable[T]]) -> T:
    """For synchronous callers (commands, tests): open the repositories, run one operation, close them."""

    async def go() -> T:
        async with open_repositories(settings) as repositories:
            return await operation(repositories)

    return asyncio.run(go())
