"""Resending is safe for a client that is not fleetbus's: a raw pika client that sends its events
without a message id (the envelope's ``message_id`` is optional) and sends them again, as a client
does after a lost confirm. The same (robot, epoch, seq) with the same content is a duplicate,
counted, whatever optional fields a send leaves out; the same key with other content is a reused
number, dead-lettered. Against the real broker, the worker and each store."""

from __future__ import annotations

import json
import uuid
from typing import Any

import pika

from fleetbus.broker.accounts import Account
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import keyed_message_id, new_epoch
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventQuery
from tests.factories import hazard, status
from tests.support import Bus, wait_for


def publish(account: Account, messages: list[tuple[str, dict[str, Any]]]) -> None:
    """Each message as its own JSON body, with the properties the contract asks for but no
    message_id: confirmed by the broker, as a client resending after a lost confirm sends them."""
    connection = blocking_connection(account.amqp_url)
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        properties = pika.BasicProperties(
            user_id=account.name, content_type="application/json", delivery_mode=2
        )
        for event_type, envelope in messages:
            body = json.dumps(envelope).encode()
            channel.basic_publish(
                f"{account.name}.events", f"{account.name}.{event_type}", body, properties, mandatory=True
            )
    finally:
        connection.close()


def test_a_client_resending_without_message_ids_gets_duplicates_counted_never_dead_letters(
    stored_bus: Bus,
) -> None:
    bus = stored_bus
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    epoch = new_epoch()

    def event(seq: int, event_type: str, body: dict[str, Any], **envelope: Any) -> tuple[str, dict[str, Any]]:
        head = {"robot_id": "explorer1", "epoch": epoch, "seq": seq, "type": event_type}
        return event_type, {**head, "body": body, **envelope}

    fire, battery = event(0, "hazard", hazard(0)), event(1, "status", status(80.0))
    with_id = event(2, "status", status(70.0), message_id=str(uuid.uuid4()), sent_at="2026-11-24T20:56:01Z")
    with bus.worker():
        publish(account, [fire, battery, with_id])
        wait_for(lambda: bus.count(robot_id="explorer1") == 3, what="the three events stored")
        first = {record.seq: record for record in bus.find(EventQuery(robot_id="explorer1"))}

        # sent again: the very bytes; the body's keys in another order with an optional field given
        # at its default and a sent_at stamped now; and the event that had a message id, without it
        reordered = {"type": "hazard", "seq": 0, "epoch": epoch, "robot_id": "explorer1"}
        reordered["body"] = {**dict(reversed(list(hazard(0).items()))), "frame_id": "map"}
        reordered["sent_at"] = "2026-11-25T08:00:00+00:00"
        without_id = event(2, "status", status(70.0))
        resends = [fire, battery, ("hazard", reordered), without_id]
        # the same number with another body: a reused number, not a resend
        reused = event(1, "status", status(12.0))
        publish(account, [*resends, reused])
        duplicates = wait_for(
            lambda: (
                (found := bus.with_store(lambda s: s.events.duplicates("explorer1")))
                and len(found) == 4
                and found
            ),
            what="the four resends counted as duplicates",
        )
        [letter] = wait_for(lambda: bus.dead_letters(), what="the reused number dead-lettered")

    assert bus.count(robot_id="explorer1") == 3, "nothing stored twice"
    assert sorted(d.seq for d in duplicates) == [0, 0, 1, 2] and not any(d.redelivered for d in duplicates)
    by_seq = {d.seq: d.message_id for d in duplicates}
    assert by_seq[1] == first[1].message_id, "an event sent without an id has one id at every send"
    assert {d.message_id for d in duplicates if d.seq == 0} == {first[0].message_id}, (
        "the reordered resend is the same event, with the same derived id"
    )
    assert first[2].message_id == with_id[1]["message_id"], "an id the robot gave is the one kept"
    assert letter.reason == "sequence-reused" and "reused sequence number 1" in letter.detail
    assert first[1].message_id in letter.detail
    stored = {record.seq: record for record in bus.find(EventQuery(robot_id="explorer1"))}
    assert stored == first, "what was stored stays as it was"
    assert stored[1].body["battery_percent"] == 80.0


def test_the_robot_clients_events_are_named_by_their_key_and_a_resend_is_a_duplicate(bus: Bus) -> None:
    """fleetbus's client names an event by its key, not a digest of its content (it builds each
    once and resends it from its outbox as it was); the worker still compares content, so a
    resend is a duplicate and another event under a used number is refused."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    robot = RobotClient(account.amqp_url, state_dir=bus.settings.robots_dir)
    bus.clients.append(robot)
    with bus.worker():
        fire, battery = robot.publish_many([("hazard", hazard(0)), ("status", status(80.0))])
        assert [fire.message_id, battery.message_id] == [
            keyed_message_id("explorer1", robot.epoch, 0),
            keyed_message_id("explorer1", robot.epoch, 1),
        ]
        robot.enqueue([fire, battery])  # as the outbox resends after a lost confirm
        duplicates = wait_for(
            lambda: (
                (found := bus.with_store(lambda s: s.events.duplicates("explorer1")))
                and len(found) == 2
                and found
            ),
            what="the two resends counted as duplicates",
        )
        forged = battery.model_copy(
            update={"body": battery.body.model_copy(update={"battery_percent": 12.0})}
        )
        robot.enqueue([forged], wait=False)
        [letter] = wait_for(lambda: bus.dead_letters(), what="the other content under a used number refused")
    stored = {record.seq: record for record in bus.find(EventQuery(robot_id="explorer1"))}
    assert {seq: record.message_id for seq, record in stored.items()} == {
        0: str(fire.message_id),
        1: str(battery.message_id),
    }
    assert sorted((d.seq, d.message_id) for d in duplicates) == [
        (0, str(fire.message_id)),
        (1, str(battery.message_id)),
    ]
    assert letter.reason == "sequence-reused" and stored[1].body["battery_percent"] == 80.0
