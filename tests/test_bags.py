"""Importing ROS bags (ROS 1, ROS 2 with SQLite3 or MCAP storage) into the recording, without ROS."""

from __future__ import annotations

import asyncio
import base64
import os
import sqlite3
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from fleetbus.schemas.ros import BYTES_KEY, ROS_EXCHANGE, ROS_TYPE, TRUNCATED_KEY, topic_of
from fleetbus.workers.recorder import bag_import
from fleetbus.workers.recorder.bag_import import import_bag
from fleetbus.workers.recorder.ros_fields import nanos_to_datetime
from fleetbus.workers.store import open_recording_store
from fleetbus.workers.store.base import WriteResult
from fleetbus.workers.store.recordings import RecordedMessage, RecordQuery
from fleetbus.workers.store.sqlite_recordings import SQLiteRecordingStore
from tests.ros_bags import FORMATS, Written, storage_file, write_bag
from tests.support import Bus

ROBOT = "bag-explorer"
LIMIT = 1024 * 1024


def bag_path(tmp_path: Path, kind: str) -> Path:
    return tmp_path / ("run.bag" if kind == "ros1" else f"run-{kind}")


def recorded(path: Path, robot: str | None = None) -> list[RecordedMessage]:
    async def go() -> list[RecordedMessage]:
        async with SQLiteRecordingStore(path) as store:
            return await store.find_recorded(RecordQuery(ROS_TYPE, robot_id=robot))

    return asyncio.run(go())


def run_import(
    store_path: Path, bag: Path, max_bytes: int = LIMIT, robot: str = ROBOT
) -> bag_import.ImportReport:
    async def go() -> bag_import.ImportReport:
        async with SQLiteRecordingStore(store_path) as store:
            return await import_bag(store, bag, robot, max_bytes)

    return asyncio.run(go())


def plain_fields(fields: dict[str, Any]) -> dict[str, Any]:
    """The stored fields with a base64 byte array read back as bytes, for comparing."""
    out = {}
    for name, value in fields.items():
        if isinstance(value, dict) and BYTES_KEY in value:
            assert value["length"] == len(base64.b64decode(value[BYTES_KEY]))
            out[name] = base64.b64decode(value[BYTES_KEY])
        else:
            out[name] = value
    return out


def assert_imported(records: Sequence[RecordedMessage], written: Sequence[Written]) -> None:
    assert len(records) == len(written), "every message of the bag, once"
    for record, sent in zip(records, written, strict=True):
        document = record.document
        assert (document["topic"], document["ros_type"]) == (sent.topic, sent.ros_type)
        assert document["log_time_ns"] == sent.log_time_ns, "the bag's log time, to the nanosecond"
        assert record.recorded_at == nanos_to_datetime(sent.log_time_ns)
        expected = dict(sent.fields)
        got = plain_fields(document["fields"])
        assert {k: got[k] for k in expected} == expected
        assert (record.robot_id, record.exchange, record.type) == (ROBOT, ROS_EXCHANGE, ROS_TYPE)
        assert topic_of(record.routing_key) == sent.topic and record.routing_key.startswith(f"{ROBOT}.ros.")
        if "header" in sent.fields:
            stamp = sent.fields["header"]["stamp"]
            assert record.sent_at == nanos_to_datetime(stamp["sec"] * 10**9 + stamp["nanosec"])
        else:
            assert record.sent_at is None


@pytest.mark.parametrize("kind", FORMATS)
def test_every_message_of_a_bag_is_imported_with_its_times(tmp_path: Path, kind: str) -> None:
    bag = bag_path(tmp_path, kind)
    written = write_bag(bag, kind, count=30)
    store = tmp_path / "recording.sqlite3"

    report = run_import(store, bag)

    assert (report.messages, report.stored, report.already) == (30, 30, 0)
    assert_imported(recorded(store), written)


@pytest.mark.parametrize("kind", FORMATS)
def test_importing_a_bag_again_stores_nothing_twice(tmp_path: Path, kind: str) -> None:
    bag = bag_path(tmp_path, kind)
    written = write_bag(bag, kind, count=12)
    store = tmp_path / "recording.sqlite3"
    run_import(store, bag)

    again = run_import(store, bag)

    assert (again.messages, again.stored, again.already) == (12, 0, 12)
    assert_imported(recorded(store), written)
    # the same bag for a second robot (the same run seen by two robots) is that robot's own
    other = run_import(store, bag, robot="bag-other")
    assert (other.messages, other.stored, other.already) == (12, 12, 0)
    assert len(recorded(store, "bag-other")) == 12
    assert (run_import(store, bag, robot="bag-other").stored, run_import(store, bag).stored) == (0, 0)
    assert_imported(recorded(store, ROBOT), written)


def fleetbus(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """The command line on a data directory of its own (the embedded SQLite recording)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("FLEETBUS_")}
    env.update(FLEETBUS_DATA_DIR=str(tmp_path / "data"), COLUMNS="200")
    return subprocess.run(
        [sys.executable, "-m", "fleetbus", *args], env=env, capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize("kind", FORMATS)
def test_a_truncated_bag_is_refused_naming_the_file_and_nothing_is_stored(tmp_path: Path, kind: str) -> None:
    bag = bag_path(tmp_path, kind)
    write_bag(bag, kind, count=60, image_bytes=4000)
    damaged = storage_file(bag)
    damaged.write_bytes(damaged.read_bytes()[: damaged.stat().st_size * 2 // 3])

    result = fleetbus(tmp_path, "import", str(bag), "--robot", ROBOT)

    assert result.returncode == 1, result.stdout
    message = " ".join(result.stderr.split())
    assert str(bag) in message and "nothing was imported" in message
    recording = tmp_path / "data" / "recording.sqlite3"
    assert not recording.exists() or recorded(recording) == []


def test_the_command_imports_and_says_so_when_run_again(tmp_path: Path) -> None:
    bag = bag_path(tmp_path, "ros2-mcap")
    written = write_bag(bag, "ros2-mcap", count=9)

    first = fleetbus(tmp_path, "import", str(bag), "--robot", ROBOT)
    second = fleetbus(tmp_path, "import", str(bag), "--robot", ROBOT)

    assert first.returncode == 0, first.stderr
    assert "imported 9 messages" in " ".join(first.stdout.split())
    assert second.returncode == 0, second.stderr
    assert "all 9 messages" in " ".join(second.stdout.split())
    assert "were in the recording already" in " ".join(second.stdout.split())
    assert_imported(recorded(tmp_path / "data" / "recording.sqlite3"), written)


def test_a_bad_robot_name_or_a_missing_bag_is_an_error(tmp_path: Path) -> None:
    bad_name = fleetbus(tmp_path, "import", str(tmp_path / "none.bag"), "--robot", "Bad.Name")
    missing = fleetbus(tmp_path, "import", str(tmp_path / "none.bag"), "--robot", ROBOT)

    assert bad_name.returncode == 2 and "invalid name" in bad_name.stderr
    assert missing.returncode == 1 and "none.bag: no such file" in " ".join(missing.stderr.split())


class FailingStore(SQLiteRecordingStore):
    """Writes its first batches, then the database is gone."""

    def __init__(self, path: Path, batches: int) -> None:
        super().__init__(path)
        self.batches = batches

    async def write_recorded(self, records: Sequence[RecordedMessage]) -> list[WriteResult]:
        if self.batches == 0:
            raise ConnectionError("the database went away")
        self.batches -= 1
        return await super().write_recorded(records)


def test_a_write_failing_half_way_leaves_nothing_of_that_import(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(bag_import, "BATCH", 5)
    store = tmp_path / "recording.sqlite3"
    earlier = tmp_path / "earlier.bag"
    kept = write_bag(earlier, "ros1", count=4)
    run_import(store, earlier)
    bag = bag_path(tmp_path, "ros2-sqlite3")
    write_bag(bag, "ros2-sqlite3", count=20)

    async def go() -> None:
        async with FailingStore(store, batches=2) as failing:
            await import_bag(failing, bag, ROBOT, LIMIT)

    with pytest.raises(ConnectionError):
        asyncio.run(go())

    assert_imported(recorded(store), kept)  # the earlier bag's messages, and nothing of this one


def test_byte_arrays_over_the_size_limit_are_described_not_kept(tmp_path: Path) -> None:
    bag = bag_path(tmp_path, "ros2-mcap")
    write_bag(bag, "ros2-mcap", count=3, image_bytes=6000)
    store = tmp_path / "recording.sqlite3"

    report = run_import(store, bag, max_bytes=4000)

    assert report.trimmed == 1
    image = next(r for r in recorded(store) if r.document["ros_type"] == "sensor_msgs/msg/Image")
    data = image.document["fields"]["data"]
    assert data[TRUNCATED_KEY] is True and data["length"] == 6000 and len(data["sha256"]) == 64
    assert image.document["fields"]["width"] == 6000, "the rest of the message is kept"
    assert "size limit" in (image.problem or "")


async def test_a_bag_is_imported_alike_into_either_store(stored_bus: Bus, tmp_path: Path) -> None:
    """SQLite and MongoDB hold the same records: the byte arrays' keys are ones MongoDB stores as they are."""
    bag = bag_path(tmp_path, "ros2-sqlite3")
    written = write_bag(bag, "ros2-sqlite3", count=12)
    async with open_recording_store(stored_bus.settings) as store:
        first = await import_bag(store, bag, ROBOT, LIMIT)
        again = await import_bag(store, bag, ROBOT, LIMIT)
        records = await store.find_recorded(RecordQuery(ROS_TYPE))

    assert (first.stored, again.stored, again.already) == (12, 0, 12)
    assert all(r.raw is None and r.problem is None for r in records), "kept as documents"
    assert_imported(records, written)


def test_a_ros2_bag_without_message_definitions_is_read_with_the_standard_types(tmp_path: Path) -> None:
    """Bags recorded before ROS 2 Iron carry no definitions of their types."""
    bag = bag_path(tmp_path, "ros2-sqlite3")
    written = write_bag(bag, "ros2-sqlite3", count=6)
    with sqlite3.connect(storage_file(bag)) as db:
        db.execute("DELETE FROM message_definitions")
    store = tmp_path / "recording.sqlite3"

    report = run_import(store, bag)

    assert report.stored == 6
    assert_imported(recorded(store), written)


def test_a_large_image_is_kept_whole_in_the_blob_store_and_exported_byte_for_byte(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    bag = bag_path(tmp_path, "ros1")
    frame = 640 * 480 * 3  # a 640x480 rgb8 camera image: over the 1 MiB limit once in JSON
    written = write_bag(bag, "ros1", count=3, image_bytes=frame)
    imported = fleetbus(tmp_path, "import", str(bag), "--robot", ROBOT)
    assert imported.returncode == 0, imported.stderr
    assert "described" not in imported.stdout, "nothing trimmed"
    [image] = [r for r in recorded(tmp_path / "data" / "recording.sqlite3") if "image" in r.document["topic"]]
    kept = image.document["fields"]["data"]
    assert kept["length"] == frame and set(kept) == {"_blob", "length"}
    blob = tmp_path / "data" / "recording.sqlite3.blobs" / kept["_blob"][:2] / kept["_blob"]
    assert blob.read_bytes() == written[2].fields["data"], "in the blob store, whole"

    out = tmp_path / "out.bag"
    exported = fleetbus(tmp_path, "export", "--bag", str(out))
    assert exported.returncode == 0, exported.stderr

    def images(path: Path) -> list[bytes]:
        with AnyReader([path]) as reader:
            return [raw for c, _, raw in reader.messages() if c.topic.endswith("image_raw")]

    assert images(out) == images(bag), "the image, byte for byte"


def test_a_robots_ros_1_and_ros_2_imports_of_one_topic_export_to_one_bag_connection(tmp_path: Path) -> None:
    """Two imports of one type on one topic (a ROS 1 bag and a ROS 2 bag) are two kept definitions;
    where their ROS 1 forms are the same (``std_msgs/String``), the exported bag has one connection
    for the topic (a ROS 2 header has no ``seq``: a stamped type's two forms are two connections)."""
    from rosbags.rosbag1 import Reader

    write_bag(tmp_path / "run.bag", "ros1", count=6)
    write_bag(tmp_path / "run2", "ros2-mcap", count=6, start_ns=2_000_000_000_000_000_000)
    for bag in ("run.bag", "run2"):
        imported = fleetbus(tmp_path, "import", str(tmp_path / bag), "--robot", "explorer1")
        assert imported.returncode == 0, imported.stderr
    out = tmp_path / "out.bag"
    exported = fleetbus(tmp_path, "export", "--bag", str(out), "--robot", "explorer1")
    assert exported.returncode == 0, exported.stderr
    with Reader(out) as reader:
        topics = [connection.topic for connection in reader.connections]
        assert set(topics) == {"/explorer1/camera/image_raw", "/explorer1/chatter", "/explorer1/robot/pose"}
        assert topics.count("/explorer1/chatter") == 1
        assert reader.message_count == 12
