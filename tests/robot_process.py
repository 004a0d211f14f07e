"""A robot as a process of its own, for tests that kill it: publish, then drain, then report.

    python -m tests.robot_process STATE_DIR --events N [--drain]   # its URL: the first line of stdin

Publishes N status events without waiting (they go to the outbox and out whenever the broker
answers), prints ``queued N`` once all are in the outbox, and with ``--drain`` waits until the
outbox is empty and prints ``drained``. It then idles until killed or terminated.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from fleetbus.publishers.client import RobotClient
from tests.factories import status


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("state_dir", type=Path)
    parser.add_argument("--events", type=int, default=0)
    parser.add_argument("--drain", action="store_true")
    args = parser.parse_args()
    url = sys.stdin.readline().strip()  # it holds a password: never an argument
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    robot = RobotClient(url, state_dir=args.state_dir)
    robot.start()
    for start in range(0, args.events, 100):
        robot.publish_many([("status", status(50)) for _ in range(min(100, args.events - start))], wait=False)
    print(f"queued {args.events}", flush=True)
    if args.drain:
        while not robot.flush(timeout=1.0) and not stop.is_set():
            pass
        print("drained", flush=True)
    stop.wait()
    robot.close()
    sys.exit(0)


if __name__ == "__main__":
    main()
