"""fleetbus replay against the real broker: recorded messages go out again, in order and on time."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from typing import Any

import pika
import pytest

from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import EventType
from fleetbus.workers.recorder.replay import schedule
from fleetbus.workers.store import open_recording_store
from fleetbus.workers.store.recordings import RecordedMessage
from tests.factories import status
from tests.support import Bus, wait_for
from tests.test_cli import fleetbus

EXCHANGE, QUEUE = "replay.test", "replay.out"


@pytest.fixture
def listener(bus: Bus) -> Iterator[pika.adapters.blocking_connection.BlockingChannel]:
    """A topic exchange of the test's own with a queue bound to every key (as the administrator)."""
    connection = blocking_connection(bus.admin_url)
    channel = connection.channel()
    channel.exchange_declare(EXCHANGE, "topic", durable=True)
    channel.queue_declare(QUEUE, durable=True)
    channel.queue_bind(QUEUE, EXCHANGE, "#")
    yield channel
    connection.close()


def drain(channel: Any, count: int) -> list[tuple[Any, Any, bytes]]:
    got: list[tuple[Any, Any, bytes]] = []

    def take() -> bool:
        method, properties, body = channel.basic_get(QUEUE, auto_ack=True)
        if method is not None:
            got.append((method, properties, body))
        return len(got) == count

    wait_for(take, what=f"{count} replayed messages")
    return got


def report(result: Any) -> dict[str, Any]:
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_recorded_messages_are_replayed_as_they_were_received(bus: Bus, listener: Any) -> None:
    robot = bus.add("replay-robot")
    with bus.recorder():
        with bus.robot(robot) as client:
            sent = [client.publish(EventType.STATUS, status(float(i))) for i in range(3)]
        bus.publish_raw(
            robot, "replay-robot.camera", b"\x00\x01raw", message_id="raw-1", correlation_id="c-1"
        )
        wait_for(lambda: len(bus.recorded("status")) == 3 and bus.recorded("camera"), what="all recorded")
    done = report(fleetbus(bus, "replay", "--to", EXCHANGE, "--since", "10m", "--speed", "0", "--json"))
    assert (done["published"], done["unroutable"], done["skipped"]) == (4, 0, 0)
    received = drain(listener, 4)
    assert [m.routing_key for m, _, _ in received] == ["replay-robot.status"] * 3 + ["replay-robot.camera"]
    for (_, properties, body), event in zip(received, sent, strict=False):
        assert json.loads(body) == json.loads(event.model_dump_json())
        assert properties.message_id == str(event.message_id) and properties.delivery_mode == 2
        assert properties.user_id is None, "the broker would refuse the robot's user_id from another login"
        assert properties.headers["x-replay-of-user-id"] == "replay-robot"
        assert properties.headers["x-replay-of-exchange"] == "replay-robot.events"
    _, raw_properties, raw_body = received[3]
    assert raw_body == b"\x00\x01raw" and raw_properties.correlation_id == "c-1"

    only = report(fleetbus(bus, "replay", "--to", EXCHANGE, "--since", "10m", "--type", "camera", "--json"))
    assert only["published"] == 1


def test_replay_keeps_the_original_spacing_divided_by_the_speed(bus: Bus, listener: Any) -> None:
    start = datetime.now(timezone.utc) - timedelta(minutes=1)
    offsets = [0.0, 0.2, 0.5, 0.9]
    records = [
        RecordedMessage(
            key=f"k{i}",
            type="tf",
            recorded_at=start + timedelta(seconds=offset),
            exchange="someone.events",
            routing_key="someone.tf",
            user_id="someone",
            robot_id="someone",
            document={"i": i},
        )
        for i, offset in enumerate(offsets)
    ]

    async def write() -> None:
        async with open_recording_store(bus.settings) as store:
            await store.write_recorded(records)

    asyncio.run(write())
    done = report(
        fleetbus(bus, "replay", "--to", EXCHANGE, "--since", start.isoformat(), "--speed", "2", "--json")
    )
    assert done["span_s"] == offsets[-1] / 2
    assert done["earliest_s"] >= 0, "never before its time"
    assert [json.loads(body)["i"] for _, _, body in drain(listener, 4)] == [0, 1, 2, 3]


def test_unroutable_and_missing_exchanges(bus: Bus) -> None:
    robot = bus.add("replay-lost")
    with bus.recorder():
        bus.publish_raw(robot, "replay-lost.tf", b"{}", message_id="x")
        wait_for(lambda: bus.recorded("tf"), what="recorded")
    missing = fleetbus(bus, "replay", "--to", "no.such.exchange", "--since", "10m")
    assert missing.returncode == 1 and "--declare" in missing.stderr
    made = report(fleetbus(bus, "replay", "--to", "replay.empty", "--declare", "--since", "10m", "--json"))
    assert (made["published"], made["unroutable"]) == (0, 1)
    bad = fleetbus(bus, "replay", "--to", "replay.empty", "--since", "10m", "-w", "a=1")
    assert bad.returncode == 2 and "exactly one --type" in bad.stderr


def test_schedule() -> None:
    at = datetime(2021, 6, 1, tzinfo=timezone.utc)
    records = [
        RecordedMessage(f"k{s}", "tf", at + timedelta(seconds=s), "e", "k", None, None) for s in (0, 3, 4)
    ]
    assert schedule(records, 1) == [0, 3, 4]
    assert schedule(records, 0) == [0, 0, 0]
    with pytest.raises(ValueError, match="speed"):
        schedule(records, -1)
