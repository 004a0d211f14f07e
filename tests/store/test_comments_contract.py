"""Missions' discussions on every adapter: kept per mission in the order stored (ties in time
too), read back from another connection, the newest N of a long thread, exact times and text."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.repositories import Repositories
from tests.store.second import second_connection

T0 = datetime(2026, 11, 28, 2, 15, 0, 123456, tzinfo=timezone.utc)


async def test_comments_are_kept_per_mission_in_the_order_stored(store: Repositories) -> None:
    comments = store.comments
    assert await comments.comments("m-1") == []
    first = await comments.add_comment("m-1", "client1", "client", "Is the north yard done?", T0)
    # the same moment: the order stored still tells them apart
    second = await comments.add_comment("m-1", "oper1", "operator", "Half of it.\n<b>not bold</b>", T0)
    await comments.add_comment("m-2", "planner1", "planner", "another mission's", T0 - timedelta(hours=1))
    third = await comments.add_comment(
        "m-1", "super1", "supervisor", "Résumé at 14:00 ✓", T0 + timedelta(seconds=1)
    )
    assert first.number < second.number < third.number
    assert (second.mission_id, second.author, second.role, second.at) == ("m-1", "oper1", "operator", T0)

    other = second_connection(store)
    await other.open()
    try:
        thread = await other.comments.comments("m-1")
        assert thread == [first, second, third], "oldest first, as stored, exactly (times to the µs, text)"
        assert await other.comments.comments("m-1", limit=2) == [second, third], "the newest 2, oldest first"
        assert await other.comments.comments("m-1", after=first.number) == [second, third]
        assert await other.comments.count_comments("m-1") == 3
        assert await other.comments.count_comments("m-3") == 0
        assert [c.author for c in await other.comments.comments("m-2")] == ["planner1"]
    finally:
        await other.close()
