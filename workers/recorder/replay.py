"""Send recorded messages again, with their original spacing or faster, to reproduce a fault.

The schedule comes from the recording times: message ``i`` goes out ``(t_i - t_0) / speed``
seconds after the first (``speed`` 0: as fast as the broker confirms). Each is published at
that offset from the start, never earlier, so a slow publish delays the next ones only until the
schedule is caught up again. Messages already due go out without waiting for each other's
confirms (the sender bounds how many await theirs); before waiting for the next one's time, the
replay waits until the broker answered every message sent, so none is still held on the way
while the clock runs.

A replayed message keeps its body, routing key, message id, correlation id, type and headers.
It cannot keep its ``user_id`` (the broker refuses a ``user_id`` other than the publisher's), so
where it came from goes in headers: ``x-replay-of-user-id``, ``x-replay-of-exchange``,
``x-replay-recorded-at``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Protocol

from fleetbus.workers.store.recordings import RecordedMessage

#: Properties a replay carries over; reply_to and expiration would point at callers long gone.
KEPT_PROPERTIES = (
    "content_type",
    "content_encoding",
    "message_id",
    "correlation_id",
    "type",
    "app_id",
    "priority",
)


@dataclass(frozen=True)
class Settled:
    """The broker answered every message sent so far: what it said."""

    confirmed: int
    """Messages it confirmed, routed or not."""
    unroutable: int
    """Of those, how many it returned: no queue is bound for their routing keys."""


class Sender(Protocol):
    """Publishes replayed messages with the broker's confirms, several awaiting theirs at once."""

    def send(self, record: RecordedMessage, body: bytes, properties: dict[str, Any]) -> None:
        """Publish one message (routing key from the record), in order, without waiting for its
        confirm; when the sender's window of messages awaiting theirs is full, it waits for room."""
        ...

    def settle(self) -> Settled:
        """Wait until the broker answered every message sent; raise when it refused one or did
        not answer in time, naming the message and how many were confirmed before it."""
        ...


@dataclass
class ReplayReport:
    published: int = 0
    unroutable: int = 0
    skipped: int = 0
    """Records whose body was not kept (too large when recorded)."""
    span_s: float = 0.0
    """Seconds after the start at which the last message was due."""
    earliest_s: float | None = None
    """The least a message was published after it was due (never below 0: never early)."""
    latest_s: float | None = None
    """The most a message was published after it was due (the broker or the store held it up)."""

    def sent(self, due: float, at: float) -> None:
        late = at - due
        self.earliest_s = late if self.earliest_s is None else min(self.earliest_s, late)
        self.latest_s = late if self.latest_s is None else max(self.latest_s, late)


def due(first: datetime, record: RecordedMessage, speed: float) -> float:
    """Seconds after the start at which ``record`` is due, the first one having been recorded at ``first``."""
    if speed < 0:
        raise ValueError("speed must be 0 (as fast as possible) or more")
    return 0.0 if speed == 0 else (record.recorded_at - first).total_seconds() / speed


def schedule(records: Sequence[RecordedMessage], speed: float) -> list[float]:
    return [due(records[0].recorded_at, record, speed) for record in records] if records else []


def replay_properties(record: RecordedMessage) -> dict[str, Any]:
    """The AMQP properties of the replayed copy (names as pika's ``BasicProperties`` takes them)."""
    properties = {name: record.properties[name] for name in KEPT_PROPERTIES if name in record.properties}
    headers = dict(record.properties.get("headers") or {})
    headers.update(
        {
            "x-replay-of-user-id": record.user_id or "",
            "x-replay-of-exchange": record.exchange,
            "x-replay-recorded-at": record.recorded_at.isoformat(),
        }
    )
    return {**properties, "headers": headers, "delivery_mode": 2}


def replay(
    records: Iterable[RecordedMessage],
    sender: Sender,
    speed: float = 1.0,
    *,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    on_each: Callable[[RecordedMessage], None] = lambda record: None,
) -> ReplayReport:
    """Publish ``records`` (in recording order) on their schedule; they are read as they go out,
    so a window of any length is replayed in the memory of what its iterator and the sender's
    messages awaiting their confirms hold."""
    if speed < 0:
        raise ValueError("speed must be 0 (as fast as possible) or more")
    report = ReplayReport()
    start = clock()
    first: datetime | None = None
    for record in records:
        first = first or record.recorded_at
        report.span_s = when = due(first, record, speed)
        if clock() < start + when:
            sender.settle()  # nothing still on its way while the clock runs: each goes out on time
            wait = start + when - clock()
            if wait > 0:
                sleep(wait)
        body = record.body_bytes()
        if body is None:
            report.skipped += 1
        else:
            report.sent(when, clock() - start)
            sender.send(record, body, replay_properties(record))
        on_each(record)
    settled = sender.settle()
    report.published = settled.confirmed - settled.unroutable
    report.unroutable = settled.unroutable
    return report
