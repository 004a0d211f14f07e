"""Map versions on SQLite: staged chunks and a blob table, one repository of `sqlite_repositories`."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence
from datetime import datetime, timezone
from typing import Any

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.maps import MapRejected, MapStore, MapVersion
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

MAP_SCHEMA = """
CREATE TABLE IF NOT EXISTS map_staging (
    map_id    TEXT    NOT NULL,
    idx       INTEGER NOT NULL,
    data      BLOB    NOT NULL,
    staged_at INTEGER,
    PRIMARY KEY (map_id, idx)
);
CREATE TABLE IF NOT EXISTS maps (
    version    INTEGER PRIMARY KEY AUTOINCREMENT,
    robot_id   TEXT    NOT NULL,
    epoch      TEXT    NOT NULL,
    seq        INTEGER NOT NULL,
    metadata   TEXT    NOT NULL,
    created_at INTEGER NOT NULL,
    size       INTEGER NOT NULL,
    sha256     TEXT    NOT NULL,
    chunk_size INTEGER NOT NULL,
    chunks     INTEGER NOT NULL,
    read_at    INTEGER,
    UNIQUE (robot_id, epoch, seq)
);
CREATE TABLE IF NOT EXISTS map_blobs (
    version INTEGER NOT NULL,
    idx     INTEGER NOT NULL,
    data    BLOB    NOT NULL,
    PRIMARY KEY (version, idx)
);
"""


def _map_version(row: sqlite3.Row) -> MapVersion:
    return MapVersion(
        version=row["version"],
        robot_id=row["robot_id"],
        epoch=row["epoch"],
        seq=row["seq"],
        metadata=json.loads(row["metadata"]),
        created_at=from_micros(row["created_at"]),
        size=row["size"],
        sha256=row["sha256"],
        chunk_size=row["chunk_size"],
        chunks=row["chunks"],
    )


class SQLiteMaps(OnSQLite, MapStore):
    async def stage_map_chunk(self, map_id: str, index: int, data: bytes) -> None:
        now = to_micros(datetime.now(timezone.utc))
        await self._run(
            lambda db: db.execute(
                "INSERT OR IGNORE INTO map_staging (map_id, idx, data, staged_at) VALUES (?, ?, ?, ?)",
                (map_id, index, data, now),
            )
        )

    async def staged_map_chunks(self, map_id: str) -> dict[int, bytes]:
        rows = await self._run(
            lambda db: db.execute("SELECT idx, data FROM map_staging WHERE map_id = ?", (map_id,)).fetchall()
        )
        return {row["idx"]: bytes(row["data"]) for row in rows}

    async def commit_map(
        self,
        robot_id: str,
        epoch: str,
        seq: int,
        image: bytes,
        metadata: dict[str, Any],
        created_at: datetime,
        sha256: str,
        chunk_size: int,
        staged_map_id: str | None,
    ) -> MapVersion:
        pieces = [image[i : i + chunk_size] for i in range(0, len(image), chunk_size)]

        def commit(db: sqlite3.Connection) -> MapVersion:
            def work() -> MapVersion:
                row = db.execute(
                    "SELECT * FROM maps WHERE robot_id = ? AND epoch = ? AND seq = ?", (robot_id, epoch, seq)
                ).fetchone()
                if row is None:
                    cursor = db.execute(
                        "INSERT INTO maps "
                        "(robot_id, epoch, seq, metadata, created_at, size, sha256, chunk_size, chunks) "
                        "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                        (
                            robot_id,
                            epoch,
                            seq,
                            json.dumps(metadata),
                            to_micros(created_at),
                            len(image),
                            sha256,
                            chunk_size,
                            len(pieces),
                        ),
                    )
                    db.executemany(
                        "INSERT INTO map_blobs (version, idx, data) VALUES (?, ?, ?)",
                        [(cursor.lastrowid, i, piece) for i, piece in enumerate(pieces)],
                    )
                    row = db.execute("SELECT * FROM maps WHERE version = ?", (cursor.lastrowid,)).fetchone()
                if staged_map_id is not None:
                    db.execute("DELETE FROM map_staging WHERE map_id = ?", (staged_map_id,))
                return _map_version(row)

            return in_transaction(db, work)

        return await self._run(commit)

    async def committed_map(self, robot_id: str, epoch: str, seq: int) -> MapVersion | None:
        row = await self._run(
            lambda db: db.execute(
                "SELECT * FROM maps WHERE robot_id = ? AND epoch = ? AND seq = ?", (robot_id, epoch, seq)
            ).fetchone()
        )
        return _map_version(row) if row else None

    async def map_version(self, version: int | None = None) -> MapVersion | None:
        if version is None:
            sql, params = "SELECT * FROM maps ORDER BY version DESC LIMIT 1", ()
        else:
            sql, params = "SELECT * FROM maps WHERE version = ?", (version,)
        row = await self._run(lambda db: db.execute(sql, params).fetchone())
        return _map_version(row) if row else None

    async def map_chunk(self, version: int, index: int) -> bytes:
        row = await self._run(
            lambda db: db.execute(
                "SELECT data FROM map_blobs WHERE version = ? AND idx = ?", (version, index)
            ).fetchone()
        )
        if row is None:
            raise MapRejected(f"map version {version} has no chunk {index}")
        return bytes(row["data"])

    async def map_versions(self) -> list[MapVersion]:
        rows = await self._run(lambda db: db.execute("SELECT * FROM maps ORDER BY version DESC").fetchall())
        return [_map_version(row) for row in rows]

    async def note_map_read(self, version: int, at: datetime) -> None:
        await self._run(
            lambda db: db.execute("UPDATE maps SET read_at = ? WHERE version = ?", (to_micros(at), version))
        )

    async def map_reads(self) -> dict[int, datetime]:
        rows = await self._run(
            lambda db: db.execute("SELECT version, read_at FROM maps WHERE read_at IS NOT NULL").fetchall()
        )
        return {row[0]: from_micros(row[1]) for row in rows}

    async def delete_map_versions(self, versions: Sequence[int]) -> int:
        chosen = [(version,) for version in versions]

        def delete(db: sqlite3.Connection) -> int:
            def work() -> int:
                db.executemany("DELETE FROM map_blobs WHERE version = ?", chosen)
                return sum(db.execute("DELETE FROM maps WHERE version = ?", row).rowcount for row in chosen)

            return in_transaction(db, work)

        return await self._run(delete) if chosen else 0

    async def expire_staged_chunks(self, before: datetime, limit: int) -> dict[str, int]:
        def expire(db: sqlite3.Connection) -> dict[str, int]:
            def work() -> dict[str, int]:
                stale = db.execute(
                    "SELECT map_id, count(*) FROM map_staging "
                    "GROUP BY map_id HAVING max(staged_at) < ? LIMIT ?",
                    (to_micros(before), int(limit)),
                ).fetchall()
                db.executemany("DELETE FROM map_staging WHERE map_id = ?", [(row[0],) for row in stale])
                return {row[0]: row[1] for row in stale}

            return in_transaction(db, work)

        return await self._run(expire)
