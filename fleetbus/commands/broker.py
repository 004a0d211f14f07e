"""``fleetbus broker up | down | status`` (placeholder until the local node lands)."""

from __future__ import annotations

import typer

app = typer.Typer(help="The project's private RabbitMQ node.", no_args_is_help=True)
