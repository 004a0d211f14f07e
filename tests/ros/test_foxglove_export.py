"""Exported ROS messages, read by the tools ROS users read them with: an MCAP file decoded by
Foxglove's own packages (the readers its Image, PointCloud2, LaserScan, Map and TF panels use), and
a ROS 1 bag read back by the rosbag API, byte for byte what rosbag wrote in the imported bags."""

from __future__ import annotations

import asyncio
import base64
import json
import subprocess
from pathlib import Path
from typing import Any

from fleetbus.workers.recorder.bag_import import import_bag
from fleetbus.workers.store import open_recording_store
from tests.peers import PEERS, node
from tests.ros.conftest import ROS_PYTHON
from tests.ros_bags import write_bag
from tests.support import Bus
from tests.test_cli import fleetbus

SENSOR_BAG = Path(__file__).with_name("sensor_bag.py")
ROBOTS = {"fox-a": 0, "fox-b": 1}
ROS2_ROBOT = "fox-c"
T0 = 1_772_442_000
READ_BAG = """
import base64, json, sys, rosbag
bag = rosbag.Bag(sys.argv[1])
info = bag.get_type_and_topic_info()
read = {}
for topic, raw, at in bag.read_messages(raw=True):
    read.setdefault(topic, []).append(base64.b64encode(raw[1]).decode())
print(json.dumps({
    "topics": {t: [i.msg_type, i.message_count] for t, i in info.topics.items()},
    "data": read,
}))
"""


def sensor_bag(path: Path, offset: int, count: int = 2) -> dict[str, Any]:
    command = [ROS_PYTHON, str(SENSOR_BAG), str(path), str(offset), str(count)]
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    written: dict[str, Any] = json.loads(done.stdout)
    return written


def foxglove_read(path: Path) -> list[dict[str, Any]]:
    done = subprocess.run(
        [node(), str(PEERS / "mcap_decode.js"), str(path)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return [json.loads(line) for line in done.stdout.splitlines()]


def test_exported_ros_messages_decode_in_foxglove_and_rosbag(
    bus: Bus, ros_installed: None, tmp_path: Path
) -> None:
    written = {robot: sensor_bag(tmp_path / f"{robot}.bag", offset) for robot, offset in ROBOTS.items()}
    ros2 = write_bag(tmp_path / "ros2", "ros2-mcap", count=6)

    async def load() -> None:
        async with open_recording_store(bus.settings) as store:
            for robot in ROBOTS:
                await import_bag(store, tmp_path / f"{robot}.bag", robot, bus.settings.max_message_bytes)
            await import_bag(store, tmp_path / "ros2", ROS2_ROBOT, bus.settings.max_message_bytes)

    asyncio.run(load())

    out = tmp_path / "all.mcap"
    exported = fleetbus(bus, "export", "--mcap", str(out), "--type", "ros", "--json")
    assert exported.returncode == 0, exported.stderr
    lines = foxglove_read(out)
    messages = [line for line in lines if line["kind"] == "message"]
    by_topic: dict[str, list[dict[str, Any]]] = {}
    for line in messages:
        by_topic.setdefault(line["topic"], []).append(line)

    # one channel per robot and topic, each in its native encoding
    expected_topics = {f"/{robot}{topic}" for robot in ROBOTS for topic in written[robot]}
    expected_topics |= {f"/{ROS2_ROBOT}{topic}" for topic in {w.topic for w in ros2}}
    assert set(by_topic) == expected_topics
    for robot in ROBOTS:
        for topic, sent in written[robot].items():
            got = by_topic[f"/{robot}{topic}"]
            assert [(m["schema"], m["encoding"]) for m in got] == [(sent["type"], "ros1")] * len(sent["data"])
            assert {m["channel_metadata"]["robot"] for m in got} == {robot}
    assert {m["encoding"] for m in messages if m["topic"].startswith(f"/{ROS2_ROBOT}/")} == {"cdr"}

    # what the panels draw, as Foxglove's readers decode it
    image = by_topic["/fox-b/camera/image_raw"][1]["message"]
    assert (image["width"], image["height"], image["encoding"]) == (4, 3, "rgb8")
    assert base64.b64decode(image["data"]["base64"]) == bytes((1 + 1 + k) % 256 for k in range(36))
    cloud = by_topic["/fox-a/points"][0]["message"]
    assert [f["name"] for f in cloud["fields"]] == ["x", "y", "z"] and cloud["width"] == 3
    assert len(base64.b64decode(cloud["data"]["base64"])) == 36
    scan = by_topic["/fox-a/scan"][1]["message"]
    assert scan["ranges"] == [1.0, 2.0, "Infinity", 3.5, 1.5]
    grid = by_topic["/fox-b/map"][0]["message"]
    assert grid["info"]["width"] == 4 and grid["data"]["base64"]
    tf = by_topic["/fox-a/tf"][1]["message"]["transforms"]
    moves = [(t["header"]["frame_id"], t["child_frame_id"], t["transform"]["translation"]["x"]) for t in tf]
    assert moves == [("map", "odom", 0.0), ("odom", "base_link", 1.5)]
    assert tf[0]["header"]["stamp"] == {"sec": T0, "nsec": 100_000_123}
    ros2_pose = by_topic[f"/{ROS2_ROBOT}/robot/pose"][0]["message"]
    assert ros2_pose["pose"]["position"]["y"] == 2.5 and ros2_pose["header"]["frame_id"] == "map"
    [metadata] = [line for line in lines if line["kind"] == "metadata"]
    assert metadata["metadata"]["robots"] == "all" and metadata["metadata"]["types"] == "ros"

    # a ROS 1 bag of two robots, read back by the rosbag API: what rosbag wrote, byte for byte
    bag = tmp_path / "out.bag"
    robots = [arg for robot in ROBOTS for arg in ("--robot", robot)]
    exported = fleetbus(bus, "export", "--bag", str(bag), *robots)
    assert exported.returncode == 0, exported.stderr
    done = subprocess.run([ROS_PYTHON, "-c", READ_BAG, str(bag)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    read = json.loads(done.stdout)
    for robot in ROBOTS:
        for topic, sent in written[robot].items():
            assert read["topics"][f"/{robot}{topic}"] == [sent["type"], len(sent["data"])]
            assert read["data"][f"/{robot}{topic}"] == sent["data"], f"{robot} {topic}: the same bytes"

    # a topic, one robot and a window to the nanosecond: the second scan alone
    second = T0 * 10**9 + 100_000_123
    one = tmp_path / "one.mcap"
    window = ["--since", str(second), "--until", str(second + 1)]
    exported = fleetbus(bus, "export", "--mcap", str(one), "--robot", "fox-a", "--topic", "/scan", *window)
    assert exported.returncode == 0, exported.stderr
    [scan_line] = [line for line in foxglove_read(one) if line["kind"] == "message"]
    assert scan_line["topic"] == "/fox-a/scan" and scan_line["log_time"] == str(second)

    # refused, saying why, and no file written
    never = tmp_path / "never.mcap"
    for args, code, said in (
        (["--robot", "fox-z"], 2, "nothing is recorded of robot 'fox-z'"),
        (["--since", str(second), "--until", str(second)], 2, "the window is empty or inverted"),
        (["--topic", "/nothing"], 1, "nothing to export"),
    ):
        refused = fleetbus(bus, "export", "--mcap", str(never), *args)
        assert refused.returncode == code and said in refused.stderr.replace("\n", " "), refused.stderr
        assert not never.exists() and not never.with_name("never.mcap.partial").exists()
