"""``fleetbus trace MESSAGE_ID``: where a message came from and who received it."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import typer
from rich.table import Table

from fleetbus.broker.routes import Route
from fleetbus.cli.context import clock, console, fail, route_map
from fleetbus.cli.services import with_recording
from fleetbus.workers.recorder.queries import record_view

if TYPE_CHECKING:
    from fleetbus.api.services.recording import RecordedMessage, Recording, Trace


def _consumers(route: Route) -> str:
    """The consuming accounts (``--json`` also gives their connections)."""
    return ", ".join(sorted({c.label for c in route.consumers})) or "none now"


def _provenance(record: RecordedMessage, result: Trace) -> Table:
    table = Table(show_header=False, title=f"message {result.message_id}", title_justify="left")
    table.add_column(style="bold")
    table.add_column()
    rows = [
        ("type", record.type + ("" if record.known else " (no fleetbus schema: stored as received)")),
        ("published by", f"{record.user_id or '(no user_id)'} (user_id, validated by the broker)"),
        ("exchange", record.exchange),
        ("routing key", record.routing_key),
        (
            "mission",
            (result.stored.mission_id if result.stored else None) or record.mission_id or "none recorded",
        ),
        ("sent at", clock(record.sent_at) if record.sent_at else "unknown"),
        ("recorded at", clock(record.recorded_at)),
        ("received by the service", clock(result.stored.received_at) if result.stored else "not stored"),
        ("size", f"{record.size} bytes"),
    ]
    if record.problem:
        rows.append(("note", record.problem))
    for name, value in rows:
        table.add_row(name, value)
    return table


def _routes(result: Trace, records: list[RecordedMessage], title: str, label: str | None = None) -> Table:
    """One row per queue each record reaches; ``label`` names a first column telling records apart."""
    table = Table(title=title, title_justify="left")
    for column in ([label] if label else []) + ["queue", "via", "consumers now", "outcome"]:
        table.add_column(column)
    for record in records:
        for route in result.routes.get(record.key, []):
            cells = [record.routing_key] if label else []
            cells += [
                route.queue,
                " → ".join(route.via),
                _consumers(route),
                result.outcome(record, route.queue, clock),
            ]
            table.add_row(*cells)
    return table


def _as_json(result: Trace) -> dict[str, Any]:
    def routes(record: RecordedMessage) -> list[dict[str, Any]]:
        return [
            {"queue": r.queue, "via": list(r.via), "consumers": [c.__dict__ for c in r.consumers]}
            for r in result.routes.get(record.key, [])
        ]

    return {
        "message_id": result.message_id,
        "records": [{**record_view(r), "routes": routes(r)} for r in result.records],
        "stored": {
            "received_at": result.stored.received_at.isoformat(),
            "mission_id": result.stored.mission_id,
            "epoch": result.stored.epoch,
            "seq": result.stored.seq,
        }
        if result.stored
        else None,
        "caused": [{**record_view(r), "routes": routes(r)} for r in result.caused],
    }


def trace(
    message_id: str,
    as_json: bool = typer.Option(False, "--json", help="JSON instead of tables"),
) -> None:
    """Where MESSAGE_ID came from (broker-validated user, exchange, routing key, mission, times),
    what the service made of it, and the queues and consumers that receive such a message."""
    routes = route_map()

    async def run(recording: Recording) -> Trace:
        return await recording.trace(message_id, routes)

    result = with_recording(run, events=True)
    origin = result.origin
    if origin is None:
        fail(
            f"message {message_id!r} was never recorded (is the recorder running? `fleetbus recorder types`)"
        )
    if as_json:
        typer.echo(json.dumps(_as_json(result), ensure_ascii=False, indent=2))
        return
    console.print(_provenance(origin, result))
    if routes is not None:
        console.print(_routes(result, [origin], "received by (the broker's routes now)"))
        if result.caused:
            console.print(
                _routes(result, result.caused, "notifications it caused, and their receivers", "notification")
            )
    elif result.caused:
        console.print(
            f"caused {len(result.caused)} notifications: {', '.join(r.routing_key for r in result.caused)}"
        )
