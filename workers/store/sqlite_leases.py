"""Leases on SQLite, one repository of `sqlite_repositories`.

An acquisition is one upsert whose update only applies when the lease is free to take, so
SQLite's single writer decides between two workers asking at once.
"""

from __future__ import annotations

import sqlite3
from datetime import datetime

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.leases import Lease, LeaseStore
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

LEASE_SCHEMA = """
CREATE TABLE IF NOT EXISTS leases (
    name       TEXT PRIMARY KEY,
    holder     TEXT    NOT NULL,
    expires_at INTEGER NOT NULL
) WITHOUT ROWID;
"""

ACQUIRE = (
    "INSERT INTO leases (name, holder, expires_at) VALUES (:name, :holder, :until) "
    "ON CONFLICT (name) DO UPDATE SET holder = excluded.holder, expires_at = excluded.expires_at "
    "WHERE leases.holder = excluded.holder OR leases.expires_at <= :now OR leases.holder = :replacing"
)


class SQLiteLeases(OnSQLite, LeaseStore):
    async def acquire_lease(
        self, name: str, holder: str, until: datetime, now: datetime, replacing: str | None = None
    ) -> bool:
        params = {
            "name": name,
            "holder": holder,
            "until": to_micros(until),
            "now": to_micros(now),
            "replacing": replacing,
        }

        def acquire(db: sqlite3.Connection) -> bool:
            return in_transaction(db, lambda: db.execute(ACQUIRE, params).rowcount == 1)

        return await self._run(acquire)

    async def release_lease(self, name: str, holder: str) -> None:
        def release(db: sqlite3.Connection) -> None:
            in_transaction(
                db, lambda: db.execute("DELETE FROM leases WHERE name = ? AND holder = ?", (name, holder))
            )

        await self._run(release)

    async def leases(self, prefix: str = "") -> list[Lease]:
        rows = await self._run(
            lambda db: db.execute(
                "SELECT * FROM leases WHERE substr(name, 1, ?) = ? ORDER BY name", (len(prefix), prefix)
            ).fetchall()
        )
        return [Lease(row["name"], row["holder"], from_micros(row["expires_at"])) for row in rows]
