"""How the console writes times: UTC, to the second, whatever zone a time was made in."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.api.console.templating import templates

WHEN = templates.env.filters["when"]
SHOWN = "2026-11-28 14:03:05"


def test_a_time_shows_in_utc_to_the_second() -> None:
    assert WHEN(datetime(2026, 11, 28, 14, 3, 5, 999_999, tzinfo=timezone.utc)) == SHOWN
    assert WHEN(datetime(2026, 11, 28, 15, 3, 5, tzinfo=timezone(timedelta(hours=1)))) == SHOWN
    assert WHEN(datetime(2026, 11, 28, 9, 3, 5, tzinfo=timezone(timedelta(hours=-5)))) == SHOWN
    assert WHEN(None) == ""
