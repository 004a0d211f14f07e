"""``fleetbus missions``: missions of the service layer from the server's shell, through the services
the HTTP API and the console use (the same checks, the same refusals).

fleetbus missions create --owner client1 --use-case survey --title "East wing"   # for a client or planner
fleetbus missions comment m-1 "the survey is done" --as ops1   # comment as the account ops1
fleetbus missions comments m-1 [--json]                       # the thread, oldest first
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table
from rich.text import Text

from fleetbus.cli.context import clock, console, endpoint, fail
from fleetbus.cli.services import with_services

if TYPE_CHECKING:
    from fleetbus.api.services.standalone import Services
    from fleetbus.workers.store.comments import Comment
    from fleetbus.workers.store.missions import Mission

app = typer.Typer(
    help="Missions of the service layer: create one for a client; a mission's discussion.",
    no_args_is_help=True,
)


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

    from fleetbus.api.services.errors import NotFound
    from fleetbus.schemas.missions import MissionPlan

    try:
        body = MissionPlan.model_validate(json.loads(plan.read_text())) if plan else MissionPlan()
    except (OSError, ValueError, ValidationError) as error:
        fail(f"{plan}: {error}", 2)

    async def run(services: Services) -> Mission:
        user = await services.users.get_user(owner)
        if user is None:
            raise NotFound(f"no user {owner!r}")
        return await services.missions.create(user, use_case, title, body)

    mission = with_services(run, endpoint().amqp_url)
    console.print(
        f"created mission {mission.mission_id} ({mission.use_case}) for {mission.owner}: {mission.title}",
        highlight=False,
    )


@app.command("comment")
def comment(
    mission_id: Annotated[str, typer.Argument(metavar="ID", help="the mission, e.g. m-1")],
    text: Annotated[str, typer.Argument(help="the comment (quote it)")],
    author: Annotated[
        str,
        typer.Option(
            "--as",
            help="the account that comments, one of the registry (`fleetbus users list`): the rule "
            "is the API's (the mission's client, planners, supervisors, operators, admins)",
        ),
    ],
    as_json: Annotated[bool, typer.Option("--json", help="print the comment as JSON")] = False,
) -> None:
    """Comment on mission ID as the account --as, as POST /missions/ID/comments does for it."""
    from fleetbus.api.services.errors import NotFound

    async def add(services: Services) -> Comment:
        user = await services.users.get_user(author)
        if user is None:
            raise NotFound(f"no account {author!r} in the registry (`fleetbus users list`); nothing stored")
        return await services.mission_comments.add(user, mission_id, text)

    made = with_services(add)
    if as_json:
        typer.echo(json.dumps(made.as_dict()))
        return
    console.print(
        f"comment {made.number} on {made.mission_id} by {made.author} ({made.role}) at {clock(made.at)} UTC"
    )


@app.command("comments")
def comments(
    mission_id: Annotated[str, typer.Argument(metavar="ID", help="the mission, e.g. m-1")],
    limit: Annotated[int, typer.Option(min=1, help="the newest this many comments")] = 500,
    as_json: Annotated[bool, typer.Option("--json", help="one JSON object a line")] = False,
) -> None:
    """Mission ID's discussion, oldest first: who (and in which role), when (UTC), what."""

    async def read(services: Services) -> list[Comment]:
        return await services.mission_comments.any_thread(mission_id, limit)

    found = with_services(read)
    if as_json:
        for each in found:
            typer.echo(json.dumps(each.as_dict()))
        return
    table = Table("#", "when (UTC)", "author", "role", "comment", title=f"mission {mission_id}")
    for each in found:
        table.add_row(str(each.number), clock(each.at), each.author, each.role, Text(each.text))  # as typed
    console.print(table)
    if not found:
        console.print("no comments yet")
