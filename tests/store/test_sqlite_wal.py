"""A write-ahead log that grew (a large transaction, or writes while a long read held it) is cut
back once it is checkpointed, instead of keeping its largest size on disk for good."""

from __future__ import annotations

import asyncio
import sqlite3
from pathlib import Path

import pytest

import fleetbus.workers.store.sqlite_database as sqlite_database
from fleetbus.workers.store.sqlite_database import SQLiteDatabase


class Blobs(SQLiteDatabase):
    def _prepare(self, db: sqlite3.Connection) -> None:
        db.execute("CREATE TABLE IF NOT EXISTS blobs (body BLOB)")

    async def put(self, count: int, size: int) -> None:
        def write(db: sqlite3.Connection) -> None:
            db.execute("BEGIN IMMEDIATE")
            db.executemany("INSERT INTO blobs VALUES (?)", [(b"x" * size,)] * count)
            db.execute("COMMIT")

        await self._run(write)

    async def checkpoint(self) -> None:
        await self._run(lambda db: db.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchall())


def test_the_write_ahead_log_is_cut_back_after_a_large_transaction(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(sqlite_database, "WAL_KEPT_BYTES", 256 * 1024)
    wal = Path(f"{tmp_path / 'store.sqlite3'}-wal")

    sizes: list[int] = []

    async def run() -> None:
        store = Blobs(tmp_path / "store.sqlite3")
        await store.open()
        try:
            await store.put(64, 64 * 1024)  # 4 MiB in one transaction: the log holds it all
            sizes.append(wal.stat().st_size)  # noqa: ASYNC240 (a test's one look)
            await store.checkpoint()
            await store.put(1, 10)  # the next writer starts the log again from its beginning
            sizes.append(wal.stat().st_size)  # noqa: ASYNC240
        finally:
            await store.close()

    asyncio.run(run())
    grown, after = sizes
    assert grown > 4 * 1024 * 1024
    assert after <= 256 * 1024
