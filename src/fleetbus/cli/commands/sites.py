"""``fleetbus sites [add | robots | remove]``, on central: the sites, their robots and links."""

from __future__ import annotations

import json
from collections.abc import Sequence
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from fleetbus.cli.accounts import with_accounts
from fleetbus.cli.context import actor, admin_api, console, endpoint
from fleetbus.cli.services import with_services
from fleetbus.schemas.site_changes import RobotAccount
from fleetbus.workers.recorder.summary import shorten

if TYPE_CHECKING:
    from fleetbus.api.services.sites import SiteRow
    from fleetbus.api.services.standalone import Services

app = typer.Typer(
    help="On central: the sites, their robots, and how their links fare.", invoke_without_command=True
)

Robots = Annotated[str, typer.Option("--robots", help="the site's robots, comma separated")]


def _names(text: str) -> list[str]:
    return [name.strip() for name in text.replace(" ", ",").split(",") if name.strip()]


def _ago(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    seconds = max(0.0, seconds)
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


@app.callback()
def sites(
    ctx: typer.Context,
    as_json: Annotated[bool, typer.Option("--json", help="one JSON document")] = False,
) -> None:
    """Each site: link up or down and since when, what it forwarded, how far behind central is."""
    if ctx.invoked_subcommand is not None:
        return
    ep = endpoint()
    with admin_api(ep) as api:

        async def read(services: Services) -> list[SiteRow]:
            return await services.sites.view(api)

        rows = with_services(read, ep.amqp_url)
    now = datetime.now(timezone.utc)
    if as_json:
        console.print_json(json.dumps([row.as_dict() for row in rows]))
        return
    table = Table(title=f"{len(rows)} sites")
    numbers = ("forwarded", "late", "behind", "waiting", "states")
    for column in ("site", "link", "since", "robots", *numbers, "reported"):
        table.add_column(column, justify="right" if column in numbers else "left")
    for row in rows:
        since = _ago((now - row.since).total_seconds()) + " ago" if row.since else "-"
        table.add_row(
            row.site,
            "[green]up[/]" if row.link_up else "[red]down[/]",
            since,
            shorten(", ".join(row.robots), 40),
            f"{row.forwarded:,}",
            f"{row.late:,}",
            _ago(row.behind_s),
            "?" if row.waiting is None else f"{row.waiting:,}",
            "?" if row.hazard_states_waiting is None else f"{row.hazard_states_waiting:,}",
            _ago(row.report_age_s) + " ago" if row.reported_at else "never",
        )
    console.print(table)
    for row in rows:
        if row.near_full:
            console.print(
                f"[red]alert[/]: site {row.site}'s uplink is near full: {'; '.join(row.near_full)}",
                highlight=False,
            )
    console.print(
        "waiting: events to be forwarded, as the site's newest report said (states: the hazard states "
        "made at the site; reported: how old that is; while the link is down it ages); "
        "behind: since the newest event central received from the site was sent",
        highlight=False,
    )


@app.command()
def add(
    site: Annotated[str, typer.Argument(help="the site's name (its account at central)")],
    robots: Robots = "",
    rotate: Annotated[bool, typer.Option("--rotate", help="give an existing site a new password")] = False,
    by: Annotated[str | None, typer.Option(help="who makes it, for the record (default: your login)")] = None,
) -> None:
    """Make a site's account at central (tagged impersonator, confined to its robots, which must
    be robots of the account registry) and send the site their accounts; its URL, for `fleetbus
    site up --central-file`, is printed once."""
    ep = endpoint()
    added = with_accounts(
        ep, lambda accounts, _repos, _api: accounts.add_site(site, _names(robots), actor(by), rotate=rotate)
    )
    _say_sent(site, added.sent)
    _say_removed(site, added.removed)
    robots_ = ", ".join(added.robots) or "none yet"
    console.print(f"site [bold]{site}[/] with robots {robots_}; its central URL (shown once):")
    console.print(added.public_url, soft_wrap=True, highlight=False)


@app.command("robots")
def robots_command(
    site: Annotated[str, typer.Argument(help="the site")],
    add_: Annotated[str, typer.Option("--add", help="robots to add, comma separated")] = "",
    remove: Annotated[str, typer.Option("--remove", help="robots to remove, comma separated")] = "",
    by: Annotated[
        str | None, typer.Option(help="who changes it, for the record (default: your login)")
    ] = None,
) -> None:
    """Change which robots a site forwards for (its account's permissions follow): the site is sent
    the accounts of those added and told to remove its copies of those removed."""
    ep = endpoint()
    changed = with_accounts(
        ep,
        lambda accounts, _repos, _api: accounts.change_site_robots(
            site, _names(add_), _names(remove), actor(by)
        ),
    )
    _say_sent(site, changed.sent)
    _say_removed(site, changed.removed)
    console.print(f"site [bold]{site}[/]: {', '.join(changed.robots) or 'no robots'}")


@app.command()
def sync(site: Annotated[str, typer.Argument(help="the site")]) -> None:
    """Send the site every one of its robots' accounts, the list of its robots (the site removes
    its copies of the accounts central gave it that are not on it: robots removed at central or
    taken from the site) and every mission again (after a re-key, to a new site node, or when a
    change could not be sent); declare what central takes from the site (its status and hazards
    exchanges, made again if they went)."""
    ep = endpoint()
    synced = with_accounts(ep, lambda accounts, _repos, _api: accounts.sync_site(site))
    _say_sent(site, synced.sent)
    console.print(
        f"sent {site} the list of its robots: {', '.join(synced.robots) or 'none'} (`fleetbus site "
        "apply` removes its copies of the accounts of any other robot central gave it)",
        highlight=False,
    )
    missions = with_services(lambda services: services.sites.send_missions(site), ep.amqp_url)
    console.print(f"sent {site} {missions} missions", highlight=False)


def _say_removed(site: str, robots: Sequence[str]) -> None:
    if robots:
        console.print(
            f"told {site} to remove its copies of the accounts of {', '.join(robots)} "
            "(`fleetbus site apply` removes them)",
            highlight=False,
        )


def _say_sent(site: str, accounts: Sequence[RobotAccount]) -> None:
    if accounts:
        names = ", ".join(account.name for account in accounts)
        console.print(
            f"sent {site} the accounts of {names} (`fleetbus site apply` applies them)", highlight=False
        )
