"""What the commands share: settings, the resolved broker, clean error exits."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import typer
import yaml
from rich.console import Console

from broker.endpoint import BrokerEndpoint, resolve_broker
from broker.management import ManagementAPI
from fleetbus.config import Settings, load_settings

console = Console()
errors = Console(stderr=True)


def fail(message: str, code: int = 1) -> NoReturn:
    errors.print(f"[bold red]error:[/] {message}", highlight=False)
    raise typer.Exit(code)


def settings() -> Settings:
    return load_settings()


def endpoint(start: bool = True) -> BrokerEndpoint:
    try:
        return resolve_broker(settings(), start=start)
    except Exception as error:  # any failure to find a broker ends the command with its reason
        fail(f"no broker: {error}")


@contextmanager
def admin_api(ep: BrokerEndpoint) -> Iterator[ManagementAPI]:
    with ManagementAPI.from_urls(ep.management_url, ep.amqp_url) as api:
        yield api


def load_data(argument: str) -> Any:
    """DATA on the command line: inline JSON, or ``@file.json`` / ``@file.yaml``."""
    if argument.startswith("@"):
        path = Path(argument[1:])
        if not path.exists():
            fail(f"{path}: no such file")
        text = path.read_text()
        if path.suffix.lower() in (".yaml", ".yml"):
            try:
                return yaml.safe_load(text)
            except yaml.YAMLError as error:
                fail(f"{path} is not valid YAML: {error}")
        argument = text
    try:
        return json.loads(argument)
    except json.JSONDecodeError as error:
        fail(f"DATA is not valid JSON ({error}); pass JSON or @file.json / @file.yaml")
