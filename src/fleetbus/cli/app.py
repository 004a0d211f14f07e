"""The ``fleetbus`` console script: one Typer app, one module per command group.

A command's module is imported when that command runs (or a help page lists it), not at every
start: `fleetbus hazards` does not load what `fleetbus api` or `fleetbus worker` need (FastAPI,
aio-pika, the workers), and starts in a fraction of the time.

Other distributions add commands through the ``fleetbus.commands`` entry points, each naming a
function or a Typer app: the development tooling (``dev/``) adds ``broker`` and ``demo`` so.
"""

from __future__ import annotations

import functools
import importlib
from importlib.metadata import entry_points
from typing import Any

import click
import typer
from typer.core import TyperGroup

#: Each command: its name -> (module in ``fleetbus.cli.commands``, attribute), the attribute a
#: function (one command) or a Typer app (a group of commands). Listed in help in this order.
COMMANDS: dict[str, tuple[str, str]] = {
    "worker": ("worker", "worker"),
    "setup": ("setup", "setup"),
    "publish": ("events", "publish"),
    "query": ("events", "query"),
    "dlq": ("dlq", "dlq"),
    "outbox": ("outbox", "outbox"),
    "hazards": ("hazards", "app"),
    "missions": ("missions", "app"),
    "schemas": ("schemas_export", "export_schemas"),
    "tail": ("tail", "tail"),
    "timeline": ("timeline", "timeline"),
    "trace": ("trace", "trace"),
    "evaluate": ("evaluate", "evaluate"),
    "replay": ("replay", "replay"),
    "import": ("bags", "import_bag"),
    "export": ("bags", "export"),
    "stats": ("stats", "stats"),
    "certs": ("certs", "app"),
    "users": ("users", "app"),
    "beacons": ("beacons", "app"),
    "map": ("maps", "app"),
    "recorder": ("recorder", "app"),
    "api": ("api", "app"),
    "shards": ("shards", "app"),
    "team": ("team", "app"),
    "alerts": ("alerts", "app"),
    "site": ("site", "app"),
    "sites": ("sites", "app"),
    "ros": ("ros", "app"),
}


#: The entry point group other distributions add commands with.
PLUGIN_GROUP = "fleetbus.commands"


@functools.cache
def plugin_commands() -> dict[str, Any]:
    """The commands installed distributions add, by name (their entry points, not yet loaded); a
    name of fleetbus's own is never replaced."""
    return {ep.name: ep for ep in entry_points(group=PLUGIN_GROUP) if ep.name not in COMMANDS}


def command_names() -> list[str]:
    return [*COMMANDS, *plugin_commands()]


class LazyCommands(TyperGroup):
    """The top-level group: knows its commands by name, imports one when it is asked for."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return command_names()

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        # fleetbus's own commands are known without reading the installed distributions' entry
        # points, which takes about 0.1 s
        if cmd_name in COMMANDS or cmd_name in plugin_commands():
            return load_command(cmd_name)
        return None


@functools.cache
def load_command(name: str) -> click.Command:
    """The click command ``name`` is, built as registering it on the app would (``command`` for
    a function, ``add_typer`` for an app), with the app's settings."""
    if name in COMMANDS:
        module, attribute = COMMANDS[name]
        target = getattr(importlib.import_module(f"fleetbus.cli.commands.{module}"), attribute)
    else:
        target = plugin_commands()[name].load()
    holder = typer.Typer(rich_markup_mode=app.rich_markup_mode, pretty_exceptions_show_locals=False)
    if isinstance(target, typer.Typer):
        holder.add_typer(target, name=name)
    else:
        holder.command(name)(target)
    return typer.main.get_group(holder).commands[name]


app = typer.Typer(
    name="fleetbus",
    cls=LazyCommands,
    help="Event backbone and database server for a team of robots.",
    no_args_is_help=True,
    pretty_exceptions_show_locals=False,
)


@app.callback()
def main() -> None:
    """(Its commands are :data:`COMMANDS`: a callback makes the app a group without registering them.)"""


if __name__ == "__main__":
    app()
