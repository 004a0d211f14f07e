"""SQLite uses the recording's indexes for the queries they were made for (its query plans say so)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from fleetbus.workers.store.recordings import Condition, Op, RecordQuery
from fleetbus.workers.store.sqlite_recordings import SQLiteRecordingStore, find_sql
from tests.store.test_recordings_contract import T0, rec


def plan(path: Path, query: RecordQuery) -> str:
    sql, params = find_sql(query)
    with sqlite3.connect(path) as db:
        return " | ".join(row[-1] for row in db.execute(f"EXPLAIN QUERY PLAN {sql}", params))


async def test_field_conditions_use_the_field_index(tmp_path: Path) -> None:
    path = tmp_path / "recording.sqlite3"
    query = RecordQuery(
        "tf",
        conditions=(
            Condition("frame", Op.EQ, "/kinect/depth"),
            Condition("child_frame", Op.EQ, "/object/bottle"),
        ),
        since=T0,
    )
    async with SQLiteRecordingStore(path) as store:
        await store.write_recorded(
            [rec(f"k{i}", {"frame": f"/f{i % 7}", "child_frame": "/c"}) for i in range(200)]
        )
        assert "__f_" not in plan(path, query)
        await store.ensure_field_index("tf", ["frame", "child_frame"])
    assert "USING INDEX rec_tf__f_" in plan(path, query)


async def test_robot_and_time_use_their_indexes(tmp_path: Path) -> None:
    path = tmp_path / "recording.sqlite3"
    async with SQLiteRecordingStore(path) as store:
        await store.write_recorded([rec("k", type="status")])
    assert "rec_status__robot_time" in plan(path, RecordQuery("status", robot_id="herb", since=T0))
    assert "rec_status__time" in plan(path, RecordQuery("status", since=T0))
    assert "rec_status__message" in plan(path, RecordQuery("status", message_id="m"))
