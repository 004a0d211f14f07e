"""``fleetbus schemas DIR``: write the JSON Schema of every message."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fleetbus.cli.context import console
from fleetbus.schemas.export import write_json_schemas


def export_schemas(
    directory: Annotated[Path, typer.Argument(help="where to write *.schema.json")] = Path("schemas-json"),
) -> None:
    """Export the JSON Schemas of every event type (and the envelope union)."""
    for path in write_json_schemas(directory):
        console.print(f"wrote {path}")
