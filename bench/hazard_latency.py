"""Hazard notification latency: the explorer's publish to the warden's receipt, under telemetry load.

    .venv/bin/python -m bench.hazard_latency [--runs 3] [--quick]

The suite runs it three ways: ``hazard`` (`fleetbus worker --no-recorder` under the telemetry;
the targets are on it), ``hazard-idle`` (no telemetry: the floor) and ``hazard-recorder``
(`fleetbus worker` as it starts by default, with its recorder child process, under the telemetry).

An explorer publishes hazards (``robot.publish``, as robot code does: outbox, broker confirm) at
HAZARD_RATE a second while four other robots publish RATE telemetry events a second in a
process of their own, and `fleetbus worker` runs in another. The warden, localised beforehand so
the gate is open, takes its notifications in a robot process of its own (:mod:`bench.warden`),
as a warden does; the explorer lives in this process. Both read ``time.monotonic()``, one clock
for every process of the machine, so no clock skew enters the figures.

Between two hazards a raw message goes through a queue declared like the ingest queue to a
consumer of this process (pika both ends): one hop through the same broker under the same load,
next to the hazard's two hops (robot to worker, worker to warden) with the store in between.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from types import TracebackType
from typing import Any

import pika
from pika.adapters.blocking_connection import BlockingChannel

from bench.processes import worker_process
from bench.raw import declare_queue, ingest_queue_arguments
from bench.results import percentile
from bench.scenario import Context, Figures
from bench.telemetry import TelemetryLoad
from bench.warden import WardenProcess
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import EventType, RobotKind
from tests.support import wait_for

HAZARD_RATE = 20
RATE = 1000
LOADERS = 4
PING_QUEUE = "bench.ping"
PERSISTENT = pika.BasicProperties(delivery_mode=2)
#: Where a hazard's time goes, by the product's own stamps: the explorer's outbox, the broker and
#: the express queue until the worker takes it; in the worker until it is stored, then until the
#: hazard service has built the notification; its publish and delivery to the warden.
STAGES = ("to the worker", "in the worker, until stored", "stored to notified", "to the warden")


def hazard(i: int) -> dict[str, Any]:
    return {
        "pose": {"x": 2.5, "y": 1.25},
        "description": f"bench hazard {i}",
        "detected_at": datetime.now(timezone.utc).isoformat(),
    }


class Arrivals:
    """Receive on a thread of its own; ``at[i]`` is when message ``i`` arrived (monotonic seconds)."""

    def __init__(self, receive: Callable[[Callable[[int], bool]], None], name: str) -> None:
        self._receive = receive
        self.at: dict[int, float] = {}
        self.stop = threading.Event()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def arrived(self, i: int) -> bool:
        """Note message ``i``; True to go on receiving."""
        self.at.setdefault(i, time.monotonic())
        return not self.stop.is_set()

    def _run(self) -> None:
        try:
            while not self.stop.is_set():
                self._receive(self.arrived)
        except BaseException as error:  # handed over by wait
            self.error = error

    def __enter__(self) -> Arrivals:
        self._thread.start()
        return self

    def wait(self, count: int, timeout: float) -> None:
        wait_for(lambda: self.error is not None or len(self.at) >= count, timeout, f"{count} arrivals")
        if self.error is not None:
            raise self.error

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop.set()
        self._thread.join(30)


def ping_receiver(admin_url: str) -> Callable[[Callable[[int], bool]], None]:
    def receive(arrived: Callable[[int], bool]) -> None:
        connection = blocking_connection(admin_url)
        try:
            channel = connection.channel()
            channel.basic_qos(prefetch_count=64)
            for method, _properties, body in channel.consume(PING_QUEUE, inactivity_timeout=0.5):
                if method is None:
                    return  # quiet for a while: back to the caller, who knows whether to go on
                going_on = arrived(int(body))
                channel.basic_ack(method.delivery_tag)
                if not going_on:
                    return
        finally:
            if connection.is_open:
                connection.close()

    return receive


@dataclass
class Paced:
    """When each hazard and each raw ping went out (monotonic seconds, by number)."""

    sent: dict[int, float] = field(default_factory=dict)
    pinged: dict[int, float] = field(default_factory=dict)
    confirmed: list[float] = field(default_factory=list)
    """How long each publish took: outbox, broker confirm."""
    stamped: list[float] = field(default_factory=list)
    """From the publish call to the event's ``sent_at``: building it."""


def publish_paced(
    explorer: RobotClient,
    ping: BlockingChannel,
    numbers: range,
    rate: float = HAZARD_RATE,
    before_each: Callable[[int], None] | None = None,
) -> Paced:
    """The explorer publishes hazards ``numbers`` at ``rate`` a second (as robot code does), and
    half-way between two hazards a raw message of the same number goes to PING_QUEUE;
    ``before_each(i)`` is called just before hazard ``i`` is published."""
    paced = Paced()
    start = time.monotonic()
    for k, i in enumerate(numbers):
        time.sleep(max(0.0, start + k / rate - time.monotonic()))  # the schedule
        if before_each is not None:
            before_each(i)
        paced.sent[i] = time.monotonic()
        wall = time.time()
        event = explorer.publish(EventType.HAZARD, hazard(i))
        paced.stamped.append(event.sent_at.timestamp() - wall)
        paced.confirmed.append(time.monotonic() - paced.sent[i])
        time.sleep(max(0.0, start + (k + 0.5) / rate - time.monotonic()))
        paced.pinged[i] = time.monotonic()
        ping.basic_publish("", PING_QUEUE, str(i).encode(), PERSISTENT)
    return paced


def measure(
    context: Context,
    count: int,
    rate: float = RATE,
    worker_args: tuple[str, ...] = (),
) -> Figures:
    """``count`` hazards under ``rate`` telemetry events a second; `fleetbus worker WORKER_ARGS`."""
    with context.bus() as bus:
        explorer = bus.robot(bus.add("bench-explorer", kind=RobotKind.EXPLORER))
        warden_url = bus.add("bench-warden", kind=RobotKind.WARDEN).amqp_url
        loaders = [bus.add(f"bench-telemetry{i}").amqp_url for i in range(LOADERS)]
        declare_queue(bus.admin_url, ingest_queue_arguments(), PING_QUEUE)
        with worker_process(bus, *worker_args), WardenProcess(bus, warden_url) as warden:
            wait_for(lambda: all(w.localised for w in bus.with_store(lambda r: r.hazards.robots("warden"))))
            context.show(f"{rate:,.0f} telemetry events/s starting")
            ping = blocking_connection(bus.admin_url)
            with (
                TelemetryLoad(bus, loaders, rate) as load,
                Arrivals(ping_receiver(bus.admin_url), "ping") as pings,
            ):
                context.show(f"{count} hazards at {HAZARD_RATE}/s under {rate:,.0f} telemetry events/s")
                paced = publish_paced(explorer, ping.channel(), range(count))
                sent, pinged = paced.sent, paced.pinged
                confirmed, stamped = paced.confirmed, paced.stamped
                warden.wait(count, 60)
                pings.wait(count, 60)
            ping.close()
    hazard_ms = [1000 * (warden.at[i] - sent[i]) for i in sent]
    ping_ms = [1000 * (pings.at[i] - pinged[i]) for i in pinged]
    return {
        "hazard p50 ms": percentile(hazard_ms, 50),
        "hazard p99 ms": percentile(hazard_ms, 99),
        "hazard max ms": max(hazard_ms),
        "explorer's publish p50 ms": percentile([1000 * seconds for seconds in confirmed], 50),
        "building the event p50 ms": percentile([1000 * seconds for seconds in stamped], 50),
        **{
            f"{stage} p50 ms": percentile([1000 * times[k] for times in warden.stages.values()], 50)
            for k, stage in enumerate(STAGES)
        },
        "raw hop p50 ms": percentile(ping_ms, 50),
        "raw hop p99 ms": percentile(ping_ms, 99),
        "telemetry events/s": load.rate,
    }


def figures(context: Context) -> Figures:
    """The suite's hazard latency: the worker alone (`--no-recorder`), under the telemetry load."""
    return measure(context, context.size(200, 100), RATE, ("--no-recorder",))


def figures_idle(context: Context) -> Figures:
    """The same path with no telemetry beside it: the floor the load adds to."""
    return measure(context, context.size(200, 100), 0, ("--no-recorder",))


def figures_with_recorder(context: Context) -> Figures:
    """Under the load, with `fleetbus worker` as it starts by default: with its recorder child."""
    return measure(context, context.size(200, 100), RATE)


if __name__ == "__main__":
    from bench.suite import main

    sys.exit(main(["--only", "hazard,hazard-idle,hazard-recorder", *sys.argv[1:]]))
