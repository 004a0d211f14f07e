"""``fleetbus team [out | in NAME]``: the team the hazard gate follows; wardens out of service and back."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from fleetbus.cli.context import actor, clock, console, endpoint, settings
from fleetbus.cli.services import with_services
from fleetbus.workers.team import TeamMember, ago

if TYPE_CHECKING:
    from fleetbus.api.services.standalone import Services
    from fleetbus.api.services.team import TeamView

app = typer.Typer(
    help="The team the hazard gate follows. Alone: every robot with its kind, localised or not, "
    "last seen (any event), stale (silent longer than FLEETBUS_STALE_AFTER_S), in service (who "
    "changed that, when) and whether it counts for the gate; then the gate: open, or why it holds "
    "hazards. `out` and `in` take a warden out of service and put it back.",
    invoke_without_command=True,
)


@app.callback()
def team(
    ctx: typer.Context,
    as_json: Annotated[bool, typer.Option("--json", help="one JSON document")] = False,
    offset: Annotated[int, typer.Option(min=0, help="skip this many robots (by name)")] = 0,
    limit: Annotated[int | None, typer.Option(min=1, help="show at most this many robots")] = None,
) -> None:
    """Every robot of the team: its kind, localised or not, when it was last heard from (any event),
    stale (silent longer than FLEETBUS_STALE_AFTER_S), in service or not (who changed it, when),
    and whether it counts for the hazard gate; then the gate itself."""
    if ctx.invoked_subcommand is not None:
        return
    config = settings()

    async def read(services: Services) -> TeamView:
        return await services.team.view(offset=offset, limit=limit)

    view = with_services(read)
    members, state, closed = view.members, view.gate, view.closed_because
    now = datetime.now(timezone.utc)
    if as_json:
        document = {
            "robots": [member.as_dict() for member in members],
            "total": view.total,
            "offset": offset,
            "gate": {"open": state.open, "announces_to": state.wardens, "closed_because": closed},
        }
        typer.echo(json.dumps(document))
        return
    table = Table(
        "robot",
        "kind",
        "localised",
        "last seen",
        "stale",
        "in service",
        "counts for the gate",
        "outbox dropped",
        caption=f"robots {offset + 1} to {offset + len(members)} of {view.total}" if members else None,
    )
    for member in members:
        table.add_row(
            member.robot.name,
            member.robot.kind or "?",
            "yes" if member.robot.localised else "[yellow]no[/]",
            ago(member.last_seen, now),
            f"[red]stale[/] (> {config.stale_after_s:g} s)" if member.stale else "",
            _service(member),
            "yes" if member.counts_for_gate else "",
            ", ".join(f"{kind} {n:,}" for kind, n in sorted(member.outbox_dropped.items())),
        )
    console.print(table)
    if closed:
        console.print(f"hazard gate: [yellow]closed[/]: {closed}", highlight=False)
    else:
        console.print(f"hazard gate: open: announcing to {', '.join(state.wardens)}", highlight=False)


def _service(member: TeamMember) -> str:
    """``yes`` or ``no``, with who last changed it and when (the audit record)."""
    robot = member.robot
    text = "yes" if robot.in_service else "[red]no[/]"
    if robot.service_changed_at is not None:
        text += f" ({robot.service_changed_by}, {clock(robot.service_changed_at)[:19]})"
    return text


def _change(name: str, in_service: bool, by: str | None) -> None:
    """As ``POST /team/NAME/out`` and ``/in`` do: the same checks and refusals."""
    who = actor(by)

    async def work(services: Services) -> None:
        await services.team.set_in_service(name, in_service, who)

    with_services(work, endpoint().amqp_url)
    console.print(f"{name} {'back in service' if in_service else 'out of service'} (by {who})")


By = Annotated[str | None, typer.Option(help="who makes the change, for the record (default: your login)")]


@app.command("out")
def take_out(name: str, by: By = None) -> None:
    """Take warden NAME out of service: it no longer holds the hazard gate and is sent no hazards."""
    _change(name, False, by)


@app.command("in")
def put_back(name: str, by: By = None) -> None:
    """Put warden NAME back in service: it is sent the open hazards it missed, then counts for the
    gate again (held hazards wait for it to be localised)."""
    _change(name, True, by)
