"""Mounts and check-ins on every adapter: bookings, what is recorded under which mission, the log."""

from __future__ import annotations

import asyncio
from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.workers.store.channels import Booked, ChannelAction, ChannelChange, CheckIn, Mount
from fleetbus.workers.store.discards import Discard
from fleetbus.workers.store.repositories import Repositories
from tests.store.second import second_connection

T0 = datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc)


async def test_a_robot_is_mounted_by_one_operator_at_a_time(store: Repositories) -> None:
    mount = await store.channels.mount("robot1", "alice", "m-1", T0)
    assert mount == Mount("robot1", "alice", "m-1", T0)
    assert await store.channels.mount("robot1", "alice", "m-1", T0 + timedelta(seconds=1)) == mount, (
        "idempotent"
    )
    with pytest.raises(Booked, match="robot1 is mounted by alice for mission m-1"):
        await store.channels.mount("robot1", "bob", "m-1", T0)
    with pytest.raises(Booked, match="robot1 is mounted by alice"):
        await store.channels.mount("robot1", "bob", "m-2", T0)
    assert await store.channels.mounts() == [mount]


async def test_an_operator_is_booked_by_one_mission(store: Repositories) -> None:
    await store.channels.mount("robot1", "alice", "m-1", T0)
    await store.channels.mount("robot2", "alice", "m-1", T0)
    with pytest.raises(Booked, match="operator alice is booked by mission m-1"):
        await store.channels.mount("robot3", "alice", "m-2", T0)
    with pytest.raises(Booked, match="operator alice is booked by mission m-1"):
        await store.channels.check_in("alice", "m-2", T0)
    assert [m.robot for m in await store.channels.mounts(operator="alice")] == ["robot1", "robot2"]
    assert await store.channels.mounts(robot="robot3") == []
    # once nothing holds her to m-1, she may work for m-2
    assert (await store.channels.unmount("robot1")) is not None
    assert (await store.channels.unmount("robot2", "alice")) is not None
    assert await store.channels.mount("robot3", "alice", "m-2", T0) == Mount("robot3", "alice", "m-2", T0)


async def test_a_check_in_books_the_operator_too(store: Repositories) -> None:
    assert await store.channels.check_in("alice", "m-1", T0) == CheckIn("alice", "m-1", T0)
    assert await store.channels.check_in("alice", "m-1", T0 + timedelta(seconds=5)) == CheckIn(
        "alice", "m-1", T0
    )
    with pytest.raises(Booked, match="booked by mission m-1"):
        await store.channels.mount("robot1", "alice", "m-2", T0)
    assert await store.channels.check_out("alice", "m-2") is False
    assert await store.channels.check_out("alice", "m-1") is True
    assert await store.channels.check_ins() == []
    await store.channels.mount("robot1", "alice", "m-2", T0)


async def test_unmount_only_the_operators_own_unless_forced(store: Repositories) -> None:
    await store.channels.mount("robot1", "alice", "m-1", T0)
    assert await store.channels.unmount("robot1", "bob") is None
    assert await store.channels.unmount("robot9") is None
    assert await store.channels.unmount("robot1") == Mount("robot1", "alice", "m-1", T0)
    assert await store.channels.mounts() == []


async def test_data_is_recorded_under_a_mission_while_its_operator_is_checked_in(store: Repositories) -> None:
    await store.channels.mount("robot1", "alice", "m-1", T0)
    await store.channels.mount("robot2", "bob", "m-2", T0)
    await store.channels.mount("robot3", "carol", "m-1", T0)
    assert await store.channels.recording_missions(["robot1", "robot2", "robot3", "robot4"]) == {}
    await store.channels.check_in("alice", "m-1", T0)
    await store.channels.check_in("bob", "m-2", T0)
    assert await store.channels.recording_missions(["robot1", "robot2", "robot3", "robot4"]) == {
        "robot1": "m-1",
        "robot2": "m-2",
    }
    assert [c.operator for c in await store.channels.check_ins(mission_id="m-1")] == ["alice"]
    await store.channels.check_out("alice", "m-1")
    await store.channels.unmount("robot2")
    assert await store.channels.recording_missions(["robot1", "robot2"]) == {}
    assert await store.channels.recording_missions([]) == {}


async def test_of_two_operators_mounting_one_robot_one_wins(store: Repositories) -> None:
    async with second_connection(store) as other:
        results = await asyncio.gather(
            store.channels.mount("robot1", "alice", "m-1", T0),
            other.channels.mount("robot1", "bob", "m-2", T0),
            return_exceptions=True,
        )
    assert sorted(type(r).__name__ for r in results) == ["Booked", "Mount"], results
    [winner] = [r for r in results if isinstance(r, Mount)]
    assert await store.channels.mounts() == [winner]
    loser = "bob" if winner.operator == "alice" else "alice"
    # the loser holds no booking: it may mount another robot for any mission
    await store.channels.mount("robot2", loser, "m-3", T0)


async def test_channel_changes_are_kept_in_order(store: Repositories) -> None:
    changes = [
        ChannelChange(T0, "alice", ChannelAction.MOUNT, "m-1", "alice", "robot1", ""),
        ChannelChange(T0, "alice", ChannelAction.CHECK_IN, "m-1", "alice", None, ""),
        ChannelChange(
            T0 + timedelta(seconds=1), "super1", ChannelAction.FORCE_UNMOUNT, "m-1", "alice", "robot1", "x"
        ),
        ChannelChange(T0 + timedelta(seconds=2), "bob", ChannelAction.MOUNT, "m-2", "bob", "robot2", ""),
    ]
    for change in changes:
        await store.channels.record_change(change)
    assert await store.channels.channel_changes() == changes
    assert await store.channels.channel_changes(mission_id="m-1") == changes[:3]
    assert await store.channels.channel_changes(limit=2) == changes[2:]


async def test_beacon_discards_are_counted_once_per_message(store: Repositories) -> None:
    def discard(
        exchange: str, message_id: str | None, second: int, reason: str = "no type header"
    ) -> Discard:
        return Discard(
            exchange,
            "r.beacon",
            exchange.split(".")[0],
            message_id,
            reason,
            T0 + timedelta(seconds=second),
            {"a": "1"},
        )

    first = [
        discard("guide1.beacon", "a", 0),
        discard("guide1.beacon", "b", 1),
        discard("robot2.beacon", None, 2),
    ]
    assert await store.discards.record_discards(first) == 3
    again = [discard("guide1.beacon", "b", 3), discard("robot2.beacon", None, 4, "no codename header")]
    assert await store.discards.record_discards(again) == 1, (
        "the redelivered 'b' counts once; no id: always new"
    )
    counts = await store.discards.discard_counts()
    assert [(c.exchange, c.count, c.last_at, c.last_reason) for c in counts] == [
        ("guide1.beacon", 2, T0 + timedelta(seconds=1), "no type header"),
        ("robot2.beacon", 2, T0 + timedelta(seconds=4), "no codename header"),
    ]
    recent = await store.discards.recent_discards(2)
    assert [d.received_at for d in recent] == [T0 + timedelta(seconds=4), T0 + timedelta(seconds=2)]
    assert recent[0].headers == {"a": "1"} and recent[0].user_id == "robot2"
