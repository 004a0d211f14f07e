"""A hazard registered from its stored record carries the event exactly as pydantic dumps it."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.schemas.envelope import EVENT_ADAPTER
from fleetbus.workers.store.hazards import DEFAULT_MISSION, NewHazard
from fleetbus.workers.validation import event_record
from tests.factories import hazard

EPOCH = "20261123T140000000Z-0a1b2c3d"
OFFSETS = [timezone.utc, timezone(timedelta(hours=2)), timezone(timedelta(hours=-5, minutes=-30))]


@pytest.mark.parametrize("microsecond", [0, 5, 123456])
@pytest.mark.parametrize("zone", OFFSETS, ids=str)
def test_the_event_rebuilt_from_the_record_is_the_event_as_dumped(microsecond: int, zone: timezone) -> None:
    sent_at = datetime(2026, 11, 23, 14, 0, 0, microsecond, tzinfo=zone)
    event = EVENT_ADAPTER.validate_python(
        {
            "robot_id": "explorer1",
            "epoch": EPOCH,
            "seq": 7,
            "sent_at": sent_at,
            "type": "hazard",
            "body": hazard(),
        }
    )
    received_at = datetime.now(timezone.utc)
    record = event_record(event, received_at, "explorer1", "explorer1.events", "explorer1.hazard")
    new = NewHazard.of(record)
    assert new.event == EVENT_ADAPTER.dump_python(event, mode="json")
    assert list(new.event) == list(EVENT_ADAPTER.dump_python(event, mode="json"))
    assert (new.mission_id, new.epoch, new.seq, new.received_at) == (DEFAULT_MISSION, EPOCH, 7, received_at)
    assert NewHazard.of(replace(record, mission_id="m1")).mission_id == "m1"
