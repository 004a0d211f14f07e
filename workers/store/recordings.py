"""The recording: every message seen on the bus, one collection (or table) per message type.

This is the recorder's storage, apart from the event log the services use, and the system of
record for the bus's traffic: what was received, as received (properties, headers, a body that
is not JSON as bytes), accepted or not, including types no schema knows. The event log
(:class:`~fleetbus.workers.store.repositories.EventLog`) is the system of record for validated
events; both are kept (``docs/decisions/0007-store-repositories.md`` says why). Each record
carries when it was recorded and where it came from (the broker-validated ``user_id``, exchange,
routing key).

Queries name fields of the stored document by dotted paths (``body.name``, ``frame``) and
compare them with JSON scalars; both adapters give the same answers (``tests/store``).
"""

from __future__ import annotations

import abc
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime
from enum import Enum
from typing import Any, Union

from fleetbus.schemas.ros import BLOB_KEY, ROS_TYPE, byte_arrays
from fleetbus.workers.store.base import WriteResult
from fleetbus.workers.store.port import (
    INTEGER,
    JSON,
    TEXT,
    TIME,
    Database,
    In,
    Index,
    Range,
    Schema,
    prune_oldest,
)

Scalar = Union[str, int, float, bool, None]  # noqa: UP007  (a runtime alias; Python 3.10 reads it)

#: Type names become table and collection names: short, lower case, nothing a query could abuse.
TYPE_NAME = re.compile(r"^[a-z][a-z0-9_]{0,39}$")
#: A blob's name: the SHA-256 of its bytes, in lower-case hex.
BLOB_DIGEST = re.compile(r"^[0-9a-f]{64}$")
#: One segment of a field path: a key (letters, digits, ``_``, ``-``) or an array index.
PATH_SEGMENT = re.compile(r"^(?:[A-Za-z_][A-Za-z0-9_-]{0,63}|[0-9]{1,6})$")


class RecordingError(ValueError):
    """A query the recording cannot run; the message names the problem."""


def check_type_name(name: str) -> str:
    if not TYPE_NAME.fullmatch(name):
        raise RecordingError(
            f"invalid type {name!r}: use 1-40 lower-case letters, digits or '_', starting with a letter"
        )
    return name


def check_digest(digest: str) -> str:
    if not BLOB_DIGEST.fullmatch(digest):
        raise RecordingError(f"invalid blob name {digest!r}: a SHA-256 in lower-case hex")
    return digest


def check_path(path: str) -> tuple[str, ...]:
    """The segments of a dotted field path, or :class:`RecordingError` naming the bad one."""
    segments = tuple(path.split("."))
    for segment in segments:
        if not PATH_SEGMENT.fullmatch(segment):
            raise RecordingError(
                f"invalid field {path!r}: segment {segment!r} must be a name (letters, digits, '_', '-') "
                "or an array index"
            )
    return segments


@dataclass(frozen=True)
class RecordedMessage:
    """One message as the recorder received it, with its provenance."""

    key: str
    """Idempotency key: the same message delivered twice is recorded once."""
    type: str
    recorded_at: datetime
    exchange: str
    """The exchange it was published to (the robot's own ``<robot>.events`` for events)."""
    routing_key: str
    user_id: str | None
    """The broker-validated publisher (AMQP ``user_id``); None when the publisher set none."""
    robot_id: str | None
    """The robot it came from (events, requests, dead letters); None for the service's messages."""
    message_id: str | None = None
    mission_id: str | None = None
    sent_at: datetime | None = None
    seq: int | None = None
    known: bool = False
    """Whether a fleetbus schema describes this type; unknown types are stored as received."""
    problem: str | None = None
    """Why the body is kept raw or not at all (not JSON, too large, not storable as a document)."""
    document: Any = None
    """The body as parsed JSON, as received; None when kept raw."""
    raw: bytes | None = None
    """The body's bytes, when it is not JSON (or not storable as a document); empty when the body
    was not kept at all (too large)."""
    properties: dict[str, Any] = field(default_factory=dict)
    """AMQP properties and headers that matter for replay and analysis, JSON-safe."""
    size: int = 0
    """Bytes of the message body as received."""
    received: bytes | None = field(default=None, compare=False, repr=False)
    """The body's bytes while the record is written (not stored: for a store that must keep it raw)."""

    @property
    def body_kept(self) -> bool:
        return not (self.raw == b"" and self.size > 0)

    def body_bytes(self) -> bytes | None:
        """The body to send again: the bytes kept raw, or the JSON re-encoded; None when not kept."""
        if self.received is not None:
            return self.received
        if self.raw is not None:
            return self.raw if self.body_kept else None
        return json.dumps(self.document, separators=(",", ":"), ensure_ascii=False).encode()

    def as_raw(self, problem: str, body: bytes) -> RecordedMessage:
        """The same record with the body kept as bytes, saying why (for a store that cannot hold it)."""
        return replace(self, document=None, raw=body, problem=problem)


class Op(str, Enum):
    EQ = "="
    NE = "!="
    LT = "<"
    LE = "<="
    GT = ">"
    GE = ">="
    CONTAINS = "~"


ORDERING = (Op.LT, Op.LE, Op.GT, Op.GE)


@dataclass(frozen=True)
class Condition:
    """``path op value`` on the stored document.

    ``= null`` matches a missing or null field and ``!= null`` a present one; ``!=`` also
    matches documents without the field. Ordering compares numbers with numbers and strings
    with strings only; ``~`` is a case-sensitive substring test on strings.
    """

    path: str
    op: Op
    value: Scalar

    def __post_init__(self) -> None:
        check_path(self.path)
        if self.op in ORDERING and (self.value is None or isinstance(self.value, bool)):
            raise RecordingError(f"{self.path} {self.op.value} {self.value!r}: order by a number or a string")
        if self.op is Op.CONTAINS and not isinstance(self.value, str):
            raise RecordingError(f"{self.path} ~ {self.value!r}: '~' looks for a string")


@dataclass(frozen=True)
class RecordQuery:
    type: str
    conditions: tuple[Condition, ...] = ()
    robot_id: str | None = None
    message_id: str | None = None
    since: datetime | None = None
    """Inclusive lower bound on ``recorded_at``."""
    until: datetime | None = None
    """Exclusive upper bound on ``recorded_at``."""
    limit: int | None = None
    newest_first: bool = False
    mission_id: str | None = None
    after: tuple[datetime, str] | None = None
    """Only records after this ``(recorded_at, key)`` in recording order: the next page of a
    window read oldest first, ``limit`` records at a time."""


@dataclass(frozen=True)
class TypeSummary:
    type: str
    records: int
    bytes: int
    """Sum of the recorded bodies' sizes."""
    first: datetime | None
    last: datetime | None


#: Decimal places kept of computed means and deviations (durations in seconds: nanoseconds).
DIGITS = 9


@dataclass(frozen=True)
class OutcomeStats:
    """Successes, failures and duration of one group (one behaviour), as the database computed them."""

    name: str
    successes: int
    failures: int
    mean_duration: float
    std_duration: float
    """Population standard deviation, as in the reference's MapReduce ``finalize``."""

    @property
    def runs(self) -> int:
        return self.successes + self.failures

    @property
    def success_rate(self) -> float:
        return self.successes / self.runs if self.runs else 0.0

    @classmethod
    def of(cls, name: str, successes: int, runs: int, mean: float, std: float) -> OutcomeStats:
        """What an adapter's database computed, rounded alike (the last bits of a float sum depend
        on the order and method of summation, which differ between databases)."""
        return cls(name, int(successes), int(runs - successes), round(mean, DIGITS), round(std, DIGITS))


@dataclass(frozen=True)
class OutcomeFields:
    """Where a type's documents keep the group name, the success flag and the duration."""

    name: str = "body.name"
    success: str = "body.success"
    duration: str = "body.duration_s"


@dataclass(frozen=True)
class StorageSample:
    """The recorder's periodic look at the database: its size, and what it inserted since the last look."""

    sampled_at: datetime
    run_id: str
    database_bytes: int
    inserted: int


SAMPLES = Schema(
    "recorder_samples",
    {"run_id": TEXT, "sampled_at": TIME, "database_bytes": INTEGER, "inserted": INTEGER},
    key=("run_id", "sampled_at"),
    indexes=(Index("sampled_at"),),
)
FIELD_INDEXES = Schema(
    "recording_field_indexes",
    {"type": TEXT, "name": TEXT, "paths": JSON, "used_at": TIME},
    key=("type", "name"),
)
"""The field indexes a database holds for each type, by the name it gave them, and when each was
last asked for (the least recently used is dropped first)."""
PIECES = Schema(
    "recording_pieces",
    {"name": TEXT, "robot_id": TEXT.maybe, "staged_at": TIME},
    key=("name",),
    indexes=(Index("staged_at"),),
)
"""The pieces of large ROS byte arrays (``ros_chunk``) waiting in the blob store for the message
that names them, by their name there, from when: those whose message never came are swept."""
BLOB_REFS = Schema(
    "recording_blob_refs",
    {"type": TEXT, "key": TEXT, "digest": TEXT, "recorded_at": TIME},
    key=("type", "key", "digest"),
    indexes=(Index("digest"), Index("type", "recorded_at")),
)
"""Which record names which blob: retention deletes a blob with the last record naming it (the
same bytes are kept once, and may be named by records of other types or times)."""
#: References a deletion reads and forgets in one step.
REFS_BATCH = 500


def blobs_named(record: RecordedMessage) -> set[str]:
    """The digests of the blobs a record's document names (``{"_blob": sha256, ...}``)."""
    # only ROS messages (live or from a bag) name blobs: every other record is not walked
    if record.type != ROS_TYPE or not isinstance(record.document, dict):
        return set()
    return {str(found[BLOB_KEY]) for found in byte_arrays(record.document, BLOB_KEY)}


class Bookkeeping:
    """What the recording keeps about itself, written once over the persistence port: its storage
    samples, and its field indexes and their use."""

    def __init__(self, database: Database, max_field_indexes: int) -> None:
        self.max_field_indexes = max_field_indexes
        self._samples = database.collection(SAMPLES)
        self._indexes = database.collection(FIELD_INDEXES)
        self._pieces = database.collection(PIECES)
        self._refs = database.collection(BLOB_REFS)

    async def add_sample(self, sample: StorageSample) -> None:
        await self._samples.insert([sample.__dict__])

    async def prune_samples(self, before: datetime | None, keep: int | None, limit: int) -> int:
        """Up to ``limit`` of the oldest samples: older than ``before``, then beyond the newest ``keep``."""
        return await prune_oldest(self._samples, "sampled_at", before, keep, limit, order="sampled_at")

    async def samples(self, since: datetime | None = None) -> list[StorageSample]:
        where = {} if since is None else {"sampled_at": Range(ge=since)}
        return [
            StorageSample(**doc) for doc in await self._samples.find(where, order=["sampled_at", "run_id"])
        ]

    async def used(self, type: str, name: str, at: datetime) -> bool:
        """Note that the index ``name`` was asked for; False when there is none by that name."""
        return await self._indexes.update({"type": type, "name": name}, {"used_at": at}) == 1

    async def make_room(self, type: str) -> list[tuple[str, tuple[str, ...]]]:
        """Forget the least recently used indexes of ``type`` beyond room for one more; their names
        and paths (the caller drops them)."""
        held = await self._indexes.find({"type": type}, order=["used_at", "name"])
        dropped = held[: max(0, len(held) - self.max_field_indexes + 1)]
        for index in dropped:
            await self._indexes.delete({"type": type, "name": index["name"]})
        return [(index["name"], tuple(index["paths"])) for index in dropped]

    async def made(self, type: str, name: str, paths: Sequence[str], at: datetime) -> None:
        await self._indexes.put({"type": type, "name": name, "paths": list(paths), "used_at": at})

    async def piece_staged(self, name: str, robot_id: str | None, at: datetime) -> None:
        """Note a piece in the blob store (before it is written); a piece noted already keeps its time."""
        await self._pieces.insert([{"name": name, "robot_id": robot_id, "staged_at": at}])

    async def pieces_settled(self, names: Sequence[str]) -> None:
        if names:
            await self._pieces.delete({"name": In(list(names))})

    async def pieces_staged_before(self, before: datetime, limit: int) -> list[tuple[str, str | None]]:
        """``(name, robot)`` of the oldest pieces noted before ``before``, ``limit`` at most."""
        where = {"staged_at": Range(lt=before)}
        found = await self._pieces.find(where, order=["staged_at", "name"], limit=limit)
        return [(doc["name"], doc["robot_id"]) for doc in found]

    async def blobs_referenced(self, records: Sequence[RecordedMessage]) -> None:
        """Note the blobs each record names (before the records are written: a record stored is
        never without its references)."""
        refs = [
            {"type": record.type, "key": record.key, "digest": digest, "recorded_at": record.recorded_at}
            for record in records
            for digest in sorted(blobs_named(record))
        ]
        if not refs:
            return
        for ref, inserted in zip(refs, await self._refs.insert(refs), strict=True):
            if not inserted:  # the message again (redelivered): its record, if not yet written, takes
                # this time, so the reference does too, lest retention by age release it first
                where = {"type": ref["type"], "key": ref["key"], "digest": ref["digest"]}
                await self._refs.update({**where, "recorded_at": Range(lt=ref["recorded_at"])}, ref)

    async def refs_of(self, type: str, keys: Sequence[str]) -> list[dict[str, Any]]:
        found: list[dict[str, Any]] = []
        for start in range(0, len(keys), REFS_BATCH):
            found += await self._refs.find({"type": type, "key": In(list(keys[start : start + REFS_BATCH]))})
        return found

    async def refs_before(self, type: str, before: datetime, limit: int) -> list[dict[str, Any]]:
        where = {"type": type, "recorded_at": Range(lt=before)}
        return await self._refs.find(where, order=["recorded_at", "key"], limit=limit)

    async def release(self, type: str, refs: Sequence[dict[str, Any]]) -> list[str]:
        """Forget ``refs`` (of records of ``type`` deleted); the digests no record names any more."""
        keys = sorted({ref["key"] for ref in refs})
        for start in range(0, len(keys), REFS_BATCH):
            await self._refs.delete({"type": type, "key": In(keys[start : start + REFS_BATCH])})
        digests = sorted({ref["digest"] for ref in refs})
        return [digest for digest in digests if not await self._refs.find({"digest": digest}, limit=1)]

    async def field_indexes(self, type: str) -> list[tuple[str, ...]]:
        return sorted(tuple(index["paths"]) for index in await self._indexes.find({"type": type}))


class RecordingStore(abc.ABC):
    """Async storage of recorded messages. Implementations: SQLite (embedded) and MongoDB; what
    the recording keeps about itself is written once (:class:`Bookkeeping`)."""

    name: str
    bookkeeping: Bookkeeping

    @abc.abstractmethod
    async def open(self) -> None: ...

    @abc.abstractmethod
    async def close(self) -> None: ...

    async def write_recorded(self, records: Sequence[RecordedMessage]) -> list[WriteResult]:
        """Store a batch durably (one collection per type, made on first sight), skipping known keys.

        Returns one result per record, in order. A record the database cannot hold as a
        document is stored with its body raw and a ``problem`` saying so, never dropped.
        Raises :class:`~workers.store.base.StoreUnavailable` when the database cannot be reached.
        """
        await self.bookkeeping.blobs_referenced(records)
        return await self._write_records(records)

    @abc.abstractmethod
    async def _write_records(self, records: Sequence[RecordedMessage]) -> list[WriteResult]:
        """:meth:`write_recorded` in the database, the blobs' references noted already."""

    @abc.abstractmethod
    async def find_recorded(self, query: RecordQuery) -> list[RecordedMessage]:
        """Records of one type matching the query, by ``recorded_at`` then key."""

    @abc.abstractmethod
    async def recorded_types(self) -> list[str]:
        """The name of every type recorded so far, sorted."""

    # Large values (an image's pixels) are kept apart from the documents, by their content's
    # SHA-256 (lower-case hex): the same bytes are kept once.
    @abc.abstractmethod
    async def put_blob(self, digest: str, data: bytes) -> bool:
        """Keep ``data`` under ``digest`` (its SHA-256, checked by the caller); True when it was
        not kept yet, durably when this returns."""

    @abc.abstractmethod
    async def get_blob(self, digest: str) -> bytes | None:
        """The bytes kept under ``digest``, or None."""

    @abc.abstractmethod
    async def delete_blobs(self, digests: Sequence[str]) -> int:
        """Forget the bytes kept under ``digests`` (those kept); how many were kept."""

    @abc.abstractmethod
    async def type_summary(self, type: str) -> TypeSummary:
        """How many records of a type, their bytes, the first and last recording times."""

    @abc.abstractmethod
    async def ensure_field_index(self, type: str, paths: Sequence[str]) -> None:
        """An index on these document fields (then ``recorded_at``) of a type; idempotent."""

    async def field_indexes(self, type: str) -> list[tuple[str, ...]]:
        """The field paths of each field index of a type."""
        return await self.bookkeeping.field_indexes(type)

    @abc.abstractmethod
    async def outcome_stats(
        self,
        type: str,
        fields: OutcomeFields,
        since: datetime | None = None,
        until: datetime | None = None,
        robot_id: str | None = None,
    ) -> list[OutcomeStats]:
        """Per name: successes (``success`` is true), failures, and mean and standard deviation of
        ``duration`` over records with a string name and a numeric duration, by name."""

    # retention: a record goes with the blobs no other record names
    async def delete_recorded_before(self, type: str, before: datetime) -> int:
        deleted = await self._delete_records_before(type, before)
        # the references go after their records (a crash between leaves them for the next sweep)
        while batch := await self.bookkeeping.refs_before(type, before, REFS_BATCH):
            refs = await self.bookkeeping.refs_of(type, sorted({ref["key"] for ref in batch}))
            await self._forget_blobs(type, refs)
        return deleted

    @abc.abstractmethod
    async def _delete_records_before(self, type: str, before: datetime) -> int: ...

    @abc.abstractmethod
    async def oldest_recorded(self, type: str, limit: int) -> list[tuple[str, int]]:
        """``(key, size)`` of the oldest records of a type."""

    async def delete_recorded(self, type: str, keys: Sequence[str]) -> int:
        refs = await self.bookkeeping.refs_of(type, keys)
        deleted = await self._delete_records(type, keys)
        await self._forget_blobs(type, refs)
        return deleted

    @abc.abstractmethod
    async def _delete_records(self, type: str, keys: Sequence[str]) -> int: ...

    async def _forget_blobs(self, type: str, refs: Sequence[dict[str, Any]]) -> None:
        orphans = await self.bookkeeping.release(type, refs)
        if orphans:
            await self.delete_blobs(orphans)

    # statistics
    @abc.abstractmethod
    async def database_bytes(self) -> int:
        """What the recording takes in the database now (files on disk, or data and indexes),
        its blobs included."""

    async def add_sample(self, sample: StorageSample) -> None:
        await self.bookkeeping.add_sample(sample)

    async def samples(self, since: datetime | None = None) -> list[StorageSample]:
        return await self.bookkeeping.samples(since)

    async def prune_samples(self, before: datetime | None, keep: int | None, limit: int) -> int:
        return await self.bookkeeping.prune_samples(before, keep, limit)

    async def __aenter__(self) -> RecordingStore:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()
