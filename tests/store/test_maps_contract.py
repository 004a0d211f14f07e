"""Map versions on every adapter: staged chunks, committed images read back chunk by chunk."""

from __future__ import annotations

import hashlib
from datetime import datetime, timezone

from fleetbus.workers.store.repositories import Repositories

T0 = datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc)
EPOCH = "20210601T182526564Z-0a1b2c3d"
LATER = "20210601T190000000Z-4e5f6a7b"
META = {
    "resolution": 0.11,
    "origin": [2.1, 3.5, 0.0],
    "occupied_thresh": 0.65,
    "free_thresh": 0.196,
    "negate": 0,
}


async def read_back(store: Repositories, version: int) -> bytes:
    found = await store.maps.map_version(version)
    assert found is not None
    return b"".join([await store.maps.map_chunk(version, i) for i in range(found.chunks)])


async def test_versions_are_kept_and_read_back_exactly(store: Repositories) -> None:
    image = bytes(range(256)) * 40 + b"tail"
    digest = hashlib.sha256(image).hexdigest()
    await store.maps.stage_map_chunk("m-1", 1, image[1000:])
    await store.maps.stage_map_chunk("m-1", 0, image[:1000])
    await store.maps.stage_map_chunk("m-1", 0, b"ignored: already staged")
    staged = await store.maps.staged_map_chunks("m-1")
    assert b"".join(staged[i] for i in sorted(staged)) == image

    first = await store.maps.commit_map("explorer1", EPOCH, 5, image, META, T0, digest, 4096, "m-1")
    assert (first.version, first.size, first.chunks, first.sha256) == (1, len(image), 3, digest)
    assert await store.maps.staged_map_chunks("m-1") == {}
    again = await store.maps.commit_map("explorer1", EPOCH, 5, image, META, T0, digest, 4096, None)
    assert again == first, "the same event commits one version"
    assert await store.maps.committed_map("explorer1", EPOCH, 5) == first
    assert await store.maps.committed_map("explorer1", EPOCH, 6) is None
    assert await store.maps.committed_map("explorer1", LATER, 5) is None, "the same number in another epoch"
    second = await store.maps.commit_map("explorer1", LATER, 5, b"P5 small", META, T0, "0" * 64, 4096, None)
    assert second.version == 2 and (second.epoch, second.seq) == (LATER, 5)
    latest = await store.maps.map_version()
    assert latest == second
    assert await read_back(store, 1) == image
    assert (await store.maps.map_version(1)).metadata == META
    assert await store.maps.map_version(7) is None
