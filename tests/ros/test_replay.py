"""Replay into ROS: a recorded window published on a real ROS master as its original topics and
types, at the recorded pace slowed down, counted and compared by a rospy subscriber."""

from __future__ import annotations

import asyncio
import base64
import itertools
import json
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

from fleetbus.workers.recorder.bag_import import import_bag
from fleetbus.workers.store import open_recording_store
from tests.ros.conftest import RosMaster, ros_peer
from tests.ros.test_foxglove_export import sensor_bag
from tests.support import Bus

ROBOT = "replayer"
SPEED = 0.5
#: sensor_bag.py writes each topic's messages 100 ms apart.
APART_S = 0.1
INSTANTS = 6


def read_lines(process: subprocess.Popen[str], count: int, timeout: float) -> list[str]:
    """The next ``count`` lines ``process`` prints (several may come at once); fails after ``timeout``."""
    lines: list[str] = []

    def read() -> None:
        assert process.stdout is not None
        while len(lines) < count and (line := process.stdout.readline()):
            lines.append(line)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout)
    assert len(lines) == count, f"{len(lines)} of {count} lines printed within {timeout} s: {lines}"
    return lines


def test_a_recorded_window_is_published_again_on_ros_at_its_pace(
    bus: Bus, ros_master: RosMaster, tmp_path: Path
) -> None:
    bag = tmp_path / "sensors.bag"
    written = sensor_bag(bag, 0, INSTANTS)

    async def load() -> None:
        async with open_recording_store(bus.settings) as store:
            await import_bag(store, bag, ROBOT, bus.settings.max_message_bytes)

    asyncio.run(load())
    topics = sorted(written)
    with ros_peer(ros_master, "record", *topics) as subscriber:
        command = [sys.executable, "-m", "fleetbus", "ros", "replay", ROBOT, "--subscribers", "1"]
        command += ["--speed", str(SPEED), "--delay", "0.5"]
        env = {**ros_master.env, **bus.worker_env(), "COLUMNS": "200"}
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        total = sum(len(sent["data"]) for sent in written.values())
        assert f"replayed {total} messages of {ROBOT} on {len(topics)} topics" in done.stdout
        received = [json.loads(line) for line in read_lines(subscriber, total, 30)]
    for topic, sent in written.items():
        got = [m for m in received if m["topic"] == topic]
        assert [m["type"] for m in got] == [sent["type"]] * len(sent["data"]), "its original type"
        assert [m["data"] for m in got] == sent["data"], f"{topic}: the recorded messages, byte for byte"
        # at half the recorded pace, once under way (a new subscriber's first deliveries may lag):
        # the bar lies between that pace and the recorded one, so a late delivery or two cannot fail it
        gaps = [b["t"] - a["t"] for a, b in itertools.pairwise(got)]
        assert got[-1]["t"] - got[1]["t"] >= (len(got) - 2) * APART_S / SPEED * 0.75, f"{topic}: {gaps}"
    assert base64.b64decode(received[0]["data"]), "not empty"


def test_a_replay_with_no_master_says_so_instead_of_waiting(
    bus: Bus, ros_installed: None, tmp_path: Path
) -> None:
    """rospy waits for ever for a master; the replay gives up after its wait, naming the master."""
    bag = tmp_path / "sensors.bag"
    sensor_bag(bag, 0, 2)

    async def load() -> None:
        async with open_recording_store(bus.settings) as store:
            await import_bag(store, bag, ROBOT, bus.settings.max_message_bytes)

    asyncio.run(load())
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))  # bound, never listening: no master there
        uri = f"http://127.0.0.1:{closed.getsockname()[1]}/"
        env = {**os.environ, **bus.worker_env(), "ROS_MASTER_URI": uri, "COLUMNS": "200"}
        command = [sys.executable, "-m", "fleetbus", "ros", "replay", ROBOT]
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    assert f"no ROS master answers at {uri}" in done.stderr.replace("\n", ""), done.stderr
