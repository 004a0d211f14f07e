"""``fleetbus schemas DIR``: write the JSON Schema of every message, and the AsyncAPI document."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fleetbus.cli.context import console, settings
from fleetbus.schemas.export import write_json_schemas
from fleetbus.settings import Settings


def robots_broker(config: Settings) -> str | None:
    """The broker address `fleetbus users add` hands robots, from the settings and the private
    node's state alone (nothing is started or asked): ``FLEETBUS_PUBLIC_AMQP_URL``, else
    ``FLEETBUS_AMQP_URL``'s, else the private node's AMQPS listener once it has run (none
    without the development tooling)."""
    if config.public_amqp_url or config.amqp_url:
        return config.public_amqp_url or config.amqp_url
    from fleetbus.cli.local_broker import local_broker

    local = local_broker()
    return local.public_url(config) if local is not None else None


def export_schemas(
    directory: Annotated[
        Path, typer.Argument(help="where to write <type>.schema.json and asyncapi.json")
    ] = Path("schemas-json"),
) -> None:
    """Write the JSON Schema of every event type (<type>.schema.json, and event.schema.json for the
    envelope of any type) and asyncapi.json, the AsyncAPI document of the bus: its channels
    (exchanges and queues), the messages on each, and its server: the broker robots are handed here."""
    config = settings()
    written = write_json_schemas(
        directory, broker_url=robots_broker(config), max_message_bytes=config.max_message_bytes
    )
    for path in written:
        console.print(f"wrote {path}")
