"""Pruning and the bound counts on SQLite, one repository of `sqlite_repositories`.

Each call is one short transaction on the store's thread, so a worker's batch waits for at most
one of them, never for a whole round of pruning.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Mapping
from datetime import datetime
from typing import Any

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.hazards import HazardState
from fleetbus.workers.store.housekeeping import BoundCount, Housekeeping
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

HOUSEKEEPING_SCHEMA = """
CREATE INDEX IF NOT EXISTS events_type_received ON events (type, received_at);
CREATE INDEX IF NOT EXISTS duplicates_time ON duplicates (seen_at);
CREATE INDEX IF NOT EXISTS beacon_discards_time ON beacon_discards (received_at);
CREATE TABLE IF NOT EXISTS bound_counts (
    bound    TEXT    NOT NULL,
    subject  TEXT    NOT NULL,
    count    INTEGER NOT NULL,
    first_at INTEGER NOT NULL,
    last_at  INTEGER NOT NULL,
    PRIMARY KEY (bound, subject)
) WITHOUT ROWID;
"""
OPEN_STATES = tuple(state.value for state in HazardState if state is not HazardState.CLEARED)
#: Events whose message id is in the JSON array bound to ``:kept`` stay.
NOT_KEPT = "message_id NOT IN (SELECT value FROM json_each(:kept))"


def _open_hazard_message_ids(db: sqlite3.Connection) -> list[str]:
    marks = ",".join("?" * len(OPEN_STATES))
    rows = db.execute(
        f"SELECT json_extract(event, '$.message_id') FROM hazards WHERE state IN ({marks})", OPEN_STATES
    )
    return [row[0] for row in rows if row[0] is not None]


def _prune_rows(
    db: sqlite3.Connection, table: str, time: str, before: datetime | None, keep: int | None, limit: int
) -> int:
    """Within a transaction: the oldest rows of a rowid table, by time, then beyond the newest
    ``keep`` in the order they were inserted (the store's own order, which has no ties)."""
    deleted = 0
    if before is not None:
        deleted += db.execute(
            f"DELETE FROM {table} WHERE rowid IN "
            f"(SELECT rowid FROM {table} WHERE {time} < ? ORDER BY {time} LIMIT ?)",
            (to_micros(before), limit),
        ).rowcount
    if keep is not None and deleted < limit:
        last = db.execute(
            f"SELECT rowid FROM {table} ORDER BY rowid DESC LIMIT 1 OFFSET ?", (keep,)
        ).fetchone()
        if last is not None:
            deleted += db.execute(
                f"DELETE FROM {table} WHERE rowid IN "
                f"(SELECT rowid FROM {table} WHERE rowid <= ? ORDER BY rowid LIMIT ?)",
                (last[0], limit - deleted),
            ).rowcount
    return deleted


def _prune_events(
    db: sqlite3.Connection, type: str, before: datetime | None, keep: int | None, limit: int
) -> int:
    """Within a transaction. The events table has no rowid: its order is the reception time."""
    cut = to_micros(before) if before is not None else None
    if keep is not None:
        kept = db.execute(
            "SELECT received_at FROM events WHERE type = ? ORDER BY received_at DESC LIMIT 1 OFFSET ?",
            (type, keep - 1),
        ).fetchone()
        if kept is not None:  # the oldest of the newest ``keep``: everything received before it goes
            cut = kept[0] if cut is None else max(cut, kept[0])
    if cut is None:
        return 0
    params: dict[str, Any] = {
        "type": type,
        "kept": json.dumps(_open_hazard_message_ids(db) if type == "hazard" else []),
        "before": cut,
        "limit": limit,
    }
    # the events table has no rowid: a batch is named by its message ids (indexed), not by the
    # key, so that this does not depend on how an event is keyed, and events received at the same
    # moment still go ``limit`` at a time
    where = f"type = :type AND received_at < :before AND {NOT_KEPT}"
    # the unary + keep SQLite from scanning the time index again: the batch's ids are looked up
    return db.execute(
        "DELETE FROM events WHERE +type = :type AND +received_at < :before AND message_id IN "
        f"(SELECT message_id FROM events WHERE {where} ORDER BY received_at LIMIT :limit)",
        params,
    ).rowcount


class SQLiteHousekeeping(OnSQLite, Housekeeping):
    async def prune_events(self, type: str, before: datetime | None, keep: int | None, limit: int) -> int:
        return await self._run(
            lambda db: in_transaction(db, lambda: _prune_events(db, type, before, keep, limit))
        )

    async def prune_duplicates(self, before: datetime | None, keep: int | None, limit: int) -> int:
        return await self._run(
            lambda db: in_transaction(
                db, lambda: _prune_rows(db, "duplicates", "seen_at", before, keep, limit)
            )
        )

    async def prune_discards(self, before: datetime | None, keep: int | None, limit: int) -> int:
        return await self._run(
            lambda db: in_transaction(
                db, lambda: _prune_rows(db, "beacon_discards", "received_at", before, keep, limit)
            )
        )

    async def count_bounded(self, counts: Mapping[tuple[str, str], int], at: datetime) -> None:
        moment = to_micros(at)
        rows = [(bound, subject, n, moment, moment) for (bound, subject), n in counts.items() if n]
        if not rows:
            return
        sql = (
            "INSERT INTO bound_counts (bound, subject, count, first_at, last_at) VALUES (?, ?, ?, ?, ?) "
            "ON CONFLICT (bound, subject) DO UPDATE "
            "SET count = count + excluded.count, last_at = excluded.last_at"
        )
        await self._run(lambda db: in_transaction(db, lambda: db.executemany(sql, rows)))

    async def bound_counts(self) -> list[BoundCount]:
        rows = await self._run(
            lambda db: db.execute("SELECT * FROM bound_counts ORDER BY bound, subject").fetchall()
        )
        return [
            BoundCount(
                row["bound"],
                row["subject"],
                row["count"],
                from_micros(row["first_at"]),
                from_micros(row["last_at"]),
            )
            for row in rows
        ]
