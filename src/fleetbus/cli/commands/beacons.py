"""``fleetbus beacons load | list | stranded``: the beacon registry and where people are likely stranded."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
import yaml
from rich.table import Table

from fleetbus.cli.context import console, fail
from fleetbus.cli.services import with_services
from fleetbus.cli.times import TIME_FORMS, parse_time

if TYPE_CHECKING:
    from fleetbus.api.services.standalone import Services
    from fleetbus.workers.store.beacons import Beacon

app = typer.Typer(help="BLE beacons: the registry and the people likely stranded.", no_args_is_help=True)


@app.command("load")
def load(path: Path) -> None:
    """Add or update beacons from a YAML or JSON list of {id, x, y, label} (x, y: finite numbers,
    metres in the map frame); a file with one bad entry is refused whole."""
    try:
        entries = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as error:
        fail(f"cannot read {path}: {error}")

    async def work(services: Services) -> list[Beacon]:
        return await services.beacons.load(entries)

    beacons = with_services(work, refused=f"{path}: ")
    console.print(f"{len(beacons)} beacons in the registry")


@app.command("list")
def list_beacons() -> None:
    """The registry."""
    table = Table("beacon", "x", "y", "label", "visited at")

    async def read(services: Services) -> list[Beacon]:
        return await services.beacons.registry()

    for beacon in with_services(read):
        table.add_row(
            beacon.beacon_id, f"{beacon.x:g}", f"{beacon.y:g}", beacon.label, str(beacon.visited_at or "")
        )
    console.print(table)


@app.command("stranded")
def stranded_people(
    since: Annotated[
        str,
        typer.Option(help=f"heard since: {TIME_FORMS}; at most FLEETBUS_BEACON_WINDOW_MAX_MINUTES (60) back"),
    ] = "10m",
    as_json: Annotated[bool, typer.Option("--json")] = False,
) -> None:
    """Beacons heard recently: where people are likely stranded, and when they were last heard."""
    start = parse_time(since, "--since")
    assert start is not None

    async def read(services: Services) -> list[dict[str, Any]]:
        return await services.beacons.stranded(start)

    entries = with_services(read)
    if as_json:
        typer.echo(json.dumps(entries, indent=2))
        return
    table = Table(
        "beacon",
        "label",
        "where",
        "last heard",
        "RSSI",
        "by",
        "sightings",
        "visited",
        title="likely stranded",
    )
    for entry in entries:
        where = entry["location"] and f"({entry['location']['x']:g}, {entry['location']['y']:g})"
        table.add_row(
            entry["beacon_id"],
            entry["label"] or "?",
            where or "not in registry",
            entry["last_seen"][:23],
            str(entry["last_rssi"]),
            entry["seen_by"],
            str(entry["sightings"]),
            entry["visited_at"] or "no",
        )
    console.print(table)
