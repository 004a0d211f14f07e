"""``fleetbus replay``: republish the recorded messages of a time window to an exchange."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Annotated, Any

import pika
import pika.exceptions
import typer
from rich.progress import Progress, TextColumn, TimeElapsedColumn

from fleetbus.api.services.errors import ServiceRefusal
from fleetbus.cli.context import console, endpoint, errors, fail
from fleetbus.cli.services import fail_refused, recording_stream
from fleetbus.cli.times import TIME_FORMS, parse_time
from fleetbus.publishers.confirms import SERVICE_CONFIRM_TIMEOUT_S, Outgoing, PipelinedConfirms
from fleetbus.publishers.errors import PublishRefused
from fleetbus.publishers.tls import blocking_connection
from fleetbus.workers.recorder.queries import parse_condition
from fleetbus.workers.recorder.replay import ReplayReport
from fleetbus.workers.recorder.replay import replay as replay_records

if TYPE_CHECKING:
    from fleetbus.api.services.recording import RecordedMessage


class Publisher:
    """pika with publisher confirms and ``mandatory``: an unroutable message is counted, not lost."""

    def __init__(self, url: str, exchange: str, declare: bool) -> None:
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

    def __call__(self, record: RecordedMessage, body: bytes, properties: dict[str, Any]) -> bool:
        """Whether the broker routed it (and confirmed it); a nack or no confirm in time raises."""
        message = Outgoing(self._exchange, record.routing_key, body, pika.BasicProperties(**properties))
        outcome = self._confirms.send_one(message)
        if outcome.nacked:
            raise PublishRefused(f"the broker nacked {record.routing_key}: a queue could not take it now")
        return not outcome.returned

    def close(self) -> None:
        if self._connection.is_open:
            self._connection.close()


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
            report = replay_records(records, publish, speed, on_each=lambda r: progress.advance(task))
    except ServiceRefusal as refusal:
        fail_refused(refusal)
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
