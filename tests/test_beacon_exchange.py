"""The beacon exchange against the real broker: only messages with the beacon headers get through;
the broker discards the rest and the workers count them, by publisher, with the reason."""

from __future__ import annotations

from collections.abc import Sequence

import pika
import pika.exceptions
import pytest

from fleetbus.publishers.confirms import Outgoing, PipelinedConfirms
from fleetbus.publishers.errors import PublishRefused
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.discards import Discard, Discards
from tests.support import Bus, wait_for
from tests.test_cli import fleetbus

#: The run of a hand-made client that publishes the raw sightings below.
EPOCH = new_epoch()


def sighting(beacon_id: str = "b1", rssi: int = -60) -> dict:
    return {"beacon_id": beacon_id, "rssi": rssi, "pose": {"x": 1.0, "y": 2.0}}


def publish_raw(url: str, exchange: str, seq: int, headers: dict | None, robot: str = "guide1") -> None:
    event = build_event("beacon", robot, EPOCH, seq, sighting())
    connection = blocking_connection(url)
    try:
        confirms = PipelinedConfirms(connection, connection.channel(), timeout=10)
        properties = pika.BasicProperties(
            delivery_mode=2,
            user_id=robot,
            message_id=str(event.message_id),
            headers=headers,
            content_type="application/json",
        )
        confirms.publish([Outgoing(exchange, f"{robot}.beacon", encode_event(event), properties)], timeout=10)
    finally:
        if connection.is_open:
            connection.close()


def recorded_discards(bus: Bus, count: int) -> list[Discard] | None:
    found = bus.with_store(lambda store: store.discards.recent_discards(2 * count))
    return found if len(found) == count else None


def test_beacons_without_the_headers_are_discarded_and_counted(bus: Bus) -> None:
    account = bus.add("guide1", kind=RobotKind.GUIDE)
    guide = bus.robot(account)
    bad = [
        ({"codename": "guide1"}, "no 'type' header"),
        ({"type": "beacon"}, "no 'codename' header"),
        ({"type": "sighting", "codename": "guide1"}, "header 'type' is 'sighting', not 'beacon'"),
        (None, "no 'type' header; no 'codename' header"),
    ]
    with bus.worker() as worker:
        for seq, (headers, _) in enumerate(bad, start=100):
            publish_raw(account.amqp_url, "guide1.beacon", seq, headers)  # confirmed: the broker took it
        publish_raw(account.amqp_url, "guide1.beacon", 200, {"type": "beacon", "codename": "ble-1"})
        guide.publish("beacon", sighting("b2"))  # the client sets the headers itself
        wait_for(lambda: bus.count("beacon") == 2, what="the two beacons with headers stored")
        discards = wait_for(lambda: recorded_discards(bus, 4), what="4 discards recorded")
        assert worker.stats().rejected == 0, "discarded by the broker, never seen by the ingest"
    assert sorted(d.reason for d in discards) == sorted(reason for _, reason in bad)
    assert {(d.exchange, d.user_id, d.routing_key) for d in discards} == {
        ("guide1.beacon", "guide1", "guide1.beacon")
    }
    [count] = bus.with_store(lambda s: s.discards.discard_counts())
    assert (count.exchange, count.count) == ("guide1.beacon", 4)
    shown = fleetbus(bus, "stats")  # where an operator looks
    assert "beacons the broker discarded: guide1.beacon 4 " in " ".join(shown.stdout.split()), shown.stdout
    stored = bus.find()
    assert {r.seq for r in stored} == {200, 0} and {r.exchange for r in stored} == {"guide1.beacon"}


def test_a_beacon_sent_to_the_events_exchange_is_dead_lettered(bus: Bus) -> None:
    account = bus.add("guide1", kind=RobotKind.GUIDE)
    with bus.worker():
        publish_raw(account.amqp_url, "guide1.events", 5, {"type": "beacon", "codename": "guide1"})
        [letter] = wait_for(lambda: bus.dead_letters(), what="the sighting dead-lettered")
    assert letter.reason == "wrong-exchange"
    assert "beacon events are published to 'guide1.beacon', not 'guide1.events'" in letter.detail
    assert bus.count("beacon") == 0


def test_a_robot_cannot_publish_to_another_robots_beacon_exchange(bus: Bus) -> None:
    explorer = bus.add("explorer1", kind=RobotKind.EXPLORER)
    bus.add("guide1", kind=RobotKind.GUIDE)
    with pytest.raises(PublishRefused, match="ACCESS_REFUSED"):
        publish_raw(
            explorer.amqp_url, "guide1.beacon", 1, {"type": "beacon", "codename": "x"}, robot="explorer1"
        )
    # nor straight to the shared beacon exchange, which only the service writes to
    with pytest.raises(PublishRefused, match="ACCESS_REFUSED"):
        publish_raw(
            explorer.amqp_url, "fleetbus.beacon", 1, {"type": "beacon", "codename": "x"}, robot="explorer1"
        )


def test_a_discard_the_counter_fails_on_is_counted_when_it_comes_again(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A failure the counter does not expect (a bug, a store error that is not transient) is
    logged and counted, and the message goes back to the queue to be tried again: left unacked,
    it held a prefetch slot, and a prefetch's worth of them stopped the counting without a word."""
    account = bus.add("guide1", kind=RobotKind.GUIDE)
    failures: list[int] = []
    record = Discards.record_discards

    async def fails_once(log: Discards, discards: Sequence[Discard]) -> int:
        if not failures:
            failures.append(len(discards))
            raise RuntimeError("the discard log failed")
        return await record(log, discards)

    monkeypatch.setattr(Discards, "record_discards", fails_once)
    with bus.worker() as worker:
        publish_raw(account.amqp_url, "guide1.beacon", 100, {"codename": "guide1"})
        [discard] = wait_for(lambda: recorded_discards(bus, 1), what="the discard recorded at its second try")
        assert discard.reason == "no 'type' header" and failures == [1]
        assert worker.context is not None and worker.context.discards.failed == 1
