"""Outages a robot team meets in the field, each made for real, and what arrived counted exactly.

The broker itself is killed in ``test_broker_restart.py``; here the workers stop, robots lose
the network or are killed, a confirm is lost on the way back, MongoDB goes away.
"""

from __future__ import annotations

import errno
import itertools
import json
import logging
import signal
import socket
import threading
import time
from dataclasses import replace
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from fleetbus.broker.accounts import Account
from fleetbus.publishers import storage as storage_module
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.closing import CLOSE_WAIT_S
from fleetbus.publishers.errors import BrokerUnavailable, LoginRefused
from fleetbus.publishers.outbox import OutboxWriteFailed, Overflow, TypePolicy
from fleetbus.publishers.state_lock import RobotStateInUse
from fleetbus.schemas.envelope import Event, build_event, encode_event
from fleetbus.schemas.routing import EXPRESS_QUEUE, INGEST_QUEUE, RobotKind
from fleetbus.workers.store.base import EventQuery
from fleetbus_dev.local_node import LocalNode
from tests.factories import hazard, status
from tests.link import NetworkLink
from tests.store.mongodb import MONGOECO_PYTHON, NO_MONGODB, MongoecoServer
from tests.support import (
    Bus,
    Publishing,
    assert_stored_once_in_order,
    keys,
    network_link,
    read_line,
    wait_for,
)
from tests.test_cli import fleetbus

#: How long the workers stay stopped while the robots keep publishing: a few seconds in the default
#: suite, the full minute under ``slow``. What is proven (nothing stored meanwhile, the queues
#: hold it all, everything stored once and in order after) does not depend on the length.
WORKER_OUTAGES = [pytest.param(3.0, id="3s"), pytest.param(60.0, id="60s", marks=pytest.mark.slow)]
#: Events each robot publishes, at least, while its workers are stopped.
OUTAGE_EVENTS = 50


@pytest.mark.parametrize("outage_s", WORKER_OUTAGES)
def test_workers_stopped_while_robots_publish(bus: Bus, outage_s: float) -> None:
    robots = [bus.robot(bus.add(f"explorer{i}", kind=RobotKind.EXPLORER)) for i in (1, 2)]
    worker = bus.spawn_worker()
    try:
        publishing = [Publishing(robot).start() for robot in robots]
        wait_for(lambda: bus.count() >= 100, what="events stored before the workers stop")
        worker.send_signal(signal.SIGTERM)
        assert worker.wait(60) == 0, "the worker stops cleanly on SIGTERM"
        stored = bus.count()
        before = [len(p.sent) for p in publishing]
        outage_ends = time.monotonic() + outage_s
        wait_for(
            lambda: time.monotonic() >= outage_ends,
            timeout=outage_s + 10,
            what=f"{outage_s:g} s of robots publishing with no worker",
        )
        # publishing all along, each robot at its own pace (a rate would measure the machine's load)
        pairs = list(zip(publishing, before, strict=True))
        wait_for(
            lambda: all(len(p.sent) >= count + OUTAGE_EVENTS for p, count in pairs),
            what=f"each robot publishing {OUTAGE_EVENTS} events while no worker ran",
        )
        sent = {p.robot.robot_id: p.stop() for p in publishing}
        for robot in robots:
            assert robot.flush(30)
        total = sum(len(seqs) for seqs in sent.values())
        assert bus.count() == stored, "nothing was stored while no worker ran"
        waiting = bus.ready_messages(INGEST_QUEUE) + bus.ready_messages(EXPRESS_QUEUE)
        assert waiting == total - stored, "the queues hold every event since"
        worker = bus.spawn_worker()
        wait_for(lambda: bus.count() == total, timeout=120, what=f"the worker to catch up to {total}")
    finally:
        worker.send_signal(signal.SIGTERM)
        worker.wait(60)
    for robot_id, seqs in sent.items():
        assert_stored_once_in_order(bus, robot_id, seqs)
    assert bus.gaps() == [] and bus.ready_messages(INGEST_QUEUE) == bus.ready_messages(EXPRESS_QUEUE) == 0


def test_robot_process_killed_with_1000_events_in_its_outbox(bus: Bus, link_for: list[NetworkLink]) -> None:
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
    link.cut()
    with bus.worker():
        robot = bus.spawn_robot(link.url(account.amqp_url), "--events", "1000")
        read_line(robot, "queued 1000")
        robot.kill()
        robot.wait(30)
        outbox = bus.outbox("explorer1")
        assert outbox.pending() == 1000, "all 1000 wait on disk after the kill"
        waiting = [(entry.epoch, entry.seq) for entry in outbox.entries()]
        outbox.close()
        assert bus.count() == 0

        link.restore()
        robot = bus.spawn_robot(link.url(account.amqp_url), "--drain")
        try:
            read_line(robot, "drained", timeout=120)
        finally:
            robot.terminate()
            robot.wait(30)
        wait_for(lambda: bus.count() == 1000, timeout=60, what="the 1000 events in the store")
    assert [seq for _, seq in waiting] == list(range(1000)) and len({epoch for epoch, _ in waiting}) == 1
    assert_stored_once_in_order(bus, "explorer1", waiting)  # sent by the next run as the first built them


def test_a_lost_confirm_makes_a_resend_not_a_second_record(bus: Bus, link_for: list[NetworkLink]) -> None:
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
    explorer = bus.robot(account, via=link)
    with bus.worker() as worker:
        link.mute_replies()  # the broker takes the events; its confirms never reach the robot
        sent = explorer.publish_many([("hazard", hazard(i)) for i in range(20)], wait=False)
        wait_for(lambda: bus.count() == 20, what="the 20 events stored from the first copy")
        assert explorer.outbox.pending() == 20, "unconfirmed, so still in the outbox"
        link.restore()
        link.drop_connections()  # the robot notices, reconnects and sends its window again
        assert explorer.flush(60)
        wait_for(lambda: worker.stats().duplicates == 20, what="the 20 resent copies recognised")
        duplicates = bus.with_store(lambda store: store.events.duplicates("explorer1"))
    assert bus.count() == 20
    assert sorted(d.seq for d in duplicates) == [e.seq for e in sent]
    assert not any(d.redelivered for d in duplicates), "sent again by the robot, not redelivered"
    assert bus.gaps() == []


def plain_explorer_link(
    bus: Bus, link_for: list[NetworkLink], broker_node: LocalNode | None
) -> tuple[Account, NetworkLink]:
    """explorer1's account with a plain AMQP URL, and a link to the private node's plain listener
    (the link reads AMQP frames: it cannot see into TLS)."""
    if broker_node is None:
        pytest.skip("needs the private node's plain AMQP listener; the run's broker is a configured one")
    ports = broker_node.ports()
    assert ports is not None
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = NetworkLink(ports["amqp"]).start()
    link_for.append(link)
    plain = urlsplit(account.amqp_url)._replace(scheme="amqp", query="").geturl()
    return replace(account, amqp_url=plain), link


def test_a_broker_slow_to_confirm_is_waited_for_and_a_silent_one_is_left(
    bus: Bus, link_for: list[NetworkLink], broker_node: LocalNode | None
) -> None:
    """A loaded broker confirms late but answers: the robot keeps its connection (reconnecting
    would add to the load, a storm with a whole team). One that answers nothing is given up on
    after the confirm timeout, as before. (The link reads the broker's frames to hold its
    confirms, so the robot comes in over the node's plain AMQP listener.)"""
    plain, link = plain_explorer_link(bus, link_for, broker_node)
    explorer = bus.robot(plain, via=link, confirm_timeout=2.0)
    with bus.worker() as worker:
        link.hold_confirms(5)  # two and a half confirm timeouts
        explorer.publish_many([("status", status(90 - i)) for i in range(20)], wait=False)
        assert explorer.flush(60)
        assert link.connections == 1, "the robot waited for the slow confirms on its connection"
        link.hold_confirms(0)
        link.mute_replies()  # now silent
        explorer.publish_many([("status", status(50))], wait=False)
        wait_for(lambda: len(link.attempts) > 1, 30, "the robot leaving the silent broker")
        link.restore()
        assert explorer.flush(60)  # every copy is at the broker; the worker stores them after
        wait_for(lambda: bus.count() == 21, what="the 21 events stored")
        # sentinels: the second is published once the first is stored, so it comes in a later batch
        # (one consumer, batch after batch): every copy sent before the first is counted by then
        explorer.publish("status", status(40))
        wait_for(lambda: bus.count() == 22, what="the first sentinel stored")
        explorer.publish("status", status(30))
        wait_for(lambda: bus.count() == 23, what="the second sentinel stored, after the first one's batch")
        stats = worker.stats()
        assert stats.duplicates <= 1, "only the event in doubt when the broker went silent was sent again"


def test_a_robot_whose_password_was_changed_says_so_once_and_gets_in_again_once_it_is_restored(
    bus: Bus, tmp_path: Path, link_for: list[NetworkLink], caplog: pytest.LogCaptureFixture
) -> None:
    """A refused login is no outage: said once (naming the robot, never the password), kept in
    ``last_error``, raised at once by ``connect()`` and by a service call; the sender keeps
    trying, so a password fixed on the broker lets the robot in without a restart."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
    robot = bus.robot(account, via=link, max_reconnect_delay=0.2)
    before = bus.api.get_user("explorer1")
    assert before is not None
    caplog.set_level(logging.INFO, logger="fleetbus.robot")
    bus.add("explorer1", kind=RobotKind.EXPLORER)  # rotated: the robot's password is the old one
    link.drop_connections()  # the broker keeps a connection made before: the robot reconnects
    said = "the broker refused robot explorer1's credentials"
    wait_for(lambda: said in (robot.last_error or ""), what="the refusal in last_error")
    tries = robot._sender._failures
    wait_for(lambda: robot._sender._failures >= tries + 5, what="five more tries, refused too")
    refusals = [record for record in caplog.records if said in record.getMessage()]
    assert [record.levelno for record in refusals] == [logging.ERROR], "said once, as an error"
    password = urlsplit(account.amqp_url).password
    assert password and password not in caplog.text

    started = time.monotonic()
    robot.publish("hazard", hazard(0))  # cut off: on disk, and back at once
    assert time.monotonic() - started < 2 and robot.outbox.pending() == 1
    with pytest.raises(LoginRefused, match=said):
        robot.wardens()
    other = RobotClient(account.amqp_url, state_dir=tmp_path / "other", connect_timeout=20)
    try:
        started = time.monotonic()
        with pytest.raises(LoginRefused, match=said) as refused:
            other.connect()
        assert time.monotonic() - started < 5, "at the first refusal, not after connect_timeout"
        assert isinstance(refused.value, BrokerUnavailable), "code that catches BrokerUnavailable still does"
    finally:
        other.close(flush_timeout=0)

    tags = before["tags"]
    tags = ",".join(tags) if isinstance(tags, list) else tags
    bus.api.put_user_hash("explorer1", before["password_hash"], before["hashing_algorithm"], tags)
    wait_for(lambda: robot.connected, what="the robot back in with its password restored")
    assert robot.flush(10) and robot.last_error is None
    assert any("accepts robot explorer1's login again" in r.getMessage() for r in caplog.records)


def test_threads_publishing_at_once_are_stored_in_the_order_their_events_were_numbered(
    bus: Bus, link_for: list[NetworkLink]
) -> None:
    """Six threads publish at once, first while the robot is cut off (everything waits in the
    outbox, in number order), then connected: the store receives every event once, in order."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
    robot = bus.robot(account, via=link)
    sent: list[Event] = []  # list.append is atomic

    def publish_from_threads(count: int) -> None:
        def publish() -> None:
            for i in range(count):
                sent.append(robot.publish("status", status(float(i % 100)), wait=False))

        threads = [threading.Thread(target=publish) for _ in range(6)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()

    link.cut()
    wait_for(lambda: not robot.connected, what="the robot cut off")
    publish_from_threads(100)
    waiting = [entry.seq for entry in robot.outbox.entries()]
    inversions = sum(a > b for a, b in itertools.pairwise(waiting))
    assert len(waiting) == 600 and inversions == 0, f"{inversions} inversions in the outbox"
    link.restore()
    with bus.worker():
        publish_from_threads(100)  # connected: each thread's publishes go out while others' do
        assert robot.flush(60)
        wait_for(lambda: bus.count(robot_id="explorer1") == 1200, what="the 1,200 events stored")
    assert_stored_once_in_order(bus, "explorer1", keys(sent))


def test_gaps_are_recorded_and_cleared_when_the_missing_events_arrive(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    events = explorer.build([("status", status(80 - i)) for i in range(10)])
    with bus.worker():
        explorer.enqueue(events[:3] + events[6:])
        wait_for(lambda: bus.count() == 7, what="7 events stored")
        [gap] = bus.gaps("explorer1")
        assert (gap.first, gap.last, gap.size) == (3, 5, 3)
        listed = fleetbus(bus, "query", "gaps", "--json")
        assert listed.returncode == 0, listed.stderr
        assert [json.loads(line)["missing"] for line in listed.stdout.splitlines()] == [3]
        explorer.enqueue(events[4:5])
        wait_for(lambda: bus.count() == 8, what="a late event")
        assert [(g.first, g.last) for g in bus.gaps()] == [(3, 3), (5, 5)]
        explorer.enqueue(events[3:4] + events[5:6])
        wait_for(lambda: bus.count() == 10, what="the last two")
    assert bus.gaps() == []
    assert "0 open gaps" in fleetbus(bus, "query", "gaps").stdout


def test_telemetry_dropped_while_cut_off_shows_as_a_gap(bus: Bus, link_for: list[NetworkLink]) -> None:
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
    policies = {"status": TypePolicy(Overflow.DROP_OLDEST, 10), "hazard": TypePolicy(Overflow.KEEP, 100)}
    explorer = bus.robot(account, via=link, outbox_policies=policies)
    with bus.worker():
        link.cut()
        explorer.publish_many(
            [("status", status(90)) for _ in range(30)] + [("hazard", hazard())], wait=False
        )
        shown = fleetbus(bus, "outbox", "explorer1", "--json")
        assert shown.returncode == 0, shown.stderr
        types = json.loads(shown.stdout)["types"]
        assert (types["status"]["waiting"], types["status"]["dropped"]) == (10, 20)
        assert (types["hazard"]["waiting"], types["hazard"]["dropped"]) == (1, 0)
        link.restore()
        assert explorer.flush(60)
        wait_for(lambda: bus.count() == 11, what="the 10 newest status events and the hazard")
    assert [(g.first, g.last) for g in bus.gaps("explorer1")] == [(0, 19)], "the dropped ones, on record"
    assert [r.seq for r in bus.find(EventQuery(robot_id="explorer1"))] == list(range(20, 31))


def test_a_number_reused_in_its_epoch_is_dead_lettered_and_the_stored_event_kept(bus: Bus) -> None:
    """The same (robot, epoch, seq) with another message id. The robot client cannot send one (each
    start numbers in an epoch of its own, and a resend is the message it built); a hand-made client,
    or a bug, can: it is dead-lettered, naming both messages, and what is stored stays."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    explorer = bus.robot(account)
    with bus.worker():
        first = explorer.publish_many([("hazard", hazard(i, "Fire")) for i in range(3)])
        wait_for(lambda: bus.count() == 3, what="3 hazards")
        forged = build_event("hazard", "explorer1", explorer.epoch, 0, hazard(9, "Gas leak"))
        bus.publish_raw(account, "explorer1.hazard", encode_event(forged), message_id=str(forged.message_id))
        letters = wait_for(lambda: bus.dead_letters(), what="the reused number dead-lettered")
    [letter] = letters
    assert letter.reason == "sequence-reused"
    assert f"reused sequence number 0 of epoch {explorer.epoch}" in letter.detail
    assert str(first[0].message_id) in letter.detail and str(forged.message_id) in letter.detail
    stored = bus.find(EventQuery(robot_id="explorer1"))
    assert [r.message_id for r in stored] == [str(e.message_id) for e in first], "nothing stored changed"
    hazards = bus.with_store(lambda repos: repos.hazards.open_hazards(None))
    assert [h.event["message_id"] for h in hazards] == [str(e.message_id) for e in first], (
        "the reused number registered no hazard"
    )


@pytest.mark.skipif(not MONGOECO_PYTHON.exists(), reason=NO_MONGODB)
def test_mongodb_gone_while_events_arrive(bus: Bus, tmp_path: Path) -> None:
    """The MongoDB server killed mid-stream and started again on its data: nothing acked while it
    was gone, everything stored once it is back."""
    server = MongoecoServer(tmp_path / "mongoeco.log")
    data = tmp_path / "mongo.db"
    url = server.start(path=data)
    port = urlsplit(url).port
    bus.settings = bus.settings.updated(mongodb_url=f"{url}fleetbus")
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    try:
        with bus.worker() as worker:
            first = explorer.publish_many([("status", status(80)) for _ in range(20)])
            wait_for(lambda: bus.count() == 20, what="20 events in MongoDB")
            server.kill()
            second = explorer.publish_many([("status", status(70)) for _ in range(30)])
            wait_for(lambda: worker.stats().store_retries >= 2, what="the worker to retry the store")
            assert bus.ready_messages(INGEST_QUEUE) == 0, "held unacked by the worker, not lost"
            server.start(port=port or 0, path=data)
            wait_for(lambda: bus.count() == 50, timeout=90, what="all 50 events once MongoDB is back")
        assert_stored_once_in_order(bus, "explorer1", keys(first + second))
    finally:
        server.stop()


def no_space_for(name: str, before: float = 0.0) -> object:
    """``write_atomically`` failing with ENOSPC for the outbox file ``name`` (after ``before`` s)."""
    real = storage_module.write_atomically

    def write(path: Path, data: bytes, durable: bool = True) -> None:
        if path.name == name:
            time.sleep(before)
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, data, durable)

    return write


def test_a_publish_whose_outbox_write_fails_after_the_event_was_sent_says_so_and_a_resend_is_stored_once(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The express path puts an event on the wire before its outbox write ends: when the disk is
    full the publish raises OutboxWriteFailed saying it may have been sent, and enqueueing the
    same event again does not make a second record."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    with bus.worker():
        explorer.publish("status", status(90))  # the express lane is open, the outbox empty
        wait_for(lambda: bus.count("status") == 1, what="the first event in the store")
        # the write ends after the sender had time to send (a full disk, and slow); the outbox was
        # emptied, so its next segment is numbered 0 again
        monkeypatch.setattr(storage_module, "write_atomically", no_space_for("seg-000000000000.json", 0.5))
        with pytest.raises(
            OutboxWriteFailed, match="stored none of the 1 events, which the sender had"
        ) as raised:
            explorer.publish("hazard", hazard())
        monkeypatch.undo()
        failed = raised.value
        assert failed.sent and failed.kept == 0 and [e.type.value for e in failed.not_kept] == ["hazard"]
        assert explorer.outbox.pending() == 0
        wait_for(lambda: bus.count("hazard") == 1, what="the hazard that was sent")

        explorer.enqueue(failed.not_kept)  # as the guide says: the same events, not new ones
        assert explorer.flush(timeout=30)
        sentinel = explorer.publish("hazard", hazard())  # on the express lane, behind the resend
        wait_for(lambda: bus.count("hazard") >= 2, what="the hazard sent after the resend stored")
    stored = [(r.epoch, r.seq) for r in bus.find(EventQuery(type="hazard"))]
    assert stored == [(failed.events[0].epoch, failed.events[0].seq), (sentinel.epoch, sentinel.seq)]


def test_a_publish_of_many_whose_outbox_write_fails_on_a_later_segment_sends_only_those_kept(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    with bus.worker():
        # 600 events fill segments 0 and 1 (256 each); the disk is full when segment 2 is written
        monkeypatch.setattr(storage_module, "write_atomically", no_space_for("seg-000000000002.json"))
        with pytest.raises(OutboxWriteFailed, match="only the first 512 of 600 events") as raised:
            explorer.publish_many([("status", status(80)) for _ in range(600)])
        monkeypatch.undo()
        failed = raised.value
        assert (failed.kept, failed.sent, len(failed.not_kept)) == (512, False, 88)
        sentinel = explorer.publish("status", status(70))  # in the robot's shard, behind them
        wait_for(lambda: bus.count("status") >= 513, what="the 512 events kept, and one sent after")
        assert bus.count("status") == 513, "none of those not kept was sent"

        explorer.enqueue(failed.not_kept)
        wait_for(lambda: bus.count("status") == 601, what="all 600 once the rest was enqueued again")
    stored = [r.seq for r in bus.find(EventQuery(type="status"))]
    assert sorted(stored) == sorted([e.seq for e in failed.events] + [sentinel.seq])


def test_close_returns_in_its_time_while_the_broker_holds_the_confirms_and_unlocks_only_a_stopped_sender(
    bus: Bus, link_for: list[NetworkLink], broker_node: LocalNode | None
) -> None:
    """A broker that is alive but does not confirm is waited for up to six confirm timeouts; a
    close() does not wait that long: the sender stops waiting, its events stay in the outbox for
    the next run, and the robot's state is unlocked once the sender has ended."""
    plain, link = plain_explorer_link(bus, link_for, broker_node)
    explorer = bus.robot(plain, via=link, confirm_timeout=5.0, close_timeout=1.0)
    link.hold_confirms(120)
    explorer.publish_many([("status", status(90 - i)) for i in range(20)], wait=False)
    wait_for(lambda: link.held_confirms > 0, what="the window on the wire, its confirms held")

    started = time.monotonic()
    explorer.close()
    assert time.monotonic() - started < 1.0 + 2.0 + 1.0, "close_timeout, and the sender's stop"
    assert not explorer._sender._thread.is_alive()

    again = RobotClient(plain.amqp_url, state_dir=bus.settings.robots_dir)  # the state is unlocked
    try:
        assert again.outbox.pending() == 20, "they wait for the next run"
    finally:
        again.close(flush_timeout=0)


def test_close_returns_in_its_time_when_the_network_went_silent_after_a_service_call(
    bus: Bus, link_for: list[NetworkLink], broker_node: LocalNode | None
) -> None:
    """A service call opened the calling thread's own connection; then nothing the broker sends
    reaches the robot any more (no reset: a silent network). Closing that connection waits for the
    broker's answer for a moment only, then drops the socket, where it waited for the heartbeat."""
    plain, link = plain_explorer_link(bus, link_for, broker_node)
    explorer = bus.robot(plain, via=link, close_timeout=1.0)
    with bus.worker():
        assert explorer.wardens(timeout=10) == []
        link.mute_replies()
        started = time.monotonic()
        explorer.close()
    assert time.monotonic() - started < 1.0 + 2.0 + CLOSE_WAIT_S + 1.0
    assert not explorer._sender._thread.is_alive(), "the sender closed its connection in time too"


def test_a_sender_that_cannot_stop_in_time_keeps_the_robots_state_locked_until_it_ends(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A broker that takes the TCP connection and never answers holds the sender in pika's
    connection handshake, which the stop cannot cut short: close() returns all the same, says so,
    and the robot's state stays locked until the sender ends (it would write into files a new
    client owns)."""
    silent = socket.create_server(("127.0.0.1", 0))  # the kernel accepts; nobody answers
    accepted: socket.socket | None = None
    try:
        url = f"amqp://explorer1:secret@127.0.0.1:{silent.getsockname()[1]}/"
        robot = RobotClient(url, state_dir=tmp_path, close_timeout=0.5, durable=False)
        robot.start()
        silent.settimeout(30)
        accepted, _ = silent.accept()  # the sender is in its first connection attempt
        started = time.monotonic()
        with caplog.at_level(logging.ERROR, logger="fleetbus.robot"):
            robot.close()
        assert time.monotonic() - started < 0.5 + 2.0 + 1.0
        assert "did not stop" in caplog.text
        assert robot._sender._thread.is_alive()
        with pytest.raises(RobotStateInUse):
            RobotClient(url, state_dir=tmp_path)
        wait_for(lambda: not robot._sender._thread.is_alive(), 60, "the sender's attempt ending")
        wait_for(lambda: robot._lock._fd is None, 5, "the state unlocked")
        RobotClient(url, state_dir=tmp_path).close()
    finally:
        if accepted is not None:
            accepted.close()
        silent.close()
