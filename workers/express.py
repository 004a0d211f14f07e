"""The express lane on a thread, event loop, broker connection and store connection of its own.

A hazard must not wait for the telemetry the worker has in hand. On the shards' event loop it
did: after an outage the shard consumers take hundreds of status events at a time, and their
frames, their delivery callbacks and the validation of a whole batch ran before the hazard's next
step, every step of its way (up to hundreds of milliseconds a hazard while a 30,000-event backlog
drained, measured in ``bench/hazard_backlog.py``). Here the hazard has its own socket (no shard
frames ahead of it), its own loop (no shard callbacks ahead of it in the ready queue), and its
own store connection, and the worker's interpreter hands the lock between threads every
:data:`SWITCH_INTERVAL_S` instead of every 5 ms, so a thread waiting for it (the express lane,
woken by its socket) runs soon. Decision record 0014 has the measurements and the options.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import sys
import threading
from collections.abc import Awaitable, Callable

from aio_pika.abc import AbstractRobustConnection

from fleetbus.workers.ingest import BROKER_ERRORS, IngestConsumer
from fleetbus.workers.store import Repositories
from fleetbus.workers.tasks import stopped

log = logging.getLogger("fleetbus.express")

#: How often (seconds) a thread that holds the interpreter's lock is asked to let a waiting one
#: run; CPython's default is 5 ms, which a hazard paid at each step of its way through the worker.
SWITCH_INTERVAL_S = 0.0005

#: Builds the express lane's consumer on the lane's own connection and store.
MakeConsumer = Callable[[AbstractRobustConnection, Repositories], Awaitable[IngestConsumer]]


class ExpressLane:
    """Consume the express lane on a thread of its own until :meth:`stop`.

    ``done`` (a future of the caller's loop) completes when consuming ended by itself, with the
    error if it failed, as a shard's consumer task does.
    """

    def __init__(
        self,
        repositories: Repositories,
        connect: Callable[[str], Awaitable[AbstractRobustConnection]],
        make_consumer: MakeConsumer,
    ) -> None:
        """``connect(name)``: a connection of the worker's account, named ``name`` on the broker;
        ``repositories``: the worker's (:meth:`~Repositories.for_another_loop` says what the lane uses)."""
        self._repositories = repositories
        self._connect = connect
        self._make_consumer = make_consumer
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._started: concurrent.futures.Future[None] = concurrent.futures.Future()
        self._ended: concurrent.futures.Future[None] = concurrent.futures.Future()
        self.task: asyncio.Future[None]
        self._thread = threading.Thread(target=self._main, name="fleetbus-express", daemon=True)

    async def start(self) -> None:
        """Start the thread; return once it consumes the lane (raise what kept it from it)."""
        self.task = asyncio.wrap_future(self._ended)
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        self._thread.start()
        await asyncio.wrap_future(self._started)

    async def stop(self) -> None:
        """Stop taking messages; the batch in hand is finished and acked, the rest given back."""
        loop, stopping = self._loop, self._stopping
        if loop is not None and stopping is not None and self._thread.is_alive():
            with contextlib.suppress(RuntimeError):  # its loop just closed
                loop.call_soon_threadsafe(stopping.set)
        await stopped(self.task, "consuming the express lane")
        await asyncio.to_thread(self._thread.join)

    def _main(self) -> None:
        try:
            asyncio.run(self._run())
        except BaseException as error:  # handed to the caller's loop
            if not self._started.done():
                self._started.set_exception(error)
            self._ended.set_exception(error)
        else:
            if not self._started.done():
                self._started.set_result(None)
            self._ended.set_result(None)

    async def _run(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stopping = stopping = asyncio.Event()
        repositories = self._repositories.for_another_loop()
        own = repositories is not self._repositories
        if own:
            await repositories.open()
        try:
            connection = await self._connect("fleetbus-worker-express")
            try:
                consumer = await self._make_consumer(connection, repositories)
                running = asyncio.create_task(consumer.run(), name="fleetbus-express-lane")
                self._started.set_result(None)
                stop = asyncio.create_task(stopping.wait())
                await asyncio.wait({running, stop}, return_when=asyncio.FIRST_COMPLETED)
                stop.cancel()
                await consumer.stop()
                await running
            finally:
                # what was received but not acked goes back to the queue with the connection
                with contextlib.suppress(*BROKER_ERRORS):
                    await connection.close()
        finally:
            if own:
                await repositories.close()
