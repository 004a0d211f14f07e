"""Integers beyond what the stores hold (64 bits: SQLite's INTEGER, MongoDB's int64), sent by a
robot, on both stores: an event field past the bound is refused by the schema, naming the field
(``schema``, not the worker failing on it as ``internal-error``); a ROS message's own value (a
``uint64`` field holds up to 2**64 - 1) is kept as sent."""

from __future__ import annotations

import json

from fleetbus.schemas.bodies import INT64_MAX
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.routing import EventType, RobotKind
from fleetbus.workers.store.base import EventQuery
from tests.factories import status
from tests.support import Bus, wait_for

EPOCH = new_epoch()
UINT64_MAX = 2**64 - 1


def test_an_integer_beyond_64_bits_is_a_schema_error_and_a_ros_value_is_kept(stored_bus: Bus) -> None:
    bus = stored_bus
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    past = json.loads(encode_event(build_event(EventType.STATUS, "explorer1", EPOCH, 0, status())))
    past["seq"] = INT64_MAX + 1
    bus.publish_raw(account, "explorer1.status", json.dumps(past).encode(), message_id="past-the-bound")
    ros = build_event(
        EventType.ROS,
        "explorer1",
        EPOCH,
        1,
        {"topic": "/ids", "ros_type": "std_msgs/UInt64", "log_time_ns": 1, "fields": {"data": UINT64_MAX}},
    )
    bus.publish_raw(account, "explorer1.ros", encode_event(ros), message_id=str(ros.message_id))
    last = build_event(EventType.STATUS, "explorer1", EPOCH, 2, status())  # the sentinel
    bus.publish_raw(account, "explorer1.status", encode_event(last), message_id=str(last.message_id))
    with bus.worker():
        wait_for(lambda: bus.count(EventType.STATUS.value) == 1, what="the sentinel stored")
        [letter] = wait_for(lambda: bus.dead_letters(), what="the event past the bound dead-lettered")
        [kept] = wait_for(lambda: bus.find(EventQuery(type="ros")), what="the ROS message stored")
    assert (letter.message_id, letter.reason) == ("past-the-bound", "schema")
    assert "seq" in letter.detail and str(INT64_MAX) in letter.detail
    assert kept.body["fields"] == {"data": UINT64_MAX}
