"""``fleetbus missions``: a mission's discussion from the server's shell.

fleetbus missions comment m-1 "the survey is done" --as ops1   # comment as the account ops1
fleetbus missions comments m-1 [--json]                       # the thread, oldest first
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table
from rich.text import Text

from fleetbus.cli.context import clock, console, fail, settings

if TYPE_CHECKING:
    from fleetbus.api.mission_comments import MissionComments
    from fleetbus.workers.store import Repositories
    from fleetbus.workers.store.comments import Comment

app = typer.Typer(help="A mission's discussion: its thread, and a comment added to it.", no_args_is_help=True)


def _discussions(repos: Repositories) -> MissionComments:
    from fleetbus.api.mission_comments import MissionComments
    from fleetbus.api.missions import Missions

    return MissionComments(Missions(repos.missions, repos.channels), repos.comments)


@app.command("comment")
def comment(
    mission_id: Annotated[str, typer.Argument(metavar="ID", help="the mission, e.g. m-1")],
    text: Annotated[str, typer.Argument(help="the comment (quote it)")],
    author: Annotated[
        str,
        typer.Option(
            "--as",
            help="the account that comments: the rule is the API's (the mission's client, planners, "
            "supervisors, operators, admins)",
        ),
    ],
    as_json: Annotated[bool, typer.Option("--json", help="print the comment as JSON")] = False,
) -> None:
    """Comment on mission ID as the account --as, as POST /missions/ID/comments does for it."""
    from fleetbus.api.errors import NotFound, ServiceRefusal
    from fleetbus.workers.store import run_with_repositories

    async def add(repos: Repositories) -> Comment:
        user = await repos.users.get_user(author)
        if user is None:
            raise NotFound(f"no user {author!r}")
        return await _discussions(repos).add(user, mission_id, text)

    try:
        made = run_with_repositories(settings(), add)
    except ServiceRefusal as refusal:
        fail(refusal.detail)
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
    from fleetbus.api.errors import ServiceRefusal
    from fleetbus.workers.store import run_with_repositories

    async def read(repos: Repositories) -> list[Comment]:
        await _discussions(repos).mission(mission_id)
        return await repos.comments.comments(mission_id, limit)

    try:
        found = run_with_repositories(settings(), read)
    except ServiceRefusal as refusal:
        fail(refusal.detail)
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
