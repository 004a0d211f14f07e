"""Each robot's trail over a window: the poses its stored ``localisation`` events reported, oldest
first, as the live map draws them (and replays them under its time slider).

One store read, bounded: the newest :data:`TRAIL_POINTS` localisations of the window; when the
window holds more, the answer says so (``truncated``) and starts where its points start."""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any

from fleetbus.api.console.latest import Pose
from fleetbus.api.services.stored_events import StoredEvents
from fleetbus.schemas.routing import EventType

#: At most this many poses in one answer (all robots together).
TRAIL_POINTS = 20_000
#: The windows the map offers, in minutes.
WINDOWS = (10, 60, 360, 1440)


async def trails(events: StoredEvents, until: datetime, window: timedelta) -> dict[str, Any]:
    """``{"since", "until", "truncated", "robots": {name: [[ms, x, y, heading°], ...]}}``: each
    robot's localised poses sent in [until - window, until), oldest first; times in milliseconds
    since the epoch (UTC)."""
    since = until - window
    found = await events.sent_between(EventType.LOCALISATION.value, since, until, TRAIL_POINTS + 1)
    truncated = len(found) > TRAIL_POINTS
    robots: dict[str, list[list[float]]] = {}
    for record in reversed(found[:TRAIL_POINTS]):
        pose = Pose.of(record)
        if pose is None:
            continue
        at = round(record.sent_at.timestamp() * 1000)
        robots.setdefault(record.robot_id, []).append([at, pose.x, pose.y, round(pose.heading_degrees, 1)])
    start = found[TRAIL_POINTS - 1].sent_at if truncated else since
    return {
        "since": round(start.timestamp() * 1000),
        "until": round(until.timestamp() * 1000),
        "truncated": truncated,
        "robots": robots,
    }
