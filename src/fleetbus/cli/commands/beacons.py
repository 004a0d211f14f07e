"""``fleetbus beacons load | list | stranded``: the beacon registry and where people are likely stranded."""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Annotated, TypeVar

import typer
import yaml
from rich.table import Table

from fleetbus.cli.context import console, fail, settings
from fleetbus.cli.times import TIME_FORMS, parse_time
from fleetbus.workers.beacons import stranded
from fleetbus.workers.store import Repositories, run_with_repositories
from fleetbus.workers.store.beacons import Beacon

T = TypeVar("T")
app = typer.Typer(help="BLE beacons: the registry and the people likely stranded.", no_args_is_help=True)


def _with_repositories(operation: Callable[[Repositories], Awaitable[T]]) -> T:
    return run_with_repositories(settings(), operation)


def parse_beacons(path: Path) -> list[Beacon]:
    """A YAML or JSON list of ``{id, x, y, label}``."""
    try:
        entries = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as error:
        fail(f"cannot read {path}: {error}")
    if not isinstance(entries, list):
        fail(f"{path}: expected a list of beacons with id, x, y and label")
    beacons = []
    for number, entry in enumerate(entries, 1):
        try:
            beacons.append(
                Beacon(str(entry["id"]), float(entry["x"]), float(entry["y"]), str(entry.get("label", "")))
            )
        except (KeyError, TypeError, ValueError) as error:
            fail(f"{path}: beacon {number}: needs id, x and y ({error!r})")
    return beacons


@app.command("load")
def load(path: Path) -> None:
    """Add or update beacons from a YAML or JSON list of {id, x, y, label}."""
    beacons = parse_beacons(path)

    _with_repositories(lambda repos: repos.beacons.put_beacons(beacons))
    console.print(f"{len(beacons)} beacons in the registry")


@app.command("list")
def list_beacons() -> None:
    """The registry."""
    table = Table("beacon", "x", "y", "label", "visited at")
    for beacon in _with_repositories(lambda repos: repos.beacons.beacons()):
        table.add_row(
            beacon.beacon_id, f"{beacon.x:g}", f"{beacon.y:g}", beacon.label, str(beacon.visited_at or "")
        )
    console.print(table)


@app.command("stranded")
def stranded_people(
    since: Annotated[str, typer.Option(help=f"heard since: {TIME_FORMS}")] = "10m",
    as_json: Annotated[bool, typer.Option("--json")] = False,
) -> None:
    """Beacons heard recently: where people are likely stranded, and when they were last heard."""
    start = parse_time(since, "--since")
    assert start is not None
    entries = _with_repositories(lambda repos: stranded(repos.beacons, repos.events, start))
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
