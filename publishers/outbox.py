"""The robot's outbox: every event waits here, on disk, until the broker confirmed it.

The outbox is part of the robot's personal database (TinyDB). TinyDB rewrites a whole file on
every write, so one file would make each append slower as the outbox grows; the outbox is
therefore split into segment files of at most ``segment_events`` events (and ``segment_bytes``
of bodies), and bodies larger than ``blob_bytes`` (map chunks) go to a file of their own. An
append rewrites only the newest segment; a confirmed window rewrites or deletes only the oldest.

Each event type has an overflow policy: ``keep`` types (hazards, maps, behaviour outcomes,
beacon sightings) are never dropped, and an append that would pass their limit raises
:class:`OutboxFull` instead; ``drop-oldest`` types (telemetry) lose their oldest waiting entries
when the limit is reached, and the outbox counts what it dropped.

The sender takes hazards and localisations (the express lane's types) before everything else
that waits, each kind oldest first: after an outage a hazard does not wait behind the telemetry
queued before it, and the localisations that open the hazard gate come with it. Each type keeps
its own order, and so does everything that is neither (a map's chunks before its map).

Entries the broker refused for good (access refused, unroutable) move to ``refused.json`` with
the reason, so one bad event cannot block the ones behind it.
"""

from __future__ import annotations

import enum
import logging
import re
import threading
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Protocol

from tinydb import TinyDB
from tinydb.table import Document

from fleetbus.publishers.errors import PublisherError
from fleetbus.publishers.storage import AtomicJSONStorage, own_folder, write_atomically
from fleetbus.publishers.unreadable import (
    UNREADABLE,
    UNREADABLE_COUNT,
    check_counters,
    check_event,
    check_tables,
    set_aside,
)
from fleetbus.schemas.envelope import Event, encode_event
from fleetbus.schemas.routing import EXPRESS_TYPES, EventType

log = logging.getLogger("fleetbus.robot.outbox")

SEGMENT_NAME = re.compile(r"^seg-(\d{12})\.json$")
BLOB_PREFIX = "blob-"


class Overflow(str, enum.Enum):
    KEEP = "keep"
    DROP_OLDEST = "drop-oldest"


@dataclass(frozen=True)
class TypePolicy:
    overflow: Overflow
    limit: int
    """Most entries of this type that may wait."""


#: Events a segment file holds at most (by default): each append rewrites the newest segment.
SEGMENT_EVENTS = 256
#: Publishes of at most this many events may be sent while they are being written (latency);
#: larger ones are bulk and go the ordinary way, from the outbox.
EXPRESS_MAX = 16
KEEP_LIMIT = 100_000
#: Refused events whose reasons the refused list keeps, the newest: it is for reading why (the
#: counts by type are kept whole), and a broker refusing everything a robot sends would otherwise
#: grow it, and the file rewritten whole at each refusal, for ever.
REFUSED_KEPT = 1_000
#: What the sender takes first from what waits: the express lane's types.
FIRST = frozenset(t.value for t in EXPRESS_TYPES)
DEFAULT_POLICIES: Mapping[str, TypePolicy] = {
    EventType.STATUS.value: TypePolicy(Overflow.DROP_OLDEST, 10_000),
    EventType.LOCALISATION.value: TypePolicy(Overflow.DROP_OLDEST, 1_000),
    EventType.HAZARD.value: TypePolicy(Overflow.KEEP, KEEP_LIMIT),
    EventType.MAP.value: TypePolicy(Overflow.KEEP, 1_000),
    EventType.MAP_CHUNK.value: TypePolicy(Overflow.KEEP, 20_000),
    EventType.BEHAVIOUR.value: TypePolicy(Overflow.KEEP, KEEP_LIMIT),
    EventType.BEACON.value: TypePolicy(Overflow.KEEP, KEEP_LIMIT),
    EventType.ROS.value: TypePolicy(Overflow.KEEP, KEEP_LIMIT),
    EventType.ROS_CHUNK.value: TypePolicy(Overflow.KEEP, 20_000),
    EventType.MEASUREMENT.value: TypePolicy(Overflow.KEEP, KEEP_LIMIT),
}
DEFAULT_POLICY = TypePolicy(Overflow.KEEP, KEEP_LIMIT)
#: The environment variable a robot's client reads its outbox limits from (:func:`policies_with_limits`).
LIMITS_VARIABLE = "FLEETBUS_OUTBOX_LIMITS"


def policies_with_limits(
    text: str, base: Mapping[str, TypePolicy] = DEFAULT_POLICIES
) -> dict[str, TypePolicy]:
    """``base`` with the limits ``text`` sets: ``status=500 localisation=100`` (commas or spaces
    between). Each named type keeps its overflow: telemetry thinned to its newest ``N`` waiting
    (the older dropped, and counted), a type never dropped refusing the ``N+1``-th (``OutboxFull``).
    Raises ValueError naming what does not parse."""
    policies = dict(base)
    known = {t.value for t in EventType}
    for word in text.replace(",", " ").split():
        name, _, number = word.partition("=")
        if name not in known:
            known_list = ", ".join(sorted(known))
            raise ValueError(f"{LIMITS_VARIABLE}: unknown type {name!r} in {word!r}; known: {known_list}")
        if not number.isdigit() or int(number) < 1:
            raise ValueError(f"{LIMITS_VARIABLE}: {word!r} needs a whole number, 1 or more, after '='")
        policies[name] = TypePolicy(_policy(base, name).overflow, int(number))
    return policies


class ExpressJob(Protocol):
    entries: list[Entry]

    def stored(self, entries: list[Entry]) -> None:
        """Where the entries were written (positions filled in)."""

    def abandon(self) -> bool:
        """The write failed: the sender must not send them if it has not yet; True if it has (or is
        sending them), so that they may have reached the broker."""

    def wait_sent(self, timeout: float) -> None:
        """Return once the sender wrote the events to its socket (or gave up), or after ``timeout``."""


#: Longest a publisher waits for the sender to put express events on the wire before writing them.
EXPRESS_HEAD_START = 0.05

ExpressOffer = Callable[[list["Entry"]], "ExpressJob | None"]


class OutboxFull(PublisherError):
    """A type that is never dropped reached its limit; the events were not taken."""


class OutboxError(PublisherError):
    """The outbox's own files failed while the sender took or settled events (a full disk, a
    file missing or unreadable, one that no longer parses): not the network's doing, which
    reconnecting or sending again would not mend. What was taken or settled is as it was."""


class OutboxWriteFailed(OutboxError):
    """A publish's events could not all be stored (a full disk): :attr:`kept` of them, the first,
    are in the outbox and will be sent; the others (:attr:`not_kept`) are not, and were not sent
    either unless :attr:`sent` says they may have been (the sender put them on the wire while they
    were being written). To try again, hand the same events to ``RobotClient.enqueue``: the same
    epoch and sequence numbers, so the server keeps one copy of any that did reach it."""

    def __init__(self, folder: Path, events: Sequence[Event], kept: int, sent: bool, error: OSError) -> None:
        self.events = list(events)
        self.kept = kept
        self.sent = sent
        total, lost = len(self.events), len(self.events) - kept
        if kept:
            what = (
                f"stored only the first {kept} of {total} events, which will be sent; the other "
                f"{lost} were neither stored nor sent"
            )
        elif sent:
            what = (
                f"stored none of the {total} events, which the sender had already sent: the broker "
                "may have them, but they will not be sent again"
            )
        else:
            what = f"stored none of the {total} events, and none was sent"
        super().__init__(
            f"the outbox in {folder} {what} ({error!r}); to try again, enqueue the same events "
            "(error.not_kept), not new ones: the server keeps one copy of each"
        )

    @property
    def not_kept(self) -> list[Event]:
        """The events not in the outbox, to hand to ``enqueue`` again once the disk has room."""
        return self.events[self.kept :]


#: What reading or writing the outbox's files raises when they fail: the file system's errors,
#: and a file that no longer parses (JSON) or holds something else than the outbox wrote.
_FILE_ERRORS = (OSError, ValueError, KeyError, TypeError)


@dataclass(frozen=True)
class Entry:
    """One waiting event, as it goes on the wire."""

    epoch: str
    seq: int
    type: str
    message_id: str
    sent_at: datetime
    body: bytes
    position: tuple[int, int]
    """(segment number, TinyDB document id): where it waits."""


@dataclass(frozen=True)
class RefusedEntry:
    epoch: str
    seq: int
    type: str
    message_id: str
    sent_at: datetime
    reason: str
    refused_at: datetime


@dataclass(frozen=True)
class TypeSummary:
    waiting: int
    dropped: int
    refused: int
    oldest: datetime | None


@dataclass
class _Segment:
    number: int
    path: Path
    counts: Counter[str] = field(default_factory=Counter)
    bytes: int = 0
    db: TinyDB | None = None

    @property
    def size(self) -> int:
        return sum(self.counts.values())


def _entry_of(event: Event, body: bytes, position: tuple[int, int]) -> Entry:
    return Entry(
        event.epoch, event.seq, event.type.value, str(event.message_id), event.sent_at, body, position
    )


def _policy(policies: Mapping[str, TypePolicy], event_type: str) -> TypePolicy:
    return policies.get(event_type, DEFAULT_POLICY)


def _parse_time(text: str) -> datetime:
    return datetime.fromisoformat(text)


class Outbox:
    def __init__(
        self,
        folder: Path,
        policies: Mapping[str, TypePolicy] = DEFAULT_POLICIES,
        *,
        durable: bool = True,
        segment_events: int = SEGMENT_EVENTS,
        segment_bytes: int = 1 << 20,
        blob_bytes: int = 64 << 10,
        read_only: bool = False,
    ) -> None:
        """``read_only``: look into the outbox of a robot that may be running, changing nothing."""
        self.folder = folder
        self.policies = policies
        self._durable = durable
        self._segment_events = segment_events
        self._segment_bytes = segment_bytes
        self._blob_bytes = blob_bytes
        self._read_only = read_only
        self._lock = threading.RLock()
        self._in_flight: set[tuple[int, int]] = set()
        self._first_in_flight: set[tuple[int, int]] = set()
        """Those of :data:`FIRST`'s types (a segment holding none waiting is not read for them)."""
        if not read_only:
            own_folder(folder)
        elif not folder.is_dir():
            raise FileNotFoundError(f"no outbox at {folder}")
        self._set_aside = 0
        """Files found unreadable on opening and set aside, not yet counted as dropped."""
        self._meta = self._readable_db(
            "meta.json", check_counters, "the counts of the events dropped and refused until now"
        )
        self._refused = self._readable_db(
            "refused.json",
            check_tables,
            "the reasons of the events the broker refused (those events were not to be sent again)",
        )
        self._segments: list[_Segment] = []
        self._dropped: Counter[str] | None = None
        self._recover()
        if self._set_aside:
            self._count("dropped", UNREADABLE_COUNT, self._set_aside)

    @contextmanager
    def _own_files(self, doing: str) -> Iterator[None]:
        """Raise what the outbox's files fail with, while ``doing``, as :class:`OutboxError`."""
        try:
            yield
        except _FILE_ERRORS as error:
            raise OutboxError(f"the outbox in {self.folder} could not {doing}: {error!r}") from error

    # ------------------------------------------------------------------ opening and recovery

    def _readable_db(self, name: str, check: Callable[[Any], None], holds: str) -> TinyDB:
        """The TinyDB file ``name``, set aside first if what it holds does not parse (``check``)."""
        path = self.folder / name
        db = TinyDB(path, storage=AtomicJSONStorage, durable=self._durable)
        try:
            check(db.storage.read())
        except UNREADABLE as error:
            db.close()
            self._unreadable(path, error, holds)
            db = TinyDB(path, storage=AtomicJSONStorage, durable=self._durable)
        return db

    def _unreadable(self, path: Path, error: Exception, holds: str) -> None:
        """Set aside a file found unreadable on opening, so that the robot starts all the same;
        one only looked into (``read_only``) raises :class:`OutboxError` naming it instead."""
        if self._read_only:
            raise OutboxError(f"the outbox in {self.folder} cannot read {path.name}: {error!r}") from error
        moved = set_aside(path)
        self._set_aside += 1
        log.error(
            "the outbox file %s cannot be read (%r): set aside as %s, never deleted, and counted as "
            "dropped (%s); lost with it: %s",
            path,
            error,
            moved.name,
            UNREADABLE_COUNT,
            holds,
        )

    def _recover(self) -> None:
        """Index the segments left by an earlier run; drop leftovers of writes a crash cut short."""
        referenced: set[str] = set()
        for path in sorted(self.folder.iterdir()):
            if path.name.startswith(".") and path.name.endswith(".tmp"):
                if not self._read_only:
                    path.unlink()
                continue
            match = SEGMENT_NAME.match(path.name)
            if not match:
                continue
            segment = _Segment(int(match[1]), path)
            try:
                docs = self._docs(segment)
                for doc in docs:
                    check_event(doc)
            except UNREADABLE as error:
                if segment.db is not None:
                    segment.db.close()
                    segment.db = None
                lost = path.read_bytes().count(b'"message_id"')
                self._unreadable(path, error, f"about {lost} events that waited in it, not sent")
                continue
            for doc in docs:
                segment.counts[doc["type"]] += 1
                segment.bytes += len(doc.get("body", ""))
                if "blob" in doc:
                    referenced.add(doc["blob"])
            self._release(segment)
            if segment.size:
                self._segments.append(segment)
            elif not self._read_only:
                path.unlink()
        if self._read_only:
            return
        for path in self.folder.glob(f"{BLOB_PREFIX}*.json"):
            if path.name in referenced:
                continue
            if self._set_aside:  # perhaps a body of an event in a file set aside: kept with it
                set_aside(path)
            else:
                path.unlink()  # written just before a crash, never appended

    def _open(self, segment: _Segment) -> TinyDB:
        if segment.db is None:
            segment.db = TinyDB(segment.path, storage=AtomicJSONStorage, durable=self._durable)
        return segment.db

    def _release(self, segment: _Segment) -> None:
        """Forget a segment's cached contents unless it is the newest (appends), the oldest
        (drains) or has entries in flight (its settle comes soon)."""
        if (
            segment.db is not None
            and (not self._segments or segment not in (self._segments[0], self._segments[-1]))
            and not any(number == segment.number for number, _ in self._in_flight)
        ):
            segment.db.close()
            segment.db = None

    def _docs(self, segment: _Segment) -> list[Any]:
        return sorted(self._open(segment).table("events").all(), key=lambda doc: doc.doc_id)

    def _raw_docs(self, segment: _Segment) -> list[tuple[int, dict[str, Any]]]:
        """The segment's events as stored, by position: for reading only. Without TinyDB's copy of
        each into a Document, which was 7 % of the sender's time in a drain."""
        stored = (self._open(segment).storage.read() or {}).get("events", {})
        return sorted((int(doc_id), doc) for doc_id, doc in stored.items())

    def close(self) -> None:
        with self._lock:
            for segment in self._segments:
                if segment.db is not None:
                    segment.db.close()
                    segment.db = None
            self._meta.close()
            self._refused.close()

    # ------------------------------------------------------------------ appending

    def append(self, events: Sequence[Event], express: ExpressOffer | None = None) -> None:
        """Store events durably, in order; raise :class:`OutboxFull` (taking none) past a keep limit.

        ``express``: when nothing waits or is in flight, the events are offered to the sender before
        they are written, so the network send and the fsync overlap; an accepted offer learns where
        they were stored (or that the write failed) and they stay in flight until it settles them.
        """
        if not events:
            return
        with self._lock:
            adding = Counter(event.type.value for event in events)
            counts = self.counts()
            for event_type, n in adding.items():
                policy = _policy(self.policies, event_type)
                if policy.overflow is Overflow.KEEP and counts[event_type] + n > policy.limit:
                    raise OutboxFull(
                        f"{counts[event_type]} {event_type} events wait already and {event_type} is never "
                        f"dropped; its limit is {policy.limit}"
                    )
            bodies = [encode_event(event) for event in events]
            job = None
            if (
                express is not None
                and len(events) <= EXPRESS_MAX
                and not self._segments
                and not self._in_flight
                and len(events) <= self._segment_events  # one segment: stored whole or not at all
            ):
                job = express(
                    [_entry_of(event, body, (-1, -1)) for event, body in zip(events, bodies, strict=True)]
                )
                if job is not None:
                    # Let the sender put them on the wire first: writing the segment here would
                    # hold the interpreter lock and keep the sender thread from running for most
                    # of the write (about 1 ms); the fsync then overlaps the broker's work.
                    job.wait_sent(EXPRESS_HEAD_START)
            positions: list[tuple[int, int]] = []
            try:
                self._write(events, bodies, positions)
            except OSError as error:
                sent = job.abandon() if job is not None else False
                raise OutboxWriteFailed(self.folder, events, len(positions), sent, error) from error
            except BaseException:
                if job is not None:
                    job.abandon()
                raise
            if job is not None:
                self._in_flight |= set(positions)
                job.stored(
                    [replace(entry, position=p) for entry, p in zip(job.entries, positions, strict=True)]
                )
            for event_type in adding:
                self._enforce_drop_limit(event_type)

    def _write(
        self, events: Sequence[Event], bodies: Sequence[bytes], positions: list[tuple[int, int]]
    ) -> None:
        """Write the events, segment after segment, adding where each went to ``positions``: when
        a write fails, those it holds are stored (and will be sent), the others are not."""
        start = 0
        while start < len(events):
            segment = self._tail_with_room()
            room = max(1, self._segment_events - segment.size)
            part = [
                self._doc(event, body)
                for event, body in zip(
                    events[start : start + room], bodies[start : start + room], strict=True
                )
            ]
            try:
                ids = self._open(segment).table("events").insert_multiple(part)
            except BaseException:
                if not segment.size:  # begun for this write, never written
                    self._unlink_segment(segment, missing_ok=True)
                raise
            positions += [(segment.number, doc_id) for doc_id in ids]
            for doc in part:
                segment.counts[doc["type"]] += 1
                segment.bytes += len(doc.get("body", ""))
            start += len(part)

    def _doc(self, event: Event, body: bytes) -> dict[str, Any]:
        doc: dict[str, Any] = {
            "epoch": event.epoch,
            "seq": event.seq,
            "type": event.type.value,
            "message_id": str(event.message_id),
            "sent_at": event.sent_at.isoformat(),
        }
        blob = self._blob_path(str(event.message_id), body)
        if blob is not None:
            write_atomically(blob, body, self._durable)
            doc["blob"] = blob.name
        else:
            doc["body"] = body.decode()
        return doc

    def _tail_with_room(self) -> _Segment:
        if self._segments:
            tail = self._segments[-1]
            if tail.size < self._segment_events and tail.bytes < self._segment_bytes:
                return tail
        number = self._segments[-1].number + 1 if self._segments else 0
        segment = _Segment(number, self.folder / f"seg-{number:012d}.json")
        self._segments.append(segment)
        if len(self._segments) > 2:
            self._release(self._segments[-2])
        return segment

    def _enforce_drop_limit(self, event_type: str) -> None:
        policy = _policy(self.policies, event_type)
        excess = self.counts()[event_type] - policy.limit
        if policy.overflow is not Overflow.DROP_OLDEST or excess <= 0:
            return
        dropped = 0
        for segment in list(self._segments):
            if dropped == excess:
                break
            if not segment.counts[event_type]:
                continue
            doomed = [
                doc
                for doc in self._docs(segment)
                if doc["type"] == event_type and (segment.number, doc.doc_id) not in self._in_flight
            ][: excess - dropped]
            self._remove(segment, doomed)
            dropped += len(doomed)
        if dropped:
            self._count("dropped", event_type, dropped)

    # ------------------------------------------------------------------ draining

    def take(self, limit: int, whole_segments: bool = False) -> list[Entry]:
        """The ``limit`` entries to send next, not in flight yet, marked in flight until :meth:`settle`:
        the waiting ones of :data:`FIRST`'s types, oldest first, then the others, oldest first.

        A sender may take the next window while the broker still confirms the last one. With
        ``whole_segments`` the take of the others stops before a segment it could only take part
        of (unless that is the first): settling it then deletes segment files without reading
        them again. Raises :class:`OutboxError` when a file fails, taking nothing.
        """
        with self._lock:
            in_flight, first_in_flight = set(self._in_flight), set(self._first_in_flight)
            try:
                with self._own_files("read the events to send"):
                    return self._take(limit, whole_segments)
            except OutboxError:
                self._in_flight, self._first_in_flight = in_flight, first_in_flight
                raise

    def _take(self, limit: int, whole_segments: bool) -> list[Entry]:
        entries, stopped = self._take_first(limit, whole_segments)
        flying = Counter(number for number, _ in self._in_flight)
        read: list[_Segment] = []
        # the first segment this take reads may be taken in part, unless the first take stopped
        taken_first = 0 if stopped else len(entries)
        for segment in self._segments:
            if len(entries) == limit:
                break
            waiting = segment.size - flying[segment.number]
            if waiting <= 0:
                continue  # all of it is being sent already
            if whole_segments and len(entries) > taken_first and len(entries) + waiting > limit:
                break
            read.append(segment)
            for doc_id, doc in self._raw_docs(segment):
                if len(entries) == limit:
                    break
                if (segment.number, doc_id) not in self._in_flight:
                    entries.append(self._entry(segment, doc_id, doc))
                    self._in_flight.add((segment.number, doc_id))
        for segment in read:
            self._release(segment)
        return entries

    def _take_first(self, limit: int, whole_segments: bool) -> tuple[list[Entry], bool]:
        """Up to ``limit`` waiting entries of :data:`FIRST`'s types, oldest first, marked in flight.

        All of them, including those that wait behind nothing (the telemetry before them is in
        flight already): taking only those behind telemetry would send a later hazard before an
        earlier one, which the express lane receives out of order. True with them if it stopped
        before a segment of theirs only that it could not take whole."""
        entries: list[Entry] = []
        flying = Counter(number for number, _ in self._first_in_flight)
        for segment in self._segments:
            if len(entries) == limit:
                break
            firsts = sum(segment.counts[t] for t in FIRST)
            waiting = firsts - flying[segment.number]
            if waiting <= 0:
                continue  # none of them waits here (or all are being sent)
            if whole_segments and entries and firsts == segment.size and len(entries) + waiting > limit:
                return entries, True  # as the oldest-first take does: a segment of theirs only, whole
            for doc_id, doc in self._raw_docs(segment):
                position = (segment.number, doc_id)
                if len(entries) == limit:
                    break
                if doc["type"] in FIRST and position not in self._in_flight:
                    entries.append(self._entry(segment, doc_id, doc))
                    self._in_flight.add(position)
                    self._first_in_flight.add(position)
            self._release(segment)
        return entries, False

    def _entry(self, segment: _Segment, doc_id: int, doc: dict[str, Any]) -> Entry:
        body = (self.folder / doc["blob"]).read_bytes() if "blob" in doc else doc["body"].encode()
        return Entry(
            epoch=doc["epoch"],
            seq=doc["seq"],
            type=doc["type"],
            message_id=doc["message_id"],
            sent_at=_parse_time(doc["sent_at"]),
            body=body,
            position=(segment.number, doc_id),
        )

    def settle(
        self,
        confirmed: Iterable[Entry],
        refused: Mapping[str, str] | None = None,
        window: Iterable[Entry] | None = None,
    ) -> None:
        """Remove confirmed entries and move refused ones (message id -> reason) aside.

        ``window`` is the whole take they came from (default: all in flight). Entries of it neither
        confirmed nor refused (nacked) stay, in their place, for the next take. Raises
        :class:`OutboxError` when a file fails; settling the same again then finishes the work.
        """
        with self._lock, self._own_files("settle the events the broker answered"):
            self._settle(confirmed, refused or {}, window)

    def _settle(
        self, confirmed: Iterable[Entry], refused: Mapping[str, str], window: Iterable[Entry] | None
    ) -> None:
        taken = list(confirmed)
        done = None if window is None else {entry.position for entry in window}
        by_segment: dict[int, list[Entry]] = {}
        refused_docs: list[dict[str, Any]] = []
        now = datetime.now(timezone.utc).isoformat()
        for entry in taken:
            by_segment.setdefault(entry.position[0], []).append(entry)
            if entry.message_id in refused:
                refused_docs.append(
                    {
                        "epoch": entry.epoch,
                        "seq": entry.seq,
                        "type": entry.type,
                        "message_id": entry.message_id,
                        "sent_at": entry.sent_at.isoformat(),
                        "reason": refused[entry.message_id],
                        "refused_at": now,
                    }
                )
        if refused_docs:
            self._keep_refused(refused_docs)
        for segment in list(self._segments):
            leaving = by_segment.get(segment.number)
            if not leaving:
                continue
            ids = {entry.position[1] for entry in leaving}
            if len(ids) == segment.size and all(entry.position in self._in_flight for entry in leaving):
                # every event it holds is confirmed (in flight, nothing else removed them):
                # delete it without reading it again
                self._delete_segment(segment, leaving)
            else:
                self._remove(segment, [doc for doc in self._docs(segment) if doc.doc_id in ids])
        self._in_flight = set() if done is None else self._in_flight - done
        self._first_in_flight &= self._in_flight

    def release(self) -> None:
        """Nothing of the last take was settled (the connection broke): it waits again, and counts
        again against the drop limits it was spared while in flight. Raises :class:`OutboxError`
        when a file fails while the limits are applied (the take waits again all the same)."""
        with self._lock:
            types = {t for segment in self._segments for t, n in segment.counts.items() if n}
            self._in_flight = set()
            self._first_in_flight = set()
            with self._own_files("apply the drop limits to the events put back"):
                for event_type in types:
                    self._enforce_drop_limit(event_type)

    def _blob_path(self, message_id: str, body: bytes) -> Path | None:
        """Where a body too large to wait inside a segment waits instead; None for the others."""
        return self.folder / f"{BLOB_PREFIX}{message_id}.json" if len(body) > self._blob_bytes else None

    def _delete_segment(self, segment: _Segment, entries: Sequence[Entry]) -> None:
        """Delete a segment all of whose ``entries`` are leaving, and their blobs."""
        self._unlink_segment(segment)
        for entry in entries:
            blob = self._blob_path(entry.message_id, entry.body)
            if blob is not None:
                blob.unlink(missing_ok=True)

    def _unlink_segment(self, segment: _Segment, missing_ok: bool = False) -> None:
        if segment.db is not None:
            segment.db.close()
            segment.db = None
        segment.path.unlink(missing_ok=missing_ok)
        self._segments.remove(segment)

    def _remove(self, segment: _Segment, docs: Sequence[Any]) -> None:
        if not docs:
            return
        if len(docs) == segment.size:
            self._unlink_segment(segment)
        else:
            self._open(segment).table("events").remove(doc_ids=[doc.doc_id for doc in docs])
            for doc in docs:
                segment.counts[doc["type"]] -= 1
                segment.bytes -= len(doc.get("body", ""))
            self._release(segment)
        for doc in docs:
            if "blob" in doc:
                (self.folder / doc["blob"]).unlink(missing_ok=True)

    # ------------------------------------------------------------------ what waits

    def counts(self) -> Counter[str]:
        with self._lock:
            total: Counter[str] = Counter()
            for segment in self._segments:
                total.update(segment.counts)
            return +total

    def pending(self) -> int:
        return sum(self.counts().values())

    def entries(self, limit: int | None = None) -> list[Entry]:
        """Waiting entries, oldest first (without marking them in flight)."""
        with self._lock:
            out: list[Entry] = []
            for segment in self._segments:
                for doc_id, doc in self._raw_docs(segment):
                    if limit is not None and len(out) == limit:
                        return out
                    out.append(self._entry(segment, doc_id, doc))
                self._release(segment)
            return out

    def refused(self) -> list[RefusedEntry]:
        with self._lock:
            return [
                RefusedEntry(
                    epoch=doc["epoch"],
                    seq=doc["seq"],
                    type=doc["type"],
                    message_id=doc["message_id"],
                    sent_at=_parse_time(doc["sent_at"]),
                    reason=doc["reason"],
                    refused_at=_parse_time(doc["refused_at"]),
                )
                for doc in self._refused.table("refused").all()
            ]

    def _keep_refused(self, docs: list[dict[str, Any]]) -> None:
        """Under the lock: count them, and keep their reasons in the list, its newest only."""
        table = self._refused.table("refused")
        rows = table.all()  # read once: the file is read again at each of TinyDB's reads
        if self._counter("refused") == Counter() and rows:
            # counted from the list, once: an outbox from before the counts were kept
            for event_type, n in Counter(doc["type"] for doc in rows).items():
                self._count("refused", event_type, n)
        kept = {doc["message_id"] for doc in rows}
        docs = [doc for doc in docs if doc["message_id"] not in kept]  # a settle tried again
        for event_type, n in Counter(doc["type"] for doc in docs).items():
            self._count("refused", event_type, n)
        ids = [row.doc_id for row in rows] + table.insert_multiple(docs)
        beyond = len(ids) - REFUSED_KEPT
        if beyond > 0:
            table.remove(doc_ids=sorted(ids)[:beyond])

    def dropped(self) -> Counter[str]:
        """What the thinning dropped, by type, since the outbox was made (kept on disk)."""
        with self._lock:
            if self._dropped is None:
                self._dropped = self._counter("dropped")
            return Counter(self._dropped)

    def refused_counts(self) -> Counter[str]:
        """What the broker refused, by type, since the outbox was made (its list keeps the newest)."""
        with self._lock:
            return self._counter("refused") or Counter(entry.type for entry in self.refused())

    def summary(self) -> dict[str, TypeSummary]:
        """Per type: how many wait, the oldest one's time, how many were dropped or refused."""
        with self._lock:
            oldest: dict[str, datetime] = {}
            for segment in self._segments:
                missing = [t for t, n in segment.counts.items() if n and t not in oldest]
                if missing:
                    for doc in self._docs(segment):
                        oldest.setdefault(doc["type"], _parse_time(doc["sent_at"]))
                    self._release(segment)
            waiting = self.counts()
            dropped = self.dropped()
            refused = self.refused_counts()
            types = sorted(set(waiting) | set(dropped) | set(refused))
            never = datetime.max.replace(tzinfo=timezone.utc)
            return {
                t: TypeSummary(waiting[t], dropped[t], refused[t], oldest.get(t))
                for t in sorted(types, key=lambda t: (oldest.get(t, never), t))
            }

    def _counter(self, name: str) -> Counter[str]:
        doc = self._meta.table("counters").get(doc_id=1)
        return Counter(doc.get(name, {})) if doc else Counter()

    def _count(self, name: str, event_type: str, n: int) -> None:
        table = self._meta.table("counters")
        doc = dict(table.get(doc_id=1) or {})
        counts = dict(doc.get(name, {}))
        counts[event_type] = counts.get(event_type, 0) + n
        doc[name] = counts
        table.upsert(Document(doc, doc_id=1))
        if name == "dropped":
            self._dropped = Counter(counts)
