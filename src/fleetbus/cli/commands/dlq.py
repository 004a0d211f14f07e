"""``fleetbus dlq``: the dead-lettered messages and why each was refused."""

from __future__ import annotations

import json
from typing import Annotated

import typer
from rich.table import Table

from fleetbus.bounds import bounds
from fleetbus.cli.context import console, dead_letters, settings
from fleetbus.schemas.routing import DEAD_LETTER_QUEUE
from fleetbus.workers.overflow import dropped_from_queue
from fleetbus.workers.store import run_with_repositories


def dlq(
    limit: Annotated[int, typer.Option(help="at most this many")] = 1000,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """List the dead-letter queue without removing anything from it, and how many older dead
    letters the queue dropped when full (FLEETBUS_DEAD_LETTERS_MAX)."""
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
    dropped = dropped_dead_letters()
    if dropped:
        kept = bounds(settings()).dead_letters.describe()
        console.print(
            f"{dropped:,} older ones were dropped: the queue keeps the newest {kept} "
            "(FLEETBUS_DEAD_LETTERS_MAX); the recording keeps them all (`fleetbus query dead_letter`)",
            soft_wrap=True,
        )


def dropped_dead_letters() -> int:
    """What the full queue dropped, as the workers counted it."""
    counts = run_with_repositories(settings(), lambda repos: repos.housekeeping.bound_counts())
    return dropped_from_queue(counts, DEAD_LETTER_QUEUE)
