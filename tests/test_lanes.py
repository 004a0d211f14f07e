"""The express lane: hazards and localisations have a queue of their own, handled beside the bulk.

A bulk batch is held for real: a status event with a low battery makes the worker warn the
operators, and a queue bound to ``notify.battery`` that refuses every message (``x-max-length``
0, ``reject-publish``) makes the broker nack the warning, so the worker keeps that batch in hand
and retries it, as it would with an operator's inbox full or a queue recovering after a restart.
"""

from __future__ import annotations

import asyncio
import signal
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from datetime import datetime, timedelta, timezone
from types import SimpleNamespace
from typing import Any

import aio_pika
import aio_pika.abc
import pytest

from fleetbus.broker.accounts import Role
from fleetbus.broker.tls import aio_connect
from fleetbus.broker.topology import core_topology, declare_with_url
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import Event
from fleetbus.schemas.routing import (
    EXPRESS_QUEUE,
    INGEST_QUEUE,
    NOTIFY_EXCHANGE,
    RobotKind,
    ingest_shard_queue,
    notification_routing_key,
)
from fleetbus.workers.attempts import AttemptLimit, attempt_key
from fleetbus.workers.express import ExpressLane
from fleetbus.workers.ingest import IngestConsumer
from fleetbus.workers.shards import shard_lease
from fleetbus.workers.store import HazardState, Repositories, repositories_for
from fleetbus.workers.store.base import EventQuery
from fleetbus.workers.validation import Accepted, Rejected
from tests.factories import hazard, status
from tests.support import Bus, notifications_until, read_inbox, wait_for

REFUSING_QUEUE = "test.refuses-battery-warnings"


@contextmanager
def battery_warnings_refused(bus: Bus) -> Iterator[None]:
    """While it lasts, the broker nacks every battery warning the worker publishes."""
    connection = blocking_connection(bus.admin_url)
    try:
        channel = connection.channel()
        channel.queue_declare(REFUSING_QUEUE, arguments={"x-max-length": 0, "x-overflow": "reject-publish"})
        channel.queue_bind(REFUSING_QUEUE, NOTIFY_EXCHANGE, notification_routing_key("battery"))
        yield
        channel.queue_delete(REFUSING_QUEUE)
    finally:
        connection.close()


def in_queue(bus: Bus, name: str = INGEST_QUEUE) -> tuple[int, int]:
    """Ready and unacked messages of a queue, as the management API reports them."""
    queue = bus.api.get_queue(bus.vhost, name)
    return queue.get("messages_ready", 0), queue.get("messages_unacknowledged", 0)


def acks(bus: Bus, name: str) -> int:
    """How many messages the queue's consumers have acked: a count that only grows, so a figure
    the management API has not updated yet can only make a wait longer, never end it early."""
    return int(bus.api.get_queue(bus.vhost, name).get("message_stats", {}).get("ack", 0))


def localised(bus: Bus) -> bool:
    return all(robot.localised for robot in bus.with_store(lambda store: store.hazards.robots("warden")))


def test_a_hazard_reaches_the_wardens_while_a_bulk_batch_is_stuck(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with bus.worker() as worker:
        warden.publish("localisation", {"localised": True})
        wait_for(lambda: localised(bus), what="warden1 localised")
        with battery_warnings_refused(bus):
            explorer.publish("status", status(battery=5.0))
            assert worker.context is not None
            stats = worker.context.stats
            wait_for(lambda: stats.store_retries >= 2, what="the status batch retrying its battery warning")

            sent = explorer.publish("hazard", hazard(0))
            [note] = warden.receive(1, timeout=30)
            assert note.event == sent and note.hazard_id == 1, "announced while the status batch is stuck"
            # counted once the worker's services return, which may be just after the warden has it
            wait_for(lambda: stats.notified == 1, what="the hazard's announcement counted")
            retries = stats.store_retries
            wait_for(lambda: stats.store_retries > retries, what="the status batch still in hand, retrying")
            wait_for(lambda: in_queue(bus) == (0, 1), what="the status in hand, unacked")
            wait_for(lambda: acks(bus, EXPRESS_QUEUE) >= 2, what="the localisation and the hazard acked")
        # the warning goes through at the next retry
        wait_for(lambda: in_queue(bus) == (0, 0), what="the status acked")
        assert stats.notified == 2 and stats.duplicates == 0
    assert sorted(r.type for r in bus.find()) == ["hazard", "localisation", "status"], "each stored once"


def test_worker_killed_with_a_hazard_done_beside_a_stuck_batch(bus: Bus) -> None:
    """Nothing lost, nothing doubled: the hazard was acked on its own queue, the status comes again."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    worker = bus.spawn_worker()
    try:
        warden.publish("localisation", {"localised": True})
        wait_for(lambda: localised(bus), what="warden1 localised")
        with battery_warnings_refused(bus):
            low = explorer.publish("status", status(battery=5.0))
            wait_for(lambda: bus.count("status") == 1, what="the status stored, its warning refused")
            sent = explorer.publish("hazard", hazard(0))
            [note] = warden.receive(1, timeout=30)
            assert note.event == sent
            wait_for(lambda: in_queue(bus) == (0, 1), what="the status unacked")
            wait_for(lambda: acks(bus, EXPRESS_QUEUE) >= 2, what="the localisation and the hazard acked")
            worker.send_signal(signal.SIGKILL)
            worker.wait(30)
        worker = bus.spawn_worker()
        wait_for(lambda: in_queue(bus) == (0, 0), timeout=60, what="the status handled again and acked")
        sentinel = explorer.publish("hazard", hazard(1))  # announced after anything sent before it
        after = notifications_until(warden, lambda note: note.event == sentinel)
        assert [n.event for n in after] == [sentinel], "the hazard was marked announced: not sent twice"
    finally:
        worker.send_signal(signal.SIGTERM)
        worker.wait(60)
    assert bus.count("status") == 1 and bus.count("hazard") == 2, "stored once each"
    duplicates = bus.with_store(lambda store: store.events.duplicates("explorer1"))
    assert [(d.seq, d.redelivered) for d in duplicates] == [(low.seq, True)]
    assert bus.gaps() == []


class Crashed(BaseException):
    """What kills the worker in the middle of a message (an error would be dead-lettered as
    ``internal-error``; a BaseException ends the consumer as a crash would)."""


class CrashesOn:
    """A batch check that dies on one message id, every time, before anything is stored."""

    def __init__(self, message_id: str) -> None:
        self.message_id = message_id
        self.attempts = 0

    async def check(self, accepted: Sequence[Accepted]) -> dict[int, Rejected]:
        if any(item.event.message_id == self.message_id for item in accepted):
            self.attempts += 1
            raise Crashed(self.message_id)
        return {}


async def on_express_lane(
    bus: Bus, connection: aio_pika.abc.AbstractConnection, store: Repositories, **options: Any
) -> tuple[aio_pika.abc.AbstractChannel, IngestConsumer]:
    """A consumer of the express lane on a channel of its own, as the worker makes it, with ``options``."""
    channel = await connection.channel(publisher_confirms=True)
    await channel.set_qos(prefetch_count=16)
    consumer = IngestConsumer(
        channel,
        await channel.get_queue(EXPRESS_QUEUE),
        store.events,
        store.rejections,
        max_message_bytes=bus.settings.max_message_bytes,
        **options,
    )
    return channel, consumer


async def express_consumer(
    bus: Bus, check: CrashesOn
) -> tuple[aio_pika.abc.AbstractConnection, IngestConsumer]:
    """The express lane's consumer, with ``check`` and a limit of LIMIT."""
    connection = await aio_connect(bus.admin_url)
    store = repositories_for(bus.settings)
    await store.open()
    _, consumer = await on_express_lane(
        bus, connection, store, checks=[check], attempts=AttemptLimit(store.attempts, LIMIT)
    )
    connection.close_callbacks.add(lambda *_: asyncio.ensure_future(store.close()))
    return connection, consumer


LIMIT = 3


async def dies_in_hand(bus: Bus, check: CrashesOn) -> None:
    """An express consumer that dies on ``check``'s message, its connection then closed as a dead
    worker's is: the broker delivers what it had in hand again."""
    connection, consumer = await express_consumer(bus, check)
    with pytest.raises(Crashed):
        await asyncio.wait_for(consumer.run(), 30)
    await connection.close()


async def runs_while(bus: Bus, check: CrashesOn, explorer: RobotClient, hazards: int) -> None:
    """An express consumer running while ``explorer`` reports one more hazard, until the store
    holds ``hazards`` hazards."""
    connection, consumer = await express_consumer(bus, check)
    lane = asyncio.create_task(consumer.run())
    try:
        await asyncio.to_thread(explorer.publish, "hazard", hazard(hazards))
        what = f"{hazards} hazards stored"
        await asyncio.to_thread(wait_for, lambda: bus.count("hazard") == hazards, 30, what)
    finally:
        await consumer.stop()
        await lane
        await connection.close()


def test_a_message_is_counted_under_one_key_at_every_delivery_with_or_without_a_message_id() -> None:
    def delivery(tag: int, body: bytes, message_id: str | None = None) -> Any:
        return SimpleNamespace(
            user_id="explorer1",
            exchange="explorer1.events",
            routing_key="explorer1.hazard",
            message_id=message_id,
            body=body,
            delivery_tag=tag,
        )

    assert attempt_key(delivery(1, b"{}")) == attempt_key(delivery(7, b"{}")), "no id: still one message"
    assert attempt_key(delivery(1, b"{}", "m1")) == attempt_key(delivery(9, b"{}", "m1"))
    assert attempt_key(delivery(1, b"{}", "m1")) != attempt_key(delivery(1, b"[]", "m1")), "an id reused"


def test_a_message_the_worker_dies_on_is_set_aside_after_the_limit(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    asyncio.run(declare_with_url(bus.admin_url, [core_topology()]))
    poison = explorer.publish("hazard", hazard(0))
    check = CrashesOn(poison.message_id)

    for _ in range(1 + LIMIT):  # the first delivery, and LIMIT redeliveries: each one dies
        asyncio.run(dies_in_hand(bus, check))
    assert check.attempts == 1 + LIMIT

    asyncio.run(runs_while(bus, check, explorer, hazards=1))  # the next hazard is stored
    assert check.attempts == 1 + LIMIT, "not begun again"
    [letter] = bus.dead_letters()
    assert (letter.message_id, letter.reason) == (str(poison.message_id), "delivery-limit")
    assert f"{1 + LIMIT} times" in letter.detail
    assert [r.seq for r in bus.find()] == [poison.seq + 1], "the poison was never stored; the next was"
    # every consumer is gone, so nothing is unacked: the exact count (the HTTP API's lags seconds)
    assert bus.ready_messages(EXPRESS_QUEUE) == 0


def test_an_event_stored_from_a_redelivery_says_so(bus: Bus) -> None:
    """A worker dies with a hazard in hand; the next takes it from the broker again and stores it
    marked redelivered (RabbitMQ keeps a queue's order only for messages not redelivered, so the
    mark says which events may have come after later ones). The hazard after it is not marked."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    asyncio.run(declare_with_url(bus.admin_url, [core_topology()]))
    first = explorer.publish("hazard", hazard(0))
    check = CrashesOn(first.message_id)

    asyncio.run(dies_in_hand(bus, check))
    check.message_id = "none"  # the next worker stores it
    asyncio.run(runs_while(bus, check, explorer, hazards=2))  # and one more
    assert check.attempts == 1
    assert [(r.seq, r.redelivered) for r in bus.find()] == [(first.seq, True), (first.seq + 1, False)]


class Handled:
    """A batch service that writes down, in one shared log, which consumer handled which event;
    ``hold`` keeps the consumer's first batch in hand until released."""

    def __init__(self, name: str, log: list[str], hold: asyncio.Event | None = None) -> None:
        self.name, self.log, self.hold = name, log, hold
        self.in_hand = asyncio.Event()

    async def handle(self, accepted: Sequence[Accepted]) -> int:
        self.log.extend(f"{self.name}:{item.event.seq}" for item in accepted)
        if self.hold is not None:
            self.in_hand.set()
            await self.hold.wait()
            self.hold = None
            self.log.append(f"{self.name} done")
        return 0


def test_a_worker_handing_the_express_lane_over_finishes_its_batch_before_the_next_gets_any(
    bus: Bus,
) -> None:
    """The express lane's single active consumer is the hazard service's only lock: a consumer that
    stops keeps the lane until its batch is done (no cancel first), so the next one starts after it.
    Events published while it finishes still come to it, and go to the next once its channel closes."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    first = explorer.publish_many([("hazard", hazard(0)), ("hazard", hazard(1))])

    async def hand_over() -> tuple[list[str], list[Event]]:
        connection = await aio_connect(bus.admin_url)
        store = repositories_for(bus.settings)
        await store.open()
        log: list[str] = []
        release = asyncio.Event()

        async def consumer(service: Handled) -> tuple[aio_pika.abc.AbstractChannel, IngestConsumer]:
            return await on_express_lane(
                bus, connection, store, services=[service], batch_size=1, exclusive=True
            )

        try:
            leaving = Handled("leaving", log, hold=release)
            leaving_channel, leaving_lane = await consumer(leaving)
            leaving_run = asyncio.create_task(leaving_lane.run())
            await asyncio.wait_for(leaving.in_hand.wait(), 30)  # the active consumer, one batch in hand
            next_channel, next_lane = await consumer(Handled("next", log))
            next_run = asyncio.create_task(next_lane.run())
            await leaving_lane.stop()
            later = await asyncio.to_thread(
                explorer.publish_many, [("hazard", hazard(2)), ("hazard", hazard(3))]
            )
            # both taken by a consumer (the one leaving: still the lane's only active consumer)
            await asyncio.to_thread(wait_for, lambda: bus.ready_messages(EXPRESS_QUEUE) == 0, 30, "delivered")
            release.set()
            await asyncio.wait_for(leaving_run, 30)
            await leaving_channel.close()  # what it received and did not handle goes back, in order
            handled = len(first) + len(later) + 1  # each event once, and the one leaving said done
            await asyncio.to_thread(wait_for, lambda: len(log) >= handled, 30, "every event handled")
            await next_lane.stop()
            await asyncio.wait_for(next_run, 30)
            await next_channel.close()
            return log, later
        finally:
            await connection.close()
            await store.close()

    log, later = asyncio.run(hand_over())
    assert log == [
        f"leaving:{first[0].seq}",
        "leaving done",
        *(f"next:{event.seq}" for event in [first[1], *later]),
    ], "the next consumer began only once the one leaving was done, and took the rest in order"


@contextmanager
def operators_copies_refused(bus: Bus) -> Iterator[None]:
    """While it lasts, the broker nacks every hazard announcement's copy for the operators."""
    connection = blocking_connection(bus.admin_url)
    try:
        channel = connection.channel()
        channel.queue_declare(REFUSING_QUEUE, arguments={"x-max-length": 0, "x-overflow": "reject-publish"})
        channel.queue_bind(REFUSING_QUEUE, NOTIFY_EXCHANGE, notification_routing_key("hazard"))
        yield
        channel.queue_delete(REFUSING_QUEUE)
    finally:
        connection.close()


def test_the_wardens_hear_of_hazards_while_the_copies_for_the_operators_wait(bus: Bus) -> None:
    """Only the wardens' copies are on a hazard's way: the operators' copy and the mark follow, and
    the lane is acked once they are done. While the broker refuses the operators' copies, both
    hazards reach the warden, once each; they stay held and unacked until the copies go through."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    operator = bus.add("operator1", role=Role.OPERATOR)
    with bus.worker() as worker:
        warden.publish("localisation", {"localised": True})
        wait_for(lambda: localised(bus), what="warden1 localised")
        assert worker.context is not None
        stats = worker.context.stats
        with operators_copies_refused(bus):
            first = explorer.publish("hazard", hazard(0))
            [note] = warden.receive(1, timeout=30)
            assert note.event == first and note.received_at <= note.stored_at <= note.notified_at
            wait_for(lambda: stats.store_retries >= 1, what="the operators' copy refused and tried again")
            second = explorer.publish("hazard", hazard(1))
            [note] = warden.receive(1, timeout=30)
            assert note.event == second, "the next hazard did not wait for the first one's copy"
            wait_for(lambda: in_queue(bus, EXPRESS_QUEUE) == (0, 2), what="both hazards in hand, unacked")
            states = [h.state for h in bus.with_store(lambda store: store.hazards.open_hazards(None))]
            assert states == [HazardState.HELD, HazardState.HELD], "marked only once the copies are confirmed"
        wait_for(lambda: in_queue(bus, EXPRESS_QUEUE) == (0, 0), what="both acked once the copies went")
        states = [h.state for h in bus.with_store(lambda store: store.hazards.open_hazards(None))]
        assert states == [HazardState.ANNOUNCED, HazardState.ANNOUNCED]
        sentinel = explorer.publish("hazard", hazard(2))
        after = notifications_until(warden, lambda note: note.event == sentinel)
        assert [n.event for n in after] == [sentinel], "neither was announced to the warden again"
    # a copy the broker nacked reached the queues that took it: the operators' inbox may hold a
    # repeat (the same message id, which consumers skip), never a hazard missing or out of order
    copies = read_inbox(
        operator.amqp_url, operator.name, lambda got: any(c.event == sentinel for c in got), 30
    )
    firsts = list(dict.fromkeys(c.event.seq for c in copies if c.topic.value == "hazard"))
    assert firsts == [first.seq, second.seq, sentinel.seq]


def test_a_hazard_behind_a_backlog_of_telemetry_is_stored_and_announced_before_it(bus: Bus) -> None:
    """After an outage: 10,000 status events wait in the shard, then a hazard. The hazard reaches
    the warden, announced before the last of the telemetry queued ahead of it was even taken from
    the broker (the store's ``announced_at`` and ``received_at``)."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        wait_for(lambda: localised(bus), what="warden1 localised")
    backlog = 10_000
    for _ in range(backlog // 1000):
        explorer.publish_many([("status", status())] * 1000)
    sent = explorer.publish("hazard", hazard(0))
    with bus.worker():
        [note] = warden.receive(1, timeout=60)
        assert note.event == sent
        wait_for(lambda: bus.count("status") == backlog, 120, "the backlog stored")
    [announced] = bus.with_store(lambda store: store.hazards.open_hazards(None))
    last = bus.find(EventQuery(type="status", newest_first=True, limit=1))[0]
    assert announced.announced_at is not None
    assert announced.announced_at < last.received_at, "the hazard waited for the telemetry ahead of it"


def _consumers(bus: Bus) -> Counter[str]:
    """Consumers by queue, as the broker lists them (a single active consumer's waiting ones too)."""
    return Counter(consumer["queue"]["name"] for consumer in bus.api.list_consumers(bus.vhost))


def test_shard_0_taken_again_after_the_express_lane_failed_to_start_has_one_consumer(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Taking shard 0 starts its queue's consumer, then the express lane. When the lane fails to
    start, the heartbeat lets the shard go and takes it again at the next beat: the first consumer
    must have stopped, or each failed beat would leave one more consumer on the shard's queue."""
    starts: list[str] = []
    start = ExpressLane.start

    async def fails_once(lane: ExpressLane) -> None:
        starts.append("start")
        if len(starts) == 1:
            raise RuntimeError("the express lane could not connect")
        await start(lane)

    monkeypatch.setattr(ExpressLane, "start", fails_once)
    # shard 0 held by a worker of another host until this worker runs, so that this worker takes
    # it on a heartbeat (where a failed start is logged and tried again at the next beat)
    other = "elsewhere:1:worker-x"

    def hold_shard_0(for_s: float) -> bool:
        now = datetime.now(timezone.utc)
        return bus.with_store(
            lambda store: store.leases.acquire_lease(
                shard_lease(0), other, now + timedelta(seconds=for_s), now
            )
        )

    assert hold_shard_0(600)
    with bus.worker() as worker:
        assert worker.context is not None and not worker.context.shards.held
        assert hold_shard_0(0)  # the other worker's lease ends
        wait_for(lambda: _consumers(bus)[EXPRESS_QUEUE] == 1, 60, "the express lane consuming")
        assert len(starts) == 2
        assert _consumers(bus)[ingest_shard_queue(0)] == 1


def _connected_since(bus: Bus, at_ms: float) -> int:
    """How many connections the worker's account opened on the test's virtual host since ``at_ms``."""
    connections = bus.api.list_vhost_connections(bus.vhost)
    return sum(c.get("user") == "fleetbus" and c.get("connected_at", 0) > at_ms for c in connections)


def test_a_worker_whose_express_lane_lost_its_channel_before_an_ack_handles_the_batch_again_and_goes_on(
    bus: Bus,
) -> None:
    """A hazard's operators' copy refused, its batch waits unacked; the broker then closes the
    worker's connections. The copy goes through on the new channel, the ack on the old one cannot:
    the broker gives the hazard again, and the worker handles it again (stored once, announced
    once) and goes on, where its lane used to stop by itself and the worker with it."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    worker = bus.spawn_worker("--no-recorder")
    try:
        warden.publish("localisation", {"localised": True})
        wait_for(lambda: localised(bus), what="warden1 localised")
        with operators_copies_refused(bus):
            first = explorer.publish("hazard", hazard(0))
            [note] = warden.receive(1, timeout=30)
            assert note.event == first
            wait_for(lambda: in_queue(bus, EXPRESS_QUEUE) == (0, 1), what="the hazard in hand, unacked")
            closed_at = time.time() * 1000
            assert bus.api.close_connections_of("fleetbus", "the test closes the worker's connections")
            wait_for(lambda: _connected_since(bus, closed_at) == 2, what="the worker connected again")
        wait_for(lambda: in_queue(bus, EXPRESS_QUEUE) == (0, 0), what="the hazard handled again and acked")
        sentinel = explorer.publish("hazard", hazard(1))
        [next_note] = warden.receive(1, timeout=30)
        assert next_note.event == sentinel, "the first hazard was not announced again"
        assert worker.poll() is None, "the worker goes on"
        assert bus.count("hazard") == 2
    finally:
        worker.send_signal(signal.SIGTERM)
        code = worker.wait(60)
    printed = b"".join(path.read_bytes() for path in bus.settings.data_dir.glob("worker-*.log")).decode()
    assert code == 0, printed
    assert "channel closed before its ack" in printed, printed
