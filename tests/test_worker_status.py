"""A worker's retries are visible where an operator looks: its status in the store, and
``fleetbus stats``, on both stores."""

from __future__ import annotations

import pytest

from fleetbus.schemas.routing import NOTIFY_EXCHANGE, EventType, RobotKind
from fleetbus.workers.store.statuses import Statuses, WorkerStatus
from tests.factories import status
from tests.support import Bus, wait_for
from tests.test_cli import fleetbus

BLOCKER = "test.blocker"


def _block_notifications(bus: Bus) -> None:
    """A queue bound to every notification that refuses every message: the broker nacks each
    notification the worker publishes, a transient failure it retries."""
    with bus.admin_channel() as channel:
        channel.queue_declare(BLOCKER, arguments={"x-max-length": 0, "x-overflow": "reject-publish"})
        channel.queue_bind(BLOCKER, NOTIFY_EXCHANGE, "notify.#")


def _statuses(bus: Bus) -> list[WorkerStatus]:
    return bus.with_store(lambda store: store.statuses.statuses())


def test_a_worker_retrying_shows_what_it_waits_for_and_its_counts(stored_bus: Bus) -> None:
    bus = stored_bus
    robot = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    _block_notifications(bus)
    with bus.worker():
        robot.publish(EventType.STATUS, status(5.0))  # low battery: a notification, nacked
        [waiting] = wait_for(
            lambda: [s for s in _statuses(bus) if s.waiting_for], what="the worker's status saying it retries"
        )
        assert waiting.waiting_for == "the store and the notifications"
        assert "DeliveryError" in (waiting.last_error or "") and waiting.waiting_since is not None
        assert waiting.counters["store_retries"] >= 1
        shown = fleetbus(bus, "stats", "--since", "10m")
        assert shown.returncode == 0, shown.stderr
        assert "waiting for" in shown.stdout and "the store and the notifications" in shown.stdout

        with bus.admin_channel() as channel:
            channel.queue_delete(BLOCKER)
        [recovered] = wait_for(
            lambda: [s for s in _statuses(bus) if not s.waiting_for and s.counters.get("notified")],
            what="the worker's status once the notification went out",
        )
        assert recovered.name == waiting.name and recovered.counters["stored"] == 1
        assert bus.count(EventType.STATUS.value) == 1


def test_a_status_write_that_fails_unexpectedly_does_not_end_the_reports(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The status is how an operator tells a worker is alive: a write failing for any reason is
    logged and the next one goes (it used to end the reporting task, the worker still running)."""
    failed: list[str] = []
    put = Statuses.put_status

    async def fails_once(board: Statuses, worker_status: WorkerStatus) -> None:
        if not failed:
            failed.append(worker_status.name)
            raise RuntimeError("the status could not be written")
        await put(board, worker_status)

    monkeypatch.setattr(Statuses, "put_status", fails_once)
    robot = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    with bus.worker():
        robot.publish(EventType.STATUS, status(80.0))
        wait_for(
            lambda: [s for s in _statuses(bus) if s.counters.get("stored") == 1],
            what="a status written after the failed one",
        )
    assert len(failed) == 1
