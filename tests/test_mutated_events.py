"""Broken events, as a faulty robot could send them, at a real worker on both stores: valid events
of every kind the worker stores, each broken one to three times at random (a field removed, given
a value of another kind or an extreme one, an unknown field added, inside nested fields too),
with a fixed seed. Each is stored or dead-lettered with a reason that names the message's fault;
none is ``internal-error``, the worker failing on it."""

from __future__ import annotations

import json
import random
import uuid
from collections import Counter
from collections.abc import Callable
from typing import Any

import pika

from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.bodies import INT64_MAX
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.rejections import RejectReason
from fleetbus.schemas.routing import EventType, RobotKind
from tests.factories import hazard, small_map, status
from tests.support import Bus, wait_for

SEED = 20261129
EVENTS = 300
#: Values a broken field is given: other kinds, extremes, past the stores' 64-bit integers.
ODD: list[Any] = [
    None, -1, 0, 1e308, -1e308, INT64_MAX + 1, 2**70, -(2**70), "", "x" * 5000, [], {}, [1, 2],
    {"a": {"b": []}}, True, "NaN", "\u0000", "\U0010ffff", 3.5, "2021-13-45T99:99:99Z",
]  # fmt: skip
BODIES: dict[EventType, Callable[[int], dict[str, Any]]] = {
    EventType.HAZARD: hazard,
    EventType.STATUS: lambda i: status(50.0),
    EventType.MAP: lambda i: small_map(),
    EventType.LOCALISATION: lambda i: {"localised": True, "pose": {"x": 1.0, "y": 2.0}},
    EventType.BEHAVIOUR: lambda i: {"name": "grab", "success": True, "duration_s": 1.5},
    EventType.MEASUREMENT: lambda i: {"quantity": "temperature", "value": 21.5, "pose": {"x": 0.0, "y": 0.0}},
    EventType.ROS: lambda i: {
        "topic": "/chatter", "ros_type": "std_msgs/String", "log_time_ns": i, "fields": {"data": "hi"}
    },
}  # fmt: skip


def broken(doc: Any, rng: random.Random) -> Any:
    """``doc`` with one thing broken, at any depth."""
    if isinstance(doc, dict) and doc and rng.random() < 0.8:
        key = rng.choice(list(doc))
        choice = rng.random()
        if choice < 0.25:
            doc.pop(key)
        elif choice < 0.6:
            doc[key] = rng.choice(ODD)
        elif choice < 0.7:
            doc[f"unknown{rng.randint(0, 9)}"] = rng.choice(ODD)
        else:
            doc[key] = broken(doc[key], rng)
        return doc
    if isinstance(doc, list) and doc:
        i = rng.randrange(len(doc))
        doc[i] = rng.choice(ODD) if rng.random() < 0.5 else broken(doc[i], rng)
        return doc
    return rng.choice(ODD)


def test_every_broken_event_is_stored_or_refused_for_its_fault(stored_bus: Bus) -> None:
    bus = stored_bus
    rng = random.Random(SEED)
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    epoch = new_epoch()
    connection = blocking_connection(account.amqp_url)
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        for seq in range(EVENTS):
            kind = rng.choice(list(BODIES))
            doc = json.loads(encode_event(build_event(kind, "explorer1", epoch, seq, BODIES[kind](seq))))
            for _ in range(rng.randint(1, 3)):
                doc = broken(doc, rng)
            properties = pika.BasicProperties(
                user_id="explorer1",
                delivery_mode=2,
                content_type="application/json",
                message_id=uuid.uuid4().hex,
            )
            body = json.dumps(doc).encode()
            channel.basic_publish(
                "explorer1.events", f"explorer1.{kind.value}", body, properties, mandatory=True
            )
    finally:
        connection.close()
    with bus.worker():
        wait_for(lambda: bus.count() + len(bus.dead_letters()) == EVENTS, 120, "each stored or dead-lettered")
        reasons = Counter(letter.reason for letter in bus.dead_letters())
    assert RejectReason.INTERNAL_ERROR.value not in reasons, reasons
    assert reasons[RejectReason.SCHEMA.value] > EVENTS // 2, "most broken events break the schema"
