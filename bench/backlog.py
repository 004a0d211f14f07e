"""Robots whose outboxes filled during an outage, draining them at once, in a process of their own.

    python -m bench.backlog STATE_DIR COUNT URL [URL ...]

Each URL is a robot's account. Every robot gets COUNT status events in its outbox while its
client is not started (an outage: the broker was away), then the process prints ``filled`` and
waits for a line on its standard input. On that line every robot starts at once (the broker is
back: each drains its outbox, oldest first, with pipelined confirms), the process prints
``draining``, and once every outbox is empty it prints one JSON line:
``{"drained_s": S}`` (seconds from the start to the last confirm). It then waits for its standard
input to close.

:class:`Backlog` runs it beside a measurement.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from types import TracebackType

from bench.ingest import status_items
from bench.processes import spawn_until_ready
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.outbox import Overflow, TypePolicy
from tests.support import Bus, read_line

#: Events appended to an outbox at a time while it fills.
CHUNK = 1000


def main() -> None:
    state_dir, count, urls = Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3:]
    # every event kept: the backlog is what is measured, not the outbox's thinning
    keep_all = {"status": TypePolicy(Overflow.KEEP, count)}
    robots = [RobotClient(url, state_dir=state_dir, outbox_policies=keep_all) for url in urls]
    for robot in robots:
        items = status_items(count)
        for start in range(0, count, CHUNK):
            robot.outbox.append(robot.build(items[start : start + CHUNK]))
    print("filled", flush=True)
    sys.stdin.readline()
    started = time.monotonic()
    for robot in robots:
        robot.start()
    print("draining", flush=True)
    for robot in robots:
        if not robot.flush(600):
            raise SystemExit(f"{robot.robot_id}: {robot.outbox.pending()} events still waiting")
    print(json.dumps({"drained_s": time.monotonic() - started}), flush=True)
    sys.stdin.read()
    for robot in robots:
        robot.close()


class Backlog:
    """``python -m bench.backlog`` for robots (their URLs) of ``bus``: filled on entry; :meth:`go`
    starts the drain; :meth:`wait` returns the seconds it took."""

    def __init__(self, bus: Bus, urls: list[str], count: int) -> None:
        folder = str(bus.settings.robots_dir)
        self._command = [sys.executable, "-m", "bench.backlog", folder, str(count), *urls]
        self._log = bus.settings.data_dir / "backlog.log"

    def __enter__(self) -> Backlog:
        self._process = spawn_until_ready(self._command, self._log, "filled")
        return self

    def go(self) -> None:
        assert self._process.stdin is not None
        self._process.stdin.write("go\n")
        self._process.stdin.flush()
        read_line(self._process, "draining", timeout=60)

    def wait(self, timeout: float = 600) -> float:
        """Seconds from the start of the drain until every outbox was empty."""
        line = read_line(self._process, "{", timeout=timeout)
        return float(json.loads(line)["drained_s"])

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._process.communicate(timeout=60)  # closes its stdin: it stops
        if self._process.returncode != 0 and exc is None:
            raise RuntimeError(f"the backlog's robots failed ({self._process.returncode}); see {self._log}")


if __name__ == "__main__":
    main()
