"""The broker killed with SIGKILL and restarted: workers and robots carry on, nothing lost or doubled.

These tests run on a private node of their own (``killable_node``), not the suite's shared one.
"""

from __future__ import annotations

import time
from datetime import timedelta

import pytest

from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventQuery
from fleetbus_dev.local_node import LocalNode
from tests.factories import hazard, status
from tests.support import Bus, Publishing, assert_stored_once_in_order, wait_for


def test_broker_killed_and_restarted_under_load(killable_bus: Bus, killable_node: LocalNode) -> None:
    """Events reach the store exactly once, in order, across a SIGKILL of the broker.

    (A notification across a broker kill: the Table 6 test below.)
    """
    bus = killable_bus
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER), connect_timeout=60)
    with bus.worker():
        before = explorer.publish_many([("status", status(80)) for _ in range(100)])
        wait_for(lambda: bus.count("status") == 100, what="100 events before the kill")
        killable_node.kill()
        killable_node.up()
        # the robot reconnects and resends its window; the worker's connection recovers by itself
        after = explorer.publish_many([("status", status(70)) for _ in range(100)])
        wait_for(lambda: bus.count("status") == 200, timeout=120, what="200 events after the restart")
    sent = [e.seq for e in before + after]
    assert [r.seq for r in bus.find(EventQuery(type="status"))] == sent, "each once, in order"


def test_the_recorder_records_again_after_the_broker_restarts(
    killable_bus: Bus, killable_node: LocalNode
) -> None:
    """The recorder's connection comes back by itself after a SIGKILL of the broker, and what it
    held unacked then is redelivered and recorded once."""
    bus = killable_bus
    robot = bus.add("rec-restart")
    with bus.recorder() as recorder:
        for i in range(20):
            bus.publish_raw(robot, "rec-restart.tf", b'{"i": %d}' % i, message_id=f"before-{i}")
        wait_for(lambda: recorder.stats().recorded == 20, what="20 recorded before the kill")
        killable_node.kill()
        killable_node.up()
        for i in range(20):
            bus.publish_raw(robot, "rec-restart.tf", b'{"i": %d}' % i, message_id=f"after-{i}")
        wait_for(lambda: recorder.stats().recorded == 40, timeout=120, what="20 more after the restart")
    assert sorted(r.message_id or "" for r in bus.recorded("tf")) == sorted(
        [f"before-{i}" for i in range(20)] + [f"after-{i}" for i in range(20)]
    )


#: How long the broker stays dead while the robots keep publishing: a few seconds in the default
#: suite, the full 30 s under ``slow``. What is proven (nothing reaches the store meanwhile, every
#: outbox drains after, everything stored once and in order) does not depend on the length.
BROKER_OUTAGES = [pytest.param(3.0, id="3s"), pytest.param(30.0, id="30s", marks=pytest.mark.slow)]


@pytest.mark.parametrize("outage_s", BROKER_OUTAGES)
def test_broker_killed_while_three_robots_publish(
    killable_bus: Bus, killable_node: LocalNode, outage_s: float
) -> None:
    bus = killable_bus
    robots = [bus.robot(bus.add(f"explorer{i}", kind=RobotKind.EXPLORER)) for i in (1, 2, 3)]
    with bus.worker():
        publishing = [Publishing(robot).start() for robot in robots]
        wait_for(lambda: bus.count() >= 150, what="traffic before the kill")
        killable_node.kill()
        outage_ends = time.monotonic() + outage_s
        # what the broker may have taken before it died: every robot's events up to the publish it
        # had in flight (that one returns once it is queued in the outbox); a worker may still
        # store the batch it had in hand, but nothing published after these
        at_kill = [len(p.sent) for p in publishing]
        wait_for(
            lambda: all(len(p.sent) > n for p, n in zip(publishing, at_kill, strict=True)),
            what="every robot past the publish it had in flight at the kill",
        )
        before_kill = {p.robot.robot_id: set(list(p.sent)) for p in publishing}
        backlog = max(10, int(outage_s * 100 / 30))  # 50 a second each when unloaded; 100 in 30 s at least
        wait_for(
            lambda: time.monotonic() >= outage_ends and all(r.outbox.pending() >= backlog for r in robots),
            timeout=outage_s + 30,
            what=f"{outage_s:g} s of outage with every robot still publishing into its outbox",
        )
        for robot_id, taken in before_kill.items():
            stored = {(r.epoch, r.seq) for r in bus.find(EventQuery(robot_id=robot_id))}
            assert stored <= taken, f"{robot_id}: nothing published while the broker was dead was stored"
        killable_node.up()
        wait_for(lambda: all(r.connected for r in robots), timeout=60, what="the robots to reconnect")
        drained_from = [len(p.sent) for p in publishing]
        wait_for(
            lambda: all(len(p.sent) >= n + 50 for p, n in zip(publishing, drained_from, strict=True)),
            what="live publishing after the restart",
        )
        sent = {p.robot.robot_id: p.stop() for p in publishing}
        for robot in robots:
            assert robot.flush(120), f"{robot.robot_id}'s outbox did not drain"
        total = sum(len(seqs) for seqs in sent.values())
        wait_for(lambda: bus.count() == total, timeout=120, what=f"all {total} events in the store")
    for robot_id, seqs in sent.items():
        assert_stored_once_in_order(bus, robot_id, seqs)
    assert bus.gaps() == []


def table7_row(bus: Bus, explorer: RobotClient) -> tuple[int, int]:
    return explorer.outbox.pending(), bus.count("hazard")


def test_tables_6_and_7_hazards_detected_while_the_server_is_down(
    killable_bus: Bus, killable_node: LocalNode
) -> None:
    """The reference's Appendix A.4 and A.5, with the broker killed as the server that stops responding.

    Table 7 (hazards in the personal database, hazards in the central database):
    responding 0, 1; not responding 1, 1; responding again 0, 2. Table 6: the hazard detected while
    the server did not respond reaches the warden once it responds, late, with its detection time.
    """
    bus = killable_bus
    bus.settings = bus.settings.updated(late_after_s=1.0)  # the outage below lasts longer than this
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    table7: list[tuple[str, int, int]] = []
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        fresh = explorer.publish("hazard", hazard(0, "Fire"))
        [note] = warden.receive(1, timeout=30)
        assert note.event == fresh and not note.late
        table7.append(("responding", *table7_row(bus, explorer)))

        killable_node.kill()
        started = time.monotonic()
        detected = explorer.publish("hazard", hazard(1, "Gas leak"))
        assert time.monotonic() - started < 5, "publishing returns at once while the server is down"
        table7.append(("not responding", *table7_row(bus, explorer)))

        killable_node.up()
        assert explorer.flush(60)
        wait_for(lambda: bus.count("hazard") == 2, timeout=60, what="the second hazard in the store")
        table7.append(("responding again", *table7_row(bus, explorer)))
        [late] = warden.receive(1, timeout=60)
    assert table7 == [("responding", 0, 1), ("not responding", 1, 1), ("responding again", 0, 2)]
    assert late.event == detected, "Table 6: the hazard reaches the warden exactly as detected"
    assert late.late and late.event.body.detected_at == detected.body.detected_at
    assert late.received_at > detected.sent_at + timedelta(seconds=1)


def test_a_recorder_that_gives_up_on_the_broker_ends_instead_of_staying_half_alive(bus: Bus) -> None:
    """Its parent (``fleetbus worker``) starts a recorder that ended again: one that lost its
    connection for good must end, not stay up recording nothing."""
    with pytest.raises(RuntimeError, match="injected"), bus.recorder() as recorder:
        assert recorder.context is not None and recorder._loop is not None
        queue = recorder.context.connection

        async def broken() -> None:
            raise RuntimeError("injected: a reconnection that fails in a way nobody retries")

        queue._reconnect = broken  # type: ignore[method-assign]
        connection = queue._connection
        assert connection is not None
        recorder._loop.call_soon_threadsafe(connection.close)  # as if the broker had dropped it
        wait_for(lambda: not recorder._thread.is_alive(), 30, "the recorder ending")


def test_a_service_call_after_the_broker_restarted_succeeds_at_the_first_try(
    killable_bus: Bus, killable_node: LocalNode
) -> None:
    """Between two calls nothing runs the service connection (no heartbeats), so the client only
    learns at the next call that the broker restarted: it reconnects and sends that call's
    request then, which never left on the dead connection, instead of failing once."""
    bus = killable_bus
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN), connect_timeout=60)
    with bus.worker():
        assert [w["name"] for w in warden.wardens(timeout=30)] == ["warden1"]
        killable_node.kill()
        killable_node.up()
        # the request waits in its queue until the worker reconnected too
        assert [w["name"] for w in warden.wardens(timeout=60)] == ["warden1"]
