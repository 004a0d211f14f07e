"""One contract, every adapter: exact round trips, idempotent writes, queries, unavailability."""

from __future__ import annotations

import sqlite3
import time
from dataclasses import replace
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from fleetbus.workers.store.base import EventQuery, EventRecord, StoreUnavailable
from fleetbus.workers.store.mongo import mongo_repositories
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.sqlite import sqlite_repositories

T0 = datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc)
EPOCH = "20210601T182526564Z-0a1b2c3d"
LATER = "20210601T190000000Z-4e5f6a7b"


def record(
    robot: str = "explorer1",
    seq: int = 0,
    type: str = "hazard",
    at: datetime = T0,
    epoch: str = EPOCH,
    **body: object,
) -> EventRecord:
    return EventRecord(
        robot_id=robot,
        epoch=epoch,
        seq=seq,
        type=type,
        message_id=f"m-{robot}-{epoch[-8:]}-{seq}",
        sent_at=at,
        received_at=at + timedelta(microseconds=1234),
        body=body or {"pose": {"x": 2.66, "y": 1.22}, "description": "Feu ☢", "nested": [1, {"a": None}]},
        user_id=robot,
        exchange=f"{robot}.events",
        routing_key=f"{robot}.{type}",
    )


async def test_every_field_round_trips_exactly(store: Repositories) -> None:
    original = record()
    [result] = await store.events.write_events([original])
    assert result.inserted
    [found] = await store.events.find_events(EventQuery())
    assert found == original
    assert found.sent_at.microsecond == 564500 and found.sent_at.tzinfo is not None


async def test_mission_and_local_times_round_trip(store: Repositories) -> None:
    tokyo = timezone(timedelta(hours=9))
    original = replace(
        record(seq=7, at=datetime(2021, 6, 2, 3, 25, 26, 999, tzinfo=tokyo)),
        mission_id="mission-β",
        received_at=datetime(2021, 6, 1, 18, 25, 27, 1, tzinfo=timezone.utc),
    )
    await store.events.write_events([original])
    [found] = await store.events.find_events(EventQuery())
    assert found == original and found.mission_id == "mission-β"
    assert found.sent_at.utcoffset() == timedelta(0), "stored and returned in UTC"
    assert (found.sent_at.microsecond, found.received_at.microsecond) == (999, 1)


async def test_a_records_mission_never_changes_and_can_be_queried(store: Repositories) -> None:
    await store.events.write_events([replace(record(seq=0), mission_id="m-1"), record(seq=1)])
    again = await store.events.write_events(
        [replace(record(seq=0), mission_id="m-2"), replace(record(seq=1), mission_id="m-2")]
    )
    assert [r.inserted for r in again] == [False, False], (
        "a redelivery under another mission is the same event"
    )
    assert [(r.seq, r.mission_id) for r in await store.events.find_events(EventQuery())] == [
        (0, "m-1"),
        (1, None),
    ]
    assert [r.seq for r in await store.events.find_events(EventQuery(mission_id="m-1"))] == [0]
    assert await store.events.find_events(EventQuery(mission_id="m-2")) == []


async def test_writes_are_idempotent_on_robot_and_sequence(store: Repositories) -> None:
    first = await store.events.write_events([record(seq=0), record(seq=1), record(seq=0)])
    assert [r.inserted for r in first] == [True, True, False]
    again = await store.events.write_events([record(seq=1, description="changed"), record(seq=2)])
    assert [r.inserted for r in again] == [False, True]
    assert await store.events.count_events() == 3
    [one] = await store.events.find_events(
        EventQuery(robot_id="explorer1", since=T0, limit=1, newest_first=False)
    )
    assert one.seq == 0
    stored_1 = next(r for r in await store.events.find_events(EventQuery()) if r.seq == 1)
    assert stored_1.body["description"] == "Feu ☢", "a duplicate never overwrites what is stored"


async def test_a_number_is_one_event_per_epoch(store: Repositories) -> None:
    """Each start of a robot's client numbers from 0 in an epoch of its own: the same number in two
    epochs is two events; in one epoch with another message, the stored message is named."""
    reused = replace(record(seq=0, epoch=LATER), message_id="m-other")
    results = await store.events.write_events([record(seq=0), record(seq=0, epoch=LATER), reused])
    assert [(r.inserted, r.stored_message_id) for r in results] == [
        (True, None),
        (True, None),
        (False, record(seq=0, epoch=LATER).message_id),
    ]
    found = await store.events.find_events(EventQuery(robot_id="explorer1"))
    assert sorted(r.key for r in found) == [("explorer1", EPOCH, 0), ("explorer1", LATER, 0)]


async def test_queries_filter_and_order(store: Repositories) -> None:
    records = [
        record("explorer1", 0, "hazard", T0),
        record("explorer1", 1, "status", T0 + timedelta(seconds=1)),
        record("warden1", 0, "localisation", T0 + timedelta(seconds=1)),
        record("explorer1", 2, "hazard", T0 + timedelta(seconds=2)),
        record("warden1", 1, "hazard", T0 + timedelta(seconds=3)),
    ]
    records += [record("warden1", 9, "status", T0 + timedelta(seconds=4))]
    records += [record("warden1", 10, "status", T0 + timedelta(seconds=4))]
    await store.events.write_events(list(reversed(records)))
    keys = lambda found: [(r.robot_id, r.seq) for r in found]  # noqa: E731
    assert keys(await store.events.find_events(EventQuery())) == keys(records), (
        "by time, then robot, then seq"
    )
    assert keys(await store.events.find_events(EventQuery(newest_first=True))) == keys(reversed(records))
    assert keys(await store.events.find_events(EventQuery(type="hazard"))) == [
        ("explorer1", 0),
        ("explorer1", 2),
        ("warden1", 1),
    ]
    assert keys(await store.events.find_events(EventQuery(robot_id="warden1"))) == [
        ("warden1", 0),
        ("warden1", 1),
        ("warden1", 9),
        ("warden1", 10),
    ]
    window = EventQuery(since=T0 + timedelta(seconds=1), until=T0 + timedelta(seconds=3))
    assert keys(await store.events.find_events(window)) == [
        ("explorer1", 1),
        ("warden1", 0),
        ("explorer1", 2),
    ]
    newest = EventQuery(limit=2, newest_first=True)
    assert keys(await store.events.find_events(newest)) == [("warden1", 10), ("warden1", 9)], "seq is numeric"
    assert await store.events.count_events(type="hazard") == 3
    assert await store.events.count_events(robot_id="warden1") == 4
    assert await store.events.count_events() == 7
    assert await store.events.count_events(type="hazard", robot_id="warden1") == 1


async def test_a_batch_of_500_in_one_call(store: Repositories) -> None:
    batch = [record("explorer1", i, "status", T0 + timedelta(milliseconds=i), battery=i) for i in range(500)]
    results = await store.events.write_events(batch)
    assert all(r.inserted for r in results)
    assert await store.events.count_events(type="status") == 500


async def test_locked_sqlite_is_unavailable_and_nothing_is_written(tmp_path: Path) -> None:
    async with sqlite_repositories(tmp_path / "store.sqlite3", busy_timeout=0.2) as store:
        locker = sqlite3.connect(tmp_path / "store.sqlite3", isolation_level=None)
        locker.execute("BEGIN EXCLUSIVE")
        started = time.monotonic()
        with pytest.raises(StoreUnavailable, match="locked"):
            await store.events.write_events([record(seq=0)])
        assert time.monotonic() - started < 10, "the busy timeout bounds the wait"
        locker.execute("ROLLBACK")
        locker.close()
        assert await store.events.count_events() == 0
        [result] = await store.events.write_events([record(seq=0)])
        assert result.inserted


async def test_a_failed_sqlite_batch_writes_nothing_and_leaves_no_transaction(tmp_path: Path) -> None:
    async with sqlite_repositories(tmp_path / "store.sqlite3") as store:
        broken = replace(record(seq=1), type=None)  # type: ignore[arg-type]
        with pytest.raises(sqlite3.IntegrityError):
            await store.events.write_events([record(seq=0), broken])
        assert await store.events.count_events() == 0
        [result] = await store.events.write_events([record(seq=0)])
        assert result.inserted


async def test_unreachable_mongodb_is_unavailable() -> None:
    url = "mongodb://fleet:s3cret@127.0.0.1:9,127.0.0.1:11/fleetbus"
    store = mongo_repositories(url, server_selection_timeout=0.5)
    try:
        with pytest.raises(StoreUnavailable, match=r"127\.0\.0\.1:9,127\.0\.0\.1:11/fleetbus") as opened:
            await store.open()
        assert "s3cret" not in str(opened.value)
        with pytest.raises(StoreUnavailable):
            await store.events.write_events([record(seq=0)])
        with pytest.raises(StoreUnavailable):
            await store.events.find_events(EventQuery())
        with pytest.raises(StoreUnavailable):
            await store.events.count_events()
    finally:
        await store.close()


async def test_events_received_since_follow_the_order_they_were_received(store: Repositories) -> None:
    # sent out of order (a robot's outbox drains late): the feed follows received_at, not sent_at
    late = replace(record(seq=1, at=T0 - timedelta(hours=1)), received_at=T0 + timedelta(seconds=2))
    first = replace(record(seq=2), received_at=T0 + timedelta(seconds=1))
    other = replace(record(robot="explorer2", seq=0), received_at=T0 + timedelta(seconds=1))
    await store.events.write_events([late, first, other])
    found = await store.events.events_received_since(T0 + timedelta(seconds=1), limit=10)
    assert [r.key for r in found] == [first.key, other.key, late.key]
    assert [r.key for r in await store.events.events_received_since(T0, limit=1)] == [first.key]
    assert await store.events.events_received_since(T0 + timedelta(seconds=3), limit=10) == []
    keys = await store.events.keys_received_since(T0 + timedelta(seconds=1), limit=10)
    assert keys == [(r.key, r.received_at) for r in found], "the same, without the events"
    assert await store.events.keys_received_since(T0 + timedelta(seconds=3), limit=10) == []
