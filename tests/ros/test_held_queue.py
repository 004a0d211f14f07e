"""What the ROS bridge holds between ROS and the outbox is bounded by messages and by bytes, on
both sides of the pipe; what does not fit is counted as dropped where ``fleetbus ros status``
shows it. (The bridge's writer is not started here, so nothing leaves the queue unless taken.)"""

from __future__ import annotations

import io
import json
import queue
import threading
import time
from pathlib import Path

import pytest

from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.ros.bridge import Bridge, BridgeOptions
from fleetbus.publishers.ros.counters import DropReason
from fleetbus.publishers.ros.held import HeldQueue
from fleetbus.publishers.ros.mapping import load_mapping


def test_a_queue_holds_up_to_its_count_and_its_bytes_and_one_large_message_alone() -> None:
    held: HeldQueue[str] = HeldQueue(most_messages=3, most_bytes=1000)
    assert held.offer("a", 400) and held.offer("b", 400)
    assert not held.offer("c", 400), "past the bytes"
    assert held.offer("d", 200), "up to the bytes exactly"
    assert not held.offer("e", 1), "past the count"
    assert [held.get(0), held.get(0), held.get(0)] == ["a", "b", "d"]
    assert held.held_bytes == 0
    assert held.offer("image", 5000), "a message over the whole bound passes when nothing is held"
    assert not held.offer("f", 1)
    assert held.get(0) == "image"
    with pytest.raises(queue.Empty):
        held.get(0)


def test_images_the_bridge_cannot_take_in_time_are_dropped_by_bytes_and_counted(tmp_path: Path) -> None:
    robot = RobotClient("amqp://nobody:unused@127.0.0.1:1/", state_dir=tmp_path)  # never connects
    options = BridgeOptions(queue=10_000, queue_bytes=3 * 1024 * 1024)
    bridge = Bridge(robot, load_mapping(None), options, tmp_path)
    image = {
        "kind": "message",
        "topic": "/camera/image_raw",
        "type": "sensor_msgs/Image",
        "received_ns": time.time_ns(),
    }
    # as the ROS side sends an image: its pixels after its line, as they are
    fields = {"data": {"_raw": 0, "length": 1_000_000}}
    line = json.dumps({**image, "fields": fields, "raw": [1_000_000]}).encode()
    for _ in range(10):
        bridge._take_line(line, threading.Event(), io.BytesIO(bytes(1_000_000)))
    assert bridge.counters.dropped["/camera/image_raw"][DropReason.BRIDGE_QUEUE] == 7
    assert len(bridge._take(draining=True)) == 3
