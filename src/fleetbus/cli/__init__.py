"""The `fleetbus` command line: one Typer app, one module per command group (`fleetbus.cli.commands`)."""

from fleetbus.cli.app import app

__all__ = ["app"]
