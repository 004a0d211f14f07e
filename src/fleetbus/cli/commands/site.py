"""``fleetbus site up | status | down``, on a site: its links to central."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from fleetbus.broker.accounts import vhost_of
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI, ManagementError
from fleetbus.broker.sites import start_site_links, stop_site_links
from fleetbus.broker.tls import shovel_uris
from fleetbus.broker.uplink import bounds_of
from fleetbus.broker.urls import mask_password
from fleetbus.cli.commands.setup import set_up
from fleetbus.cli.context import admin_api, console, endpoint, fail, no_password_in_argv, settings
from fleetbus.cli.services import with_services
from fleetbus.publishers.tls import TlsSettingError
from fleetbus.schemas.routing import DOWNLINK_REJECTED_QUEUE
from fleetbus.workers.overflow import dropped_from_queue
from fleetbus.workers.site_status import site_view

if TYPE_CHECKING:
    from fleetbus.api.services.standalone import Services
    from fleetbus.workers.store.housekeeping import BoundCount

app = typer.Typer(
    help="On a site: its links to central (the uplink and downlink shovels).", no_args_is_help=True
)

SHOVEL_PLUGINS = ("rabbitmq_shovel", "rabbitmq_shovel_management")


def _shovels_enabled(api: ManagementAPI, vhost: str) -> bool:
    try:
        api.shovel_status(vhost)
    except ManagementError:
        return False
    return True


def _enable_shovels(ep: BrokerEndpoint, api: ManagementAPI) -> None:
    """The shovel plugins: enabled on the private node at once; on another broker, say how."""
    if _shovels_enabled(api, vhost_of(ep.amqp_url)):
        return
    if ep.kind != "private":
        plugins = " ".join(SHOVEL_PLUGINS)
        fail(f"enable the shovel plugins on the site's broker first: rabbitmq-plugins enable {plugins}")
    from fleetbus.cli.local_broker import require_local_broker

    try:
        require_local_broker().enable_plugins(settings(), SHOVEL_PLUGINS)
    except Exception as error:  # the node's own error names what failed
        fail(str(error))


@app.command()
def up(
    name: Annotated[str, typer.Option("--name", help="the site's name, as central knows it")],
    central_file: Annotated[
        Path | None,
        typer.Option(
            "--central-file",
            help="a file holding the site's URL at central (`fleetbus sites add` printed it; keep it "
            "0600); default FLEETBUS_CENTRAL_URL",
        ),
    ] = None,
    central: Annotated[
        str | None,
        typer.Option(
            "--central",
            help="the site's URL at central, without a password (a client certificate's, "
            "auth_mechanism=external): a password on the command line is seen by every user of the machine",
        ),
    ] = None,
) -> None:
    """Start the site's links: this broker (started if it is the private one) forwards everything it
    accepts to central, and takes central's changes; run `fleetbus worker` beside it as usual."""
    config = settings()
    no_password_in_argv(central, "--central", "in a file (--central-file) or in FLEETBUS_CENTRAL_URL")
    if central_file is not None:
        try:
            central = central_file.read_text().strip()
        except OSError as error:
            fail(f"--central-file: {error}", code=2)
    central = central or config.central_url
    if not central:
        fail("no central URL: give --central-file or set FLEETBUS_CENTRAL_URL")
    try:
        shovel_uris(central)  # a URL the shovels cannot verify with is refused before anything changes
    except TlsSettingError as error:
        fail(f"the central URL cannot be used for the site's links: {error}")
    ep = endpoint()
    set_up(ep)
    with admin_api(ep) as api:
        _enable_shovels(ep, api)
        asyncio.run(
            start_site_links(
                ep.amqp_url,
                api,
                name,
                central,
                bounds=bounds_of(config),
                rejected_max=config.downlink_rejected_max,
                reconnect_delay_s=config.site_reconnect_delay_s,
            )
        )
    console.print(
        f"site [bold]{name}[/]: forwarding to {mask_password(central)} (fleetbus-uplink-hazards, "
        "fleetbus-uplink, fleetbus-uplink-telemetry), taking central's changes (fleetbus-downlink, "
        "fleetbus-downlink-maps)",
        soft_wrap=True,
        highlight=False,
    )


@app.command()
def status(as_json: Annotated[bool, typer.Option("--json", help="one JSON document")] = False) -> None:
    """The uplink, downlink and hazard uplink: running or not, since when, and what waits to be
    forwarded."""
    ep = endpoint()

    async def read(services: Services) -> tuple[list[str], list[BoundCount]]:
        return await services.site_team.names(), await services.stats.removed()

    team, counts = with_services(read)
    dropped = dropped_from_queue(counts, DOWNLINK_REJECTED_QUEUE)
    with admin_api(ep) as api:
        link = site_view(api, vhost_of(ep.amqp_url), team)
    if as_json:
        console.print_json(json.dumps({**link.as_dict(), "rejected_dropped": dropped}))
        return
    table = Table(title="links to central")
    for column in ("shovel", "state", "since", "reason"):
        table.add_column(column)
    others = [s for name, s in link.shovels.items() if name not in (link.uplink.name, link.downlink.name)]
    shovels = (link.uplink, link.downlink, *([link.hazard_uplink] if link.hazard_uplink else []), *others)
    for shovel in shovels:
        colour = "green" if shovel.state == "running" else "red"
        table.add_row(shovel.name, f"[{colour}]{shovel.state}[/]", shovel.since or "-", shovel.reason or "")
    console.print(table)
    waiting = "?" if link.waiting is None else f"{link.waiting:,}"
    by_class = ", ".join(
        f"{name} {depth.waiting:,} of {depth.bound:,}" for name, depth in link.classes.items()
    )
    console.print(f"waiting to be forwarded: {waiting} events ({by_class})", highlight=False)
    if link.hazard_states_waiting:
        console.print(f"hazard states waiting for central: {link.hazard_states_waiting:,}", highlight=False)
    if link.rejected:
        console.print(
            f"[red]downlink messages not applied: {link.rejected:,}[/] "
            "(kept in fleetbus.downlink.rejected, each with the reason in its x-fleetbus-rejected header)",
            highlight=False,
        )
    if dropped:
        console.print(
            f"{dropped:,} older downlink messages not applied were dropped: fleetbus.downlink.rejected "
            f"keeps the newest {link.rejected_bound or '?'} (FLEETBUS_DOWNLINK_REJECTED_MAX)",
            highlight=False,
        )
    if link.not_forwarded:
        console.print(
            f"not forwarded (central did not send their accounts): {', '.join(link.not_forwarded)}",
            highlight=False,
        )


@app.command()
def apply(
    once: Annotated[bool, typer.Option("--once", help="apply what is waiting, then stop")] = False,
    name: Annotated[
        str | None,
        typer.Option("--name", help="the site's name, to report to central; default FLEETBUS_SITE_NAME"),
    ] = None,
) -> None:
    """Apply central's changes (its robots' accounts, the team's missions) to this site as they
    come, until Ctrl-C. With the site's name and FLEETBUS_CENTRAL_URL, it also reports what waits
    in the uplink and how the links fare to central every FLEETBUS_SITE_REPORT_EVERY_S (`fleetbus
    sites` there shows it)."""
    from fleetbus.workers.downlink import apply_downlink
    from fleetbus.workers.site_report import report_to_central

    config = settings()
    ep = endpoint()
    site, central = name or config.site_name, config.central_url
    with admin_api(ep) as api:
        vhost = vhost_of(ep.amqp_url)

        def report() -> bool:
            assert site and central
            team, held = with_services(lambda services: services.site_team.in_use())
            return report_to_central(api, vhost, site, central, team, held)

        tick = report if site and central else None
        if tick is None:
            console.print("not reporting to central: no site name (--name) or no FLEETBUS_CENTRAL_URL")
        try:
            applied = apply_downlink(
                config,
                ep.amqp_url,
                api,
                idle_s=1.0 if once else None,
                tick=tick,
                tick_every_s=config.site_report_every_s,
            )
        except KeyboardInterrupt:
            return
    console.print(f"applied {applied} changes from central", highlight=False)


@app.command()
def down() -> None:
    """Stop forwarding (delete every shovel of the site); what waits in the uplink stays for the
    next `site up`."""
    ep = endpoint()
    with admin_api(ep) as api:
        stop_site_links(api, vhost_of(ep.amqp_url))
    console.print("the site's links to central are stopped")
