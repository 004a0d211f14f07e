"""The beacon registry: where each BLE beacon is and what it marks, and whether a guide visited it."""

from __future__ import annotations

import abc
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from fleetbus.workers.store.port import REAL, TEXT, TIME, Database, Schema


@dataclass(frozen=True)
class Beacon:
    beacon_id: str
    x: float
    y: float
    label: str
    visited_at: datetime | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "beacon_id": self.beacon_id,
            "x": self.x,
            "y": self.y,
            "label": self.label,
            "visited_at": self.visited_at.isoformat() if self.visited_at else None,
        }


class BeaconRegistry(abc.ABC):
    @abc.abstractmethod
    async def put_beacons(self, beacons: list[Beacon]) -> None:
        """Add or update beacons (their visit state is kept)."""

    @abc.abstractmethod
    async def beacons(self) -> list[Beacon]: ...

    @abc.abstractmethod
    async def get_beacon(self, beacon_id: str) -> Beacon | None: ...

    @abc.abstractmethod
    async def mark_visited(self, beacon_id: str, at: datetime) -> Beacon | None:
        """Record that a guide reached the beacon; None if it is not registered."""


BEACONS = Schema(
    "beacons",
    {"beacon_id": TEXT, "x": REAL, "y": REAL, "label": TEXT, "visited_at": TIME.maybe},
    key=("beacon_id",),
)


class Beacons(BeaconRegistry):
    def __init__(self, database: Database) -> None:
        self._database = database
        self._beacons = database.collection(BEACONS)

    async def put_beacons(self, beacons: list[Beacon]) -> None:
        async def put() -> None:
            for beacon in beacons:
                await self._beacons.put(beacon.__dict__, overwrite=["x", "y", "label"])

        await self._database.transaction(put)

    async def beacons(self) -> list[Beacon]:
        return [Beacon(**doc) for doc in await self._beacons.find(order=["beacon_id"])]

    async def get_beacon(self, beacon_id: str) -> Beacon | None:
        doc = await self._beacons.get(beacon_id)
        return Beacon(**doc) if doc else None

    async def mark_visited(self, beacon_id: str, at: datetime) -> Beacon | None:
        async def mark() -> Beacon | None:
            await self._beacons.update({"beacon_id": beacon_id}, {"visited_at": at})
            return await self.get_beacon(beacon_id)

        return await self._database.transaction(mark)
