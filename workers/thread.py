"""Run the real worker on its own thread and event loop, beside synchronous code.

The demo and the tests use it next to pika's blocking robot clients, which would otherwise
block the worker's event loop.
"""

from __future__ import annotations

import asyncio
import threading
from types import TracebackType

from broker.endpoint import BrokerEndpoint
from fleetbus.config import Settings
from workers.ingest import IngestStats
from workers.runner import WorkerContext, run_worker


class WorkerThread:
    def __init__(self, settings: Settings, endpoint: BrokerEndpoint) -> None:
        self._settings = settings
        self._endpoint = endpoint
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._started = threading.Event()
        self._context: WorkerContext | None = None
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._main, name="fleetbus-worker", daemon=True)

    def _main(self) -> None:
        async def body() -> None:
            self._loop = asyncio.get_running_loop()
            self._stop = asyncio.Event()
            self._started.set()
            await run_worker(self._settings, self._endpoint, self._stop, on_started=self._on_started)

        try:
            asyncio.run(body())
        except BaseException as error:  # handed to the caller by stop()
            self.error = error
        finally:
            self._started.set()

    def _on_started(self, context: WorkerContext) -> None:
        self._context = context

    def stats(self) -> IngestStats:
        """The running worker's counters (a snapshot is not needed: they only grow)."""
        return self._context.consumer.stats if self._context else IngestStats()

    def start(self) -> WorkerThread:
        self._thread.start()
        self._started.wait()
        return self

    def stop(self, timeout: float = 60.0) -> None:
        """Ask the worker to stop as on SIGTERM, wait for it, and re-raise what killed it."""
        if self._loop is not None and self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise TimeoutError(f"the worker did not stop within {timeout:.0f} s")
        if self.error is not None:
            raise self.error

    def __enter__(self) -> WorkerThread:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()
