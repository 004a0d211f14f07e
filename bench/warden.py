"""The hazard benchmark's warden, a robot process of its own that reports each hazard's receipt.

    python -m bench.warden STATE_DIR URL_FILE

It connects as the warden whose URL is in URL_FILE (mode 0600), publishes that it is localised
(so the gate is open), prints ``listening``, then one JSON line per hazard notification until its
standard input closes: ``{"i": 7, "at": <time.monotonic()>, "stages": [to the worker, until
stored, until notified, to the warden]}``, hazards numbered by the last word of their
description. ``at`` is read on receipt, before anything else is done. CLOCK_MONOTONIC is one
clock for every process of a machine, so the parent compares it with its own
``time.monotonic()`` at publish; the stages are differences of the product's wall-clock stamps
(``sent_at``; ``received_at``, when the worker took it from the broker; ``stored_at``;
``notified_at``) and the receipt.

A process of its own, as a warden is: in the explorer's process it would wait for that process's
interpreter lock while the explorer writes its outbox and settles its confirms.
:class:`WardenProcess` runs it beside a measurement.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path
from types import TracebackType

from bench.processes import spawn_until_ready
from fleetbus.broker.accounts import save_secret
from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.routing import EventType, Topic
from tests.support import Bus, wait_for


def listen(warden: RobotClient, stop: threading.Event) -> None:
    while not stop.is_set():
        for note in warden.notifications(stop=stop):
            at, now = time.monotonic(), time.time()
            if note.topic is Topic.HAZARD:
                stored_at = note.stored_at or note.notified_at
                sent, received, stored, notified = (
                    t.timestamp() for t in (note.event.sent_at, note.received_at, stored_at, note.notified_at)
                )
                stages = [received - sent, stored - received, notified - stored, now - notified]
                i = int(note.event.body.description.split()[-1])
                print(json.dumps({"i": i, "at": at, "stages": stages}), flush=True)
            if stop.is_set():
                break


def main() -> None:
    state_dir, url = Path(sys.argv[1]), Path(sys.argv[2]).read_text().strip()
    warden = RobotClient(url, state_dir=state_dir)
    warden.connect()
    warden.publish(EventType.LOCALISATION, {"localised": True})
    stop = threading.Event()

    def until_stdin_closes() -> None:
        sys.stdin.read()
        stop.set()

    threading.Thread(target=until_stdin_closes, daemon=True).start()
    print("listening", flush=True)
    try:
        listen(warden, stop)
    finally:
        warden.close()


class WardenProcess:
    """``python -m bench.warden`` for the warden at ``url`` of ``bus``, while the ``with`` lasts.

    ``at[i]`` is when hazard ``i`` reached the warden (monotonic seconds), ``stages[i]`` its way.
    """

    def __init__(self, bus: Bus, url: str) -> None:
        url_file = bus.settings.data_dir / "warden.url"  # mode 0600: argv would show the password
        save_secret(url_file, url)
        self._command = [sys.executable, "-m", "bench.warden", str(bus.settings.robots_dir), str(url_file)]
        self._log = bus.settings.data_dir / "warden.log"
        self.at: dict[int, float] = {}
        self.stages: dict[int, tuple[float, ...]] = {}
        self._reader = threading.Thread(target=self._read, name="warden-reader", daemon=True)

    def __enter__(self) -> WardenProcess:
        self._process = spawn_until_ready(self._command, self._log, "listening")
        self._reader.start()
        return self

    def _read(self) -> None:
        assert self._process.stdout is not None
        for line in self._process.stdout:
            receipt = json.loads(line)
            i = receipt["i"]
            self.stages.setdefault(i, tuple(receipt["stages"]))
            self.at.setdefault(i, receipt["at"])

    def wait(self, count: int, timeout: float) -> None:
        wait_for(
            lambda: len(self.at) >= count or self._process.poll() is not None,
            timeout,
            f"{count} hazards at the warden",
        )
        if len(self.at) < count:
            raise RuntimeError(
                f"the warden stopped ({self._process.returncode}) after {len(self.at)} of {count} "
                f"hazards; see {self._log}"
            )

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        assert self._process.stdin is not None
        self._process.stdin.close()  # it stops
        returncode = self._process.wait(60)
        self._reader.join(30)
        if returncode != 0 and exc is None:
            raise RuntimeError(f"the warden failed ({returncode}); see {self._log}")


if __name__ == "__main__":
    main()
