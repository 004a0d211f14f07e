"""The ``fleetbus`` console script: one Typer app, one module per command group."""

from __future__ import annotations

import typer

from fleetbus.commands import broker as broker_commands

app = typer.Typer(
    name="fleetbus",
    help="Event backbone and database server for a team of robots.",
    no_args_is_help=True,
    pretty_exceptions_show_locals=False,
)
app.add_typer(broker_commands.app, name="broker")

if __name__ == "__main__":
    app()
