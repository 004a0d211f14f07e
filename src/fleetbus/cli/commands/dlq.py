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
    from fleetbus.api.services.dead_letters import Listing
    from fleetbus.api.services.standalone import Services


def dlq(
    limit: Annotated[int, typer.Option(min=1, help="at most this many")] = 1000,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """List the dead-letter queue without removing anything from it, and how many older dead
    letters the queue dropped when full (FLEETBUS_DEAD_LETTERS_MAX)."""

    async def read(services: Services) -> tuple[Listing, int]:
        queue = services.dead_letters
        listing = await queue.listing(limit)
        return listing, 0 if as_json else await queue.dropped()

    listing, dropped = with_services(read, endpoint().amqp_url)
    letters = listing.letters
    if as_json:
        for letter in letters:
            typer.echo(json.dumps(letter.as_dict()))
        return
    title = f"{listing.in_queue:,} dead letters"
    if len(letters) < listing.in_queue:
        title += f", the oldest {len(letters):,} listed (--limit)"
    table = Table("reason", "from", "routing key", "rejected at", "detail", title=title)
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
