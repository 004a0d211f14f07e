"""The beacon discard log on SQLite, one repository of `sqlite_repositories`."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.discards import Discard, DiscardCount, DiscardLog
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

DISCARD_SCHEMA = """
CREATE TABLE IF NOT EXISTS beacon_discards (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    exchange    TEXT    NOT NULL,
    routing_key TEXT    NOT NULL,
    user_id     TEXT,
    message_id  TEXT,
    reason      TEXT    NOT NULL,
    received_at INTEGER NOT NULL,
    headers     TEXT    NOT NULL
);
CREATE UNIQUE INDEX IF NOT EXISTS beacon_discards_message
    ON beacon_discards (exchange, message_id) WHERE message_id IS NOT NULL;
"""


def _discard(row: sqlite3.Row) -> Discard:
    return Discard(
        row["exchange"],
        row["routing_key"],
        row["user_id"],
        row["message_id"],
        row["reason"],
        from_micros(row["received_at"]),
        json.loads(row["headers"]),
    )


class SQLiteDiscards(OnSQLite, DiscardLog):
    async def record_discards(self, discards: Sequence[Discard]) -> int:
        rows = [
            (
                d.exchange,
                d.routing_key,
                d.user_id,
                d.message_id,
                d.reason,
                to_micros(d.received_at),
                json.dumps(d.headers),
            )
            for d in discards
        ]

        def write(db: sqlite3.Connection) -> int:
            return in_transaction(
                db,
                lambda: sum(
                    db.execute(
                        "INSERT INTO beacon_discards (exchange, routing_key, user_id, message_id, reason, "
                        "received_at, headers) VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT DO NOTHING",
                        row,
                    ).rowcount
                    for row in rows
                ),
            )

        return await self._run(write)

    async def discard_counts(self) -> list[DiscardCount]:
        rows = await self._run(
            lambda db: db.execute(
                "SELECT d.exchange, counts.n, d.received_at, d.reason FROM beacon_discards d JOIN "
                "(SELECT exchange, count(*) AS n, max(id) AS last FROM beacon_discards GROUP BY exchange) "
                "counts ON d.id = counts.last ORDER BY d.exchange"
            ).fetchall()
        )
        return [DiscardCount(row[0], row[1], from_micros(row[2]), row[3]) for row in rows]

    async def recent_discards(self, limit: int = 20) -> list[Discard]:
        rows = await self._run(
            lambda db: db.execute(
                "SELECT * FROM beacon_discards ORDER BY id DESC LIMIT ?", (limit,)
            ).fetchall()
        )
        return [_discard(row) for row in rows]
