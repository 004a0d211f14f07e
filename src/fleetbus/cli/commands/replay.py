"""``fleetbus replay``: republish the recorded messages of a time window to an exchange."""

from __future__ import annotations

import json
from collections import deque
from typing import TYPE_CHECKING, Annotated, Any

import pika
import pika.exceptions
import typer
from rich.progress import Progress, TextColumn, TimeElapsedColumn

from fleetbus.api.services.errors import ServiceRefusal
from fleetbus.cli.context import console, endpoint, errors, fail, no_password_in_argv
from fleetbus.cli.services import fail_refused, recording_stream
from fleetbus.cli.times import TIME_FORMS, parse_time
from fleetbus.publishers.confirms import SERVICE_CONFIRM_TIMEOUT_S, Outgoing, PipelinedConfirms
from fleetbus.publishers.errors import PublisherError, PublishRefused
from fleetbus.publishers.tls import blocking_connection
from fleetbus.workers.recorder.queries import parse_condition
from fleetbus.workers.recorder.replay import ReplayReport, Settled
from fleetbus.workers.recorder.replay import replay as replay_records

if TYPE_CHECKING:
    from fleetbus.api.services.recording import RecordedMessage


#: Messages a replay keeps awaiting their confirms, counted from the oldest not yet answered to
#: the newest sent (so answers out of order do not let it grow): enough for the broker to confirm
#: them in batches, few enough that what they hold (their records, and their frames until they
#: go out) stays a few megabytes. 1 is the replay that waits for each message's confirm.
IN_FLIGHT = 1024


class Publisher:
    """pika with publisher confirms and ``mandatory``: an unroutable message is counted, not lost.
    Up to :data:`IN_FLIGHT` messages await their confirms at once, in the order they were sent."""

    def __init__(self, url: str, exchange: str, declare: bool, in_flight: int = IN_FLIGHT) -> None:
        self._connection = blocking_connection(url)
        self._channel = self._connection.channel()
        self._exchange = exchange
        try:
            self._channel.exchange_declare(exchange, "topic", durable=True, passive=not declare)
        except pika.exceptions.ChannelClosedByBroker as error:
            self._connection.close()
            hint = " (add --declare to create it as a topic exchange)" if error.reply_code == 404 else ""
            fail(f"exchange {exchange!r}: {error.reply_text}{hint}")
        self._confirms = PipelinedConfirms(self._connection, self._channel, SERVICE_CONFIRM_TIMEOUT_S)
        self._limit = in_flight
        self._waiting: deque[tuple[int, RecordedMessage]] = deque()
        """Delivery tag and record of each message sent, from the oldest not yet answered on."""
        self._confirmed = 0
        self._unroutable = 0

    def send(self, record: RecordedMessage, body: bytes, properties: dict[str, Any]) -> None:
        if len(self._waiting) >= self._limit:
            self._wait(self._limit - 1)
        message = Outgoing(self._exchange, record.routing_key, body, pika.BasicProperties(**properties))
        try:
            tag = self._confirms.write_one(message)
        except PublisherError as error:
            raise self._stopped(error, record) from error
        self._waiting.append((tag, record))

    def settle(self) -> Settled:
        self._wait(0)
        return Settled(self._confirmed, self._unroutable)

    def _wait(self, at_most: int) -> None:
        """Wait until at most ``at_most`` messages await their confirms; a nack raises."""
        waiting, confirms = self._waiting, self._confirms
        while len(waiting) > at_most:
            try:
                confirms.wait_for(waiting[0][0], SERVICE_CONFIRM_TIMEOUT_S)
            except PublisherError as error:
                raise self._stopped(error) from error
            while waiting and confirms.answered(waiting[0][0]):
                tag, record = waiting[0]
                if confirms.nacked(tag):
                    raise PublishRefused(
                        f"the broker nacked {_named(record)} (a queue could not take it now); "
                        f"{self._counts(len(waiting) - 1)}"
                    )
                waiting.popleft()
                self._confirmed += 1
        # every return comes before its message's confirm: once all are answered, all are counted
        self._unroutable += confirms.take_returns()

    def _stopped(self, error: PublisherError, sending: RecordedMessage | None = None) -> PublisherError:
        """``error`` again, naming the oldest message not confirmed and how many were before it."""
        oldest = self._waiting[0][1] if self._waiting else sending
        assert oldest is not None, "a publish failed with nothing sent"
        after = max(len(self._waiting) - 1, 0)
        return type(error)(f"{error}; not confirmed: {_named(oldest)}, {self._counts(after)}")

    def _counts(self, after: int) -> str:
        text = f"the {self._confirmed:,} messages before it were confirmed"
        return f"{text}, the {after:,} sent after it were not waited for" if after else text

    def sleep(self, seconds: float) -> None:
        """Wait for a paced message's time while answering the broker (its heartbeats: a gap of
        minutes in the recording must not cost the connection)."""
        self._connection.sleep(seconds)

    def close(self) -> None:
        if self._connection.is_open:
            self._connection.close()


def _named(record: RecordedMessage) -> str:
    named = f"the {record.type} message on {record.routing_key} recorded at {record.recorded_at.isoformat()}"
    return f"{named} (message id {record.message_id})" if record.message_id else named


def replay(
    to: Annotated[str, typer.Option("--to", help="the exchange to publish to")],
    since: Annotated[str, typer.Option(help=f"recorded from this time: {TIME_FORMS}")],
    until: Annotated[
        str | None, typer.Option(help="recorded before this time (default: now; the same forms)")
    ] = None,
    message_types: Annotated[
        list[str] | None,
        typer.Option("--type", help="only this type (repeatable; default: all but dead letters)"),
    ] = None,
    robot: Annotated[str | None, typer.Option(help="only this robot's messages")] = None,
    where: Annotated[
        list[str] | None, typer.Option("--where", "-w", help="FIELD=VALUE…, with one --type")
    ] = None,
    speed: Annotated[float, typer.Option(help="2 = twice as fast, 0 = as fast as possible")] = 1.0,
    declare: Annotated[
        bool, typer.Option("--declare", help="create the exchange (topic) if missing")
    ] = False,
    url: Annotated[
        str | None, typer.Option(help="AMQP URL to publish with (default: the administrator's)")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="print the report as JSON")] = False,
) -> None:
    """Republish recorded messages of a window to an exchange, in order, with their original
    spacing divided by --speed; the routing keys, bodies and headers are the recorded ones.
    The window is read from the recording as it is sent, so its length does not matter."""
    types = message_types or []
    try:
        conditions = [parse_condition(text, types[0]) for text in where or []] if types else []
        if where and len(types) != 1:
            raise ValueError("--where needs exactly one --type")
        start, end = parse_time(since, "--since"), parse_time(until, "--until")
    except ValueError as error:  # the recording's refusal of a condition (a RecordingError) too
        fail(str(error), code=2)
    if speed < 0:
        fail("--speed must be 0 or more", code=2)
    no_password_in_argv(url, "--url", "in FLEETBUS_AMQP_URL (the account replay publishes as)")
    publish = Publisher(url or endpoint().amqp_url, to, declare)
    columns = (TextColumn("replaying: {task.completed:,.0f} messages"), TimeElapsedColumn())
    try:
        with (
            recording_stream(
                lambda recording: recording.between(
                    start, end, types=types, robot_id=robot, conditions=conditions
                )
            ) as records,
            Progress(*columns, console=errors, transient=as_json) as progress,
        ):
            task = progress.add_task("replay", total=None)
            report = replay_records(
                records, publish, speed, sleep=publish.sleep, on_each=lambda r: progress.advance(task)
            )
    except ServiceRefusal as refusal:
        fail_refused(refusal)
    except PublisherError as error:
        fail(f"replay stopped: {error}")
    finally:
        publish.close()
    if as_json:
        typer.echo(json.dumps(report.__dict__))
        return
    console.print(_summary(report, to, speed))


def _summary(report: ReplayReport, exchange: str, speed: float) -> str:
    text = f"replayed {report.published} messages to {exchange} over {report.span_s:.1f} s (speed {speed:g})"
    if report.unroutable:
        text += f"; {report.unroutable} unroutable (no queue bound for their keys)"
    if report.skipped:
        text += f"; {report.skipped} skipped (body not kept)"
    return text
