"""The coordination state on every adapter: hazard ids, the held list, claims, localisation."""

from __future__ import annotations

import asyncio
from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.workers.store.beacons import Beacon
from fleetbus.workers.store.hazards import MOST_HAZARDS, HazardRefused, HazardState, NewHazard
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.team import gate
from tests.store.test_contract import record

T0 = datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc)
BODY = {"pose": {"x": 2.66, "y": 1.22}, "description": "Fire"}
EPOCH = "20210601T182526564Z-0a1b2c3d"
LATER = "20210601T190000000Z-4e5f6a7b"


async def test_ids_are_sequential_per_mission_and_idempotent(store: Repositories) -> None:
    first = await store.hazards.add_hazard("m1", "explorer1", EPOCH, 10, BODY, T0, held=False)
    second = await store.hazards.add_hazard("m1", "explorer1", EPOCH, 11, BODY, T0, held=False)
    other = await store.hazards.add_hazard("m2", "explorer1", EPOCH, 12, BODY, T0, held=False)
    again = await store.hazards.add_hazard("m1", "explorer1", EPOCH, 10, {"different": True}, T0, held=True)
    later = await store.hazards.add_hazard("m1", "explorer1", LATER, 10, BODY, T0, held=False)
    assert (first.hazard_id, second.hazard_id, other.hazard_id, later.hazard_id) == (1, 2, 1, 3)
    assert again == first, "the same event registers the same hazard once"
    assert (later.epoch, later.seq) == (LATER, 10), "the same number in another epoch is another event"
    assert first.event == BODY and first.state is HazardState.ANNOUNCED and first.received_at == T0


async def test_held_hazards_come_out_in_detection_order(store: Repositories) -> None:
    for seq in range(3):
        await store.hazards.add_hazard("m1", "explorer1", EPOCH, seq, {**BODY, "n": seq}, T0, held=True)
    held = await store.hazards.held_hazards("m1")
    assert [h.hazard_id for h in held] == [1, 2, 3]
    await store.hazards.mark_announced(held[:2], T0 + timedelta(seconds=5))
    assert [h.hazard_id for h in await store.hazards.held_hazards()] == [3]
    announced = await store.hazards.get_hazard("m1", 1)
    assert announced is not None and announced.state is HazardState.ANNOUNCED
    assert announced.announced_at == T0 + timedelta(seconds=5)


async def test_a_hazard_is_registered_by_holding_it_never_by_storing_its_event(store: Repositories) -> None:
    """One place says how a hazard is registered, the same on every backend: the hazard service's
    ``hold_hazards``; storing a batch (``store_batch``) registers none."""
    stored = await store.events.store_batch([record(seq=2, type="status"), record(seq=3)], T0, urgent=True)
    assert all(result.inserted for result in stored.results)
    assert await store.hazards.held_hazards() == [] and await store.hazards.open_hazards(None) == []
    hazard = NewHazard.of(stored.records[1])
    [held] = (await store.hazards.hold_hazards([hazard])).hazards
    assert (held.robot_id, held.seq, held.hazard_id, held.state) == ("explorer1", 3, 1, HazardState.HELD)
    assert held.event == hazard.event
    await store.events.store_batch(stored.records, T0, urgent=True)  # redelivered: stored before, nothing new
    assert (await store.hazards.hold_hazards([hazard])).hazards == [held]


async def test_holding_hazards_registers_them_once_and_tells_the_gate(store: Repositories) -> None:
    await store.hazards.register_robot("warden1", "warden")
    await store.hazards.register_robot("warden2", "warden")
    await store.hazards.set_localised("warden1", True, T0)
    first = NewHazard("m1", "explorer1", EPOCH, 10, BODY, T0)
    held = await store.hazards.hold_hazards([first, NewHazard("m2", "explorer1", EPOCH, 11, BODY, T0)])
    assert [(h.mission_id, h.hazard_id, h.state) for h in held.hazards] == [
        ("m1", 1, HazardState.HELD),
        ("m2", 1, HazardState.HELD),
    ]
    assert [w.name for w in held.wardens] == ["warden1", "warden2"]
    assert not gate(held.wardens).open, "warden2 is not localised"
    again = await store.hazards.hold_hazards([first])
    assert again.hazards == held.hazards, "the same event again is not a second hazard"
    await store.hazards.set_localised("warden2", True, T0)
    assert gate((await store.hazards.hold_hazards([])).wardens).open
    await store.hazards.mark_announced(held.hazards[:1], T0)
    assert [h.mission_id for h in (await store.hazards.hold_hazards([])).hazards] == ["m2"]


async def test_claim_reach_release_and_refusals(store: Repositories) -> None:
    await store.hazards.add_hazard("m1", "explorer1", EPOCH, 0, BODY, T0, held=False)
    await store.hazards.add_hazard("m1", "explorer1", EPOCH, 1, BODY, T0, held=True)
    claimed = await store.hazards.claim("m1", 1, "warden1", T0)
    assert (claimed.state, claimed.claimed_by) == (HazardState.CLAIMED, "warden1")
    with pytest.raises(HazardRefused, match="claimed by warden1"):
        await store.hazards.claim("m1", 1, "warden2", T0)
    with pytest.raises(HazardRefused, match="no hazard 9"):
        await store.hazards.claim("m1", 9, "warden2", T0)
    with pytest.raises(HazardRefused, match="held"):
        await store.hazards.claim("m1", 2, "warden2", T0)
    with pytest.raises(HazardRefused, match="claimed by warden1"):
        await store.hazards.mark_reached("m1", 1, "warden2", T0)
    released = await store.hazards.release("m1", 1, "warden1", T0)
    assert (released.state, released.claimed_by) == (HazardState.ANNOUNCED, None)
    await store.hazards.claim("m1", 1, "warden2", T0)
    reached = await store.hazards.mark_reached("m1", 1, "warden2", T0 + timedelta(seconds=30))
    assert reached.state is HazardState.REACHED and reached.reached_at == T0 + timedelta(seconds=30)
    assert [h.hazard_id for h in await store.hazards.open_hazards("m1")] == [1, 2]
    with pytest.raises(HazardRefused, match="claimed by warden2"):
        await store.hazards.mark_cleared("m1", 1, "warden1", T0)
    cleared = await store.hazards.mark_cleared("m1", 1, "warden2", T0 + timedelta(seconds=60))
    assert cleared.state is HazardState.CLEARED and cleared.cleared_at == T0 + timedelta(seconds=60)
    assert [h.hazard_id for h in await store.hazards.open_hazards("m1")] == [2]
    unchanged = await store.hazards.get_hazard("m1", 2)
    assert unchanged is not None and unchanged.state is HazardState.HELD


async def test_recent_hazards_are_every_hazard_newest_first_a_page_at_a_time(store: Repositories) -> None:
    """What the console's hazards page lists: cleared ones too, of every mission, newest first."""
    for seq, (mission, seconds) in enumerate([("m1", 0), ("m2", 10), ("m1", 20), ("m1", 30)]):
        at = T0 + timedelta(seconds=seconds)
        await store.hazards.add_hazard(mission, "explorer1", EPOCH, seq, BODY, at, held=False)
    await store.hazards.claim("m1", 1, "warden1", T0)
    await store.hazards.mark_reached("m1", 1, "warden1", T0)
    await store.hazards.mark_cleared("m1", 1, "warden1", T0)
    newest = await store.hazards.recent_hazards(3)
    assert [(h.mission_id, h.hazard_id) for h in newest] == [("m1", 3), ("m1", 2), ("m2", 1)]
    [oldest] = await store.hazards.recent_hazards(3, offset=3)
    assert (oldest.mission_id, oldest.hazard_id, oldest.state) == ("m1", 1, HazardState.CLEARED)
    assert await store.hazards.recent_hazards(3, offset=4) == []
    for past_every_row in (MOST_HAZARDS, MOST_HAZARDS + 1, 2**63, 2**100):  # past the stores' integers too
        assert await store.hazards.recent_hazards(3, offset=past_every_row) == []
    announced = await store.hazards.recent_hazards(2, state=HazardState.ANNOUNCED)
    assert [(h.mission_id, h.hazard_id) for h in announced] == [("m1", 3), ("m1", 2)]
    assert await store.hazards.hazard_counts() == {HazardState.ANNOUNCED: 3, HazardState.CLEARED: 1}


async def test_the_hazards_cleared_last_come_first_and_as_many_as_asked(store: Repositories) -> None:
    for seq in range(4):
        await store.hazards.add_hazard("m1", "explorer1", EPOCH, seq, BODY, T0, held=False)
    await store.hazards.add_hazard("m2", "explorer1", EPOCH, 9, BODY, T0, held=False)
    assert await store.hazards.cleared_hazards(10) == []
    for mission_id, hazard_id, minutes in (("m1", 2, 1), ("m2", 1, 3), ("m1", 4, 2), ("m1", 1, 4)):
        await store.hazards.claim(mission_id, hazard_id, "warden1", T0)
        await store.hazards.mark_reached(mission_id, hazard_id, "warden1", T0)
        await store.hazards.mark_cleared(mission_id, hazard_id, "warden1", T0 + timedelta(minutes=minutes))
    cleared = await store.hazards.cleared_hazards(3)
    assert [(h.mission_id, h.hazard_id) for h in cleared] == [("m1", 1), ("m2", 1), ("m1", 4)]
    assert all(h.state is HazardState.CLEARED for h in cleared)
    assert [h.hazard_id for h in await store.hazards.open_hazards("m1")] == [3], "still open"


async def test_two_claims_at_once_one_wins(store: Repositories) -> None:
    await store.hazards.add_hazard("m1", "explorer1", EPOCH, 0, BODY, T0, held=False)
    outcomes = await asyncio.gather(
        store.hazards.claim("m1", 1, "warden1", T0),
        store.hazards.claim("m1", 1, "warden2", T0),
        return_exceptions=True,
    )
    winners = [o for o in outcomes if not isinstance(o, Exception)]
    refusals = [o for o in outcomes if isinstance(o, HazardRefused)]
    assert len(winners) == 1 and len(refusals) == 1
    stored = await store.hazards.get_hazard("m1", 1)
    assert stored is not None and stored.claimed_by == winners[0].claimed_by


async def test_robot_registry_and_localisation(store: Repositories) -> None:
    await store.hazards.register_robot("warden1", "warden")
    await store.hazards.register_robot("warden2", "warden")
    await store.hazards.set_localised("warden1", True, T0)
    await store.hazards.set_localised(
        "warden1", False, T0 - timedelta(seconds=1)
    )  # late, older report: ignored
    await store.hazards.set_localised("guide1", True, T0)
    wardens = await store.hazards.robots("warden")
    assert [(r.name, r.localised) for r in wardens] == [("warden1", True), ("warden2", False)]
    assert {r.name: r.kind for r in await store.hazards.robots()} == {
        "guide1": None,
        "warden1": "warden",
        "warden2": "warden",
    }


async def test_beacon_registry(store: Repositories) -> None:
    await store.beacons.put_beacons([Beacon("b1", 1.0, 2.0, "room 101"), Beacon("b2", 5.5, -1.0, "stairs")])
    visited = await store.beacons.mark_visited("b1", T0)
    assert visited == Beacon("b1", 1.0, 2.0, "room 101", T0)
    await store.beacons.put_beacons([Beacon("b1", 1.5, 2.0, "room 101 east")])
    assert await store.beacons.get_beacon("b1") == Beacon("b1", 1.5, 2.0, "room 101 east", T0), (
        "an update keeps the visit"
    )
    assert [b.beacon_id for b in await store.beacons.beacons()] == ["b1", "b2"]
    assert await store.beacons.get_beacon("b9") is None
    assert await store.beacons.mark_visited("b9", T0) is None


async def test_the_hazards_of_a_window_are_those_received_before_its_end_not_cleared_before_its_start(
    store: Repositories,
) -> None:
    """The live map's past: what existed at some moment of the window, with the times of its steps."""
    for seq, seconds in enumerate((0, 0, 5, 20)):  # hazards 1 to 4, received at these seconds
        await store.hazards.add_hazard(
            "m1", "explorer1", EPOCH, seq, BODY, T0 + timedelta(seconds=seconds), held=False
        )
    for hazard_id, cleared_after in ((1, 10), (2, 2)):
        await store.hazards.claim("m1", hazard_id, "warden1", T0 + timedelta(seconds=1))
        await store.hazards.mark_reached("m1", hazard_id, "warden1", T0 + timedelta(seconds=1))
        await store.hazards.mark_cleared("m1", hazard_id, "warden1", T0 + timedelta(seconds=cleared_after))
    since, until = T0 + timedelta(seconds=3), T0 + timedelta(seconds=15)
    # 3 open since second 5; 1 cleared at 10, inside; 2 cleared at 2, before; 4 received at 20, after
    during = await store.hazards.hazards_during(since, until, 10)
    assert [h.hazard_id for h in during] == [3, 1]
    assert during[1].claimed_at == T0 + timedelta(seconds=1)
    assert during[1].cleared_at == T0 + timedelta(seconds=10)
    assert [h.hazard_id for h in await store.hazards.hazards_during(since, until, 1)] == [3]
    later = await store.hazards.hazards_during(T0 + timedelta(seconds=30), T0 + timedelta(seconds=31), 10)
    assert [h.hazard_id for h in later] == [4, 3], "the open ones, however long ago received"
