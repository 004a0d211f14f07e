"""The ingest worker: validate, check, store durably, run the services, then ack, in batches.

A batch is what arrived within a few milliseconds (at most the prefetch). Messages that fail
validation or a check are dead-lettered with their reason, the others are written in one
transaction, the services (hazards, maps, battery) act on them and publish their notifications,
and only then is the batch acked. A crash anywhere before the ack means redelivery; the store's
(robot, epoch, seq) key and idempotent services turn it into a no-op.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Awaitable, Callable, Collection, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Protocol, TypeVar

import aiormq.exceptions
from aio_pika.abc import AbstractChannel, AbstractIncomingMessage, AbstractQueue
from aio_pika.exceptions import AMQPError, ChannelInvalidStateError
from tenacity import RetryCallState

from fleetbus.broker.retry import Stopped, async_retrying, pause, run_retrying
from fleetbus.schemas.routing import EventType
from fleetbus.workers.attempts import AttemptLimit
from fleetbus.workers.batches import BatchInbox
from fleetbus.workers.dead_letters import last_unsettled, move_to_dead_letters, rejection_of
from fleetbus.workers.store.base import StoreUnavailable, WriteResult
from fleetbus.workers.store.ledger import Duplicate
from fleetbus.workers.store.rejections import RejectionLog
from fleetbus.workers.store.repositories import EventLog
from fleetbus.workers.validation import Accepted, Rejected, RejectReason, classify

log = logging.getLogger("fleetbus.ingest")
T = TypeVar("T")
BROKER_ERRORS = (AMQPError, aiormq.exceptions.AMQPError, ChannelInvalidStateError, ConnectionError)


class BatchService(Protocol):
    """Work done on each stored batch before it is acked; must be idempotent (batches are redelivered)."""

    async def handle(self, accepted: Sequence[Accepted]) -> int:
        """Apply the batch; return how many notifications it published."""
        ...


class BatchCheck(Protocol):
    """A check that needs the store, made before a batch is written; refused items are dead-lettered."""

    async def check(self, accepted: Sequence[Accepted]) -> dict[int, Rejected]:
        """The refused items, by their index in ``accepted``."""
        ...


class ControlMessages(Protocol):
    """Messages on a queue that are not robots' events but instructions from the service itself."""

    def accepts(self, message: AbstractIncomingMessage) -> bool: ...

    async def handle(self, messages: Sequence[AbstractIncomingMessage]) -> int:
        """Act on them (after the batch's events; idempotent); return notifications published."""
        ...


@dataclass
class IngestStats:
    stored: int = 0
    duplicates: int = 0
    rejected: int = 0
    internal_errors: int = 0
    """Messages set aside because handling them raised an unexpected error (a bug): dead-lettered
    as ``internal-error``, each with its traceback in the log."""
    notified: int = 0
    store_retries: int = 0
    by_reason: dict[str, int] = field(default_factory=dict)
    waiting_for: str | None = None
    """What a consumer is retrying now (a transient failure), shown in its status."""
    waiting_since: datetime | None = None
    last_error: str | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)
    """The express lane counts on a thread of its own (:mod:`fleetbus.workers.express`)."""

    def add(self, counter: str, n: int = 1) -> None:
        with self._lock:
            setattr(self, counter, getattr(self, counter) + n)

    def rejected_for(self, reason: str) -> None:
        with self._lock:
            self.rejected += 1
            self.by_reason[reason] = self.by_reason.get(reason, 0) + 1

    def retrying(self, what: str, error: BaseException | None) -> None:
        self.add("store_retries")
        if self.waiting_for is None:
            self.waiting_since = datetime.now(timezone.utc)
        self.waiting_for, self.last_error = what, f"{type(error).__name__}: {error}" if error else None

    def recovered(self) -> None:
        self.waiting_for = self.waiting_since = self.last_error = None


class IngestConsumer:
    def __init__(
        self,
        channel: AbstractChannel,
        queue: AbstractQueue,
        events: EventLog,
        rejections: RejectionLog,
        *,
        max_message_bytes: int,
        checks: Sequence[BatchCheck] = (),
        services: Sequence[BatchService] = (),
        urgent: Collection[EventType] = (),
        batch_size: int = 256,
        linger: float = 0.0,
        stats: IngestStats | None = None,
        attempts: AttemptLimit | None = None,
        exclusive: bool = False,
        control: ControlMessages | None = None,
        finishing: Callable[[], list[Callable[[], Awaitable[None]]]] | None = None,
    ) -> None:
        """``finishing``: after a batch's services, what they left to finish before it is acked
        (:meth:`~fleetbus.workers.coordination.HazardCoordinator.take_finishing`): the batch is
        acked once that is done, and the next batch begins meanwhile."""
        self._channel = channel
        self._queue = queue
        self._events = events
        self._rejections = rejections
        self._checks = checks
        self._services = services
        self._urgent = frozenset(urgent)
        self._max_bytes = max_message_bytes
        self._inbox = BatchInbox(batch_size, linger)
        self._taken: dict[int, datetime] = {}
        """When each message in hand was taken from the broker (its ``received_at``), by ``id``."""
        self._stopping = asyncio.Event()
        self._consumer_tag: str | None = None
        self._attempts = attempts
        """A classic queue's delivery limit, kept here (a quorum queue keeps its own)."""
        self._control = control
        self._finishing = finishing
        self._acking: asyncio.Task[None] | None = None
        """The last batch's ack, waiting for what was left to finish; each waits for the one
        before, so batches are acked in order."""
        self._ack_error: BaseException | None = None
        """What failed finishing or acknowledging handled batches: this consumer stops (its unacked
        messages come again) and :meth:`run` raises it, rather than hold them unacked while the
        broker sends no more."""
        self._exclusive = exclusive
        """The queue's work must never overlap with the next consumer's (its single active consumer
        is the only lock): on stop, this consumer finishes the batch in hand and leaves the rest
        unacked for the channel's close to give back. Cancelling first would let the broker hand the
        queue to the next consumer while this batch is still being handled."""
        # one worker's shard consumers share their counters
        self.stats = stats if stats is not None else IngestStats()

    async def run(self) -> None:
        """Consume until :meth:`stop`; then finish what was received and return. Raise what kept a
        handled batch from its ack (:meth:`_on_acked`): the consumer stopped by itself."""
        await self._consume()
        if self._ack_error is not None:
            raise self._ack_error

    async def _consume(self) -> None:
        self._consumer_tag = await self._queue.consume(self._take, no_ack=False)
        while self._ack_error is None and not (
            self._stopping.is_set() and (self._exclusive or self._inbox.empty())
        ):
            batch = await self._inbox.next_batch(self._stopping)
            if batch:
                try:
                    await self._handle_or_isolate(batch)
                    if self._acking is not None and self._acking.done():
                        await self._acked()
                except Stopped:
                    log.warning("stopping with the store down: %d messages left for redelivery", len(batch))
                    return
                except BROKER_ERRORS as error:
                    log.warning(
                        "broker connection lost mid-batch (%r); %d messages will be redelivered",
                        error,
                        len(batch),
                    )
                    await self._give_back(batch)
        try:
            await self._acked()
        except Stopped:
            log.warning("stopping with the store down: the last batches are left for redelivery")
        except BROKER_ERRORS as error:
            log.warning("broker connection lost finishing the last batches (%r); they come again", error)

    async def _acked(self) -> None:
        """Wait until the batches handled so far are acked (raise what kept one from it)."""
        acking, self._acking = self._acking, None
        if acking is not None:
            await acking

    async def _ack_after(
        self,
        before: asyncio.Task[None] | None,
        finishing: list[Callable[[], Awaitable[None]]],
        last: AbstractIncomingMessage | None,
    ) -> None:
        if before is not None:
            await before
        for finish in finishing:
            await self._retrying(finish)
        if last is not None:
            try:
                await last.ack(multiple=True)
            except BROKER_ERRORS as error:
                # The channel the batch came on is gone, and the broker gives its unacked messages
                # again (on the robust connection's new channel): handled again, idempotently, its
                # finishing done. Nothing to stop for; the batches after it are acked as they come.
                log.warning("a handled batch's channel closed before its ack (%r); it comes again", error)

    def _on_acked(self, acking: asyncio.Task[None]) -> None:
        """A batch's finishing or ack that failed (past its retries) ends the consumer: the ones
        chained after it would wait for it for ever, and the broker, its prefetch spent, sends no
        more. :meth:`run` raises its error (the worker stops, and its messages come again)."""
        error = None if acking.cancelled() else acking.exception()
        if error is None or isinstance(error, Stopped) or self._ack_error is not None:
            return  # Stopped: asked to stop meanwhile, run() leaves the batches for redelivery
        self._ack_error = error
        log.error("finishing a handled batch failed: %r; this consumer stops", error)
        self._stopping.set()  # wakes run() from waiting for the next batch

    async def _take(self, message: AbstractIncomingMessage) -> None:
        """The consumer callback: from now the message is the worker's, whatever waits before it."""
        self._taken[id(message)] = datetime.now(timezone.utc)
        await self._inbox.put(message)

    async def _handle_or_isolate(self, batch: list[AbstractIncomingMessage]) -> None:
        try:
            await self._handle(batch)
        except (Stopped, *BROKER_ERRORS):
            raise
        except Exception:
            log.exception("unexpected error handling a batch of %d; taking them one by one", len(batch))
            await self._isolate(batch)

    async def _isolate(self, batch: list[AbstractIncomingMessage]) -> None:
        """After an unexpected error: each message of the batch on its own, and the one that raises
        again dead-lettered as ``internal-error`` (a bug in the worker, not the robot's fault), so
        that one message cannot stop its queue."""
        for message in batch:
            if message.processed:  # dead-lettered, or acked with an earlier one
                continue
            try:
                await self._handle([message])
            except (Stopped, *BROKER_ERRORS):
                raise
            except Exception as error:
                log.exception("unexpected error handling %s from %s", message.message_id, message.user_id)
                self.stats.add("internal_errors")
                detail = f"the worker failed on it: {type(error).__name__}: {error}"
                await self._reject(message, Rejected(RejectReason.INTERNAL_ERROR, detail))

    async def _give_back(self, batch: list[AbstractIncomingMessage]) -> None:
        """Return an unfinished batch for redelivery.

        When the channel is gone the broker redelivers it by itself; when the channel survived
        (the error was elsewhere), an unacked message would stay with this consumer forever, so
        it is nacked back to the queue, after a pause that keeps a persistent fault from spinning.
        """
        for message in batch:
            self._taken.pop(id(message), None)
        if self._channel.is_closed:
            return
        await pause(1.0, self._stopping)
        last = last_unsettled(batch)
        if last is not None:
            with contextlib.suppress(*BROKER_ERRORS):
                await last.nack(multiple=True, requeue=True)

    async def stop(self) -> None:
        """Stop taking new messages; :meth:`run` returns once the ones received are handled (an
        ``exclusive`` consumer: once the batch in hand is; closing its channel gives the rest back)."""
        if self._consumer_tag is not None and not self._channel.is_closed and not self._exclusive:
            with contextlib.suppress(AMQPError, aiormq.exceptions.AMQPError, ChannelInvalidStateError):
                await self._queue.cancel(self._consumer_tag)
        self._stopping.set()

    async def _reject(self, message: AbstractIncomingMessage, verdict: Rejected) -> None:
        """Dead-letter it with its reason: recorded first (idempotent), then moved by the broker."""
        rejection = rejection_of(message, verdict.reason.value, verdict.detail)
        await self._retrying(lambda: self._rejections.record_rejections([rejection]))
        await move_to_dead_letters(message)
        self.stats.rejected_for(verdict.reason.value)
        log.warning(
            "dead-lettered %s from %s: %s: %s",
            message.message_id,
            message.user_id,
            verdict.reason.value,
            verdict.detail,
        )

    async def _handle(self, batch: list[AbstractIncomingMessage]) -> None:
        limit = self._attempts
        if limit is None or not any(message.redelivered for message in batch):
            await self._process(batch)
            return
        # after a crash: one at a time, each counted before it is begun (workers.attempts)
        for message in batch:
            refused = await self._retrying(lambda message=message: limit.admit(message))
            if refused is None:
                await self._process([message])
            else:
                self._taken.pop(id(message), None)  # never processed: its arrival time is not needed
                await self._reject(message, refused)
            await self._retrying(lambda message=message: limit.handled([message]))

    async def _process(self, batch: list[AbstractIncomingMessage]) -> None:
        control = self._control
        instructions = [message for message in batch if control is not None and control.accepts(message)]
        candidates: list[tuple[AbstractIncomingMessage, Accepted]] = []
        now = datetime.now(timezone.utc)
        taken = {id(message): self._taken.pop(id(message), now) for message in batch}
        for message in batch:
            if message in instructions:
                continue
            verdict = classify(message, self._max_bytes, taken[id(message)])
            if isinstance(verdict, Rejected):
                await self._reject(message, verdict)
            else:
                candidates.append((message, verdict))
        for check in self._checks:
            items = [item for _, item in candidates]
            refused = await self._retrying(lambda check=check, items=items: check.check(items))
            for index in sorted(refused):
                await self._reject(candidates[index][0], refused[index])
            candidates = [pair for index, pair in enumerate(candidates) if index not in refused]
        if candidates:
            # stamped with their missions, written, and seen by the sequence ledger: one store call
            at = datetime.now(timezone.utc)
            records = [item.record for _, item in candidates]
            urgent = any(item.event.type in self._urgent for _, item in candidates)
            stored = await self._retrying(lambda: self._events.store_batch(records, at, urgent=urgent))
            stored_at = datetime.now(timezone.utc)
            candidates = [
                (message, Accepted(item.event, record, item.forwarded, stored_at))
                for (message, item), record in zip(candidates, stored.records, strict=True)
            ]
            accepted, duplicates = await self._sort_out(candidates, stored.results, at)
            for service in self._services:
                # awaited before adding: another consumer sharing the stats may count meanwhile
                notified = await self._retrying(lambda service=service: service.handle(accepted))
                self.stats.add("notified", notified)
            # bookkeeping after the services, so that it does not delay notifications
            await self._retrying(lambda: self._events.record_duplicates(duplicates))
            self.stats.add("duplicates", len(duplicates))  # counted once the ledger holds them
        if control is not None and instructions:
            self.stats.add("notified", await self._retrying(lambda: control.handle(instructions)))
        last = last_unsettled(batch)
        finishing = self._finishing() if self._finishing is not None else []
        if finishing or self._acking is not None:
            self._acking = asyncio.create_task(self._ack_after(self._acking, finishing, last))
            self._acking.add_done_callback(self._on_acked)
        elif last is not None:
            await last.ack(multiple=True)

    async def _sort_out(
        self,
        candidates: list[tuple[AbstractIncomingMessage, Accepted]],
        results: Sequence[WriteResult],
        at: datetime,
    ) -> tuple[list[Accepted], list[Duplicate]]:
        """Count what was stored, dead-letter reused numbers; return the rest and the duplicates."""
        duplicates: list[Duplicate] = []
        accepted: list[Accepted] = []
        for (message, item), result in zip(candidates, results, strict=True):
            record = item.record
            if result.reused(record):
                # Each client start numbers in an epoch of its own, so only a client that is not
                # fleetbus's (or a bug) can send one number twice with two events.
                detail = (
                    f"{record.robot_id} reused sequence number {record.seq} of epoch {record.epoch}: "
                    f"message {record.message_id} is another event than the stored "
                    f"{result.stored_message_id} (its type or body differ)"
                )
                await self._reject(message, Rejected(RejectReason.SEQUENCE_REUSED, detail))
                continue
            accepted.append(item)
            if result.inserted or result.rewritten:
                self.stats.add("stored")
            else:
                duplicates.append(
                    Duplicate(
                        record.robot_id,
                        record.epoch,
                        record.seq,
                        record.message_id,
                        at,
                        bool(message.redelivered),
                    )
                )
        return accepted, duplicates

    async def _retrying(self, operation: Callable[[], Awaitable[T]]) -> T:
        """Run a store or service step until it succeeds; raise Stopped if asked to stop meanwhile.

        Transient: the store unreachable, or the broker nacking a notification (a queue it routes
        to is still recovering after a broker restart). Every step is idempotent, so a retry after
        a partial success repeats at most a notification, never a record.
        """

        what = "the store and the notifications"

        def counted(state: RetryCallState) -> None:
            self.stats.retrying(what, state.outcome.exception() if state.outcome else None)

        retrying = async_retrying(
            what,
            on=(StoreUnavailable, aiormq.exceptions.DeliveryError),
            stop=self._stopping,
            logger=log,
            on_retry=counted,
        )
        result = await run_retrying(retrying, operation)
        if self.stats.waiting_for is not None:
            self.stats.recovered()
        return result
