"""Robot programs as processes of their own, each run as short as robot code makes it.

Each program (``tests.robot_program``) is the README's snippet: a ``with RobotClient(...)``
block that publishes and ends. What arrived is counted in the store, the outbox and the
dead-letter queue after each run.
"""

from __future__ import annotations

import subprocess
import sys
import time
from urllib.parse import urlsplit

from schemas.routing import RobotKind
from tests.link import NetworkLink
from tests.support import PROJECT_ROOT, Bus, wait_for


def run_program(bus: Bus, url: str, *args: str, timeout: float = 120) -> str:
    """Run a robot program with the account ``url`` to its end; its output."""
    done = subprocess.run(
        [sys.executable, "-m", "tests.robot_program", url, str(bus.settings.robots_dir), *args],
        cwd=PROJECT_ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def waiting(bus: Bus, robot: str) -> int:
    outbox = bus.outbox(robot)
    try:
        return outbox.pending()
    finally:
        outbox.close()


def test_three_short_robot_programs_each_deliver_their_hazard(stored_bus: Bus) -> None:
    """``publish`` waits for the first connection, so a program that publishes right after it
    started and ends at once leaves nothing in its outbox."""
    bus = stored_bus
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    with bus.worker():
        for run in (1, 2, 3):
            output = run_program(bus, account.amqp_url, "--hazards", "1")
            assert "published 1" in output and "closed" in output
            assert waiting(bus, "explorer1") == 0, f"run {run} left its hazard in the outbox"
            wait_for(lambda run=run: bus.count("hazard") == run, what=f"the hazard of run {run} stored")


def test_a_robot_program_started_without_the_broker_neither_blocks_nor_loses_its_hazards(bus: Bus) -> None:
    """The first publish waits for the first connection attempt only; once it failed, the others
    return at once, and leaving the block gives up as soon as its one more attempt fails (not
    after its close timeout). The hazards go with the next run that reaches the broker."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = NetworkLink(urlsplit(account.amqp_url).port or 5672).start()
    try:
        link.cut()  # the robot starts without a way to the broker
        started = time.monotonic()
        run_program(bus, link.url(account.amqp_url), "--hazards", "3", "--close-timeout", "60")
        took = time.monotonic() - started
        assert took < 20, f"the program took {took:.1f} s: a publish or the close waited for the broker"
        assert waiting(bus, "explorer1") == 3, "the three hazards wait on disk"
        link.restore()
        with bus.worker():
            run_program(bus, link.url(account.amqp_url))  # publishes nothing; its close delivers
            assert waiting(bus, "explorer1") == 0
            wait_for(lambda: bus.count("hazard") == 3, what="the three hazards stored")
    finally:
        link.stop()
