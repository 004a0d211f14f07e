"""Robot programs as processes of their own, each run as short as robot code makes it.

Each program (``tests.robot_program``) is the README's snippet: a ``with RobotClient(...)``
block that publishes and ends. What arrived is counted in the store, the outbox, the hazard
registry, a warden's inbox and the dead-letter queue after the runs. What is tested is the robot's
side, so the server's store is SQLite: the store's behaviour is one implementation over the
persistence port, whose contract runs on both databases (decision 0020).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

from fleetbus.broker.dead_letter_queue import peek_dead_letters
from fleetbus.publishers.client import RobotClient, robot_folder
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.hazards import DEFAULT_MISSION, Hazard, HazardState
from fleetbus_dev.local_node import LocalNode
from tests.link import NetworkLink
from tests.support import (
    PROJECT_ROOT,
    Bus,
    EventKey,
    assert_stored_once_in_order,
    network_link,
    read_line,
    wait_for,
)


def start_program(bus: Bus, url: str, *args: str, state_dir: Path | None = None) -> subprocess.Popen[str]:
    """A robot program with the account ``url``, its personal database under ``state_dir`` (default:
    the test's robots folder)."""
    folder = state_dir or bus.settings.robots_dir
    return subprocess.Popen(
        [sys.executable, "-m", "tests.robot_program", str(folder), *args],
        cwd=PROJECT_ROOT,
        env={**os.environ, "FLEETBUS_ROBOT_URL": url},  # a password is never an argument
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=open(bus.settings.data_dir / f"program-{uuid.uuid4().hex[:6]}.log", "wb"),
        text=True,
    )


def finish(program: subprocess.Popen[str], timeout: float = 120) -> str:
    """Wait for a program's end; its output."""
    output, _ = program.communicate(timeout=timeout)
    assert program.returncode == 0, f"the robot program failed ({program.returncode}): {output}"
    return output


def run_program(bus: Bus, url: str, *args: str, timeout: float = 120) -> str:
    """Run a robot program with the account ``url`` to its end; its output."""
    return finish(start_program(bus, url, *args), timeout)


def epoch_of(output: str) -> str:
    """The epoch a program's output names (its ``ready EPOCH`` line)."""
    return next(line.split()[1] for line in output.splitlines() if line.startswith("ready "))


def waiting(bus: Bus, robot: str) -> int:
    outbox = bus.outbox(robot)
    try:
        return outbox.pending()
    finally:
        outbox.close()


def test_three_short_robot_programs_each_deliver_their_hazard(bus: Bus) -> None:
    """``publish`` waits for the first connection, so a program that publishes right after it
    started and ends at once leaves nothing in its outbox."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    with bus.worker():
        for run in (1, 2, 3):
            output = run_program(bus, account.amqp_url, "--hazards", "1")
            assert "published 1" in output and "closed" in output
            assert waiting(bus, "explorer1") == 0, f"run {run} left its hazard in the outbox"
            wait_for(lambda run=run: bus.count("hazard") == run, what=f"the hazard of run {run} stored")


def test_a_robot_program_started_without_the_broker_neither_blocks_nor_loses_its_hazards(
    bus: Bus, link_for: list[NetworkLink]
) -> None:
    """The first publish waits for the first connection attempt only; once it failed, the others
    return at once, and leaving the block gives up as soon as its one more attempt fails (not
    after its close timeout). The hazards go with the next run that reaches the broker."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
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


def localised_warden(bus: Bus) -> RobotClient:
    """A warden that reports itself localised, so that hazards are announced as they arrive."""
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    warden.publish("localisation", {"localised": True})
    wait_for(
        lambda: all(r.localised for r in bus.with_store(lambda store: store.hazards.robots("warden"))),
        what="warden1 localised",
    )
    return warden


def assert_hazards_delivered(bus: Bus, warden: RobotClient, runs: dict[str, int]) -> None:
    """Each run's hazards (its epoch: how many) stored once and in order, announced to the warden
    once each, and nothing dead-lettered."""
    sent: list[EventKey] = [(epoch, seq) for epoch, count in runs.items() for seq in range(count)]
    total = len(sent)
    wait_for(lambda: bus.count("hazard") == total, timeout=60, what=f"{total} hazards stored")
    notes = warden.receive(total, timeout=60)
    assert sorted((n.event.epoch, n.event.seq) for n in notes) == sorted(sent), "each announced once"

    def open_hazards() -> list[Hazard]:
        return bus.with_store(lambda store: store.hazards.open_hazards(DEFAULT_MISSION))

    assert [h.hazard_id for h in open_hazards()] == list(range(1, total + 1))
    # a hazard is marked announced once its copies were confirmed: just after the warden has it
    wait_for(
        lambda: {h.state for h in open_hazards()} == {HazardState.ANNOUNCED},
        what="every hazard marked announced",
    )
    assert peek_dead_letters(bus.admin_url) == [], "nothing dead-lettered (no sequence-reused)"
    assert_stored_once_in_order(bus, "explorer1", sent)
    assert bus.gaps() == []


def test_a_robot_that_lost_its_personal_database_keeps_publishing(bus: Bus) -> None:
    """Before epochs, the second run counted from 0 again and all five were dead-lettered as
    ``sequence-reused``: the robot was muted."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    with bus.worker():
        warden = localised_warden(bus)
        first = run_program(bus, account.amqp_url, "--hazards", "5")
        shutil.rmtree(robot_folder(bus.settings.robots_dir, "explorer1"))  # a new disk, a re-flash
        second = run_program(bus, account.amqp_url, "--hazards", "5")
        assert_hazards_delivered(bus, warden, {epoch_of(first): 5, epoch_of(second): 5})
    assert epoch_of(first) < epoch_of(second), "epochs sort in the order the runs began"


def test_a_robot_that_lost_its_personal_database_while_the_broker_is_down_keeps_publishing(
    killable_bus: Bus, killable_node: LocalNode
) -> None:
    """The second run, without its database, publishes while the broker is dead: its five hazards
    wait in the new outbox with its new epoch, and go with the next run, as they were built."""
    bus = killable_bus
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    with bus.worker():
        warden = localised_warden(bus)
        first = run_program(bus, account.amqp_url, "--hazards", "5")
        shutil.rmtree(robot_folder(bus.settings.robots_dir, "explorer1"))
        killable_node.kill()
        second = run_program(bus, account.amqp_url, "--hazards", "5")
        assert waiting(bus, "explorer1") == 5, "the second run's hazards wait on disk"
        killable_node.up()
        third = run_program(bus, account.amqp_url, "--close-timeout", "60")  # delivers what waits
        assert waiting(bus, "explorer1") == 0
        assert len({epoch_of(first), epoch_of(second), epoch_of(third)}) == 3
        assert_hazards_delivered(bus, warden, {epoch_of(first): 5, epoch_of(second): 5})


def test_two_processes_with_one_robot_account_publish_at_once(bus: Bus, tmp_path: Path) -> None:
    """Two personal databases, one account (a spare running with the robot's credentials): each
    process numbers in its own epoch, so neither reuses the other's numbers."""
    # fewer on the emulated MongoDB, whose inserts slow down as a collection grows (not MongoDB's)
    each = 1000 if bus.settings.mongodb_url is None else 400
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    with bus.worker():
        programs = [
            start_program(
                bus,
                account.amqp_url,
                "--status",
                str(each),
                "--wait-for-go",
                "--close-timeout",
                "120",
                state_dir=tmp_path / folder,
            )
            for folder in ("robot-a", "robot-b")
        ]
        epochs = [epoch_of(read_line(program, "ready")) for program in programs]
        for program in programs:
            assert program.stdin is not None
            program.stdin.write("go\n")
            program.stdin.flush()
        for program in programs:
            assert f"published {each}" in finish(program)
        wait_for(lambda: bus.count() == 2 * each, timeout=120, what=f"{2 * each} events stored")
    assert len(set(epochs)) == 2
    assert peek_dead_letters(bus.admin_url) == [], "nothing dead-lettered (no sequence-reused)"
    assert_stored_once_in_order(bus, "explorer1", [(epoch, seq) for epoch in epochs for seq in range(each)])
    assert bus.gaps() == [] and bus.with_store(lambda store: store.events.duplicates()) == []
