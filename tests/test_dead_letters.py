"""Dead letters against the real broker and both stores: each bad message once, with its reason,
whenever the worker dies; a bug in the worker is its own class of error (``internal-error``)."""

from __future__ import annotations

import json
import logging
import signal
import uuid
from collections import Counter
from collections.abc import Sequence

import pytest

from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.routing import EventType, RobotKind
from fleetbus.workers.telemetry import BatteryWatch
from fleetbus.workers.validation import Accepted
from tests.factories import status
from tests.support import Bus, wait_for

BAD = 3
EPOCH = new_epoch()


def _publish_bad_and_good(bus: Bus) -> tuple[list[str], list[str]]:
    """Bad statuses (no such field) between good ones, published raw as the robot; their message ids."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    bad, good = [], []
    for seq in range(2 * BAD + 1):
        message_id = uuid.uuid4().hex
        if seq % 2:
            body = json.dumps({"robot_id": "explorer1", "seq": seq, "type": "status", "nope": 1}).encode()
            bad.append(message_id)
        else:
            event = build_event(EventType.STATUS, "explorer1", EPOCH, seq, status(50.0 + seq))
            body, message_id = encode_event(event), str(event.message_id)
            good.append(message_id)
        bus.publish_raw(account, "explorer1.status", body, message_id=message_id)
    return bad, good


def test_a_worker_killed_right_after_each_rejection_leaves_one_dead_letter_per_bad_message(
    stored_bus: Bus,
) -> None:
    bus = stored_bus
    bad, good = _publish_bad_and_good(bus)
    for _ in bad:  # each run dead-letters one message and dies by SIGKILL before its batch's ack
        faulty = bus.spawn_worker("--no-recorder", module="tests.faulty_worker")
        assert faulty.wait(60) == -signal.SIGKILL, "the worker killed itself after a rejection"
    with bus.worker() as worker:
        wait_for(lambda: bus.count(EventType.STATUS.value) == len(good), what="the good statuses stored")
        letters = wait_for(lambda: (found := bus.dead_letters()) and len(found) >= BAD and found)
        # the queue is drained: everything the worker will ever see of it is in hand
        wait_for(lambda: bus.ready_messages("fleetbus.ingest.events") == 0, what="the shard drained")
        assert worker.stats().internal_errors == 0
    letters = bus.dead_letters()
    assert Counter(letter.message_id for letter in letters) == Counter(bad), "each bad message once"
    assert {letter.reason for letter in letters} == {"schema"}
    assert all("nope" in letter.detail for letter in letters), [letter.detail for letter in letters]
    assert {(letter.user_id, letter.exchange, letter.routing_key) for letter in letters} == {
        ("explorer1", "explorer1.events", "explorer1.status")
    }


def test_a_bug_in_a_service_dead_letters_that_message_as_an_internal_error_and_the_rest_go_on(
    stored_bus: Bus, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    bus = stored_bus
    handle = BatteryWatch.handle

    async def buggy(self: BatteryWatch, accepted: Sequence[Accepted]) -> int:
        if any(item.record.body.get("battery_percent") == 13.0 for item in accepted):
            raise KeyError("a bug in the battery watch")
        return await handle(self, accepted)

    monkeypatch.setattr(BatteryWatch, "handle", buggy)
    robot = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    with bus.worker() as worker, caplog.at_level(logging.ERROR, logger="fleetbus.ingest"):
        robot.publish_many([(EventType.STATUS, status(b)) for b in (50.0, 13.0, 60.0)])
        [letter] = wait_for(lambda: bus.dead_letters(), what="the message the bug met dead-lettered")
        robot.publish(EventType.STATUS, status(70.0))  # the worker carries on
        wait_for(lambda: bus.count(EventType.STATUS.value) == 4, what="every status stored")
        assert worker.stats().internal_errors == 1
        assert worker.stats().by_reason == {"internal-error": 1}
    assert letter.reason == "internal-error"
    assert "KeyError" in letter.detail and "battery watch" in letter.detail
    assert any(record.exc_info and "battery watch" in str(record.exc_info[1]) for record in caplog.records), (
        "logged with its traceback"
    )
