"""Each robot's newest event (of a type, or any), for a page of the team in one query."""

from __future__ import annotations

from datetime import timedelta

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
