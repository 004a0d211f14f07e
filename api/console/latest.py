"""The newest of each robot, as the console shows it: when it was last heard from, its newest
status (battery) and its newest pose, kept in memory.

Read from the store on every refresh, these would cost three queries per robot (100 robots: 300
queries every half second). Instead the robots are read from the store once, the first time a
page shows them (:meth:`Latest.seed`: three queries for all of them), and from then on follow
the live feed's batches (:meth:`Feed.watch`), which carry everything the store received since.
Values only move forward (the newest wins), so it does not matter whether the store's answer or
a batch arrives first.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Collection
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from fastapi import Request

from fleetbus.api.services.stored_events import EventRecord, StoredEvents
from fleetbus.schemas.routing import EventType
from fleetbus.workers.telemetry import battery_of

#: The events that say where their robot is.
POSE_TYPES = (EventType.STATUS.value, EventType.LOCALISATION.value)


@dataclass(frozen=True)
class Pose:
    x: float
    y: float
    yaw: float
    """Heading in radians, counter-clockwise from the map's x axis."""
    at: datetime
    """When the robot sent it."""
    type: str
    """The event that reported it (status or localisation)."""

    @classmethod
    def of(cls, record: EventRecord) -> Pose | None:
        pose = record.body.get("pose")
        if not isinstance(pose, dict):
            return None
        return cls(
            float(pose["x"]),
            float(pose["y"]),
            _yaw(pose.get("orientation") or {}),
            record.sent_at,
            record.type,
        )

    @property
    def heading_degrees(self) -> float:
        return math.degrees(self.yaw)


def _yaw(q: dict[str, Any]) -> float:
    """The rotation about z of a quaternion (ROS's ``tf.transformations`` convention)."""
    x, y, z, w = (float(q.get(k, d)) for k, d in (("x", 0.0), ("y", 0.0), ("z", 0.0), ("w", 1.0)))
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


@dataclass
class RobotLatest:
    last_seen: datetime | None = None
    """When the newest event of any type arrived."""
    status: EventRecord | None = None
    pose: Pose | None = None

    @property
    def battery(self) -> float | None:
        return None if self.status is None else battery_of(self.status.body)

    def observe(self, record: EventRecord) -> None:
        if self.last_seen is None or record.received_at > self.last_seen:
            self.last_seen = record.received_at
        if record.type == EventType.STATUS.value and (
            self.status is None or record.sent_at > self.status.sent_at
        ):
            self.status = record
        if record.type in POSE_TYPES and (self.pose is None or record.sent_at > self.pose.at):
            self.pose = Pose.of(record) or self.pose


class Latest:
    """Every robot's newest values, for every page of one API process."""

    def __init__(self, events: StoredEvents) -> None:
        self._events = events
        self._robots: dict[str, RobotLatest] = {}
        self._seeded: set[str] = set()
        self._lock = asyncio.Lock()

    def observe(self, records: list[EventRecord]) -> None:
        """A batch of the feed (:meth:`Feed.watch`)."""
        for record in records:
            self._robots.setdefault(record.robot_id, RobotLatest()).observe(record)

    def of(self, robot: str) -> RobotLatest:
        return self._robots.get(robot) or RobotLatest()

    def last_seen(self) -> dict[str, datetime]:
        return {name: robot.last_seen for name, robot in self._robots.items() if robot.last_seen}

    async def seed(self, team: Collection[str]) -> bool:
        """Read from the store, once each, the robots of ``team`` not read yet (True if any was);
        forget robots no longer in the team, so memory is bounded by the team's size."""
        async with self._lock:
            for gone in set(self._robots) - set(team):
                del self._robots[gone]
            self._seeded &= set(team)
            new = sorted(set(team) - self._seeded)
            if new:
                # three queries for all of them: the newest event of any type, status, localisation
                for type in (None, *POSE_TYPES):
                    self.observe(list((await self._events.newest_of(new, type)).values()))
                self._seeded.update(new)
            return bool(new)


def latest_for(request: Request) -> Latest:
    """The process's :class:`Latest`, following its feed from the first page that asks."""
    state = request.app.state
    if getattr(state, "latest", None) is None:
        state.latest = Latest(state.service.events)
        state.feed.watch(state.latest.observe)
    return state.latest
