"""The recorder: consume the copy of every message on the bus, store it as received, then ack.

Batches are written in one durable write and acked after it, so a crash means redelivery,
which the records' keys make harmless. Between batches (and when idle) it applies the
retention policies and samples the database's size for ``fleetbus stats``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import uuid
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta, timezone
from typing import TypeVar

import pika.exceptions

from fleetbus.broker.dead_letter_queue import moved_letter_key
from fleetbus.broker.retry import Stopped, async_retrying, run_retrying
from fleetbus.defaults import DEFAULT_MAX_MESSAGE_BYTES, DEFAULT_RECORDER_KEEP, DEFAULT_RECORDER_SAMPLES_KEEP
from fleetbus.limits import Retention, parse_retention
from fleetbus.workers.batches import BatchInbox
from fleetbus.workers.dead_letters import last_unsettled, move_to_dead_letters, rejection_of
from fleetbus.workers.recorder.capture import (
    DEAD_LETTER,
    DEFAULT_MAX_TYPES,
    OTHER,
    REJECTION,
    TypeNames,
    capture,
)
from fleetbus.workers.recorder.filters import RoutingFilter
from fleetbus.workers.recorder.retention import RetentionSweeper, samples_retention
from fleetbus.workers.recorder.ros_blobs import RosBlobs
from fleetbus.workers.recorder.ros_derived import derived_records
from fleetbus.workers.recorder.source import Delivery, RecorderQueue
from fleetbus.workers.store.base import StoreUnavailable, WriteResult
from fleetbus.workers.store.recordings import RecordedMessage, RecordingStore, StorageSample
from fleetbus.workers.store.rejections import RejectionLog

log = logging.getLogger("fleetbus.recorder")
T = TypeVar("T")
MissionLookup = Callable[[set[str]], Awaitable[dict[str, str]]]
"""The mission each of these robots is being recorded under now (robots under none left out)."""
BoundCounter = Callable[[Mapping[tuple[str, str], int], datetime], Awaitable[None]]
"""Adds what a bound removed, by bound and subject, to the counts ``fleetbus stats`` shows
(:meth:`~fleetbus.workers.store.housekeeping.Housekeeping.count_bounded`)."""
ROS_PIECES_BOUND = "ros-pieces"
RECORDING_BOUND = "recording"
CONNECTION_LOST = (pika.exceptions.AMQPError, ConnectionError)


@dataclass(frozen=True)
class RecorderOptions:
    filter: RoutingFilter = field(default_factory=RoutingFilter)
    retention: Mapping[str, Retention] = field(
        default_factory=lambda: parse_retention([DEFAULT_RECORDER_KEEP])
    )
    max_types: int = DEFAULT_MAX_TYPES
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES
    sample_interval: float = 60.0
    """Seconds between two looks at the database's size (``fleetbus stats``)."""
    retention_interval: float = 30.0
    samples_keep: Retention = field(default_factory=lambda: samples_retention(DEFAULT_RECORDER_SAMPLES_KEEP))
    """The size samples kept (``FLEETBUS_RECORDER_SAMPLES_KEEP``), by age or number."""
    ros_pieces_ttl: timedelta = timedelta(hours=1)
    """Pieces of a large ROS message (``ros_chunk``) that no record named this long are removed."""
    batch_size: int = 256
    linger: float = 0.05
    """Seconds a batch waits for more messages: recording is not urgent, and fewer, larger
    transactions cost less (at 100 msg/s, 6 % of a core instead of 10 % with 5 ms)."""


@dataclass
class RecorderStats:
    recorded: int = 0
    duplicates: int = 0
    filtered: int = 0
    unstorable: int = 0
    """Messages not stored even raw: each dead-lettered (reason ``unstorable``) and logged."""
    store_retries: int = 0
    swept: int = 0
    pieces_swept: int = 0
    """``ros_chunk`` pieces removed because their message never came (``FLEETBUS_ROS_PIECES_TTL``)."""
    by_type: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Unstorable:
    """A record the store would not take, even raw (the message is dead-lettered)."""

    detail: str


UNSTORABLE = "unstorable"


class RecorderConsumer:
    def __init__(
        self,
        queue: RecorderQueue,
        store: RecordingStore,
        options: RecorderOptions,
        names: TypeNames,
        missions: MissionLookup | None = None,
        rejections: RejectionLog | None = None,
        bounded: BoundCounter | None = None,
    ) -> None:
        """``bounded``: where what the sweeps remove is counted for operators (else only logged)."""
        self._rejections = rejections
        self._bounded = bounded
        self._queue = queue
        self._store = store
        self._options = options
        self._names = names
        self._missions = missions
        self._inbox: BatchInbox[Delivery] = BatchInbox(options.batch_size, options.linger)
        self._stopping = asyncio.Event()
        self._sweeper = RetentionSweeper(store, options.retention, options.samples_keep)
        self._run_id = uuid.uuid4().hex[:12]
        self.blobs = RosBlobs(store, self._retrying)
        """The large byte arrays of live ROS messages, put together from their ``ros_chunk`` events."""
        self._since_sample = 0
        self.stats = RecorderStats()

    async def run(self) -> None:
        """Consume until :meth:`stop`; then finish what was received and return."""
        await self._queue.consume(self._inbox.put_nowait)
        loop = asyncio.get_running_loop()
        next_sample = next_sweep = loop.time()
        while not (self._stopping.is_set() and self._inbox.empty()):
            if loop.time() >= next_sample:
                await self._sample()
                next_sample = loop.time() + self._options.sample_interval
            if loop.time() >= next_sweep:
                await self._sweep()
                next_sweep = loop.time() + self._options.retention_interval
            idle = max(0.0, min(next_sample, next_sweep) - loop.time())
            batch = await self._inbox.next_batch(self._stopping, idle=idle)
            if not batch:
                continue
            try:
                await self._process(batch)
            except Stopped:
                log.warning("stopping with the store down: %d messages left for redelivery", len(batch))
                return
            except CONNECTION_LOST as error:
                log.warning(
                    "broker connection lost mid-batch (%r); %d messages will be redelivered",
                    error,
                    len(batch),
                )
        await self._sample()

    async def stop(self) -> None:
        """Stop taking new messages; :meth:`run` returns once the ones received are stored."""
        with contextlib.suppress(*CONNECTION_LOST):
            await self._queue.cancel()
        self._stopping.set()

    def _capture(self, message: Delivery) -> RecordedMessage:
        try:
            return capture(message, self._names, self._options.max_message_bytes)
        except Exception as error:  # a bug here must not make the message a poison that stops recording
            log.exception("could not read a message from %s on %s", message.user_id, message.exchange)
            return RecordedMessage(
                key=uuid.uuid4().hex,
                type=OTHER,
                recorded_at=datetime.now(timezone.utc),
                exchange=message.exchange or "",
                routing_key=message.routing_key or "",
                user_id=message.user_id,
                robot_id=message.user_id,
                problem=f"the recorder could not read it ({error!r}); kept raw",
                raw=message.body,
                size=len(message.body),
            )

    async def _process(self, batch: list[Delivery]) -> None:
        records: list[RecordedMessage] = []
        kept: list[Delivery] = []
        letters: dict[int, str] = {}
        for message in batch:
            if self._options.filter.keeps(message.routing_key or ""):
                records.append(self._capture(message))
                kept.append(message)
                key = moved_letter_key(message.headers, message.user_id, message.message_id, message.body)
                if key is not None and records[-1].type == DEAD_LETTER:
                    letters[len(records) - 1] = key
            else:
                self.stats.filtered += 1
        if letters and self._rejections is not None:
            records = await self._with_reasons(records, letters)
        if records and self._missions is not None:
            records = await self._stamp_missions(records)
        pieces: list[str] = []
        if records:
            records, pieces = await self.blobs.prepare(records)
            results = await self._retrying(lambda: self._write(records))
            for message, record, result in zip(kept, records, results, strict=True):
                if isinstance(result, Unstorable):
                    await self._dead_letter(message, result)
                elif result.inserted:
                    self.stats.recorded += 1
                    self.stats.by_type[record.type] = self.stats.by_type.get(record.type, 0) + 1
                    self._since_sample += 1
                else:
                    self.stats.duplicates += 1
            # what a message brings (its transforms, its type's definition) is written again with
            # it, also when redelivered: it may be what was lost
            derived = [d for record in records for d in derived_records(record)]
            if derived:
                await self._retrying(lambda: self._write(derived))
            await self.blobs.settle(pieces)  # the blobs they made are kept and named: their pieces go
        last = last_unsettled(batch)
        if last is not None:
            await last.ack(multiple=True)

    async def _dead_letter(self, message: Delivery, unstorable: Unstorable) -> None:
        """What the store would not take even raw goes to the dead-letter queue (the queue's
        policy, README "The recorder"), its reason kept in the service's store when there is one."""
        if self._rejections is not None:
            rejection = rejection_of(message, UNSTORABLE, unstorable.detail)
            rejections = self._rejections
            await self._retrying(lambda: rejections.record_rejections([rejection]))
        await move_to_dead_letters(message)
        self.stats.unstorable += 1
        log.error(
            "could not store %s from %s on %s even raw; dead-lettered: %s",
            message.routing_key,
            message.user_id,
            message.exchange,
            unstorable.detail,
        )

    async def _with_reasons(
        self, records: list[RecordedMessage], letters: dict[int, str]
    ) -> list[RecordedMessage]:
        """Dead letters the broker moved carry no reason: the one the worker kept is added."""
        assert self._rejections is not None
        rejections = self._rejections
        kept = await self._retrying(lambda: rejections.rejections(list(letters.values())))
        for index, key in letters.items():
            if key in kept:
                reason = {"reason": kept[key].reason, "detail": kept[key].detail}
                records[index] = replace(
                    records[index], properties={**records[index].properties, REJECTION: reason}
                )
        return records

    async def _stamp_missions(self, records: list[RecordedMessage]) -> list[RecordedMessage]:
        """Each robot's message carries the mission the robot is recorded under, as the event log's do."""
        assert self._missions is not None
        lookup = self._missions
        robots = {r.robot_id for r in records if r.robot_id and r.mission_id is None}
        missions = await self._retrying(lambda: lookup(robots)) if robots else {}
        return [
            replace(r, mission_id=missions[r.robot_id])
            if r.mission_id is None and r.robot_id in missions
            else r
            for r in records
        ]

    async def _write(self, records: list[RecordedMessage]) -> list[WriteResult | Unstorable]:
        """Write a batch; one the store refuses is written record by record, so that one bad
        record cannot hold back the others (it is kept raw under ``other``, or else dead-lettered)."""
        try:
            return await self._store.write_recorded(records)
        except StoreUnavailable:
            raise
        except Exception as error:
            if len(records) > 1:
                log.exception("could not store a batch of %d; storing them one by one", len(records))
                return [result for record in records for result in await self._write([record])]
            record = records[0]
            if record.type == OTHER and record.problem and "could not be stored" in record.problem:
                log.exception("could not store %s on %s even raw", record.routing_key, record.exchange)
                return [Unstorable(f"the recording store refused it, even raw: {error!r}")]
            fallback = replace(
                record.as_raw(
                    f"could not be stored as recorded ({error!r}); kept raw", record.body_bytes() or b""
                ),
                type=OTHER,
            )
            return await self._write([fallback])

    async def _retrying(self, operation: Callable[[], Awaitable[T]]) -> T:
        def counted(_: object) -> None:
            self.stats.store_retries += 1

        retrying = async_retrying(
            "the recording store", on=StoreUnavailable, stop=self._stopping, logger=log, on_retry=counted
        )
        return await run_retrying(retrying, operation)

    async def _sample(self) -> None:
        with contextlib.suppress(StoreUnavailable):
            size = await self._store.database_bytes()
            await self._store.add_sample(
                StorageSample(datetime.now(timezone.utc), self._run_id, size, self._since_sample)
            )
            self._since_sample = 0

    async def _sweep(self) -> None:
        try:
            deleted = await self._sweeper.sweep()
        except StoreUnavailable as error:
            log.warning("retention sweep skipped: %s", error)
            return
        if deleted:
            self.stats.swept += sum(deleted.values())
            log.info("retention deleted %s", ", ".join(f"{n} {t}" for t, n in sorted(deleted.items())))
            await self._count_bounded({(RECORDING_BOUND, type): n for type, n in deleted.items()})
        await self._sweep_pieces()

    async def _sweep_pieces(self) -> None:
        """The pieces of large ROS messages whose message never came: removed, and counted."""
        now = datetime.now(timezone.utc)
        try:
            removed = await self.blobs.sweep(now - self._options.ros_pieces_ttl)
        except StoreUnavailable as error:
            log.warning("sweep of ros_chunk pieces skipped: %s", error)
            return
        if not removed:
            return
        self.stats.pieces_swept += sum(removed.values())
        log.warning(
            "removed ros_chunk pieces no ROS message named within %s (FLEETBUS_ROS_PIECES_TTL): %s",
            self._options.ros_pieces_ttl,
            ", ".join(f"{n} of {robot}" for robot, n in sorted(removed.items())),
        )
        await self._count_bounded({(ROS_PIECES_BOUND, robot): n for robot, n in removed.items()}, now)

    async def _count_bounded(
        self, counts: Mapping[tuple[str, str], int], now: datetime | None = None
    ) -> None:
        """Add what a bound removed to the counts ``fleetbus stats`` shows (when this recorder has
        the service's store to count in)."""
        if self._bounded is not None:
            bounded, at = self._bounded, now or datetime.now(timezone.utc)
            await self._retrying(lambda: bounded(counts, at))
