"""``fleetbus dlq``: the dead-lettered messages and why each was refused."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from fleetbus.bounds import bounds
from fleetbus.cli.context import console, endpoint, settings
from fleetbus.cli.services import with_services

if TYPE_CHECKING:
    from fleetbus.api.services.dead_letters import DeadLetter
    from fleetbus.api.services.standalone import Services


def dlq(
    limit: Annotated[int, typer.Option(min=1, help="at most this many")] = 1000,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """List the dead-letter queue without removing anything from it, and how many older dead
    letters the queue dropped when full (FLEETBUS_DEAD_LETTERS_MAX)."""

    async def read(services: Services) -> tuple[list[DeadLetter], int]:
        queue = services.dead_letters
        letters = (await queue.listing(limit)).letters
        return letters, 0 if as_json else await queue.dropped()

    letters, dropped = with_services(read, endpoint().amqp_url)
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
    if dropped:
        kept = bounds(settings()).dead_letters.describe()
        console.print(
            f"{dropped:,} older ones were dropped: the queue keeps the newest {kept} "
            "(FLEETBUS_DEAD_LETTERS_MAX); the recording keeps them all (`fleetbus query dead_letter`)",
            soft_wrap=True,
        )
