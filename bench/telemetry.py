"""Background telemetry: robots publishing status events at a steady total rate, in a process of its own.

    python -m bench.telemetry STATE_DIR RATE [--pose] URLS_FILE

Each line of URLS_FILE (mode 0600: the URLs hold passwords, which argv would show to every
user of the machine) is a robot's account. Every robot publishes its share of RATE events a
second with ``publish_many`` (robot code's call, confirmed), in small batches on an absolute
schedule (at most ``TICKS`` times a second, and no more often than an event is due): status
events, or with ``--pose`` a status and a localisation (its pose) in turn. The process prints
``publishing`` once every robot is connected, runs until its standard input closes, then prints
one JSON line: ``{"published": N, "seconds": S}``.

:class:`TelemetryLoad` runs it beside a measurement.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import threading
import time
import uuid
from pathlib import Path
from types import TracebackType

from bench.ingest import status_items
from bench.processes import spawn_until_ready
from fleetbus.broker.accounts import save_secret
from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.routing import EventType
from tests.support import Bus

TICKS = 50
POSE = (EventType.LOCALISATION, {"localised": True, "pose": {"x": 12.5, "y": -3.25}})


def publish_steadily(
    robot: RobotClient,
    rate: float,
    stop: threading.Event,
    counts: list[int],
    errors: list[BaseException],
    pose: bool = False,
) -> None:
    """By time t, ``rate * t`` events published (and confirmed), in batches at most TICKS times a
    second and no more often than an event is due; with ``pose``, a status and a localisation in
    turn. Each robot starts at a random phase of its tick, so that a fleet does not publish in
    lockstep (and a thousand robots at 1 Hz wake their process a thousand times a second, not
    fifty thousand)."""
    items = [status_items(1)[0], *([POSE] if pose else [])]
    tick = 1 / min(TICKS, max(rate, 1.0))
    if stop.wait(random.uniform(0, tick)):
        return
    started = time.monotonic()
    published = 0
    try:
        while not stop.is_set():
            due = int(rate * (time.monotonic() - started)) - published
            if due > 0:
                robot.publish_many([items[(published + i) % len(items)] for i in range(due)])
                published += due
                counts.append(due)
            stop.wait(tick)  # the schedule's tick; the count catches up with the clock
    except BaseException as error:  # reported by main
        errors.append(error)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("state_dir", type=Path)
    parser.add_argument("rate", type=float, help="events a second, all robots together")
    parser.add_argument("--pose", action="store_true", help="a status and a localisation in turn")
    parser.add_argument("urls", type=Path, help="a file of the robots' AMQP URLs, one a line")
    args = parser.parse_args()
    robots = [RobotClient(url, state_dir=args.state_dir) for url in args.urls.read_text().split()]
    for robot in robots:
        robot.connect()
    stop = threading.Event()
    counts: list[int] = []
    errors: list[BaseException] = []
    threads = [
        threading.Thread(
            target=publish_steadily, args=(robot, args.rate / len(robots), stop, counts, errors, args.pose)
        )
        for robot in robots
    ]
    started = time.monotonic()
    for thread in threads:
        thread.start()
    print("publishing", flush=True)
    sys.stdin.read()  # until the parent closes it (or dies)
    stop.set()
    for thread in threads:
        thread.join()
    seconds = time.monotonic() - started
    for robot in robots:
        robot.close()
    if errors:
        raise SystemExit(f"a robot stopped publishing: {errors[0]!r}")
    print(json.dumps({"published": sum(counts), "seconds": seconds}), flush=True)


#: The niceness of a simulated fleet's processes when the bench stands in for robots that run
#: elsewhere: robots do not share the server's cores, and a fleet of hundreds simulated on them
#: would otherwise take what the broker and the workers need (on 2 cores, 1,000 simulated robots
#: took half a core). At 15 they run on what the server leaves.
FLEET_NICE = 15


class TelemetryLoad:
    """``python -m bench.telemetry`` for robots (their URLs) of ``bus``, while the ``with`` lasts."""

    def __init__(
        self,
        bus: Bus,
        urls: list[str],
        rate: float,
        pose: bool = False,
        ready_timeout: float = 60,
        lean: bool = False,
        nice: int = 0,
    ) -> None:
        """``ready_timeout``: seconds its robots may take to connect (many on a loaded machine);
        ``lean``: status events from :mod:`bench.lean_robots` instead of a ``RobotClient`` each;
        ``nice``: the process's niceness (see :data:`FLEET_NICE`)."""
        self._ready_timeout = ready_timeout
        urls_file = bus.settings.data_dir / f"telemetry-{uuid.uuid4().hex[:8]}.urls"
        save_secret(urls_file, "\n".join(urls))
        if lean and pose:
            raise ValueError("lean robots publish status events only")
        self._command = ["nice", "-n", str(nice)] if nice else []
        self._command += (
            [sys.executable, "-m", "bench.lean_robots", str(rate), str(urls_file)]
            if lean
            else [
                sys.executable,
                "-m",
                "bench.telemetry",
                str(bus.settings.robots_dir),
                str(rate),
                *(["--pose"] if pose else []),
                str(urls_file),
            ]
        )
        self._log = bus.settings.data_dir / "telemetry.log"
        self.rate = 0.0
        """The rate achieved, once stopped."""
        self.published = 0
        """Events published (and confirmed), once stopped."""

    def __enter__(self) -> TelemetryLoad:
        self._process = spawn_until_ready(self._command, self._log, "publishing", self._ready_timeout)
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        output, _ = self._process.communicate(timeout=60)  # closes its stdin: it stops
        if self._process.returncode != 0:
            raise RuntimeError(f"the telemetry load failed ({self._process.returncode}); see {self._log}")
        summary = json.loads(output.strip().splitlines()[-1])
        self.published = summary["published"]
        self.rate = summary["published"] / summary["seconds"]


if __name__ == "__main__":
    main()
