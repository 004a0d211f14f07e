"""``fleetbus publish`` and ``fleetbus query``: put one event on the bus, read recorded ones."""

from __future__ import annotations

import contextlib
import json
from dataclasses import asdict
from datetime import datetime
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from fleetbus.cli.context import (
    clock,
    console,
    fail,
    load_data,
    settings,
)
from fleetbus.cli.options import RobotUrl, check_url_option, robot_url
from fleetbus.cli.services import with_recording, with_services
from fleetbus.cli.times import TIME_FORMS, parse_time
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.errors import BrokerUnavailable, PublisherError
from fleetbus.publishers.state_lock import RobotStateInUse
from fleetbus.schemas.envelope import SchemaError, validate_body
from fleetbus.schemas.routing import EventType
from fleetbus.workers.recorder.capture import LEDGER_VIEWS
from fleetbus.workers.recorder.queries import LIMIT_MAX, SEARCH_LIMIT, record_view
from fleetbus.workers.recorder.summary import summarize

if TYPE_CHECKING:
    from fleetbus.api.services.recording import RecordedMessage, Recording


def publish(
    robot: str,
    event_type: Annotated[EventType, typer.Argument(metavar="TYPE")],
    data: Annotated[str, typer.Argument(help="JSON, or @file.json / @file.yaml")],
    url: RobotUrl = None,
    timeout: Annotated[float, typer.Option(help="seconds to wait for the broker's confirm")] = 10.0,
) -> None:
    """Publish one event as ROBOT, through its outbox; it returns once the broker confirmed it.

    If the broker does not confirm within TIMEOUT, the event stays in the robot's outbox (exit
    status 3) and goes out, in order, with the robot's next connection.
    """
    body = load_data(data)
    try:
        validate_body(event_type, body)
    except SchemaError as error:
        fail(f"invalid {event_type.value} body: {error}", code=2)
    check_url_option(url)
    client = open_robot(robot, robot_url(robot, url), timeout)
    try:
        with contextlib.suppress(BrokerUnavailable):
            client.connect(timeout)
        event = client.publish(event_type, body, wait=False)
        confirmed = client.flush(timeout)
    except PublisherError as error:
        fail(str(error))
    finally:
        client.close(flush_timeout=0)  # it waited its TIMEOUT already
    if not confirmed:
        fail(
            f"{event.type.value} {event.epoch}/{event.seq} waits in {robot}'s outbox: the broker did not "
            f"confirm it within {timeout:g} s ({client.last_error or 'no answer'}); it goes out with the "
            f"robot's next connection (see `fleetbus outbox {robot}`)",
            code=3,
        )
    console.print(
        f"published {event.type.value} {event.message_id} as {robot}, epoch {event.epoch} seq {event.seq}"
    )


def open_robot(robot: str, url: str, timeout: float) -> RobotClient:
    """The robot's client on ``url`` (as :func:`robot_url` found it)."""
    try:
        client = RobotClient(url, state_dir=settings().robots_dir, connect_timeout=timeout)
    except RobotStateInUse as error:
        fail(str(error))
    if client.robot_id != robot:
        client.close()
        fail(f"the URL logs in as {client.robot_id!r}, not {robot!r}")
    return client


def query(
    message_type: Annotated[
        str,
        typer.Argument(
            metavar="TYPE",
            help=f"any recorded type: hazard, behaviour, tf, notification…; or {' or '.join(LEDGER_VIEWS)}",
        ),
    ],
    where: Annotated[
        list[str] | None,
        typer.Option(
            "--where",
            "-w",
            help="FIELD=VALUE, or != < <= > >= ~ (contains); repeat for AND. "
            "Body fields of event types may be named alone (name=grab)",
        ),
    ] = None,
    robot: Annotated[str | None, typer.Option(help="only this robot")] = None,
    mission: Annotated[str | None, typer.Option(help="only messages recorded under this mission")] = None,
    since: Annotated[str | None, typer.Option(help=f"recorded from this time: {TIME_FORMS}")] = None,
    until: Annotated[str | None, typer.Option(help="recorded before this time (the same forms)")] = None,
    limit: Annotated[
        int, typer.Option(min=1, max=LIMIT_MAX, help="at most this many, the newest")
    ] = SEARCH_LIMIT,
    latest: Annotated[bool, typer.Option("--latest", help="only the newest match")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """Recorded messages of TYPE matching every condition, oldest first (the newest LIMIT of them);
    or the open sequence gaps, or the duplicates the workers were sent."""
    if message_type in LEDGER_VIEWS:
        show_ledger(message_type, robot, limit, as_json)
        return
    limit = 1 if latest else limit

    async def run(recording: Recording) -> tuple[list[RecordedMessage], list[str]]:
        found = await recording.find(
            message_type,
            recording.conditions(where or [], message_type),
            robot_id=robot,
            since=parse_time(since, "--since"),
            until=parse_time(until, "--until"),
            limit=limit,
            newest_first=True,
            mission_id=mission,
        )
        return found, await recording.types()

    records, types = with_recording(run)
    records.reverse()
    if as_json:
        for record in records:
            typer.echo(json.dumps(record_view(record), ensure_ascii=False))
        return
    if not records and message_type not in types:
        console.print(
            f"nothing recorded of type {message_type!r}; recorded: {', '.join(types) or 'nothing yet'} "
            "(`fleetbus worker` records unless --no-recorder; or run `fleetbus recorder run`)",
            highlight=False,
        )
        return
    table = Table(title=f"{len(records)} {message_type} events")
    table.add_column("recorded at (UTC)", no_wrap=True)
    table.add_column("robot", no_wrap=True)
    table.add_column("seq", justify="right", no_wrap=True)
    table.add_column("body", no_wrap=True)
    widest = max((len(r.robot_id or r.user_id or "") for r in records), default=5)
    room = max(20, console.width - widest - 23 - 6 - 13)
    for record in records:
        table.add_row(
            clock(record.recorded_at),
            record.robot_id or record.user_id or "",
            "" if record.seq is None else str(record.seq),
            summarize(record, room),
        )
    console.print(table)
    if len(records) == limit and not latest:
        console.print(f"[dim]showing the newest {limit}; use --limit or --since for more[/]")


def show_ledger(view: str, robot: str | None, limit: int, as_json: bool) -> None:
    """Open gaps in the robots' sequence numbers, or the duplicates the workers recognised."""
    if view == "gaps":
        gaps = with_services(lambda services: services.ledger.gaps(robot))
        if as_json:
            for gap in gaps:
                typer.echo(json.dumps({**asdict(gap), "missing": gap.size}, default=datetime.isoformat))
            return
        table = Table(
            "robot", "epoch", "missing seq", "events", "open since (UTC)", title=f"{len(gaps)} open gaps"
        )
        for gap in gaps:
            span = str(gap.first) if gap.first == gap.last else f"{gap.first}-{gap.last}"
            table.add_row(gap.robot_id, gap.epoch, span, str(gap.size), clock(gap.detected_at))
        console.print(table)
        return
    duplicates = with_services(lambda services: services.ledger.duplicates(robot, limit))
    if as_json:
        for duplicate in duplicates:
            typer.echo(json.dumps(asdict(duplicate), default=datetime.isoformat))
        return
    table = Table(
        "robot", "epoch", "seq", "message id", "seen at (UTC)", "why", title=f"{len(duplicates)} duplicates"
    )
    for d in duplicates:
        why = "redelivered by the broker" if d.redelivered else "sent again by the robot"
        table.add_row(d.robot_id, d.epoch, str(d.seq), d.message_id, clock(d.seen_at), why)
    console.print(table)
