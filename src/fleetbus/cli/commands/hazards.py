"""``fleetbus hazards``: every hazard of a mission, where it stands, and why a held one waits;
``fleetbus hazards claim|reached|cleared|release ID --for WARDEN``: a step taken for a warden."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from fleetbus.cli.context import actor, console, endpoint, fail, settings
from fleetbus.workers.store import Hazard, HazardState, Repositories, run_with_repositories
from fleetbus.workers.store.hazards import DEFAULT_MISSION
from fleetbus.workers.team import gate, last_seen_of, why_held

if TYPE_CHECKING:
    from fleetbus.workers.hazard_steps import StepTaken


async def _open_and_why(repos: Repositories, mission: str) -> list[tuple[Hazard, str]]:
    """The mission's open hazards, each with why it is held ("" once announced)."""
    found = await repos.hazards.open_hazards(mission)
    if not any(hazard.state is HazardState.HELD for hazard in found):
        return [(hazard, "") for hazard in found]
    team = await repos.hazards.robots()
    state, now = gate(team), datetime.now(timezone.utc)
    seen = await last_seen_of(repos.events, state.waiting_for)
    return [(hazard, why_held(hazard, state, seen, now)) for hazard in found]


app = typer.Typer(
    help="Hazards not cleared yet, in the order detected: held (and why), announced, claimed or "
    "reached. `claim`, `reached`, `cleared` and `release` take a hazard's step for a warden.",
    invoke_without_command=True,
)
Mission = Annotated[str, typer.Option(help="the mission")]


@app.callback()
def hazards(
    ctx: typer.Context,
    mission: Mission = DEFAULT_MISSION,
    as_json: Annotated[bool, typer.Option("--json")] = False,
    offset: Annotated[int, typer.Option(min=0, help="skip this many hazards")] = 0,
    limit: Annotated[int | None, typer.Option(min=1, help="show at most this many hazards")] = None,
) -> None:
    """Hazards not cleared yet, in the order detected: held (and why), announced, claimed or reached."""
    if ctx.invoked_subcommand is not None:
        return
    found = run_with_repositories(settings(), lambda repos: _open_and_why(repos, mission))
    found = found[offset : None if limit is None else offset + limit]
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
        "site",
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
            f"{hazard.site} (#{hazard.site_hazard_id})" if hazard.site else "",
            hazard.claimed_by or "",
            why,
        )
    console.print(table)


HazardId = Annotated[int, typer.Argument(help="the hazard's id (`fleetbus hazards` lists them)")]
Warden = Annotated[str, typer.Option("--for", help="the warden the step is taken for")]
By = Annotated[str | None, typer.Option(help="who takes the step, for the record (default: your login)")]


def _step(step: str, hazard_id: int, warden: str, mission: str, by: str | None) -> None:
    from fleetbus.workers.hazard_steps import StepRefused, take_step

    who, admin_url = actor(by), endpoint().amqp_url

    async def work(repos: Repositories) -> StepTaken:
        return await take_step(
            repos.hazards, repos.channels, admin_url, mission, hazard_id, warden, step, who
        )

    try:
        taken = run_with_repositories(settings(), work)
    except StepRefused as refused:
        fail(str(refused))
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
