"""A backend's store: every repository (:mod:`fleetbus.workers.store.repositories`) over one
database. Consumers never receive it whole: :class:`~fleetbus.workers.store.repositories.Repositories`
hands each the repositories it uses."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import datetime

from fleetbus.workers.store.attempts import AttemptLog
from fleetbus.workers.store.base import EventRecord, WriteResult
from fleetbus.workers.store.beacons import BeaconRegistry
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.discards import DiscardLog
from fleetbus.workers.store.hazards import CoordinationStore
from fleetbus.workers.store.housekeeping import Housekeeping
from fleetbus.workers.store.leases import LeaseStore
from fleetbus.workers.store.ledger import RobotEpoch
from fleetbus.workers.store.maps import MapStore
from fleetbus.workers.store.missions import MissionStore
from fleetbus.workers.store.rejections import RejectionLog
from fleetbus.workers.store.repositories import EventLog
from fleetbus.workers.store.statuses import StatusBoard
from fleetbus.workers.store.users import UserStore


class Store(
    EventLog,
    CoordinationStore,
    BeaconRegistry,
    MapStore,
    UserStore,
    MissionStore,
    ChannelStore,
    DiscardLog,
    LeaseStore,
    AttemptLog,
    RejectionLog,
    StatusBoard,
    Housekeeping,
):
    """Implemented by :class:`~workers.store.sqlite.SQLiteEventStore` and
    :class:`~workers.store.mongo.MongoEventStore`."""

    async def store_batch(
        self, records: Sequence[EventRecord], at: datetime, *, urgent: bool = False
    ) -> StoredBatch:
        """A worker's batch, recorded: each record stamped with the mission its robot is recorded
        under now (a record that has one keeps it), written (:meth:`write_events`), and the sequence
        numbers it holds observed by the ledger (:meth:`observe_sequences`, at ``at``).

        The ledger sees a number once the store holds that event: inserted now, or stored before
        under the same message id. A reused number (another message id) is not the robot's event,
        so it is not observed. Adapters that can do all of it in one transaction should (SQLite
        does); this default makes the three calls in turn, each idempotent. ``urgent``: someone
        waits on an event of the batch (a hazard): an adapter may trade throughput for latency.
        Storing a batch registers no hazard on any backend: the hazard service does, in
        :meth:`~fleetbus.workers.store.hazards.CoordinationStore.hold_hazards`.
        """
        missions = await self.recording_missions({record.robot_id for record in records})
        stamped = stamp_missions(records, missions)
        results = await self.write_events(stamped)
        await self.observe_sequences(held_sequences(stamped, results), at)
        return StoredBatch(stamped, results)


@dataclass(frozen=True)
class StoredBatch:
    records: list[EventRecord]
    """The batch's records as written: with their mission stamps."""
    results: list[WriteResult]
    """One per record, in order (see :meth:`EventStore.write_events`)."""


def stamp_missions(records: Sequence[EventRecord], missions: dict[str, str]) -> list[EventRecord]:
    return [
        replace(record, mission_id=missions[record.robot_id])
        if record.mission_id is None and record.robot_id in missions
        else record
        for record in records
    ]


def held_sequences(
    records: Sequence[EventRecord], results: Sequence[WriteResult]
) -> dict[RobotEpoch, list[int]]:
    """By robot and epoch, the numbers whose events the store holds after a write (not the reused ones)."""
    held: dict[RobotEpoch, list[int]] = {}
    for record, result in zip(records, results, strict=True):
        if result.inserted or result.stored_message_id == record.message_id:
            held.setdefault(RobotEpoch(record.robot_id, record.epoch), []).append(record.seq)
    return held
