"""The robot's sender tells a message the broker refused from a broker it cannot reach, for real.

Refused (the broker answered no to this message: access refused, unroutable): set aside in the
outbox's refused list with the reason, raised from the ``publish`` that waits, never sent again,
and the events behind it carry on. Outage (no connection, a lost one, a nack: a queue that
cannot take messages now): the event stays in the outbox and goes again after a jittered,
capped wait; nothing is ever marked refused for it.
"""

from __future__ import annotations

import errno
import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from itertools import pairwise

import pika.exceptions
import pytest

from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.errors import PublishRefused
from fleetbus.publishers.sender import Sender
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import INGEST_EXCHANGE, RobotKind
from fleetbus_dev.local_node import LocalNode
from tests.factories import hazard, status
from tests.link import NetworkLink
from tests.support import Bus, network_link, wait_for

REFUSING_QUEUE = "test.refuses-everything"
COPIES_QUEUE = "test.copies"


def reconnected(robot: RobotClient, link: NetworkLink) -> None:
    """Break the robot's connection, and wait until its sender made a new one through the link."""
    before = link.connections
    link.drop_connections()
    wait_for(lambda: link.connections > before and robot.connected, what="the robot to reconnect")


@contextmanager
def every_publish_nacked(bus: Bus, robot: str) -> Iterator[None]:
    """While it lasts, a queue bound to the robot's exchange refuses everything (``x-max-length`` 0,
    ``reject-publish``), so the broker nacks each of the robot's publishes; another queue keeps a
    copy of each, which counts the robot's tries."""
    connection = blocking_connection(bus.admin_url)
    try:
        channel = connection.channel()
        channel.queue_declare(REFUSING_QUEUE, arguments={"x-max-length": 0, "x-overflow": "reject-publish"})
        channel.queue_declare(COPIES_QUEUE)
        for queue in (REFUSING_QUEUE, COPIES_QUEUE):
            channel.queue_bind(queue, f"{robot}.events", "#")
        yield
        channel.queue_delete(REFUSING_QUEUE)
    finally:
        connection.close()


def test_an_unroutable_event_is_set_aside_and_the_next_one_goes_through(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    with bus.worker():
        bus.api.unbind(bus.vhost, "explorer1.events", INGEST_EXCHANGE, "#", to_exchange=True)
        with pytest.raises(PublishRefused, match=r"unroutable .*NO_ROUTE"):
            explorer.publish("hazard", hazard(0, "Fire"))
        bus.api.bind(bus.vhost, "explorer1.events", INGEST_EXCHANGE, "#", to_exchange=True)
        kept = explorer.publish("hazard", hazard(1, "Gas leak"))
        wait_for(lambda: bus.count("hazard") == 1, what="the second hazard stored")
    [refused] = explorer.outbox.refused()
    assert "NO_ROUTE" in refused.reason and explorer.outbox.pending() == 0, "set aside, not resent"
    assert [r.message_id for r in bus.find()] == [str(kept.message_id)]


def test_an_event_refused_access_is_set_aside_and_connection_losses_refuse_nothing(
    bus: Bus, link_for: list[NetworkLink]
) -> None:
    """The broker caches a channel's permission checks, so each change is seen on a new connection:
    the link breaks the robot's connection, which must never make an event refused."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
    explorer = bus.robot(account, via=link)
    granted = bus.api.get_permissions(bus.vhost, "explorer1")
    assert granted is not None
    with bus.worker():
        first = explorer.publish("hazard", hazard(0, "Fire"))
        bus.api.put_permissions(bus.vhost, "explorer1", granted["configure"], "^$", granted["read"])
        reconnected(explorer, link)
        with pytest.raises(PublishRefused, match="ACCESS_REFUSED"):
            explorer.publish("hazard", hazard(1, "Gas leak"))
        bus.api.put_permissions(
            bus.vhost, "explorer1", granted["configure"], granted["write"], granted["read"]
        )
        reconnected(explorer, link)
        last = explorer.publish("hazard", hazard(2, "Smoke"))
        wait_for(lambda: bus.count("hazard") == 2, what="the first and the last hazard stored")
    [refused] = explorer.outbox.refused()
    assert refused.type == "hazard" and "403" in refused.reason, "only the refused one, once"
    assert explorer.outbox.pending() == 0
    assert sorted(r.message_id for r in bus.find()) == sorted(str(e.message_id) for e in (first, last))


def test_a_nacked_event_is_kept_and_tried_again_after_a_capped_jittered_wait(bus: Bus) -> None:
    """A nack says a queue cannot take the message now, not that the message is wrong: it is not
    refused. (The sender used to send it again at once, as fast as the broker answered: 3,714
    tries in 3 s here, and ``publish`` waited out its whole confirm timeout.)"""
    explorer = bus.robot(
        bus.add("explorer1", kind=RobotKind.EXPLORER), confirm_timeout=60, max_reconnect_delay=0.5
    )
    with every_publish_nacked(bus, "explorer1"):
        started = time.monotonic()
        explorer.publish("status", status(80))
        assert time.monotonic() - started < 30, "publish returned once the broker nacked it"
        assert explorer.outbox.pending() == 1 and explorer.outbox.refused() == []
        wait_for(lambda: bus.ready_messages(COPIES_QUEUE) >= 4, what="the robot to try again")
        window_starts, tries_before = time.monotonic(), bus.ready_messages(COPIES_QUEUE)
        wait_for(lambda: time.monotonic() - window_starts >= 3.0, what="3 s of nacks")
        tries = bus.ready_messages(COPIES_QUEUE) - tries_before
        assert tries <= 40, f"{tries} tries in 3 s: the sender did not wait between them"
        assert explorer.outbox.pending() == 1 and explorer.outbox.refused() == [], "still kept"
    assert explorer.flush(30), "taken once the queue takes messages again"
    assert explorer.outbox.refused() == []


@pytest.mark.parametrize("robots", [3])
def test_a_team_reconnects_after_a_broker_kill_at_jittered_capped_times(
    killable_bus: Bus, killable_node: LocalNode, link_for: list[NetworkLink], robots: int
) -> None:
    """While the broker is dead, each robot's attempts reach its link (which cannot forward them):
    the waits between them vary (full jitter, not a fixed schedule the whole team shares) and stay
    under the cap. Once the broker is back, every robot reconnects and nothing was refused."""
    bus = killable_bus
    cap = 1.0
    accounts = [bus.add(f"explorer{i}", kind=RobotKind.EXPLORER) for i in range(robots)]
    team = []
    for account in accounts:
        link = network_link(link_for, account)
        team.append((bus.robot(account, via=link, max_reconnect_delay=cap), link))
    with bus.worker():
        killable_node.kill()
        published = [robot.publish("hazard", hazard(i)) for i, (robot, _) in enumerate(team)]
        wait_for(
            lambda: all(len(link.attempts) >= 14 for _, link in team),
            timeout=60,
            what="a dozen attempts from each robot while the broker is dead",
        )
        waits = [[b - a for a, b in pairwise(link.attempts[4:14])] for _, link in team]
        killable_node.up()
        for robot, _ in team:
            assert robot.flush(60), f"{robot.robot_id} did not deliver after the restart"
        wait_for(lambda: bus.count("hazard") == robots, timeout=60, what="every robot's hazard stored")
    for robot_waits in waits:
        # past the fourth attempt the bound is the cap: each wait is drawn between 0 and 1 s
        assert max(robot_waits) < cap + 2.0, f"a wait of {max(robot_waits):.2f} s: the cap is {cap} s"
        assert max(robot_waits) - min(robot_waits) > 0.2 * cap, f"waits that do not vary: {robot_waits}"
    assert all(robot.outbox.refused() == [] for robot, _ in team), "an outage refuses nothing"
    assert sorted(r.message_id for r in bus.find()) == sorted(str(e.message_id) for e in published)


def test_nacks_in_a_row_make_the_sender_reconnect_and_the_event_stays(bus: Bus) -> None:
    """A channel that keeps nacking (RabbitMQ 3.10 after a quorum queue's leader moved, on a
    cluster) is left for a new connection after NACKS_BEFORE_RECONNECT nacks; the event is kept."""
    explorer = bus.robot(
        bus.add("explorer1", kind=RobotKind.EXPLORER), confirm_timeout=60, max_reconnect_delay=0.2
    )
    with every_publish_nacked(bus, "explorer1"):
        explorer.publish("status", status(80))
        wait_for(
            lambda: "times in a row" in (explorer.last_error or ""),
            timeout=30,
            what="a reconnection after nacks",
        )
        assert explorer.outbox.pending() == 1 and explorer.outbox.refused() == []
    assert explorer.flush(30), "taken once the queue takes messages again"


def test_a_connection_lost_while_waiting_after_a_nack_leaves_the_sender_running(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What handling one failure raises (the connection lost in the wait after a nack) is handled
    too: the sender thread goes on, connects again, and sends the event once the queue takes it.
    (The thread used to end there, while the client still said connected.)"""
    lost: list[float] = []
    wait_after_nack = Sender._pause

    def pause(sender: Sender, delay: float) -> None:
        if not lost:
            lost.append(delay)
            raise pika.exceptions.StreamLostError("the connection was lost while waiting")
        wait_after_nack(sender, delay)

    monkeypatch.setattr(Sender, "_pause", pause)
    explorer = bus.robot(
        bus.add("explorer1", kind=RobotKind.EXPLORER), confirm_timeout=60, max_reconnect_delay=0.2
    )
    with every_publish_nacked(bus, "explorer1"):
        explorer.publish("status", status(80))
        wait_for(lambda: "lost while waiting" in (explorer.last_error or ""), what="the failure handled")
        assert explorer.outbox.pending() == 1 and explorer.outbox.refused() == []
    assert explorer.flush(30), "sent once the queue takes messages again: the sender still runs"


def test_an_outbox_that_cannot_settle_is_tried_again_without_sending_anything_again(
    bus: Bus, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A full disk while the confirmed events leave the outbox is the outbox's fault, not the
    network's: the sender keeps its connection, sends nothing again, says it once and keeps it in
    ``last_error``, and settles them once the disk has room."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER), max_reconnect_delay=0.5)
    full = True

    real = {name: getattr(explorer.outbox, name) for name in ("_delete_segment", "_remove")}
    tries: list[str] = []

    def no_space_for(name: str, *args: object, **kwargs: object) -> None:
        if full:
            tries.append(name)
            raise OSError(errno.ENOSPC, "No space left on device")
        real[name](*args, **kwargs)

    for name in real:  # what a settle writes: a segment deleted, or rewritten without the settled
        monkeypatch.setattr(explorer.outbox, name, lambda *a, _n=name, **k: no_space_for(_n, *a, **k))

    caplog.set_level(logging.INFO, logger="fleetbus.robot")
    failures = explorer._sender._failures
    with bus.admin_channel() as channel:
        channel.queue_declare(COPIES_QUEUE)
        channel.queue_bind(COPIES_QUEUE, "explorer1.events", "#")
        explorer.publish_many([("status", status(80 - i)) for i in range(10)], wait=False)
        wait_for(lambda: "No space left" in (explorer.last_error or ""), what="the outbox's error")
        # it tried again and again: reconnecting and sending the window again after each, it had
        # sent them once more for every try
        wait_for(lambda: len(tries) >= 4, what="the settle tried again three times")
        assert bus.ready_messages(COPIES_QUEUE) == 10, "each sent once"
        assert explorer.connected and explorer._sender._failures == failures, "no reconnect"
        assert explorer.outbox.pending() == 10
        said = [r for r in caplog.records if "could not settle" in r.getMessage()]
        assert [r.levelno for r in said] == [logging.ERROR], "said once"

        full = False
        wait_for(lambda: explorer.outbox.pending() == 0, what="the events settled once there is room")
        assert bus.ready_messages(COPIES_QUEUE) == 10 and explorer.last_error is None
        assert any("the outbox works again" in r.getMessage() for r in caplog.records)


def test_an_outbox_file_that_cannot_be_read_holds_the_sender_back_without_reconnecting(
    bus: Bus, link_for: list[NetworkLink], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A body file gone missing (or unreadable) when the sender takes the next window: it waits
    and tries again, connected, and sends what waits once the file is back."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    link = network_link(link_for, account)
    explorer = bus.robot(account, via=link, max_reconnect_delay=0.5)
    link.cut()
    wait_for(lambda: not explorer.connected, what="the robot cut off")
    explorer.publish_many([("status", status(80 - i)) for i in range(5)], wait=False)
    real = explorer.outbox._entry
    missing = True
    tries: list[object] = []

    def entry(*args: object) -> object:
        if missing:
            tries.append(args)
            raise FileNotFoundError(2, "No such file or directory", "blob-x.json")
        return real(*args)

    monkeypatch.setattr(explorer.outbox, "_entry", entry)
    with bus.admin_channel() as channel:
        channel.queue_declare(COPIES_QUEUE)
        channel.queue_bind(COPIES_QUEUE, "explorer1.events", "#")
        link.restore()
        wait_for(lambda: explorer.connected, what="the robot back")
        failures = explorer._sender._failures
        wait_for(lambda: "could not read the events" in (explorer.last_error or ""), what="the error")
        wait_for(lambda: len(tries) >= 3, what="the take tried again twice")
        assert explorer.connected and explorer._sender._failures == failures, "no reconnect"
        assert bus.ready_messages(COPIES_QUEUE) == 0 and explorer.outbox.pending() == 5
        missing = False
        assert explorer.flush(10)
        assert bus.ready_messages(COPIES_QUEUE) == 5 and explorer.last_error is None
