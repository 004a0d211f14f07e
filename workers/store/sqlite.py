"""The embedded default store: SQLite in WAL mode, one durable transaction per batch; every
repository over one file (:func:`sqlite_repositories`).

Calls run on the caller's thread or the store's own (:mod:`fleetbus.workers.store.sqlite_database`); each
commit is durable before ``write_events`` or ``store_batch`` returns, which is what the worker's
ack waits for. ``store_batch`` stamps, writes and updates the sequence ledger in one transaction.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any, TypeVar

from fleetbus.workers.store.attempts import Attempts
from fleetbus.workers.store.base import (
    EventQuery,
    EventRecord,
    Received,
    WriteResult,
    from_micros,
    to_micros,
)
from fleetbus.workers.store.beacons import Beacons
from fleetbus.workers.store.interface import StoredBatch, held_sequences, numbers_of, stamp_missions
from fleetbus.workers.store.leases import Leases
from fleetbus.workers.store.rejections import Rejections
from fleetbus.workers.store.repositories import EventLog, Repositories
from fleetbus.workers.store.sqlite_channels import CHANNEL_SCHEMA, SQLiteChannels, recording_missions
from fleetbus.workers.store.sqlite_coordination import HAZARD_SCHEMA, SQLiteCoordination, add_hazard_columns
from fleetbus.workers.store.sqlite_database import in_transaction
from fleetbus.workers.store.sqlite_discards import DISCARD_SCHEMA, SQLiteDiscards
from fleetbus.workers.store.sqlite_housekeeping import HOUSEKEEPING_SCHEMA, SQLiteHousekeeping
from fleetbus.workers.store.sqlite_ledger import LEDGER_SCHEMA, SQLiteLedger, observe, observed
from fleetbus.workers.store.sqlite_maps import MAP_SCHEMA, SQLiteMaps
from fleetbus.workers.store.sqlite_missions import MISSION_SCHEMA, SQLiteMissions
from fleetbus.workers.store.sqlite_port import SQLiteStore
from fleetbus.workers.store.sqlite_sites import SITE_SCHEMA, SQLiteSites
from fleetbus.workers.store.statuses import Statuses
from fleetbus.workers.store.users import Users

T = TypeVar("T")

#: An urgent batch of up to this many events may be written on the caller's thread (``store_batch``).
SMALL_BATCH = 16

SCHEMA = """
CREATE TABLE IF NOT EXISTS events (
    robot_id    TEXT    NOT NULL,
    epoch       TEXT    NOT NULL,
    seq         INTEGER NOT NULL,
    type        TEXT    NOT NULL,
    message_id  TEXT    NOT NULL,
    sent_at     INTEGER NOT NULL,
    received_at INTEGER NOT NULL,
    body        TEXT    NOT NULL,
    user_id     TEXT    NOT NULL,
    exchange    TEXT    NOT NULL,
    routing_key TEXT    NOT NULL,
    mission_id  TEXT,
    digest      TEXT,
    PRIMARY KEY (robot_id, epoch, seq)
) WITHOUT ROWID;
CREATE INDEX IF NOT EXISTS events_type_time ON events (type, sent_at);
CREATE INDEX IF NOT EXISTS events_robot_time ON events (robot_id, sent_at);
CREATE INDEX IF NOT EXISTS events_time ON events (sent_at);
CREATE INDEX IF NOT EXISTS events_message_id ON events (message_id);
CREATE INDEX IF NOT EXISTS events_received ON events (received_at);
"""
COLUMNS = (
    "robot_id, epoch, seq, type, message_id, sent_at, received_at, body, user_id, exchange, routing_key, "
    "mission_id, digest"
)
# Unlike INSERT OR IGNORE, this skips only an existing key: a NOT NULL violation still raises
# instead of being reported as a duplicate.
INSERT = (
    f"INSERT INTO events ({COLUMNS}) VALUES ({','.join('?' * 13)}) "
    "ON CONFLICT (robot_id, epoch, seq) DO NOTHING"
)


def add_event_columns(db: sqlite3.Connection) -> None:
    """Add ``digest`` to an ``events`` table made before it (its rows keep NULL: compared by
    message id); idempotent."""
    if "digest" not in {row[1] for row in db.execute("PRAGMA table_info(events)")}:
        try:
            db.execute("ALTER TABLE events ADD COLUMN digest TEXT")
        except sqlite3.OperationalError as error:  # the other connection added it first
            if "duplicate column" not in str(error):
                raise


def _row(record: EventRecord) -> tuple[Any, ...]:
    return (
        record.robot_id,
        record.epoch,
        record.seq,
        record.type,
        record.message_id,
        to_micros(record.sent_at),
        to_micros(record.received_at),
        json.dumps(record.body, separators=(",", ":"), ensure_ascii=False),
        record.user_id,
        record.exchange,
        record.routing_key,
        record.mission_id,
        record.digest,
    )


def _write(db: sqlite3.Connection, records: Sequence[EventRecord]) -> list[WriteResult]:
    """Within the caller's transaction: insert each record unless its key is taken or the ledger
    has seen its number (its event pruned since)."""
    seen = observed(db, numbers_of(records))
    results: list[WriteResult] = []
    for record in records:
        row = _row(record)
        if record.key not in seen and db.execute(INSERT, row).rowcount == 1:
            results.append(WriteResult(inserted=True))
            continue
        stored = db.execute(
            "SELECT message_id, received_at, digest FROM events WHERE robot_id = ? AND epoch = ? AND seq = ?",
            row[:3],
        ).fetchone()
        results.append(
            WriteResult(
                inserted=False,
                stored_message_id=stored[0],
                stored_digest=stored[2],
                rewritten=(stored[0], stored[1]) == (row[4], row[6]),
            )
            if stored
            else WriteResult(inserted=False, pruned=True)
        )
    return results


def _record(row: sqlite3.Row) -> EventRecord:
    return EventRecord(
        robot_id=row["robot_id"],
        epoch=row["epoch"],
        seq=row["seq"],
        type=row["type"],
        message_id=row["message_id"],
        sent_at=from_micros(row["sent_at"]),
        received_at=from_micros(row["received_at"]),
        body=json.loads(row["body"]),
        user_id=row["user_id"],
        exchange=row["exchange"],
        routing_key=row["routing_key"],
        mission_id=row["mission_id"],
        digest=row["digest"],
    )


class SQLiteFile(SQLiteStore):
    """The file every repository of one :class:`Repositories` shares, with all their tables."""

    def _prepare(self, db: sqlite3.Connection) -> None:
        super()._prepare(db)
        for schema in (
            SCHEMA,
            HAZARD_SCHEMA,
            MAP_SCHEMA,
            LEDGER_SCHEMA,
            MISSION_SCHEMA,
            CHANNEL_SCHEMA,
            DISCARD_SCHEMA,
            HOUSEKEEPING_SCHEMA,
            SITE_SCHEMA,
        ):
            db.executescript(schema)
        add_event_columns(db)
        add_hazard_columns(db)


def sqlite_repositories(path: Path, busy_timeout: float = 2.0) -> Repositories:
    """Every repository over one SQLite file, not yet opened."""
    file = SQLiteFile(path, busy_timeout)
    return Repositories(
        name="sqlite",
        events=SQLiteEventLog(file),
        hazards=SQLiteCoordination(file),
        beacons=Beacons(file),
        maps=SQLiteMaps(file),
        missions=SQLiteMissions(file),
        channels=SQLiteChannels(file),
        users=Users(file),
        discards=SQLiteDiscards(file),
        rejections=Rejections(file),
        attempts=Attempts(file),
        leases=Leases(file),
        statuses=Statuses(file),
        housekeeping=SQLiteHousekeeping(file),
        sites=SQLiteSites(file),
        opener=file.open,
        closer=file.close,
        again=lambda: sqlite_repositories(path, busy_timeout),
    )


class SQLiteEventLog(SQLiteLedger, EventLog):
    """The event log and its sequence ledger; the system of record for validated events."""

    async def write_events(self, records: Sequence[EventRecord]) -> list[WriteResult]:
        return await self._run(lambda db: in_transaction(db, lambda: _write(db, records)))

    async def store_batch(
        self, records: Sequence[EventRecord], at: datetime, *, urgent: bool = False
    ) -> StoredBatch:
        """One transaction: the mission lookup, the write and the ledger (one commit, one fsync).
        Hazards are registered by the hazard service (``hold_hazards``), as on every backend.

        An urgent small batch is written without the hand-over to the store's thread when it can
        be. Bulk batches always take the thread: the event loop keeps receiving while SQLite
        writes, which is what lets the batches grow under load (written on the loop, the drain
        of a backlog fell from about 7,000 to 4,900 events a second in ``python -m bench.ingest``).
        """

        def work(db: sqlite3.Connection) -> StoredBatch:
            stamped = stamp_missions(records, recording_missions(db, {r.robot_id for r in records}))
            results = _write(db, stamped)
            observe(db, held_sequences(stamped, results), at)
            return StoredBatch(stamped, results)

        return await self._run(
            lambda db: in_transaction(db, lambda: work(db)), small=urgent and len(records) <= SMALL_BATCH
        )

    async def find_events(self, query: EventQuery) -> list[EventRecord]:
        where, params = _where(query.type, query.robot_id, query.since, query.until, query.mission_id)
        order = "DESC" if query.newest_first else "ASC"
        keys = ", ".join(f"{column} {order}" for column in ("sent_at", "robot_id", "epoch", "seq"))
        sql = f"SELECT * FROM events{where} ORDER BY {keys}"
        if query.limit is not None:
            sql += f" LIMIT {int(query.limit)}"
        return await self._run(lambda db: [_record(row) for row in db.execute(sql, params)])

    async def keys_received_since(self, since: datetime, limit: int) -> list[Received]:
        # covered by the events_received index (a WITHOUT ROWID table's index holds the key)
        sql = (
            "SELECT robot_id, epoch, seq, received_at FROM events WHERE received_at >= ? "
            "ORDER BY received_at, robot_id, epoch, seq LIMIT ?"
        )
        return await self._run(
            lambda db: [
                Received((robot, epoch, seq), from_micros(at))
                for robot, epoch, seq, at in db.execute(sql, (to_micros(since), int(limit)))
            ]
        )

    async def events_received_since(self, since: datetime, limit: int) -> list[EventRecord]:
        sql = "SELECT * FROM events WHERE received_at >= ? ORDER BY received_at, robot_id, epoch, seq LIMIT ?"
        return await self._run(
            lambda db: [_record(row) for row in db.execute(sql, (to_micros(since), int(limit)))]
        )

    async def count_events(self, type: str | None = None, robot_id: str | None = None) -> int:
        where, params = _where(type, robot_id, None, None)
        return await self._run(
            lambda db: db.execute(f"SELECT count(*) FROM events{where}", params).fetchone()[0]
        )


def _where(
    type: str | None,
    robot_id: str | None,
    since: datetime | None,
    until: datetime | None,
    mission_id: str | None = None,
) -> tuple[str, list[Any]]:
    clauses: list[str] = []
    params: list[Any] = []
    for clause, value in (
        ("type = ?", type),
        ("robot_id = ?", robot_id),
        ("sent_at >= ?", to_micros(since) if since else None),
        ("sent_at < ?", to_micros(until) if until else None),
        ("mission_id = ?", mission_id),
    ):
        if value is not None:
            clauses.append(clause)
            params.append(value)
    return (" WHERE " + " AND ".join(clauses) if clauses else ""), params
