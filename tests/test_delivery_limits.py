"""Delivery limits of the quorum queues (``FLEETBUS_CLUSTER``), against the real broker.

RabbitMQ 4 gives every quorum queue a limit of 20 deliveries per message unless told otherwise:
a message returned unacknowledged more often is dead-lettered, or dropped. fleetbus gives each
quorum queue a limit chosen for what it holds (:mod:`fleetbus.broker.policies`). These tests
deliver messages more than 20 times and count: the dead letters ``fleetbus dlq`` lists, a
robot's notification while its link keeps dropping, a hazard in the express lane while the
worker that holds it keeps dying are all kept; a message past a worker queue's limit goes to
the dead letters with the reason ``delivery_limit``, never silently away.

The quorum queues live on one node here (``cluster=True`` on the suite's node): how often a
message may be delivered is the queue's business, not the cluster's.
"""

from __future__ import annotations

import json
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass

import pika
import pytest

from fleetbus.broker.accounts import Account
from fleetbus.broker.dead_letter_actions import discard_dead_letter
from fleetbus.broker.policies import COMMAND_DELIVERY_LIMIT, WORKER_DELIVERY_LIMIT
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.routing import (
    DEAD_LETTER_QUEUE,
    EXPRESS_QUEUE,
    OVERFLOW_QUEUE,
    EventType,
    RobotKind,
    commands_queue,
    inbox_queue,
)
from tests.factories import hazard
from tests.link import NetworkLink
from tests.support import Bus, network_link, wait_for

#: More than RabbitMQ 4's default limit of 20.
ROUNDS = 25

pytestmark = pytest.mark.rabbitmq_versions


@pytest.fixture
def quorum_bus(bus: Bus) -> Iterator[Bus]:
    """The test's virtual host as a cluster's: every queue that holds data is a quorum queue."""
    bus.settings = bus.settings.updated(cluster=True)
    bus.service_accounts()  # `fleetbus setup`: the topology and the policies
    yield bus


def _queue_type(bus: Bus, queue: str) -> str:
    return str(bus.api.get_queue(bus.vhost, queue)["type"])


@dataclass
class Taken:
    times: int = 0
    """How often the message was taken."""
    delivery_count: int = 0
    """The broker's count of its earlier deliveries, the last time it was taken."""


def _taken_and_returned(bus: Bus, url: str, queue: str, most: int) -> Taken:
    """Take the one message of ``queue`` with ``url``'s login and give it back unacknowledged (the
    channel closes, as when its consumer dies), at most ``most`` times or until the broker moved it
    to the dead letters. A consumer, not ``basic.get``, which a single-active-consumer quorum queue
    refuses."""
    connection = blocking_connection(url)
    taken = Taken()
    try:
        while taken.times < most:
            channel = connection.channel()
            channel.basic_qos(prefetch_count=1)
            deadline = time.monotonic() + 30
            for method, properties, _ in channel.consume(queue, inactivity_timeout=0.05):
                if method is not None:
                    taken.times += 1
                    taken.delivery_count = int((properties.headers or {}).get("x-delivery-count", 0))
                    break
                if bus.ready_messages(DEAD_LETTER_QUEUE) or time.monotonic() > deadline:
                    assert bus.ready_messages(DEAD_LETTER_QUEUE), f"{queue} lost its message after {taken}"
                    return taken
            channel.close()  # given back: in the queue again in a moment
    finally:
        connection.close()
    return taken


def test_the_dead_letters_listed_25_times_are_all_still_there(quorum_bus: Bus) -> None:
    """`fleetbus dlq` reads the letters and puts them back: each listing is a delivery."""
    bus = quorum_bus
    assert _queue_type(bus, DEAD_LETTER_QUEUE) == "quorum"
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    bad = []
    for seq in range(2):
        message_id = uuid.uuid4().hex
        body = json.dumps({"robot_id": "explorer1", "seq": seq, "type": "status", "nope": 1}).encode()
        bus.publish_raw(account, "explorer1.status", body, message_id=message_id)
        bad.append(message_id)
    with bus.worker():
        wait_for(lambda: len(bus.dead_letters()) == len(bad), what="the two dead letters")
    first = {letter.letter_id: letter.message_id for letter in bus.dead_letters()}
    for _ in range(ROUNDS):
        assert sorted(letter.message_id or "" for letter in bus.dead_letters()) == sorted(bad)
    letters = bus.dead_letters()
    # each letter keeps its name however often it was read: `fleetbus dlq requeue ID` finds it
    assert {letter.letter_id: letter.message_id for letter in letters} == first
    assert all(int(letter.headers.get("x-delivery-count", 0)) >= ROUNDS for letter in letters), [
        letter.headers.get("x-delivery-count") for letter in letters
    ]
    assert {letter.reason for letter in letters} == {"schema"}
    assert bus.ready_messages(OVERFLOW_QUEUE) == 0, "nothing counted as dropped"
    discarded = discard_dead_letter(bus.admin_url, letters[0].letter_id)
    assert [letter.message_id for letter in bus.dead_letters()] == [
        message_id for message_id in bad if message_id != discarded.message_id
    ]


def test_an_inbox_keeps_a_notification_its_robot_held_while_its_link_dropped_25_times(
    quorum_bus: Bus, link_for: list[NetworkLink]
) -> None:
    bus = quorum_bus
    warden = bus.add("warden1", kind=RobotKind.WARDEN)
    inbox = inbox_queue("warden1")
    assert _queue_type(bus, inbox) == "quorum"
    link = network_link(link_for, warden)
    notification = b'{"a notification": "the worker made"}'
    with bus.admin_channel() as channel:
        channel.confirm_delivery()
        channel.basic_publish("", inbox, notification, pika.BasicProperties(delivery_mode=2))
    for round_ in range(ROUNDS):
        _held_when_the_link_drops(link, warden, inbox)
        wait_for(lambda: bus.ready_messages(inbox) == 1, what=f"the notification after drop {round_ + 1}")
    connection = blocking_connection(warden.amqp_url)
    try:
        method, properties, body = connection.channel().basic_get(inbox, auto_ack=True)
    finally:
        connection.close()
    assert method is not None and body == notification
    assert properties.headers["x-delivery-count"] == ROUNDS
    assert bus.ready_messages(OVERFLOW_QUEUE) == 0, "nothing counted as dropped"


def _held_when_the_link_drops(link: NetworkLink, robot: Account, inbox: str) -> None:
    """The robot receives the notification through ``link``; the link drops before it acks."""
    connection = blocking_connection(link.url(robot.amqp_url))
    channel = connection.channel()
    channel.basic_qos(prefetch_count=1)
    for method, _, _ in channel.consume(inbox, inactivity_timeout=30):
        assert method is not None, "the notification did not come"
        break
    link.drop_connections()
    with pytest.raises(pika.exceptions.AMQPError):
        connection.process_data_events(time_limit=5)
        connection.close()


def test_a_hazard_whose_worker_died_25_times_while_holding_it_is_stored_once(quorum_bus: Bus) -> None:
    bus = quorum_bus
    assert _queue_type(bus, EXPRESS_QUEUE) == "quorum"
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    event = build_event(EventType.HAZARD, "explorer1", new_epoch(), 0, hazard())
    bus.publish_raw(account, "explorer1.hazard", encode_event(event), message_id=str(event.message_id))
    service = bus.service_accounts().service_url
    taken = _taken_and_returned(bus, service, EXPRESS_QUEUE, ROUNDS)  # a worker dying each time
    assert taken == Taken(ROUNDS, ROUNDS - 1)
    with bus.worker():
        wait_for(lambda: bus.count(EventType.HAZARD.value) == 1, what="the hazard stored")
        wait_for(lambda: bus.ready_messages(EXPRESS_QUEUE) == 0, what="the express lane drained")
    assert bus.dead_letters() == []


def test_a_hazard_past_the_express_lanes_limit_goes_to_the_dead_letters(quorum_bus: Bus) -> None:
    """A message that took the worker down each time is set aside, with the broker's reason."""
    bus = quorum_bus
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    event = build_event(EventType.HAZARD, "explorer1", new_epoch(), 0, hazard())
    bus.publish_raw(account, "explorer1.hazard", encode_event(event), message_id=str(event.message_id))
    service = bus.service_accounts().service_url
    taken = _taken_and_returned(bus, service, EXPRESS_QUEUE, WORKER_DELIVERY_LIMIT + 2)
    assert taken.times == WORKER_DELIVERY_LIMIT + 1, "delivered once, then again as often as the limit allows"
    letters = wait_for(lambda: bus.dead_letters(), what="the hazard in the dead letters")
    assert [letter.message_id for letter in letters] == [str(event.message_id)]
    assert letters[0].reason == "delivery_limit"
    assert EXPRESS_QUEUE in letters[0].detail
    assert bus.ready_messages(EXPRESS_QUEUE) == 0


def test_a_command_its_robot_never_acknowledges_is_a_dead_letter_and_an_expired_one_is_not(
    quorum_bus: Bus,
) -> None:
    bus = quorum_bus
    robot = bus.add("explorer1", kind=RobotKind.EXPLORER)
    queue = commands_queue("explorer1")
    assert _queue_type(bus, queue) == "quorum"
    with bus.admin_channel() as channel:
        channel.confirm_delivery()
        expiring = pika.BasicProperties(delivery_mode=2, message_id="stale", expiration="1")
        channel.basic_publish("", queue, b'{"command": "stale"}', expiring)
    # the stale command expires unread: dropped, as every command older than its time to live
    wait_for(lambda: bus.ready_messages(queue) == 0, what="the stale command expired")
    with bus.admin_channel() as channel:
        channel.confirm_delivery()
        poison = pika.BasicProperties(delivery_mode=2, message_id="poison")
        channel.basic_publish("", queue, b'{"command": "poison"}', poison)
    taken = _taken_and_returned(bus, robot.amqp_url, queue, COMMAND_DELIVERY_LIMIT + 2)
    assert taken.times == COMMAND_DELIVERY_LIMIT + 1
    # the queue dead-letters in order: the poison command's letter comes after the stale one's would
    letters = wait_for(lambda: bus.dead_letters(), what="the poison command in the dead letters")
    assert [(letter.message_id, letter.reason) for letter in letters] == [("poison", "delivery_limit")]
