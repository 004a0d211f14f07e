"""Each robot's trail over a window: the poses its stored ``status`` and ``localisation`` events
reported (the same events its marker on the map follows), oldest first, as the live map draws them
(and replays them under its time slider).

One answer reads at most ``points`` poses, however big the team and the window (the setting
``FLEETBUS_CONSOLE_TRAIL_POINTS``). When the window holds no more, it is every pose. When it holds
more, the window is cut into equal steps, as many as the budget gives each robot of the team and
each pose type, and each robot's trail is its last pose of each step: the whole window at a coarser
grain, down to the robot's newest pose, where a lost robot was last. That is one store query a step
and pose type, each an index seek for each robot, so the cost follows the budget, not the number of
poses stored."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from datetime import datetime, timedelta
from typing import Any

from fleetbus.api.console.latest import POSE_TYPES, Pose
from fleetbus.api.services.hazards import Hazard
from fleetbus.api.services.stored_events import EventRecord, StoredEvents

#: The windows the map offers, in minutes.
WINDOWS = (10, 60, 360, 1440)
#: A sampled trail keeps at least this many poses of each robot (its first and its newest), however
#: many robots share the budget.
MIN_STEPS = 2


async def trails(
    events: StoredEvents, robots: Sequence[str], until: datetime, window: timedelta, points: int
) -> dict[str, Any]:
    """``{"since", "until", "step", "robots": {name: [[ms, x, y, heading°], ...]}}``: each robot's
    poses sent in [until - window, until), oldest first; times in milliseconds since the epoch
    (UTC). ``step`` is 0 when every pose is there, else the steps' length in milliseconds (each
    robot's last pose of each step is there)."""
    since = until - window
    step = timedelta(0)
    found = await _every_pose(events, since, until, points)
    if found is None:
        # a step reads each robot's newest pose of each type: the reads stay within the budget
        steps = max(MIN_STEPS, points // max(len(robots) * len(POSE_TYPES), 1))
        step = window / steps
        found = await _last_of_each_step(events, robots, since, until, steps)
    return {
        "since": _ms(since),
        "until": _ms(until),
        "step": round(step.total_seconds() * 1000),
        "robots": _poses_by_robot(found),
    }


async def _every_pose(
    events: StoredEvents, since: datetime, until: datetime, points: int
) -> list[EventRecord] | None:
    """Every event of the pose types sent in the window, or None when there are more than ``points``
    (known from the index before any is read)."""
    found: list[EventRecord] = []
    for type in POSE_TYPES:
        room = points - len(found)
        if await events.more_sent_between(type, since, until, room):
            return None
        found += await events.sent_between(type, since, until, room) if room else []
    return found


async def _last_of_each_step(
    events: StoredEvents, robots: Sequence[str], since: datetime, until: datetime, steps: int
) -> list[EventRecord]:
    found: list[EventRecord] = []
    start = since
    for number in range(1, steps + 1):
        end = until if number == steps else since + (until - since) * number / steps
        newest: dict[str, EventRecord] = {}
        for type in POSE_TYPES:
            for robot, record in (await events.newest_of(robots, type, since=start, until=end)).items():
                if Pose.of(record) is not None and (
                    robot not in newest or record.sent_at > newest[robot].sent_at
                ):
                    newest[robot] = record
        found += newest.values()
        start = end
    return found


def _poses_by_robot(found: Iterable[EventRecord]) -> dict[str, list[list[float]]]:
    robots: dict[str, list[list[float]]] = {}
    for record in sorted(found, key=lambda record: (record.sent_at, record.seq)):
        pose = Pose.of(record)
        if pose is not None:
            point = [_ms(record.sent_at), pose.x, pose.y, round(pose.heading_degrees, 1)]
            robots.setdefault(record.robot_id, []).append(point)
    return robots


def where_seen(body: dict[str, Any]) -> dict[str, Any] | None:
    """Where a hazard event's robot saw it (the body's pose), if the body says."""
    pose = body.get("pose")
    return pose if isinstance(pose, dict) and "x" in pose and "y" in pose else None


def position(hazard: Hazard) -> dict[str, Any] | None:
    """Where the robot saw the hazard (its event's pose), if it says."""
    return where_seen(hazard.event.get("body", {}))


def hazard_times(hazards: Iterable[Hazard]) -> list[dict[str, Any]]:
    """Each hazard that says where it was, with the times of its steps (ms since the epoch, or
    None), from which the map shows its state at any moment: held from ``received``, then
    announced, claimed, reached, and gone once ``cleared``."""
    found = []
    for hazard in hazards:
        at = position(hazard)
        if at is None:
            continue
        steps = {
            "received": hazard.received_at,
            "announced": hazard.announced_at,
            "claimed": hazard.claimed_at,
            "reached": hazard.reached_at,
            "cleared": hazard.cleared_at,
        }
        found.append(
            {
                "id": f"{hazard.mission_id}-{hazard.hazard_id}",
                "label": hazard.hazard_id,
                "x": float(at["x"]),
                "y": float(at["y"]),
                "description": str(hazard.event.get("body", {}).get("description", "")),
                **{step: None if time is None else _ms(time) for step, time in steps.items()},
            }
        )
    return found


def _ms(at: datetime) -> int:
    return round(at.timestamp() * 1000)
