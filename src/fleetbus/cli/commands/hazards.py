"""``fleetbus hazards``: every open hazard (of every mission, or of one), where it stands, and why
a held one waits;
``fleetbus hazards claim|reached|cleared|release ID --for WARDEN``: a step taken for a warden."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from fleetbus.api.services.hazards import DEFAULT_MISSION
from fleetbus.cli.context import actor, console, endpoint
from fleetbus.cli.services import with_services

if TYPE_CHECKING:
    from fleetbus.api.services.hazards import OpenHazard
    from fleetbus.api.services.standalone import Services
    from fleetbus.workers.hazard_steps import StepTaken

app = typer.Typer(
    help="Hazards not cleared yet, in the order detected: held (and why), announced, claimed or "
    "reached. `claim`, `reached`, `cleared` and `release` take a hazard's step for a warden.",
    invoke_without_command=True,
)
Mission = Annotated[str, typer.Option(help="the hazard's mission (`fleetbus hazards` lists it)")]


@app.callback()
def hazards(
    ctx: typer.Context,
    mission: Annotated[
        str | None, typer.Option(help="only this mission's (default: every mission's)")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json")] = False,
    offset: Annotated[int, typer.Option(min=0, help="skip this many hazards")] = 0,
    limit: Annotated[int | None, typer.Option(min=1, help="show at most this many hazards")] = None,
) -> None:
    """Hazards not cleared yet, in the order detected: held (and why), announced, claimed or reached."""
    if ctx.invoked_subcommand is not None:
        return

    async def read(services: Services) -> list[OpenHazard]:
        return await services.hazards.open(mission)

    found = with_services(read)[offset : None if limit is None else offset + limit]
    if as_json:
        for each in found:
            typer.echo(json.dumps({**each.hazard.as_dict(), "held_because": each.held_because or None}))
        return
    table = Table(
        "mission",
        "id",
        "state",
        "description",
        "where",
        "detected at",
        "by",
        "site",
        "claimed by",
        "held because",
        title=f"mission {mission}" if mission else "every mission",
    )
    for each in found:
        hazard, body = each.hazard, each.hazard.event["body"]
        table.add_row(
            hazard.mission_id,
            str(hazard.hazard_id),
            hazard.state.value,
            body["description"],
            f"({body['pose']['x']:g}, {body['pose']['y']:g})",
            body["detected_at"][:23],
            hazard.robot_id,
            f"{hazard.site} (#{hazard.site_hazard_id})" if hazard.site else "",
            hazard.claimed_by or "",
            each.held_because,
        )
    console.print(table)


HazardId = Annotated[int, typer.Argument(help="the hazard's id (`fleetbus hazards` lists them)")]
Warden = Annotated[str, typer.Option("--for", help="the warden the step is taken for")]
By = Annotated[str | None, typer.Option(help="who takes the step, for the record (default: your login)")]


def _step(step: str, hazard_id: int, warden: str, mission: str, by: str | None) -> None:
    """As ``POST /hazards/MISSION/ID/STEP`` does: the same checks and refusals."""
    who = actor(by)

    async def work(services: Services) -> StepTaken:
        return await services.hazard_steps.take(mission, hazard_id, warden, step, who)

    taken = with_services(work, endpoint().amqp_url)
    console.print(f"hazard {hazard_id}: {taken.hazard.state.value} for {warden} (by {who})", highlight=False)
    if taken.not_told:
        console.print(f"[yellow]{taken.not_told}[/]", highlight=False)


@app.command("claim")
def claim(hazard_id: HazardId, warden: Warden, mission: Mission = DEFAULT_MISSION, by: By = None) -> None:
    """Claim hazard HAZARD_ID for a warden in service (the rules of the warden's own request);
    the warden is told in its inbox."""
    _step("claim", hazard_id, warden, mission, by)


@app.command("reached")
def reached(hazard_id: HazardId, warden: Warden, mission: Mission = DEFAULT_MISSION, by: By = None) -> None:
    """Report that the warden holding the claim reached hazard HAZARD_ID."""
    _step("reached", hazard_id, warden, mission, by)


@app.command("cleared")
def cleared(hazard_id: HazardId, warden: Warden, mission: Mission = DEFAULT_MISSION, by: By = None) -> None:
    """Report that the warden holding the claim cleared hazard HAZARD_ID."""
    _step("cleared", hazard_id, warden, mission, by)


@app.command("release")
def release(hazard_id: HazardId, warden: Warden, mission: Mission = DEFAULT_MISSION, by: By = None) -> None:
    """Give up the warden's claim of hazard HAZARD_ID: it is announced again."""
    _step("release", hazard_id, warden, mission, by)
