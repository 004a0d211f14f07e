"""The workers' statuses on SQLite, one repository of `sqlite_repositories`."""

from __future__ import annotations

import json
import sqlite3

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction
from fleetbus.workers.store.statuses import StatusBoard, WorkerStatus

STATUS_SCHEMA = """
CREATE TABLE IF NOT EXISTS worker_status (
    name          TEXT    PRIMARY KEY,
    updated_at    INTEGER NOT NULL,
    counters      TEXT    NOT NULL,
    waiting_for   TEXT,
    waiting_since INTEGER,
    last_error    TEXT
) WITHOUT ROWID;
"""


class SQLiteStatuses(OnSQLite, StatusBoard):
    async def put_status(self, status: WorkerStatus) -> None:
        row = (
            status.name,
            to_micros(status.updated_at),
            json.dumps(status.counters),
            status.waiting_for,
            to_micros(status.waiting_since) if status.waiting_since else None,
            status.last_error,
        )
        await self._run(
            lambda db: in_transaction(
                db, lambda: db.execute("INSERT OR REPLACE INTO worker_status VALUES (?, ?, ?, ?, ?, ?)", row)
            )
        )

    async def statuses(self) -> list[WorkerStatus]:
        def read(db: sqlite3.Connection) -> list[WorkerStatus]:
            rows = db.execute(
                "SELECT name, updated_at, counters, waiting_for, waiting_since, last_error "
                "FROM worker_status ORDER BY name"
            )
            return [
                WorkerStatus(
                    name,
                    from_micros(updated_at),
                    json.loads(counters),
                    waiting_for,
                    from_micros(waiting_since) if waiting_since is not None else None,
                    last_error,
                )
                for name, updated_at, counters, waiting_for, waiting_since, last_error in rows
            ]

        return await self._run(read)
