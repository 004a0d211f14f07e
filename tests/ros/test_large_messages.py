"""Large ROS messages (camera images, point clouds) recorded live, whole up to the bound: through the
real bridge, in ``ros_chunk`` pieces through the broker, put together by the recorder in the blob
store, and back whole from ``fleetbus export`` as Foxglove's reader and rosbag read them."""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import subprocess
from datetime import timedelta
from pathlib import Path
from typing import Any

import psutil

from fleetbus.publishers.outbox import policies_with_limits
from fleetbus.publishers.ros.bridge import chunk_events
from fleetbus.publishers.ros.convert import byte_array
from fleetbus.schemas.bodies import CHUNK_BYTES
from fleetbus.schemas.envelope import validate_body
from fleetbus.schemas.ros import BLOB_KEY, TRUNCATED_KEY, to_blobs, with_raw
from fleetbus.schemas.routing import EventType, RobotKind
from fleetbus.workers.recorder.ros_blobs import piece_name
from fleetbus.workers.store import open_recording_store
from fleetbus.workers.store.base import EventQuery
from fleetbus.workers.store.recordings import RecordedMessage
from tests.factories import status
from tests.link import NetworkLink
from tests.ros.conftest import ROS_PYTHON, RosMaster, ros_peer, running_bridge
from tests.ros.test_foxglove_export import foxglove_read
from tests.support import Bus, network_link, read_line, wait_for
from tests.test_cli import fleetbus

IMAGES, CLOUDS, HUGE = "/camera/image_raw", "/points", "/camera/huge"
#: The bound of the test's bridge: a 640x480 image and a 1 MiB cloud are under it, 1280x720 over.
BOUND = 2 * 1024 * 1024
READ_BAG = """
import hashlib, json, sys, rosbag
for topic, msg, at in rosbag.Bag(sys.argv[1]).read_messages():
    print(json.dumps([topic, hashlib.sha256(msg.data).hexdigest()]))
"""


def blobs(bus: Bus, names: list[str]) -> dict[str, bytes | None]:
    async def go() -> dict[str, bytes | None]:
        async with open_recording_store(bus.settings) as store:
            return {name: await store.get_blob(name) for name in names}

    return asyncio.run(go())


def data_of(record: RecordedMessage) -> dict[str, Any]:
    data: dict[str, Any] = record.document["fields"]["data"]
    return data


def published(node: subprocess.Popen[str]) -> list[dict[str, Any]]:
    """What the sensors peer printed of each message it published, until it says it is done."""
    sent: list[dict[str, Any]] = json.loads(read_line(node, '{"sent"', 60))["sent"]
    return sent


def test_images_and_point_clouds_are_recorded_whole_and_export_whole(
    bus: Bus, ros_master: RosMaster, tmp_path: Path
) -> None:
    robot = bus.robot(bus.add("camrobot", kind=RobotKind.EXPLORER))
    with (
        bus.worker(),
        bus.recorder(),
        running_bridge(robot, ros_master, bus.settings.robots_dir, blob_max=BOUND) as bridge,
        ros_peer(ros_master, "sensors", "4", "4") as sensors,
    ):
        sent = published(sensors)
        records = wait_for(
            lambda: len(r := bus.recorded("ros", robot_id="camrobot")) == len(sent) and r,
            timeout=60,
            what="every image and cloud recorded",
        )
        wait_for(lambda: bridge.counters.over_bound[HUGE] == 1, what="the huge image counted")
        # the event log keeps each piece (2 of each image, 2 of each cloud) without its bytes
        wait_for(lambda: bus.count("ros_chunk", "camrobot") == 16, what="the chunks in the event log")
        [chunk] = bus.find(EventQuery(type="ros_chunk", robot_id="camrobot", limit=1))
        assert "data" not in chunk.body and chunk.body["size"] == CHUNK_BYTES
        bridge.report()
        status = json.loads(bridge.status_file.read_text())
    assert len(sent) == 9
    # rospy numbers the headers itself: a message is known by its data's SHA-256
    by_key = {(r.document["topic"], data_of(r).get(BLOB_KEY) or data_of(r)["sha256"]): r for r in records}
    assert len(by_key) == len(records), "each message recorded once"
    whole = [line for line in sent if line["topic"] != HUGE]
    for line in whole:
        data = data_of(by_key[line["topic"], line["sha256"]])
        assert data == {BLOB_KEY: line["sha256"], "length": line["length"]}, line
    kept = blobs(bus, [line["sha256"] for line in whole])
    for line in whole:
        assert hashlib.sha256(kept[line["sha256"]] or b"").hexdigest() == line["sha256"], "the bytes kept"
    assert {line["length"] for line in whole} == {640 * 480 * 3, 65_536 * 16}
    assert not any(blobs(bus, [piece_name(line["sha256"], 0) for line in whole]).values())

    # over the bound: described, counted in the record and in ros status
    [huge] = [line for line in sent if line["topic"] == HUGE]
    huge_record = by_key[HUGE, huge["sha256"]]
    assert data_of(huge_record) == {TRUNCATED_KEY: True, "length": huge["length"], "sha256": huge["sha256"]}
    assert "FLEETBUS_ROS_BLOB_MAX_BYTES" in (huge_record.problem or "")
    assert status["topics"][HUGE]["over_bound"] == 1
    assert status["topics"][IMAGES]["blobs"] == 4 and status["topics"][CLOUDS]["blobs"] == 4

    # back whole: Foxglove's reader decodes the MCAP file's images and clouds...
    mcap = tmp_path / "sensors.mcap"
    exported = fleetbus(bus, "export", "--mcap", str(mcap), "--robot", "camrobot")
    assert exported.returncode == 0, exported.stderr
    assert "1" in exported.stderr and "left out" in exported.stderr, exported.stderr  # the huge one
    decoded = {
        (line["topic"], hashlib.sha256(base64.b64decode(line["message"]["data"]["base64"])).hexdigest()): line
        for line in foxglove_read(mcap)
        if line["kind"] == "message" and line["encoding"] == "ros1"
    }
    assert set(decoded) == {(f"/camrobot{line['topic']}", line["sha256"]) for line in whole}
    widths = {line["message"]["width"] for (topic, _), line in decoded.items() if topic.endswith(IMAGES)}
    assert widths == {640}
    assert all(line["message"]["point_step"] == 16 for (t, _), line in decoded.items() if t.endswith(CLOUDS))

    # ...and rosbag reads them from the bag
    bag = tmp_path / "sensors.bag"
    exported = fleetbus(bus, "export", "--bag", str(bag), "--robot", "camrobot")
    assert exported.returncode == 0, exported.stderr
    read = subprocess.run([ROS_PYTHON, "-c", READ_BAG, str(bag)], capture_output=True, text=True)
    assert read.returncode == 0, read.stderr
    in_bag = sorted(json.loads(line) for line in read.stdout.splitlines())
    assert in_bag == sorted([f"/camrobot{line['topic']}", line["sha256"]] for line in whole)


def ros_message(topic: str, seq: int, data: bytes) -> tuple[list[Any], str]:
    """The events the bridge sends for a message whose ``data`` is large, and its SHA-256."""
    named: dict[str, bytes] = {}
    array = {"_base64": base64.b64encode(data).decode(), "length": len(data)}
    fields = to_blobs({"header": {"seq": seq}, "data": array}, named, BOUND)
    body = {"topic": topic, "ros_type": "sensor_msgs/msg/Image", "log_time_ns": 10**18 + seq}
    body["fields"] = fields
    events = [*chunk_events(named), (EventType.ROS, validate_body(EventType.ROS, body))]
    return events, hashlib.sha256(data).hexdigest()


def test_a_recorder_killed_amid_the_pieces_loses_and_doubles_nothing(bus: Bus) -> None:
    """Pieces sent again, a recorder killed with pieces kept but no record yet, and a message whose
    pieces never all arrived: each message recorded once, whole or said missing, never half.
    (``stored_bus`` instead of ``bus`` runs it on MongoDB's GridFS too: 25 s more, beyond the
    suite's budget for these tests.)"""
    robot = bus.robot(bus.add("killcam", kind=RobotKind.EXPLORER))
    first, first_sha = ros_message("/camera/image_raw", 0, bytes(range(256)) * 4000)  # 2 pieces
    second, second_sha = ros_message("/camera/image_raw", 1, b"\x01" * (CHUNK_BYTES * 2 + 5))  # 3
    lost, lost_sha = ros_message("/camera/image_raw", 2, b"\x02" * (CHUNK_BYTES + 7))  # 2
    worker = bus.spawn_worker()
    try:
        wait_for(lambda: len(psutil.Process(worker.pid).children()) == 1, timeout=30, what="the recorder")
        [recorder] = psutil.Process(worker.pid).children()
        robot.publish_many(first[:1], wait=True)  # half of the first message's pieces
        piece = piece_name(first_sha, 0)
        wait_for(lambda: blobs(bus, [piece])[piece], what="a piece kept")
        recorder.kill()  # mid-way: a piece kept, no record
        recorder.wait(30)
        wait_for(lambda: psutil.Process(worker.pid).children() not in ([], [recorder]), what="a new recorder")
        # the same piece again (a resend), the rest, a second message, and one missing a piece
        robot.publish_many([*first[:1], *first[1:], *second, lost[0], lost[-1]], wait=True)
        records = wait_for(
            lambda: len(r := bus.recorded("ros", robot_id="killcam")) == 3 and r, timeout=60, what="3 records"
        )
    finally:
        worker.kill()
        worker.wait(30)
    by_seq = {r.document["fields"]["header"]["seq"]: r for r in records}
    assert data_of(by_seq[0])[BLOB_KEY] == first_sha and data_of(by_seq[1])[BLOB_KEY] == second_sha
    kept = blobs(bus, [first_sha, second_sha, lost_sha])
    assert hashlib.sha256(kept[first_sha] or b"").hexdigest() == first_sha
    assert hashlib.sha256(kept[second_sha] or b"").hexdigest() == second_sha
    assert kept[lost_sha] is None, "a half-received blob is never kept as whole"
    said = data_of(by_seq[2])
    assert said[TRUNCATED_KEY] is True and said["sha256"] == lost_sha
    assert "1 of its 2 pieces" in said["missing"]
    assert "1 of its 2 pieces did not arrive" in (by_seq[2].problem or "")
    pieces = [piece_name(first_sha, i) for i in range(2)] + [piece_name(second_sha, i) for i in range(3)]
    assert not any(blobs(bus, pieces).values()), "the pieces of the blobs made are gone"
    chunks = bus.recorded("ros_chunk", robot_id="killcam")
    assert len(chunks) == 1 + 1 + 1 + 3 + 1, "every chunk event on the bus recorded once"
    assert all(c.document["body"]["data"] is None for c in chunks), "a chunk's bytes are kept once"


def test_pieces_whose_message_never_comes_are_swept_and_counted(bus: Bus) -> None:
    """A bridge killed mid-message: the pieces it sent wait for a record that never comes. The
    recorder removes them once older than FLEETBUS_ROS_PIECES_TTL and counts them where
    `fleetbus stats` shows them; a whole message's blob stays."""
    robot = bus.robot(bus.add("sweepcam", kind=RobotKind.EXPLORER))
    whole, whole_sha = ros_message("/camera/image_raw", 0, b"\x03" * (CHUNK_BYTES + 9))  # 2 pieces
    cut, cut_sha = ros_message("/camera/image_raw", 1, b"\x04" * (CHUNK_BYTES * 2 + 1))  # 3 pieces
    with bus.recorder(ros_pieces_ttl=timedelta(seconds=1), retention_interval=0.2) as recorder:
        robot.publish_many([*whole, *cut[:2]], wait=True)  # the bridge killed after 2 of its 3 pieces
        wait_for(lambda: recorder.stats().pieces_swept >= 2, what="the two pieces swept")
        assert bus.recorded("ros", robot_id="sweepcam")[0].document["fields"]["data"][BLOB_KEY] == whole_sha
        # the sentinel: a piece kept after that sweep is swept by a later one (the recorder's one
        # loop sweeps in turn), once older than the TTL; a piece swept or counted again comes first
        sentinel, sentinel_sha = ros_message("/camera/image_raw", 2, b"\x05" * (CHUNK_BYTES + 3))
        robot.publish_many([*sentinel[:1], ("status", status(50))], wait=True)
        # recorded in order: once the status is, the piece before it was kept
        wait_for(lambda: bus.recorded("status", robot_id="sweepcam"), what="the sentinel piece kept")
        piece = piece_name(sentinel_sha, 0)
        wait_for(lambda: not blobs(bus, [piece])[piece], what="the sentinel piece swept")
        wait_for(lambda: recorder.stats().pieces_swept >= 3, what="the sentinel piece counted")
    assert recorder.stats().pieces_swept == 3, "only the pieces no message named, and the sentinel"
    assert not any(blobs(bus, [piece_name(cut_sha, i) for i in range(3)]).values())
    assert blobs(bus, [whole_sha])[whole_sha] == b"\x03" * (CHUNK_BYTES + 9)
    stats = fleetbus(bus, "stats", "--json")
    assert stats.returncode == 0, stats.stderr
    rows = [json.loads(line) for line in stats.stdout.splitlines()]
    swept = [(r["subject"], r["count"]) for r in rows if r.get("bound") == "ros-pieces"]
    assert swept == [("sweepcam", 3)]


def test_a_full_outbox_drops_the_large_messages_and_lets_the_small_ones_through(
    bus: Bus, ros_master: RosMaster, link_for: list[NetworkLink]
) -> None:
    """The broker away, an outbox that holds one chunk: images and clouds are dropped and counted
    (``outbox-full``), the small message of the same moments still goes into the outbox."""
    account = bus.add("fullcam", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
    robot = bus.robot(account, via=link, outbox_policies=policies_with_limits("ros_chunk=1"))
    link.cut()
    with (
        running_bridge(robot, ros_master, bus.settings.robots_dir, blob_max=BOUND) as bridge,
        ros_peer(ros_master, "sensors", "1", "10") as sensors,
    ):
        published(sensors)
        wait_for(
            lambda: (
                bridge.counters.recorded[HUGE] == 1
                and all(bridge.counters.dropped.get(t, {}).get("outbox-full") == 1 for t in (IMAGES, CLOUDS))
            ),
            what="the image and the cloud dropped, the described image kept",
        )
        assert robot.outbox.pending() == 1, "the described image waits; no chunk does"
        assert bridge.counters.recorded[IMAGES] == 0 and bridge.counters.recorded[CLOUDS] == 0
        bridge.report()  # `fleetbus ros status` shows what waits in the outbox, by type
        outbox = json.loads(bridge.status_file.read_text())["broker"]["outbox"]
        assert (sum(outbox["waiting"].values()), outbox["dropped"], outbox["refused"]) == (1, {}, {})
        link.restore()  # the bridge stops at once (its notifications wait for the broker)


def test_an_array_sent_beside_its_line_becomes_a_blob_and_a_mapping_reads_it() -> None:
    """The ROS side sends a large byte array after its message's line, as it is: the bridge keeps
    it as a blob, and a mapped message (an occupancy grid past 64 KiB) reads it as bytes."""
    data = bytes(range(256)) * 400
    fields = with_raw({"info": {"width": 320}, "data": {"_raw": 0, "length": len(data)}}, [data])
    assert byte_array(fields["data"]) == data
    named: dict[str, bytes] = {}
    digest = hashlib.sha256(data).hexdigest()
    assert to_blobs(fields, named, BOUND) == {
        "info": {"width": 320},
        "data": {BLOB_KEY: digest, "length": len(data)},
    }
    assert named == {digest: data}
