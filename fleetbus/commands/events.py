"""``fleetbus publish`` and ``fleetbus query``: put one event on the bus, read stored ones."""

from __future__ import annotations

import contextlib
import json
from dataclasses import asdict
from datetime import datetime, timezone
from typing import Annotated, Any

import typer
from rich.table import Table

from fleetbus.context import console, fail, load_data, settings
from publishers.client import RobotClient
from publishers.errors import BrokerUnavailable, PublisherError
from publishers.state_lock import RobotStateInUse
from schemas.envelope import SchemaError, validate_body
from schemas.routing import EventType
from workers.store import run_with_store
from workers.store.base import EventQuery, EventRecord


def robot_url(robot: str, url: str | None) -> str:
    if url:
        return url
    saved = settings().accounts_dir / f"{robot}.url"
    if saved.exists():
        return saved.read_text().strip()
    fail(f"no credentials for {robot!r}: use --url, FLEETBUS_ROBOT_URL or `fleetbus users add {robot}`")


def publish(
    robot: str,
    event_type: Annotated[EventType, typer.Argument(metavar="TYPE")],
    data: Annotated[str, typer.Argument(help="JSON, or @file.json / @file.yaml")],
    url: Annotated[str | None, typer.Option(envvar="FLEETBUS_ROBOT_URL", help="the robot's AMQP URL")] = None,
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
    client = open_robot(robot, url, timeout)
    try:
        with contextlib.suppress(BrokerUnavailable):
            client.connect(timeout)
        event = client.publish(event_type, body, wait=False)
        confirmed = client.flush(timeout)
    except PublisherError as error:
        fail(str(error))
    finally:
        client.close()
    if not confirmed:
        fail(
            f"{event.type.value} seq {event.seq} waits in {robot}'s outbox: the broker did not confirm it "
            f"within {timeout:g} s ({client.last_error or 'no answer'}); it goes out with the robot's next "
            f"connection (see `fleetbus outbox {robot}`)",
            code=3,
        )
    console.print(f"published {event.type.value} {event.message_id} as {robot}, seq {event.seq}")


def open_robot(robot: str, url: str | None, timeout: float) -> RobotClient:
    try:
        client = RobotClient(robot_url(robot, url), state_dir=settings().robots_dir, connect_timeout=timeout)
    except RobotStateInUse as error:
        fail(str(error))
    if client.robot_id != robot:
        client.close()
        fail(f"the URL logs in as {client.robot_id!r}, not {robot!r}")
    return client


def parse_time(value: str | None) -> datetime | None:
    """ISO 8601, or a duration back from now: ``90s``, ``10m``, ``2h``, ``1d``."""
    if value is None:
        return None
    units = {"s": 1, "m": 60, "h": 3600, "d": 86400}
    if value[-1:] in units and value[:-1].replace(".", "", 1).isdigit():
        return datetime.fromtimestamp(
            datetime.now(timezone.utc).timestamp() - float(value[:-1]) * units[value[-1]], timezone.utc
        )
    try:
        parsed = datetime.fromisoformat(value)
    except ValueError:
        fail(f"cannot read time {value!r}: use ISO 8601 or a duration like 10m")
    return parsed if parsed.tzinfo else parsed.replace(tzinfo=timezone.utc)


def record_dict(record: EventRecord) -> dict[str, Any]:
    out = record.__dict__.copy()
    out["sent_at"] = record.sent_at.isoformat()
    out["received_at"] = record.received_at.isoformat()
    return out


def _shorten(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 1] + "…"


def _clock(moment: datetime) -> str:
    return moment.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]


#: What ``fleetbus query`` shows besides event types: the sequence ledger.
LEDGER_VIEWS = ("gaps", "duplicates")


def query(
    event_type: Annotated[
        str, typer.Argument(metavar="TYPE", help=f"an event type, or {' or '.join(LEDGER_VIEWS)}")
    ],
    robot: Annotated[str | None, typer.Option(help="only this robot")] = None,
    mission: Annotated[str | None, typer.Option(help="only events recorded under this mission")] = None,
    since: Annotated[str | None, typer.Option(help="from this time (ISO 8601 or e.g. 10m ago)")] = None,
    until: Annotated[str | None, typer.Option(help="before this time")] = None,
    limit: Annotated[int, typer.Option(help="at most this many, the newest")] = 50,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """Stored events of TYPE, oldest first (the newest LIMIT of them); or the open sequence gaps,
    or the duplicates the workers were sent."""
    if event_type in LEDGER_VIEWS:
        show_ledger(event_type, robot, limit, as_json)
        return
    if event_type not in EventType._value2member_map_:
        known = ", ".join([*(t.value for t in EventType), *LEDGER_VIEWS])
        fail(f"unknown TYPE {event_type!r}; known: {known}", code=2)
    q = EventQuery(
        type=event_type,
        robot_id=robot,
        since=parse_time(since),
        until=parse_time(until),
        limit=limit,
        newest_first=True,
        mission_id=mission,
    )
    records = list(reversed(run_with_store(settings(), lambda store: store.find_events(q))))
    if as_json:
        for record in records:
            typer.echo(json.dumps(record_dict(record)))
        return
    table = Table(title=f"{len(records)} {event_type} events")
    widest = max((len(r.robot_id) for r in records), default=5)
    seq_width = max((len(str(r.seq)) for r in records), default=3)
    table.add_column("robot", no_wrap=True)
    table.add_column("seq", justify="right", no_wrap=True)
    table.add_column("sent at (UTC)", no_wrap=True)
    table.add_column("body", no_wrap=True)
    room = max(20, console.width - widest - seq_width - 23 - 13)
    for record in records:
        table.add_row(
            record.robot_id,
            str(record.seq),
            _clock(record.sent_at),
            _shorten(json.dumps(record.body, separators=(",", ":")), room),
        )
    console.print(table)
    if len(records) == limit:
        console.print(f"[dim]showing the newest {limit}; use --limit or --since for more[/]")


def show_ledger(view: str, robot: str | None, limit: int, as_json: bool) -> None:
    """Open gaps in the robots' sequence numbers, or the duplicates the workers recognised."""
    if view == "gaps":
        gaps = run_with_store(settings(), lambda store: store.gaps(robot))
        if as_json:
            for gap in gaps:
                typer.echo(json.dumps({**asdict(gap), "missing": gap.size}, default=datetime.isoformat))
            return
        table = Table("robot", "missing seq", "events", "open since (UTC)", title=f"{len(gaps)} open gaps")
        for gap in gaps:
            span = str(gap.first) if gap.first == gap.last else f"{gap.first}-{gap.last}"
            table.add_row(gap.robot_id, span, str(gap.size), _clock(gap.detected_at))
        console.print(table)
        return
    duplicates = run_with_store(settings(), lambda store: store.duplicates(robot, limit))
    if as_json:
        for duplicate in duplicates:
            typer.echo(json.dumps(asdict(duplicate), default=datetime.isoformat))
        return
    table = Table("robot", "seq", "message id", "seen at (UTC)", "why", title=f"{len(duplicates)} duplicates")
    for d in duplicates:
        why = "redelivered by the broker" if d.redelivered else "sent again by the robot"
        table.add_row(d.robot_id, str(d.seq), d.message_id, _clock(d.seen_at), why)
    console.print(table)
