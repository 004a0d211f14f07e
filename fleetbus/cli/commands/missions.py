"""``fleetbus missions create``: a mission made for a client or planner, through the missions service
the HTTP API's ``POST /missions`` and the console's New mission page use (the same checks: the
owner's role and its allowed use cases, the same refusal)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from fleetbus.cli.accounts import with_accounts
from fleetbus.cli.context import console, endpoint, fail

if TYPE_CHECKING:
    from fleetbus.api.accounts import Accounts
    from fleetbus.broker.management import ManagementAPI
    from fleetbus.workers.store import Repositories
    from fleetbus.workers.store.missions import Mission

app = typer.Typer(help="Missions of the service layer.", no_args_is_help=True)


@app.command("create")
def create(
    owner: Annotated[
        str,
        typer.Option(help="the client or planner it is for: it owns it, and its allowed use cases apply"),
    ],
    use_case: Annotated[str, typer.Option(help="its use case (`GET /use-cases` lists them)")],
    title: Annotated[str, typer.Option(help="its title")],
    plan: Annotated[
        Path | None,
        typer.Option(help="a JSON file of its plan (geofence, points of interest...); default: empty"),
    ] = None,
) -> None:
    """Create a mission in planning for OWNER, as OWNER's `POST /missions` would: refused when
    OWNER may not create missions or may not use the use case (`fleetbus users use-cases`)."""
    from pydantic import ValidationError

    from fleetbus.api.missions import Missions
    from fleetbus.schemas.missions import MissionPlan
    from fleetbus.workers.sites import send_mission_to_sites

    try:
        body = MissionPlan.model_validate(json.loads(plan.read_text())) if plan else MissionPlan()
    except (OSError, ValueError, ValidationError) as error:
        fail(f"{plan}: {error}", 2)
    ep = endpoint()

    async def run(accounts: Accounts, repos: Repositories, _api: ManagementAPI) -> Mission:
        missions = Missions(
            repos.missions,
            repos.channels,
            lambda mission: send_mission_to_sites(repos.sites, ep.amqp_url, mission),
        )
        return await missions.create(await accounts.get(owner), use_case, title, body)

    mission = with_accounts(ep, run)
    console.print(
        f"created mission {mission.mission_id} ({mission.use_case}) for {mission.owner}: {mission.title}",
        highlight=False,
    )
