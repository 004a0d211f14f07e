"""What a console refresh costs per robot: each robot read from the store once, then followed from
the feed's batches (the real SQLite store, its reads counted)."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timedelta
from pathlib import Path

import pytest

from fleetbus.api.console.latest import Latest
from fleetbus.api.services.stored_events import StoredEvents
from fleetbus.workers.store.base import EventRecord
from fleetbus.workers.store.sqlite import sqlite_repositories
from tests.store.test_contract import T0, record

ROBOTS = [f"explorer{n}" for n in range(5)]


def status(robot: str, seq: int, battery: float, x: float, seconds: float) -> EventRecord:
    body = {"battery_percent": battery, "pose": {"x": x, "y": 1.0}, "processing_rate_hz": 10.0}
    return record(robot, seq, "status", T0 + timedelta(seconds=seconds), **body)


async def test_robots_are_read_from_the_store_once_then_follow_the_feed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    async with sqlite_repositories(tmp_path / "store.sqlite3") as store:
        for robot in ROBOTS:
            await store.events.write_events(
                [
                    status(robot, 0, 90.0, 1.0, 0),
                    status(robot, 1, 80.0, 2.0, 10),
                    record(robot, 2, "localisation", T0 + timedelta(seconds=20), localised=True),
                ]
            )
        reads: list[tuple[list[str], str | None]] = []
        newest_events = store.events.newest_events

        async def counted(
            robots: Sequence[str], type: str | None = None, **window: datetime | None
        ) -> dict[str, EventRecord]:
            assert window == {"since": None, "until": None}, "the newest of all time"
            reads.append((sorted(robots), type))
            return await newest_events(robots, type)

        monkeypatch.setattr(store.events, "newest_events", counted)
        latest = Latest(StoredEvents(store.events))

        assert await latest.seed(ROBOTS)
        assert reads == [(ROBOTS, None), (ROBOTS, "status"), (ROBOTS, "localisation")], (
            "the newest event, status and localisation of all of them: three queries, each robot once"
        )
        newest = latest.of("explorer3")
        assert (newest.battery, newest.pose and newest.pose.x) == (80.0, 2.0)
        assert newest.last_seen == T0 + timedelta(seconds=20, microseconds=1234)

        for _ in range(10):  # every refresh after: no read at all, whatever the team's size
            assert not await latest.seed(ROBOTS)
        assert len(reads) == 3

        latest.observe([status("explorer3", 3, 15.0, 7.5, 30)])  # a batch of the feed
        latest.observe([status("explorer3", 1, 80.0, 2.0, 10)])  # a late copy of an older one
        assert (latest.of("explorer3").battery, latest.of("explorer3").pose.x) == (15.0, 7.5)  # type: ignore[union-attr]

        assert not await latest.seed(ROBOTS[:-1])  # explorer4 left the team: forgotten
        assert latest.of("explorer4").last_seen is None and "explorer4" not in latest.last_seen()
        assert len(reads) == 3
