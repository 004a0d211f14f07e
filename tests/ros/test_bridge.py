"""The live ROS bridge against a real ROS 1 master, real ROS nodes and the real broker."""

from __future__ import annotations

import errno
import json
import stat
import time
import xmlrpc.client
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pika
import pytest

from fleetbus.broker.accounts import Role
from fleetbus.broker.mounts import bind_all, mount_bindings
from fleetbus.publishers import storage as storage_module
from fleetbus.publishers.ros.bridge import WRITER_PART
from fleetbus.publishers.ros.mapping import Mapping, load_mapping
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventQuery
from tests.factories import hazard, status
from tests.link import NetworkLink
from tests.ros.conftest import RosMaster, ros_peer, running_bridge
from tests.support import Bus, network_link, read_line, wait_for

GOAL, COSTMAP = "/move_base_simple/goal", "/move_base/local_costmap/costmap"
#: The topics ``ros_peer.py samples`` publishes on (one latched message each).
SAMPLE_TOPICS = {"/chatter", "/imu", "/robot_pose", "/map", GOAL, COSTMAP}
#: The header stamp ros_peer.py gives its samples.
SAMPLE_STAMP = datetime.fromtimestamp(1_700_000_000.25, timezone.utc)


def ros_records(bus: Bus, robot: str) -> dict[str, dict[str, Any]]:
    """The last stored ``ros`` event body of each topic."""
    return {r.body["topic"]: r.body for r in bus.find(EventQuery(type="ros", robot_id=robot))}


def test_every_topic_is_recorded_mapped_ones_become_events_and_hazards_come_back_as_ros(
    bus: Bus, ros_master: RosMaster
) -> None:
    account = bus.add("rosbot1", kind=RobotKind.WARDEN)
    robot = bus.robot(account)
    explorer = bus.robot(bus.add("scout1", kind=RobotKind.EXPLORER))
    operator = bus.add("oper1", Role.OPERATOR)
    bind_all(bus.api, bus.vhost, mount_bindings("rosbot1", "oper1"))  # what a mount does
    with (
        bus.worker(),
        bus.recorder(),
        ros_peer(ros_master, "listen", "/fleetbus/hazard_pose", "geometry_msgs/PoseStamped") as listener,
        ros_peer(ros_master, "listen", "/fleetbus/goal", "geometry_msgs/PoseStamped") as goals,
        ros_peer(ros_master, "samples"),
        running_bridge(robot, ros_master, bus.settings.robots_dir, commands_url=account.amqp_url) as bridge,
    ):
        every_topic = SAMPLE_TOPICS
        records = wait_for(
            lambda: (r := ros_records(bus, "rosbot1")) and every_topic <= set(r) and r,
            what="every topic stored as ros events, mapped ones too",
        )
        assert records["/chatter"]["ros_type"] == "std_msgs/msg/String", "named as bag imports name types"
        # the bridge's files in the robot's folder are its owner's only, as the outbox is
        folder = bus.settings.robots_dir / "rosbot1"
        modes = {
            name: stat.S_IMODE((folder / name).stat().st_mode) for name in ("ros-bridge.json", "ros-side.log")
        }
        assert modes == {"ros-bridge.json": 0o600, "ros-side.log": 0o600}
        assert records["/chatter"]["fields"] == {"data": "hello fleetbus"}
        assert records["/chatter"]["stamp"] is None, "a message without a header has no stamp"
        imu = records["/imu"]  # a type fleetbus has no model of
        assert imu["ros_type"] == "sensor_msgs/msg/Imu"
        assert datetime.fromisoformat(imu["stamp"]) == SAMPLE_STAMP
        assert imu["fields"]["header"]["frame_id"] == "imu_link"
        assert imu["fields"]["header"]["stamp"] == {"sec": 1_700_000_000, "nanosec": 250_000_000}
        assert imu["fields"]["linear_acceleration"] == {"x": 0.0, "y": 0.0, "z": 9.81}
        assert imu["fields"]["orientation_covariance"] == [0.5] * 9
        # a mapped message is also kept as the ROS message it was: z, its frame, its stamp
        pose_message = records["/robot_pose"]
        assert pose_message["ros_type"] == "geometry_msgs/msg/PoseStamped"
        assert pose_message["fields"]["header"]["frame_id"] == "map"
        assert datetime.fromisoformat(pose_message["stamp"]) == SAMPLE_STAMP
        assert pose_message["fields"]["pose"]["position"] == {"x": 3.5, "y": -1.25, "z": 0.0}
        assert records["/map"]["fields"]["info"]["width"] == 4
        assert records[GOAL]["fields"]["pose"]["position"]["x"] == 42.0

        # the pose is the robot's localisation (its place on the console's map), the grid a map;
        # the operator's goal and the local costmap are no rule's topics: recorded, not mapped
        [pose] = wait_for(lambda: bus.find(EventQuery(type="localisation", robot_id="rosbot1")), what="pose")
        assert pose.body == {
            "localised": True,
            "pose": {"x": 3.5, "y": -1.25, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        }
        wait_for(lambda: bus.count("map", "rosbot1"), what="the grid stored as a map")
        # the bridge counts a batch just after its outbox write, so the store may have it first:
        # wait for every topic counted (a goal or costmap made a map would be counted with it)
        wait_for(
            lambda: (
                every_topic <= set(bridge.counters.recorded)
                and bridge.counters.mapped == {"/robot_pose": 1, "/map": 1}
            ),
            what="the pose and the grid counted as mapped, the goal and the costmap not",
        )
        stored = explorer.fetch_map()
        rows = [bytes([254, 254, 254, 0]), bytes([254, 205, 0, 254]), bytes([254, 254, 0, 205])]
        assert stored.pgm == b"P5\n4 3\n255\n" + b"".join(rows), "top row first, map_server's thresholds"
        assert stored.metadata["resolution"] == pytest.approx(0.05)  # a float32 in ROS
        assert stored.metadata["origin"] == [-1.0, -2.0, 0.0]

        # the recording keeps them as it keeps a bag's messages (fleetbus.schemas.ros)
        recorded = wait_for(
            lambda: (
                (r := {r.routing_key: r for r in bus.recorded("ros", robot_id="rosbot1")})
                and {"rosbot1.ros.imu", "rosbot1.ros.chatter"} <= set(r)
                and r
            ),
            what="/imu and /chatter recorded",
        )
        imu_record = recorded["rosbot1.ros.imu"]
        assert imu_record.exchange == "ros"
        assert imu_record.sent_at == SAMPLE_STAMP
        assert imu_record.document == imu
        assert recorded["rosbot1.ros.chatter"].document["fields"] == {"data": "hello fleetbus"}

        # the warden (localised by its pose) is told of a hazard: on a ROS topic, for ROS code
        explorer.publish("hazard", hazard(0, "Fire"))
        line = json.loads(read_line(listener, '{"topic": "/fleetbus/hazard_pose"', 30))
        assert line == {"topic": "/fleetbus/hazard_pose", "frame_id": "map", "x": 2.66, "y": 1.22}

        # a goal from the operator who mounted the robot: a PoseStamped, as RViz sends one
        connection = blocking_connection(operator.amqp_url)
        try:
            channel = connection.channel()
            channel.confirm_delivery()
            goal = json.dumps({"x": 4.0, "y": 5.5, "frame_id": "map"}).encode()
            channel.basic_publish(
                "oper1.commands", "rosbot1.goal", goal, pika.BasicProperties(user_id="oper1"), mandatory=True
            )
        finally:
            connection.close()
        line = json.loads(read_line(goals, '{"topic": "/fleetbus/goal"', 30))
        assert line == {"topic": "/fleetbus/goal", "frame_id": "map", "x": 4.0, "y": 5.5}


def test_the_outbox_keeps_what_the_bridge_records_while_the_broker_is_away(
    bus: Bus, ros_master: RosMaster, link_for: list[NetworkLink]
) -> None:
    account = bus.add("rosbot2", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
    robot = bus.robot(account, via=link)
    link.cut()
    with (
        bus.worker(),
        ros_peer(ros_master, "samples"),
        running_bridge(robot, ros_master, bus.settings.robots_dir) as bridge,
    ):
        wait_for(lambda: {"/chatter", "/imu"} <= set(bridge.counters.recorded), what="messages taken")
        wait_for(lambda: robot.outbox.pending() >= 4, what="ros events, pose and map waiting in the outbox")
        assert bus.count(robot_id="rosbot2") == 0, "nothing reached the broker through the cut link"
        link.restore()
        wait_for(lambda: {"/chatter", "/imu"} <= set(ros_records(bus, "rosbot2")), what="delivered")
        wait_for(lambda: bus.count("map", "rosbot2") and bus.count("localisation", "rosbot2"), what="events")


def test_a_batch_the_full_disk_kept_only_on_the_wire_is_stored_once(
    bus: Bus, ros_master: RosMaster, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A batch into an empty outbox goes on the wire while it is written; when that write fails (a
    full disk) the bridge puts the same events in the outbox again once it has room, with their
    numbers: the server keeps one copy. Built again, they had new numbers and were stored twice."""
    robot = bus.robot(bus.add("rosbot6", kind=RobotKind.EXPLORER))
    real, failed = storage_module.write_atomically, []

    def first_write_fails_after_the_send(path: Path, data: bytes, durable: bool = True) -> None:
        if not failed and path.name.startswith("seg-"):
            failed.append(path.name)
            time.sleep(0.5)  # a slow, full disk: the sender has put the batch on the wire meanwhile
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, data, durable)

    monkeypatch.setattr(storage_module, "write_atomically", first_write_fails_after_the_send)
    with (
        bus.worker(),
        running_bridge(robot, ros_master, bus.settings.robots_dir) as bridge,
        ros_peer(ros_master, "burst", "/once", "5"),
    ):
        wait_for(lambda: failed, what="the first outbox write failed")
        wait_for(lambda: bridge.counters.recorded.get("/once") == 6, what="the burst (and its last) recorded")
        assert WRITER_PART not in bridge.counters.parts.failing(), "the writer recovered"
        assert robot.flush(timeout=30)
        recorded = dict(bridge.counters.recorded)
        # after every ros event the bridge sent, in the robot's shard: once it is stored, so are they
        robot.publish("status", status())
        wait_for(lambda: bus.count("status", "rosbot6") == 1, what="a status sent after them stored")
    stored = [r.body["topic"] for r in bus.find(EventQuery(type="ros", robot_id="rosbot6"))]
    assert {topic: stored.count(topic) for topic in recorded} == recorded, "each message stored once"


def test_filters_and_the_rate_limit_drop_and_count(bus: Bus, ros_master: RosMaster) -> None:
    robot = bus.robot(bus.add("rosbot3", kind=RobotKind.EXPLORER))
    with (
        bus.worker(),
        ros_peer(ros_master, "samples"),
        ros_peer(ros_master, "burst", "/fast", "300"),
        running_bridge(
            robot, ros_master, bus.settings.robots_dir, exclude=("/chatter", "/rosout*"), max_rate_hz=20
        ) as bridge,
    ):

        def fast() -> dict[str, Any]:
            return bridge.counters.snapshot()["topics"].get("/fast", {})

        # every one of the 301 messages is either forwarded or counted as dropped
        counts = wait_for(
            lambda: (f := fast()) and f["recorded"] + sum(f["dropped"].values()) == 301 and f,
            what="all of /fast forwarded or counted",
        )
        assert counts["dropped"]["rate"] > 0
        assert set(counts["dropped"]) == {"rate"}
        wait_for(lambda: bus.count("ros", "rosbot3") >= counts["recorded"], what="the forwarded ones stored")
        wait_for(lambda: "/imu" in bridge.counters.recorded, what="/imu recorded")
        # topics are found in one listing: /imu found means /chatter was seen, and left out
        assert "/chatter" not in bridge.counters.types
        assert not any(topic.startswith("/rosout") for topic in bridge.counters.types)
    status = json.loads(bridge.status_file.read_text())
    assert status["topics"]["/fast"]["dropped"] == counts["dropped"]


def test_a_message_its_rule_cannot_map_is_still_recorded_and_counted(
    bus: Bus, ros_master: RosMaster, tmp_path: Path
) -> None:
    """A hazard rule on /chatter, whose strings hold no pose, with no localisation rule to give
    the robot's last one: no hazard can be made, and the message is recorded all the same."""
    path = tmp_path / "mapping.yaml"
    path.write_text("standard: false\nrules:\n  - {topic: /chatter, type: std_msgs/String, event: hazard}\n")
    robot = bus.robot(bus.add("rosbot5", kind=RobotKind.EXPLORER))
    with (
        bus.worker(),
        ros_peer(ros_master, "samples"),
        running_bridge(robot, ros_master, bus.settings.robots_dir, mapping=load_mapping(path)) as bridge,
    ):
        records = wait_for(
            lambda: (r := ros_records(bus, "rosbot5")) and "/chatter" in r and r, what="/chatter recorded"
        )
        assert records["/chatter"]["fields"] == {"data": "hello fleetbus"}
        chatter = wait_for(
            lambda: (c := bridge.counters.snapshot()["topics"].get("/chatter")) and c["recorded"] and c,
            what="/chatter counted",
        )
        assert chatter["dropped"] == {"not-mapped": 1}
        assert "/chatter" not in bridge.counters.mapped


def received_by_the_bridge(master: RosMaster) -> set[str]:
    """The topics on which the bridge's ROS node has received bytes, by its own statistics (ROS's
    slave API, ``getBusStats``): what its ROS side holds or has sent on."""
    caller = "/fleetbus_test"
    ros = xmlrpc.client.ServerProxy(master.env["ROS_MASTER_URI"])
    _, _, (_, subscribers, _) = ros.getSystemState(caller)
    nodes = {node for _, names in subscribers for node in names if node.startswith("/fleetbus_bridge")}
    received: set[str] = set()
    for node in nodes:
        _, _, uri = ros.lookupNode(caller, node)
        _, _, (_, subscribed, _) = xmlrpc.client.ServerProxy(uri).getBusStats(caller)
        received |= {topic for topic, connections in subscribed if any(c[1] > 0 for c in connections)}
    return received


def test_a_mapped_topics_message_goes_at_once_whatever_the_linger(bus: Bus, ros_master: RosMaster) -> None:
    """The ROS side gathers lines for a linger into one write to the pipe, and the bridge messages
    into one outbox write; a message a mapping rule names ends both at once."""
    robot = bus.robot(bus.add("rosbot4", kind=RobotKind.EXPLORER))
    with (
        bus.worker(),
        ros_peer(ros_master, "samples"),
        running_bridge(robot, ros_master, bus.settings.robots_dir, linger_s=600),
    ):
        wait_for(lambda: bus.count("localisation", "rosbot4"), what="the pose, long before the linger ends")
        wait_for(lambda: bus.count("map", "rosbot4"), what="the grid, long before the linger ends")


def test_a_stopping_bridge_forwards_what_its_ros_side_received(bus: Bus, ros_master: RosMaster) -> None:
    """Stopped in the middle of a linger, nothing already received is lost: the ROS side sends what
    it holds once its input closes, and the bridge puts what it read in the outbox before it ends."""
    robot = bus.robot(bus.add("rosbot5", kind=RobotKind.EXPLORER))
    with bus.worker(), ros_peer(ros_master, "samples"):
        with running_bridge(
            robot, ros_master, bus.settings.robots_dir, mapping=Mapping([]), linger_s=600
        ) as bridge:
            wait_for(
                lambda: SAMPLE_TOPICS <= received_by_the_bridge(ros_master), what="every sample received"
            )
            assert not bridge.counters.recorded, "within the linger, nothing was forwarded yet"
        wait_for(lambda: SAMPLE_TOPICS <= set(ros_records(bus, "rosbot5")), what="every sample stored")
        assert bus.count("ros", "rosbot5") == len(SAMPLE_TOPICS)
