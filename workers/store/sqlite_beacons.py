"""The beacon registry on SQLite, one repository of `sqlite_repositories`."""

from __future__ import annotations

import sqlite3
from datetime import datetime

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.beacons import Beacon, BeaconRegistry
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

BEACON_SCHEMA = """
CREATE TABLE IF NOT EXISTS beacons (
    beacon_id  TEXT PRIMARY KEY,
    x          REAL NOT NULL,
    y          REAL NOT NULL,
    label      TEXT NOT NULL,
    visited_at INTEGER
);
"""


def _beacon(row: sqlite3.Row) -> Beacon:
    visited = row["visited_at"]
    return Beacon(
        row["beacon_id"], row["x"], row["y"], row["label"], from_micros(visited) if visited else None
    )


class SQLiteBeacons(OnSQLite, BeaconRegistry):
    async def put_beacons(self, beacons: list[Beacon]) -> None:
        rows = [(b.beacon_id, b.x, b.y, b.label) for b in beacons]

        def put(db: sqlite3.Connection) -> None:
            in_transaction(
                db,
                lambda: db.executemany(
                    "INSERT INTO beacons (beacon_id, x, y, label) VALUES (?, ?, ?, ?) "
                    "ON CONFLICT (beacon_id) "
                    "DO UPDATE SET x = excluded.x, y = excluded.y, label = excluded.label",
                    rows,
                ),
            )

        await self._run(put)

    async def beacons(self) -> list[Beacon]:
        rows = await self._run(lambda db: db.execute("SELECT * FROM beacons ORDER BY beacon_id").fetchall())
        return [_beacon(row) for row in rows]

    async def get_beacon(self, beacon_id: str) -> Beacon | None:
        row = await self._run(
            lambda db: db.execute("SELECT * FROM beacons WHERE beacon_id = ?", (beacon_id,)).fetchone()
        )
        return _beacon(row) if row else None

    async def mark_visited(self, beacon_id: str, at: datetime) -> Beacon | None:
        await self._run(
            lambda db: db.execute(
                "UPDATE beacons SET visited_at = ? WHERE beacon_id = ?", (to_micros(at), beacon_id)
            )
        )
        return await self.get_beacon(beacon_id)
