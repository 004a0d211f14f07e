"""How the stores keep times: integer microseconds since the epoch, exact both ways."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.workers.store.base import from_micros, to_micros

MOMENTS = [
    datetime(1970, 1, 1, tzinfo=timezone.utc),
    datetime(1969, 12, 31, 23, 59, 59, 999_999, tzinfo=timezone.utc),
    datetime(2026, 11, 28, 13, 49, 7, 123_456, tzinfo=timezone.utc),
    datetime(2026, 11, 28, 14, 49, 7, 1, tzinfo=timezone(timedelta(hours=1))),
    datetime(9999, 12, 31, 23, 59, 59, 999_999, tzinfo=timezone.utc),
    datetime(1, 1, 1, tzinfo=timezone.utc),
]


@pytest.mark.parametrize("moment", MOMENTS, ids=str)
def test_a_time_read_back_is_the_same_instant_in_utc_to_the_microsecond(moment: datetime) -> None:
    back = from_micros(to_micros(moment))
    assert back == moment and back.tzinfo is timezone.utc
    assert back.microsecond == moment.astimezone(timezone.utc).microsecond


def test_microseconds_keep_their_order_and_their_distance() -> None:
    first = datetime(2026, 11, 28, 13, 49, 7, 999_999, tzinfo=timezone.utc)
    assert to_micros(first + timedelta(microseconds=1)) - to_micros(first) == 1
    assert from_micros(to_micros(first) + 1) == first + timedelta(microseconds=1)
