"""The guide robot's beacon services: sightings from known robots, people likely stranded, the next goal.

A sighting is a ``beacon`` event (beacon id, RSSI, the robot's pose). The registry says where each
beacon is and what it marks; beacons heard within the recent window are where people are likely
stranded, and the guide's goal is the one first heard among those not visited yet.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime, timedelta, timezone
from typing import Any

from fleetbus.schemas.routing import EventType
from fleetbus.workers.rpc import Handler, ServiceError
from fleetbus.workers.store.base import EventQuery, EventStore
from fleetbus.workers.store.beacons import BeaconRegistry
from fleetbus.workers.store.team import TeamStore
from fleetbus.workers.validation import Accepted, Rejected, RejectReason

DEFAULT_WINDOW = timedelta(minutes=10)


def window_refusal(window: timedelta, limit: timedelta) -> str | None:
    """Why a look ``window`` back at the beacons is refused (it goes further than ``limit``), or None."""
    if window <= limit:
        return None
    asked, most = (f"{d.total_seconds() / 60:,.1f}".removesuffix(".0") for d in (window, limit))
    setting = "FLEETBUS_BEACON_WINDOW_MAX_MINUTES"
    return f"the beacons are looked at {most} minutes back at most ({setting}), not {asked}"


class KnownRobotsOnly:
    """Refuses beacon sightings from robots the team does not know (not registered with the store)."""

    def __init__(self, team: TeamStore) -> None:
        self._team = team

    async def check(self, accepted: Sequence[Accepted]) -> dict[int, Rejected]:
        sightings = [i for i, item in enumerate(accepted) if item.event.type is EventType.BEACON]
        if not sightings:
            return {}
        known = {robot.name for robot in await self._team.robots()}
        return {
            i: Rejected(
                RejectReason.UNKNOWN_ROBOT,
                f"beacon sighting from {accepted[i].event.robot_id!r}, which is not a registered robot "
                "(`fleetbus users add NAME --kind guide`)",
            )
            for i in sightings
            if accepted[i].event.robot_id not in known
        }


async def stranded(beacons: BeaconRegistry, events: EventStore, since: datetime) -> list[dict[str, Any]]:
    """Beacons heard since ``since``: where (registry and robot pose), when, by whom; first heard first."""
    registry = {beacon.beacon_id: beacon for beacon in await beacons.beacons()}
    seen: dict[str, dict[str, Any]] = {}
    for record in await events.find_events(EventQuery(type=EventType.BEACON.value, since=since)):
        beacon_id = record.body["beacon_id"]
        beacon = registry.get(beacon_id)
        entry = seen.setdefault(
            beacon_id,
            {
                "beacon_id": beacon_id,
                "label": beacon.label if beacon else None,
                "location": {"x": beacon.x, "y": beacon.y} if beacon else None,
                "visited_at": beacon.visited_at.isoformat() if beacon and beacon.visited_at else None,
                "first_seen": record.sent_at.isoformat(),
                "sightings": 0,
            },
        )
        entry.update(
            last_seen=record.sent_at.isoformat(),
            last_rssi=record.body["rssi"],
            seen_by=record.robot_id,
            robot_pose=record.body.get("pose"),
        )
        entry["sightings"] += 1
    return list(seen.values())


def beacon_services(beacons: BeaconRegistry, events: EventStore, max_window: timedelta) -> dict[str, Handler]:
    """``max_window``: how far back a look at the beacons may go (each sighting in it is read into
    memory; the setting ``beacon_window_max``)."""

    def window(params: dict[str, Any]) -> datetime:
        minutes = params.get("minutes", DEFAULT_WINDOW.total_seconds() / 60)
        if isinstance(minutes, bool) or not isinstance(minutes, (int, float)) or not 0 < minutes < math.inf:
            raise ServiceError(f"minutes must be a positive number, not {minutes!r}")
        if refusal := window_refusal(timedelta(minutes=minutes), max_window):
            raise ServiceError(refusal)
        return datetime.now(timezone.utc) - timedelta(minutes=minutes)

    def beacon_id(params: dict[str, Any]) -> str:
        value = params.get("beacon_id")
        if not isinstance(value, str) or not value:
            raise ServiceError(f"beacon_id must be a non-empty string, not {value!r}")
        return value

    async def info(caller: str, params: dict[str, Any]) -> Any:
        beacon = await beacons.get_beacon(beacon_id(params))
        if beacon is None:
            raise ServiceError(f"no beacon {params['beacon_id']!r} in the registry")
        return beacon.as_dict()

    async def stranded_people(caller: str, params: dict[str, Any]) -> Any:
        return await stranded(beacons, events, window(params))

    async def goal(caller: str, params: dict[str, Any]) -> Any:
        for entry in await stranded(beacons, events, window(params)):
            if entry["location"] is not None and entry["visited_at"] is None:
                return entry
        return None

    async def visited(caller: str, params: dict[str, Any]) -> Any:
        beacon = await beacons.mark_visited(beacon_id(params), datetime.now(timezone.utc))
        if beacon is None:
            raise ServiceError(f"no beacon {params['beacon_id']!r} in the registry")
        return beacon.as_dict()

    return {
        "beacon.info": info,
        "beacon.stranded": stranded_people,
        "beacon.goal": goal,
        "beacon.visited": visited,
    }
