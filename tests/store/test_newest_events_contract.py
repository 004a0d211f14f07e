"""Each robot's newest event (of a type, or any), for a page of the team in one query."""

from __future__ import annotations

from datetime import timedelta

from fleetbus.workers.store.base import EventQuery
from fleetbus.workers.store.repositories import Repositories
from tests.store.test_contract import T0, record


async def test_each_robots_newest_event_and_newest_of_a_type_in_one_call(store: Repositories) -> None:
    later = T0 + timedelta(seconds=5)
    old_status = record("explorer1", 0, "status", T0, battery_percent=80.0, outbox_dropped={"status": 3})
    new_status = record("explorer1", 1, "status", later, battery_percent=79.0, outbox_dropped={"status": 7})
    hazard = record("explorer1", 2, "hazard", later + timedelta(seconds=1))
    localised = record("warden1", 0, "localisation", T0, localised=True)
    await store.events.write_events([old_status, new_status, hazard, localised])
    robots = ["explorer1", "warden1", "guide1"]
    assert await store.events.newest_events(robots) == {"explorer1": hazard, "warden1": localised}
    assert await store.events.newest_events(robots, "status") == {"explorer1": new_status}
    assert await store.events.newest_events([]) == {}


async def test_each_robots_newest_event_of_a_type_within_a_window(store: Repositories) -> None:
    """The live map's sampled trails: each robot's last pose of a step, ``until`` excluded."""
    poses = [
        record("explorer1", seq, "localisation", T0 + timedelta(seconds=seq), localised=True)
        for seq in range(6)
    ]
    other = record("warden1", 0, "localisation", T0 + timedelta(seconds=1), localised=True)
    status = record("warden1", 1, "status", T0 + timedelta(seconds=2), battery_percent=50.0)
    await store.events.write_events([*poses, other, status])
    robots = ["explorer1", "warden1"]
    step = {"since": T0 + timedelta(seconds=1), "until": T0 + timedelta(seconds=3)}
    assert await store.events.newest_events(robots, "localisation", **step) == {
        "explorer1": poses[2],
        "warden1": other,
    }
    assert await store.events.newest_events(robots, since=T0 + timedelta(seconds=2)) == {
        "explorer1": poses[5],
        "warden1": status,
    }
    assert await store.events.newest_events(robots, "localisation", until=T0) == {}


async def test_whether_a_window_holds_more_events_than_a_number(store: Repositories) -> None:
    poses = [
        record("explorer1", seq, "localisation", T0 + timedelta(seconds=seq), localised=True)
        for seq in range(6)
    ]
    status = record("explorer1", 6, "status", T0 + timedelta(seconds=2), battery_percent=50.0)
    await store.events.write_events([*poses, status])
    window = EventQuery(type="localisation", since=T0 + timedelta(seconds=1), until=T0 + timedelta(seconds=5))
    assert await store.events.holds_more_events(window, 3)  # seconds 1 to 4
    assert not await store.events.holds_more_events(window, 4)
    assert await store.events.holds_more_events(EventQuery(), 6)  # the status too
    assert not await store.events.holds_more_events(EventQuery(), 7)
