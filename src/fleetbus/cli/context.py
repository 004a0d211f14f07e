"""What the commands share: settings, the resolved broker, clean error exits."""

from __future__ import annotations

import getpass
import json
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import typer
from rich.console import Console

# What only some commands need is imported in the functions that need it: every command loads
# this module, and one that reads the store should not wait for the broker's clients to load.
if TYPE_CHECKING:
    from fleetbus.broker.endpoint import BrokerEndpoint
    from fleetbus.broker.management import ManagementAPI
    from fleetbus.broker.routes import RouteMap
    from fleetbus.settings import Settings

console = Console()
errors = Console(stderr=True)


def fail(message: str, code: int = 1) -> NoReturn:
    errors.print(f"[bold red]error:[/] {message}", highlight=False)
    raise typer.Exit(code)


def no_password_in_argv(url: str | None, option: str, instead: str) -> None:
    """End the command (status 2) when ``url``, given as ``option`` on the command line, holds a
    password: every user of the machine sees a command's arguments. ``instead``: where it goes."""
    from urllib.parse import urlsplit

    if url is not None and urlsplit(url).password:
        fail(
            f"{option} holds a password, which every user of this machine sees on the command line: "
            f"give it {instead}",
            code=2,
        )


def settings() -> Settings:
    """The settings; one that does not parse ends the command, naming its variable."""
    from fleetbus.settings import load_settings

    try:
        return load_settings()
    except ValueError as error:
        fail(str(error), code=2)


def actor(by: str | None) -> str:
    """Who makes a change from the command line, for the record: ``--by``, else the login."""
    return by or f"{getpass.getuser()} (command line)"


def endpoint(start: bool = True) -> BrokerEndpoint:
    from fleetbus.cli.local_broker import resolve_broker

    try:
        return resolve_broker(settings(), start=start)
    except Exception as error:  # any failure to find a broker ends the command with its reason
        fail(f"no broker: {error}")


def service_account(account: str | None = None) -> str:
    """The URL the worker (``fleetbus``, the default) or the recorder (``fleetbus-recorder``)
    logs in with: never the administrator's."""
    from fleetbus.broker.accounts import SERVICE_USER
    from fleetbus.broker.endpoint import service_account_url
    from fleetbus.cli.local_broker import resolve_broker

    try:
        current = settings()
        return service_account_url(current, account or SERVICE_USER, lambda: resolve_broker(current).amqp_url)
    except Exception as error:  # any failure to find the broker ends the command with its reason
        fail(f"no broker: {error}")


@contextmanager
def admin_api(ep: BrokerEndpoint) -> Iterator[ManagementAPI]:
    from fleetbus.broker.management import ManagementAPI

    with ManagementAPI.from_urls(ep.management_url, ep.amqp_url) as api:
        yield api


def clock(moment: datetime) -> str:
    return moment.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]


def route_map() -> RouteMap | None:
    """The broker's exchanges, bindings and consumers now; None (with a warning) when it does not answer."""
    from fleetbus.broker.accounts import vhost_of
    from fleetbus.broker.endpoint import BrokerEndpoint, derive_management_url
    from fleetbus.broker.routes import RouteMap
    from fleetbus.cli.local_broker import resolve_broker

    config = settings()
    try:
        if config.amqp_url:  # only its management API is asked: no AMQP login to probe first
            management_url = config.management_url or derive_management_url(config.amqp_url)
            ep = BrokerEndpoint(config.amqp_url, management_url, "external")
        else:
            ep = resolve_broker(config, start=False)
        with admin_api(ep) as api:
            return RouteMap.from_management(api, vhost_of(ep.amqp_url))
    except Exception as error:  # the recording still answers without the broker
        errors.print(f"[yellow]note:[/] no broker to ask for routes and consumers ({error})", highlight=False)
        return None


def load_data(argument: str) -> Any:
    """DATA on the command line: inline JSON, or ``@file.json`` / ``@file.yaml``."""
    if argument.startswith("@"):
        path = Path(argument[1:])
        if not path.exists():
            fail(f"{path}: no such file")
        text = path.read_text()
        if path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            try:
                return yaml.safe_load(text)
            except yaml.YAMLError as error:
                fail(f"{path} is not valid YAML: {error}")
        argument = text
    try:
        return json.loads(argument)
    except json.JSONDecodeError as error:
        fail(f"DATA is not valid JSON ({error}); pass JSON or @file.json / @file.yaml")
