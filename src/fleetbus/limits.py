"""The grammar of every bound the settings give, and the values it reads into: one place for the
recorder's retention, the store's pruning and the broker's queue lengths alike.

A limit is an age (``30d``), a size (``1GB``) or a number of records (``100000``). Retention specs
read like ``status=7d``, ``map_chunk=500MB``, ``tf=100000`` and ``*=1GB`` (any type with no spec of
its own); several specs for one type all apply. Sizes count the bodies as received; the database
holds them with its own overhead (indexes, JSON text or BSON).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from datetime import datetime, timedelta, timezone

ANY_TYPE = "*"
AGE_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400}
SIZE_UNITS = {"B": 1, "KB": 1000, "MB": 1000**2, "GB": 1000**3, "KIB": 1024, "MIB": 1024**2, "GIB": 1024**3}
SPEC = re.compile(r"^(?P<type>\*|[a-z][a-z0-9_]{0,39})=(?P<amount>[0-9]+(?:\.[0-9]+)?)(?P<unit>[A-Za-z]*)$")
DURATION = re.compile(r"(?P<amount>[0-9]+(?:\.[0-9]+)?)(?P<unit>[smhd])")
LIMIT = re.compile(r"^(?P<amount>[0-9]+(?:\.[0-9]+)?)(?P<unit>[A-Za-z]*)$")


@dataclass(frozen=True)
class Retention:
    max_age: timedelta | None = None
    max_bytes: int | None = None
    max_records: int | None = None

    def merged(self, other: Retention) -> Retention:
        return replace(
            self,
            max_age=other.max_age or self.max_age,
            max_bytes=other.max_bytes or self.max_bytes,
            max_records=other.max_records or self.max_records,
        )

    def describe(self) -> str:
        parts = []
        if self.max_age:
            parts.append(_age(self.max_age))
        if self.max_bytes:
            parts.append(
                f"{self.max_bytes / 1e9:g} GB" if self.max_bytes >= 1e9 else f"{self.max_bytes / 1e6:g} MB"
            )
        if self.max_records:
            parts.append(f"{self.max_records} records")
        return ", ".join(parts) or "everything"


def _age(age: timedelta) -> str:
    seconds = age.total_seconds()
    for unit, size in sorted(AGE_UNITS.items(), key=lambda item: -item[1]):
        if seconds >= size and seconds % size == 0:
            return f"{seconds / size:g}{unit}"
    return f"{seconds:g}s"


def parse_retention(specs: Iterable[str]) -> dict[str, Retention]:
    """``["status=7d", "*=1GB"]`` as policies by type; a spec that does not parse raises ValueError."""
    policies: dict[str, Retention] = {}
    for spec in specs:
        match = SPEC.fullmatch(spec.strip())
        if not match:
            raise ValueError(
                f"retention {spec!r}: write TYPE=LIMIT with LIMIT an age (30s, 10m, 12h, 7d), a size "
                "(500KB, 200MB, 1GB) or a number of records; TYPE may be * for every other type"
            )
        policy = parse_limit(f"{match['amount']}{match['unit']}", what=f"retention {spec!r}")
        policies[match["type"]] = policies.get(match["type"], Retention()).merged(policy)
    return policies


def parse_limit(text: str, what: str = "limit") -> Retention:
    """One limit without a type: an age (``30d``), a size (``1GB``) or a number of records (``100000``)."""
    match = LIMIT.fullmatch(text.strip())
    if not match:
        raise ValueError(
            f"{what}: write an age (30s, 10m, 12h, 7d), a size (500KB, 1GB) or a number, not {text!r}"
        )
    amount, unit = float(match["amount"]), match["unit"]
    if amount <= 0:
        raise ValueError(f"{what}: a limit above 0 (a limit of 0 would keep nothing), not {text!r}")
    if unit in AGE_UNITS:
        return Retention(max_age=read_duration(text))
    if unit.upper() in SIZE_UNITS:
        return Retention(max_bytes=int(amount * SIZE_UNITS[unit.upper()]))
    if not unit and amount.is_integer():
        return Retention(max_records=int(amount))
    raise ValueError(f"{what}: unknown unit {unit!r}; use s, m, h, d, KB, MB, GB or none")


def read_iso_time(text: str) -> datetime:
    """A time in ISO 8601 (``2026-11-27T08:00:00Z``), the one way fleetbus reads one: a ``Z`` on
    every Python (3.10 reads none), and one without a zone is UTC; ValueError otherwise."""
    iso = text[:-1] + "+00:00" if text.endswith(("Z", "z")) else text
    moment = datetime.fromisoformat(iso)
    return moment if moment.tzinfo else moment.replace(tzinfo=timezone.utc)


def read_duration(text: str) -> timedelta:
    """``90s``, ``10m``, ``2h``, ``1d`` (a fraction allowed: ``1.5h``), the one way fleetbus reads a
    span of time, in a setting or an option; ValueError otherwise."""
    match = DURATION.fullmatch(text.strip())
    if not match:
        raise ValueError(f"{text!r} is not a duration: write a number and s, m, h or d (90s, 10m, 2h, 1d)")
    return timedelta(seconds=float(match["amount"]) * AGE_UNITS[match["unit"]])


def parse_ttl(text: str, variable: str) -> timedelta:
    """An age (``30m``, ``1h``, ``2d``) as a time span; ValueError naming ``variable`` otherwise."""
    limit = parse_limit(text, variable)
    if limit.max_age is None:
        raise ValueError(f"{variable}: write an age (30m, 1h, 2d), not {text!r}")
    return limit.max_age


def policy_for(policies: Mapping[str, Retention], type: str) -> Retention | None:
    return policies.get(type) or policies.get(ANY_TYPE)


@dataclass(frozen=True)
class QueueLimit:
    """A queue's length: the broker drops its oldest messages beyond either."""

    messages: int | None = None
    bytes: int | None = None

    def describe(self) -> str:
        parts = []
        if self.messages is not None:
            parts.append(f"{self.messages:,} messages")
        if self.bytes is not None:
            parts.append(f"{self.bytes / 1e9:g} GB" if self.bytes >= 1e9 else f"{self.bytes / 1e6:g} MB")
        return " or ".join(parts)
