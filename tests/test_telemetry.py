"""Telemetry: stored and queryable by robot and time; a low battery warns the operators once per drop."""

from __future__ import annotations

from datetime import datetime, timezone

from fleetbus.broker.accounts import Role
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventQuery
from tests.factories import status
from tests.support import Bus, notifications_until, wait_for


def test_battery_crossing_below_threshold_notifies_operators_once_per_drop(bus: Bus) -> None:
    guide = bus.robot(bus.add("guide1", kind=RobotKind.GUIDE))
    operator = bus.robot(bus.add("ops1", role=Role.OPERATOR))
    levels = [50, 15, 10, 30, 12, 11]  # threshold 20: drops below at 15 and at 12
    with bus.worker():
        for level in levels:  # one at a time, so each is its own batch as in the field
            guide.publish("status", status(level))
        # a third drop after them: its warning comes after any of theirs (one robot's statuses are
        # handled in order), so the warnings before it are all there were
        guide.publish("status", status(60))
        sentinel = guide.publish("status", status(5))
        notes = notifications_until(operator, lambda note: note.event == sentinel)
    assert [n.event.body.battery_percent for n in notes] == [15, 12, 5]
    assert {n.topic.value for n in notes} == {"battery"}


def test_telemetry_queries_by_robot_and_time(bus: Bus) -> None:
    guide = bus.robot(bus.add("guide1", kind=RobotKind.GUIDE))
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    with bus.worker():
        before = datetime.now(timezone.utc)
        guide.publish_many([("status", {**status(80), "current_waypoint": f"wp{i}"}) for i in range(5)])
        middle = datetime.now(timezone.utc)
        guide.publish_many([("status", status(70)) for _ in range(3)])
        explorer.publish("status", status(60))
        wait_for(lambda: bus.count("status") == 9, what="9 status events")
    first = bus.find(EventQuery(type="status", robot_id="guide1", since=before, until=middle))
    assert [r.body["current_waypoint"] for r in first] == [f"wp{i}" for i in range(5)]
    assert all(r.body["processing_rate_hz"] == 10.0 for r in first)
    assert len(bus.find(EventQuery(type="status", robot_id="guide1", since=middle))) == 3
