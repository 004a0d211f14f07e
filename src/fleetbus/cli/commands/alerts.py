"""``fleetbus alerts [ack ID]``: the alerts to acknowledge (checked against the store first), and
acknowledging one, as ``GET /alerts`` and ``POST /alerts/{id}/acknowledge`` do."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from fleetbus.cli.context import actor, admin_api, clock, console, fail, settings
from fleetbus.cli.services import with_services
from fleetbus.schemas.roles import UserRole

if TYPE_CHECKING:
    from fleetbus.api.services.alerts import Alert, AlertList, Alerts
    from fleetbus.api.services.standalone import Services

app = typer.Typer(
    help="Alerts the operators acknowledge: a hazard announced or unclaimed, a robot's battery low, a "
    "robot stale, a site's uplink near its bound, dead letters growing. Alone: those not acknowledged "
    "yet (the store is checked first). `ack ID` acknowledges one.",
    invoke_without_command=True,
)


def _alerts(services: Services) -> Alerts:
    """The alerts, counting the dead letters through the broker's management API."""
    import asyncio

    from fleetbus.broker.accounts import vhost_of
    from fleetbus.broker.dead_letter_queue import dead_letters_waiting
    from fleetbus.cli.local_broker import resolve_broker

    config = settings()

    async def waiting() -> int:
        def count() -> int:  # a broker that does not run leaves the dead-letter alerts as they were
            ep = resolve_broker(config, start=False)
            with admin_api(ep) as api:
                return dead_letters_waiting(api, vhost_of(ep.amqp_url))

        return await asyncio.to_thread(count)

    return services.alerts(waiting)


def _row(alert: Alert) -> dict[str, object]:
    return {
        "id": alert.id,
        "kind": alert.kind,
        "subject": alert.subject,
        "detail": alert.detail,
        "since": alert.since.isoformat(),
        "raised_at": alert.raised_at.isoformat(),
        "ended_at": alert.ended_at.isoformat() if alert.ended_at else None,
        "acknowledged_by": alert.acknowledged_by,
        "acknowledged_at": alert.acknowledged_at.isoformat() if alert.acknowledged_at else None,
    }


@app.callback()
def alerts(
    ctx: typer.Context,
    show_all: Annotated[
        bool, typer.Option("--all", help="also the last acknowledged, with who acknowledged each and when")
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="one JSON document")] = False,
) -> None:
    """The alerts not acknowledged yet, oldest first: id, kind, subject, what, since when, ongoing or
    ended; with --all also the last acknowledged (FLEETBUS_ALERTS_ACKNOWLEDGED_SHOWN)."""
    if ctx.invoked_subcommand is not None:
        return

    async def read(services: Services) -> AlertList:
        found = _alerts(services)
        await found.check()
        return await found.listing(show_all)

    listing = with_services(read)
    if as_json:
        document = {
            "unacknowledged": [_row(alert) for alert in listing.unacknowledged],
            "acknowledged": [_row(alert) for alert in listing.acknowledged],
        }
        typer.echo(json.dumps(document))
        return
    table = Table("id", "kind", "subject", "what", "since", "state", title="alerts to acknowledge")
    for alert in listing.unacknowledged:
        state = f"ended {clock(alert.ended_at)[:19]}" if alert.ended_at else "[red]ongoing[/]"
        table.add_row(str(alert.id), alert.kind, alert.subject, alert.detail, clock(alert.since)[:19], state)
    console.print(table if listing.unacknowledged else "no alert to acknowledge", highlight=False)
    if show_all:
        done = Table("id", "kind", "subject", "what", "acknowledged by", "at (UTC)", title="acknowledged")
        for alert in listing.acknowledged:
            at = clock(alert.acknowledged_at)[:19] if alert.acknowledged_at else ""
            by = alert.acknowledged_by or ""
            done.add_row(str(alert.id), alert.kind, alert.subject, alert.detail, by, at)
        console.print(done)


@app.command("ack")
def acknowledge(
    alert_id: Annotated[int, typer.Argument(min=1, help="the alert's id, as `fleetbus alerts` lists it")],
    by: Annotated[
        str | None,
        typer.Option(help="the user acknowledging it, whose role must allow it (else your login, as admin)"),
    ] = None,
) -> None:
    """Acknowledge alert ALERT_ID: who (--by, else your login) and when (UTC) are recorded."""
    from fleetbus.api.services.alerts import acknowledged_text

    async def ack(services: Services) -> Alert:
        role = UserRole.ADMIN  # the command line holds the store: an administrator's
        if by is not None:
            user = await services.users.get_user(by)
            if user is None:
                fail(f"no user {by!r}")
            role = user.role
        return await services.alerts().acknowledge(alert_id, actor(by), role)

    alert = with_services(ack)
    console.print(acknowledged_text(alert), highlight=False)
