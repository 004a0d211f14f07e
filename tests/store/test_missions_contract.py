"""Missions on every adapter: numbering, plans only in planning, atomic state changes, history."""

from __future__ import annotations

import asyncio
from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.schemas.missions import MissionState
from fleetbus.workers.store.missions import MissionConflict
from fleetbus.workers.store.repositories import Repositories
from tests.store.second import second_connection

T0 = datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc)
PLAN = {"geofence": {"frame_id": "map", "polygon": [{"x": 0, "y": 0}, {"x": 10, "y": 0}, {"x": 0, "y": 10}]}}
S = MissionState


async def test_missions_are_numbered_and_round_trip(store: Repositories) -> None:
    first = await store.missions.create_mission("survey", "Quay wall", "client1", PLAN, T0)
    second = await store.missions.create_mission("hazard-response", "Fire", "client2", {}, T0)
    assert (first.mission_id, first.number, second.mission_id) == ("m-1", 1, "m-2")
    assert first.state is S.PLANNING and first.plan == PLAN and first.created_at == T0
    assert await store.missions.get_mission("m-1") == first
    assert await store.missions.get_mission("m-9") is None
    assert [m.mission_id for m in await store.missions.missions()] == ["m-1", "m-2"]
    assert [m.mission_id for m in await store.missions.missions(owner="client2")] == ["m-2"]


async def test_the_tenth_mission_sorts_after_the_ninth(store: Repositories) -> None:
    for i in range(10):
        await store.missions.create_mission("survey", f"mission {i}", "client1", {}, T0)
    assert [m.number for m in await store.missions.missions()] == list(range(1, 11))


async def test_plans_change_only_in_the_expected_state(store: Repositories) -> None:
    mission = await store.missions.create_mission("survey", "Quay wall", "client1", {}, T0)
    later = T0 + timedelta(seconds=1)
    updated = await store.missions.update_plan(mission.mission_id, PLAN, S.PLANNING, later)
    assert updated.plan == PLAN and updated.updated_at == later
    await store.missions.transition_mission(mission.mission_id, S.PLANNING, S.IN_PROGRESS, "super1", later)
    with pytest.raises(MissionConflict, match="is in_progress") as refused:
        await store.missions.update_plan(mission.mission_id, {}, S.PLANNING, later)
    assert refused.value.current is not None and refused.value.current.plan == PLAN


async def test_a_transition_from_the_wrong_state_changes_nothing(store: Repositories) -> None:
    mission = await store.missions.create_mission("survey", "Quay wall", "client1", {}, T0)
    with pytest.raises(MissionConflict) as refused:
        await store.missions.transition_mission(mission.mission_id, S.IN_PROGRESS, S.REVIEWING, "super1", T0)
    assert refused.value.current == mission
    with pytest.raises(MissionConflict, match="no mission 'm-404'"):
        await store.missions.transition_mission("m-404", S.PLANNING, S.IN_PROGRESS, "super1", T0)
    assert await store.missions.get_mission(mission.mission_id) == mission
    assert len(await store.missions.mission_history(mission.mission_id)) == 1


async def test_of_two_concurrent_transitions_one_wins(store: Repositories) -> None:
    mission = await store.missions.create_mission("hazard-response", "Fire", "client1", {}, T0)
    async with second_connection(store) as other:
        results = await asyncio.gather(
            store.missions.transition_mission(mission.mission_id, S.PLANNING, S.FILED, "planner1", T0),
            other.missions.transition_mission(mission.mission_id, S.PLANNING, S.CLOSED, "client1", T0),
            return_exceptions=True,
        )
    winners = [r for r in results if not isinstance(r, BaseException)]
    losers = [r for r in results if isinstance(r, MissionConflict)]
    assert len(winners) == 1 and len(losers) == 1, results
    assert losers[0].current is not None and losers[0].current.state is winners[0].state
    history = await store.missions.mission_history(mission.mission_id)
    assert [(h.source, h.target) for h in history] == [(None, S.PLANNING), (S.PLANNING, winners[0].state)]


async def test_history_records_who_and_when(store: Repositories) -> None:
    mission = await store.missions.create_mission("survey", "Quay wall", "client1", {}, T0)
    steps = [(S.PLANNING, S.IN_PROGRESS, "super1"), (S.IN_PROGRESS, S.REVIEWING, "fleetbus")]
    for i, (source, target, by) in enumerate(steps, start=1):
        await store.missions.transition_mission(
            mission.mission_id, source, target, by, T0 + timedelta(minutes=i), f"n{i}"
        )
    history = await store.missions.mission_history(mission.mission_id)
    assert [(h.source, h.target, h.by, h.at, h.note) for h in history] == [
        (None, S.PLANNING, "client1", T0, "created"),
        (S.PLANNING, S.IN_PROGRESS, "super1", T0 + timedelta(minutes=1), "n1"),
        (S.IN_PROGRESS, S.REVIEWING, "fleetbus", T0 + timedelta(minutes=2), "n2"),
    ]


async def test_a_mission_from_central_is_kept_only_when_newer(store: Repositories) -> None:
    """A site keeps central's missions: a newer version replaces the one kept, an older one does not."""
    from fleetbus.workers.store.missions import Mission

    first = Mission("m-7", 7, "survey", "Quay wall", "client1", S.PLANNING, PLAN, T0, T0)
    later = Mission("m-7", 7, "survey", "Quay wall", "client1", S.CLOSED, PLAN, T0, T0 + timedelta(seconds=5))
    assert await store.missions.put_mission(first)
    assert not await store.missions.put_mission(first), "the same version again changes nothing"
    assert await store.missions.put_mission(later)
    assert not await store.missions.put_mission(first), "an older one never overwrites a newer"
    assert await store.missions.get_mission("m-7") == later
    history = await store.missions.mission_history("m-7")
    assert [(h.source, h.target) for h in history] == [(None, S.PLANNING), (S.PLANNING, S.CLOSED)]
