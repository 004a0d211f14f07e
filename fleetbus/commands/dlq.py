"""``fleetbus dlq``: the dead-lettered messages and why each was refused."""

from __future__ import annotations

import json
from typing import Annotated

import typer
from rich.table import Table

from fleetbus.context import console, dead_letters


def dlq(
    limit: Annotated[int, typer.Option(help="at most this many")] = 1000,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """List the dead-letter queue without removing anything from it."""
    letters = dead_letters(limit)
    if as_json:
        for letter in letters:
            typer.echo(json.dumps(letter.as_dict()))
        return
    table = Table(
        "reason", "from", "routing key", "rejected at", "detail", title=f"{len(letters)} dead letters"
    )
    for letter in letters:
        table.add_row(
            letter.reason, letter.user_id or "?", letter.routing_key, letter.rejected_at or "", letter.detail
        )
    console.print(table)
