"""Run the real worker (or recorder) on its own thread and event loop, beside synchronous code.

The demo and the tests use it next to pika's blocking robot clients, which would otherwise
block the worker's event loop.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Awaitable, Callable
from types import TracebackType
from typing import Any, Generic, TypeVar

from fleetbus.settings import Settings
from fleetbus.workers.ingest import IngestStats
from fleetbus.workers.runner import WorkerContext, run_worker

C = TypeVar("C")
T = TypeVar("T", bound="LoopThread[Any]")
Runner = Callable[[asyncio.Event, Callable[[C], None]], Awaitable[None]]


class LoopThread(Generic[C]):
    """``run(stop, on_started)`` on a thread of its own until :meth:`stop`; ``context`` once started."""

    def __init__(self, run: Runner[C], name: str) -> None:
        self._run = run
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._started = threading.Event()
        self.context: C | None = None
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._main, name=name, daemon=True)

    def _main(self) -> None:
        async def body() -> None:
            self._loop = asyncio.get_running_loop()
            self._stop = asyncio.Event()
            await self._run(self._stop, self._on_started)

        try:
            asyncio.run(body())
        except BaseException as error:  # handed to the caller by stop()
            self.error = error
        finally:
            self._started.set()

    def _on_started(self, context: C) -> None:
        self.context = context
        self._started.set()

    def start(self: T) -> T:
        """Start, and return once it consumes (its queues exist), or once it failed to start."""
        self._thread.start()
        self._started.wait()
        return self

    def stop(self, timeout: float = 60.0) -> None:
        """Ask it to stop as on SIGTERM, wait for it, and re-raise what killed it."""
        if self._loop is not None and self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise TimeoutError(f"{self._thread.name} did not stop within {timeout:.0f} s")
        if self.error is not None:
            raise self.error

    @property
    def running(self) -> bool:
        """It has not ended (by itself, or stopped)."""
        return self._thread.is_alive()

    def __enter__(self: T) -> T:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


class WorkerThread(LoopThread[WorkerContext]):
    def __init__(self, settings: Settings, url: str) -> None:
        """The worker logging in with ``url``, the ``fleetbus`` account's (:mod:`fleetbus.workers.setup`)."""
        super().__init__(
            lambda stop, started: run_worker(settings, url, stop, on_started=started), "fleetbus-worker"
        )

    def stats(self) -> IngestStats:
        """The running worker's counters (a snapshot is not needed: they only grow)."""
        return self.context.stats if self.context else IngestStats()
