"""Workers' statuses on every adapter: the latest per worker replaces the one before."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.statuses import WorkerStatus
from tests.store.second import second_connection

T0 = datetime(2026, 11, 24, 8, 0, 0, tzinfo=timezone.utc)


async def test_the_latest_status_of_each_worker_is_kept(store: Repositories) -> None:
    waiting = WorkerStatus(
        "worker-a",
        T0,
        {"stored": 10, "store_retries": 3},
        "the store and the notifications",
        T0 - timedelta(seconds=4),
        "SQLite data.sqlite3: database is locked",
    )
    await store.statuses.put_status(waiting)
    await store.statuses.put_status(WorkerStatus("worker-b", T0, {"stored": 1}))
    recovered = WorkerStatus("worker-a", T0 + timedelta(seconds=5), {"stored": 12, "store_retries": 3})
    await store.statuses.put_status(recovered)
    other = second_connection(store)  # what `fleetbus stats` sees
    await other.open()
    try:
        assert await other.statuses.statuses() == [recovered, WorkerStatus("worker-b", T0, {"stored": 1})]
    finally:
        await other.close()
    await store.statuses.put_status(waiting)
    assert (await store.statuses.statuses())[0] == waiting
