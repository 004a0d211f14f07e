"""``fleetbus export --mcap``: the recording, read back from the MCAP file with ``mcap``'s reader."""

from __future__ import annotations

import asyncio
import base64
import json
import tracemalloc
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from io import BytesIO
from pathlib import Path
from typing import Any

import jsonschema
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from fleetbus.schemas.routing import EventType, RobotKind
from fleetbus.workers.recorder.bag_import import import_bag
from fleetbus.workers.recorder.mcap_export import export_mcap, nanos
from fleetbus.workers.recorder.queries import recorded_between
from fleetbus.workers.recorder.ros_fields import plain
from fleetbus.workers.store import open_recording_store
from fleetbus.workers.store.recordings import RecordedMessage
from tests.factories import hazard, small_map, status
from tests.ros_bags import write_bag
from tests.support import Bus, wait_for
from tests.test_cli import fleetbus

FOXGLOVE = {"foxglove.Grid", "foxglove.PoseInFrame", "foxglove.SceneUpdate"}


def read_mcap(path: Path) -> list[tuple[Any, Any, Any]]:
    with path.open("rb") as stream:
        return list(make_reader(stream).iter_messages(log_time_order=False))


def whole_recording(bus: Bus) -> list[RecordedMessage]:
    async def go() -> list[RecordedMessage]:
        async with open_recording_store(bus.settings) as store:
            return [record async for record in recorded_between(store, None, None)]

    return asyncio.run(go())


def assert_valid(schema: Any, data: bytes) -> Any:
    """The message is JSON that its channel's schema (a valid JSON Schema) accepts."""
    assert schema.encoding == "jsonschema"
    assert b"$ref" not in schema.data, "self-contained: no reference to resolve"
    document = json.loads(schema.data)
    jsonschema.Draft202012Validator.check_schema(document)
    message = json.loads(data)
    jsonschema.validate(message, document)
    return message


def ros1_fields(schema: Any, data: bytes) -> Any:
    """A ROS 1 message read with the definition its channel's schema carries (``rosbags``)."""
    store = get_typestore(Stores.EMPTY)
    name = schema.name.replace("/", "/msg/", 1)
    store.register(get_types_from_msg(schema.data.decode(), name))
    return plain(store.deserialize_ros1(data, name))


def test_recorded_and_imported_messages_round_trip_through_mcap(bus: Bus, tmp_path: Path) -> None:
    explorer = bus.add("mcap-explorer", kind=RobotKind.EXPLORER)
    warden = bus.add("mcap-warden", kind=RobotKind.WARDEN)
    with bus.worker(), bus.recorder(), bus.robot(explorer) as robot, bus.robot(warden) as guard:
        guard.publish(EventType.LOCALISATION, {"localised": True, "pose": {"x": 1.0, "y": 2.0}})
        robot.publish(EventType.MAP, small_map())
        for i in range(4):
            robot.publish(EventType.HAZARD, hazard(i, description=f"fire {i}"))
            robot.publish(EventType.STATUS, status(80.0 - i))
        wait_for(
            lambda: (
                len(bus.recorded("hazard")) == 4
                and len(bus.recorded("status")) == 4
                and bus.recorded("map")
                and bus.recorded("localisation")
            ),
            what="the robots' events recorded",
        )
    bag = tmp_path / "drive.bag"
    write_bag(bag, "ros1", count=9)

    async def load() -> None:
        async with open_recording_store(bus.settings) as store:
            await import_bag(store, bag, "mcap-explorer", bus.settings.max_message_bytes)

    asyncio.run(load())
    expected = whole_recording(bus)
    out = tmp_path / "run.mcap"

    result = fleetbus(bus, "export", "--mcap", str(out))

    assert result.returncode == 0, result.stderr
    messages = read_mcap(out)
    own = [(s, c, m) for s, c, m in messages if s.name not in FOXGLOVE]
    assert len(own) == len(expected), "every recorded message, once"
    for (schema, channel, message), record in zip(own, expected, strict=True):
        if record.type == "ros":
            assert channel.topic == f"/mcap-explorer{record.document['topic']}", "per robot and topic"
            assert schema.name == record.document["ros_type"].replace("/msg/", "/")
            assert (schema.encoding, channel.message_encoding) == ("ros1msg", "ros1"), "native"
            assert message.log_time == record.document["log_time_ns"], "the bag's time, to the nanosecond"
            assert ros1_fields(schema, message.data) == record.document["fields"]
        else:
            data = assert_valid(schema, message.data)
            assert channel.topic == f"/{record.robot_id or 'fleetbus'}/{record.type}"
            assert schema.name == f"fleetbus.{record.type}"
            assert message.log_time == nanos(record.recorded_at)
            assert data == record.document
        assert message.publish_time == (nanos(record.sent_at) if record.sent_at else message.log_time)
    assert [m.log_time for _, _, m in own] == sorted(m.log_time for _, _, m in own), "in order"

    views: dict[str, list[Any]] = {}
    for schema, channel, message in messages:
        if schema.name in FOXGLOVE:
            views.setdefault(channel.topic, []).append(assert_valid(schema, message.data))
    assert sorted(views) == [
        "/mcap-explorer/hazards",
        "/mcap-explorer/map/grid",
        "/mcap-explorer/status/pose",
        "/mcap-warden/localisation/pose",
    ]
    labels = [e["texts"][0]["text"] for update in views["/mcap-explorer/hazards"] for e in update["entities"]]
    assert labels == [f"fire {i}" for i in range(4)]
    [grid] = views["/mcap-explorer/map/grid"]
    assert grid["column_count"] == 64 and grid["cell_size"] == {"x": 0.11, "y": 0.11}
    assert len(base64.b64decode(grid["data"])) == 64 * 48
    assert views["/mcap-warden/localisation/pose"][0]["pose"]["position"] == {"x": 1.0, "y": 2.0, "z": 0.0}

    only = tmp_path / "hazards.mcap"
    chosen = fleetbus(bus, "export", "--mcap", str(only), "--type", "hazard", "--robot", "mcap-explorer")
    assert chosen.returncode == 0, chosen.stderr
    topics = {c.topic for _, c, _ in read_mcap(only)}
    assert topics == {"/mcap-explorer/hazard", "/mcap-explorer/hazards"}
    refused = fleetbus(bus, "export", "--mcap", str(only))
    assert refused.returncode == 2 and "exists" in refused.stderr


def records(count: int) -> Iterator[RecordedMessage]:
    """``count`` status records, made one at a time."""
    start = datetime(2026, 1, 1, tzinfo=timezone.utc)
    for i in range(count):
        at = start + timedelta(milliseconds=i)
        document = {"type": "status", "seq": i, "body": status(50.0), "padding": "x" * 200}
        yield RecordedMessage(
            key=f"k{i:08d}",
            type="status",
            recorded_at=at,
            exchange="r.events",
            routing_key="r.status",
            user_id="r",
            robot_id="r",
            document=document,
        )


def test_export_is_streamed_its_memory_does_not_grow_with_the_window() -> None:
    class Sink(BytesIO):
        """Counts what is written and keeps none of it."""

        def write(self, data: Any) -> int:
            return len(data)

    small, large = 3_000, 15_000
    tracemalloc.start()
    try:
        export_mcap(records(small), Sink())
        small_peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        export_mcap(records(large), Sink())
        large_peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # five times the messages (about 4 MB of JSON against 0.8 MB): the peak stays that of a chunk
    assert large_peak < small_peak * 1.5, (small_peak, large_peak)
