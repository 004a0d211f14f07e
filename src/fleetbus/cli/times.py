"""Times and durations on the command line: the one rule every ``--since``, ``--until`` and
``--every`` follows.

A time is one of:

- ISO 8601, ``2026-03-02T09:00`` or ``2026-03-02T09:00:00+02:00`` (``Z`` too): UTC unless it
  carries an offset;
- a time of day, ``10:00`` or ``10:00:30``: today's, in UTC unless it carries an offset
  (``10:00+02:00``), as the tables of the command line show times in UTC;
- a duration back from now, ``90s``, ``10m``, ``2h``, ``1d``.

A duration is a number and a unit: ``s``, ``m``, ``h`` or ``d``.
"""

from __future__ import annotations

import re
from datetime import datetime, time, timedelta, timezone

from fleetbus.cli.context import fail
from fleetbus.limits import DURATION, read_duration, read_iso_time

#: What a time option takes, for its help: every option says the same.
TIME_FORMS = (
    "2026-03-02T09:00, 10:00 (today) or a duration back from now: 90s, 10m, 2h, 1d; "
    "UTC unless an offset is given"
)
TIME_OF_DAY = re.compile(r"[0-9]{2}:[0-9]{2}(:[0-9]{2}(\.[0-9]+)?)?([+-][0-9]{2}:[0-9]{2}|Z)?")


def read_time(text: str, now: datetime | None = None) -> datetime:
    """The moment ``text`` names (see the module's docstring), aware; ValueError otherwise."""
    now = now or datetime.now(timezone.utc)
    value = text.strip()
    if DURATION.fullmatch(value):
        return now - read_duration(value)
    try:
        if TIME_OF_DAY.fullmatch(value):
            iso = value[:-1] + "+00:00" if value.endswith("Z") else value  # Python 3.10 reads no "Z"
            of_day = time.fromisoformat(iso)
            zone = of_day.tzinfo or timezone.utc
            return datetime.combine(now.astimezone(zone).date(), of_day.replace(tzinfo=None), tzinfo=zone)
        return read_iso_time(value)
    except ValueError:
        raise ValueError(f"cannot read the time {text!r}: write {TIME_FORMS}") from None


def parse_time(value: str | None, option: str = "time") -> datetime | None:
    """An option's time, or None when it was not given; one that does not parse ends the command
    (status 2) saying what is wrong."""
    if value is None:
        return None
    try:
        return read_time(value)
    except ValueError as error:
        fail(f"{option}: {error}", code=2)


def parse_time_ns(value: str | None, option: str = "time") -> int | None:
    """An option's time in nanoseconds since 1970: an integer of them as written (a ROS log time,
    to the nanosecond), else what :func:`parse_time` reads; None when it was not given."""
    if value is None:
        return None
    if value.isdigit():
        return int(value)
    moment = parse_time(value, option)
    assert moment is not None
    return round(moment.timestamp() * 1_000_000) * 1000


def parse_duration(value: str, option: str = "duration") -> timedelta:
    """An option's duration, more than zero; else the command ends (status 2) saying why."""
    try:
        duration = read_duration(value)
    except ValueError as error:
        fail(f"{option}: {error}", code=2)
    if duration <= timedelta(0):
        fail(f"{option}: {value!r} is no time at all: give more than 0", code=2)
    return duration
