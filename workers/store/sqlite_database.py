"""One SQLite file and one connection, used by one thread at a time: small calls run on the caller's
thread when the database is free, the rest on a thread the store owns, off the event loop.

``synchronous=FULL`` in WAL mode makes each commit durable before the call returns, which is
what a worker's ack waits for. A failed call never leaves its transaction open, and a locked or
unreachable database is reported as :class:`~workers.store.base.StoreUnavailable` (retry later).
"""

from __future__ import annotations

import asyncio
import sqlite3
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TypeVar

from workers.store.base import StoreUnavailable

T = TypeVar("T")

TRANSIENT = ("locked", "busy", "unable to open", "disk i/o error", "readonly")


class _Busy(Exception):
    """Another connection holds the write lock (raised only where no wait was allowed)."""


def _is_busy(error: sqlite3.OperationalError) -> bool:
    return (error.sqlite_errorcode & 0xFF) in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED)


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
        # the connection is used by one thread at a time: the caller's, or the store's own
        self._in_use = threading.Lock()

    def _prepare(self, db: sqlite3.Connection) -> None:
        """Create tables and indexes on a new connection; idempotent."""

    async def _run(self, work: Callable[[sqlite3.Connection], T], *, small: bool = False) -> T:
        """Run ``work`` on the connection: on the calling thread when that is safe and cheap, else on
        the store's thread.

        Handing a call to the store's thread and back costs more than a small call itself on two
        shared cores, and a hazard's way to the wardens makes several. So a ``small`` call runs
        right here when the connection is free and no other process holds the write lock. It never
        waits for that lock here (the connection's ``busy_timeout`` is 0 outside the store's
        thread): a locked database sends the call to the store's thread, where it waits as long as
        it may. Large calls (a batch under load) go to the store's thread, so that the event loop
        keeps receiving meanwhile.
        """
        if self._executor is None:
            raise RuntimeError("the store is not open")
        if small and self._db is not None and self._in_use.acquire(blocking=False):
            try:
                return self._attempt(self._db, work)
            except _Busy:
                pass  # another process writes: wait for it on the store's thread
            finally:
                self._in_use.release()
        return await asyncio.get_running_loop().run_in_executor(self._executor, self._call, work)

    def _call(self, work: Callable[[sqlite3.Connection], T]) -> T:
        """On the store's thread: wait for the write lock up to the busy timeout."""
        with self._in_use:
            if self._db is None:
                self._db = self._connect()
            db = self._db
            db.execute(f"PRAGMA busy_timeout = {int(self._busy_timeout * 1000)}")
            try:
                return self._attempt(db, work)
            except _Busy as busy:
                raise self._unavailable(busy.__cause__) from busy.__cause__
            finally:
                if self._db is not None:  # not closed by the work
                    db.execute("PRAGMA busy_timeout = 0")

    def _attempt(self, db: sqlite3.Connection, work: Callable[[sqlite3.Connection], T]) -> T:
        try:
            return work(db)
        except BaseException as error:
            # whatever failed, the next call must not find this transaction still open
            if db.in_transaction:
                db.rollback()
            if isinstance(error, sqlite3.OperationalError):
                if _is_busy(error):
                    raise _Busy from error
                if any(word in str(error).lower() for word in TRANSIENT):
                    raise self._unavailable(error) from error
            raise

    def _unavailable(self, error: BaseException | None) -> StoreUnavailable:
        return StoreUnavailable(f"SQLite {self.path}: {error}")

    def _connect(self) -> sqlite3.Connection:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        db = sqlite3.connect(
            self.path, timeout=self._busy_timeout, isolation_level=None, check_same_thread=False
        )
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
