"""The team the hazard gate follows, on every adapter: out of service and back (with who and when),
the catch-up a warden put back is owed, removal, why a hazard stays held, and when each robot was
last heard from."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.hazards import CLAIM_WHILE_OPEN, HazardState
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.team import Localisation
from fleetbus.workers.team import NO_WARDEN, gate, read_team, why_closed
from tests.store.test_contract import EPOCH, record

T0 = datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc)
BODY = {"pose": {"x": 2.66, "y": 1.22}, "description": "Fire"}


async def test_a_warden_out_of_service_and_back_is_on_record_and_owed_a_catch_up(store: Repositories) -> None:
    await store.hazards.register_robot("warden1", "warden")
    await store.hazards.register_robot("warden2", "warden")
    await store.hazards.set_localised("warden2", True, T0)
    [first, second] = await store.hazards.robots("warden")
    assert (first.in_service, first.catch_up, first.service_changed_by) == (True, False, None)
    assert not gate([first, second]).open, "warden1 is not localised"

    out = await store.hazards.set_in_service("warden1", False, "ops1", T0)
    assert out is not None
    assert (out.in_service, out.catch_up, out.service_changed_by, out.service_changed_at) == (
        False,
        False,
        "ops1",
        T0,
    )
    wardens = (await store.hazards.hold_hazards(())).wardens
    assert [(w.name, w.in_service) for w in wardens] == [("warden1", False), ("warden2", True)]
    assert gate(wardens).open, "warden1 out of service no longer holds the gate"

    back = await store.hazards.set_in_service("warden1", True, "ops2", T0 + timedelta(minutes=5))
    assert back is not None and (back.in_service, back.catch_up, back.service_changed_by) == (
        True,
        True,
        "ops2",
    )
    again = await store.hazards.set_in_service("warden1", True, "ops3", T0 + timedelta(minutes=6))
    assert again is not None and again.catch_up, "still owed until the service caught it up"
    await store.hazards.caught_up("warden1")
    [caught] = [r for r in await store.hazards.robots() if r.name == "warden1"]
    assert (caught.in_service, caught.catch_up, caught.service_changed_by) == (True, False, "ops3")
    already_in = await store.hazards.set_in_service("warden1", True, "ops1", T0 + timedelta(minutes=7))
    assert already_in is not None and not already_in.catch_up, "put back while in service: owed nothing"
    assert await store.hazards.set_in_service("warden9", False, "ops1", T0) is None


async def test_a_removed_robot_leaves_the_team(store: Repositories) -> None:
    await store.hazards.register_robot("warden1", "warden")
    await store.hazards.register_robot("explorer1", "explorer")
    assert await store.hazards.remove_robot("warden1")
    assert not await store.hazards.remove_robot("warden1"), "not in the team any more"
    assert [r.name for r in await store.hazards.robots()] == ["explorer1"]
    state = gate((await store.hazards.hold_hazards(())).wardens)
    assert not state.open and why_closed(state, {}, T0) == NO_WARDEN


async def test_a_hazard_no_warden_took_stays_held_with_the_reason_until_announced(
    store: Repositories,
) -> None:
    for seq in range(3):
        await store.hazards.add_hazard("m1", "explorer1", EPOCH, seq, BODY, T0, held=True)
    announced = await store.hazards.add_hazard("m1", "explorer1", EPOCH, 9, BODY, T0, held=False)
    held = await store.hazards.held_hazards()
    await store.hazards.note_held([*held[1:], announced], "no inbox for warden1")
    assert [(h.hazard_id, h.held_reason) for h in await store.hazards.held_hazards()] == [
        (1, None),
        (2, "no inbox for warden1"),
        (3, "no inbox for warden1"),
    ]
    assert (await store.hazards.get_hazard("m1", 4)) == announced, "an announced hazard is not touched"
    await store.hazards.mark_announced(held, T0)
    cleared = await store.hazards.get_hazard("m1", 2)
    assert cleared is not None and (cleared.state, cleared.held_reason) == (HazardState.ANNOUNCED, None)


async def test_open_hazards_of_every_mission_in_mission_then_id_order(store: Repositories) -> None:
    await store.hazards.add_hazard("m2", "explorer1", EPOCH, 0, BODY, T0, held=False)
    await store.hazards.add_hazard("m1", "explorer1", EPOCH, 1, BODY, T0, held=True)
    await store.hazards.add_hazard("m1", "explorer1", EPOCH, 2, BODY, T0, held=False)
    await store.hazards.add_hazard("m2", "explorer1", EPOCH, 3, BODY, T0, held=False)
    assert [(h.mission_id, h.hazard_id) for h in await store.hazards.open_hazards(None)] == [
        ("m1", 1),
        ("m1", 2),
        ("m2", 1),
        ("m2", 2),
    ]


async def test_the_team_says_when_each_robot_was_last_heard_from_and_who_is_stale(
    store: Repositories,
) -> None:
    for name, kind in (("explorer1", "explorer"), ("warden1", "warden"), ("guide1", "guide")):
        await store.hazards.register_robot(name, kind)
    await store.hazards.set_in_service("warden1", False, "ops1", T0)
    now = T0 + timedelta(minutes=10)
    # explorer1: an old status sent last, received after a newer hazard (its resync after an outage)
    await store.events.write_events(
        [
            record("explorer1", 0, "hazard", at=now - timedelta(minutes=8)),
            replace(record("explorer1", 1, "status", at=now - timedelta(seconds=20)), body={"battery": 80}),
            record("warden1", 0, "localisation", at=now - timedelta(minutes=5)),
        ]
    )
    team = {
        member.robot.name: member
        for member in await read_team(store.hazards, store.events, now, timedelta(minutes=1))
    }
    assert team["explorer1"].last_seen == now - timedelta(seconds=20) + timedelta(microseconds=1234)
    assert (team["explorer1"].stale, team["warden1"].stale, team["guide1"].stale) == (False, True, True)
    assert team["guide1"].last_seen is None, "never heard from"
    assert [(name, m.counts_for_gate) for name, m in sorted(team.items())] == [
        ("explorer1", False),
        ("guide1", False),
        ("warden1", False),
    ], "warden1 is out of service"
    assert team["warden1"].as_dict()["service_changed_by"] == "ops1"


async def test_a_hazard_claimed_on_its_way_keeps_its_claim_when_marked_announced(store: Repositories) -> None:
    first = await store.hazards.add_hazard("m1", "explorer1", EPOCH, 0, BODY, T0, held=True)
    claimed = await store.hazards.apply_transition(
        "m1", 1, "warden1", CLAIM_WHILE_OPEN, T0 + timedelta(seconds=1)
    )
    assert (claimed.state, claimed.claimed_by, claimed.announced_at) == (HazardState.CLAIMED, "warden1", None)
    waiting = await store.hazards.hold_hazards(())
    assert [(h.hazard_id, h.state) for h in waiting.hazards] == [(1, HazardState.CLAIMED)], (
        "until marked, the other wardens may not have their copy: it is announced again, claimed"
    )
    await store.hazards.mark_announced([first], T0)
    assert (await store.hazards.hold_hazards(())).hazards == []
    marked = await store.hazards.get_hazard("m1", 1)
    assert marked is not None and (marked.state, marked.claimed_by, marked.announced_at) == (
        HazardState.CLAIMED,
        "warden1",
        T0,
    )


async def test_a_batch_of_localisations_is_applied_in_order_and_an_older_report_changes_nothing(
    store: Repositories,
) -> None:
    await store.hazards.register_robot("warden1", "warden")
    await store.hazards.set_localisations(
        [
            Localisation("warden1", True, T0 + timedelta(seconds=2)),
            Localisation("warden1", False, T0 + timedelta(seconds=1)),  # sent before, came after
            Localisation("guide1", False, T0),  # not registered: recorded without a kind
            Localisation("guide1", True, T0 + timedelta(seconds=3)),
        ]
    )
    robots = {robot.name: robot for robot in await store.hazards.robots()}
    assert (robots["warden1"].localised, robots["warden1"].updated_at, robots["warden1"].kind) == (
        True,
        T0 + timedelta(seconds=2),
        "warden",
    )
    assert (robots["guide1"].localised, robots["guide1"].updated_at, robots["guide1"].kind) == (
        True,
        T0 + timedelta(seconds=3),
        None,
    )
    await store.hazards.set_localisations([])  # nothing to write: no transaction
    await store.hazards.set_localised("warden1", False, T0 + timedelta(seconds=4))
    assert not {robot.name: robot for robot in await store.hazards.robots()}["warden1"].localised
