"""Field queries on ROS messages, recorded live by the bridge and imported from a bag `rosbag record`
wrote in the same run: by topic, by field (text, numbers, nested), by time, and each transform of a
TF message by its frames; the same answers from the command line, the HTTP API and the console."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import httpx
import psutil

from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.recordings import RecordedMessage
from tests.console.support import Console, running_console
from tests.ros.conftest import RosMaster, ros_peer, running_bridge
from tests.ros.test_foxglove_export import foxglove_read
from tests.support import Bus, read_line, wait_for
from tests.test_cli import fleetbus

LIVE, IMPORTED = "rosq-live", "rosq-bag"
#: What ros_peer.py's scene sends on each topic.
SENT = {"/chatter": 6, "/tf": 3, "/odom": 3}


def by_topic(records: list[RecordedMessage], topic: str) -> list[RecordedMessage]:
    return [r for r in records if r.document["topic"] == topic]


def scene_recorded(bus: Bus, robot: str) -> list[RecordedMessage] | None:
    """The robot's ROS records once all the scene is there, its transforms too."""
    records = bus.recorded("ros", robot_id=robot)
    done = all(len(by_topic(records, topic)) == count for topic, count in SENT.items())
    return records if done and len(bus.recorded("ros_tf", robot_id=robot)) == 6 else None


@contextmanager
def rosbag_record(master: RosMaster, bag: Path, *topics: str) -> Iterator[None]:
    """``rosbag record`` of ``topics`` into ``bag``; stopped (and the bag closed) on leaving."""
    recorder = subprocess.Popen(
        ["rosbag", "record", "-O", str(bag), *topics],
        env=master.env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        yield
    finally:
        os.killpg(recorder.pid, signal.SIGINT)
        recorder.wait(30)
        # the ``rosbag`` wrapper exits on SIGINT at once; its ``record`` child closes the bag
        # (renames ``.active``) after, so the bag is whole only once the whole group is gone
        wait_for(lambda: not group_alive(recorder.pid), what="rosbag record to close its bag")
    assert bag.exists(), f"rosbag record wrote no {bag}"


def group_alive(group: int) -> bool:
    """Whether a process of ``group`` still runs (a zombie nobody reaped has closed its files)."""
    for process in psutil.process_iter(["status"]):
        try:
            if os.getpgid(process.pid) == group and process.info["status"] != psutil.STATUS_ZOMBIE:
                return True
        except (ProcessLookupError, psutil.Error):
            continue
    return False


def lines(result: subprocess.CompletedProcess[str]) -> list[dict[str, Any]]:
    assert result.returncode == 0, result.stderr
    return [json.loads(line) for line in result.stdout.splitlines()]


def test_ros_messages_are_found_by_topic_field_and_time_and_transforms_by_frames(
    bus: Bus, ros_master: RosMaster, tmp_path: Path
) -> None:
    robot = bus.robot(bus.add(LIVE, kind=RobotKind.EXPLORER))
    bag = tmp_path / "scene.bag"
    with (
        bus.worker(),
        bus.recorder(),
        running_bridge(robot, ros_master, bus.settings.robots_dir, include=tuple(SENT)),
    ):
        with rosbag_record(ros_master, bag, *SENT), ros_peer(ros_master, "scene", "2") as peer:
            read_line(peer, '"sent"', 60)
            live = wait_for(lambda: scene_recorded(bus, LIVE), what="the scene recorded live")
            # rosbag has it all once the bridge has: both subscribed before the first message
        imported = fleetbus(bus, "import", str(bag), "--robot", IMPORTED, "--json")
        assert imported.returncode == 0, imported.stderr
        assert json.loads(imported.stdout)["stored"] == sum(SENT.values())
        bagged = wait_for(lambda: scene_recorded(bus, IMPORTED), what="the bag imported")

        # by topic, one robot's and both
        chatter = lines(fleetbus(bus, "query", "ros", "--robot", LIVE, "-w", "topic=/chatter", "--json"))
        assert [r["fields"]["data"] for r in chatter] == [*(f"hello {i}" for i in range(5)), "goodbye"]
        assert chatter[0]["ros_type"] == "std_msgs/msg/String"
        # by a text field, named alone (``data`` is ``fields.data``), with a substring
        hellos = lines(fleetbus(bus, "query", "ros", "-w", "topic=/chatter", "-w", "data~hello", "--json"))
        assert sorted(r["__recorded"]["robot_id"] for r in hellos) == [IMPORTED] * 5 + [LIVE] * 5
        # by nested numbers, and a time window
        odom = by_topic(bagged, "/odom")
        window = ["--since", odom[1].recorded_at.isoformat(), "--until", odom[2].recorded_at.isoformat()]
        where = ["-w", "topic=/odom", "-w", "fields.pose.pose.position.x>=1", "-w", "twist.twist.linear.x<1"]
        found = lines(fleetbus(bus, "query", "ros", "--robot", IMPORTED, *where, *window, "--json"))
        assert [r["fields"]["pose"]["pose"]["position"]["x"] for r in found] == [1.0]
        # each transform by its frames (the reference's query), live and imported alike
        frames = ["-w", "frame_id=odom", "-w", "child_frame_id=base_link"]
        transforms = lines(fleetbus(bus, "query", "ros_tf", *frames, "--json"))
        assert sorted((t["__recorded"]["robot_id"], t["translation"]["x"]) for t in transforms) == [
            (robot_id, 10.0 + i) for robot_id in (IMPORTED, LIVE) for i in range(3)
        ]
        live_tf = by_topic(live, "/tf")
        assert {t["message"] for t in transforms if t["__recorded"]["robot_id"] == LIVE} == {
            r.key for r in live_tf
        }, "each transform names the message it came in"

        # a live message's definition came with it: Foxglove decodes what the bridge recorded
        out = tmp_path / "live.mcap"
        exported = fleetbus(bus, "export", "--mcap", str(out), "--robot", LIVE, "--topic", "/tf")
        assert exported.returncode == 0, exported.stderr
        decoded = [line for line in foxglove_read(out) if line["kind"] == "message"]
        assert [(m["topic"], m["schema"], m["encoding"]) for m in decoded] == [
            (f"/{LIVE}/tf", "tf2_msgs/TFMessage", "ros1")
        ] * 3
        moved = [m["message"]["transforms"][1]["transform"]["translation"]["x"] for m in decoded]
        assert moved == [10, 11, 12]

        # the same through the HTTP API and the console's Messages page
        with running_console(bus) as console:
            console.user("rosq-super", UserRole.SUPERVISOR)
            assert_same_over_http(console, odom, live_tf)


def assert_same_over_http(
    console: Console, odom: list[RecordedMessage], live_tf: list[RecordedMessage]
) -> None:
    token = console.session("rosq-super")
    bearer = {"Authorization": f"Bearer {token}"}
    with httpx.Client(base_url=console.base, headers=bearer, timeout=30) as api:
        reply = api.get(
            "/recording/records/ros",
            params={
                "where": ["topic=/odom", "pose.pose.position.x>=1"],
                "robot": IMPORTED,
                "since": odom[1].recorded_at.isoformat(),
            },
        )
        assert reply.status_code == 200, reply.text
        assert [(r["seq"], r["document"]) for r in reply.json()] == [(r.seq, r.document) for r in odom[1:]]
        reply = api.get(
            "/recording/records/ros_tf",
            params={"where": ["frame_id=map", "child_frame_id=odom"], "robot": LIVE},
        )
        assert reply.status_code == 200, reply.text
        assert [r["document"]["translation"]["x"] for r in reply.json()] == [0.0, 1.0, 2.0]
        assert {r["document"]["message"] for r in reply.json()} == {r.key for r in live_tf}
    with console.http_as("rosq-super") as http:
        query = {"type": "ros", "robot": IMPORTED, "where": "topic=/odom\npose.pose.position.x>=1"}
        page = http.get(f"/console/messages?{urlencode(query)}")
        assert page.status_code == 200, page.text
        rows = re.findall(r'<tr class="record type-ros" data-key="([0-9a-f]+)"', page.text)
        assert rows == [r.key for r in odom[1:]]
