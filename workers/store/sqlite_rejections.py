"""The rejections of dead letters on SQLite, one repository of `sqlite_repositories`."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterable, Sequence

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.rejections import Rejection, RejectionLog
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

REJECTION_SCHEMA = """
CREATE TABLE IF NOT EXISTS rejections (
    key         TEXT    PRIMARY KEY,
    reason      TEXT    NOT NULL,
    detail      TEXT    NOT NULL,
    rejected_at INTEGER NOT NULL
) WITHOUT ROWID;
"""


class SQLiteRejections(OnSQLite, RejectionLog):
    async def record_rejections(self, rejections: Sequence[Rejection]) -> None:
        if not rejections:
            return
        rows = [(r.key, r.reason, r.detail, to_micros(r.rejected_at)) for r in rejections]
        await self._run(
            lambda db: in_transaction(
                db,
                lambda: db.executemany(
                    "INSERT INTO rejections (key, reason, detail, rejected_at) VALUES (?, ?, ?, ?) "
                    "ON CONFLICT (key) DO NOTHING",
                    rows,
                ),
            )
        )

    async def rejections(self, keys: Iterable[str]) -> dict[str, Rejection]:
        wanted = list(dict.fromkeys(keys))

        def read(db: sqlite3.Connection) -> dict[str, Rejection]:
            found: dict[str, Rejection] = {}
            for start in range(0, len(wanted), 500):
                chunk = wanted[start : start + 500]
                marks = ",".join("?" * len(chunk))
                for key, reason, detail, at in db.execute(
                    f"SELECT key, reason, detail, rejected_at FROM rejections WHERE key IN ({marks})", chunk
                ):
                    found[key] = Rejection(key, reason, detail, from_micros(at))
            return found

        return await self._run(read) if wanted else {}
