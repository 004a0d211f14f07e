"""One SQLite file, used from one thread the store owns, off the event loop.

``synchronous=FULL`` in WAL mode makes each commit durable before the call returns, which is
what a worker's ack waits for. A failed call never leaves its transaction open, and a locked or
unreachable database is reported as :class:`~workers.store.base.StoreUnavailable` (retry later).
"""

from __future__ import annotations

import asyncio
import sqlite3
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TypeVar

from workers.store.base import StoreUnavailable

T = TypeVar("T")

TRANSIENT = ("locked", "busy", "unable to open", "disk i/o error", "readonly")


def in_transaction(db: sqlite3.Connection, work: Callable[[], T]) -> T:
    db.execute("BEGIN IMMEDIATE")
    try:
        result = work()
    except BaseException:
        db.execute("ROLLBACK")
        raise
    db.execute("COMMIT")
    return result


class SQLiteDatabase:
    """Subclasses create their tables in :meth:`_prepare`."""

    def __init__(self, path: Path, busy_timeout: float = 2.0) -> None:
        self.path = path
        self._busy_timeout = busy_timeout
        self._executor: ThreadPoolExecutor | None = None
        self._db: sqlite3.Connection | None = None

    def _prepare(self, db: sqlite3.Connection) -> None:
        """Create tables and indexes on a new connection; idempotent."""

    async def _run(self, work: Callable[[sqlite3.Connection], T]) -> T:
        if self._executor is None:
            raise RuntimeError("the store is not open")

        def call() -> T:
            try:
                if self._db is None:
                    self._db = self._connect()
                return work(self._db)
            except BaseException as error:
                # whatever failed, the next call must not find this transaction still open
                if self._db is not None and self._db.in_transaction:
                    self._db.rollback()
                if isinstance(error, sqlite3.OperationalError) and any(
                    word in str(error).lower() for word in TRANSIENT
                ):
                    raise StoreUnavailable(f"SQLite {self.path}: {error}") from error
                raise

        return await asyncio.get_running_loop().run_in_executor(self._executor, call)

    def _connect(self) -> sqlite3.Connection:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        db = sqlite3.connect(self.path, timeout=self._busy_timeout, isolation_level=None)
        db.row_factory = sqlite3.Row
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        self._prepare(db)
        return db

    async def open(self) -> None:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fleetbus-sqlite")
        await self._run(lambda db: None)

    async def close(self) -> None:
        if self._executor is None:
            return

        def shut(db: sqlite3.Connection) -> None:
            db.close()
            self._db = None

        if self._db is not None:
            await self._run(shut)
        self._executor.shutdown(wait=True)
        self._executor = None
