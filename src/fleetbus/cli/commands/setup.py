"""``fleetbus setup``: as the administrator, once, what the worker and the recorder need to run
with their own accounts alone (see :mod:`fleetbus.workers.setup`)."""

from __future__ import annotations

import asyncio
from typing import Annotated

import typer

from fleetbus.bounds import bounds
from fleetbus.broker.accounts import RECORDER_USER, SERVICE_USER, kept_password_file, vhost_of
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.urls import mask_password, without_password
from fleetbus.cli.context import console, endpoint, fail, settings
from fleetbus.settings import Settings
from fleetbus.workers.setup import set_up_service

ShowPassword = Annotated[
    bool,
    typer.Option("--show-password", help="print the URLs with their passwords (they are masked otherwise)"),
]


def show_url(url: str, show_password: bool) -> str:
    return url if show_password else mask_password(url)


def set_up(admin: BrokerEndpoint, show_password: bool = False, config: Settings | None = None) -> None:
    """Make the service accounts, the topology and the bindings on ``admin``; say what was made.
    ``config``: the settings to use instead of the environment's."""
    config = config or settings()
    try:
        accounts = asyncio.run(set_up_service(config, admin))
    except Exception as error:  # the management API or AMQP refused: say so, with no traceback
        fail(f"setting up the service accounts failed: {error}")
    shards = f"{config.ingest_shards} ingest shard{'s' if config.ingest_shards > 1 else ''}"
    say = console.print
    limits = bounds(config)
    say(
        f"set up in virtual host {vhost_of(admin.amqp_url)!r}: the service accounts, the topology "
        f"({shards}), the recorder's queue and bindings; each inbox keeps {limits.inbox.describe()}, "
        f"the dead-letter queue {limits.dead_letters.describe()} (FLEETBUS_INBOX_MAX, "
        "FLEETBUS_DEAD_LETTERS_MAX)",
        soft_wrap=True,
        highlight=False,
    )
    for name, url in ((SERVICE_USER, accounts.service_url), (RECORDER_USER, accounts.recorder_url)):
        say(
            f"[bold]{name:<18}[/] {show_url(url, show_password)}  "
            f"password in {kept_password_file(config.accounts_dir, name)}",
            soft_wrap=True,
            highlight=False,
        )
    say(
        f"`fleetbus worker` needs only FLEETBUS_SERVICE_URL={without_password(accounts.service_url)} "
        "and these two files (no administrator credentials)",
        soft_wrap=True,
        highlight=False,
    )


def setup(show_password: ShowPassword = False) -> None:
    """Make the service accounts (fleetbus, fleetbus-recorder), the topology, the recorder's
    bindings and the policies that bound the inboxes and the dead-letter queue, as the broker's
    administrator (FLEETBUS_AMQP_URL, else the local broker). Run it once per broker, and again
    after changing FLEETBUS_INBOX_MAX or FLEETBUS_DEAD_LETTERS_MAX; running it again changes nothing
    else that is in place. `fleetbus broker up` runs it too."""
    set_up(endpoint(), show_password)
