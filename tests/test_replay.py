"""fleetbus replay against the real broker: recorded messages go out again, in order and on time."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from typing import Any

import pika
import pytest

from fleetbus.cli.commands.replay import IN_FLIGHT
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import EventType
from fleetbus.workers.recorder.replay import Settled, replay, schedule
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


def tf(i: int, at: datetime, routing_key: str = "someone.tf", **fields: Any) -> RecordedMessage:
    return RecordedMessage(
        key=f"k{i}",
        type="tf",
        recorded_at=at,
        exchange="someone.events",
        routing_key=routing_key,
        user_id="someone",
        robot_id="someone",
        **{"document": {"i": i}, **fields},
    )


def write(bus: Bus, records: list[RecordedMessage]) -> None:
    async def go() -> None:
        async with open_recording_store(bus.settings) as store:
            await store.write_recorded(records)

    asyncio.run(go())


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
    offsets = [0.0, 0.2, 0.2, 0.2, 0.5, 0.9]  # three recorded at once go out without waiting for each other
    write(bus, [tf(i, start + timedelta(seconds=offset)) for i, offset in enumerate(offsets)])
    done = report(
        fleetbus(bus, "replay", "--to", EXCHANGE, "--since", start.isoformat(), "--speed", "2", "--json")
    )
    assert done["span_s"] == offsets[-1] / 2
    assert done["earliest_s"] >= 0, "never before its time"
    assert (done["published"], done["unroutable"]) == (6, 0)
    assert [json.loads(body)["i"] for _, _, body in drain(listener, 6)] == [0, 1, 2, 3, 4, 5]


class ScriptedSender:
    """A sender on a clock of the test's own: what the replay did, and when."""

    def __init__(self, clock: list[float], confirm_s: float) -> None:
        self.clock, self.confirm_s = clock, confirm_s
        self.steps: list[tuple[str, str, float]] = []
        self.sent = 0

    def send(self, record: RecordedMessage, body: bytes, properties: dict[str, Any]) -> None:
        self.steps.append(("send", record.key, self.clock[0]))
        self.sent += 1

    def settle(self) -> Settled:
        self.clock[0] += self.confirm_s  # the confirms take their time
        self.steps.append(("settle", "", self.clock[0]))
        return Settled(self.sent, 1)

    def sleep(self, seconds: float) -> None:
        self.steps.append(("sleep", "", self.clock[0]))
        self.clock[0] += seconds


def test_a_paced_replay_waits_for_its_confirms_before_waiting_for_the_clock() -> None:
    """What is due goes out without waiting for confirms; before the replay waits for the next
    one's time the broker answered all sent (nothing held on the way), and none goes out early."""
    at = datetime(2021, 6, 1, tzinfo=timezone.utc)
    # binary fractions of a second, so the test's clock adds up exactly
    offsets = [0.0, 0.0, 0.0, 1.0, 1.0, 1.015625, 3.0]
    records = [tf(i, at + timedelta(seconds=offset)) for i, offset in enumerate(offsets)]
    clock = [100.0]
    sender = ScriptedSender(clock, confirm_s=0.03125)
    done = replay(records, sender, speed=2, clock=lambda: clock[0], sleep=sender.sleep)
    assert [f"{kind} {key}".strip() for kind, key, _ in sender.steps] == [
        *("send k0", "send k1", "send k2", "settle", "sleep", "send k3", "send k4"),
        # k5 is due 8 ms after k4, sooner than the confirms came: it goes out late, with no sleep
        *("settle", "send k5", "settle", "sleep", "send k6", "settle"),
    ]
    due = dict(zip([r.key for r in records], schedule(records, 2), strict=True))
    assert all(when >= 100.0 + due[key] for kind, key, when in sender.steps if kind == "send")
    assert (done.published, done.unroutable, done.earliest_s, done.latest_s) == (6, 1, 0.0, 0.0234375)


def test_a_window_longer_than_the_messages_in_flight_is_counted_exactly(bus: Bus) -> None:
    """More messages than a replay keeps awaiting their confirms; every third one for a key no queue
    is bound to, a few with their bodies not kept, message ids repeated (a recording may hold the
    same message twice, or none): the counts are exact and the bound queue gets the routable ones
    in the recorded order, the last one a sentinel. A nack stops the replay, naming the message."""
    exchange, queue = "replay.some", "replay.kept"
    connection = blocking_connection(bus.admin_url)
    channel = connection.channel()
    channel.exchange_declare(exchange, "topic", durable=True)
    channel.queue_declare(queue, durable=True)
    channel.queue_bind(queue, exchange, "kept.#")
    start = datetime.now(timezone.utc) - timedelta(minutes=1)
    count = 2 * IN_FLIGHT + 100
    records = [
        tf(
            i,
            start + timedelta(milliseconds=i),
            "lost.tf" if i % 3 == 1 else "kept.tf",
            properties={"message_id": f"same-{i % 5}"},
            **({"document": None, "raw": b"", "size": 10} if i % 100 == 50 else {}),
        )
        for i in range(count)
    ]
    records.append(tf(count, start + timedelta(milliseconds=count), "kept.sentinel"))
    write(bus, records)
    done = report(
        fleetbus(bus, "replay", "--to", exchange, "--since", start.isoformat(), "--speed", "0", "--json")
    )
    skipped = [r for r in records if r.raw == b""]
    routed = [r for r in records if r.routing_key.startswith("kept.") and r.raw != b""]
    assert (done["published"], done["unroutable"], done["skipped"]) == (
        len(routed),
        len(records) - len(skipped) - len(routed),
        len(skipped),
    )
    assert len(routed) > IN_FLIGHT and done["unroutable"] > 600 and len(skipped) == 21
    received: list[int] = []
    for method, _, body in channel.consume(queue, auto_ack=True, inactivity_timeout=30):
        assert method is not None, f"no sentinel within 30 s of the last message: {len(received)} arrived"
        received.append(json.loads(body)["i"])
        if method.routing_key == "kept.sentinel":
            break
    channel.cancel()
    assert received == [int(r.key[1:]) for r in routed]

    # a queue that takes 1,000 and nacks the rest: the replay stops at the first nack, naming it
    channel.exchange_declare("replay.full", "topic", durable=True)
    overflow = {"x-max-length": 1000, "x-overflow": "reject-publish"}
    channel.queue_declare("replay.full", durable=True, arguments=overflow)
    channel.queue_bind("replay.full", "replay.full", "#")
    connection.close()
    full = fleetbus(bus, "replay", "--to", "replay.full", "--since", start.isoformat(), "--speed", "0")
    said = " ".join(full.stderr.split())
    nacked = [r for r in records if r.raw != b""][1000]
    assert full.returncode == 1, said
    named = f"the tf message on {nacked.routing_key} recorded at {nacked.recorded_at.isoformat()}"
    assert f"replay stopped: the broker nacked {named}" in said
    assert "the 1,000 messages before it were confirmed" in said


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
