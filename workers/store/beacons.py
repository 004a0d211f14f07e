"""The beacon registry: where each BLE beacon is and what it marks, and whether a guide visited it."""

from __future__ import annotations

import abc
from dataclasses import dataclass
from datetime import datetime
from typing import Any


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
