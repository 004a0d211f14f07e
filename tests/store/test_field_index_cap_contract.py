"""Indexes made for ad-hoc field queries are capped per type, the least recently used dropped first,
so that no query ever fails on MongoDB's limit of 64 indexes per collection; on every adapter."""

from __future__ import annotations

from collections.abc import AsyncIterator
from datetime import datetime, timezone
from pathlib import Path

import pytest

from fleetbus.workers.recorder.queries import find, parse_condition
from fleetbus.workers.store.mongo_recordings import MongoRecordingStore
from fleetbus.workers.store.recordings import RecordedMessage, RecordingStore
from fleetbus.workers.store.sqlite_recordings import SQLiteRecordingStore
from tests.store.conftest import fresh_database

T0 = datetime(2026, 1, 1, tzinfo=timezone.utc)


@pytest.fixture(params=["sqlite", "mongodb"])
async def capped(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[RecordingStore]:
    """A recording that keeps at most three field indexes per type."""
    if request.param == "sqlite":
        async with SQLiteRecordingStore(tmp_path / "recording.sqlite3", max_field_indexes=3) as adapter:
            yield adapter
        return
    url: str = request.getfixturevalue("mongodb_url")
    async with (
        fresh_database(url) as database,
        MongoRecordingStore(url, database=database, max_field_indexes=3) as adapter,
    ):
        yield adapter


async def a_record(store: RecordingStore) -> None:
    document = {f"f{i}": i for i in range(80)}
    await store.write_recorded(
        [RecordedMessage("k1", "tf", T0, "r1.events", "r1.tf", "r1", "r1", document=document)]
    )


async def test_the_least_recently_used_field_index_is_dropped_first(capped: RecordingStore) -> None:
    await a_record(capped)
    for paths in (["f0"], ["f1"], ["f2"]):
        await capped.ensure_field_index("tf", paths)
    await capped.ensure_field_index("tf", ["f0"])  # used again: now f1 is the least recently used
    await capped.ensure_field_index("tf", ["f3"])
    assert await capped.field_indexes("tf") == [("f0",), ("f2",), ("f3",)]
    await capped.ensure_field_index("tf", ["f4", "f5"])
    assert await capped.field_indexes("tf") == [("f0",), ("f3",), ("f4", "f5")]


async def test_seventy_query_shapes_all_answer_and_the_indexes_stay_below_mongodbs_limit(
    recording: RecordingStore,
) -> None:
    """With the default cap (32): more distinct shapes than MongoDB has index slots."""
    await a_record(recording)
    for i in range(70):
        found = await find(recording, "tf", [parse_condition(f"f{i}={i}", "tf")])
        assert [r.key for r in found] == ["k1"], f"query {i}"
    assert len(await recording.field_indexes("tf")) == 32
