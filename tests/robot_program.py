"""A short robot program, written the way the README shows one: publish, then leave the ``with`` block.

    FLEETBUS_ROBOT_URL=URL python -m tests.robot_program STATE_DIR [--hazards N] [--status N] [--wait-for-go]
                                  [--close-timeout S]

Publishes N hazards one ``publish`` at a time (as robot code does), then M status events in
``publish_many`` batches of 100, and leaves the ``with`` block, which delivers what still waits
for at most the close timeout. It prints ``ready EPOCH`` (its client's epoch) before publishing
(with ``--wait-for-go`` it then waits for a line on stdin, so that several programs can start
publishing at once), ``published N`` once its publishes returned, and ``closed`` once the block
is left.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from fleetbus.publishers.client import RobotClient
from tests.factories import hazard, status


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("state_dir", type=Path)
    parser.add_argument("--hazards", type=int, default=0)
    parser.add_argument("--status", type=int, default=0)
    parser.add_argument("--wait-for-go", action="store_true")
    parser.add_argument("--close-timeout", type=float, default=None)
    args = parser.parse_args()
    options = {} if args.close_timeout is None else {"close_timeout": args.close_timeout}
    url = os.environ["FLEETBUS_ROBOT_URL"]  # it holds a password: never an argument
    with RobotClient(url, state_dir=args.state_dir, **options) as robot:
        print(f"ready {robot.epoch}", flush=True)
        if args.wait_for_go:
            sys.stdin.readline()
        for i in range(args.hazards):
            robot.publish("hazard", hazard(i))
        for start in range(0, args.status, 100):
            robot.publish_many([("status", status(50)) for _ in range(min(100, args.status - start))])
        print(f"published {args.hazards + args.status}", flush=True)
    print("closed", flush=True)


if __name__ == "__main__":
    main()
