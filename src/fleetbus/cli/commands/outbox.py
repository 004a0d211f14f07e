"""``fleetbus outbox ROBOT``: what waits in a robot's personal database for the broker, by type."""

from __future__ import annotations

import json
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from fleetbus.cli.context import console, fail, settings
from fleetbus.publishers.client import outbox_folder
from fleetbus.publishers.outbox import Outbox, OutboxError


def _age(moment: datetime | None) -> str:
    if moment is None:
        return ""
    seconds = (datetime.now(timezone.utc) - moment).total_seconds()
    for unit, size in (("d", 86400), ("h", 3600), ("m", 60)):
        if seconds >= size:
            return f"{seconds / size:.1f} {unit}"
    return f"{seconds:.1f} s"


def outbox(
    robot: str,
    state_dir: Annotated[
        Path | None, typer.Option(help="the robots' state folder (default: $FLEETBUS_DATA_DIR/robots)")
    ] = None,
    show: Annotated[int, typer.Option("--list", help="also list the oldest N waiting events")] = 0,
    as_json: Annotated[bool, typer.Option("--json", help="JSON instead of tables")] = False,
) -> None:
    """What waits in ROBOT's outbox for the broker, by type, oldest first; what it dropped and refused.

    Safe while the robot runs: it only reads.
    """
    folder = outbox_folder(state_dir or settings().robots_dir, robot)
    try:
        box = Outbox(folder, read_only=True)
    except FileNotFoundError:
        fail(f"{robot} has no outbox at {folder}")
    except OutboxError as error:  # the robot sets such a file aside when it starts
        fail(str(error))
    try:
        summary = box.summary()
        oldest = box.entries(show) if show else []
        refused = box.refused()
    finally:
        box.close()
    if as_json:
        listed = {
            "robot": robot,
            "types": {event_type: asdict(s) for event_type, s in summary.items()},
            "oldest": [{k: v for k, v in asdict(e).items() if k not in ("body", "position")} for e in oldest],
            "refused": [asdict(r) for r in refused],
        }
        typer.echo(json.dumps(listed, default=lambda value: value.isoformat()))
        return
    waiting = sum(s.waiting for s in summary.values())
    table = Table(title=f"{robot}'s outbox: {waiting} waiting")
    for column in ("type", "waiting", "oldest sent at (UTC)", "waiting for", "dropped", "refused"):
        table.add_column(column, justify="left" if column == "type" else "right")
    for event_type, s in summary.items():
        table.add_row(
            event_type,
            str(s.waiting),
            s.oldest.strftime("%Y-%m-%d %H:%M:%S") if s.oldest else "",
            _age(s.oldest),
            str(s.dropped),
            str(s.refused),
        )
    console.print(table)
    if oldest:
        listing = Table(
            "epoch", "seq", "type", "sent at (UTC)", "message id", title=f"the oldest {len(oldest)}"
        )
        for entry in oldest:
            listing.add_row(
                entry.epoch, str(entry.seq), entry.type, entry.sent_at.isoformat()[:23], entry.message_id
            )
        console.print(listing)
    if refused:
        refusals = Table(
            "epoch", "seq", "type", "refused at", "reason", title="refused by the broker, not resent"
        )
        for r in refused:
            refusals.add_row(r.epoch, str(r.seq), r.type, r.refused_at.isoformat()[:19], r.reason)
        console.print(refusals)
