"""fleetbus's own processes (`fleetbus worker`, `fleetbus recorder run`), started for a measurement.

A benchmark runs the workers as they are deployed, in a process of their own: the robots it
drives then do not share an interpreter (and its lock) with them, and their CPU time and resident
memory can be read from /proc.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path
from types import TracebackType

import pika
import pika.exceptions
from pika.adapters.blocking_connection import BlockingChannel

from bench.profile import record
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import EXPRESS_QUEUE, INGEST_QUEUE
from tests.support import Bus, read_line, wait_for


class ConsumerCount:
    """Consumers of a queue, asked as often as a wait needs over one connection (a TLS handshake
    for every question cost more CPU than the process being waited for)."""

    def __init__(self, admin_url: str, queue: str) -> None:
        self._queue = queue
        self._connection = blocking_connection(admin_url)
        self._channel: BlockingChannel | None = None

    def __call__(self) -> int:
        """Consumers now; 0 while the queue does not exist (the broker then closes the channel)."""
        if self._channel is None or not self._channel.is_open:
            self._channel = self._connection.channel()
        try:
            return self._channel.queue_declare(self._queue, passive=True).method.consumer_count
        except pika.exceptions.ChannelClosedByBroker:
            return 0

    def close(self) -> None:
        if self._connection.is_open:
            self._connection.close()


class FleetbusProcess:
    """``python -m fleetbus ARGS``; returns from the constructor once it consumes ``queue``."""

    def __init__(
        self, args: list[str], env: dict[str, str], log: Path, admin_url: str, queue: str, timeout: float = 60
    ) -> None:
        self._log = log.open("ab")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "fleetbus", *args], env=env, stdout=self._log, stderr=subprocess.STDOUT
        )
        try:
            consumers = ConsumerCount(admin_url, queue)
            try:
                wait_for(
                    lambda: self.process.poll() is not None or consumers() >= 1,
                    timeout,
                    f"`fleetbus {' '.join(args)}` to consume {queue}",
                )
            finally:
                consumers.close()
            if self.process.returncode is not None:
                raise RuntimeError(
                    f"`fleetbus {' '.join(args)}` exited with {self.process.returncode}; see {log}"
                )
        except BaseException:
            self.kill()
            raise
        self._profiler = record(self.pid, args[0])

    @property
    def pid(self) -> int:
        return self.process.pid

    def stop(self, timeout: float = 60) -> None:
        """SIGTERM, as an operator stops it: the batch in hand is finished and acked."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            self.process.wait(timeout)
        self._finish()

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(30)
        self._finish()

    def _finish(self) -> None:
        self._log.close()
        profiler = getattr(self, "_profiler", None)
        if profiler is not None:
            profiler.wait(60)  # py-spy writes its file once the process it records has ended

    def __enter__(self) -> FleetbusProcess:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc is None:
            self.stop()
        else:
            self.kill()


def worker_process(bus: Bus, *args: str) -> FleetbusProcess:
    """`fleetbus worker ARGS` on the bus's virtual host and store, consuming the ingest queue and
    the express lane (its own connection, which may come up later)."""
    log = bus.settings.data_dir / "worker.log"
    worker = FleetbusProcess(["worker", *args], bus.service_env(), log, bus.admin_url, INGEST_QUEUE)
    express = ConsumerCount(bus.admin_url, EXPRESS_QUEUE)
    try:
        wait_for(
            lambda: worker.process.poll() is not None or express() >= 1, 60, "the express lane's consumer"
        )
    except BaseException:
        worker.kill()
        raise
    finally:
        express.close()
    return worker


def spawn_until_ready(
    command: list[str], log: Path, ready: str, timeout: float = 60
) -> subprocess.Popen[str]:
    """A helper process of a measurement, talking on its standard input and output (its errors go
    to ``log``); returned once it printed a line starting with ``ready``, killed if it never does."""
    with log.open("ab") as errors:
        process = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=errors, text=True
        )
    try:
        read_line(process, ready, timeout=timeout)
    except BaseException:
        process.kill()
        raise
    return process
