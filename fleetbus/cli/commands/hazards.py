"""``fleetbus hazards``: every hazard of a mission, where it stands, and why a held one waits."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from typing import Annotated

import typer
from rich.table import Table

from fleetbus.cli.context import console, settings
from fleetbus.workers.store import Hazard, HazardState, Repositories, run_with_repositories
from fleetbus.workers.store.hazards import DEFAULT_MISSION
from fleetbus.workers.team import gate, last_seen, why_held


async def _open_and_why(repos: Repositories, mission: str) -> list[tuple[Hazard, str]]:
    """The mission's open hazards, each with why it is held ("" once announced)."""
    found = await repos.hazards.open_hazards(mission)
    if not any(hazard.state is HazardState.HELD for hazard in found):
        return [(hazard, "") for hazard in found]
    team = await repos.hazards.robots()
    seen = {robot.name: await last_seen(repos.events, robot.name) for robot in team}
    state, now = gate(team), datetime.now(timezone.utc)
    return [(hazard, why_held(hazard, state, seen, now)) for hazard in found]


def hazards(
    mission: Annotated[str, typer.Option(help="the mission")] = DEFAULT_MISSION,
    as_json: Annotated[bool, typer.Option("--json")] = False,
) -> None:
    """Hazards not cleared yet, in the order detected: held (and why), announced, claimed or reached."""
    found = run_with_repositories(settings(), lambda repos: _open_and_why(repos, mission))
    if as_json:
        for hazard, why in found:
            typer.echo(json.dumps({**hazard.as_dict(), "held_because": why or None}))
        return
    table = Table(
        "id",
        "state",
        "description",
        "where",
        "detected at",
        "by",
        "claimed by",
        "held because",
        title=f"mission {mission}",
    )
    for hazard, why in found:
        body = hazard.event["body"]
        table.add_row(
            str(hazard.hazard_id),
            hazard.state.value,
            body["description"],
            f"({body['pose']['x']:g}, {body['pose']['y']:g})",
            body["detected_at"][:23],
            hazard.robot_id,
            hazard.claimed_by or "",
            why,
        )
    console.print(table)
