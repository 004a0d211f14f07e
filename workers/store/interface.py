"""How a worker's batch is stored: stamped with its missions, written, seen by the ledger."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from fleetbus.workers.store.base import EventRecord, WriteResult
from fleetbus.workers.store.ledger import RobotEpoch


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


def numbers_of(records: Sequence[EventRecord]) -> dict[RobotEpoch, list[int]]:
    """The records' sequence numbers by robot and epoch."""
    numbers: dict[RobotEpoch, list[int]] = {}
    for record in records:
        numbers.setdefault(RobotEpoch(record.robot_id, record.epoch), []).append(record.seq)
    return numbers


def held_sequences(
    records: Sequence[EventRecord], results: Sequence[WriteResult]
) -> dict[RobotEpoch, list[int]]:
    """By robot and epoch, the numbers whose events the store holds after a write (not the reused ones)."""
    return numbers_of(
        [record for record, result in zip(records, results, strict=True) if result.holds(record)]
    )
