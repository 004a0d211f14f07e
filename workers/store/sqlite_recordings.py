"""The recording on SQLite: its own database file, one table ``rec_<type>`` per message type.

A file apart from the event log's, so the recorder and the ingest worker never wait for each
other's write lock. Documents are JSON text; field conditions and field indexes use the same
``json_extract`` expressions, which is what lets SQLite's planner use the indexes.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import math
import os
import sqlite3
import uuid
from collections.abc import Iterable, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from fleetbus.defaults import DEFAULT_FIELD_INDEXES_MAX
from fleetbus.private_files import FILE_MODE, private_dir
from fleetbus.publishers.storage import fsync_dir
from fleetbus.workers.store.base import WriteResult, from_micros, to_micros
from fleetbus.workers.store.recordings import (
    Bookkeeping,
    Condition,
    Op,
    OutcomeFields,
    OutcomeStats,
    RecordedMessage,
    RecordingStore,
    RecordQuery,
    TypeSummary,
    check_digest,
    check_path,
    check_type_name,
)
from fleetbus.workers.store.sqlite import SQLiteStore
from fleetbus.workers.store.sqlite_database import in_transaction

TABLE_PREFIX = "rec_"
COLUMNS = (
    "key",
    "recorded_at",
    "exchange",
    "routing_key",
    "user_id",
    "robot_id",
    "message_id",
    "mission_id",
    "sent_at",
    "seq",
    "known",
    "problem",
    "document",
    "raw",
    "properties",
    "size",
)
log = logging.getLogger("fleetbus.recording")
NUMBER_TYPES = "IN ('integer', 'real')"
SQL_OPS = {Op.LT: "<", Op.LE: "<=", Op.GT: ">", Op.GE: ">="}
DELETE_CHUNK = 500


def table(type: str) -> str:
    return f'"{TABLE_PREFIX}{check_type_name(type)}"'


def table_schema(type: str) -> str:
    name, t = f"{TABLE_PREFIX}{check_type_name(type)}", table(type)
    return f"""
CREATE TABLE IF NOT EXISTS {t} (
    key         TEXT    NOT NULL PRIMARY KEY,
    recorded_at INTEGER NOT NULL,
    exchange    TEXT    NOT NULL,
    routing_key TEXT    NOT NULL,
    user_id     TEXT,
    robot_id    TEXT,
    message_id  TEXT,
    mission_id  TEXT,
    sent_at     INTEGER,
    seq         INTEGER,
    known       INTEGER NOT NULL,
    problem     TEXT,
    document    TEXT,
    raw         BLOB,
    properties  TEXT    NOT NULL,
    size        INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS "{name}__time" ON {t} (recorded_at, key);
CREATE INDEX IF NOT EXISTS "{name}__robot_time" ON {t} (robot_id, recorded_at);
CREATE INDEX IF NOT EXISTS "{name}__message" ON {t} (message_id);
CREATE INDEX IF NOT EXISTS "{name}__mission_time" ON {t} (mission_id, recorded_at);
"""


def json_path(path: str) -> str:
    """``body.pose.x`` as a SQLite JSON path literal (segments checked, so it is safe to inline)."""
    out = "$"
    for segment in check_path(path):
        out += f"[{segment}]" if segment.isdigit() else f'."{segment}"'
    return out


def extract(path: str) -> str:
    return f"json_extract(document, '{json_path(path)}')"


def json_type(path: str) -> str:
    return f"json_type(document, '{json_path(path)}')"


def _same_kind(path: str, value: Any) -> str:
    """SQLite compares across types; MongoDB only within one. This guard makes them agree."""
    if isinstance(value, bool):
        return f"{json_type(path)} = '{'true' if value else 'false'}'"
    if isinstance(value, str):
        return f"{json_type(path)} = 'text'"
    return f"{json_type(path)} {NUMBER_TYPES}"


def _equals(path: str, value: Any) -> tuple[str, list[Any]]:
    if value is None:
        return f"{extract(path)} IS NULL", []
    if isinstance(value, bool):  # json_extract gives 1/0; the guard tells true from the number 1
        return f"({extract(path)} = ? AND {_same_kind(path, value)})", [int(value)]
    return f"({extract(path)} = ? AND {_same_kind(path, value)})", [value]


def condition_sql(condition: Condition) -> tuple[str, list[Any]]:
    path, value = condition.path, condition.value
    if condition.op is Op.EQ:
        return _equals(path, value)
    if condition.op is Op.NE:
        if value is None:
            return f"{extract(path)} IS NOT NULL", []
        sql, params = _equals(path, value)
        return f"NOT COALESCE({sql}, 0)", params
    if condition.op is Op.CONTAINS:
        return f"({json_type(path)} = 'text' AND instr({extract(path)}, ?) > 0)", [value]
    return f"({extract(path)} {SQL_OPS[condition.op]} ? AND {_same_kind(path, value)})", [value]


def where(query_filters: Iterable[tuple[str, list[Any]]]) -> tuple[str, list[Any]]:
    clauses, params = [], []
    for clause, values in query_filters:
        clauses.append(clause)
        params.extend(values)
    return (" WHERE " + " AND ".join(clauses) if clauses else ""), params


def provenance_filters(
    robot_id: str | None = None,
    message_id: str | None = None,
    since: datetime | None = None,
    until: datetime | None = None,
) -> list[tuple[str, list[Any]]]:
    filters: list[tuple[str, list[Any]]] = []
    if robot_id is not None:
        filters.append(("robot_id = ?", [robot_id]))
    if message_id is not None:
        filters.append(("message_id = ?", [message_id]))
    if since is not None:
        filters.append(("recorded_at >= ?", [to_micros(since)]))
    if until is not None:
        filters.append(("recorded_at < ?", [to_micros(until)]))
    return filters


def find_sql(query: RecordQuery) -> tuple[str, list[Any]]:
    """The SELECT a query runs (the index test reads its plan)."""
    filters = provenance_filters(query.robot_id, query.message_id, query.since, query.until)
    if query.mission_id is not None:
        filters.append(("mission_id = ?", [query.mission_id]))
    if query.after is not None:  # a row value, which the (recorded_at, key) index serves
        filters.append(("(recorded_at, key) > (?, ?)", [to_micros(query.after[0]), query.after[1]]))
    filters.extend(condition_sql(condition) for condition in query.conditions)
    clause, params = where(filters)
    order = "DESC" if query.newest_first else "ASC"
    sql = f"SELECT * FROM {table(query.type)}{clause} ORDER BY recorded_at {order}, key {order}"
    if query.limit is not None:
        sql += f" LIMIT {int(query.limit)}"
    return sql, params


def _dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def _row(record: RecordedMessage) -> tuple[Any, ...]:
    return (
        record.key,
        to_micros(record.recorded_at),
        record.exchange,
        record.routing_key,
        record.user_id,
        record.robot_id,
        record.message_id,
        record.mission_id,
        to_micros(record.sent_at) if record.sent_at else None,
        record.seq,
        int(record.known),
        record.problem,
        None if record.raw is not None else _dumps(record.document),
        record.raw,
        _dumps(record.properties),
        record.size,
    )


def _record(type: str, row: sqlite3.Row) -> RecordedMessage:
    return RecordedMessage(
        key=row["key"],
        type=type,
        recorded_at=from_micros(row["recorded_at"]),
        exchange=row["exchange"],
        routing_key=row["routing_key"],
        user_id=row["user_id"],
        robot_id=row["robot_id"],
        message_id=row["message_id"],
        mission_id=row["mission_id"],
        sent_at=from_micros(row["sent_at"]) if row["sent_at"] is not None else None,
        seq=row["seq"],
        known=bool(row["known"]),
        problem=row["problem"],
        document=json.loads(row["document"]) if row["document"] is not None else None,
        raw=row["raw"],
        properties=json.loads(row["properties"]),
        size=row["size"],
    )


def folder_bytes(folder: Path) -> int:
    """The bytes of the files under ``folder`` (none when there is none)."""
    total = 0
    for parent, _, names in os.walk(folder):
        for name in names:
            try:
                total += (Path(parent) / name).stat().st_size
            except FileNotFoundError:  # deleted meanwhile
                pass
    return total


def _sqrt(value: float | None) -> float | None:
    return None if value is None else math.sqrt(max(0.0, value))


class SQLiteRecordingStore(SQLiteStore, RecordingStore):
    name = "sqlite"

    def __init__(self, path: Path, max_field_indexes: int = DEFAULT_FIELD_INDEXES_MAX) -> None:
        super().__init__(path)
        self.bookkeeping = Bookkeeping(self, max_field_indexes)

    def _prepare(self, db: sqlite3.Connection) -> None:
        super()._prepare(db)
        # SQLite's own sqrt() is a compile-time option; this one is always there.
        db.create_function("fleetbus_sqrt", 1, _sqrt, deterministic=True)

    @staticmethod
    def _tables(db: sqlite3.Connection) -> list[str]:
        rows = db.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table' AND name LIKE ? ESCAPE '\\'",
            (TABLE_PREFIX.replace("_", "\\_") + "%",),
        )
        return sorted(row[0][len(TABLE_PREFIX) :] for row in rows)

    @staticmethod
    def _exists(db: sqlite3.Connection, type: str) -> bool:
        check_type_name(type)
        row = db.execute(
            "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?", (TABLE_PREFIX + type,)
        ).fetchone()
        return row is not None

    async def _write_records(self, records: Sequence[RecordedMessage]) -> list[WriteResult]:
        rows = [(record.type, _row(record)) for record in records]
        types = sorted({type for type, _ in rows})
        placeholders = ",".join("?" * len(COLUMNS))
        insert = {
            t: f"INSERT INTO {table(t)} ({','.join(COLUMNS)}) VALUES ({placeholders}) "
            "ON CONFLICT (key) DO NOTHING"
            for t in types
        }

        def write(db: sqlite3.Connection) -> list[WriteResult]:
            # new types get their table first (executescript commits on its own)
            for t in types:
                if not self._exists(db, t):
                    db.executescript(table_schema(t))
            return in_transaction(
                db,
                lambda: [WriteResult(inserted=db.execute(insert[t], row).rowcount == 1) for t, row in rows],
            )

        return await self._run(write) if rows else []

    async def find_recorded(self, query: RecordQuery) -> list[RecordedMessage]:
        sql, params = find_sql(query)

        def find(db: sqlite3.Connection) -> list[RecordedMessage]:
            if not self._exists(db, query.type):
                return []
            return [_record(query.type, row) for row in db.execute(sql, params)]

        return await self._run(find)

    async def recorded_types(self) -> list[str]:
        return await self._run(self._tables)

    async def type_summary(self, type: str) -> TypeSummary:
        def summary(db: sqlite3.Connection) -> TypeSummary:
            if not self._exists(db, type):
                return TypeSummary(type, 0, 0, None, None)
            count, size, first, last = db.execute(
                "SELECT count(*), coalesce(sum(size), 0), min(recorded_at), max(recorded_at) "
                f"FROM {table(type)}"
            ).fetchone()
            return TypeSummary(
                type,
                count,
                size,
                from_micros(first) if first is not None else None,
                from_micros(last) if last is not None else None,
            )

        return await self._run(summary)

    async def ensure_field_index(self, type: str, paths: Sequence[str]) -> None:
        paths = tuple(paths)
        columns = ", ".join([*(extract(path) for path in paths), "recorded_at"])
        name = (
            f"{TABLE_PREFIX}{check_type_name(type)}__f_{hashlib.sha1(repr(paths).encode()).hexdigest()[:12]}"
        )
        now = datetime.now(timezone.utc)
        await self._run(lambda db: None if self._exists(db, type) else db.executescript(table_schema(type)))
        if await self.bookkeeping.used(type, name, now):
            return
        # a new shape: make room by dropping the least recently used
        for old_name, old_paths in await self.bookkeeping.make_room(type):
            await self._run(lambda db, old_name=old_name: db.execute(f'DROP INDEX IF EXISTS "{old_name}"'))
            log.info(
                "%s: dropped the least recently used field index %s (%d kept)",
                type,
                old_paths,
                self.bookkeeping.max_field_indexes,
            )
        create = f'CREATE INDEX IF NOT EXISTS "{name}" ON {table(type)} ({columns})'
        await self._run(lambda db: db.execute(create))
        await self.bookkeeping.made(type, name, paths, now)

    async def outcome_stats(
        self,
        type: str,
        fields: OutcomeFields,
        since: datetime | None = None,
        until: datetime | None = None,
        robot_id: str | None = None,
    ) -> list[OutcomeStats]:
        filters = [
            (f"{json_type(fields.name)} = 'text'", []),
            (f"{json_type(fields.duration)} {NUMBER_TYPES}", []),
            *provenance_filters(robot_id, None, since, until),
        ]
        clause, params = where(filters)
        sql = f"""
            SELECT name, successes, runs, total / runs AS mean,
                   fleetbus_sqrt(squares / runs - (total / runs) * (total / runs)) AS std
            FROM (
                SELECT {extract(fields.name)} AS name,
                       sum(CASE WHEN {json_type(fields.success)} = 'true' THEN 1 ELSE 0 END) AS successes,
                       count(*) AS runs,
                       sum(CAST({extract(fields.duration)} AS REAL)) AS total,
                       sum(CAST({extract(fields.duration)} AS REAL) * {extract(fields.duration)}) AS squares
                FROM {table(type)}{clause}
                GROUP BY name
            )
            ORDER BY name
        """

        def compute(db: sqlite3.Connection) -> list[OutcomeStats]:
            if not self._exists(db, type):
                return []
            return [OutcomeStats.of(*row) for row in db.execute(sql, params)]

        return await self._run(compute)

    async def _delete_records_before(self, type: str, before: datetime) -> int:
        def delete(db: sqlite3.Connection) -> int:
            if not self._exists(db, type):
                return 0
            return in_transaction(
                db,
                lambda: (
                    db.execute(
                        f"DELETE FROM {table(type)} WHERE recorded_at < ?", (to_micros(before),)
                    ).rowcount
                ),
            )

        return await self._run(delete)

    async def oldest_recorded(self, type: str, limit: int) -> list[tuple[str, int]]:
        def oldest(db: sqlite3.Connection) -> list[tuple[str, int]]:
            if not self._exists(db, type):
                return []
            rows = db.execute(
                f"SELECT key, size FROM {table(type)} ORDER BY recorded_at, key LIMIT ?", (int(limit),)
            )
            return [(row[0], row[1]) for row in rows]

        return await self._run(oldest)

    async def _delete_records(self, type: str, keys: Sequence[str]) -> int:
        keys = list(keys)

        def delete(db: sqlite3.Connection) -> int:
            if not keys or not self._exists(db, type):
                return 0

            def work() -> int:
                deleted = 0
                for start in range(0, len(keys), DELETE_CHUNK):
                    chunk = keys[start : start + DELETE_CHUNK]
                    deleted += db.execute(
                        f"DELETE FROM {table(type)} WHERE key IN ({','.join('?' * len(chunk))})", chunk
                    ).rowcount
                return deleted

            return in_transaction(db, work)

        return await self._run(delete)

    def blob_folder(self) -> Path:
        """Where the blobs are: files named by their digest in a folder beside the database."""
        return self.path.with_name(self.path.name + ".blobs")

    def _blob_path(self, digest: str) -> Path:
        return self.blob_folder() / check_digest(digest)[:2] / digest

    async def put_blob(self, digest: str, data: bytes) -> bool:
        path = self._blob_path(digest)

        def put() -> bool:
            if path.exists():
                return False
            made = not path.parent.exists()
            private_dir(path.parent)  # the recording is its owner's only, whoever's umask writes it
            temporary = path.with_name(f"{digest}.{uuid.uuid4().hex}.tmp")
            with os.fdopen(
                os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, FILE_MODE), "wb"
            ) as stream:
                stream.write(data)
                stream.flush()
                os.fsync(stream.fileno())
            temporary.replace(path)
            # the name, and a new folder's, durable too: a record acked after this names the blob
            fsync_dir(path.parent)
            if made:
                fsync_dir(path.parent.parent)
            return True

        return await asyncio.to_thread(put)

    async def get_blob(self, digest: str) -> bytes | None:
        path = self._blob_path(digest)
        return await asyncio.to_thread(lambda: path.read_bytes() if path.exists() else None)

    async def delete_blobs(self, digests: Sequence[str]) -> int:
        paths = [self._blob_path(digest) for digest in digests]

        def delete() -> int:
            deleted = 0
            for path in paths:
                try:
                    path.unlink()
                    deleted += 1
                except FileNotFoundError:
                    pass
            return deleted

        return await asyncio.to_thread(delete)

    async def database_bytes(self) -> int:
        files = (self.path, self.path.with_name(self.path.name + "-wal"))
        database = await self._run(lambda db: sum(path.stat().st_size for path in files if path.exists()))
        return database + await asyncio.to_thread(folder_bytes, self.blob_folder())
