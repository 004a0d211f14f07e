"""The parts of the ROS bridge (its threads, and the ROS side's process) and how each one fares.

Every part that ends when it should not is started again, after a wait that doubles with each
failure in a row (up to :data:`RESTART_MOST_S`), and what happened is kept here for the status file
(``fleetbus ros status``): a part is ``running``, or ``restarting`` with its last failure and when
the next try is. Nothing of the bridge is left half-alive: a thread that dies is restarted, never
forgotten.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

log = logging.getLogger("fleetbus.ros")

#: The longest wait before a failed part is started again.
RESTART_MOST_S = 30.0
#: The first wait; it doubles with each failure in a row.
RESTART_FIRST_S = 0.5
#: A part that ran this long before failing starts its backoff again from the first wait.
STEADY_S = 60.0

RUNNING, RESTARTING, STOPPED = "running", "restarting", "stopped"


def restart_delay(failures: int) -> float:
    """The wait before the next start after ``failures`` failures in a row (1 or more)."""
    return min(RESTART_FIRST_S * 2 ** min(failures - 1, 16), RESTART_MOST_S)


class Parts:
    """Thread-safe: each part's state, its restarts since the bridge began, its last failure."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._parts: dict[str, dict[str, Any]] = {}
        self._started: dict[str, float] = {}

    def started(self, name: str) -> None:
        with self._lock:
            part = self._parts.setdefault(name, {"state": RUNNING, "restarts": 0, "failures": 0})
            if part["state"] == RESTARTING:
                part["restarts"] += 1
            part.update(state=RUNNING, retry_in=None)
            self._started[name] = time.monotonic()

    def failed(self, name: str, detail: str) -> float:
        """Note that ``name`` failed (``detail`` says how); the wait before it starts again."""
        with self._lock:
            part = self._parts.setdefault(name, {"state": RUNNING, "restarts": 0, "failures": 0})
            if part["state"] == RUNNING and time.monotonic() - self._started.get(name, 0.0) >= STEADY_S:
                part["failures"] = 0  # it ran well for a while: a new failure, not one more of a streak
            part["failures"] += 1
            delay = restart_delay(part["failures"])
            part.update(state=RESTARTING, last_failure=detail, failed_at=time.time(), retry_in=delay)
        log.error("ROS bridge: %s failed (%s); starting it again in %.1f s", name, detail, delay)
        return delay

    def stopped(self, name: str) -> None:
        with self._lock:
            if name in self._parts:
                self._parts[name]["state"] = STOPPED

    def failing(self) -> list[str]:
        with self._lock:
            return [name for name, part in self._parts.items() if part["state"] == RESTARTING]

    def snapshot(self) -> dict[str, dict[str, Any]]:
        with self._lock:
            return {name: dict(part) for name, part in sorted(self._parts.items())}


def supervised(
    name: str, target: Callable[[], None], parts: Parts, stop: threading.Event
) -> threading.Thread:
    """A daemon thread that runs ``target`` until ``stop`` is set, and runs it again, after a
    backoff, whenever it raises or returns before ``stop``; each failure is noted in ``parts``."""

    def run() -> None:
        while not stop.is_set():
            parts.started(name)
            try:
                target()
                if stop.is_set():
                    break
                detail = "it ended by itself"
            except Exception as error:  # whatever it was, the part must come back
                log.exception("ROS bridge: %s raised", name)
                detail = f"{type(error).__name__}: {error}"
            if stop.wait(parts.failed(name, detail)):
                break
        parts.stopped(name)

    thread = threading.Thread(target=run, name=f"ros-{name}", daemon=True)
    thread.start()
    return thread
