"""A thread of the bridge that fails is started again, with a growing wait, and the status says so."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from fleetbus.publishers.ros import parts
from fleetbus.publishers.ros.commands import command_messages
from fleetbus.publishers.ros.counters import Counters, DropReason
from tests.support import wait_for


def test_a_failing_thread_is_restarted_with_backoff_and_shown(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(parts, "RESTART_FIRST_S", 0.01)
    counters, stop = Counters(), threading.Event()
    runs: list[int] = []
    failing = threading.Event()
    failing.set()

    def notifications() -> None:  # a fault injected: it fails three times, then runs until stopped
        runs.append(len(runs))
        if len(runs) <= 3:
            raise RuntimeError(f"injected fault {len(runs)}")
        failing.clear()
        stop.wait()

    thread = parts.supervised("notifications", notifications, counters.parts, stop)
    wait_for(lambda: not failing.is_set(), 10, "the thread running again")
    shown = counters.snapshot()["parts"]["notifications"]
    assert shown["state"] == "running" and shown["restarts"] == 3 and shown["failures"] == 3
    assert shown["last_failure"] == "RuntimeError: injected fault 3"
    assert "parts that failed: notifications running (3 restarts" in counters.status_line()
    stop.set()
    thread.join(5)
    assert not thread.is_alive() and counters.parts.snapshot()["notifications"]["state"] == "stopped"


def test_the_wait_doubles_up_to_its_most() -> None:
    waits = [parts.restart_delay(n) for n in range(1, 10)]
    assert waits[:4] == [0.5, 1.0, 2.0, 4.0]
    assert waits[-1] == parts.RESTART_MOST_S and waits == sorted(waits)


def test_a_thread_that_ends_by_itself_counts_as_failed() -> None:
    counters, stop = Counters(), threading.Event()
    thread = parts.supervised("commands", lambda: None, counters.parts, stop)
    wait_for(lambda: counters.parts.failing() == ["commands"], 10, "the early end noted")
    assert counters.parts.snapshot()["commands"]["last_failure"] == "it ended by itself"
    stop.set()
    thread.join(5)


def test_the_status_file_never_goes_back_to_an_older_state(tmp_path: Path) -> None:
    """The master's reader and the status ticker write the status file at once: a write that
    returned is never replaced by an older snapshot, and the file ends with the final counts."""
    counters, path = Counters(), tmp_path / "status.json"
    went_back: list[str] = []

    def writer(topic: str) -> None:
        for written in range(1, 301):
            counters.drop(topic, DropReason.RATE)  # only this thread counts this topic
            counters.write(path)
            shown = json.loads(path.read_text())["topics"].get(topic, {}).get("dropped", {}).get("rate", 0)
            if shown < written:
                went_back.append(f"{topic}: wrote {written}, the file then showed {shown}")

    threads = [threading.Thread(target=writer, args=(topic,)) for topic in ("/a", "/b")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert went_back == []
    final = json.loads(path.read_text())
    assert {t: v["dropped"] for t, v in final["topics"].items()} == {"/a": {"rate": 300}, "/b": {"rate": 300}}


def test_a_goal_with_no_place_in_it_goes_as_its_text_and_does_not_stop_the_commands() -> None:
    """A goal whose x or y is no number: its text is published (the robot's software may read it),
    no pose; the thread that follows the commands raised on it and took it again until it expired."""
    bad = command_messages(
        "bot1", "bot1.goal", "ops1", json.dumps({"x": "north", "y": 2}).encode(), "/fleetbus"
    )
    assert [m["topic"] for m in bad] == ["/fleetbus/command"]
    good = command_messages(
        "bot1", "bot1.goal", "ops1", json.dumps({"x": "4.5", "y": 2}).encode(), "/fleetbus"
    )
    assert [m["topic"] for m in good] == ["/fleetbus/command", "/fleetbus/goal"]
    assert good[1]["fields"]["pose"]["position"] == {"x": 4.5, "y": 2.0, "z": 0.0}
