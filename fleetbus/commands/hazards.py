"""``fleetbus hazards``: every hazard of a mission and where it stands."""

from __future__ import annotations

import json
from typing import Annotated

import typer
from rich.table import Table

from fleetbus.context import console, settings
from workers.store import run_with_store
from workers.store.hazards import DEFAULT_MISSION


def hazards(
    mission: Annotated[str, typer.Option(help="the mission")] = DEFAULT_MISSION,
    as_json: Annotated[bool, typer.Option("--json")] = False,
) -> None:
    """Hazards not cleared yet, in the order detected: held, announced, claimed or reached."""
    found = run_with_store(settings(), lambda store: store.open_hazards(mission))
    if as_json:
        for hazard in found:
            typer.echo(json.dumps(hazard.as_dict()))
        return
    table = Table(
        "id", "state", "description", "where", "detected at", "by", "claimed by", title=f"mission {mission}"
    )
    for hazard in found:
        body = hazard.event["body"]
        table.add_row(
            str(hazard.hazard_id),
            hazard.state.value,
            body["description"],
            f"({body['pose']['x']:g}, {body['pose']['y']:g})",
            body["detected_at"][:23],
            hazard.robot_id,
            hazard.claimed_by or "",
        )
    console.print(table)
