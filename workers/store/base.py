"""The storage interface every adapter implements, and the record it stores.

Writes are idempotent on ``(robot_id, epoch, seq)``, the event's key (:mod:`fleetbus.schemas.envelope`):
the document-id strategy is that triple, so a redelivered or resent event never becomes a second
record. ``write_events`` returns only once
the batch is durable, which is what lets a worker ack after it.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from typing import Any, NamedTuple

#: The largest integer a store keeps: SQLite's and MongoDB's are signed 64-bit. An id beyond it
#: names nothing stored.
LARGEST_INTEGER = 2**63 - 1


_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)


def to_micros(moment: datetime) -> int:
    """Integer microseconds since the epoch: exact, sortable, the same in every adapter."""
    delta = moment.astimezone(timezone.utc) - _EPOCH
    return (delta.days * 86_400 + delta.seconds) * 1_000_000 + delta.microseconds


def from_micros(value: int) -> datetime:
    # exact, and 40 % quicker than fromtimestamp: every row read decodes its times with it
    return _EPOCH + timedelta(microseconds=value)


class StoreError(Exception):
    """Base of the errors a store raises."""


class StoreUnavailable(StoreError):
    """Transient: the database cannot be reached or is locked. Retry later; nothing was written."""


@dataclass(frozen=True)
class EventRecord:
    """One stored event: the validated envelope plus what the broker told us about it."""

    robot_id: str
    epoch: str
    seq: int
    type: str
    message_id: str
    sent_at: datetime
    received_at: datetime
    body: dict[str, Any]
    user_id: str
    """The broker-validated user that published the message."""
    exchange: str
    routing_key: str
    mission_id: str | None = None
    digest: str | None = None
    """The event's content (:func:`fleetbus.schemas.envelope.content_digest`): what tells a resend
    (the same) from a reused number (another). None for a record stored without one: compared by
    message id."""
    redelivered: bool = False
    """The broker had delivered the message before (to a consumer that did not ack it: a worker or
    its connection lost). RabbitMQ keeps a queue's order only for messages not redelivered, so
    such an event may have been taken after later ones of its robot."""

    @property
    def key(self) -> tuple[str, str, int]:
        return (self.robot_id, self.epoch, self.seq)


class Received(NamedTuple):
    key: tuple[str, str, int]
    """(robot_id, epoch, seq)"""
    received_at: datetime


@dataclass(frozen=True)
class WriteResult:
    inserted: bool
    """False when a record with the same (robot_id, epoch, seq) was already stored."""
    stored_message_id: str | None = None
    """When not inserted: the message id of the record already stored under that key."""
    stored_digest: str | None = None
    """When not inserted: the content digest of the record already stored under that key (None
    for one stored without)."""
    rewritten: bool = False
    """When not inserted: the stored record is this very one (same message id, same receive time),
    so an earlier attempt of this write stored it (its answer lost: the store timed out, say). Not
    a duplicate: the robot did not send it twice."""
    pruned: bool = False
    """When not inserted: the ledger had seen this number but its event has been pruned since, so a
    resend of an old event is not stored a second time (and reuse of the number cannot be told)."""

    def holds(self, record: EventRecord) -> bool:
        """Whether the store holds ``record``'s event under its key: written now, or already, with
        the same content (a resend or a redelivery, whatever message id it carries). False for a
        reused number (another event holds the key) and for a pruned one (cannot be told)."""
        if self.inserted:
            return True
        if self.pruned:
            return False
        if self.stored_digest is not None and record.digest is not None:
            return self.stored_digest == record.digest
        return self.stored_message_id == record.message_id

    def reused(self, record: EventRecord) -> bool:
        """Whether ``record`` reuses its number: another event is stored under its key."""
        return not self.inserted and not self.pruned and not self.holds(record)


@dataclass(frozen=True)
class EventQuery:
    type: str | None = None
    robot_id: str | None = None
    since: datetime | None = None
    """Inclusive lower bound on ``sent_at``."""
    until: datetime | None = None
    """Exclusive upper bound on ``sent_at``."""
    limit: int | None = None
    newest_first: bool = False
    mission_id: str | None = None
    """Only events recorded under this mission."""
    extra: dict[str, Any] = field(default_factory=dict)


class EventStore(abc.ABC):
    """Async storage of events: the reads and writes of the event log
    (:class:`~fleetbus.workers.store.repositories.EventLog`)."""

    @abc.abstractmethod
    async def write_events(self, records: Sequence[EventRecord]) -> list[WriteResult]:
        """Store a batch atomically and durably, skipping records whose key exists.

        Returns one result per record, in order. Raises :class:`StoreUnavailable` when the
        database cannot be reached; then nothing of the batch may be assumed written.
        """

    @abc.abstractmethod
    async def find_events(self, query: EventQuery) -> list[EventRecord]:
        """Events matching the query, ordered by ``sent_at`` then robot, epoch and sequence number."""

    @abc.abstractmethod
    async def count_events(self, type: str | None = None, robot_id: str | None = None) -> int: ...

    @abc.abstractmethod
    async def holds_more_events(self, query: EventQuery, than: int) -> bool:
        """Whether more than ``than`` events match ``query`` (its type, robot, mission and window;
        not its limit or order): read from the (type, sent_at) index, not the events, however
        many match."""

    @abc.abstractmethod
    async def newest_events(
        self,
        robots: Sequence[str],
        type: str | None = None,
        *,
        since: datetime | None = None,
        until: datetime | None = None,
    ) -> dict[str, EventRecord]:
        """Each of ``robots``' newest event (by ``sent_at``; of ``type`` if given; sent in
        [``since``, ``until``) if given), for those that sent one: one query for all of them (a
        page of the team), each read by the events' (robot, type, sent_at) index however many
        events it sent."""

    @abc.abstractmethod
    async def keys_received_since(self, since: datetime, limit: int) -> list[Received]:
        """What :meth:`events_received_since` finds, without the events: only their keys and
        receive times, from the index (the console's feed reads its overlap this way, cheaply)."""

    @abc.abstractmethod
    async def events_received_since(self, since: datetime, limit: int) -> list[EventRecord]:
        """The first ``limit`` events stored with ``received_at >= since``, in the order the workers
        received them (then robot, epoch and sequence number): the console's live feed."""
