"""Import a ROS bag into the recording: all of its messages or none.

Two passes over the bag. The first reads and converts every message and stores nothing, so a
truncated or corrupt bag is refused before anything is written. The second writes the messages
in batches, each under a key made of the robot, the bag's content digest and the message's
position (:func:`fleetbus.schemas.ros.ros_record_key`): importing the same bag again for the same
robot stores nothing new, and the same bag imported for another robot is that robot's own run.
Should a write fail half-way (the database gone), the messages this import added are deleted
again before the error is raised.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.ros import ROS_TYPE, ros_record_key
from fleetbus.workers.recorder.bags import BagMessage, bag_digest, message_count, read_bag
from fleetbus.workers.recorder.ros_native import schema_record
from fleetbus.workers.recorder.ros_records import ros_record
from fleetbus.workers.recorder.ros_tf import transform_records
from fleetbus.workers.store.recordings import RecordedMessage, RecordingStore

BATCH = 500
"""Messages written at once."""
IMPORT_APP_ID = "fleetbus-import"

Progress = Callable[[str, int, int], None]
"""``(phase, done, total)``: phase ``check`` (reading the bag) then ``store``."""


@dataclass(frozen=True)
class ImportReport:
    path: str
    digest: str
    messages: int
    stored: int
    """New records; ``messages - stored`` were in the recording already (imported before)."""
    trimmed: int
    """Messages whose large arrays were described instead of kept (over the size limit)."""

    @property
    def already(self) -> int:
        return self.messages - self.stored


def record_source(robot: str, digest: str) -> str:
    """What a bag's record keys are made of (with each message's index): the robot and the bag."""
    return f"{robot}\0{digest}"


def bag_record(robot: str, digest: str, bag_file: str, item: BagMessage) -> RecordedMessage:
    """The record of one bag message: keyed by its robot, its bag and its index."""
    return ros_record(
        robot,
        item.message,
        ros_record_key(record_source(robot, digest), item.index),
        size=item.size,
        seq=item.index,
        trimmed=item.trimmed,
        properties={
            "app_id": IMPORT_APP_ID,
            "headers": {"x-ros-bag": bag_file, "x-ros-bag-sha256": digest, "x-ros-bag-index": item.index},
        },
    )


async def import_bag(
    store: RecordingStore,
    path: Path,
    robot: str,
    max_bytes: int,
    progress: Progress = lambda phase, done, total: None,
    blob_max: int = 0,
) -> ImportReport:
    """Store every message of the bag at ``path`` as ``robot``'s, or none (raising why); byte
    arrays over 64 KiB and up to ``blob_max`` bytes (0: none) whole, in the blob store."""
    validate_name(robot)
    total = message_count(path)
    digest = bag_digest(path)
    trimmed = 0
    for item in read_bag(path, max_bytes, blob_max):  # all readable before anything is stored
        trimmed += item.trimmed
        progress("check", item.index + 1, total)
    added: list[tuple[str, str]] = []  # (type, key) of each record this import stored
    batch: list[RecordedMessage] = []
    written = 0
    schemas: set[str] = set()
    blobs_added: list[str] = []
    try:
        for item in read_bag(path, max_bytes, blob_max):
            for name, data in item.blobs.items():
                if await store.put_blob(name, data):
                    blobs_added.append(name)
            record = bag_record(robot, digest, path.name, item)
            if item.schema is not None and item.schema.key not in schemas:
                schemas.add(item.schema.key)  # stored before the first message that names it
                batch.append(schema_record(item.schema, robot, item.message.topic, record.recorded_at))
            batch += [record, *transform_records(record)]
            if len(batch) >= BATCH:
                written += await _write(store, batch, added)
                progress("store", written, total)
        written += await _write(store, batch, added)
        progress("store", written, total)
    except BaseException:
        for type in {type for type, _ in added}:
            await store.delete_recorded(type, [key for kind, key in added if kind == type])
        if blobs_added:
            await store.delete_blobs(blobs_added)
        raise
    stored = sum(type == ROS_TYPE for type, _ in added)
    return ImportReport(str(path), digest, written, stored, trimmed)


async def _write(store: RecordingStore, batch: list[RecordedMessage], added: list[tuple[str, str]]) -> int:
    """Write the batch; how many messages it held (their transforms not counted)."""
    results = await store.write_recorded(batch)
    added.extend((r.type, r.key) for r, result in zip(batch, results, strict=True) if result.inserted)
    count = sum(record.type == ROS_TYPE for record in batch)
    batch.clear()
    return count
