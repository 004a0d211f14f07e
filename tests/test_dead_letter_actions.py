"""Requeue and discard one dead letter by its id, on the real broker: exactly that one, the others
left in their order; the requeued message published again as its sender, confirmed."""

from __future__ import annotations

import json
import threading
import uuid
from typing import Any
from urllib.parse import urlsplit

import pika
import pytest
from pika.adapters.blocking_connection import BlockingChannel

from fleetbus.broker import dead_letter_actions
from fleetbus.broker.accounts import Account, url_for
from fleetbus.broker.dead_letter_actions import (
    DeadLetterGone,
    RequeueRefused,
    discard_dead_letter,
    requeue_dead_letter,
)
from fleetbus.broker.dead_letter_queue import DeadLetter, peek_dead_letters
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import DEAD_LETTER_QUEUE, INGEST_QUEUE, RobotKind
from tests.support import Bus, wait_for


def _status_body(seq: int) -> bytes:
    return json.dumps({"robot_id": "explorer1", "seq": seq, "type": "status", "nope": 1}).encode()


def _refuse_everything(bus: Bus, expected: int) -> None:
    """What a worker does to a bad message: ``basic.nack`` without requeue, so the broker moves it
    to the dead-letter queue itself (with its ``x-death`` record)."""
    with bus.admin_channel() as channel:
        for _ in range(expected):
            method, _, _ = _next_in_ingest(channel)
            channel.basic_nack(method.delivery_tag, requeue=False)
    wait_for(lambda: bus.ready_messages(DEAD_LETTER_QUEUE) == expected, what="the dead letters")


def _next_in_ingest(channel: Any) -> tuple[Any, pika.BasicProperties, bytes]:
    """The next message of the ingest queue (a quorum queue with a single active consumer, which
    refuses ``basic.get``), taken unacked."""
    channel.basic_qos(prefetch_count=1)
    for method, properties, body in channel.consume(INGEST_QUEUE, inactivity_timeout=30):
        assert method is not None, "a message in the ingest queue within 30 s"
        channel.cancel()
        return method, properties, body
    raise AssertionError("the ingest queue's consumer ended")


def _dead_letters(bus: Bus, *message_ids: str) -> tuple[Account, list[DeadLetter]]:
    """Bad statuses from explorer1 (one per message id, in order), dead-lettered by the broker."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    for seq, message_id in enumerate(message_ids):
        bus.publish_raw(account, "explorer1.status", _status_body(seq), message_id=message_id)
    _refuse_everything(bus, len(message_ids))
    return account, peek_dead_letters(bus.admin_url)


def _ids(letters: list[DeadLetter]) -> list[str]:
    return [letter.letter_id for letter in letters]


def test_reading_leaves_every_letter_in_place_and_names_each_the_same_way_every_time(bus: Bus) -> None:
    _, first = _dead_letters(bus, "a", "b", "c")
    again = peek_dead_letters(bus.admin_url)
    assert [letter.message_id for letter in again] == ["a", "b", "c"]
    assert _ids(again) == _ids(first) and len(set(_ids(first))) == 3
    assert all(letter.headers["x-death"] and letter.body.startswith(b"{") for letter in first)
    assert "x-death" in first[0].headers_text() and "fleetbus.ingest.events" in first[0].headers_text()
    assert "headers" not in first[0].as_dict() and first[0].as_dict()["letter_id"] == first[0].letter_id


def test_discard_removes_exactly_the_chosen_letter_even_beside_one_with_the_same_message_id(bus: Bus) -> None:
    # a robot that sends a message again after an outage may be refused twice with one message id
    _, letters = _dead_letters(bus, "a", "twice", "twice", "d")
    chosen = letters[2]
    assert letters[1].message_id == chosen.message_id and letters[1].letter_id != chosen.letter_id

    assert discard_dead_letter(bus.admin_url, chosen.letter_id).letter_id == chosen.letter_id

    left = peek_dead_letters(bus.admin_url)
    assert _ids(left) == _ids([letters[0], letters[1], letters[3]]), "the others, in their order"
    with pytest.raises(DeadLetterGone, match="nothing was changed"):
        discard_dead_letter(bus.admin_url, chosen.letter_id, patience=0.5)
    assert _ids(peek_dead_letters(bus.admin_url)) == _ids(left)


def test_a_letter_another_reader_holds_for_a_moment_is_still_found(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A listing (the console's, `fleetbus dlq`) holds the letters it peeks, unacked, while it
    reads them: an action at that moment waits for them to come back instead of calling the
    letter gone."""
    _, [letter] = _dead_letters(bus, "held")
    holding, release, failures = threading.Event(), threading.Event(), []
    looks: list[bool] = []
    find = dead_letter_actions._find

    def counted_find(channel: BlockingChannel, wanted: str) -> Any:
        found = find(channel, wanted)
        looks.append(found is not None)
        return found

    monkeypatch.setattr(dead_letter_actions, "_find", counted_find)

    def reader() -> None:  # a listing that reads what it peeked until told it is done
        try:
            with blocking_connection(bus.admin_url) as connection:
                method, _, _ = connection.channel().basic_get(DEAD_LETTER_QUEUE, auto_ack=False)
                assert method is not None
                holding.set()
                while not release.is_set():
                    connection.sleep(0.05)
        except Exception as error:
            failures.append(error)
            holding.set()

    thread = threading.Thread(target=reader)
    thread.start()
    assert holding.wait(30) and not failures, failures
    assert bus.ready_messages(DEAD_LETTER_QUEUE) == 0, "held by the reader"
    discarded: list[DeadLetter] = []
    action = threading.Thread(
        target=lambda: discarded.append(discard_dead_letter(bus.admin_url, letter.letter_id))
    )
    action.start()
    wait_for(lambda: looks, 30, "the discard looking while the letter is held")
    release.set()
    thread.join(30)
    action.join(60)
    assert looks[0] is False, "the first look found the letter held elsewhere"
    assert [d.letter_id for d in discarded] == [letter.letter_id]
    assert not failures, failures
    assert peek_dead_letters(bus.admin_url) == []


def test_requeue_publishes_it_again_as_its_sender_confirmed_and_then_removes_it(bus: Bus) -> None:
    account, letters = _dead_letters(bus, "a", "b", "c")
    asked_for: list[str] = []

    def sender_url(user_id: str) -> str:
        asked_for.append(user_id)
        return account.amqp_url

    requeued = requeue_dead_letter(bus.admin_url, letters[1].letter_id, sender_url)

    assert requeued.message_id == "b" and asked_for == ["explorer1"]
    assert _ids(peek_dead_letters(bus.admin_url)) == _ids([letters[0], letters[2]])
    assert bus.ready_messages(INGEST_QUEUE) == 1, "published once, confirmed before the requeue returned"
    with bus.admin_channel() as channel:
        _, properties, body = _next_in_ingest(channel)
    assert (properties.message_id, properties.user_id, body) == ("b", "explorer1", _status_body(1))
    assert properties.delivery_mode == 2
    assert "x-death" not in (properties.headers or {}), "the broker's record of the old refusal is left out"
    with pytest.raises(DeadLetterGone):
        requeue_dead_letter(bus.admin_url, letters[1].letter_id, sender_url)


def test_a_requeue_the_broker_refuses_leaves_the_letter_where_it_was(bus: Bus) -> None:
    account, letters = _dead_letters(bus, "a", "b")
    wrong_password = url_for(bus.admin_url, "explorer1", uuid.uuid4().hex)
    with pytest.raises(RequeueRefused, match=r"explorer1.*stays a dead letter"):
        requeue_dead_letter(bus.admin_url, letters[0].letter_id, lambda user: wrong_password)
    # another account may not speak for explorer1: the broker checks the validated user id
    impostor = bus.add("explorer2", kind=RobotKind.EXPLORER)
    with pytest.raises(RequeueRefused, match="stays a dead letter"):
        requeue_dead_letter(bus.admin_url, letters[0].letter_id, lambda user: impostor.amqp_url)
    assert _ids(peek_dead_letters(bus.admin_url)) == _ids(letters)
    assert bus.ready_messages(INGEST_QUEUE) == 0
    # the same letter goes once its sender's own login is used
    requeue_dead_letter(bus.admin_url, letters[0].letter_id, lambda user: account.amqp_url)
    assert _ids(peek_dead_letters(bus.admin_url)) == _ids(letters[1:])


def test_a_letter_nobody_sent_cannot_be_requeued_as_anyone(bus: Bus) -> None:
    bus.add("explorer1", kind=RobotKind.EXPLORER)  # the topology
    with bus.admin_channel() as channel:
        channel.confirm_delivery()
        channel.basic_publish("fleetbus.dlx", "", b"anonymous", pika.BasicProperties(delivery_mode=2))
    [letter] = peek_dead_letters(bus.admin_url)
    with pytest.raises(RequeueRefused, match="no sender"):
        requeue_dead_letter(bus.admin_url, letter.letter_id, lambda user: bus.admin_url)
    assert _ids(peek_dead_letters(bus.admin_url)) == [letter.letter_id]


def test_a_letter_is_its_validated_senders_whatever_headers_it_carries(bus: Bus) -> None:
    """A robot's refused message may carry headers naming another robot (``x-original-...``, the
    names an older worker gave its copies): the letter is still its sender's, as the broker
    validated it, and is published again only as that sender, to that sender's exchange."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    bus.add("victim1", kind=RobotKind.EXPLORER)
    forged = {
        "x-original-user-id": "victim1",
        "x-original-exchange": "victim1.events",
        "x-original-routing-key": "victim1.status",
    }
    bus.publish_raw(account, "explorer1.status", _status_body(0), message_id="forged", headers=forged)
    _refuse_everything(bus, 1)
    [letter] = peek_dead_letters(bus.admin_url)
    assert (letter.user_id, letter.exchange, letter.routing_key) == (
        "explorer1",
        "explorer1.events",
        "explorer1.status",
    )
    asked_for: list[str] = []

    def sender_url(user_id: str) -> str:
        asked_for.append(user_id)
        return account.amqp_url

    requeue_dead_letter(bus.admin_url, letter.letter_id, sender_url)
    assert asked_for == ["explorer1"]
    with bus.admin_channel() as channel:
        _, properties, _ = _next_in_ingest(channel)
    assert (properties.user_id, set(properties.headers or {}) & set(forged)) == ("explorer1", set())


def test_a_letter_that_names_an_exchange_not_its_senders_is_not_requeued(bus: Bus) -> None:
    bus.add("explorer1", kind=RobotKind.EXPLORER)  # the topology
    admin = urlsplit(bus.admin_url).username
    death = {"exchange": "explorer1.events", "routing-keys": ["explorer1.status"], "reason": "rejected"}
    with bus.admin_channel() as channel:
        channel.confirm_delivery()
        properties = pika.BasicProperties(delivery_mode=2, user_id=admin, headers={"x-death": [death]})
        channel.basic_publish("fleetbus.dlx", "", b"{}", properties)
    [letter] = peek_dead_letters(bus.admin_url)
    with pytest.raises(RequeueRefused, match="not one of its sender"):
        requeue_dead_letter(bus.admin_url, letter.letter_id, lambda user: bus.admin_url)
    assert _ids(peek_dead_letters(bus.admin_url)) == [letter.letter_id]
