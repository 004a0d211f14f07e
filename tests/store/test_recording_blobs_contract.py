"""The recording's blob store (an image's pixels, kept apart from the documents by the SHA-256 of
their bytes), on SQLite (files beside the database) and MongoDB (GridFS): the same answers."""

from __future__ import annotations

import hashlib
from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.limits import Retention
from fleetbus.schemas.ros import BLOB_KEY, ROS_TYPE
from fleetbus.workers.recorder.retention import RetentionSweeper
from fleetbus.workers.store.recordings import RecordedMessage, RecordingError, RecordingStore

T0 = datetime(2021, 6, 1, 18, 25, 26, tzinfo=timezone.utc)


async def test_a_blob_is_kept_once_by_its_digest_and_can_be_deleted(recording: RecordingStore) -> None:
    image = bytes(range(256)) * 4096  # 1 MiB: more than one GridFS chunk
    digest = hashlib.sha256(image).hexdigest()
    assert await recording.get_blob(digest) is None
    assert await recording.put_blob(digest, image) is True
    assert await recording.put_blob(digest, image) is False, "the same bytes are kept once"
    assert await recording.get_blob(digest) == image
    empty = hashlib.sha256(b"").hexdigest()
    assert await recording.put_blob(empty, b"") is True and await recording.get_blob(empty) == b""
    assert await recording.delete_blobs([digest, "0" * 64]) == 1, "how many were kept"
    assert await recording.get_blob(digest) is None and await recording.get_blob(empty) == b""
    with pytest.raises(RecordingError, match="invalid blob name"):
        await recording.get_blob("../../etc/passwd")


def image(seed: int) -> tuple[str, bytes]:
    data = hashlib.sha256(str(seed).encode()).digest() * 8192  # 256 KiB
    return hashlib.sha256(data).hexdigest(), data


def ros(key: str, at: float, *digests: str) -> RecordedMessage:
    """A ``ros`` record naming its images' blobs as the recorder writes it."""
    fields = {"images": [{BLOB_KEY: digest, "length": 262144} for digest in digests]}
    return RecordedMessage(
        key=key,
        type=ROS_TYPE,
        recorded_at=T0 + timedelta(seconds=at),
        exchange="herb.events",
        routing_key="herb.ros.camera",
        user_id="herb",
        robot_id="herb",
        document={"topic": "/camera", "fields": fields},
        size=100,
    )


async def test_retention_deletes_the_blobs_no_record_kept_names(recording: RecordingStore) -> None:
    (a, _), (b, image_b), (c, _) = image(1), image(2), image(3)
    empty = await recording.database_bytes()
    for digest, data in (image(1), image(2), image(3)):
        await recording.put_blob(digest, data)
    assert await recording.database_bytes() >= empty + 3 * 262144, "the blobs are counted in the size"
    # the same bytes are kept once: ``b`` is named by an old record and a newer one
    await recording.write_recorded([ros("r0", 0, a, b), ros("r1", 1, c), ros("r2", 2, b), ros("r3", 3)])

    assert await RetentionSweeper(recording, {"*": Retention(max_records=3)}).sweep(T0) == {"ros": 1}
    assert await recording.get_blob(a) is None, "retention deletes what only the deleted record named"
    assert await recording.get_blob(b) == image_b, "and keeps what a record kept still names"
    assert await recording.delete_recorded_before(ROS_TYPE, T0 + timedelta(seconds=2.5)) == 2
    assert await recording.get_blob(b) is None and await recording.get_blob(c) is None
    assert await recording.database_bytes() < empty + 262144, "their bytes are no longer counted"


async def test_a_message_recorded_again_later_keeps_its_blob_until_its_record_goes(
    recording: RecordingStore,
) -> None:
    """The recorder noted a message's blobs, then died before its record was written; the message
    came again an hour later and was recorded then. Retention by age must go by that time."""
    digest, data = image(1)
    await recording.put_blob(digest, data)
    await recording.bookkeeping.blobs_referenced([ros("r0", 0, digest)])  # the record never written
    await recording.write_recorded([ros("r0", 3600, digest)])  # the message again
    assert await recording.delete_recorded_before(ROS_TYPE, T0 + timedelta(seconds=60)) == 0
    assert await recording.get_blob(digest) == data, "its record is kept: so is its blob"
    assert await recording.delete_recorded_before(ROS_TYPE, T0 + timedelta(seconds=3601)) == 1
    assert await recording.get_blob(digest) is None
