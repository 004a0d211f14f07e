"""The core loop against the real broker: robots publish, workers store and notify."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import threading

import pika

from fleetbus.broker.accounts import Role
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventQuery
from tests.factories import TABLE1_TIME, hazard, small_map, status
from tests.support import Bus, notifications_until, wait_for


def test_200_hazards_reach_both_wardens_and_are_stored_once_in_order(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    wardens = [bus.robot(bus.add(name, kind=RobotKind.WARDEN)) for name in ("warden1", "warden2")]
    with bus.worker():
        for warden in wardens:
            warden.publish("localisation", {"localised": True})
        sent = explorer.publish_many([("hazard", hazard(i)) for i in range(200)])
        for warden in wardens:
            notes = warden.receive(200, timeout=60)
            assert [n.event.seq for n in notes] == [e.seq for e in sent], "FIFO order, no loss, no repeats"
            assert [n.event for n in notes] == sent, "every field arrives exactly as sent"
            assert notes[0].event.body.detected_at.isoformat() == TABLE1_TIME
        sentinel = explorer.publish("hazard", hazard(200, "sentinel"))
        for warden in wardens:
            after = notifications_until(warden, lambda note: note.event == sentinel)
            assert [note.event for note in after] == [sentinel], "nothing else before the sentinel"
        stored = bus.find(EventQuery(type="hazard"))[:-1]  # the sentinel last
    assert [(r.robot_id, r.seq) for r in stored] == [("explorer1", e.seq) for e in sent]
    assert {r.user_id for r in stored} == {"explorer1"}
    assert {r.exchange for r in stored} == {"explorer1.events"}
    assert stored[0].body["description"] == "Fire"


def test_telemetry_is_stored_but_not_sent_to_wardens(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        explorer.publish_many([("status", status(90 - i)) for i in range(10)] + [("hazard", hazard())])
        # the sentinel: a map, which wardens are told of, on the statuses' own lane (the robot's
        # shard) after them; any status notification would reach the inbox before it
        explorer.publish("map", small_map())
        # the hazard comes by the express lane, so before or after the map: read until both came
        seen: set[str] = set()

        def both_came(note: Notification) -> bool:
            seen.add(note.topic.value)
            return {"hazard", "map"} <= seen

        notes = notifications_until(warden, both_came)
        wait_for(lambda: bus.count(robot_id="explorer1", type="status") == 10, what="10 stored statuses")
    assert sorted(n.topic.value for n in notes) == ["hazard", "map"]


def _publish_raw(url: str, routing_key: str, body: bytes, user_id: str | None) -> None:
    connection = blocking_connection(url)
    channel = connection.channel()
    channel.confirm_delivery()
    properties = pika.BasicProperties(
        delivery_mode=2,
        user_id=user_id,
        message_id=f"raw-{routing_key}-{len(body)}",
        content_type="application/json",
    )
    channel.basic_publish("explorer1.events", routing_key, body, properties, mandatory=True)
    connection.close()


def test_bad_input_is_dead_lettered_with_reasons_and_good_input_is_unaffected(bus: Bus) -> None:
    bus.settings = bus.settings.updated(max_message_bytes=8 * 1024)
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    explorer = bus.robot(account)
    bad = [
        ("explorer1.hazard", b"{not json", "not-json"),
        ("explorer1.hazard", b'{"type": "hazard", "robot_id": "explorer1", "seq": 1, "body": {}}', "schema"),
        ("explorer1.hazard", b"x" * (9 * 1024), "too-large"),
        ("explorer1.teleport", b'{"type": "teleport"}', "unknown-type"),
    ]
    with bus.worker():
        explorer.publish_many([("hazard", hazard(i)) for i in range(100)])
        for routing_key, body, _reason in bad:
            _publish_raw(account.amqp_url, routing_key, body, "explorer1")
        explorer.publish_many([("hazard", hazard(i)) for i in range(100, 200)])
        wait_for(lambda: bus.count() == 200, what="200 stored events")
        letters = wait_for(lambda: (found := bus.dead_letters()) and len(found) == 4 and found)
    assert sorted(letter.reason for letter in letters) == sorted(reason for _, _, reason in bad)
    for letter in letters:
        assert letter.user_id == "explorer1"
        assert letter.detail, "each dead letter says why"
    schema_letter = next(letter for letter in letters if letter.reason == "schema")
    assert "body.pose: Field required" in schema_letter.detail
    assert [r.seq for r in bus.find()] == list(range(200))
    assert bus.dead_letters() == letters, "listing does not consume"


def test_an_event_without_the_contracts_properties_is_refused_naming_the_property(bus: Bus) -> None:
    """No content type, another one, another charset, or transient: each dead-lettered with a reason
    that names the property, nothing of them stored; `fleetbus dlq` shows why."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    epoch = new_epoch()
    refused = {
        1: ({"content_type": None}, "content-type", "has no content_type property"),
        2: ({"content_type": "text/plain"}, "content-type", "content_type is 'text/plain'"),
        3: ({"content_type": "application/json; charset=latin-1"}, "content-type", "(UTF-8)"),
        4: ({"delivery_mode": 1}, "not-persistent", "delivery_mode is 1 (transient)"),
    }
    with bus.worker():
        for seq in (*refused, 5):
            properties = {"content_type": "application/json", "delivery_mode": 2}
            properties.update(refused[seq][0] if seq in refused else {})
            body = encode_event(build_event("hazard", "explorer1", epoch, seq, hazard(seq)))
            connection = blocking_connection(account.amqp_url)
            try:
                channel = connection.channel()
                channel.confirm_delivery()
                props = pika.BasicProperties(user_id="explorer1", **properties)
                channel.basic_publish("explorer1.events", "explorer1.hazard", body, props, mandatory=True)
            finally:
                connection.close()
        wait_for(lambda: bus.count() == 1, what="the one event with the contract's properties stored")
        letters = wait_for(lambda: (found := bus.dead_letters()) and len(found) == len(refused) and found)
    assert [r.seq for r in bus.find()] == [5]
    assert sorted((json.loads(letter.body)["seq"], letter.reason) for letter in letters) == [
        (seq, reason) for seq, (_, reason, _) in refused.items()
    ]
    for letter in letters:
        assert refused[json.loads(letter.body)["seq"]][2] in letter.detail, letter.detail
    env = {**os.environ, **bus.worker_env(), "COLUMNS": "250"}
    listed = subprocess.run(
        [sys.executable, "-m", "fleetbus", "dlq"], env=env, capture_output=True, text=True, timeout=120
    )
    assert listed.returncode == 0, listed.stderr
    assert "content-type" in listed.stdout and "not-persistent" in listed.stdout
    assert "content_type is 'text/plain'" in listed.stdout, listed.stdout


def test_worker_keeps_running_after_poison_and_later_events_flow(bus: Bus) -> None:
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    explorer = bus.robot(account)
    with bus.worker() as worker:
        for _ in range(20):
            _publish_raw(account.amqp_url, "explorer1.hazard", b"\xff\xfe", "explorer1")
        explorer.publish("hazard", hazard())
        wait_for(lambda: bus.count() == 1, what="the good event after 20 poison messages")
        assert worker.error is None


def test_worker_killed_mid_stream_ends_with_exactly_2000(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    first = bus.spawn_worker()
    published: list[int] = []

    def produce() -> None:
        for _ in range(20):
            events = explorer.publish_many([("status", status(50)) for _ in range(100)])
            published.extend(e.seq for e in events)

    producer = threading.Thread(target=produce)
    producer.start()
    try:
        wait_for(lambda: bus.count() >= 300, timeout=60, what="the first worker to store 300 events")
        first.kill()
        first.wait(10)
        stored_at_kill = bus.count()
        producer.join(120)
        assert len(published) == 2000
        second = bus.spawn_worker()
        try:
            wait_for(lambda: bus.count() == 2000, timeout=120, what="2000 stored events after the restart")
        finally:
            second.terminate()
            assert second.wait(60) == 0, "SIGTERM stops the worker cleanly"
    finally:
        producer.join(120)
        if first.poll() is None:
            first.kill()
    assert stored_at_kill < 2000, "the kill happened mid-stream"
    seqs = [r.seq for r in bus.find()]
    assert seqs == sorted(set(seqs)) == list(range(2000)), "no gaps, no duplicates"


def test_operator_receives_every_notification_topic(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    operator = bus.robot(bus.add("ops1", role=Role.OPERATOR))
    with bus.worker():
        warden.publish("localisation", {"localised": True})  # the gate opens: hazards are announced
        explorer.publish("hazard", hazard())
        [note] = operator.receive(1, timeout=15)
    assert note.event.robot_id == "explorer1"


def test_ingest_into_mongodb(bus: Bus, mongodb_url: str) -> None:
    bus.settings = bus.settings.updated(
        mongodb_url=f"{mongodb_url.rstrip('/')}/fleetbus_{bus.vhost.replace('-', '_')}"
    )
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        sent = explorer.publish_many([("hazard", hazard(i)) for i in range(50)])
        assert [n.event for n in warden.receive(50, timeout=60)] == sent
        wait_for(lambda: bus.count(robot_id="explorer1") == 50, what="50 events in MongoDB")
    assert [r.seq for r in bus.find(EventQuery(robot_id="explorer1"))] == [e.seq for e in sent]


def test_store_locked_means_no_ack_then_everything_lands(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    with bus.worker() as worker:
        explorer.publish("status", status())
        wait_for(lambda: bus.count() == 1, what="the first event")
        locker = sqlite3.connect(bus.settings.sqlite_path, isolation_level=None)
        locker.execute("BEGIN EXCLUSIVE")
        try:
            explorer.publish_many([("status", status()) for _ in range(50)])
            wait_for(lambda: worker.stats().store_retries >= 2, what="the worker to retry the locked store")
            assert bus.ready_messages("fleetbus.ingest.events") == 0, "held unacked by the worker, not lost"
        finally:
            locker.execute("ROLLBACK")
            locker.close()
        wait_for(lambda: bus.count() == 51, what="all 51 events once the lock is gone")
