"""The store's repositories, one per concern, and the one place that picks their backend.

A consumer receives the repositories it uses and nothing else, the way a nameko service gets one
dependency provider per need: the ingest consumer the event log and the rejections; the hazard
service the hazards and team; the API's accounts the users, the team and the channels; the pruner
the housekeeping, the leases and the maps... (the decision record
``docs/decisions/0007-store-repositories.md`` lists them all).

Each repository is written once, over the persistence port (:mod:`fleetbus.workers.store.port`),
which each backend implements (:mod:`~fleetbus.workers.store.sqlite`,
:mod:`~fleetbus.workers.store.mongo`); :func:`~fleetbus.workers.store.compose.repositories_on`
builds them all over one database (one SQLite file, or one MongoDB client), so that a batch can be
stamped with its missions and written with the sequence ledger in one transaction where the
backend has them. :func:`repositories_for` is the one place that picks the backend (MongoDB when
``mongodb_url`` is set, else SQLite).
"""

from __future__ import annotations

import abc
import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TypeVar

from fleetbus.workers.store.base import EventRecord, EventStore
from fleetbus.workers.store.ledger import SequenceLedger

if TYPE_CHECKING:
    from fleetbus.workers.store.alerts import AlertStore
    from fleetbus.workers.store.attempts import AttemptLog
    from fleetbus.workers.store.beacons import BeaconRegistry
    from fleetbus.workers.store.channels import ChannelStore
    from fleetbus.workers.store.comments import CommentStore
    from fleetbus.workers.store.discards import DiscardLog
    from fleetbus.workers.store.hazards import CoordinationStore
    from fleetbus.workers.store.housekeeping import Housekeeping
    from fleetbus.workers.store.interface import StoredBatch
    from fleetbus.workers.store.leases import LeaseStore
    from fleetbus.workers.store.maps import MapStore
    from fleetbus.workers.store.missions import MissionStore
    from fleetbus.workers.store.rejections import RejectionLog
    from fleetbus.workers.store.sessions import SessionStore
    from fleetbus.workers.store.sites import SiteRegistry
    from fleetbus.workers.store.statuses import StatusBoard
    from fleetbus.workers.store.users import UserStore

T = TypeVar("T")


class EventLog(EventStore, SequenceLedger):
    """The event log and its sequence ledger: the system of record for validated events, what the
    service accepted and acts on, written before the ingest acks. The recorder's recording
    (:class:`~fleetbus.workers.store.recordings.RecordingStore`) is the system of record for the
    bus's traffic, every message as received; an event is in both, on purpose
    (``docs/decisions/0007-store-repositories.md``)."""

    @abc.abstractmethod
    async def store_batch(
        self, records: Sequence[EventRecord], at: datetime, *, urgent: bool = False
    ) -> StoredBatch:
        """A worker's batch, recorded: each record stamped with the mission its robot is recorded
        under now (a record that has one keeps it), written (:meth:`write_events`), and the sequence
        numbers it holds observed by the ledger (:meth:`observe_sequences`, at ``at``).

        The ledger sees a number once the store holds that event: inserted now, or stored before
        under the same message id. A reused number (another message id) is not the robot's event,
        so it is not observed. One unit of work: one transaction on SQLite; on MongoDB the three
        steps in turn, each idempotent.
        ``urgent``: someone waits on an event of the batch (a hazard): a backend may trade
        throughput for latency. Storing a batch registers no hazard on any backend: the hazard
        service does, in :meth:`~fleetbus.workers.store.hazards.CoordinationStore.hold_hazards`.
        """


@dataclass(frozen=True)
class Repositories:
    """The repositories of one database; open and close them together (``async with``)."""

    name: str
    """The backend: ``sqlite`` or ``mongodb``."""
    events: EventLog
    hazards: CoordinationStore
    """Hazards, their exchange with central, and the team (robots, their kind, localisation and
    service); a consumer takes the part it uses (``TeamStore``, ``HazardRegistry``, ``SiteHazardSync``)."""
    beacons: BeaconRegistry
    maps: MapStore
    missions: MissionStore
    channels: ChannelStore
    """Who is mounted on and checked in to which mission."""
    users: UserStore
    sessions: SessionStore
    """The users' login sessions (the console's and the API's tokens)."""
    discards: DiscardLog
    rejections: RejectionLog
    attempts: AttemptLog
    leases: LeaseStore
    statuses: StatusBoard
    housekeeping: Housekeeping
    sites: SiteRegistry
    """On central: which robots live at which site, and what each site forwarded; on a site, how
    new the downlink's newest word on each robot was."""
    alerts: AlertStore
    """The alerts raised for the operators, and who acknowledged each."""
    comments: CommentStore
    """Each mission's discussion."""
    opener: Callable[[], Awaitable[None]] = field(repr=False)
    """Connects and creates the tables or indexes (idempotent)."""
    closer: Callable[[], Awaitable[None]] = field(repr=False)
    again: Callable[[], Repositories] = field(repr=False)
    """Another connection to the same database, not yet opened (what a second process would have)."""
    any_loop: bool = False
    """Another thread's event loop may call these very repositories: SQLite's are (each call on a
    thread-safe connection, waiting for another's transaction without blocking any loop); a
    MongoDB client belongs to the loop it was opened on."""

    def for_another_loop(self) -> Repositories:
        """What a thread with an event loop of its own uses: these, or (not :attr:`any_loop`) a new
        connection to the same database, which that thread opens and closes."""
        return self if self.any_loop else self.again()

    async def open(self) -> None:
        await self.opener()

    async def close(self) -> None:
        await self.closer()

    async def __aenter__(self) -> Repositories:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()


class StoreSettings(Protocol):
    """What opening the stores reads of the settings: :class:`fleetbus.settings.Settings` has it,
    and so does what the recording process is handed (it keeps pydantic out of its memory)."""

    @property
    def mongodb_url(self) -> str | None: ...

    @property
    def sqlite_path(self) -> Path: ...

    @property
    def recording_path(self) -> Path: ...

    @property
    def field_indexes_max(self) -> int: ...


def repositories_for(settings: StoreSettings) -> Repositories:
    """The repositories the settings select (MongoDB when ``mongodb_url`` is set), not yet opened."""
    if settings.mongodb_url:
        from fleetbus.workers.store.mongo import mongo_repositories

        return mongo_repositories(settings.mongodb_url)
    from fleetbus.workers.store.sqlite import sqlite_repositories

    return sqlite_repositories(settings.sqlite_path)


@asynccontextmanager
async def open_repositories(settings: StoreSettings) -> AsyncIterator[Repositories]:
    """The settings' repositories, open for the block."""
    async with repositories_for(settings) as repositories:
        yield repositories


def run_with_repositories(settings: StoreSettings, operation: Callable[[Repositories], Awaitable[T]]) -> T:
    """For synchronous callers (commands, tests): open the repositories, run one operation, close them."""

    async def go() -> T:
        async with open_repositories(settings) as repositories:
            return await operation(repositories)

    return asyncio.run(go())
