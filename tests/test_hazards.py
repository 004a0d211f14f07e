"""The hazard service against the real broker: ids, the localisation gate (Tables 3-5), claims."""

from __future__ import annotations

import threading
from typing import Any

import pika
import pytest
from pika.adapters.blocking_connection import BlockingChannel

from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.coordination import HazardCoordinator
from fleetbus.workers.store.hazards import HazardState
from fleetbus_dev.worker_thread import WorkerThread
from tests.factories import hazard
from tests.support import Bus, notifications_until, read_inbox, wait_for
from tests.test_team import states


def held_and_announced(bus: Bus) -> tuple[int, int]:
    hazards = bus.with_store(lambda store: store.hazards.open_hazards("default"))
    held = sum(h.state is HazardState.HELD for h in hazards)
    return held, len(hazards) - held


def test_hazards_are_held_until_every_warden_is_localised_tables_3_4_5(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    wardens = {name: bus.robot(bus.add(name, kind=RobotKind.WARDEN)) for name in ("warden1", "warden2")}
    with bus.worker():
        sent = explorer.publish_many([("hazard", hazard(0, "Fire")), ("hazard", hazard(1, "Gas leak"))])
        # Table 3: before the wardens localise, the server holds both and announces none
        wait_for(lambda: held_and_announced(bus) == (2, 0), what="2 held hazards")
        # a sentinel behind them on the express lane (one consumer, in order): once it is stored, a
        # hazard the gate had let go would be in an inbox
        wardens["warden2"].publish("localisation", {"localised": False})
        wait_for(lambda: bus.count("localisation") == 1, what="the sentinel stored")
        assert bus.ready_messages("warden1.inbox") == bus.ready_messages("warden2.inbox") == 0
        assert held_and_announced(bus) == (2, 0)

        # Table 4: one warden localised, the other not: still held
        wardens["warden1"].publish("localisation", {"localised": True})
        wait_for(
            lambda: {r.name: r.localised for r in bus.with_store(lambda s: s.hazards.robots("warden"))}[
                "warden1"
            ],
            what="warden1 recorded as localised",
        )
        wardens["warden2"].publish("localisation", {"localised": False})  # the sentinel again
        wait_for(lambda: bus.count("localisation") == 3, what="the sentinel stored")
        assert bus.ready_messages("warden1.inbox") == bus.ready_messages("warden2.inbox") == 0
        assert held_and_announced(bus) == (2, 0)

    # the held list is in the store: a new worker process carries on from it
    with bus.worker():
        # Table 5: all localised: none held, both announced, in the order detected
        wardens["warden2"].publish("localisation", {"localised": True})
        for warden in wardens.values():
            notes = warden.receive(2, timeout=30)
            assert [n.hazard_id for n in notes] == [1, 2]
            assert [n.event for n in notes] == sent, "every field as the explorer sent it (Table 1)"
        assert held_and_announced(bus) == (0, 2)
        sentinel = explorer.publish("hazard", hazard(2, "sentinel"))
        for warden in wardens.values():
            after = notifications_until(warden, lambda note: note.event == sentinel)
            assert [note.event for note in after] == [sentinel], "each hazard announced once"


def test_a_warden_that_loses_localisation_holds_new_hazards_again(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        explorer.publish("hazard", hazard(0))
        [first] = warden.receive(1, timeout=30)
        warden.publish("localisation", {"localised": False})
        wait_for(
            lambda: not bus.with_store(lambda s: s.hazards.robots("warden"))[0].localised, what="warden1 lost"
        )
        explorer.publish("hazard", hazard(1))
        wait_for(lambda: held_and_announced(bus) == (1, 1), what="the second hazard held")
        warden.publish("localisation", {"localised": True})
        [second] = warden.receive(1, timeout=30)
    assert (first.hazard_id, second.hazard_id) == (1, 2)


class LookedAtStop(threading.Event):
    """A stop event that counts how often the listener looked at it (once per quiet spell)."""

    def __init__(self) -> None:
        super().__init__()
        self.looks = 0

    def is_set(self) -> bool:
        self.looks += 1
        return super().is_set()


def test_a_listener_until_stopped_keeps_one_consumer_through_quiet_spells_and_ends_when_told(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    opened: list[object] = []
    open_channel = warden._open_consumer_channel
    monkeypatch.setattr(warden, "_open_consumer_channel", lambda: opened.append(open_channel()) or opened[-1])
    stop, received = LookedAtStop(), []
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        listener = threading.Thread(target=lambda: received.extend(warden.notifications(stop=stop)))
        listener.start()
        wait_for(lambda: stop.looks >= 4, what="the listener through four quiet spells")
        sent = explorer.publish("hazard", hazard(0))
        wait_for(lambda: len(received) == 1, what="the hazard announced to the listener")
        assert received[0].event == sent
        stop.set()
        listener.join(timeout=10)
        assert not listener.is_alive(), "the listener ends once told to stop"
    assert len(opened) == 1, "one consumer channel for the whole listen, not one per quiet spell"


def test_a_listener_thread_and_service_calls_on_another_each_use_a_connection_of_their_own(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The guide's listener: one thread on ``notifications(stop=...)`` while the main thread calls
    the services. pika's connections are not thread-safe, so two threads on one connection may
    pass by luck and fail another time; every pika round trip is recorded with its thread, which
    shows a shared connection at once."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    users: dict[int, tuple[Any, set[str]]] = {}  # id -> the connection (kept alive), its threads
    flush = pika.BlockingConnection._flush_output

    def recorded(connection: pika.BlockingConnection, *waiters: Any) -> None:
        users.setdefault(id(connection), (connection, set()))[1].add(threading.current_thread().name)
        flush(connection, *waiters)

    monkeypatch.setattr(pika.BlockingConnection, "_flush_output", recorded)
    consuming: list[str] = []
    consume = BlockingChannel._basic_consume_impl

    def consumer(channel: BlockingChannel, *args: Any, **kwargs: Any) -> Any:
        consuming.append(threading.current_thread().name)
        return consume(channel, *args, **kwargs)

    monkeypatch.setattr(BlockingChannel, "_basic_consume_impl", consumer)
    received: list[Notification] = []
    failed: list[BaseException] = []

    def listen(stop: threading.Event) -> None:
        try:
            received.extend(warden.notifications(stop=stop))
        except BaseException as error:  # the test's thread says it below
            failed.append(error)

    stop = threading.Event()
    listener = threading.Thread(target=listen, args=(stop,), name="listener")
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        listener.start()
        sent, claimed, calls = [], set(), 0
        for i in range(120):
            if i % 6 == 0:
                sent.append(explorer.publish("hazard", hazard(i // 6)))
            assert "warden1" in [w["name"] for w in warden.wardens()]
            calls += 1
            for note in list(received):
                if note.hazard_id not in claimed:
                    assert warden.claim_hazard(note.hazard_id)["claimed_by"] == "warden1"
                    claimed.add(note.hazard_id)
        wanted = {e.message_id for e in sent}
        wait_for(lambda: wanted <= {n.event.message_id for n in received}, what="every hazard announced")
        stop.set()
        listener.join(timeout=10)
        assert not listener.is_alive() and not failed, failed
        assert calls == 120 and len(claimed) >= 10
        shared = {names for _, names in users.values() if len(names) > 1}
        assert not any(shared), f"a connection used by several threads: {shared}"
        assert any("listener" in names for _, names in users.values())

        # close() on the main thread ends a listener on another thread quietly
        listener = threading.Thread(target=listen, args=(threading.Event(),), name="listener2")
        listener.start()
        wait_for(lambda: "listener2" in consuming, what="listener2 consuming its inbox")
        warden.close(flush_timeout=0)
        listener.join(timeout=10)
        assert not listener.is_alive(), "close() ends the listener"
        assert not failed, failed


def test_a_notification_whose_handler_raised_is_acked_as_documented(bus: Bus) -> None:
    """Python closes the generator alike for ``break`` and for an exception in the loop's body:
    the notification being handled is acked either way (the guide says so, and how to keep it)."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    account = bus.add("warden1", kind=RobotKind.WARDEN)
    warden = bus.robot(account)
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        assert list(warden.notifications(timeout=0.5)) == []  # the resync done: the inbox next
        explorer.publish("hazard", hazard(0))
        with pytest.raises(RuntimeError):
            for _ in warden.notifications(timeout=30):
                raise RuntimeError("the handler failed")
        assert read_inbox(account.amqp_url, "warden1", until=lambda _: True, timeout=1.0) == []


def test_an_announcement_that_cannot_be_finished_stops_the_worker_and_comes_again(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The operators' copies and the mark come after the wardens' copies, before the ack. When they
    fail past their retries, the worker stops (to be restarted): it would otherwise hold the
    express lane's messages unacked, chained behind the failure, while the broker sent no more."""
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))

    async def fails(*_: object) -> None:
        raise RuntimeError("the operators' copies could not be published")

    with bus.worker():
        warden.publish("localisation", {"localised": True})
        wait_for(
            lambda: any(r.localised for r in bus.with_store(lambda s: s.hazards.robots())), what="localised"
        )
    monkeypatch.setattr(HazardCoordinator, "_finish", fails)
    worker = WorkerThread(bus.settings, bus.service_accounts().service_url).start()
    try:
        sent = explorer.publish("hazard", hazard(0))
        [note] = warden.receive(1, timeout=30)  # the wardens' copies went before the failure
        assert note.event == sent
        wait_for(lambda: not worker.running, what="the worker stopped by itself")
    finally:
        with pytest.raises(Exception, match="could not be published"):
            worker.stop()
    assert states(bus) == [HazardState.HELD.value], "told, never marked announced"
    monkeypatch.undo()
    with bus.worker():  # the next worker takes the hazard again: announced, and marked
        wait_for(lambda: states(bus) == [HazardState.ANNOUNCED.value], what="the hazard marked announced")
