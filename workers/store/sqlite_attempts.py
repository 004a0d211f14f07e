"""The attempt counts on SQLite, one repository of `sqlite_repositories`."""

from __future__ import annotations

import sqlite3
from collections.abc import Sequence
from datetime import datetime

from fleetbus.workers.store.attempts import AttemptLog
from fleetbus.workers.store.base import to_micros
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

ATTEMPT_SCHEMA = """
CREATE TABLE IF NOT EXISTS delivery_attempts (
    key      TEXT    PRIMARY KEY,
    attempts INTEGER NOT NULL,
    last_at  INTEGER NOT NULL
) WITHOUT ROWID;
"""


class SQLiteAttempts(OnSQLite, AttemptLog):
    async def count_attempt(self, key: str, at: datetime) -> int:
        def count(db: sqlite3.Connection) -> int:
            (attempts,) = db.execute(
                "INSERT INTO delivery_attempts (key, attempts, last_at) VALUES (?, 1, ?) "
                "ON CONFLICT (key) DO UPDATE SET attempts = attempts + 1, last_at = excluded.last_at "
                "RETURNING attempts",
                (key, to_micros(at)),
            ).fetchone()
            return int(attempts)

        return await self._run(lambda db: in_transaction(db, lambda: count(db)))

    async def forget_attempts(self, keys: Sequence[str]) -> None:
        if not keys:
            return
        await self._run(
            lambda db: in_transaction(
                db,
                lambda: db.executemany("DELETE FROM delivery_attempts WHERE key = ?", [(k,) for k in keys]),
            )
        )
