"""The recording's blob store (an image's pixels, kept apart from the documents by the SHA-256 of
their bytes), on SQLite (files beside the database) and MongoDB (GridFS): the same answers."""

from __future__ import annotations

import hashlib

import pytest

from fleetbus.workers.store.recordings import RecordingError, RecordingStore


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
