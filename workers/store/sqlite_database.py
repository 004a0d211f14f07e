"""One SQLite file and two connections: the store's thread runs the calls that may wait, off the
event loop; small urgent calls run on the caller's thread, on a connection that never waits, and
go before the store's thread's next call.

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

from fleetbus.private_files import private_file
from fleetbus.workers.store.base import StoreUnavailable

T = TypeVar("T")

TRANSIENT = ("locked", "busy", "unable to open", "disk i/o error", "readonly")
#: Seconds a small call waits before trying again while another process (or another caller's
#: small call) holds what it needs. SQLite's own busy handler sleeps 1, 2, 5, 10, 15, 20, 25 ms
#: and more between tries, and a process that writes in a loop takes the lock again in between.
RETRY_S = 0.001
#: The size (bytes) SQLite cuts its write-ahead log back to once it is checkpointed.
WAL_KEPT_BYTES = 64 * 1024 * 1024


class _Busy(Exception):
    """Another connection holds the write lock (raised only where no wait was allowed)."""


class _Taken(Exception):
    """The caller's-thread connection is in use by another thread."""


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


def _wake(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)


class SQLiteDatabase:
    """Subclasses create their tables in :meth:`_prepare`."""

    def __init__(self, path: Path, busy_timeout: float = 2.0) -> None:
        self.path = path
        self._busy_timeout = busy_timeout
        self._executor: ThreadPoolExecutor | None = None
        self._db: sqlite3.Connection | None = None
        """The store's thread's connection: waits up to the busy timeout for the write lock."""
        self._inline: sqlite3.Connection | None = None
        """The callers' connection (busy timeout 0), used by one thread at a time."""
        self._inline_in_use = threading.Lock()
        # the store's thread's calls, counted as they end, and the callers waiting for one to end
        self._signals = threading.Condition()
        self._thread_busy = False
        self._thread_calls_ended = 0
        self._waiting: list[tuple[asyncio.AbstractEventLoop, asyncio.Future[None]]] = []
        self._small_waiting = 0
        """Small calls trying to run: the store's thread begins no call meanwhile."""

    def _prepare(self, db: sqlite3.Connection) -> None:
        """Create tables and indexes on a new connection; idempotent."""

    async def _run(self, work: Callable[[sqlite3.Connection], T], *, small: bool = False) -> T:
        """Run ``work``: a ``small`` call on the calling thread when that is safe and cheap, else on
        the store's thread.

        Handing a call to the store's thread and back costs more than a small call itself on two
        shared cores, and a hazard's way to the wardens makes several. So a ``small`` call runs
        right here, on a connection of its own: its reads never wait (WAL), and its writes never
        wait here for the write lock (busy timeout 0). While it tries, the store's thread begins no
        new call; when that thread holds the lock (a bulk batch), the small call waits, without
        blocking its event loop, for that one transaction to end and goes next, ahead of the
        thread's queue: a hazard waits for one batch of telemetry, not for all of them. When another
        process holds the lock, it tries again every :data:`RETRY_S` until the busy timeout, then
        hands the call to the store's thread. Large calls (a batch under load) go to the store's
        thread, so that the event loop keeps receiving.
        """
        if self._executor is None:
            raise RuntimeError("the store is not open")
        if small:
            loop = asyncio.get_running_loop()
            deadline = loop.time() + self._busy_timeout
            with self._signals:
                self._small_waiting += 1
            try:
                while loop.time() < deadline:
                    ended = self._thread_calls_ended
                    try:
                        return self._run_inline(work)
                    except _Taken:
                        await asyncio.sleep(RETRY_S)  # another thread's small call: next
                    except _Busy:
                        if self._thread_calls_ended != ended:
                            continue  # the store's thread just let go: at once again
                        if self._thread_busy:
                            await self._thread_call_ended(ended)
                        else:
                            await asyncio.sleep(RETRY_S)  # another process writes
            finally:
                with self._signals:
                    self._small_waiting -= 1
                    self._signals.notify_all()
        return await asyncio.get_running_loop().run_in_executor(self._executor, self._call, work)

    def _run_inline(self, work: Callable[[sqlite3.Connection], T]) -> T:
        if not self._inline_in_use.acquire(blocking=False):
            raise _Taken
        try:
            if self._inline is None:
                raise RuntimeError("the store is closed")
            return self._attempt(self._inline, work)
        finally:
            self._inline_in_use.release()

    async def _thread_call_ended(self, ended: int) -> None:
        """Return once the store's thread has ended a call since it had ended ``ended`` of them."""
        loop = asyncio.get_running_loop()
        future = loop.create_future()
        with self._signals:
            if self._thread_calls_ended != ended:
                return
            self._waiting.append((loop, future))
        await future

    def _call(self, work: Callable[[sqlite3.Connection], T]) -> T:
        """On the store's thread: after the small calls trying now, wait for the write lock up to
        the busy timeout."""
        with self._signals:
            self._signals.wait_for(lambda: not self._small_waiting, self._busy_timeout)
            self._thread_busy = True
        try:
            if self._db is None:
                self._db = self._connect(timeout=self._busy_timeout)
                self._prepare(self._db)
            try:
                return self._attempt(self._db, work)
            except _Busy as busy:
                raise self._unavailable(busy.__cause__) from busy.__cause__
        finally:
            self._thread_busy = False
            self._let_go()

    def _let_go(self) -> None:
        """The store's thread let the write lock go: wake the small calls waiting for that."""
        with self._signals:
            self._thread_calls_ended += 1
            waiting, self._waiting = self._waiting, []
        for loop, future in waiting:
            loop.call_soon_threadsafe(_wake, future)

    def let_small_calls_in(self, db: sqlite3.Connection) -> None:
        """Between two parts of a long write on the store's thread (in a transaction of
        :func:`in_transaction`): when small calls wait for the write lock, commit what is written,
        let them go first, and begin again. A hazard then waits for one part of a bulk batch, not
        the whole of it; with nobody waiting it costs nothing."""
        if not self._small_waiting or db is not self._db:
            return
        db.execute("COMMIT")
        self._let_go()
        with self._signals:
            self._signals.wait_for(lambda: not self._small_waiting, self._busy_timeout)
        db.execute("BEGIN IMMEDIATE")

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

    def _connect(self, timeout: float) -> sqlite3.Connection:
        private_file(self.path)  # its WAL and shared-memory files take its mode
        db = sqlite3.connect(self.path, timeout=timeout, isolation_level=None, check_same_thread=False)
        db.row_factory = sqlite3.Row
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        # A WAL grows while a long read (an export, a replay) keeps it from being checkpointed
        # and, without this, keeps that size on disk for good once it is.
        db.execute(f"PRAGMA journal_size_limit={WAL_KEPT_BYTES}")
        return db

    async def open(self) -> None:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fleetbus-sqlite")
        await self._run(lambda db: None)  # the store's connection, and the tables

        def connect_inline() -> None:
            db = self._connect(timeout=self._busy_timeout)
            db.execute("PRAGMA busy_timeout = 0")
            with self._inline_in_use:
                if self._inline is None:
                    self._inline, db = db, None
            if db is not None:  # opened twice
                db.close()

        await asyncio.get_running_loop().run_in_executor(self._executor, connect_inline)

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
        with self._inline_in_use:
            if self._inline is not None:
                self._inline.close()
                self._inline = None
