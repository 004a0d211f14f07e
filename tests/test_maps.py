"""Map transfer against the real broker: Table 2 byte for byte, a 16 MB map, bad maps refused."""

from __future__ import annotations

import base64
import hashlib
import json
import subprocess
import sys
import uuid

import pika
import yaml

from fleetbus.publishers.maps import map_events
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.bodies import MAP_CHUNK_BYTES
from fleetbus.schemas.envelope import new_epoch
from fleetbus.schemas.routing import RobotKind
from tests.factories import small_map
from tests.support import Bus, notifications_until, wait_for

#: The run of a hand-made client that publishes the raw events below.
EPOCH = new_epoch()

TABLE2 = {
    "resolution": 0.11,
    "origin": [2.1, 3.5, 0.0],
    "occupied_thresh": 0.65,
    "free_thresh": 0.196,
    "negate": 0,
}


def pgm(width: int, height: int) -> bytes:
    header = f"P5\n{width} {height}\n255\n".encode()
    row = bytes((x * 31) % 256 for x in range(width))
    return header + row * height


def team(bus: Bus) -> tuple:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    return explorer, warden


def test_table_2_map_arrives_byte_for_byte(bus: Bus) -> None:
    explorer, warden = team(bus)
    image = pgm(200, 150)
    with bus.worker():
        explorer.publish_map(image, TABLE2)
        [note] = warden.receive(1, timeout=30)
        fetched = warden.fetch_map()
    assert note.topic.value == "map" and note.map_version == fetched.version == 1
    assert fetched.pgm == image
    assert {k: fetched.metadata[k] for k in TABLE2} == TABLE2
    assert fetched.created_at == note.event.body.created_at.isoformat()


def test_a_16_mb_map_travels_in_chunks_and_every_version_is_kept(bus: Bus, tmp_path) -> None:
    explorer, warden = team(bus)
    small, large = pgm(300, 200), pgm(4000, 4000)
    with bus.worker():
        explorer.publish_map(small, TABLE2)
        events = explorer.publish_map(large, {**TABLE2, "resolution": 0.05})
        assert len(events) == -(-len(large) // MAP_CHUNK_BYTES) + 1, "chunks, then the map event"
        assert max(len(e.model_dump_json()) for e in events) < 1024 * 1024, "every message below the limit"
        notes = warden.receive(2, timeout=120)
        assert [n.map_version for n in notes] == [1, 2]
        fetched = warden.fetch_map()
        first = warden.fetch_map(version=1)
    assert hashlib.sha256(fetched.pgm).digest() == hashlib.sha256(large).digest()
    assert fetched.metadata["resolution"] == 0.05 and first.pgm == small
    env = {**bus.worker_env()}
    exported = subprocess.run(
        [sys.executable, "-m", "fleetbus", "map", "export", "--out", str(tmp_path)],
        env=env,
        capture_output=True,
        text=True,
    )
    assert exported.returncode == 0, exported.stderr
    assert (tmp_path / "map.pgm").read_bytes() == large
    assert yaml.safe_load((tmp_path / "map.yaml").read_text()) == {
        "image": "map.pgm",
        **TABLE2,
        "resolution": 0.05,
    }


def _publish_raw(url: str, events: list) -> None:
    connection = blocking_connection(url)
    channel = connection.channel()
    channel.confirm_delivery()
    for event_type, robot, seq, body in events:
        envelope = {
            "message_id": str(uuid.uuid4()),
            "robot_id": robot,
            "epoch": EPOCH,
            "seq": seq,
            "sent_at": "2021-06-01T18:25:26Z",
            "type": event_type,
            "body": body,
        }
        properties = pika.BasicProperties(delivery_mode=2, user_id=robot, content_type="application/json")
        channel.basic_publish(
            f"{robot}.events", f"{robot}.{event_type}", json.dumps(envelope).encode(), properties
        )
    connection.close()


def test_bad_maps_are_refused_and_stored_maps_do_not_change(bus: Bus) -> None:
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    explorer = bus.robot(account)
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    good = pgm(100, 80)
    chunked = map_events(pgm(1000, 600), TABLE2)  # 600,000 bytes: two chunks and the map event
    (_, chunk0), (_, chunk1), (_, map_body) = chunked
    bad_yaml = {**small_map(), "metadata": {**TABLE2, "free_thresh": 0.9}}
    not_pgm = {**small_map(), "pgm": base64.b64encode(b"GIF89a" + bytes(100)).decode()}
    wrong_sum = {**map_body, "image": {**map_body["image"], "sha256": "0" * 64}}
    with bus.worker():
        explorer.publish_map(good, TABLE2)
        warden.receive(1, timeout=30)
        _publish_raw(
            account.amqp_url,
            [
                ("map", "explorer1", 100, bad_yaml),
                ("map", "explorer1", 101, not_pgm),
                ("map_chunk", "explorer1", 102, chunk0),
                ("map", "explorer1", 103, map_body),  # chunk 1 never sent
                ("map_chunk", "explorer1", 104, chunk1),
                ("map", "explorer1", 105, wrong_sum),
            ],
        )
        letters = wait_for(lambda: (found := bus.dead_letters()) and len(found) == 4 and found)
        # the sentinel: the next good map, through the same lane
        sentinel = explorer.publish_map(good, TABLE2)[-1]
        after = notifications_until(warden, lambda note: note.event == sentinel)
        assert [note.map_version for note in after] == [2], "no bad map announced, none became a version"
        latest = warden.fetch_map()
    assert sorted(letter.reason for letter in letters) == ["bad-map", "bad-map", "schema", "schema"]
    details = " | ".join(letter.detail for letter in letters)
    for why in (
        "free_thresh must be below occupied_thresh",
        "not a PGM image",
        "chunks missing (1)",
        "SHA-256",
    ):
        assert why in details
    assert (latest.version, latest.pgm) == (2, good), "no bad map became a version"
