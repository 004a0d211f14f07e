"""``fleetbus timeline``: what a robot and the service exchanged in a time window, in order."""

from __future__ import annotations

import json
from typing import Annotated

import typer
from rich.table import Table

from fleetbus.broker.topology import inbox_bindings
from fleetbus.cli.context import clock, console, fail, route_map
from fleetbus.cli.services import with_recording, with_services
from fleetbus.cli.times import TIME_FORMS, parse_time
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.routing import NOTIFY_EXCHANGE, RobotKind, inbox_queue
from fleetbus.workers.recorder.queries import LIMIT_MAX, TIMELINE_LIMIT, record_view
from fleetbus.workers.recorder.summary import summarize


def registered_subscriptions(robot: str) -> list[str]:
    """Without a broker to ask: the topics the team registry says a robot of its kind follows."""

    found = with_services(lambda services: services.team.robot(robot))
    kind = found.kind if found else None
    return inbox_bindings(robot, RobotKind(kind) if kind else None, operator=False)


def timeline(
    robot: Annotated[str, typer.Argument(help="the robot (or operator) account")],
    since: Annotated[str, typer.Option(help=f"from this time: {TIME_FORMS}")] = "1h",
    until: Annotated[str | None, typer.Option(help="until this time (default: now; the same forms)")] = None,
    limit: Annotated[
        int, typer.Option(min=1, max=LIMIT_MAX, help="at most this many, the oldest first")
    ] = TIMELINE_LIMIT,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """Fault analysis: every message ROBOT sent or was sent, all types merged in time order.

    Sent: its events, its requests, and the service's refusals of them. Received: the
    notifications its inbox is bound to (asked of the broker now), and the hazard announcements
    delivered to it by name (a warden in service).
    """
    try:
        validate_name(robot)
    except ValueError as error:
        fail(str(error), code=2)
    routes = route_map()
    inbound = (
        routes.keys_into(inbox_queue(robot), NOTIFY_EXCHANGE) if routes else registered_subscriptions(robot)
    )
    start, end = parse_time(since, "--since"), parse_time(until, "--until")
    result = with_recording(lambda recording: recording.timeline(robot, start, end, inbound, limit))
    if as_json:
        for entry in result.entries:
            typer.echo(json.dumps({"sent": entry.sent, **record_view(entry.record)}, ensure_ascii=False))
        return
    table = Table(title=f"{robot}: {len(result.entries)} messages since {since}")
    table.add_column("recorded at (UTC)", no_wrap=True)
    table.add_column("", no_wrap=True)
    table.add_column("type", no_wrap=True)
    table.add_column("routing key", no_wrap=True)
    table.add_column("what", no_wrap=True)
    room = max(24, console.width - 23 - 3 - 14 - 30 - 16)
    for entry in result.entries:
        record = entry.record
        table.add_row(
            clock(record.recorded_at),
            "→" if entry.sent else "←",
            record.type + ("" if record.known else " (unknown)"),
            record.routing_key,
            summarize(record, room),
            style="red" if record.type == "dead_letter" else None,
        )
    console.print(table)
    console.print(
        f"[dim]→ sent by {robot}, ← sent to it (inbox bound to {', '.join(inbound) or 'nothing'}; "
        "hazard announcements delivered to it by name)[/]"
    )
    if result.truncated:
        console.print(f"[dim]more than {limit}: use --limit or a narrower window[/]")
