"""``fleetbus schemas DIR``: write the JSON Schema of every message and the AsyncAPI document."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fleetbus.cli.context import console
from fleetbus.schemas.export import write_json_schemas


def export_schemas(
    directory: Annotated[
        Path, typer.Argument(help="where to write <type>.schema.json and asyncapi.json")
    ] = Path("schemas-json"),
) -> None:
    """Write the JSON Schema of every event type (<type>.schema.json, and event.schema.json for the
    envelope of any type) and asyncapi.json, the AsyncAPI document of the bus: its channels
    (exchanges and queues) and the messages on each."""
    for path in write_json_schemas(directory):
        console.print(f"wrote {path}")
