"""The bounds on everything that grows with time or traffic, read from the settings.

Every limit is written in the recorder's retention grammar (:mod:`fleetbus.limits`):
an age (``30d``), a size (``1GB``) or a number (``100000``). Each bound takes the kinds of limit
it can hold to, and refuses the others with the variable's name, so that a typo stops the
process at start rather than leaving something unbounded.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from datetime import timedelta
from typing import TYPE_CHECKING

from fleetbus.limits import QueueLimit, Retention, parse_limit, parse_retention, parse_ttl

if TYPE_CHECKING:
    from fleetbus.settings import Settings

#: MongoDB refuses a 65th index on a collection; a recorded type has five of its own (``_id``,
#: time, robot, message id, mission), and two processes may add one at the same moment.
MAX_FIELD_INDEXES = 50


@dataclass(frozen=True)
class Bounds:
    events: dict[str, Retention]
    """The event log's retention per type (``*``: every other type), by age or number of records."""
    duplicates: Retention
    discards: Retention
    cleared_hazards: Retention
    """Cleared hazards in the registry, by the time they were cleared, or their number."""
    forwards: Retention
    """Central's log of what sites forwarded, by when central received each, or its number."""
    numberings: Retention
    rejections: Retention
    gone_workers: Retention
    """Statuses not updated (and leases expired) that long ago, or beyond their number."""
    """Why each dead letter was refused, by when it was, or their number."""
    """The sequence ledger's numberings, by when each was last observed, or their number."""
    map_versions: int
    """Versions kept per robot, the newest, besides those being fetched."""
    map_staging_ttl: timedelta
    dead_letters: QueueLimit
    inbox: QueueLimit
    site_reports: QueueLimit
    """At central, the sites' reports not read yet (each site's newest is what central keeps)."""
    site_downlink: QueueLimit
    """At central, each site's accounts, removals and missions waiting for it."""
    site_maps: QueueLimit
    """At central, each site's maps waiting for it."""
    field_indexes: int
    prune_every_s: float
    acknowledged_alerts: timedelta
    """How long an acknowledged alert whose condition ended is kept."""


def _by_age_or_count(policy: Retention, variable: str) -> Retention:
    if policy.max_bytes is not None:
        raise ValueError(f"{variable}: bounded by an age (30d) or a number of records (100000), not a size")
    return policy


def event_retention(specs: Iterable[str], variable: str = "FLEETBUS_EVENTS_KEEP") -> dict[str, Retention]:
    try:
        policies = parse_retention(specs)
    except ValueError as error:
        raise ValueError(f"{variable}: {error}") from None
    for policy in policies.values():
        _by_age_or_count(policy, variable)
    return policies


def register_retention(text: str, variable: str) -> Retention:
    """A register's bound (the duplicates, the discards): one age or number of records."""
    return _by_age_or_count(parse_limit(text, variable), variable)


def queue_limit(words: Iterable[str], variable: str) -> QueueLimit:
    """``["10000", "100MB"]``: a number of messages and/or a size."""
    messages = size = None
    for word in words:
        limit = parse_limit(word, variable)
        if limit.max_age is not None:
            raise ValueError(
                f"{variable}: a queue is bounded by a number of messages or a size, not {word!r}"
            )
        messages = limit.max_records or messages
        size = limit.max_bytes or size
    if messages is None and size is None:
        raise ValueError(f"{variable}: give a number of messages, a size, or both (e.g. '10000 100MB')")
    return QueueLimit(messages, size)


def field_index_cap(value: int, variable: str = "FLEETBUS_FIELD_INDEXES_MAX") -> int:
    if not 1 <= value <= MAX_FIELD_INDEXES:
        raise ValueError(
            f"{variable} must be from 1 to {MAX_FIELD_INDEXES} (MongoDB allows 64 indexes), not {value}"
        )
    return value


def bounds(settings: Settings) -> Bounds:
    return Bounds(
        events=event_retention(settings.events_keep),
        duplicates=register_retention(settings.duplicates_keep, "FLEETBUS_DUPLICATES_KEEP"),
        discards=register_retention(settings.discards_keep, "FLEETBUS_DISCARDS_KEEP"),
        cleared_hazards=register_retention(settings.hazards_keep, "FLEETBUS_HAZARDS_KEEP"),
        forwards=register_retention(settings.forwards_keep, "FLEETBUS_FORWARDS_KEEP"),
        numberings=register_retention(settings.ledger_keep, "FLEETBUS_LEDGER_KEEP"),
        rejections=register_retention(settings.rejections_keep, "FLEETBUS_REJECTIONS_KEEP"),
        gone_workers=register_retention(settings.gone_workers_keep, "FLEETBUS_GONE_WORKERS_KEEP"),
        map_versions=settings.map_versions_keep,
        map_staging_ttl=parse_ttl(settings.map_staging_ttl, "FLEETBUS_MAP_STAGING_TTL"),
        dead_letters=queue_limit(settings.dead_letters_max, "FLEETBUS_DEAD_LETTERS_MAX"),
        inbox=queue_limit(settings.inbox_max, "FLEETBUS_INBOX_MAX"),
        site_reports=queue_limit(settings.site_reports_max, "FLEETBUS_SITE_REPORTS_MAX"),
        site_downlink=queue_limit(settings.site_downlink_max, "FLEETBUS_SITE_DOWNLINK_MAX"),
        site_maps=queue_limit(settings.site_maps_max, "FLEETBUS_SITE_MAPS_MAX"),
        field_indexes=field_index_cap(settings.field_indexes_max),
        prune_every_s=settings.prune_every_s,
        acknowledged_alerts=timedelta(days=settings.alerts_keep_days),
    )
