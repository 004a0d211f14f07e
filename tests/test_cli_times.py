"""The command line's one rule for times and durations (``fleetbus.cli.times``)."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.cli.times import read_time
from fleetbus.limits import read_duration

NOW = datetime(2026, 3, 2, 9, 30, tzinfo=timezone.utc)
PLUS_TWO = timezone(timedelta(hours=2))


@pytest.mark.parametrize(
    ("text", "moment"),
    [
        ("10:00", datetime(2026, 3, 2, 10, 0, tzinfo=timezone.utc)),  # today, UTC
        ("08:05:30", datetime(2026, 3, 2, 8, 5, 30, tzinfo=timezone.utc)),
        ("10:00+02:00", datetime(2026, 3, 2, 10, 0, tzinfo=PLUS_TWO)),
        ("10:00Z", datetime(2026, 3, 2, 10, 0, tzinfo=timezone.utc)),
        ("2026-03-01T09:00", datetime(2026, 3, 1, 9, 0, tzinfo=timezone.utc)),  # UTC without an offset
        ("2026-03-01T09:00Z", datetime(2026, 3, 1, 9, 0, tzinfo=timezone.utc)),
        ("2026-03-01T09:00:00+02:00", datetime(2026, 3, 1, 9, 0, tzinfo=PLUS_TWO)),
        ("2026-03-01", datetime(2026, 3, 1, tzinfo=timezone.utc)),
        ("10m", NOW - timedelta(minutes=10)),
        ("1.5h", NOW - timedelta(minutes=90)),
        ("30d", NOW - timedelta(days=30)),
    ],
)
def test_every_form_of_a_time(text: str, moment: datetime) -> None:
    assert read_time(text, now=NOW) == moment


def test_a_time_of_day_is_the_day_of_its_own_zone() -> None:
    late = datetime(2026, 3, 2, 23, 30, tzinfo=timezone.utc)  # already 3 March at +02:00
    assert read_time("01:00+02:00", now=late) == datetime(2026, 3, 3, 1, 0, tzinfo=PLUS_TWO)


@pytest.mark.parametrize("text", ["10", "ten", "25:00", "10:00 UTC", "m", "-5m", "2026-13-01"])
def test_what_is_no_time_is_refused_saying_what_is_read(text: str) -> None:
    with pytest.raises(ValueError, match="cannot read the time"):
        read_time(text, now=NOW)


def test_durations() -> None:
    assert read_duration("90s") == timedelta(seconds=90)
    assert read_duration("1m") == timedelta(minutes=1)
    with pytest.raises(ValueError, match="s, m, h or d"):
        read_duration("1w")


def test_the_http_api_and_the_command_line_read_a_time_the_same_way() -> None:
    """One reader of ISO 8601 for both, a ``Z`` taken on every Python (3.10's fromisoformat reads none)."""
    from fleetbus.cli.times import read_time as cli_time
    from fleetbus.limits import read_iso_time as api_time

    for text in ("2026-11-27T08:00:00Z", "2026-11-27T08:00:00+00:00", "2026-11-27T08:00:00"):
        assert api_time(text) == cli_time(text) == datetime(2026, 11, 27, 8, tzinfo=timezone.utc), text
